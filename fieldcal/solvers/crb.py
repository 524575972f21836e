"""Cramér-Rao bound on a triad's 9 parameters, with every position's orientation a nuisance.

The measurement model is the full one, not the norm residuals: each average is
K·(true input in body axes) + b with Gaussian noise of known covariance, and the body-axis
direction of each input is unknown (2 angles per position, plus the heading of the horizontal
Earth rate for a gyro dwell). The bound is the 9x9 block of the inverse Fisher information.

With ``ThermalTerms`` (issue 28) each average is also tagged with its window's temperature and
the model is the joint fit's (``fieldcal.solvers.thermal``): diag(1 + s₁ΔT)·K·a + b₀ + Σₖ bₖΔTᵏ;
the bound then covers the nine parameters and the thermal terms, 9 + 3·order (+ 3 with s₁).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fieldcal.model import N_PARAMS


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a × b over the last axis (size 3): np.cross's own products and differences, without its
    axis handling, which took half of `fieldcal plan`'s time."""
    return np.stack([a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1],
                     a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
                     a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]], axis=-1)


def _tangent_basis(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors perpendicular to each row of d, (n, 3) each."""
    helper = np.where(np.abs(d[:, [0]]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    e1 = _cross(d, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    return e1, _cross(d, e1)


def _perturber(d0: np.ndarray):
    """angles (..., n, 2) -> the unit directions (..., n, 3) ``angles`` away from d0's rows; d0's
    tangent basis is made once, not at each evaluation of the model."""
    e1, e2 = _tangent_basis(d0)

    def perturbed(angles: np.ndarray) -> np.ndarray:
        d = d0 + angles[..., [0]] * e1 + angles[..., [1]] * e2
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    return perturbed


def _distorted(thetas: np.ndarray, true: np.ndarray) -> np.ndarray:
    """K·true + b for parameter rows ``thetas`` (m, 9) and inputs ``true`` (m, n, 3): the model
    of ``fieldcal.model.distort_with``, for every row of a Jacobian's evaluations at once."""
    b = thetas[:, None, :3]
    kx, ky, kz, dyz, dzy, dzx = (thetas[:, None, j] for j in range(3, 9))
    tx, ty, tz = true[..., 0], true[..., 1], true[..., 2]
    return np.stack([kx * tx, -dyz * ky * tx + ky * ty, dzy * kz * tx - dzx * kz * ty + kz * tz], axis=-1) + b


@dataclass(frozen=True)
class EndBias:
    """Where the bias is wanted at the end of the calibration (DESIGN 12): ``cross`` (data × 3)
    is the covariance of the data's noise with K times the bias process at that time, ``point``
    (3 × 3) that term's own covariance (``end_bias_terms``)."""

    cross: np.ndarray
    point: np.ndarray


@dataclass(frozen=True)
class EndBiasBound:
    """Error covariances (3 × 3, output units) of the bias at the end of the calibration:
    ``predicted``, of its best linear unbiased predictor from the same data (the constant's
    estimate plus what the residuals say of the process at the end), and ``constant``, of the
    turn-on constant's estimate used as it (what a solver that reports the constant delivers)."""

    predicted: np.ndarray
    constant: np.ndarray


def end_bias_terms(noise, sensitivity: np.ndarray, starts, durations, end_s: float) -> EndBias:
    """``EndBias`` for windows of a triad whose noise (``drivers.noise.TriadNoise``) enters before
    its K (``sensitivity``): data window-major then axis, as ``average_covariance`` orders it."""
    kk = sensitivity @ sensitivity.T
    cross = np.kron(noise.point_covariance(starts, durations, end_s)[:, None], kk)
    return EndBias(cross, noise.bias_variance() * kk)


@dataclass(frozen=True)
class ThermalTerms:
    """The thermal model a bound is taken for: ``delta_t`` the temperature of each average minus
    the model's reference (K, one per average in the data's order, as the covariance orders it),
    the true ``bias_terms`` bₖ (order, 3) and ``scale_drift`` s₁ (3,), or None for a model without
    the drift. The bound's parameters after the nine: b₁ x, y, z, …, b_order, then s₁ x, y, z."""

    delta_t: np.ndarray
    bias_terms: np.ndarray
    scale_drift: np.ndarray | None = None

    @property
    def count(self) -> int:
        return np.size(self.bias_terms) + (3 if self.scale_drift is not None else 0)

    def start(self) -> np.ndarray:
        drift = () if self.scale_drift is None else np.asarray(self.scale_drift, dtype=float)
        return np.r_[np.asarray(self.bias_terms, dtype=float).ravel(), drift]

    def steps(self, bias_step: np.ndarray) -> np.ndarray:
        """Difference steps: each term moving the averages about as much as ``bias_step`` does."""
        span = max(float(np.ptp(self.delta_t)), 1e-3)
        order = len(np.reshape(self.bias_terms, (-1, 3)))
        terms = np.tile(bias_step, order) / np.repeat(span ** np.arange(1, order + 1), 3)
        return np.r_[terms, np.full(3 if self.scale_drift is not None else 0, 1e-6 / span)]

    def apply(self, mean_fn):
        """``mean_fn`` of rows x = (θ, nuisances) made a function of rows x = (θ, thermal terms,
        nuisances) (rows (m, p), as ``_bound`` evaluates them all at once)."""
        order = len(np.reshape(self.bias_terms, (-1, 3)))
        dt = np.asarray(self.delta_t, dtype=float)[:, None]
        powers = dt ** np.arange(1, order + 1)

        def mean(x):
            m = len(x)
            theta, terms = x[:, :N_PARAMS], x[:, N_PARAMS:N_PARAMS + 3 * order].reshape(m, order, 3)
            drift = x[:, None, N_PARAMS + 3 * order:N_PARAMS + self.count] if self.scale_drift is not None else 0.0
            rows = mean_fn(np.concatenate([theta, x[:, N_PARAMS + self.count:]], axis=1)).reshape(m, -1, 3)
            bias = theta[:, None, :3]
            return ((rows - bias) * (1.0 + dt[None] * drift) + bias
                    + np.einsum("nk,mkj->mnj", powers, terms)).reshape(m, -1)

        return mean


@dataclass(frozen=True)
class KroneckerCovariance:
    """The covariance C ⊗ M of data ordered window-major then axis: ``windows`` C (n × n), one
    axis's covariance between the window means, and ``axes`` M (3 × 3), K·Kᵀ (noise entering
    before K, the same on every axis: ``fieldcal.solvers.solve.average_covariance`` without
    quantisation). Its Cholesky factor is Lc ⊗ Lm: two small factorisations instead of one of
    3n × 3n, and the whitening two triangular solves on the reshaped data."""

    windows: np.ndarray
    axes: np.ndarray

    def whiten(self, rhs: np.ndarray) -> np.ndarray:
        """(Lc ⊗ Lm)⁻¹ · rhs for rhs (3n, k)."""
        from scipy.linalg import solve_triangular

        n, k = len(self.windows), rhs.shape[1]
        by_window = solve_triangular(np.linalg.cholesky(self.windows), rhs.reshape(n, 3 * k), lower=True,
                                     check_finite=False)
        by_axis = by_window.reshape(n, 3, k).transpose(1, 0, 2).reshape(3, n * k)
        out = solve_triangular(np.linalg.cholesky(self.axes), by_axis, lower=True, check_finite=False)
        return out.reshape(3, n, k).transpose(1, 0, 2).reshape(3 * n, k)


def _whiten(covariance, rhs: np.ndarray) -> np.ndarray:
    """L⁻¹ · rhs, L the Cholesky factor of ``covariance`` (a matrix or a KroneckerCovariance),
    by forward substitution (np.linalg.solve would factor the triangle again by LU, a cubic cost
    that was a fifth of `fieldcal plan`'s CPU). Imported here: crb reaches paths (the solvers'
    end bias) that need no whitening."""
    if isinstance(covariance, KroneckerCovariance):
        return covariance.whiten(rhs)
    from scipy.linalg import solve_triangular

    return solve_triangular(np.linalg.cholesky(covariance), rhs, lower=True, check_finite=False)


# The rank rule: which parameters the data determine. Judged on the whitened Jacobian with its
# columns scaled to unit length (each parameter's information on its own is then 1, whatever its
# unit), whose singular values s say how much the data see of each direction of the parameters.
# A direction with s below RANK_TOL of the largest is one the data do not see: its information is
# numerically nil, not small. The threshold sits two decades above what rounding puts on such a
# direction (JACOBIAN_ROUNDING: the central differences' relative error, ε over the 1e-6 step;
# the near-singular designs of a planned run's first positions show them at 1e-11 to 1e-16) and
# three below the weakest direction a design does determine (a gyro's misalignments seen through
# the Earth rate alone, ~3e-5 at a planned run's sixth position).
RANK_TOL = 1e-8
JACOBIAN_ROUNDING = 2e-10
# When the equilibrated information's inverse has a trace under this, its smallest eigenvalue is
# above 1/trace (so every s/s_max ≥ 1/sqrt(p·1e10), well over RANK_TOL) and the inverse from its
# Cholesky factor is accurate; otherwise the singular value decomposition decides and inverts.
_CHOLESKY_TRACE = 1e10


@dataclass(frozen=True)
class _Information:
    """The inverse of the information (in the Jacobian's per-step units) where it is defined:
    ``inverse`` (p × p) is the Moore-Penrose one on the directions the data see; ``null`` (k × p,
    rows) the directions they do not, in the unit-column coordinates ``scale`` gives (y = scale ⊙ u),
    and ``tolerance`` the share of a functional in them that rounding alone can put there."""

    inverse: np.ndarray
    scale: np.ndarray
    null: np.ndarray
    tolerance: float

    def undetermined(self, rows: np.ndarray) -> np.ndarray:
        """Which linear functionals (rows (m, p) on the per-step parameters) the data cannot tell:
        those with more than ``tolerance`` of their (unit-coordinate) length in a null direction."""
        if not len(self.null):
            return np.zeros(len(rows), dtype=bool)
        unit = rows / self.scale
        length = np.sum(unit**2, axis=1)
        share = np.sum((unit @ self.null.T) ** 2, axis=1)
        return share > self.tolerance * np.where(length > 0, length, 1.0)


def _information(Jw: np.ndarray) -> _Information:
    """``_Information`` of the whitened Jacobian ``Jw`` (data × p) under the rank rule above."""
    from scipy.linalg import lapack

    p = Jw.shape[1]
    scale = np.linalg.norm(Jw, axis=0)
    scale = np.where(scale > 0, scale, 1.0)  # a parameter the data never see: a zero column, null
    unit = Jw / scale
    # LAPACK's Cholesky factor and the inverse from it (potrf, potri: the lower triangle), a
    # quarter of the time of a triangular solve on the identity and its product.
    root, failed = lapack.dpotrf(unit.T @ unit, lower=1)
    if not failed:  # else not numerically positive definite: the decomposition decides
        lower, failed = lapack.dpotri(root, lower=1)
        inverse = np.tril(lower) + np.tril(lower, -1).T
        if not failed and np.trace(inverse) <= _CHOLESKY_TRACE:
            return _Information(inverse / np.outer(scale, scale), scale, np.zeros((0, p)), 0.0)
    _, s, vt = np.linalg.svd(unit)  # vt (p × p): directions past the rank have no s, that is 0
    s = np.r_[s, np.zeros(p - len(s))]
    seen = s > RANK_TOL * s[0]
    kept = vt[seen] / s[seen, None]
    # Wedin: the null directions found lean into the seen ones by at most the rounding over the
    # gap to the smallest seen s, so a functional truly outside them shows at most its square.
    gap = s[seen][-1] / s[0] if seen.any() else 1.0
    return _Information((kept.T @ kept) / np.outer(scale, scale), scale, vt[~seen],
                        (JACOBIAN_ROUNDING / gap) ** 2)


def _undetermined_to_inf(matrix: np.ndarray, undetermined: np.ndarray) -> np.ndarray:
    """``matrix`` (a covariance) with what the data cannot tell blanked: those rows and columns
    nan, their variances inf (σ infinite: not yet determined)."""
    if not undetermined.any():
        return matrix
    out = matrix.copy()
    out[undetermined, :] = np.nan
    out[:, undetermined] = np.nan
    out[undetermined, undetermined] = np.inf
    return out


def _bound(mean_fn, x0: np.ndarray, steps: np.ndarray, covariance, end: EndBias | None = None,
           wanted: int = N_PARAMS):
    """``mean_fn`` maps rows of parameters (m, p) to rows of the data's means (m, data): the
    Jacobian's 2p central differences are one call. A parameter the data cannot tell apart
    (the rank rule above) has an infinite variance, never a large finite one."""
    shifts = np.diag(steps)
    means = mean_fn(np.concatenate([x0 + shifts, x0 - shifts]))
    p = len(x0)
    J = ((means[:p] - means[p:]) / (2 * steps)[:, None]).T * steps  # derivatives per step: columns of comparable size
    # J and the cross-covariance whitened in one call
    whitened = _whiten(covariance, J if end is None else np.concatenate([J, end.cross], axis=1))
    Jw = whitened[:, :len(x0)]
    information = _information(Jw)
    info_inv = information.inverse
    bound = _undetermined_to_inf(info_inv[:wanted, :wanted] * np.outer(steps[:wanted], steps[:wanted]),
                                 information.undetermined(np.eye(p)[:wanted]))
    if end is None:
        return bound
    # Goldberger's BLUP of E·x + (K·bias process at the end), x = steps ⊙ u: with the whitened
    # cross-covariance Gw, error = V − GwᵀGw + (E − GwᵀJw)·I⁻¹·(E − GwᵀJw)ᵀ. The constant's own
    # estimate E·I⁻¹·Jwᵀ·w has error E I⁻¹ Eᵀ − E I⁻¹ Jwᵀ Gw − (…)ᵀ + V.
    Gw = whitened[:, len(x0):]
    E = np.zeros((3, len(x0)))
    E[np.arange(3), np.arange(3)] = steps[:3]
    lead = E - Gw.T @ Jw
    predicted = end.point - Gw.T @ Gw + lead @ info_inv @ lead.T
    shared = E @ info_inv @ Jw.T @ Gw
    constant = E @ info_inv @ E.T - shared - shared.T + end.point
    return bound, EndBiasBound(_undetermined_to_inf(predicted, information.undetermined(lead)),
                               _undetermined_to_inf(constant, information.undetermined(E)))


def _param_steps(theta: np.ndarray, reference: float) -> np.ndarray:
    k = np.abs(theta[3:6])
    return 1e-6 * np.r_[k * reference, k, np.ones(3)]


def _with_thermal(mean, x0, steps, thermal: ThermalTerms | None, bias_step: np.ndarray):
    """(mean, x0, steps, parameters wanted) with the thermal terms after the nine, if any."""
    if thermal is None:
        return mean, x0, steps, N_PARAMS
    return (thermal.apply(mean), np.r_[x0[:N_PARAMS], thermal.start(), x0[N_PARAMS:]],
            np.r_[steps[:N_PARAMS], thermal.steps(bias_step), steps[N_PARAMS:]], N_PARAMS + thermal.count)


def specific_force_bound(theta, up_body: np.ndarray, gravity: float, covariance, end: EndBias | None = None,
                         thermal: ThermalTerms | None = None):
    """Bound for static averages K·g·d_i + b, d_i the true up direction in body axes; with
    ``end``, (bound, EndBiasBound); with ``thermal``, of the thermal model too."""
    up_body = np.asarray(up_body, dtype=float)
    n = len(up_body)
    perturbed = _perturber(up_body)

    def mean(x):
        d = perturbed(x[:, N_PARAMS:].reshape(len(x), n, 2))
        return _distorted(x[:, :N_PARAMS], gravity * d).reshape(len(x), -1)

    x0 = np.r_[theta, np.zeros(2 * n)]
    steps = np.r_[_param_steps(theta, gravity), np.full(2 * n, 1e-6)]
    mean, x0, steps, wanted = _with_thermal(mean, x0, steps, thermal, _param_steps(theta, gravity)[:3])
    return _bound(mean, x0, steps, covariance, end, wanted)


def angular_rate_bound(theta, axis_body: np.ndarray, table_rate: np.ndarray, north_body: np.ndarray,
                       earth_rate: float, latitude_rad: float, covariance, turning=None,
                       end: EndBias | None = None, thermal: ThermalTerms | None = None):
    """Bound for per-position +ω, −ω and static averages (data order: all +, all −, all static).

    axis_body: true table axis (local up) in body axes per position; north_body: true horizontal
    direction of the Earth rate in body axes during each static dwell; turning: the indices of
    the positions with a rate step, in order (default: every position), and table_rate one rate
    for them all or one each. With ``end``, (bound, EndBiasBound); with ``thermal`` (its
    ``delta_t`` in the same data order), of the thermal model too.
    """
    axis_body = np.asarray(axis_body, dtype=float)
    n = len(axis_body)
    turning = np.arange(n) if turning is None else np.asarray(turning, dtype=int)
    rate = np.broadcast_to(np.asarray(table_rate, dtype=float), (len(turning),))
    vertical, horizontal = earth_rate * np.sin(latitude_rad), earth_rate * np.cos(latitude_rad)

    # A position without a rate step sees only the Earth rate, in a direction its placement
    # leaves free: two angles about the nominal one (a third would be unidentifiable).
    resting = np.setdiff1d(np.arange(n), turning)
    axis_t, north_t = axis_body[turning], north_body[turning]
    up_r, north_r = axis_body[resting], north_body[resting]
    north_r = north_r - np.einsum("ij,ij->i", north_r, up_r)[:, None] * up_r
    earth_r = vertical * up_r + horizontal * north_r / np.linalg.norm(north_r, axis=1, keepdims=True)
    earth_r /= np.linalg.norm(earth_r, axis=1, keepdims=True)
    k = len(turning)
    turning_axis, resting_earth = _perturber(axis_t), _perturber(earth_r)

    def mean(x):
        m = len(x)
        theta_, nuis = x[:, :N_PARAMS], x[:, N_PARAMS:N_PARAMS + 3 * k].reshape(m, k, 3)
        d = turning_axis(nuis[..., :2])
        # Heading: rotate the true north direction about d by the third nuisance angle.
        north = north_t - np.einsum("ij,mij->mi", north_t, d)[..., None] * d
        north /= np.linalg.norm(north, axis=-1, keepdims=True)
        north = np.cos(nuis[..., [2]]) * north + np.sin(nuis[..., [2]]) * _cross(d, north)
        plus = _distorted(theta_, (rate + vertical)[:, None] * d)
        minus = _distorted(theta_, (-rate + vertical)[:, None] * d)
        seen = np.empty((m, n, 3))
        seen[:, turning] = vertical * d + horizontal * north
        if len(resting):
            seen[:, resting] = earth_rate * resting_earth(x[:, N_PARAMS + 3 * k:].reshape(m, -1, 2))
        static = _distorted(theta_, seen)
        return np.concatenate([plus.reshape(m, -1), minus.reshape(m, -1), static.reshape(m, -1)], axis=1)

    count = 3 * k + 2 * len(resting)
    x0 = np.r_[theta, np.zeros(count)]
    steps = np.r_[_param_steps(theta, float(np.mean(rate))), np.full(count, 1e-6)]
    mean, x0, steps, wanted = _with_thermal(mean, x0, steps, thermal, steps[:3])
    return _bound(mean, x0, steps, covariance, end, wanted)
