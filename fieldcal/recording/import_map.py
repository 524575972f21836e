"""Import maps: which file holds which triad in which columns, in what units, on what clock.

An import map is a YAML file (``configs/recordings/NAME.yaml``, or any path)::

    description: free text (optional)
    files:                              # one entry per input file, in the order they are given
      - name: accelerometer file        # optional, for messages (default "file 1", ...)
        delimiter: null                 # one character, or null / "whitespace" for runs of blanks
                                        #   (default ",")
        comment: "#"                    # prefix of lines to skip (default "#"; null for none)
        time: {column: 0, unit: s}      # 0-based column; unit s, ms, us or ns, or instead
                                        #   scale: seconds per text unit (e.g. 1.0e-4)
        temperature: {column: 7}        # optional: the unit's temperature, °C (scale: °C per
                                        #   text unit, e.g. 0.01; default 1), for apply's
                                        #   thermal model
        # or no time column at all: the samples are 1 / rate_hz apart (or `--rate` at import)
        rate_hz: 100
        variable: acc                   # a MATLAB MAT-file (v4-v7.2): the matrix to read, one
                                        #   sample a row (default: its only numeric matrix)
        triads:
          accelerometer: {columns: [1, 2, 3], kind: specific_force, unit: count}
          # optional scale: the value kept is text value * scale, in the unit named

Columns (and the time column) may be given by their names in the file's header line instead of
numbers, e.g. ``columns: [acc_x, acc_y, acc_z]``: the header is the last text line before the
first sample that holds them all; metadata lines above it (``Fs,100``, ``Device,...``) are
skipped as header lines.

Every problem is one line naming the file and the dotted field, as a :class:`ImportMapError`.
The parsing itself is ``drivers.protocols.delimited``: each entry becomes a ChannelMap.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from drivers.protocols.delimited import ChannelMap
from fieldcal.model import ANGULAR_RATE, KINDS, SPECIFIC_FORCE
from fieldcal.paths import RECORDINGS_DIR, find_named, not_found  # noqa: F401 (RECORDINGS_DIR: imported from here)
from fieldcal.validation import IDENTIFIER, FieldReader, describe, join, parse_yaml, read_yaml_text

TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
# Units that clearly belong to one kind: naming one for the other kind is a mistake in the map.
# Anything else ("count", "LSB", "mV", ...) is accepted as the device's own unit.
_UNITS_OF = {SPECIFIC_FORCE: {"m/s^2", "m/s2", "m/s²", "g", "mg", "ug"},
             ANGULAR_RATE: {"rad/s", "mrad/s", "deg/s", "°/s", "dps", "mdeg/s", "deg/h", "°/h"}}
_EXAMPLES = {SPECIFIC_FORCE: "m/s^2, g, mg", ANGULAR_RATE: "rad/s, deg/s"}


class ImportMapError(ValueError):
    def __init__(self, message: str, path: str = "", field: str = ""):
        super().__init__(message)
        self.path, self.field = path, field


@dataclass(frozen=True)
class FileSpec:
    """One input file: its name for messages, how to parse it, and its triads' kinds and units.

    ``channel_map`` is None when a column is named (``names``: the names to find in the header
    line, ``channels``: the mapping to complete with their numbers, see :meth:`resolve`).
    ``rate_hz``: the sample rate of a file with no time column."""

    name: str
    channel_map: ChannelMap | None
    kinds: dict[str, str]
    units: dict[str, str]
    rate_hz: float | None = None
    names: tuple[str, ...] = ()
    channels: dict | None = None
    where: str = ""  # the entry's place in the map, for messages
    variable: str | None = None  # a MATLAB MAT-file's matrix to read (see recording.containers)

    @property
    def has_time(self) -> bool:
        return (self.channels or {}).get("time_column") is not None if self.channel_map is None \
            else self.channel_map.time_column is not None

    @property
    def has_temperature(self) -> bool:
        return (self.channels or {}).get("temperature_column") is not None if self.channel_map is None \
            else self.channel_map.temperature_column is not None

    def resolve(self, header: list[str], path: str) -> ChannelMap:
        """The channel map with each named column replaced by its number in ``header``."""
        if self.channel_map is not None:
            return self.channel_map
        index = {name: i for i, name in reversed(list(enumerate(header)))}

        def number(column):
            return index[column] if isinstance(column, str) else column
        channels = dict(self.channels)
        channels["time_column"] = number(channels["time_column"])
        channels["temperature_column"] = number(channels.get("temperature_column"))
        channels["triads"] = {t: dict(body, columns=[number(c) for c in body["columns"]])
                              for t, body in channels["triads"].items()}
        try:
            return ChannelMap.from_mapping(channels, self.where)
        except ValueError as exc:
            raise ImportMapError(f"{path}: {exc}", path, self.where) from None


@dataclass(frozen=True)
class ImportMap:
    """An import map: which file holds which triads, in which columns and units."""
    path: str  # where it was read from (for messages)
    text: str  # the YAML as written, kept in the session for provenance
    files: tuple[FileSpec, ...]
    description: str = ""

    @property
    def file_names(self) -> tuple[str, ...]:
        return tuple(f.name for f in self.files)


def resolve_map_path(name_or_path: str | os.PathLike) -> Path:
    """A path as given, or a bare name: NAME.yaml here, else a shipped map (configs/recordings/),
    by the rule of ``fieldcal.paths`` that also finds configs and procedures."""
    found = find_named(name_or_path, "import map")
    if found is None:
        raise ImportMapError(not_found(name_or_path, "import map"), str(name_or_path))
    return found


def load_import_map(name_or_path: str | os.PathLike) -> ImportMap:
    """Read and validate an import map; any problem is a one-line ImportMapError."""
    path = resolve_map_path(name_or_path)
    text = read_yaml_text(path, ImportMapError, "import map")
    return parse_import_map(parse_yaml(text, str(path), ImportMapError), str(path), text)


def parse_import_map(doc, path: str, text: str = "") -> ImportMap:
    """Validate an already-loaded YAML document (``path`` only names it in messages)."""
    r = FieldReader(path, ImportMapError)
    m = r.mapping(doc, "", ("files",), ("description",))
    description = r.string(m, "description", "", optional=True) or ""
    files_in = m["files"]
    if not isinstance(files_in, list) or not files_in:
        r.fail("files", "a list of files (one entry per input file)", describe(files_in))
    files: list[FileSpec] = []
    owner: dict[str, str] = {}  # triad name -> the file entry that defines it
    for i, entry in enumerate(files_in):
        spec = _file(r, entry, f"files[{i}]", i)
        for name in spec.kinds:
            if name in owner:
                r.fail(f"files[{i}].triads.{name}", f"a triad name not used by another file "
                       f"(already in {owner[name]})", describe(name))
            owner[name] = f"files[{i}]"
        files.append(spec)
    names = [f.name for f in files]
    for i, name in enumerate(names):
        if name in names[:i]:
            r.fail(f"files[{i}].name", "a name not used by another file", describe(name))
    return ImportMap(path=path, text=text, files=tuple(files), description=description)


def _file(r: FieldReader, entry, where: str, index: int) -> FileSpec:
    m = r.mapping(entry, where, ("triads",), ("name", "delimiter", "comment", "time", "rate_hz", "variable",
                                              "temperature"))
    name = r.string(m, "name", where, optional=True) or f"file {index + 1}"
    variable = r.string(m, "variable", where, optional=True) or None
    time_column, time_scale = (None, 1.0) if m.get("time") is None else _time(r, m["time"], join(where, "time"))
    temperature_column, temperature_scale = (None, 1.0) if m.get("temperature") is None \
        else _temperature(r, m["temperature"], join(where, "temperature"))
    rate_hz = None
    if "rate_hz" in m:
        rate_hz = r.number(m, "rate_hz", where)
        if not rate_hz > 0:
            r.fail(join(where, "rate_hz"), "a sample rate > 0 (Hz)", describe(m["rate_hz"]))
        if time_column is not None:
            r.fail(join(where, "rate_hz"), "no rate_hz when the file has a time column (the "
                   "timestamps give the rate)", describe(m["rate_hz"]))

    triads_in = m["triads"]
    if not isinstance(triads_in, dict) or not triads_in:
        r.fail(join(where, "triads"), "a mapping of triad name -> {columns, kind, unit, scale}",
               describe(triads_in))
    kinds, units, columns = {}, {}, {}
    for tname, body in triads_in.items():
        here = f"{where}.triads.{tname}"
        if not isinstance(tname, str) or not IDENTIFIER.fullmatch(tname):
            r.fail(join(where, "triads"), "triad names of ASCII letters, digits and _ "
                   "(starting with a letter)", describe(tname))
        t = r.mapping(body, here, ("columns", "kind", "unit"), ("scale",))
        kinds[tname] = r.string(t, "kind", here, KINDS)
        units[tname] = r.string(t, "unit", here)
        other = next(k for k in KINDS if k != kinds[tname])
        if units[tname] in _UNITS_OF[other]:
            r.fail(join(here, "unit"), f"a unit of {kinds[tname].replace('_', ' ')} "
                   f"(e.g. {_EXAMPLES[kinds[tname]]}, count)",
                   f"{describe(units[tname])}, a unit of {other.replace('_', ' ')}")
        columns[tname] = {"columns": t["columns"], "unit": units[tname]}
        if "scale" in t:
            columns[tname]["scale"] = t["scale"]
        cols = t["columns"] if isinstance(t["columns"], list) else []
        clash = [k for k, c in enumerate(cols) if type(c) in (int, str) and c == time_column]
        if clash:  # checked here: ChannelMap would name the time column "time_column"
            r.fail(f"{here}.columns[{clash[0]}]", f"a column not used elsewhere (also "
                   f"{where}.time.column)", describe(time_column))

    channels = {"delimiter": m.get("delimiter", ","), "comment": m.get("comment", "#"),
                "time_column": time_column, "time_scale": time_scale, "triads": columns,
                "temperature_column": temperature_column, "temperature_scale": temperature_scale}
    names = tuple(c for c in [time_column, temperature_column] + [c for body in columns.values()
                                             for c in (body["columns"] if isinstance(body["columns"], list) else [])]
                  if isinstance(c, str))
    # Named columns are numbered once the header is read; the rest is checked now, with numbers
    # standing in for the names, by the parser's own validation.
    stand_in = {n: 10_000 + i for i, n in enumerate(dict.fromkeys(names))}
    trial = dict(channels, time_column=stand_in.get(time_column, time_column),
                 temperature_column=stand_in.get(temperature_column, temperature_column),
                 triads={t: dict(b, columns=[stand_in.get(c, c) if isinstance(c, str) else c for c in b["columns"]]
                                 if isinstance(b["columns"], list) else b["columns"]) for t, b in columns.items()})
    try:  # delimiter, comment, columns and scales are checked by the parser's own validation
        channel_map = ChannelMap.from_mapping(trial, where)
    except ValueError as exc:
        raise ImportMapError(f"{r.path}: {exc}", r.path, where) from None
    if names:
        return FileSpec(name=name, channel_map=None, kinds=kinds, units=units, rate_hz=rate_hz,
                        names=tuple(dict.fromkeys(names)), channels=channels, where=where, variable=variable)
    return FileSpec(name=name, channel_map=channel_map, kinds=kinds, units=units, rate_hz=rate_hz, where=where,
                    variable=variable)


def _time(r: FieldReader, raw, where: str) -> tuple[int, float]:
    m = r.mapping(raw, where, ("column",), ("unit", "scale"))
    column = m["column"]
    named = isinstance(column, str) and column.strip() != ""
    if not named and (isinstance(column, bool) or not isinstance(column, int) or column < 0):
        r.fail(join(where, "column"), "a column number (0-based integer >= 0) or its name in the "
               "header line", describe(column))
    if ("unit" in m) == ("scale" in m):  # exactly one: a guessed time unit is a silent 1000x
        r.fail(where, "either unit (s, ms, us, ns) or scale (seconds per text unit), not "
               f"{'both' if 'unit' in m else 'neither'}", "a mapping with keys " + ", ".join(m))
    if "unit" in m:
        return column, TIME_UNITS[r.string(m, "unit", where, tuple(TIME_UNITS))]
    scale = r.number(m, "scale", where)
    if scale <= 0:
        r.fail(join(where, "scale"), "a number > 0 (seconds per text unit)", describe(m["scale"]))
    return column, scale


def _temperature(r: FieldReader, raw, where: str) -> tuple[int | str, float]:
    """The temperature column (a number or its header name) and its scale, °C per text unit."""
    m = r.mapping(raw, where, ("column",), ("scale",))
    column = m["column"]
    named = isinstance(column, str) and column.strip() != ""
    if not named and (isinstance(column, bool) or not isinstance(column, int) or column < 0):
        r.fail(join(where, "column"), "a column number (0-based integer >= 0) or its name in the "
               "header line", describe(column))
    scale = r.number(m, "scale", where) if "scale" in m else 1.0
    if not scale > 0:
        r.fail(join(where, "scale"), "a number > 0 (°C per text unit)", describe(m["scale"]))
    return column, scale
