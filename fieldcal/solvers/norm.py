"""The norm method (paper eqs. 17-18) solved with Powell's method, and a least-squares cross-check.

Both solvers minimise the same weighted sum of squared norm residuals. The weights come from the
covariance of the averages, propagated through the residuals at the starting point; the search
runs in coordinates whitened by the Jacobian there, so Powell's initial direction set is already
conjugate and raw-count devices (b ≈ 32768, k ≈ 415 count per m/s²) need no hand-tuned start.
"""
from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
from scipy.linalg import blas, lapack
from scipy.special import chdtrc  # χ² survival function; scipy.stats would cost ~0.4 s to import

from fieldcal.calibration import Calibration, SolverDiagnostics
from fieldcal.model import N_PARAMS, PARAM_NAMES
from fieldcal.solvers.ellipsoid import DegenerateError

METHODS = ("powell", "lsq")
# A parameter known no better than this fraction of its natural scale (|K|·reference for a bias,
# k for a scale factor, 1 rad for an angle) means the positions do not determine it.
_DEGENERATE_FRACTION = 0.01
_GEOMETRY_RATIO = 1e-4
# Powell searches in whitened coordinates z whose unit is about one standard deviation of the
# solution, so its tolerances are fractions of σ. Each line search is bounded (scipy then runs a
# bounded Brent search with an absolute tolerance in z, where its unbounded search tolerates a
# fraction of the step and so spends ~30 evaluations confirming that a converged direction has
# nothing left); the search stops when an iteration improves χ² by less than _STOP_DECREASE, the
# square of a move of 3e-4 σ. The box is far wider than any start-to-optimum distance; a solution
# near its edge is searched again without it.
_LINE_TOL_SIGMA = 1e-4
_STOP_DECREASE = 1e-7
_BOX_SIGMA = 100.0
# Not a user's method: the least χ² a set of averages allows, found by Gauss-Newton from the same
# start, to choose among pose sets (recording.pose_choice.choose_poses) before one solve by the
# method asked for. It finds the same minimum as Powell at a quarter of the cost (1.5 ms against
# 6.9 ms a pose set of imu_tk's recording, the solve's set-up included); scipy's
# least_squares costs as much as Powell on these problems, and its Levenberg-Marquardt stops
# about 0.04σ short of the minimum on imu_tk's recording.
SCREEN = "gauss-newton"
# A step this small (in σ of the solution) ends the iteration: Powell's line tolerance. The
# residuals' rounding (raw counts near 32768) moves a converged iteration by some 1e-5 σ.
_SCREEN_STEP_SIGMA = _LINE_TOL_SIGMA
_SCREEN_ITERATIONS = 20


class CalibrationError(ValueError):
    """The averages cannot give a calibration; the message says why and what would help."""


def _jacobian(fun, x: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """Central differences; fun takes a stack of points (..., n) and returns (..., m)."""
    shifts = np.diag(steps)
    values = fun(np.concatenate([x + shifts, x - shifts]))
    return ((values[:len(steps)] - values[len(steps):]) / (2 * steps)[:, None]).T


def _natural_scales(problem, theta: np.ndarray) -> np.ndarray:
    """Size of each parameter's natural unit: |K|·reference for biases, k for scales, 1 rad."""
    k = np.abs(theta[3:6])
    return np.r_[k * problem.reference_scale, k, np.ones(3)]


def _forward_jacobian(fun, x: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """Forward differences; fun takes a stack of points (..., n) and returns (..., m)."""
    values = fun(np.vstack([x, x + np.diag(steps)]))
    return ((values[1:] - values[0]) / steps[:, None]).T


class Whitener:
    """r ↦ L⁻¹r for residuals r (..., m), with L Lᵀ = G Σ Gᵀ the residuals' covariance at the start
    (G = ∂r/∂u). Independent residuals (a diagonal G Σ Gᵀ) are scaled one by one: no m×m matrix."""

    def __init__(self, inverse_sigma: np.ndarray | None = None, inverse_factor: np.ndarray | None = None):
        self.inverse_sigma, self.inverse_factor = inverse_sigma, inverse_factor

    def __call__(self, r: np.ndarray) -> np.ndarray:
        if self.inverse_sigma is not None:
            return r * self.inverse_sigma
        assert self.inverse_factor is not None  # one of the two is always given
        if r.ndim == 1 and self.inverse_factor.flags.f_contiguous:
            # L⁻¹ is lower triangular: its product with one point's residuals (Powell evaluates
            # one at a time, ~170 of them a solve) reads and multiplies half the matrix.
            return blas.dtrmv(self.inverse_factor, r, lower=1)
        return r @ self.inverse_factor.T

    def matrix(self) -> np.ndarray:
        """L⁻¹ itself (m, m), for a check."""
        if self.inverse_sigma is not None:
            return np.diag(self.inverse_sigma)
        assert self.inverse_factor is not None  # one of the two is always given
        return self.inverse_factor


def _residual_covariance(problem, theta0, u, cov) -> np.ndarray:
    """G Σ Gᵀ: (m,) when it is diagonal, else (m, m). A problem whose every residual depends on one
    average of three numbers alone (``point_gradients``: each residual's (3,) gradient) has a G of
    1×3 blocks on the diagonal, so G Σ Gᵀ costs 9 products per pair of averages and, with Σ given
    per average and axis, is diagonal; any other problem's G comes by forward differences."""
    gradients = getattr(problem, "point_gradients", None)
    if gradients is not None:
        g = gradients(theta0)  # (n, 3)
        if cov.ndim == 2 and cov.shape[1] == 3 and cov.shape[0] == len(g):  # per-average, per-axis 1σ
            return np.einsum("ia,ia->i", g**2, cov**2)
        n = len(g)
        return np.einsum("ia,iajb,jb->ij", g, cov.reshape(n, 3, n, 3), g, optimize=True)
    if cov.shape == (len(u) // 3, 3):
        cov = np.diag(cov.ravel() ** 2)
    steps = 1e-6 * np.maximum(np.abs(u), np.abs(theta0[3:6]).max() * problem.reference_scale)
    # Forward differences: the residuals are smooth in u and only weights depend on G.
    G = _forward_jacobian(lambda x: problem.residuals(theta0, x), u, steps)
    return G @ cov @ G.T


def _residual_whitener(problem, theta0, covariance) -> Whitener | None:
    """The whitening of the residuals at the start (see Whitener), or None without a covariance."""
    if covariance is None:
        return None
    u = problem.data
    by_parts = getattr(covariance, "residual_covariance", None)  # a covariance kept by its parts
    if by_parts is not None and hasattr(problem, "point_gradients"):
        return _whitener_of(problem, by_parts(problem.point_gradients(theta0)))
    cov = np.asarray(covariance.dense() if by_parts is not None else covariance, dtype=float)
    if cov.shape != (len(u), len(u)) and cov.shape != (len(u) // 3, 3):
        raise ValueError(f"{problem.name}: covariance must be ({len(u)}, {len(u)}) or "
                         f"({len(u) // 3}, 3) sigmas, got {cov.shape}")
    return _whitener_of(problem, _residual_covariance(problem, theta0, u, cov))


def _whitener_of(problem, S: np.ndarray) -> Whitener:
    """The whitening of residuals of covariance S: (m,) diagonal, or (m, m)."""
    if S.ndim == 1:
        if not np.all(S > 0):
            raise CalibrationError(f"{problem.name}: the covariance of the averages is not positive definite")
        return Whitener(inverse_sigma=1.0 / np.sqrt(S))
    # In Fortran order, factored and inverted in place by LAPACK (the triangular inverse: a third
    # of a general one's work), L⁻¹ ready for BLAS's triangular product (Whitener.__call__).
    L, info = lapack.dpotrf(np.asfortranarray(S, dtype=float), lower=1, clean=1, overwrite_a=1)
    if info == 0:
        inverse, info = lapack.dtrtri(L, lower=1, overwrite_c=1)
    if info != 0:
        raise CalibrationError(f"{problem.name}: the covariance of the averages is not positive definite")
    return Whitener(inverse_factor=inverse)


def solve_norm(problem, covariance=None, method: str = "powell") -> Calibration:
    """Solve one triad's norm equations.

    ``covariance`` is that of ``problem.data`` (the averages, flattened), or an (n, 3) array of
    each average's per-axis 1σ; without it every residual weighs the same and the uncertainty
    comes from the residual scatter alone.
    """
    if method not in METHODS + (SCREEN,):
        raise ValueError(f"method: expected one of {', '.join(METHODS)}, got {method!r}")
    n_resid = len(problem.residual_labels)
    if n_resid < N_PARAMS:
        raise CalibrationError(f"{problem.name}: {n_resid} equations for {N_PARAMS} unknowns; "
                               f"add at least {N_PARAMS - n_resid} more positions")
    if covariance is None and n_resid == N_PARAMS:
        raise CalibrationError(f"{problem.name}: {N_PARAMS} equations fit exactly and leave no "
                               "scatter to estimate the uncertainty; add a position or give σ")
    try:
        theta0 = problem.initial()
    except DegenerateError as exc:
        raise CalibrationError(f"{problem.name}: positions are degenerate: {exc}") from None
    whitener = _residual_whitener(problem, theta0, covariance)
    u = problem.data

    residuals_at = problem.residual_function(u)

    def whitened(theta):  # theta (9,) or a stack (k, 9)
        r = residuals_at(theta)
        return r if whitener is None else whitener(r)

    natural = _natural_scales(problem, theta0)
    # Geometry first, independent of the noise: relative residual per natural unit of each
    # parameter. Well-spread positions give a smallest-to-largest singular value ratio near 0.2;
    # six axis-aligned directions (the classic test) give about 1e-6.
    J_geometry = _jacobian(lambda th: residuals_at(th) / problem.reference_scale, theta0,
                           1e-7 * natural) * natural
    sv = np.linalg.svd(J_geometry, compute_uv=False)
    if sv[-1] < _GEOMETRY_RATIO * sv[0]:
        raise CalibrationError(f"{problem.name}: positions are degenerate (condition number "
                               f"{sv[0] / sv[-1]:.3g}); {_spread_hint(problem)}")
    J0 = _jacobian(whitened, theta0, 1e-7 * natural) * natural
    # Search in z with theta = theta0 + natural * R⁻¹ z, where J0 = Q R: locally ‖r‖² ≈ ‖z − z*‖².
    Q, R = np.linalg.qr(J0)
    to_theta = natural[:, None] * np.linalg.inv(R)

    def from_z(z):
        return theta0 + to_theta @ z

    if method == "powell":
        # Start from the Gauss-Newton step of the linearisation already at hand (Q is ∂r/∂z).
        res = _powell(lambda z: whitened(from_z(z)), -Q.T @ whitened(theta0),
                      per_sigma=whitener is not None, dof=n_resid - N_PARAMS)
        iterations, evaluations = int(res.nit), int(res.nfev)
    elif method == SCREEN:
        res = _gauss_newton(lambda z: whitened(theta0 + z @ to_theta.T), -Q.T @ whitened(theta0),
                            per_sigma=whitener is not None, dof=n_resid - N_PARAMS)
        iterations, evaluations = int(res.nit), int(res.nfev)
    else:
        from scipy import optimize  # only the searches that use it pay for its import (see _powell)
        res = optimize.least_squares(lambda z: whitened(from_z(z)), np.zeros(N_PARAMS), method="lm",
                                     xtol=1e-12, ftol=1e-12)
        iterations, evaluations = int(res.nfev), int(res.nfev)
    if not res.success:
        raise CalibrationError(f"{problem.name}: {method} did not converge ({res.message})")
    theta = from_z(res.x)
    r_w = whitened(theta)
    chi2 = float(r_w @ r_w)
    dof = n_resid - N_PARAMS
    J = _jacobian(whitened, theta, 1e-7 * natural) * natural
    sv = np.linalg.svd(J, compute_uv=False)
    cov_natural = np.linalg.inv(J.T @ J)
    scaled = whitener is None
    if whitener is not None and dof > 0 and chdtrc(dof, chi2) < 1e-3:
        scaled = True  # the scatter is well beyond the stated noise: trust the scatter (Birge)
    if scaled:
        cov_natural *= chi2 / dof
    sigma_natural = np.sqrt(np.diag(cov_natural))
    worst = int(np.argmax(sigma_natural))
    if sigma_natural[worst] > _DEGENERATE_FRACTION:
        raise CalibrationError(
            f"{problem.name}: positions are degenerate: {PARAM_NAMES[worst]} is determined only to "
            f"±{sigma_natural[worst]:.2g} of its scale (condition number {sv[0] / sv[-1]:.3g}); "
            f"{_spread_hint(problem)}")
    return Calibration(  # a screening's is a least-squares solution too; its search says how it was found
        name=problem.name, kind=problem.kind, output_unit=problem.output_unit,
        method="lsq" if method == SCREEN else method,
        theta=theta, covariance=cov_natural * np.outer(natural, natural),
        residuals=problem.residuals(theta, u), residual_labels=problem.residual_labels,
        diagnostics=SolverDiagnostics(
            iterations=iterations, evaluations=evaluations, converged=bool(res.success),
            message=str(res.message), search=method, chi2=chi2, dof=dof, scaled_by_residuals=scaled,
            condition_number=float(sv[0] / sv[-1])))


def _powell(residuals_of_z, z_start: np.ndarray, per_sigma: bool, dof: int):
    """Powell's method on ‖r(z)‖², tolerances in σ of the solution (see _LINE_TOL_SIGMA).

    With weights (per_sigma) a unit of z is 1σ; without, the residuals keep their own unit, and σ
    in z is the residual scatter: the directions, box and objective are scaled by it (the same
    minimum).
    """
    f_start = float(np.sum(residuals_of_z(z_start) ** 2))
    scale = 1.0 if per_sigma or dof <= 0 or f_start <= 0 else f_start / dof
    sigma_z = math.sqrt(scale)

    def chi2(z):
        r = residuals_of_z(z)
        return float(r @ r) / scale

    options = {"direc": sigma_z * np.eye(N_PARAMS), "xtol": _LINE_TOL_SIGMA, "maxfev": 5000,
               "ftol": _STOP_DECREASE / max(f_start / scale, 1.0)}
    box = np.column_stack([z_start - _BOX_SIGMA * sigma_z, z_start + _BOX_SIGMA * sigma_z])
    # scipy.optimize is imported here, not with the module: ~0.2 s of CPU beyond scipy.linalg and
    # scipy.special, which what solves without a search (a sub-model, rests only; the live engine
    # until it solves) does not pay.
    from scipy import optimize
    res = optimize.minimize(chi2, z_start, method="Powell", bounds=box, options=options)
    if res.success and np.max(np.abs(res.x - z_start)) > 0.5 * _BOX_SIGMA * sigma_z:
        res = optimize.minimize(chi2, res.x, method="Powell", options=options)
    return res


def _gauss_newton(residuals_of_z, z: np.ndarray, per_sigma: bool, dof: int) -> SimpleNamespace:
    """Gauss-Newton on ‖r(z)‖² from z (residuals_of_z takes a stack of points), the Jacobian by
    central differences in one evaluation of the stack. Fails (success False) when a step does
    not lower χ² or the steps do not shrink below _SCREEN_STEP_SIGMA (solve_norm then raises
    CalibrationError, and choose_poses solves that set by the method asked for instead). The unit
    of σ in z as in _powell. Its result has the fields solve_norm reads of scipy's OptimizeResult
    (x, success, nit, nfev, message), without importing scipy.optimize for a search it does not use."""
    r = residuals_of_z(z)
    f = float(r @ r)
    sigma_z = 1.0 if per_sigma or dof <= 0 or f <= 0 else math.sqrt(f / dof)
    steps = np.full(len(z), 1e-4 * sigma_z)
    evaluations = 1
    for iteration in range(1, _SCREEN_ITERATIONS + 1):
        J = _jacobian(residuals_of_z, z, steps)
        step = np.linalg.lstsq(J, -r, rcond=None)[0]
        r_new = residuals_of_z(z + step)
        f_new = float(r_new @ r_new)
        evaluations += 2 * len(z) + 1
        if np.max(np.abs(step)) < _SCREEN_STEP_SIGMA * sigma_z:  # χ² then changes by rounding only
            return SimpleNamespace(x=z + step if f_new <= f else z, success=True, nit=iteration,
                                   nfev=evaluations, message="the Gauss-Newton step is below 1e-4 σ")
        if not f_new <= f * (1 + 1e-9):
            return SimpleNamespace(x=z, success=False, nit=iteration, nfev=evaluations,
                                   message="a Gauss-Newton step did not lower χ²")
        z, r, f = z + step, r_new, f_new
    return SimpleNamespace(x=z, success=False, nit=_SCREEN_ITERATIONS, nfev=evaluations,
                           message=f"no convergence in {_SCREEN_ITERATIONS} Gauss-Newton steps")


def _spread_hint(problem) -> str:
    """How many distinct axes the measured directions span, for the operator."""
    directions = problem.directions()
    axes: list[np.ndarray] = []
    for d in directions:  # a few dozen positions at most
        if all(abs(d @ a) < math.cos(math.radians(10)) for a in axes):
            axes.append(d)
    return (f"{len(directions)} measurements point along only {len(axes)} distinct axes (10° apart); "
            "add positions with an axis between the cube faces (paper Table 2, positions 13-18)")
