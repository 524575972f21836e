"""A recording's text file in an import map's layout, read block by block by Apache Arrow's CSV
reader (``pyarrow.csv.open_csv``): the columns read (the time and the triads calibrated; other
columns may hold anything) as float64 numpy arrays, ``block_bytes`` of text at a time, whatever
the file's length.

What is read, and what is refused (a one-line :class:`TextError` naming the file and line):

- Lines before the first sample (column names, ``Fs,100`` metadata, comments) are skipped; the
  first sample is the first line with a number in every column read. Named columns are found
  in the header line as ``fieldcal import`` finds them.
- After it, blank lines and comment lines are skipped; every other line is a sample and must
  have as many fields as the first one, with a finite number in every column read. A line that
  does not (a short line, text, ``nan``) stops the read with its line number: apply never drops
  or guesses a sample.
- A last line with no line end is a recording cut off mid-write (its last number may be cut
  short): refused before anything is read.
- Blank-separated files (``delimiter: null``) have their runs of blanks made single spaces,
  block by block (numpy), before Arrow splits them on a space.

Arrow reports a bad line without its number; only then is the file scanned again, line by line
from the last good block, to name the line.
"""
from __future__ import annotations

import math
import re
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from drivers.protocols.delimited import ChannelMap
from fieldcal.recording.import_map import FileSpec
from fieldcal.recording.importer import HEADER_SEARCH_BYTES, HEADER_SEARCH_LINES, _header_fields

_PLAIN_NUMBER = re.compile(rb'"?[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?"?')  # what Arrow reads as a double
_LINES = re.compile(rb"[^\n]*\n|[^\n]+\Z")  # with their line ends, as file iteration gives them
_LF, _CR = 10, 13
_TAIL_BYTES = 1 << 16


class TextError(ValueError):
    """One line: the file, the line number where known, what is wrong and what to do."""

    def __init__(self, message: str, path: str, line: int | None = None):
        super().__init__(message)
        self.path, self.line = path, line


@dataclass(frozen=True)
class Layout:
    """How the file's samples are read: the resolved channel map, the (role, column) read (the
    time and the triads calibrated: other columns may hold anything), where the first sample
    starts (byte offset, and how many lines come before it), and its number of fields."""

    channel_map: ChannelMap
    roles: tuple[tuple[str, int], ...]
    start: int
    lines_before: int
    fields: int

    @property
    def squeezed(self) -> bool:
        return self.channel_map.delimiter is None

    def split(self, line: bytes) -> list[bytes]:
        return split_fields(self.channel_map, line)

    def skipped(self, line: bytes) -> bool:
        """A line that is no sample and no fault: blank, or a comment with another number of
        fields than a sample (Arrow hands over only such lines; a comment line with as many
        fields as a sample is read as one, and refused)."""
        text = line.strip(b" \t\r\n")
        comment = self.channel_map.comment
        return not text or (comment is not None and text.startswith(comment.encode("ascii"))
                            and len(self.split(line)) != self.fields)

    def fault(self, line: bytes) -> str | None:
        """Why a sample line cannot be read, or None if it can."""
        fields = self.split(line)
        if len(fields) != self.fields:
            return f"{len(fields)} fields where the first sample has {self.fields}"
        for role, column in self.roles:
            field = fields[column].strip(b" \t")
            if not _PLAIN_NUMBER.fullmatch(field) or not math.isfinite(float(field.strip(b'"'))):
                shown = field.decode("utf-8", "replace")
                return f"{role} (column {column + 1}) is {shown!r}, not a finite number" if shown \
                    else f"{role} (column {column + 1}) is empty"
        return None


def split_fields(cm: ChannelMap, line: bytes) -> list[bytes]:
    line = line.rstrip(b"\r\n")
    return line.split() if cm.delimiter is None else line.split(cm.delimiter.encode("ascii"))


def layout(path: str, spec: FileSpec, triads) -> Layout:
    """Read the start of the file (and its end): the resolved channel map and the first sample;
    TextError for a file with no sample near its start or cut off mid-line. ``triads``: the
    names of the triads read."""
    with open(path, "rb") as fh:
        head = fh.read(HEADER_SEARCH_BYTES)
        fh.seek(0, 2)
        size = fh.tell()
        fh.seek(max(size - _TAIL_BYTES, 0))
        tail = fh.read()
    cm = spec.resolve(_header_fields(head, spec, path), path) if spec.channel_map is None else spec.channel_map
    roles = tuple((role, c) for role, c in cm.columns if role == "time" or role.rsplit(".", 1)[0] in triads)
    complete = head if size <= len(head) else head[:head.rfind(b"\n") + 1]
    offset = 0
    for number, line in enumerate(_LINES.findall(complete)[:HEADER_SEARCH_LINES], 1):
        probe = Layout(cm, roles, offset, number - 1, len(split_fields(cm, line)))
        if max(c for _, c in roles) < probe.fields and not probe.skipped(line) and probe.fault(line) is None:
            _check_ending(path, tail, cm)
            return probe
        offset += len(line)
    raise TextError(f"apply: {path}: no sample of {spec.name} in its first {HEADER_SEARCH_LINES} lines (a line "
                    f"with a number in every column read: {', '.join(r for r, _ in roles)}); "
                    "check the map's delimiter and columns", path)


def _check_ending(path: str, tail: bytes, cm: ChannelMap) -> None:
    last = tail[tail.rfind(b"\n") + 1:]
    text = last.strip(b" \t\r")
    if text and not (cm.comment and text.startswith(cm.comment.encode("ascii"))):
        line = _count_lines(path) + 1
        raise TextError(f"apply: {path}: line {line}: the last line has no line end: the recording was cut "
                        f"off mid-write and its last number may be cut short ({last[:60].decode('utf-8', 'replace')!r}); "
                        "delete the line, or end it with a newline if it is whole", path, line)


def _count_lines(path: str) -> int:
    with open(path, "rb") as fh:
        return sum(block.count(b"\n") for block in iter(lambda: fh.read(1 << 22), b""))


def read_blocks(path: str, lay: Layout, block_bytes: int) -> Iterator[np.ndarray]:
    """(n, k) float64 per block: the columns read, in ``lay.roles`` order."""
    import pyarrow as pa
    from pyarrow import csv

    cm = lay.channel_map
    names = [f"f{c}" for _, c in lay.roles]

    def invalid_row(row) -> str:  # a line with another number of fields than the first sample
        return "skip" if lay.skipped(row.text.encode("utf-8", "surrogateescape")) else "error"

    read = csv.ReadOptions(block_size=block_bytes, autogenerate_column_names=True)
    parse = csv.ParseOptions(delimiter=" " if lay.squeezed else cm.delimiter, invalid_row_handler=invalid_row)
    convert = csv.ConvertOptions(include_columns=names, column_types={n: pa.float64() for n in names},
                                 null_values=[], strings_can_be_null=False, quoted_strings_can_be_null=False)
    rows = 0
    with open(path, "rb") as fh:
        fh.seek(lay.start)
        source = _Squeezed(fh) if lay.squeezed else fh
        try:
            reader = csv.open_csv(source, read_options=read, parse_options=parse, convert_options=convert)
            for batch in reader:
                values = np.column_stack([batch.column(n).to_numpy() for n in names]) if batch.num_rows \
                    else np.zeros((0, len(names)))
                bad = np.flatnonzero(~np.isfinite(values).all(axis=1))
                if len(bad):
                    raise _bad_line(path, lay, rows + int(bad[0]), None)
                rows += len(values)
                yield values
        except pa.ArrowInvalid as exc:
            raise _bad_line(path, lay, rows, exc) from None


def _bad_line(path: str, lay: Layout, from_row: int, exc: Exception | None) -> TextError:
    """The first sample line at or after sample ``from_row`` that cannot be read (the file is
    read again from the first sample, line by line: only ever on the way to an error)."""
    row = 0
    with open(path, "rb") as fh:
        fh.seek(lay.start)
        for number, line in enumerate(fh, lay.lines_before + 1):
            if lay.skipped(line):
                continue
            if row >= from_row:
                why = lay.fault(line)
                if why is not None:
                    shown = line.rstrip(b"\r\n")[:60].decode("utf-8", "replace")
                    return TextError(f"apply: {path}: line {number}: {why} ({shown!r}); fix or delete the line",
                                     path, number)
            row += 1
    detail = str(exc).splitlines()[0] if exc is not None else "a value that is not a finite number"
    return TextError(f"apply: {path}: after sample {from_row}: {detail}; fix or delete the line", path)


class _Squeezed:
    """A blank-separated file as Arrow reads it: each run of blanks one space, none at a line's
    start or end. Whole lines only (a run never spans two reads); line numbers are kept."""

    def __init__(self, fh) -> None:
        self._fh = fh
        self._rest = b""
        self.closed = False

    def read(self, size: int = -1) -> bytes:
        data = self._rest + (self._fh.read() if size is None or size < 0 else self._fh.read(size))
        cut = data.rfind(b"\n") + 1
        if cut == 0 and len(data) > len(self._rest):  # no line end yet: read on to one
            more = self._fh.readline()
            data, cut = data + more, len(data + more)
        self._rest = data[cut:] if cut else b""
        return squeeze_blanks(data[:cut] if cut else data)

    def readable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return False

    def close(self) -> None:
        self.closed = True


def squeeze_blanks(block: bytes) -> bytes:
    """Runs of spaces and tabs as one space, none at the start or end of a line (vectorised;
    a block already so, the usual logger's output, is returned as it is)."""
    a = np.frombuffer(block, dtype=np.uint8)
    if not len(a):
        return block
    blank = (a == 32) | (a == 9)
    line_end = (a == _LF) | (a == _CR)
    follows_blank_or_line = np.empty_like(blank)
    follows_blank_or_line[0] = True
    np.logical_or(blank[:-1], a[:-1] == _LF, out=follows_blank_or_line[1:])
    drop = blank & follows_blank_or_line  # all of a run but its first blank; a line's leading run
    drop[:-1] |= blank[:-1] & line_end[1:]  # a run's last blank before a line's end
    drop[-1] |= blank[-1]
    if not drop.any():
        return block.replace(b"\t", b" ")
    kept = a[~drop]
    # a run's first blank, kept above, may now stand just before a line's end
    blank = (kept == 32) | (kept == 9)
    trailing = np.append(blank[:-1] & ((kept[1:] == _LF) | (kept[1:] == _CR)), blank[-1:])
    kept = kept[~trailing]
    kept[kept == 9] = 32
    return kept.tobytes()
