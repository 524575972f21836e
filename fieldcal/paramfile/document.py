"""The versioned parameter file a calibration produces (schema ``fieldcal-parameters/1``).

One YAML file per calibration: for each triad the model raw = K·true + b of ``fieldcal.model``
(bias, scale factors, non-orthogonality angles with their 1σ, and K itself; optionally a
``thermal`` section, versioned on its own, holding ``fieldcal.thermal``'s model; and a
``not_calibrated`` section, versioned on its own, naming the parameters the data did not determine,
written at their nominal values with a null σ), plus provenance:
software version, procedure, solver method, a hash of the averages that went in, the station's
gravity, and optionally the device and whether it was simulated.

Design points:

* No wall-clock time anywhere: a replayed session gives the same file byte for byte.
* Floats are written with ``repr`` (PyYAML's float representer), so ``load(save(pf)) == pf``
  with every float bit-identical.
* K is the authority; the named scale factors and angles are written next to it for people and
  checked against it on load (a mismatch means a hand edit: rejected, naming the field).
* ``load`` never shows a traceback for bad content: every problem is one line,
  ``<file>: <dotted.field.path>: expected <what>, got <what> (line N)`` (or ``missing``, or
  ``unknown key 'x'; did you mean 'y'?``).
"""
from __future__ import annotations

import hashlib
import math
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Sequence

import numpy as np
import yaml

from fieldcal import __version__
from fieldcal.earth import GRAVITY_RANGE_M_S2, GRAVITY_SOURCES, HEIGHT_RANGE_M
from fieldcal.calibration import TRIAD_METHODS, Calibration, nearest
from fieldcal.model import PARAM_NAMES

SCHEMA = "fieldcal-parameters/1"
SOFTWARE = "fieldcal"
# Named values must agree with K to this relative tolerance (they are written from K exactly).
CONSISTENCY_RTOL = 1e-9
_ANGLE_ATOL = 1e-15  # rad: lets 0.0 and a denormal-sized angle from K agree

_AXES = ("x", "y", "z")
_ANGLES = ("delta_yz", "delta_zy", "delta_zx")
_SHA256 = re.compile(r"[0-9a-f]{64}")
_HEADER = ("# fieldcal calibration parameters. Per triad: raw = K * true + bias,\n"
           "# calibrated = inverse(K) * (raw - bias). Sigmas are 1-sigma. Do not edit by hand:\n"
           "# the named values are checked against K when the file is loaded.\n")


def unknown_methods(method: str) -> list[str]:
    """The parts of a provenance method ("powell+rotation") that name no known method."""
    return [m for m in method.split("+") if m not in TRIAD_METHODS]


class ParameterFileError(ValueError):
    """A parameter file that cannot be used; the message is one line naming the file and field."""

    def __init__(self, message: str, path: str = "", field: str = "") -> None:
        super().__init__(message)
        self.path = path
        self.field = field


# --------------------------------------------------------------------------------------------
# In-memory model


# A triad's parameters are a Calibration (fieldcal.calibration); the name is the file's.
TriadParameters = Calibration


OPERATOR_MAX = 100


def valid_operator(name) -> bool:
    """A name or initials as typed: printable, no line breaks, not blank, not too long."""
    return isinstance(name, str) and 0 < len(name) <= OPERATOR_MAX and name.strip() == name \
        and name.isprintable()


@dataclass(frozen=True)
class Provenance:
    """Where a parameter file came from. No timestamps: replay must reproduce the file exactly."""

    procedure: str
    method: str
    input_sha256: str
    latitude_deg: float
    height_m: float
    gravity_m_s2: float
    gravity_source: str
    device_name: str | None = None
    device_serial: str | None = None
    simulation: bool | None = None
    software_version: str = __version__
    operator: str | None = None  # who calibrated (the station's --operator); None: not said

    def __post_init__(self) -> None:
        for attr in ("procedure", "method", "gravity_source", "software_version"):
            value = getattr(self, attr)
            if not isinstance(value, str) or not value:
                raise ValueError(f"provenance.{attr}: expected a non-empty string, got {value!r}")
        if not isinstance(self.input_sha256, str) or not _SHA256.fullmatch(self.input_sha256):
            raise ValueError(f"provenance.input_sha256: expected 64 lowercase hex digits, "
                             f"got {self.input_sha256!r}")
        for attr in ("device_name", "device_serial"):
            value = getattr(self, attr)
            if value is not None and not isinstance(value, str):
                raise ValueError(f"provenance.{attr}: expected a string or None, got {value!r}")
        if self.operator is not None and not valid_operator(self.operator):
            raise ValueError(f"provenance.operator: expected a name of 1 to {OPERATOR_MAX} printable "
                             f"characters, got {self.operator!r}"[:200])
        if self.simulation is not None and not isinstance(self.simulation, bool):
            raise ValueError(f"provenance.simulation: expected true, false or None, got {self.simulation!r}")
        for attr in ("latitude_deg", "height_m", "gravity_m_s2"):
            value = getattr(self, attr)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)) \
                    or not math.isfinite(value):
                raise ValueError(f"provenance.{attr}: expected a finite number, got {value!r}")
            object.__setattr__(self, attr, float(value))
        if not -90.0 <= self.latitude_deg <= 90.0:
            raise ValueError(f"provenance.latitude_deg: expected -90..90, got {self.latitude_deg!r}")
        if not HEIGHT_RANGE_M[0] <= self.height_m <= HEIGHT_RANGE_M[1]:
            raise ValueError(f"provenance.height_m: expected {HEIGHT_RANGE_M[0]:g}..{HEIGHT_RANGE_M[1]:g} m, "
                             f"got {self.height_m!r}")
        if not GRAVITY_RANGE_M_S2[0] < self.gravity_m_s2 < GRAVITY_RANGE_M_S2[1]:
            raise ValueError(f"provenance.gravity_m_s2: expected {GRAVITY_RANGE_M_S2[0]:g}..."
                             f"{GRAVITY_RANGE_M_S2[1]:g} m/s^2, got {self.gravity_m_s2!r}")
        if self.gravity_source not in GRAVITY_SOURCES:
            raise ValueError(f"provenance.gravity_source: expected one of {', '.join(GRAVITY_SOURCES)}, "
                             f"got {self.gravity_source!r}")
        bad = unknown_methods(self.method)
        if bad:
            raise ValueError(f"provenance.method: expected {' or '.join(TRIAD_METHODS)} (joined by +), "
                             f"got {self.method!r} (nearest to {bad[0]!r}: {nearest(bad[0], TRIAD_METHODS)!r})")

    @classmethod
    def for_station(cls, station, *, procedure: str, method: str, input_sha256: str,
                    device_name: str | None = None, device_serial: str | None = None,
                    simulation: bool | None = None, operator: str | None = None) -> Provenance:
        """From a ``fieldcal.earth.Station`` (its gravity and where that came from)."""
        return cls(procedure=procedure, method=method, input_sha256=input_sha256,
                   latitude_deg=station.latitude_deg, height_m=station.height_m,
                   gravity_m_s2=station.gravity, gravity_source=station.gravity_source,
                   device_name=device_name, device_serial=device_serial, simulation=simulation,
                   operator=operator)


@dataclass(frozen=True)
class ParameterFile:
    """A parameter file: the calibrated triads and where they came from (validated on creation)."""
    triads: tuple[TriadParameters, ...]
    provenance: Provenance

    def __post_init__(self) -> None:
        triads = tuple(self.triads)
        if not triads or not all(isinstance(t, Calibration) for t in triads):
            raise ValueError("triads: expected one or more Calibrations")
        names = [t.name for t in triads]
        dupes = sorted({n for n in names if names.count(n) > 1})
        if dupes:
            raise ValueError(f"triads: expected unique names, got {', '.join(map(repr, dupes))} twice")
        if not isinstance(self.provenance, Provenance):
            raise ValueError(f"provenance: expected a Provenance, got {type(self.provenance).__name__}")
        object.__setattr__(self, "triads", triads)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(t.name for t in self.triads)

    def triad(self, name: str) -> TriadParameters:
        for t in self.triads:
            if t.name == name:
                return t
        raise KeyError(f"no triad named {name!r} (have {', '.join(self.names)})")

    def __getitem__(self, name: str) -> TriadParameters:
        return self.triad(name)

    @classmethod
    def build(cls, triads: Iterable[TriadParameters], *, station, procedure: str, method: str,
              input_sha256: str, device_name: str | None = None, device_serial: str | None = None,
              simulation: bool | None = None, operator: str | None = None) -> ParameterFile:
        """Triads plus provenance from a ``fieldcal.earth.Station`` and the hash of the averages."""
        return cls(triads=tuple(triads), provenance=Provenance.for_station(
            station, procedure=procedure, method=method, input_sha256=input_sha256,
            device_name=device_name, device_serial=device_serial, simulation=simulation,
            operator=operator))

    @classmethod
    def from_solutions(cls, solutions: Iterable, *, station, procedure: str,
                       inputs: Sequence[np.ndarray] | None = None, input_sha256: str | None = None,
                       method: str | None = None, device_name: str | None = None,
                       device_serial: str | None = None,
                       simulation: bool | None = None, operator: str | None = None) -> ParameterFile:
        """Parameters of solver solutions, with provenance from ``station`` and the averages.

        Give the averages that went in as ``inputs`` (hashed with ``hash_inputs``) or their hash
        as ``input_sha256``. ``method`` defaults to the solutions' method ("a+b" when they differ).
        """
        triads = tuple(solutions)
        if (inputs is None) == (input_sha256 is None):
            raise ValueError("give exactly one of inputs (the averages) or input_sha256")
        if input_sha256 is None:
            input_sha256 = hash_inputs(*inputs)
        if method is None:
            method = "+".join(sorted({t.method for t in triads}))
        return cls.build(triads, station=station, procedure=procedure, method=method,
                         input_sha256=input_sha256, device_name=device_name,
                         device_serial=device_serial, simulation=simulation, operator=operator)


def hash_inputs(*arrays) -> str:
    """SHA-256 (hex) of arrays' dtype, shape and C-order bytes, in order: deterministic."""
    h = hashlib.sha256(b"fieldcal-inputs/1\0")
    for a in arrays:
        arr = np.ascontiguousarray(a)
        if arr.dtype.hasobject:
            raise TypeError("hash_inputs: object arrays have no stable bytes; pass numeric arrays")
        header = f"{arr.dtype.str}|{','.join(map(str, arr.shape))}|{arr.nbytes}\0"
        h.update(header.encode("ascii"))
        # The same bytes as arr.tobytes(), read in place: no copy of a whole recording (46 MB of
        # samples at imu_tk's recording joined 16×, a tenth of the hashing's CPU in page faults).
        h.update(arr.reshape(-1).view(np.uint8))
    return h.hexdigest()


# --------------------------------------------------------------------------------------------
# Writing


class _FlowRow(list):
    """A list written on one line ([a, b, c]): the rows of K."""


class _Dumper(yaml.SafeDumper):
    def ignore_aliases(self, data: Any) -> bool:
        return True


_Dumper.add_representer(
    _FlowRow, lambda d, data: d.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=True))


def _f(x) -> float:
    return float(x)  # numpy scalars -> Python floats, whose repr round-trips exactly


def _xyz(values) -> dict:
    return {k: _f(v) for k, v in zip(_AXES, values)}


def _sigmas(t: Calibration, keys: Sequence[str], values, parameters: Sequence[str]) -> dict:
    """σ by key; null for a parameter not calibrated (it has none)."""
    return {k: None if p in t.not_calibrated else _f(v) for k, v, p in zip(keys, values, parameters)}


def _triad_document(t: Calibration) -> dict:
    named, sigma = t.file_theta, t.file_sigma
    return {
        "kind": t.kind,
        "output_unit": t.output_unit,
        "input_unit": t.input_unit,
        "bias": {**_xyz(t.bias), "unit": t.output_unit, "sigma": _sigmas(t, _AXES, sigma[0:3], PARAM_NAMES[0:3])},
        "scale_factor": {**_xyz(t.scale_factor), "unit": f"{t.output_unit} per {t.input_unit}",
                         "sigma": _sigmas(t, _AXES, sigma[3:6], PARAM_NAMES[3:6])},
        "misalignment": {**{k: _f(v) for k, v in zip(_ANGLES, named[6:9])}, "unit": "rad",
                         "sigma": _sigmas(t, _ANGLES, sigma[6:9], PARAM_NAMES[6:9])},
        "K": [_FlowRow(_f(v) for v in row) for row in t.K],
        "residual_rms": {"value": _f(t.residual_rms), "unit": t.residual_unit},
        "method": t.method,
        **({"not_calibrated": _marks_document(t)} if t.not_calibrated else {}),
        **({"thermal": _thermal_document(t)} if t.thermal is not None else {}),
        **({"bias_at_end": _bias_at_end_document(t)} if t.bias_at_end is not None else {}),
    }


# The not_calibrated section's own version (issue 27): a file without it is read as before it
# existed, every parameter calibrated; a fieldcal from before it refuses a file that has it (an
# unknown key), so no reader takes a nominal value for a calibrated one.
MARKS_VERSION = 1


def _marks_document(t: Calibration) -> dict:
    """The parameters the data did not determine: at their nominal values, σ null, and why."""
    return {"version": MARKS_VERSION, "parameters": list(t.not_calibrated),
            **({"why": t.not_calibrated_why} if t.not_calibrated_why else {})}


def _bias_at_end_document(t: Calibration) -> dict:
    """The bias at the run's last sample (sample time ``time_s``): the value the unit is used with
    right after calibration, beside the turn-on constant ``bias`` (a file without the section
    is read as before it existed)."""
    end = t.bias_at_end
    assert end is not None  # (written only when there is one)
    return {**_xyz(end.value), "unit": t.output_unit, "sigma": _xyz(end.sigma), "time_s": _f(end.time_s)}


# The thermal section's own version: a file without the section is read as before it existed.
THERMAL_VERSION = 1


def _thermal_document(t: Calibration) -> dict:
    m = t.thermal
    bias = {"order": m.order, "unit": f"{t.output_unit} per K^k",
            **{a: _FlowRow(_f(v) for v in m.bias_terms[:, i]) for i, a in enumerate(_AXES)},
            "sigma": {a: _FlowRow(_f(v) for v in m.bias_terms_sigma[:, i]) for i, a in enumerate(_AXES)}}
    doc = {"version": THERMAL_VERSION, "reference_temperature_c": _f(m.reference_c),
           "range_c": {"low": _f(m.range_c[0]), "high": _f(m.range_c[1])}, "bias": bias}
    if m.scale_drift is not None:
        doc["scale_factor"] = {**_xyz(m.scale_drift), "unit": "1/K", "sigma": _xyz(m.scale_drift_sigma)}
    return doc


def to_document(pf: ParameterFile) -> dict:
    """The plain mapping that ``dump`` writes."""
    p = pf.provenance
    prov: dict[str, Any] = {"software": SOFTWARE, "software_version": p.software_version,
                            "procedure": p.procedure, "method": p.method,
                            "input_sha256": p.input_sha256}
    if p.simulation is not None:
        prov["simulation"] = p.simulation
    prov["station"] = {"latitude_deg": p.latitude_deg, "height_m": p.height_m,
                       "gravity_m_s2": p.gravity_m_s2, "gravity_source": p.gravity_source}
    device = {k: v for k, v in (("name", p.device_name), ("serial", p.device_serial)) if v is not None}
    if device:
        prov["device"] = device
    if p.operator is not None:
        prov["operator"] = p.operator
    return {"schema": SCHEMA, "provenance": prov,
            "triads": {t.name: _triad_document(t) for t in pf.triads}}


def dump(pf: ParameterFile) -> str:
    """The file's text: deterministic (fixed key order, repr floats, no timestamps)."""
    body = yaml.dump(to_document(pf), Dumper=_Dumper, sort_keys=False, default_flow_style=False,
                     allow_unicode=True, width=200)
    return _HEADER + body


def save(pf: ParameterFile, path: str | os.PathLike) -> Path:
    """Write ``dump(pf)`` atomically: a temp file in the same directory, fsync, os.replace."""
    from fieldcal.atomic import write_atomically

    return write_atomically(path, dump(pf).encode("utf-8"))
