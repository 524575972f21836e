"""One triad's calibration, whatever solved it (or read it from a file), and how the solver got there.

Every solver returns a ``Calibration`` (norm method by Powell or least squares, classic least
squares, the gyro from rotations); the parameter file writes it and reads it back; the report,
the results screen and ``fieldcal solve`` show it. The model is raw = K·true + bias, so
calibrated = K⁻¹(raw − bias) (``fieldcal.model``).

The parameters are ``parameter_names``: the nine of ``PARAM_NAMES`` (bias, scale factor, the
named angles of K's lower triangle) or, for a full K estimated term by term (the gyro from
rotations), the twelve of ``FULL_PARAM_NAMES``. Their values ``theta`` and K are converted into
each other by ``fieldcal.model`` only; a solver gives whichever it estimated.

``diagnostics`` stands beside the calibration, not in it: a calibration read from a file has
none, and iteration counts differ between processors and BLAS builds, so they belong in no
golden output. Two calibrations are equal when the parameter files they write are equal.
"""
from __future__ import annotations

import difflib
import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from fieldcal.model import (ANGLE_TERMS, KINDS, PARAM_NAMES, SI_UNIT, k_from, k_from_params, params_from,
                            params_from_k)
from fieldcal.thermal import ThermalModel
from fieldcal.units import SCALE, SI_PER_UNIT, group_of, operator_unit

# Norm-method solvers give a lower-triangular K; a file claiming one of these methods with a
# non-zero upper triangle has been edited by hand.
LOWER_TRIANGULAR_METHODS = ("powell", "lsq")
CLASSIC_METHOD = "classic"
# The gyro calibrated from the rotations between a recording's poses: full K (the gyro-to-
# accelerometer misalignment included), residuals in rad (direction misfits).
ROTATION_METHOD = "rotation"
# A triad's biases from still poses alone (the gyro's from rests; no rotation or pose spread to
# give its scale or misalignment): the still readings' mean, residuals their scatter about it.
STILL_METHOD = "still"
TRIAD_METHODS = (*LOWER_TRIANGULAR_METHODS, CLASSIC_METHOD, ROTATION_METHOD, STILL_METHOD)
_MAX_CONDITION = 1e12  # K with a larger condition number is treated as singular


def nominal_value(kind: str, output_unit: str, parameter: str) -> float | None:
    """What a parameter is when nothing calibrated it: no bias, no misalignment, the scale of the
    output unit itself (1 for SI, 1/9.80665 for g); None for a scale in a device's own unit
    (counts), which has no nominal."""
    if group_of(parameter) != SCALE:
        return 0.0
    si = SI_PER_UNIT[kind].get(output_unit)
    return None if si is None else 1.0 / si


def nearest(value, allowed: Sequence[str]) -> str:
    """The allowed name closest to ``value``, for "nearest: ..." in a one-line error."""
    return difflib.get_close_matches(str(value), list(allowed), n=1, cutoff=0.0)[0]


def residual_units(kind: str, output_unit: str, method: str) -> tuple[str, ...]:
    """The units a triad's residuals may be in."""
    # a gyro calibrated from integrated turns (rotations, or the Ferraris protocol's full
    # turns) has its residuals as angles
    units = (SI_UNIT[kind], output_unit) + (("rad",) if method == ROTATION_METHOD or kind == "angular_rate" else ())
    return tuple(dict.fromkeys(units))


@dataclass(frozen=True)
class SolverDiagnostics:
    """How a solver reached a calibration: effort, convergence and fit quality."""

    iterations: int = 0  # Powell's iterations; for least squares MINPACK's function count
    evaluations: int = 0  # residual evaluations
    converged: bool = True
    message: str = ""
    search: str = ""  # the optimiser: "powell" or "lsq" (Levenberg-Marquardt)
    chi2: float | None = None  # of the whitened residuals
    dof: int = 0
    scaled_by_residuals: bool = False  # covariance scaled by the residual variance (Birge)
    condition_number: float | None = None  # of the Jacobian in natural units
    held: tuple[str, ...] = ()  # parameters held at their start (their σ a prior), not estimated
    extra_residuals: np.ndarray | None = None  # whitened equations beyond the triad's own

    @property
    def reduced_chi2(self) -> float | None:
        return self.chi2 / self.dof if self.chi2 is not None and self.dof else None


def _readonly(values, shape: tuple[int, ...], what: str) -> np.ndarray:
    arr = np.array(values, dtype=np.float64)  # always a copy
    if arr.shape != shape:
        raise ValueError(f"{what}: expected shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{what}: expected finite numbers, got {arr.tolist()}")
    arr.setflags(write=False)
    return arr


def _bits(x: float) -> bytes:
    return np.float64(x).tobytes()


@dataclass(frozen=True, eq=False)
class BiasAtEnd:
    """The bias at the end of the calibration (DESIGN 12): the triad's bias process at the run's
    last sample (``time_s``, sample time), the value the unit is used with right after
    calibration, predicted from the averages (``fieldcal.solvers.endbias``); output units. A
    parameter file keeps the value and σ; the covariance is the solver's."""

    value: np.ndarray  # (3,)
    time_s: float
    sigma: np.ndarray | None = None  # (3,); default from the covariance
    covariance: np.ndarray | None = None  # (3, 3)

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "value", _readonly(self.value, (3,), "bias_at_end"))
        if self.covariance is not None:
            set_(self, "covariance", _readonly(self.covariance, (3, 3), "bias_at_end.covariance"))
            if self.sigma is None:
                set_(self, "sigma", np.sqrt(np.diag(self.covariance)))
        if self.sigma is None:
            raise ValueError("bias_at_end: give the covariance or sigma")
        sigma = _readonly(self.sigma, (3,), "bias_at_end.sigma")
        if np.any(sigma < 0):
            raise ValueError(f"bias_at_end.sigma: expected values >= 0, got {sigma.tolist()}")
        set_(self, "sigma", sigma)
        if not (isinstance(self.time_s, (int, float, np.floating)) and math.isfinite(self.time_s)
                and self.time_s >= 0):
            raise ValueError(f"bias_at_end.time_s: expected a finite time >= 0, got {self.time_s!r}")
        set_(self, "time_s", float(self.time_s))

    def key(self) -> tuple:
        return (self.value.tobytes(), self.sigma.tobytes(), _bits(self.time_s))


@dataclass(frozen=True, eq=False)
class Calibration:
    """One triad's calibration. Give K or theta (the other follows), and the covariance of theta
    or its σ (a parameter file keeps only σ); the residuals or their RMS."""

    name: str
    kind: str
    output_unit: str
    method: str
    bias: np.ndarray | None = None  # (3,) output units; default theta[:3]
    K: np.ndarray | None = None  # (3, 3) output units per SI unit
    theta: np.ndarray | None = None  # parameter_names order
    covariance: np.ndarray | None = None  # of theta
    sigma: np.ndarray | None = None  # 1σ of theta; default from the covariance
    residual_rms: float | None = None  # default: RMS of residuals
    residuals: np.ndarray = field(default_factory=lambda: np.zeros(0))  # residual_unit
    residual_unit: str = ""  # default: SI unit of the kind
    residual_labels: tuple[str, ...] | None = None  # one per residual; None: (n, 3) per average
    parameter_names: tuple[str, ...] = PARAM_NAMES
    diagnostics: SolverDiagnostics | None = None  # None when read from a file
    thermal: ThermalModel | None = None  # bias and scale against temperature; None: not calibrated
    # The PARAM_NAMES parameters the data did not determine (issue 27): each at its nominal_value,
    # its σ NaN (there is none), the file marks them; ``not_calibrated_why``: what would add them.
    not_calibrated: tuple[str, ...] = ()
    not_calibrated_why: str = ""
    # the bias at the run's last sample, predicted from the averages; None: not estimated (a
    # file written before it existed, a solver that does not give it)
    bias_at_end: BiasAtEnd | None = None

    def __post_init__(self) -> None:
        set_ = object.__setattr__  # frozen: fill the derived fields once, here
        if not isinstance(self.name, str) or not self.name or not self.name.isprintable():
            raise ValueError(f"name: expected a non-empty printable string, got {self.name!r}")
        if self.kind not in KINDS:
            raise ValueError(f"{self.name}.kind: expected one of {', '.join(KINDS)}, got {self.kind!r}")
        for attr in ("output_unit", "method"):
            value = getattr(self, attr)
            if not isinstance(value, str) or not value:
                raise ValueError(f"{self.name}.{attr}: expected a non-empty string, got {value!r}")
        if self.method not in TRIAD_METHODS:
            raise ValueError(f"{self.name}.method: expected one of {', '.join(TRIAD_METHODS)}, got "
                             f"{self.method!r} (nearest: {nearest(self.method, TRIAD_METHODS)!r})")
        if not self.residual_unit:
            set_(self, "residual_unit", SI_UNIT[self.kind])
        allowed = residual_units(self.kind, self.output_unit, self.method)
        if self.residual_unit not in allowed:
            raise ValueError(f"{self.name}.residual_unit: expected {' or '.join(map(repr, allowed))}, "
                             f"got {self.residual_unit!r}")
        names = tuple(self.parameter_names)
        set_(self, "parameter_names", names)
        p = len(names)
        if self.theta is None and (self.K is None or self.bias is None):
            raise ValueError(f"{self.name}: give K and the bias, or theta")
        if self.theta is not None:
            theta = _readonly(self.theta, (p,), f"{self.name}.theta")
            set_(self, "theta", theta)
            if self.bias is None:
                set_(self, "bias", theta[:3])
            if self.K is None:
                set_(self, "K", k_from(theta, names))
        set_(self, "bias", _readonly(self.bias, (3,), f"{self.name}.bias"))
        K = _readonly(self.K, (3, 3), f"{self.name}.K")
        if np.any(np.diag(K) == 0) or not np.linalg.cond(K) < _MAX_CONDITION:
            raise ValueError(f"{self.name}.K: expected an invertible matrix with a non-zero "
                             f"diagonal, got {K.tolist()}")
        if self.method in LOWER_TRIANGULAR_METHODS and np.any(np.triu(K, 1) != 0):
            raise ValueError(f"{self.name}.K: the {self.method} method gives a lower-triangular K, "
                             f"got {K.tolist()}")
        set_(self, "K", K)
        if self.theta is None:
            set_(self, "theta", _readonly(params_from(K, self.bias, names), (p,), f"{self.name}.theta"))
        if self.covariance is not None:
            cov = np.array(self.covariance, dtype=float)
            if cov.shape != (p, p):
                raise ValueError(f"{self.name}.covariance: expected shape {(p, p)}, got {cov.shape}")
            cov.setflags(write=False)
            set_(self, "covariance", cov)
            if self.sigma is None:
                set_(self, "sigma", np.sqrt(np.diag(cov)))
        if self.sigma is None:
            raise ValueError(f"{self.name}: give the covariance or sigma")
        if self.not_calibrated and np.shape(self.sigma) == (p,):  # theirs is NaN: none, checked below
            set_(self, "sigma", np.where(np.isin(names, self.not_calibrated), 0.0, self.sigma))
        sigma = _readonly(self.sigma, (p,), f"{self.name}.sigma")
        if np.any(sigma < 0):
            raise ValueError(f"{self.name}.sigma: expected values >= 0, got {sigma.tolist()}")
        set_(self, "sigma", sigma)
        residuals = np.array(self.residuals, dtype=float)
        residuals.setflags(write=False)
        set_(self, "residuals", residuals)
        rms = float(np.sqrt(np.mean(residuals**2))) if self.residual_rms is None and residuals.size \
            else self.residual_rms
        if rms is None or not (math.isfinite(float(rms)) and float(rms) >= 0):
            raise ValueError(f"{self.name}.residual_rms: expected a finite number >= 0, got {rms!r}")
        set_(self, "residual_rms", float(rms))
        if self.thermal is not None and not isinstance(self.thermal, ThermalModel):
            raise ValueError(f"{self.name}.thermal: expected a ThermalModel or None, "
                             f"got {type(self.thermal).__name__}")
        if self.bias_at_end is not None and not isinstance(self.bias_at_end, BiasAtEnd):
            raise ValueError(f"{self.name}.bias_at_end: expected a BiasAtEnd or None, "
                             f"got {type(self.bias_at_end).__name__}")
        self._mark_not_calibrated()

    def _mark_not_calibrated(self) -> None:
        """Check that every parameter marked not calibrated is at its nominal value, and take its
        σ (and covariance) away: NaN, never a number that would read as a calibrated one's."""
        marked = tuple(self.not_calibrated)
        if not marked:
            object.__setattr__(self, "not_calibrated", ())
            return
        unknown = [n for n in marked if n not in PARAM_NAMES]
        if unknown or self.parameter_names != PARAM_NAMES:
            raise ValueError(f"{self.name}.not_calibrated: expected names of {', '.join(PARAM_NAMES)}, got "
                             f"{', '.join(map(repr, unknown or marked))}")
        marked = tuple(n for n in PARAM_NAMES if n in marked)  # one order everywhere
        index = [PARAM_NAMES.index(n) for n in marked]
        for i, n in zip(index, marked):
            nominal = nominal_value(self.kind, self.output_unit, n)
            if nominal is None:
                raise ValueError(f"{self.name}.{n}: a scale factor in {self.output_unit!r} has no nominal value: "
                                 "it cannot be left not calibrated")
            if not math.isclose(float(self.theta[i]), nominal, rel_tol=1e-12, abs_tol=1e-15):
                raise ValueError(f"{self.name}.{n}: not calibrated, so expected its nominal value {nominal!r}, "
                                 f"got {float(self.theta[i])!r}")
        sigma = np.array(self.sigma)
        sigma[index] = np.nan
        sigma.setflags(write=False)
        object.__setattr__(self, "sigma", sigma)
        if self.covariance is not None:
            cov = np.array(self.covariance)
            cov[index, :] = np.nan
            cov[:, index] = np.nan
            cov.setflags(write=False)
            object.__setattr__(self, "covariance", cov)
        object.__setattr__(self, "not_calibrated", marked)

    @property
    def calibrated(self) -> tuple[str, ...]:
        """The PARAM_NAMES parameters the data determined (all of them unless some are marked)."""
        return tuple(n for n in PARAM_NAMES if n not in self.not_calibrated)

    # The model ---------------------------------------------------------------------------

    @property
    def input_unit(self) -> str:
        return SI_UNIT[self.kind]

    @property
    def scale_factor(self) -> np.ndarray:
        return np.diag(self.K).copy()

    @property
    def misalignment(self) -> np.ndarray:
        """The angles (PARAM_NAMES) or the six terms of M (FULL_PARAM_NAMES), rad."""
        return self.theta[6:].copy()

    def named(self) -> dict[str, tuple[float, float]]:
        """Each parameter's (value, 1σ) by name."""
        return {n: (float(v), float(s))
                for n, v, s in zip(self.parameter_names, self.theta, self.sigma, strict=True)}

    def theta_of(self, truth) -> np.ndarray:
        """A simulation's truth in this calibration's parameters: given in them already, or as
        the nine PARAM_NAMES values of a lower-triangular K."""
        truth = np.asarray(truth, dtype=float)
        if len(truth) == len(self.parameter_names):
            return truth
        return params_from(k_from_params(truth), truth[:3], self.parameter_names)

    def errors_in_sigma(self, truth) -> np.ndarray:
        """(solved − true) / σ per parameter; NaN where σ is 0 (a parameter held exactly)."""
        sigma = np.where(self.sigma > 0, self.sigma, np.nan)
        return (self.theta - self.theta_of(truth)) / sigma

    def calibrate(self, raw, temperature=None, *, extrapolate: bool = False) -> np.ndarray:
        """K⁻¹(raw − bias) for a (3,) or (n, 3) array of raw outputs; SI units out.

        With a thermal model, ``temperature`` (°C: a number, or one per row) is required and
        K(T)⁻¹(raw − bias(T)) is returned; a temperature outside the calibrated range raises
        ``TemperatureOutOfRange`` unless ``extrapolate``. Without one, ``temperature`` is
        ignored: the result is exactly that of a calibration from before thermal models."""
        v = np.asarray(raw, dtype=float) - self.bias
        if v.shape[-1:] != (3,) or v.ndim > 2:
            raise ValueError(f"{self.name}: expected a (3,) or (n, 3) array, got shape {np.shape(raw)}")
        if self.thermal is None:
            return np.linalg.solve(self.K, v.T).T
        if temperature is None:
            raise ValueError(f"{self.name}: has a thermal model; give the temperature (°C) of the samples")
        rows = np.atleast_2d(v)
        t = np.broadcast_to(np.asarray(temperature, dtype=float), (len(rows),)) \
            if np.ndim(temperature) == 0 else np.asarray(temperature, dtype=float)
        if t.shape != (len(rows),):
            raise ValueError(f"{self.name}: expected one temperature per sample ({len(rows)}), "
                             f"got shape {np.shape(temperature)}")
        if not extrapolate:
            self.thermal.check_range(t, self.name)
        # K(T) = diag(r)·K, so K(T)⁻¹ w = K⁻¹ (w / r): one solve for every sample
        w = (rows - self.thermal.bias_offset(t)) / self.thermal.scale_ratio(t)
        out = np.linalg.solve(self.K, w.T).T
        return out.reshape(v.shape)

    # What the parameter file holds -------------------------------------------------------

    @property
    def file_theta(self) -> np.ndarray:
        """The nine PARAM_NAMES values a parameter file writes, all from K (its authority)."""
        return params_from_k(self.K, self.bias, full=True)

    @property
    def file_sigma(self) -> np.ndarray:
        """Their 1σ: a named angle's is that of its term of M when the terms were estimated."""
        index = {n: i for i, n in enumerate(self.parameter_names)}
        return np.array([self.sigma[index[n] if n in index else index[ANGLE_TERMS[n]]]
                         for n in PARAM_NAMES])

    def _key(self) -> tuple:
        return (self.name, self.kind, self.output_unit, self.method, self.residual_unit,
                self.bias.tobytes(), self.K.tobytes(), self.file_sigma.tobytes(), _bits(self.residual_rms),
                None if self.thermal is None else self.thermal.key(), self.not_calibrated, self.not_calibrated_why,
                None if self.bias_at_end is None else self.bias_at_end.key())

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Calibration):
            return NotImplemented
        return self._key() == other._key()

    def __hash__(self) -> int:
        return hash(self._key())


def with_not_calibrated(cal: Calibration, names, why: str = "") -> Calibration:
    """``cal`` with the PARAM_NAMES parameters ``names`` (besides any marked already) set to their
    nominal values and marked not calibrated (issue 27): what a sub-model solve did not determine.
    ``cal`` must be in PARAM_NAMES; its other values and their covariance are kept."""
    from dataclasses import replace

    marked = tuple(n for n in PARAM_NAMES if n in set(names) | set(cal.not_calibrated))
    if not marked:
        return cal
    theta = np.array(cal.theta)
    for n in marked:
        nominal = nominal_value(cal.kind, cal.output_unit, n)
        if nominal is None:
            raise ValueError(f"{cal.name}.{n}: a scale factor in {cal.output_unit!r} has no nominal value: "
                             "it cannot be left not calibrated")
        theta[PARAM_NAMES.index(n)] = nominal
    return replace(cal, theta=theta, K=None, bias=None, sigma=cal.sigma, not_calibrated=marked,
                   not_calibrated_why=why or cal.not_calibrated_why)


def operator_values(cal: Calibration) -> tuple[np.ndarray, np.ndarray, tuple[str, ...]]:
    """(values, σ, units) of a Calibration's parameters in operator units."""
    scales, units = zip(*(operator_unit(cal.kind, cal.output_unit, group_of(n))
                          for n in cal.parameter_names))
    factors = np.array(scales)
    return cal.theta * factors, cal.sigma * factors, units
