"""Loading a parameter file: safe YAML, every field validated, one-line errors naming the field."""
from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Sequence

import numpy as np
import yaml

from fieldcal import __version__
from fieldcal.model import KINDS, SI_UNIT
from fieldcal.paramfile.document import (
    _ANGLE_ATOL,
    _ANGLES,
    _AXES,
    _MAX_CONDITION,
    _SHA256,
    CONSISTENCY_RTOL,
    LOWER_TRIANGULAR_METHODS,
    SCHEMA,
    SOFTWARE,
    ParameterFile,
    ParameterFileError,
    Provenance,
    TriadParameters,
    _misalignment_of,
    dump,
    hash_inputs,
    save,
    to_document,
)


class _UniqueKeyLoader(yaml.SafeLoader):
    """safe_load, but a key given twice in one mapping is an error instead of last-one-wins."""

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            seen = set()
            for key_node, _ in node.value:
                if not isinstance(key_node, yaml.ScalarNode) or key_node.tag == "tag:yaml.org,2002:merge":
                    continue
                key = self.construct_object(key_node)
                if key in seen:
                    raise yaml.constructor.ConstructorError(
                        None, None, f"key {key!r} appears twice in one mapping", key_node.start_mark)
                seen.add(key)
        return super().construct_mapping(node, deep)


_MISSING = object()


def _join(where: str, key: str) -> str:
    return f"{where}.{key}" if where else key


def _describe(value) -> str:
    if value is _MISSING:
        return "nothing (the key is missing)"
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        if math.isnan(value):
            return ".nan"
        if math.isinf(value):
            return ".inf" if value > 0 else "-.inf"
        return repr(value)
    if isinstance(value, int):
        text = repr(value)
        return text if len(text) <= 40 else text[:37] + "..."
    if isinstance(value, str):
        return repr(value) if len(value) <= 60 else repr(value[:57]) + "..."
    if isinstance(value, (list, dict)) and not value:
        return f"an empty {'list' if isinstance(value, list) else 'mapping'}"
    if isinstance(value, list):
        return f"a list of {len(value)} item{'s' if len(value) != 1 else ''}"
    if isinstance(value, dict):
        return "a mapping"
    return f"a {type(value).__name__}"


class _Reader:
    """Validating accessors that raise ParameterFileError naming the file and dotted field."""

    def __init__(self, path: str) -> None:
        self.path = path

    def fail(self, where: str, expected: str, got: str) -> None:
        prefix = f"{self.path}: {where}: " if where else f"{self.path}: "
        raise ParameterFileError(f"{prefix}expected {expected}, got {got}", self.path, where)

    def mapping(self, value, where: str, required: Sequence[str], optional: Sequence[str] = (),
                what: str = "a mapping") -> dict:
        if not isinstance(value, dict):
            keys = ", ".join(required or optional)
            self.fail(where, f"{what} with keys {keys}" if keys else what, _describe(value))
        known = (*required, *optional)
        for key in value:
            if key not in known:
                self.fail(_join(where, key) if isinstance(key, str) else where,
                          f"only the keys {', '.join(known)}", f"the unknown key {_describe(key)}")
        return value

    def number(self, m: dict, key: str, where: str, minimum: float | None = None) -> float:
        return self.value(m.get(key, _MISSING), _join(where, key), minimum)

    def value(self, value, here: str, minimum: float | None = None) -> float:
        """A finite int or float (not a bool, not a string), as a float."""
        expected = "a number" if minimum is None else f"a number >= {minimum:g}"
        if isinstance(value, str):
            try:
                numeric = math.isfinite(float(value))
            except ValueError:
                numeric = False
            hint = " (text: YAML reads quoted or dot-less numbers as strings; write e.g. 1.0e-05)" \
                if numeric else ""
            self.fail(here, expected, _describe(value) + hint)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            self.fail(here, expected, _describe(value))
        try:
            x = float(value)
        except OverflowError:
            x = math.inf
        if not math.isfinite(x):
            self.fail(here, "a finite number", _describe(value))
        if minimum is not None and x < minimum:
            self.fail(here, expected, _describe(value))
        return x

    def string(self, m: dict, key: str, where: str, allowed: Sequence[str] | None = None,
               optional: bool = False) -> str | None:
        value = m.get(key, _MISSING)
        if value is _MISSING and optional:
            return None
        here = _join(where, key)
        if allowed is not None:
            if value not in allowed or not isinstance(value, str):
                choices = " or ".join(repr(a) for a in allowed)
                self.fail(here, choices, _describe(value))
        elif not isinstance(value, str) or not value:
            self.fail(here, "a non-empty string" + (" (quote it)" if isinstance(value, (int, float)) else ""),
                      _describe(value))
        return value

    def vector(self, m: dict, keys: Sequence[str], where: str, minimum: float | None = None) -> np.ndarray:
        return np.array([self.number(m, k, where, minimum) for k in keys])


def _read_triad(r: _Reader, name: str, raw, where: str) -> TriadParameters:
    t = r.mapping(raw, where, ("kind", "output_unit", "input_unit", "bias", "scale_factor",
                               "misalignment", "K", "residual_rms", "method"))
    kind = r.string(t, "kind", where, allowed=KINDS)
    output_unit = r.string(t, "output_unit", where)
    input_unit = r.string(t, "input_unit", where, allowed=(SI_UNIT[kind],))

    def block(key: str, names: Sequence[str], unit: str) -> tuple[np.ndarray, np.ndarray]:
        here = f"{where}.{key}"
        b = r.mapping(t.get(key, _MISSING), here, (*names, "unit", "sigma"))
        values = r.vector(b, names, here)
        r.string(b, "unit", here, allowed=(unit,))
        s = r.mapping(b.get("sigma", _MISSING), f"{here}.sigma", names)
        return values, r.vector(s, names, f"{here}.sigma", minimum=0.0)

    bias, bias_sigma = block("bias", _AXES, output_unit)
    scale, scale_sigma = block("scale_factor", _AXES, f"{output_unit} per {input_unit}")
    angles, angle_sigma = block("misalignment", _ANGLES, "rad")

    kw = f"{where}.K"
    rows = t.get("K", _MISSING)
    if not isinstance(rows, list) or len(rows) != 3:
        r.fail(kw, "a list of 3 rows of 3 numbers", _describe(rows))
    for i, row in enumerate(rows):
        if not isinstance(row, list) or len(row) != 3:
            r.fail(f"{kw}[{i}]", "a list of 3 numbers", _describe(row))
    K = np.array([[r.value(v, f"{kw}[{i}][{j}]") for j, v in enumerate(row)]
                  for i, row in enumerate(rows)])
    method = r.string(t, "method", where)
    if method in LOWER_TRIANGULAR_METHODS:
        for i, j in ((0, 1), (0, 2), (1, 2)):
            if K[i, j] != 0:
                r.fail(f"{kw}[{i}][{j}]", f"0.0 (the {method} method gives a lower-triangular K)",
                       _describe(rows[i][j]))
    for i in range(3):
        if K[i, i] == 0:
            r.fail(f"{kw}[{i}][{i}]", "a non-zero scale factor", _describe(rows[i][i]))
    cond = np.linalg.cond(K)
    if not cond < _MAX_CONDITION:
        r.fail(kw, "an invertible matrix",
               "a singular one" if not np.isfinite(cond) else f"one with condition number {cond:.3g}")

    for i, axis in enumerate(_AXES):
        if not _close(scale[i], K[i, i], 0.0):
            r.fail(f"{where}.scale_factor.{axis}", f"K[{i}][{i}] = {float(K[i, i])!r} (edited by hand?)",
                   repr(float(scale[i])))
    from_k = _misalignment_of(K)
    cells = ("K[1][0] / K[1][1]", "K[2][0] / K[2][2]", "K[2][1] / K[2][2]")
    for i, angle in enumerate(_ANGLES):
        if not _close(angles[i], from_k[i], _ANGLE_ATOL):
            r.fail(f"{where}.misalignment.{angle}",
                   f"{float(from_k[i])!r} from {'-' if i != 1 else ''}{cells[i]} (edited by hand?)",
                   repr(float(angles[i])))

    rw = f"{where}.residual_rms"
    res = r.mapping(t.get("residual_rms", _MISSING), rw, ("value", "unit"))
    rms = r.number(res, "value", rw, minimum=0.0)
    residual_unit = r.string(res, "unit", rw, allowed=tuple(dict.fromkeys((SI_UNIT[kind], output_unit))))
    try:
        return TriadParameters(name=name, kind=kind, output_unit=output_unit, bias=bias, K=K,
                               sigma=np.r_[bias_sigma, scale_sigma, angle_sigma], residual_rms=rms,
                               method=method, residual_unit=residual_unit)
    except ValueError as exc:  # should be unreachable: everything above is checked first
        r.fail(where, "a valid triad", str(exc).splitlines()[0])
        raise


def _close(a: float, b: float, atol: float) -> bool:
    return abs(a - b) <= CONSISTENCY_RTOL * max(abs(a), abs(b)) + atol


def from_document(doc, path: str = "<document>") -> ParameterFile:
    """Validate a parsed document (as ``yaml.safe_load`` gives it) into a ParameterFile."""
    r = _Reader(path)
    if doc is None:
        r.fail("", f"a {SCHEMA} parameter file (a YAML mapping)", "an empty file")
    if not isinstance(doc, dict):
        r.fail("", f"a {SCHEMA} parameter file (a YAML mapping)", _describe(doc))
    schema = doc.get("schema", _MISSING)
    if schema != SCHEMA:
        newer = isinstance(schema, str) and schema.startswith("fieldcal-parameters/")
        r.fail("schema", repr(SCHEMA) + (f" (fieldcal {__version__} reads version 1 only)" if newer else ""),
               _describe(schema))
    r.mapping(doc, "", ("schema", "provenance", "triads"))

    pw = "provenance"
    p = r.mapping(doc.get(pw, _MISSING), pw,
                  ("software", "software_version", "procedure", "method", "input_sha256", "station"),
                  ("simulation", "device"))
    r.string(p, "software", pw, allowed=(SOFTWARE,))
    version = r.string(p, "software_version", pw)
    procedure = r.string(p, "procedure", pw)
    method = r.string(p, "method", pw)
    sha = p.get("input_sha256", _MISSING)
    if not isinstance(sha, str) or not _SHA256.fullmatch(sha):
        r.fail(f"{pw}.input_sha256", "64 lowercase hex digits (SHA-256)", _describe(sha))
    simulation = p.get("simulation")
    if simulation is not None and not isinstance(simulation, bool):
        r.fail(f"{pw}.simulation", "true or false", _describe(simulation))
    sw = f"{pw}.station"
    s = r.mapping(p.get("station", _MISSING), sw,
                  ("latitude_deg", "height_m", "gravity_m_s2", "gravity_source"))
    latitude = r.number(s, "latitude_deg", sw)
    if not -90.0 <= latitude <= 90.0:
        r.fail(f"{sw}.latitude_deg", "a latitude in -90..90 degrees", _describe(s["latitude_deg"]))
    height = r.number(s, "height_m", sw)
    gravity = r.number(s, "gravity_m_s2", sw)
    if not gravity > 0:
        r.fail(f"{sw}.gravity_m_s2", "a number > 0", _describe(s["gravity_m_s2"]))
    gravity_source = r.string(s, "gravity_source", sw)
    device_name = device_serial = None
    if p.get("device") is not None:
        dw = f"{pw}.device"
        d = r.mapping(p["device"], dw, (), ("name", "serial"))
        device_name = r.string(d, "name", dw, optional=True)
        device_serial = r.string(d, "serial", dw, optional=True)
    provenance = Provenance(procedure=procedure, method=method, input_sha256=sha,
                            latitude_deg=latitude, height_m=height, gravity_m_s2=gravity,
                            gravity_source=gravity_source, device_name=device_name,
                            device_serial=device_serial, simulation=simulation,
                            software_version=version)

    raw_triads = doc.get("triads", _MISSING)
    if not isinstance(raw_triads, dict) or not raw_triads:
        r.fail("triads", "a mapping of triad name to parameters", _describe(raw_triads))
    triads = []
    for name, raw in raw_triads.items():
        if not isinstance(name, str) or not name or not name.isprintable():
            r.fail("triads", "triad names that are non-empty strings", _describe(name))
        triads.append(_read_triad(r, name, raw, f"triads.{name}"))
    return ParameterFile(triads=tuple(triads), provenance=provenance)


def loads(text: str, path: str = "<string>") -> ParameterFile:
    """Parse and validate the text of a parameter file; ``path`` is used in messages."""
    try:
        doc = yaml.load(text, Loader=_UniqueKeyLoader)  # noqa: S506 -- a SafeLoader subclass
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        where = f"line {mark.line + 1}: " if mark is not None else ""
        what = (exc.problem or exc.context or "malformed").splitlines()[0]
        raise ParameterFileError(f"{path}: not valid YAML ({where}{what})", path) from None
    except Exception as exc:  # noqa: BLE001 -- e.g. a date like 2024-02-30 raises ValueError
        detail = (str(exc).splitlines() or [type(exc).__name__])[0]
        raise ParameterFileError(f"{path}: not valid YAML ({detail})", path) from None
    return from_document(doc, path)


def load(path: str | os.PathLike) -> ParameterFile:
    """Read and validate a parameter file; any problem is a one-line ParameterFileError."""
    name = os.fspath(path)
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise ParameterFileError(f"{name}: cannot read parameter file ({exc.strerror or exc})", name) from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ParameterFileError(f"{name}: not valid YAML (not UTF-8 text at byte {exc.start})", name) from None
    return loads(text, name)


__all__ = ["SCHEMA", "ParameterFile", "ParameterFileError", "Provenance", "TriadParameters",
           "dump", "from_document", "hash_inputs", "load", "loads", "save", "to_document"]
