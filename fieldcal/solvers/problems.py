"""Norm equations for one triad, as residual functions of the 9 parameters and the averages.

Each problem flattens its averages into one vector ``u`` so that the solver can propagate their
covariance into the residuals and weight them; the residuals are in SI units of the reference.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from fieldcal.model import ANGULAR_RATE, SPECIFIC_FORCE, params_from_k
from fieldcal.solvers.ellipsoid import fit_centred_ellipsoid, fit_offset_ellipsoid


def _as_points(values, what: str) -> np.ndarray:
    arr = np.asarray(values, dtype=float)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{what}: expected an (n, 3) array, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{what}: contains NaN or infinite values")
    return arr


# cos φ below which the horizontal Earth rate (15 °/h · cos φ) is too small to use as a norm.
_POLAR_COS = 0.2


def _inverse_affine(theta) -> tuple[np.ndarray, np.ndarray]:
    """A = K⁻¹ and c = −K⁻¹b, so that calibrate_with(theta, raw) = raw·Aᵀ + c, for theta of shape
    (..., 9): the solvers evaluate many parameter vectors in one call (Jacobian columns)."""
    theta = np.asarray(theta, dtype=float)
    if theta.ndim == 1:  # one vector (Powell's line searches, ~170 a solve): the nine numbers as
        # floats, no stacked arrays to index; the same operations, so the same numbers bit for bit
        dyz, dzy, dzx = theta[6:].tolist()
        inv_x, inv_y, inv_z = (1.0 / theta[3:6]).tolist()
        A = np.array(((inv_x, 0.0, 0.0), (dyz * inv_x, inv_y, 0.0), ((dzx * dyz - dzy) * inv_x, dzx * inv_y, inv_z)))
        return A, -(A @ theta[:3, None])[..., 0]
    inv_k = 1.0 / theta[..., 3:6]
    dyz, dzy, dzx = theta[..., 6], theta[..., 7], theta[..., 8]
    A = np.zeros(theta.shape[:-1] + (3, 3))
    A[..., 0, 0], A[..., 1, 1], A[..., 2, 2] = inv_k[..., 0], inv_k[..., 1], inv_k[..., 2]
    A[..., 1, 0] = dyz * inv_k[..., 0]
    A[..., 2, 0] = (dzx * dyz - dzy) * inv_k[..., 0]
    A[..., 2, 1] = dzx * inv_k[..., 1]
    c = -(A @ theta[..., :3, None])[..., 0]
    return A, c


def _points(u: np.ndarray, start: int, stop: int) -> np.ndarray:
    """Elements start:stop of the last axis of u as (..., k, 3) points."""
    return u[..., start:stop].reshape(u.shape[:-1] + (-1, 3))


def _norms(v: np.ndarray) -> np.ndarray:
    return np.sqrt(np.einsum("...i,...i->...", v, v))


def _unit_rows(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), np.finfo(float).tiny)


@dataclass(frozen=True)
class StaticNormProblem:
    """A specific-force triad at rest in n orientations: |K⁻¹(u_i − b)| = g (paper eq. 17).

    The residual is |a| − g rather than |a|² − g²: the same equations to first order, with the
    residual in m/s² so that its weight is the variance of the average along the gravity direction.
    """

    means: np.ndarray
    gravity: float
    name: str = "accelerometer"
    output_unit: str = "m/s^2"
    labels: tuple[str, ...] = ()
    kind: str = field(default=SPECIFIC_FORCE, init=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "means", _as_points(self.means, f"{self.name} averages"))
        if not self.labels:
            object.__setattr__(self, "labels", tuple(f"static {i + 1}" for i in range(len(self.means))))

    @property
    def data(self) -> np.ndarray:
        return self.means.ravel()

    @property
    def residual_labels(self) -> tuple[str, ...]:
        return self.labels

    @property
    def reference_scale(self) -> float:
        return self.gravity

    def residuals(self, theta, u: np.ndarray) -> np.ndarray:
        """Per position; theta (..., 9) and u (..., 3n) broadcast against each other."""
        return self.residual_function(u)(theta)

    def residual_function(self, u: np.ndarray):
        """theta (..., 9) -> residuals for fixed averages u."""
        u = np.asarray(u, dtype=float)
        points = _points(u, 0, u.shape[-1])

        def residuals(theta) -> np.ndarray:
            A, c = _inverse_affine(theta)
            return _norms(points @ np.swapaxes(A, -1, -2) + c[..., None, :]) - self.gravity

        return residuals

    def point_gradients(self, theta) -> np.ndarray:
        """(n, 3): ∂r_i/∂u_i, each residual's gradient in its own average (it depends on no
        other): r_i = |a_i| − g with a_i = A u_i + c, so ∂r_i/∂u_i = (a_i/|a_i|)ᵀ A."""
        A, c = _inverse_affine(theta)
        a = self.means @ A.T + c
        return (a / _norms(a)[:, None]) @ A

    def initial(self) -> np.ndarray:
        return fit_offset_ellipsoid(self.means, self.gravity)

    def directions(self) -> np.ndarray:
        """Rough unit directions of gravity in output axes (for messages, not for solving)."""
        return _unit_rows(self.means - self.means.mean(axis=0))


@dataclass(frozen=True)
class RateNormProblem:
    """A gyro triad: rate steps (+ω then −ω about a vertical table axis) and static dwells.

    The table axis sees the table rate plus the vertical Earth rate Ωv = Ωe·sin φ; averaged over
    whole turns the horizontal Earth rate cancels. So with d the axis in calibrated body axes,
    u₊ = K(ω + Ωv)d + b and u₋ = K(−ω + Ωv)d + b, and the residuals are, per rate step:
      |K⁻¹(u₊ − u₋)/2| − ω                 (1, the norm equation of paper eq. 18, bias-free),
      K⁻¹((u₊ + u₋)/2 − b) − Ωv·d          (3, the reversal pins the bias in every direction),
    per step turned one way only (no partner), |K⁻¹(u − b)| − |ω_signed + Ωv|  (1),
    and per static dwell a = K⁻¹(u_s − b), which sees Earth rate only:
      d·a − Ωv and |a − (d·a)d| − Ωe·cos φ  (2, when the dwell is on the same table mount as a step),
      |a| − Ωe                             (1, otherwise).
    Within about 11° of a pole the horizontal Earth rate is too small for its norm to be a smooth
    residual (|a⊥| cannot go below zero), so there the across-axis term is left out; so it is when
    the dwells are too noisy to see it (``use_across`` False, set by solve.py from the noise model:
    a norm of a vector not well above its noise is biased and its linearised weight claims
    information the data do not hold, see across_earth_rate_usable).
    """

    plus: np.ndarray
    minus: np.ndarray
    table_rate: np.ndarray  # rad/s, per step, > 0
    static: np.ndarray
    static_step: np.ndarray  # per static dwell: index of the rate step on the same mount, or -1
    earth_rate: float
    earth_rate_vertical: float
    name: str = "gyroscope"
    output_unit: str = "rad/s"
    step_labels: tuple[str, ...] = ()
    static_labels: tuple[str, ...] = ()
    single: np.ndarray = field(default_factory=lambda: np.empty((0, 3)))
    single_rate: np.ndarray = field(default_factory=lambda: np.empty(0))  # rad/s, signed
    single_labels: tuple[str, ...] = ()
    use_across: bool = True  # the across-axis Earth-rate residual of paired dwells
    kind: str = field(default=ANGULAR_RATE, init=False)

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "plus", _as_points(self.plus, f"{self.name} +rate averages"))
        set_(self, "minus", _as_points(self.minus, f"{self.name} -rate averages"))
        static = np.asarray(self.static, dtype=float).reshape(-1, 3)
        set_(self, "static", _as_points(static, f"{self.name} static averages"))
        m = len(self.plus)
        if self.minus.shape != self.plus.shape:
            raise ValueError(f"{self.name}: {m} +rate averages but {len(self.minus)} -rate averages")
        rate = np.broadcast_to(np.asarray(self.table_rate, dtype=float), (m,)).copy()
        if np.any(rate <= 0):
            raise ValueError(f"{self.name}: table rates must be positive (the sign is in +/-)")
        set_(self, "table_rate", rate)
        pairing = np.asarray(self.static_step, dtype=int).reshape(-1)
        if len(pairing) != len(self.static) or np.any(pairing >= m):
            raise ValueError(f"{self.name}: static_step must give a rate step index or -1 per dwell")
        set_(self, "static_step", pairing)
        set_(self, "single", _as_points(np.asarray(self.single, dtype=float).reshape(-1, 3),
                                        f"{self.name} one-way rate averages"))
        single_rate = np.asarray(self.single_rate, dtype=float).reshape(-1)
        if len(single_rate) != len(self.single) or np.any(single_rate == 0):
            raise ValueError(f"{self.name}: one signed, non-zero table rate per one-way step")
        set_(self, "single_rate", single_rate)
        if not self.single_labels:
            set_(self, "single_labels", tuple(f"one-way step {j + 1}" for j in range(len(single_rate))))
        if not self.step_labels:
            set_(self, "step_labels", tuple(f"rate step {j + 1}" for j in range(m)))
        if not self.static_labels:
            set_(self, "static_labels", tuple(f"static {i + 1}" for i in range(len(self.static))))

    @property
    def data(self) -> np.ndarray:
        return np.concatenate([self.plus.ravel(), self.minus.ravel(), self.single.ravel(),
                               self.static.ravel()])

    @property
    def reference_scale(self) -> float:
        return float(np.mean(np.abs(np.r_[self.table_rate, self.single_rate])))

    @property
    def _uses_across(self) -> bool:
        return self.use_across and self.earth_rate_vertical**2 < (1 - _POLAR_COS**2) * self.earth_rate**2

    @property
    def residual_labels(self) -> tuple[str, ...]:
        labels = [f"{s}: |rate|" for s in self.step_labels]
        labels += [f"{s}: bias {axis}" for s in self.step_labels for axis in "xyz"]
        labels += [f"{s}: |rate|" for s in self.single_labels]
        for label, step in zip(self.static_labels, self.static_step):
            if step < 0:
                labels.append(f"{label}: |earth rate|")
            else:
                labels.append(f"{label}: earth rate along axis")
                if self._uses_across:
                    labels.append(f"{label}: earth rate across axis")
        return tuple(labels)

    def _split(self, u: np.ndarray):
        m, k = 3 * len(self.plus), 3 * len(self.single)
        return (_points(u, 0, m), _points(u, m, 2 * m), _points(u, 2 * m, 2 * m + k),
                _points(u, 2 * m + k, u.shape[-1]))

    def residuals(self, theta, u: np.ndarray) -> np.ndarray:
        """In residual_labels order; theta (..., 9) and u (..., len(data)) broadcast."""
        return self.residual_function(u)(theta)

    def residual_function(self, u: np.ndarray):
        """theta (..., 9) -> residuals for fixed averages u: what does not depend on theta (the
        half sums and differences, the layout of the static terms) is worked out once, so each
        of the solver's evaluations is one product with K⁻¹ and a few norms."""
        u = np.asarray(u, dtype=float)
        plus, minus, single, static = self._split(u)
        m, k = len(self.plus), len(self.single)
        # Rows: half differences (bias-free), half sums, one-way steps, static dwells.
        points = np.concatenate([0.5 * (plus - minus), 0.5 * (plus + minus), single, static], axis=-2)
        one_way_rate = np.abs(self.single_rate + self.earth_rate_vertical)
        paired = self.static_step >= 0
        sizes = np.where(paired, 2 if self._uses_across else 1, 1)
        # Interleave per dwell, in dwell order, to match residual_labels.
        first = 4 * m + k + np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(int)
        # Integer rows of v (below) and columns of the result, so each evaluation only gathers.
        paired_rows, lone_rows = 2 * m + k + np.flatnonzero(paired), 2 * m + k + np.flatnonzero(~paired)
        paired_at, lone_at, mount = first[paired], first[~paired], self.static_step[paired]
        across = self._uses_across and len(paired_rows) > 0
        n_resid = 4 * m + k + int(sizes.sum())
        horizontal = math.sqrt(max(self.earth_rate**2 - self.earth_rate_vertical**2, 0.0))
        vertical, earth, rate = self.earth_rate_vertical, self.earth_rate, self.table_rate

        def residuals(theta) -> np.ndarray:
            A, c = _inverse_affine(theta)
            v = points @ np.swapaxes(A, -1, -2)
            v[..., m:, :] += c[..., None, :]
            out = np.empty(v.shape[:-2] + (n_resid,))
            rate_vec = v[..., :m, :]
            rate_norm = _norms(rate_vec)
            axis = rate_vec / rate_norm[..., None]
            out[..., :m] = rate_norm - rate
            out[..., m:4 * m] = (v[..., m:2 * m, :] - vertical * axis).reshape(out.shape[:-1] + (3 * m,))
            out[..., 4 * m:4 * m + k] = _norms(v[..., 2 * m:2 * m + k, :]) - one_way_rate
            if len(paired_rows):
                a, mount_axis = v[..., paired_rows, :], axis[..., mount, :]
                along = np.einsum("...ij,...ij->...i", a, mount_axis)
                out[..., paired_at] = along - vertical
                if across:
                    out[..., paired_at + 1] = _norms(a - along[..., None] * mount_axis) - horizontal
            if len(lone_rows):
                out[..., lone_at] = _norms(v[..., lone_rows, :]) - earth
            return out

        return residuals

    def directions(self) -> np.ndarray:
        """Rough unit directions of the table axis in output axes (for messages)."""
        one_way = self.single - (self.single.mean(axis=0) if len(self.single) else 0.0)
        return _unit_rows(np.concatenate([0.5 * (self.plus - self.minus), one_way]))

    def initial(self) -> np.ndarray:
        if len(self.plus) < 6 and len(self.single):
            radius = float(np.mean(np.abs(self.single_rate + self.earth_rate_vertical)))
            return fit_offset_ellipsoid(self.single, radius)
        half_diff = 0.5 * (self.plus - self.minus)
        K = fit_centred_ellipsoid(half_diff, self.table_rate)
        # (u₊ + u₋)/2 = b + Ωv·K·d and (u₊ − u₋)/2 = ω·K·d, so the bias follows without K.
        bias = np.mean(0.5 * (self.plus + self.minus)
                       - (self.earth_rate_vertical / self.table_rate)[:, None] * half_diff, axis=0)
        return params_from_k(K, bias)

