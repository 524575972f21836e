"""Loading a parameter file: safe YAML, every field validated, one-line errors naming the field."""
from __future__ import annotations

import os
from typing import Sequence

import numpy as np

from fieldcal import __version__
from fieldcal.earth import GRAVITY_RANGE_M_S2, GRAVITY_SOURCES, HEIGHT_RANGE_M
from fieldcal.model import KINDS, PARAM_NAMES, SI_UNIT, params_from_k
from fieldcal.calibration import (
    _MAX_CONDITION,
    BiasAtEnd,
    LOWER_TRIANGULAR_METHODS,
    TRIAD_METHODS,
    nearest,
    nominal_value,
    residual_units,
)
from fieldcal.paramfile.document import (
    _ANGLE_ATOL,
    _ANGLES,
    _AXES,
    _SHA256,
    CONSISTENCY_RTOL,
    MARKS_VERSION,
    OPERATOR_MAX,
    SCHEMA,
    SOFTWARE,
    THERMAL_VERSION,
    ParameterFile,
    ParameterFileError,
    Provenance,
    TriadParameters,
    dump,
    hash_inputs,
    save,
    to_document,
    unknown_methods,
    valid_operator,
)
from fieldcal.thermal import MAX_ORDER, TEMPERATURE_LIMITS_C, ThermalModel
from fieldcal.validation import MISSING, FieldReader, describe, line_of, parse_yaml, read_yaml_file


def _read_triad(r: FieldReader, name: str, raw, where: str) -> TriadParameters:
    t = r.mapping(raw, where, ("kind", "output_unit", "input_unit", "bias", "scale_factor",
                               "misalignment", "K", "residual_rms", "method"), ("not_calibrated", "thermal", "bias_at_end"))
    kind = r.string(t, "kind", where, allowed=KINDS)
    output_unit = r.string(t, "output_unit", where)
    input_unit = r.string(t, "input_unit", where, allowed=(SI_UNIT[kind],))
    marked, why = _read_marks(r, t["not_calibrated"], f"{where}.not_calibrated") \
        if "not_calibrated" in t else ((), "")

    def block(key: str, names: Sequence[str], unit: str, parameters: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
        here = f"{where}.{key}"
        b = r.mapping(t.get(key, MISSING), here, (*names, "unit", "sigma"))
        values = r.vector(b, names, here)
        r.string(b, "unit", here, allowed=(unit,))
        s = r.mapping(b.get("sigma", MISSING), f"{here}.sigma", names)
        sigma = []
        for n, p, v in zip(names, parameters, values):
            if p not in marked:
                sigma.append(r.number(s, n, f"{here}.sigma", 0.0))
                continue
            if s.get(n) is not None:  # a not-calibrated parameter has no σ to give
                r.fail(f"{here}.sigma.{n}", f"null ({p} is not calibrated)", describe(s.get(n)), line_of(s, n))
            nominal = nominal_value(kind, output_unit, p)
            if nominal is None or not _close(v, nominal, _ANGLE_ATOL):
                r.fail(f"{here}.{n}", f"{nominal!r}, the nominal value ({p} is not calibrated)"
                       if nominal is not None else f"a calibrated scale ({output_unit!r} has no nominal one)",
                       repr(float(v)), line_of(b, n))
            sigma.append(0.0)
        return values, np.array(sigma)

    bias, bias_sigma = block("bias", _AXES, output_unit, PARAM_NAMES[0:3])
    scale, scale_sigma = block("scale_factor", _AXES, f"{output_unit} per {input_unit}", PARAM_NAMES[3:6])
    angles, angle_sigma = block("misalignment", _ANGLES, "rad", PARAM_NAMES[6:9])

    kw = f"{where}.K"
    rows = t.get("K", MISSING)
    if not isinstance(rows, list) or len(rows) != 3:
        r.fail(kw, "a list of 3 rows of 3 numbers", describe(rows))
    for i, row in enumerate(rows):
        if not isinstance(row, list) or len(row) != 3:
            r.fail(f"{kw}[{i}]", "a list of 3 numbers", describe(row))
    K = np.array([[r.value(v, f"{kw}[{i}][{j}]") for j, v in enumerate(row)]
                  for i, row in enumerate(rows)])
    method = _enum(r, t, "method", where, TRIAD_METHODS)
    if method in LOWER_TRIANGULAR_METHODS:
        for i, j in ((0, 1), (0, 2), (1, 2)):
            if K[i, j] != 0:
                r.fail(f"{kw}[{i}][{j}]", f"0.0 (the {method} method gives a lower-triangular K)",
                       describe(rows[i][j]))
    for i in range(3):
        if K[i, i] == 0:
            r.fail(f"{kw}[{i}][{i}]", "a non-zero scale factor", describe(rows[i][i]))
    cond = np.linalg.cond(K)
    if not cond < _MAX_CONDITION:
        r.fail(kw, "an invertible matrix",
               "a singular one" if not np.isfinite(cond) else f"one with condition number {cond:.3g}")

    for i, axis in enumerate(_AXES):
        if not _close(scale[i], K[i, i], 0.0):
            r.fail(f"{where}.scale_factor.{axis}", f"K[{i}][{i}] = {float(K[i, i])!r} (edited by hand?)",
                   repr(float(scale[i])))
    from_k = params_from_k(K, np.zeros(3), full=True)[6:]
    cells = ("K[1][0] / K[1][1]", "K[2][0] / K[2][2]", "K[2][1] / K[2][2]")
    for i, angle in enumerate(_ANGLES):
        if not _close(angles[i], from_k[i], _ANGLE_ATOL):
            r.fail(f"{where}.misalignment.{angle}",
                   f"{float(from_k[i])!r} from {'-' if i != 1 else ''}{cells[i]} (edited by hand?)",
                   repr(float(angles[i])))

    rw = f"{where}.residual_rms"
    res = r.mapping(t.get("residual_rms", MISSING), rw, ("value", "unit"))
    rms = r.number(res, "value", rw, minimum=0.0)
    residual_unit = r.string(res, "unit", rw, allowed=residual_units(kind, output_unit, method))
    thermal = _read_thermal(r, t["thermal"], f"{where}.thermal", output_unit) if "thermal" in t else None
    end = None
    if "bias_at_end" in t:
        ew = f"{where}.bias_at_end"
        e = r.mapping(t["bias_at_end"], ew, (*_AXES, "unit", "sigma", "time_s"))
        r.string(e, "unit", ew, allowed=(output_unit,))
        end = BiasAtEnd(value=r.vector(e, _AXES, ew),
                        sigma=r.vector(r.mapping(e.get("sigma", MISSING), f"{ew}.sigma", _AXES), _AXES,
                                       f"{ew}.sigma", minimum=0.0),
                        time_s=r.number(e, "time_s", ew, minimum=0.0))
    try:
        return TriadParameters(name=name, kind=kind, output_unit=output_unit, bias=bias, K=K,
                               sigma=np.r_[bias_sigma, scale_sigma, angle_sigma], residual_rms=rms,
                               method=method, residual_unit=residual_unit, thermal=thermal,
                               not_calibrated=marked, not_calibrated_why=why, bias_at_end=end)
    except ValueError as exc:  # should be unreachable: everything above is checked first
        r.fail(where, "a valid triad", str(exc).splitlines()[0])
        raise


def _read_marks(r: FieldReader, raw, where: str) -> tuple[tuple[str, ...], str]:
    """A triad's ``not_calibrated`` section (version MARKS_VERSION): the parameters the data did
    not determine, and why."""
    m = r.mapping(raw, where, ("version", "parameters"), ("why",))
    version = m.get("version")
    if version != MARKS_VERSION or isinstance(version, bool):
        r.fail(f"{where}.version", f"{MARKS_VERSION} (fieldcal {__version__} reads not_calibrated version "
               f"{MARKS_VERSION} only)", describe(version), line_of(m, "version"))
    names = m.get("parameters", MISSING)
    if not isinstance(names, list) or not names or any(n not in PARAM_NAMES for n in names) \
            or len(set(names)) != len(names):
        r.fail(f"{where}.parameters", f"a list of distinct names of {', '.join(PARAM_NAMES)}", describe(names),
               line_of(m, "parameters"))
    why = r.string(m, "why", where, optional=True) or ""
    return tuple(names), why


def _read_thermal(r: FieldReader, raw, where: str, output_unit: str) -> ThermalModel:
    """A triad's ``thermal`` section (version THERMAL_VERSION), every field checked."""
    m = r.mapping(raw, where, ("version", "reference_temperature_c", "range_c", "bias"), ("scale_factor",))
    version = m.get("version")
    if version != THERMAL_VERSION or isinstance(version, bool):
        r.fail(f"{where}.version", f"{THERMAL_VERSION} (fieldcal {__version__} reads thermal version "
               f"{THERMAL_VERSION} only)", describe(version), line_of(m, "version"))
    low_limit, high_limit = TEMPERATURE_LIMITS_C
    reference = r.bounded(m, "reference_temperature_c", where, low_limit, high_limit, "°C")
    rw = f"{where}.range_c"
    span = r.mapping(m.get("range_c", MISSING), rw, ("low", "high"))
    low = r.bounded(span, "low", rw, low_limit, high_limit, "°C")
    high = r.bounded(span, "high", rw, low, high_limit, "°C (not below low)")

    bw = f"{where}.bias"
    b = r.mapping(m.get("bias", MISSING), bw, ("order", "unit", *_AXES, "sigma"))
    order = r.whole(b, "order", bw, 0, MAX_ORDER)
    r.string(b, "unit", bw, allowed=(f"{output_unit} per K^k",))

    def terms(block: dict, here: str, minimum: float | None) -> np.ndarray:
        columns = []
        for axis in _AXES:
            values = block.get(axis, MISSING)
            if not isinstance(values, list) or len(values) != order:
                r.fail(f"{here}.{axis}", f"a list of {order} numbers (b1..b{order}; order is {order})",
                       describe(values), line_of(block, axis))
            columns.append([r.value(v, f"{here}.{axis}[{k}]", minimum, line_of(block, axis))
                            for k, v in enumerate(values)])
        return np.array(columns, dtype=float).reshape(3, order).T

    bias_terms = terms(b, bw, None)
    bias_sigma = terms(r.mapping(b.get("sigma", MISSING), f"{bw}.sigma", _AXES), f"{bw}.sigma", 0.0)
    drift = drift_sigma = None
    if "scale_factor" in m:
        sw = f"{where}.scale_factor"
        sf = r.mapping(m["scale_factor"], sw, (*_AXES, "unit", "sigma"))
        r.string(sf, "unit", sw, allowed=("1/K",))
        drift = r.vector(sf, _AXES, sw)
        drift_sigma = r.vector(r.mapping(sf.get("sigma", MISSING), f"{sw}.sigma", _AXES), _AXES,
                               f"{sw}.sigma", minimum=0.0)
    return ThermalModel(reference_c=reference, range_c=(low, high), bias_terms=bias_terms,
                        bias_terms_sigma=bias_sigma, scale_drift=drift, scale_drift_sigma=drift_sigma)


def _enum(r: FieldReader, m: dict, key: str, where: str, allowed: Sequence[str]) -> str:
    """A string that must be one of ``allowed``; the error names the nearest one."""
    value = r.string(m, key, where)
    if value not in allowed:
        r.fail(f"{where}.{key}", f"one of {', '.join(allowed)}",
               f"{describe(value)} (nearest: {nearest(value, allowed)!r})")
    return value


def _bounded(r: FieldReader, m: dict, key: str, where: str, bounds: tuple[float, float], unit: str,
             open_interval: bool = False) -> float:
    """A number within ``bounds`` (closed, or open at both ends)."""
    x = r.number(m, key, where)
    lo, hi = bounds
    if not (lo < x < hi if open_interval else lo <= x <= hi):
        r.fail(f"{where}.{key}", f"a number from {lo:g} to {hi:g} {unit}", describe(m[key]))
    return x


def _close(a: float, b: float, atol: float) -> bool:
    return abs(a - b) <= CONSISTENCY_RTOL * max(abs(a), abs(b)) + atol


def from_document(doc, path: str = "<document>") -> ParameterFile:
    """Validate a parsed document (as ``yaml.safe_load`` gives it) into a ParameterFile."""
    r = FieldReader(path, ParameterFileError)
    if doc is None:
        r.fail("", f"a {SCHEMA} parameter file (a YAML mapping)", "an empty file")
    if not isinstance(doc, dict):
        r.fail("", f"a {SCHEMA} parameter file (a YAML mapping)", describe(doc))
    schema = doc.get("schema", MISSING)
    if schema != SCHEMA:
        newer = isinstance(schema, str) and schema.startswith("fieldcal-parameters/")
        r.fail("schema", repr(SCHEMA) + (f" (fieldcal {__version__} reads version 1 only)" if newer else ""),
               describe(schema))
    r.mapping(doc, "", ("schema", "provenance", "triads"))

    pw = "provenance"
    p = r.mapping(doc.get(pw, MISSING), pw,
                  ("software", "software_version", "procedure", "method", "input_sha256", "station"),
                  ("simulation", "device", "operator"))
    r.string(p, "software", pw, allowed=(SOFTWARE,))
    version = r.string(p, "software_version", pw)
    procedure = r.string(p, "procedure", pw)
    method = r.string(p, "method", pw)
    bad = unknown_methods(method)
    if bad:
        r.fail(f"{pw}.method", f"{' or '.join(TRIAD_METHODS)} (joined by +)",
               f"{describe(method)} (nearest to {bad[0]!r}: {nearest(bad[0], TRIAD_METHODS)!r})")
    sha = p.get("input_sha256", MISSING)
    if not isinstance(sha, str) or not _SHA256.fullmatch(sha):
        r.fail(f"{pw}.input_sha256", "64 lowercase hex digits (SHA-256)", describe(sha))
    simulation = p.get("simulation")
    if simulation is not None and not isinstance(simulation, bool):
        r.fail(f"{pw}.simulation", "true or false", describe(simulation))
    sw = f"{pw}.station"
    s = r.mapping(p.get("station", MISSING), sw,
                  ("latitude_deg", "height_m", "gravity_m_s2", "gravity_source"))
    latitude = r.number(s, "latitude_deg", sw)
    if not -90.0 <= latitude <= 90.0:
        r.fail(f"{sw}.latitude_deg", "a latitude in -90..90 degrees", describe(s["latitude_deg"]))
    height = _bounded(r, s, "height_m", sw, HEIGHT_RANGE_M, "m (a station on land)")
    gravity = _bounded(r, s, "gravity_m_s2", sw, GRAVITY_RANGE_M_S2, "m/s^2 (Earth's surface)",
                       open_interval=True)
    gravity_source = _enum(r, s, "gravity_source", sw, GRAVITY_SOURCES)
    device_name = device_serial = None
    if p.get("device") is not None:
        dw = f"{pw}.device"
        d = r.mapping(p["device"], dw, (), ("name", "serial"))
        device_name = r.string(d, "name", dw, optional=True)
        device_serial = r.string(d, "serial", dw, optional=True)
    operator = r.string(p, "operator", pw, optional=True)
    if operator is not None and not valid_operator(operator):
        r.fail(f"{pw}.operator", f"a name of 1 to {OPERATOR_MAX} printable characters, no blanks around it",
               describe(operator))
    provenance = Provenance(procedure=procedure, method=method, input_sha256=sha,
                            latitude_deg=latitude, height_m=height, gravity_m_s2=gravity,
                            gravity_source=gravity_source, device_name=device_name,
                            device_serial=device_serial, simulation=simulation,
                            software_version=version, operator=operator)

    raw_triads = doc.get("triads", MISSING)
    if not isinstance(raw_triads, dict) or not raw_triads:
        r.fail("triads", "a mapping of triad name to parameters", describe(raw_triads))
    triads = []
    for name, raw in raw_triads.items():
        if not isinstance(name, str) or not name or not name.isprintable():
            r.fail("triads", "triad names that are non-empty strings", describe(name))
        triads.append(_read_triad(r, name, raw, f"triads.{name}"))
    return ParameterFile(triads=tuple(triads), provenance=provenance)


def loads(text: str, path: str = "<string>") -> ParameterFile:
    """Parse and validate the text of a parameter file; ``path`` is used in messages."""
    return from_document(parse_yaml(text, path, ParameterFileError), path)


def load(path: str | os.PathLike) -> ParameterFile:
    """Read and validate a parameter file; any problem is a one-line ParameterFileError."""
    return from_document(read_yaml_file(path, ParameterFileError, "parameter file"), os.fspath(path))


__all__ = ["SCHEMA", "ParameterFile", "ParameterFileError", "Provenance", "TriadParameters",
           "dump", "from_document", "hash_inputs", "load", "loads", "save", "to_document"]
