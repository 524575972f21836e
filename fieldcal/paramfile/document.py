"""The versioned parameter file a calibration produces (schema ``fieldcal-parameters/1``).

One YAML file per calibration: for each triad the model raw = K·true + b of ``fieldcal.model``
(bias, scale factors, non-orthogonality angles with their 1σ, and K itself), plus provenance:
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
from fieldcal.model import KINDS, PARAM_NAMES, SI_UNIT

SCHEMA = "fieldcal-parameters/1"
SOFTWARE = "fieldcal"
# Norm-method solvers (fieldcal.solvers.norm.METHODS) give a lower-triangular K; a file claiming
# one of these methods with a non-zero upper triangle has been edited by hand.
LOWER_TRIANGULAR_METHODS = ("powell", "lsq")
# The gyro calibrated from the rotations between a recording's poses: full K (the gyro-to-
# accelerometer misalignment included), residuals in rad (direction misfits).
ROTATION_METHOD = "rotation"
# Named values must agree with K to this relative tolerance (they are written from K exactly).
CONSISTENCY_RTOL = 1e-9
_ANGLE_ATOL = 1e-15  # rad: lets 0.0 and a denormal-sized angle from K agree
_MAX_CONDITION = 1e12  # K with a larger condition number is treated as singular

_AXES = ("x", "y", "z")
_ANGLES = ("delta_yz", "delta_zy", "delta_zx")
_SHA256 = re.compile(r"[0-9a-f]{64}")
_HEADER = ("# fieldcal calibration parameters. Per triad: raw = K * true + bias,\n"
           "# calibrated = inverse(K) * (raw - bias). Sigmas are 1-sigma. Do not edit by hand:\n"
           "# the named values are checked against K when the file is loaded.\n")


class ParameterFileError(ValueError):
    """A parameter file that cannot be used; the message is one line naming the file and field."""

    def __init__(self, message: str, path: str = "", field: str = "") -> None:
        super().__init__(message)
        self.path = path
        self.field = field


# --------------------------------------------------------------------------------------------
# In-memory model


def _readonly(values, shape: tuple[int, ...], what: str) -> np.ndarray:
    arr = np.array(values, dtype=np.float64)  # always a copy
    if arr.shape != shape:
        raise ValueError(f"{what}: expected shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{what}: expected finite numbers, got {arr.tolist()}")
    arr.setflags(write=False)
    return arr


def residual_units(kind: str, output_unit: str, method: str) -> tuple[str, ...]:
    """The units a triad's residual RMS may be in."""
    units = (SI_UNIT[kind], output_unit) + (("rad",) if method == ROTATION_METHOD else ())
    return tuple(dict.fromkeys(units))


def _bits(x: float) -> bytes:
    return np.float64(x).tobytes()


def _misalignment_of(K: np.ndarray) -> np.ndarray:
    return np.array([-K[1, 0] / K[1, 1], K[2, 0] / K[2, 2], -K[2, 1] / K[2, 2]])


@dataclass(frozen=True, eq=False)
class TriadParameters:
    """One triad's calibration: raw = K·true + bias, so calibrated = K⁻¹(raw − bias).

    ``K`` is lower-triangular for the norm method and full for the classic method (where it also
    holds the triad's rotation relative to the table). ``sigma`` is the 1σ of the nine named
    parameters in ``fieldcal.model.PARAM_NAMES`` order (bias, scale factor, misalignment).
    ``residual_rms`` is in ``residual_unit``: the SI unit of the reference for the norm method,
    the output unit for the classic method (whose residuals are in output units).
    """

    name: str
    kind: str
    output_unit: str
    bias: np.ndarray  # (3,), output units
    K: np.ndarray  # (3, 3), output units per SI unit
    sigma: np.ndarray  # (9,), PARAM_NAMES order
    residual_rms: float
    method: str
    residual_unit: str = ""  # default: SI unit of the kind

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name or not self.name.isprintable():
            raise ValueError(f"name: expected a non-empty printable string, got {self.name!r}")
        if self.kind not in KINDS:
            raise ValueError(f"{self.name}.kind: expected one of {', '.join(KINDS)}, got {self.kind!r}")
        for attr in ("output_unit", "method"):
            value = getattr(self, attr)
            if not isinstance(value, str) or not value:
                raise ValueError(f"{self.name}.{attr}: expected a non-empty string, got {value!r}")
        if not self.residual_unit:
            object.__setattr__(self, "residual_unit", SI_UNIT[self.kind])
        allowed = residual_units(self.kind, self.output_unit, self.method)
        if self.residual_unit not in allowed:
            raise ValueError(f"{self.name}.residual_unit: expected {' or '.join(map(repr, allowed))}, "
                             f"got {self.residual_unit!r}")
        object.__setattr__(self, "bias", _readonly(self.bias, (3,), f"{self.name}.bias"))
        K = _readonly(self.K, (3, 3), f"{self.name}.K")
        if np.any(np.diag(K) == 0) or not np.linalg.cond(K) < _MAX_CONDITION:
            raise ValueError(f"{self.name}.K: expected an invertible matrix with a non-zero "
                             f"diagonal, got {K.tolist()}")
        if self.method in LOWER_TRIANGULAR_METHODS and np.any(np.triu(K, 1) != 0):
            raise ValueError(f"{self.name}.K: the {self.method} method gives a lower-triangular K, "
                             f"got {K.tolist()}")
        object.__setattr__(self, "K", K)
        sigma = _readonly(self.sigma, (len(PARAM_NAMES),), f"{self.name}.sigma")
        if np.any(sigma < 0):
            raise ValueError(f"{self.name}.sigma: expected values >= 0, got {sigma.tolist()}")
        object.__setattr__(self, "sigma", sigma)
        rms = float(self.residual_rms)
        if not (math.isfinite(rms) and rms >= 0):
            raise ValueError(f"{self.name}.residual_rms: expected a finite number >= 0, got {rms!r}")
        object.__setattr__(self, "residual_rms", rms)

    @classmethod
    def from_solution(cls, sol) -> TriadParameters:
        """From a norm ``TriadSolution`` or a ``ClassicSolution`` (anything with name, kind,
        output_unit, method, K, bias, sigma, residual_rms and optionally residual_unit)."""
        return cls(name=sol.name, kind=sol.kind, output_unit=sol.output_unit,
                   bias=np.asarray(sol.bias, dtype=float), K=np.asarray(sol.K, dtype=float),
                   sigma=np.asarray(sol.sigma, dtype=float), residual_rms=float(sol.residual_rms),
                   method=sol.method, residual_unit=getattr(sol, "residual_unit", ""))

    @property
    def input_unit(self) -> str:
        return SI_UNIT[self.kind]

    @property
    def scale_factor(self) -> np.ndarray:
        return np.diag(self.K).copy()

    @property
    def misalignment(self) -> np.ndarray:
        """Δyz, Δzy, Δzx (rad) from the lower triangle of K."""
        return _misalignment_of(self.K)

    @property
    def theta(self) -> np.ndarray:
        """The nine named parameters in PARAM_NAMES order."""
        return np.r_[self.bias, self.scale_factor, self.misalignment]

    @property
    def bias_sigma(self) -> np.ndarray:
        return self.sigma[0:3].copy()

    @property
    def scale_factor_sigma(self) -> np.ndarray:
        return self.sigma[3:6].copy()

    @property
    def misalignment_sigma(self) -> np.ndarray:
        return self.sigma[6:9].copy()

    def named(self) -> dict[str, tuple[float, float]]:
        return {n: (float(v), float(s)) for n, v, s in zip(PARAM_NAMES, self.theta, self.sigma)}

    def calibrate(self, raw) -> np.ndarray:
        """K⁻¹(raw − bias) for a (3,) or (n, 3) array of raw outputs; SI units out."""
        v = np.asarray(raw, dtype=float) - self.bias
        if v.shape[-1:] != (3,) or v.ndim > 2:
            raise ValueError(f"{self.name}: expected a (3,) or (n, 3) array, got shape {np.shape(raw)}")
        return np.linalg.solve(self.K, v.T).T

    def _key(self) -> tuple:
        return (self.name, self.kind, self.output_unit, self.method, self.residual_unit,
                self.bias.tobytes(), self.K.tobytes(), self.sigma.tobytes(), _bits(self.residual_rms))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, TriadParameters):
            return NotImplemented
        return self._key() == other._key()

    def __hash__(self) -> int:
        return hash(self._key())


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
        if not self.gravity_m_s2 > 0:
            raise ValueError(f"provenance.gravity_m_s2: expected a number > 0, got {self.gravity_m_s2!r}")

    @classmethod
    def for_station(cls, station, *, procedure: str, method: str, input_sha256: str,
                    device_name: str | None = None, device_serial: str | None = None,
                    simulation: bool | None = None) -> Provenance:
        """From a ``fieldcal.earth.Station`` (its gravity and where that came from)."""
        return cls(procedure=procedure, method=method, input_sha256=input_sha256,
                   latitude_deg=station.latitude_deg, height_m=station.height_m,
                   gravity_m_s2=station.gravity, gravity_source=station.gravity_source,
                   device_name=device_name, device_serial=device_serial, simulation=simulation)


@dataclass(frozen=True)
class ParameterFile:
    triads: tuple[TriadParameters, ...]
    provenance: Provenance

    def __post_init__(self) -> None:
        triads = tuple(self.triads)
        if not triads or not all(isinstance(t, TriadParameters) for t in triads):
            raise ValueError("triads: expected one or more TriadParameters")
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
              simulation: bool | None = None) -> ParameterFile:
        """Triads plus provenance from a ``fieldcal.earth.Station`` and the hash of the averages."""
        return cls(triads=tuple(triads), provenance=Provenance.for_station(
            station, procedure=procedure, method=method, input_sha256=input_sha256,
            device_name=device_name, device_serial=device_serial, simulation=simulation))

    @classmethod
    def from_solutions(cls, solutions: Iterable, *, station, procedure: str,
                       inputs: Sequence[np.ndarray] | None = None, input_sha256: str | None = None,
                       method: str | None = None, device_name: str | None = None,
                       device_serial: str | None = None,
                       simulation: bool | None = None) -> ParameterFile:
        """Parameters of solver solutions, with provenance from ``station`` and the averages.

        Give the averages that went in as ``inputs`` (hashed with ``hash_inputs``) or their hash
        as ``input_sha256``. ``method`` defaults to the solutions' method ("a+b" when they differ).
        """
        triads = tuple(TriadParameters.from_solution(s) for s in solutions)
        if (inputs is None) == (input_sha256 is None):
            raise ValueError("give exactly one of inputs (the averages) or input_sha256")
        if input_sha256 is None:
            input_sha256 = hash_inputs(*inputs)
        if method is None:
            method = "+".join(sorted({t.method for t in triads}))
        return cls.build(triads, station=station, procedure=procedure, method=method,
                         input_sha256=input_sha256, device_name=device_name,
                         device_serial=device_serial, simulation=simulation)


def hash_inputs(*arrays) -> str:
    """SHA-256 (hex) of arrays' dtype, shape and C-order bytes, in order: deterministic."""
    h = hashlib.sha256(b"fieldcal-inputs/1\0")
    for a in arrays:
        arr = np.ascontiguousarray(a)
        if arr.dtype.hasobject:
            raise TypeError("hash_inputs: object arrays have no stable bytes; pass numeric arrays")
        header = f"{arr.dtype.str}|{','.join(map(str, arr.shape))}|{arr.nbytes}\0"
        h.update(header.encode("ascii"))
        h.update(arr.tobytes())
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


def _triad_document(t: TriadParameters) -> dict:
    return {
        "kind": t.kind,
        "output_unit": t.output_unit,
        "input_unit": t.input_unit,
        "bias": {**_xyz(t.bias), "unit": t.output_unit, "sigma": _xyz(t.bias_sigma)},
        "scale_factor": {**_xyz(t.scale_factor), "unit": f"{t.output_unit} per {t.input_unit}",
                         "sigma": _xyz(t.scale_factor_sigma)},
        "misalignment": {**{k: _f(v) for k, v in zip(_ANGLES, t.misalignment)}, "unit": "rad",
                         "sigma": {k: _f(v) for k, v in zip(_ANGLES, t.misalignment_sigma)}},
        "K": [_FlowRow(_f(v) for v in row) for row in t.K],
        "residual_rms": {"value": _f(t.residual_rms), "unit": t.residual_unit},
        "method": t.method,
    }


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
