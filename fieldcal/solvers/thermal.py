"""A triad's thermal model fitted jointly with its norm calibration (issue 28).

Each average u_i of a norm problem (``fieldcal.solvers.problems``) is tagged with the unit's mean
temperature T_i over its window. The model of ``fieldcal.thermal`` says

    u_i = diag(r_i)·K·a_i + b₀ + o_i,   o_i = Σₖ bₖ ΔT_iᵏ,  r_i = 1 + s₁ΔT_i,  ΔT_i = T_i − T_ref

so the averages the unit would have given at T_ref are u'_i = (u_i − b₀ − o_i)/r_i + b₀, and the
problem's own residuals of (θ, u') are the joint model's residuals exactly. One least-squares
solve over θ and the thermal terms together, weighted as the norm solve is (the problem's residual
covariance at the start), gives their joint covariance: the σ of K and b include what the thermal
terms take from them, and the thermal terms' σ what the geometry leaves them. Why joint rather
than a second stage: a second stage on the first stage's residuals would treat θ as exact, and
its bias terms are correlated with b₀ (both move the same averages), so its σ would be too small.

The scale drift s₁ is in every model when the equations leave room for it at order 0. The order
of the bias polynomial is chosen from the data: order k+1 is kept if its three coefficients lower
χ² by more than the 99 % point of χ² with 3 degrees of freedom (a likelihood-ratio test), or if
leaving them out would move any parameter of order k by more than half its σ (a term weak in χ²
but correlated with the others biases them if omitted), while the unknowns do not outnumber the
equations: the noise is known, so σ comes from the information, not from the residuals, and an
exactly determined model (an accelerometer's 18 norms beside a quadratic bias and the drift) has
honest σ, though no χ² to check them by. Such an exact fit may find no parameters that reproduce
the averages and stop on a fold of the model, where JᵀJ is singular (issue 26): it is known by the
χ² it leaves, its σ come from the observed information (the Hessian of ½χ²), and it is kept only
if Akaike's criterion prefers it to the order below.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import cast

import numpy as np
from scipy import optimize
from scipy.special import chdtrc

from fieldcal.calibration import Calibration, SolverDiagnostics
from fieldcal.model import N_PARAMS
from fieldcal.solvers.ellipsoid import DegenerateError
from fieldcal.solvers.norm import (CalibrationError, Whitener, _forward_jacobian, _natural_scales,
                                   _residual_whitener, _whitener_of)
from fieldcal.thermal import MAX_ORDER, ThermalModel

# χ²₃ 99 % point: scipy.stats.chi2.ppf(0.99, 3) (scipy.stats stays out of the solvers' imports)
ORDER_TEST_CHI2 = 11.344866730144373
# A lower order is kept only if the next order's terms move none of its parameters by more than
# this many of its σ (see ``better`` in solve_thermal_norm).
MAX_OMISSION_SHIFT_SIGMA = 0.5
# The least singular value of the whitened Jacobian, relative to the largest, below which a
# candidate's parameters are not determined by the windows (an order is then no candidate).
UNDETERMINED = 1e-10
# The χ² (in noise variances) an exact fit may leave and still reproduce the averages. With as
# many unknowns as equations, a least-squares minimum that leaves residuals has Jᵀr = 0 with
# r ≠ 0, so its Jacobian is singular: no parameters reproduce the averages near there and the fit
# has stopped on a fold of the model, where the Gauss-Newton information JᵀJ is singular and the
# condition number computed from it is set by rounding, not by the data (issue 26: seed 380's
# inclinometer, condition 5e10 there and 2e7-3e8 with its temperatures × 1 ± 1e-13). An exact
# fit found leaves 1e-23 to 1e-21 (benchmarks/thermal.py seeds 101-149), a fold 0.1 to 1.2.
EXACT_FIT_CHI2 = 1e-6
_BIRGE_P = 1e-3  # as solve_norm: a χ² this improbable means the scatter, not the model, sets σ
_SQRT_EPS = float(np.sqrt(np.finfo(float).eps))  # scipy's relative step of '2-point' differences


@dataclass(frozen=True)
class ThermalFit:
    """The joint solution, with χ² per order tried (the evidence for the order chosen), and the
    joint covariance of all its parameters: the nine, then b₁ x, y, z, …, then s₁ x, y, z (the
    calibration keeps the nine's block, the thermal model the others' σ; a χ² of the whole fit
    against a truth needs the correlations between them)."""

    calibration: Calibration
    chi2_by_order: dict[int, float]
    covariance: np.ndarray | None = None


def _layout(order: int, scale: bool) -> int:
    return N_PARAMS + 3 * order + (3 if scale else 0)


def _observed_information(fun, x: np.ndarray, J: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """The Hessian of ½χ² at x, JᵀJ + Σᵢ rᵢ∇²rᵢ (the second term by second differences of r(x)·r):
    at a fold JᵀJ is singular and the residuals' curvature along the fold determines the estimate.
    ``fun`` takes a stack of points: the 4 per pair of parameters are evaluated in one call."""
    r = fun(x)
    p = len(x)
    E = np.diag(steps)
    j, k = np.triu_indices(p)
    # the four corners of each pair's square: +j+k, +j−k, −j+k, −j−k
    corners = np.stack([E[j] + E[k], E[j] - E[k], E[k] - E[j], -E[j] - E[k]])
    weighted = (fun(x + corners.reshape(-1, p)) @ r).reshape(4, -1)
    curvature = np.empty((p, p))
    curvature[j, k] = curvature[k, j] = (weighted[0] - weighted[1] - weighted[2] + weighted[3]) / (4 * steps[j] * steps[k])
    return J.T @ J + curvature


def _condition_number(candidate) -> float:
    """How well a candidate's parameters are determined: the largest over the least singular value
    of J for a solution, of the observed information's square root for a fold (inf: singular)."""
    J, information, fold = candidate[4], candidate[6], candidate[7]
    if not fold:
        sv = np.linalg.svd(J, compute_uv=False)
        least, largest = sv[-1], sv[0]
    else:
        eig = np.linalg.eigvalsh(information)
        least, largest = np.sqrt(max(eig[0], 0.0)), np.sqrt(eig[-1])
    return float(largest / least) if least > 0 else np.inf


def _undetermined(candidate) -> str | None:
    """Why the windows do not determine a candidate's parameters (None: they do): its information
    singular to within UNDETERMINED (on J itself for a solution, on the observed information for
    a fold)."""
    condition = _condition_number(candidate)
    if not condition < 1 / UNDETERMINED:
        return f"condition number {condition:.3g}" + (", at a fold" if candidate[7] else "")
    return None


def _central_jacobian(fun, x: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """∂fun/∂x by central differences, one column per parameter; ``fun`` takes a stack of points
    and evaluates all 2p of them in one call."""
    shifts = np.diag(steps)
    values = fun(np.concatenate([x + shifts, x - shifts]))
    return ((values[:len(steps)] - values[len(steps):]) / (2 * steps)[:, None]).T


def _forward_jacobian_of_lm(fun, z: np.ndarray) -> np.ndarray:
    """The Jacobian scipy's least_squares takes by its default '2-point' differences (its step
    rule: √ε·max(1, |z|), signed as z, its step z + h − z), its p + 1 points evaluated in one call
    of ``fun`` on their stack instead of one call each (the Levenberg-Marquardt iterations' cost)."""
    h = _SQRT_EPS * np.where(z >= 0, 1.0, -1.0) * np.maximum(1.0, np.abs(z))
    shifted = z + np.diag(h)
    values = fun(np.vstack([z, shifted]))
    return ((values[1:] - values[0]) / (np.diag(shifted) - z)[:, None]).T


def _residual_covariance_at(problem, theta: np.ndarray, u: np.ndarray, covariance) -> np.ndarray:
    """G Σ Gᵀ with G = ∂r/∂u at (θ, u) by forward differences (u: the averages at T_ref): (m, m), or
    its diagonal (m,) when that is all there is."""
    cov = covariance.dense() if hasattr(covariance, "dense") else np.asarray(covariance, dtype=float)
    variances = cov.ravel() ** 2 if cov.shape == (len(u) // 3, 3) else None  # per-average, per-axis 1σ
    steps = 1e-6 * np.maximum(np.abs(u), np.abs(theta[3:6]).max() * problem.reference_scale)
    G = _forward_jacobian(lambda x: problem.residuals(theta, x), u, steps)
    if variances is not None and G.shape[0] == G.shape[1] and not np.any(G[~np.eye(len(G), dtype=bool)]):
        # each residual moves with one number of the data (a held pose's u − c): G Σ Gᵀ is the
        # diagonal (m,), the same numbers without two m³ products (m = 606 for 200 windows)
        g = np.diag(G)
        return (g * variances) * g
    return G @ (np.diag(variances) if variances is not None else cov) @ G.T


def _one_by_one(whitener: Whitener) -> Whitener:
    """The same whitening, by one scale per residual when L⁻¹ is diagonal: a held pose's residuals
    (u − c, ``fieldcal.solvers.held``) each move with one number of the data, and the m×m products
    were most of its fit's CPU (606 residuals for a PX4 log's 200 windows); the same numbers."""
    factor = whitener.inverse_factor
    if factor is None or np.any(factor[~np.eye(len(factor), dtype=bool)]):
        return whitener
    return Whitener(inverse_sigma=np.diag(factor).copy())


def _split(x: np.ndarray, order: int, scale: bool):
    """θ, the bias terms (order, 3) and the drift (3,) of x, or of each row of a stack x (..., p)."""
    theta = x[..., :N_PARAMS]
    terms = x[..., N_PARAMS:N_PARAMS + 3 * order].reshape(*x.shape[:-1], order, 3)
    drift = x[..., N_PARAMS + 3 * order:] if scale else np.zeros(3)
    return theta, terms, drift


def _corrected(u_points: np.ndarray, dt: np.ndarray, theta, terms, drift, powers=None) -> np.ndarray:
    """The averages at T_ref: (u − b₀ − Σ bₖ ΔTᵏ)/(1 + s₁ΔT) + b₀, flattened (per row of a stack
    of θ, terms and drift); ``powers``: ΔTᵏ (n, order), worked out once per fit."""
    if powers is None:
        powers = dt[:, None] ** np.arange(1, terms.shape[-2] + 1)
    offset = powers @ terms
    b0 = theta[..., None, :3]
    corrected = (u_points - b0 - offset) / (1.0 + dt[:, None] * drift[..., None, :]) + b0
    return corrected.reshape(*corrected.shape[:-2], -1)


def solve_thermal_norm(problem, temperatures_c, covariance, *, reference_c: float | None = None,
                       max_order: int = MAX_ORDER, scale: bool = True) -> ThermalFit:
    """The joint fit of ``problem`` (a norm problem whose ``data`` are 3-vector averages) with
    the thermal terms; ``temperatures_c`` one per average, in the order of ``problem.data``;
    ``covariance`` as ``solve_norm`` takes it. ``reference_c`` defaults to the mean temperature.
    ``scale``: also fit s₁ at the order chosen when the equations leave room for it."""
    u = np.asarray(problem.data, dtype=float)
    points = u.reshape(-1, 3)
    temperatures = np.asarray(temperatures_c, dtype=float)
    if temperatures.shape != (len(points),) or not np.all(np.isfinite(temperatures)):
        raise ValueError(f"{problem.name}: expected one finite temperature per average ({len(points)}), "
                         f"got shape {temperatures.shape}")
    if not 0 <= max_order <= MAX_ORDER:
        raise ValueError(f"max_order: expected 0 to {MAX_ORDER}, got {max_order}")
    ref = float(np.mean(temperatures)) if reference_c is None else float(reference_c)
    dt = temperatures - ref
    span = max(float(np.ptp(temperatures)), 1e-3)
    if covariance is None:  # the order test weighs χ² against the noise: it needs the noise
        raise ValueError(f"{problem.name}: the thermal fit needs the covariance of the averages")
    try:  # the problem's own first guess: a warm unit's averages may defeat the plain solve
        theta_start = np.asarray(problem.initial(), dtype=float)
    except DegenerateError as exc:
        raise CalibrationError(f"{problem.name}: positions are degenerate: {exc}") from None
    n_resid = len(problem.residual_labels)
    natural = _natural_scales(problem, theta_start)
    bias_scale = natural[:3]

    def fit(order: int, scale: bool, whitener: Whitener):
        p = _layout(order, scale)
        steps = np.r_[natural, np.tile(bias_scale, order) / np.repeat(span ** np.arange(1, order + 1), 3),
                      np.full(3 if scale else 0, 1e-3 / span)]

        powers = dt[:, None] ** np.arange(1, order + 1)

        def whitened(x):  # x (p,) or a stack (k, p)
            theta, terms, drift = _split(x, order, scale)
            return whitener(problem.residuals(theta, _corrected(points, dt, theta, terms, drift, powers)))

        x0 = np.r_[theta_start, np.zeros(p - N_PARAMS)]

        def whitened_z(z):
            return whitened(x0 + z * steps)

        res = optimize.least_squares(whitened_z, np.zeros(p), jac=lambda z: _forward_jacobian_of_lm(whitened_z, z),
                                     method="lm", xtol=1e-12, ftol=1e-12)
        if not res.success:
            return res.message
        x = x0 + res.x * steps
        J = _central_jacobian(whitened, x, 1e-6 * steps)
        r = whitened(x)
        chi2 = float(r @ r)
        fold = n_resid == p and chi2 > EXACT_FIT_CHI2
        # (second differences: a step 1000 times the Jacobian's keeps the rounding of r·r small;
        # the folds' σ agree to 3 digits at 1e-3 and 1e-4 natural units and move 20 % at 1e-5)
        information = _observed_information(whitened, x, J, 1e-3 * steps) if fold else J.T @ J
        return (order, scale, x, chi2, J, res, information, fold)

    def better(candidate, than) -> bool:
        """Whether the next order's three coefficients are kept: they lower χ² significantly, or
        leaving them out would move a parameter of the lower order by more than half its σ; a
        fold, only if Akaike's criterion prefers it."""
        if than is None or than[3] - candidate[3] >= ORDER_TEST_CHI2:
            return True
        if candidate[7]:
            # A fold's estimates move from the lower order's along the fold by the model's
            # geometry, not by the data's evidence (the inclinometer, whose truth has no thermal
            # terms, moved 11-21 of its order 1's σ on its folds of seeds 101-149), so a move says
            # nothing of the lower order's bias. Its χ² does: kept when the drop exceeds twice the
            # three coefficients it adds (Akaike): 6.7-10.6 on the accelerometer's folds (its true
            # b₂ left out of order 1), 0.1-1.2 on the inclinometer's.
            return bool(than[3] - candidate[3] > 2 * 3)
        # The χ² test alone under-fits where a term is weak in χ² but correlated with the others
        # (a warming accelerometer's b₂ beside its scale drift on 18 norms): the lower order then
        # carries the omitted term in its biases and scale factors, 4-5σ of its own σ on
        # configs/sim-warmup.yaml. So the lower order must also leave the others where they are.
        order, with_scale = than[0], than[1]
        shared = np.r_[np.arange(_layout(order, False)),
                       np.arange(_layout(order + 1, False), _layout(order + 1, with_scale))]
        sigma = np.sqrt(np.diag(np.linalg.pinv(than[4].T @ than[4])))
        return bool(np.max(np.abs(candidate[2][shared] - than[2]) / sigma) > MAX_OMISSION_SHIFT_SIGMA)

    # The scale drift is in every candidate when the equations leave room for it at order 0: left
    # out, a warming accelerometer's drift (50 ppm/K, 0.3 mg over 6 K) is no term of the model, so
    # its 18 norms' χ² sat at 20-70 on 3 degrees of freedom and the biases and scale factors it
    # pulled missed by 3-6σ even after the Birge inflation (configs/sim-warmup.yaml, RMS z 2.06).
    # Fitted at every order, it also keeps the order test from taking its signature for a bias term.
    with_drift = scale and n_resid >= _layout(0, True)

    def select(whitener: Whitener):
        chosen = None
        chi2_by_order: dict[int, float] = {}
        unconverged = undetermined = None
        for order in range(max_order + 1):
            # The noise is known (the covariance of the averages), so σ comes from the information
            # and not from the residuals: a model with as many unknowns as equations is determined.
            if n_resid < _layout(order, with_drift):
                break
            candidate = fit(order, with_drift, whitener)
            if isinstance(candidate, str):
                # An order whose fit does not converge is no candidate: a warm gyro's order 0 (its
                # bias moving 0.8 °/s over the run, 250 Earth rates) misfits by χ² ~ 10⁷ and the
                # least squares can run out of evaluations on it (configs/sim-warmup.yaml seeds 34
                # and 51), which failed the whole triad. The next order is tried; after a lower
                # order was chosen, the search ends with it.
                unconverged = candidate
                if chosen is not None:
                    break
                continue
            if _undetermined(candidate):
                # An order the windows cannot determine is no candidate either: an exact fit (order
                # 2 and the drift on the inclinometer's 18 norms) was singular at some warm-ups'
                # temperatures (configs/sim-warmup.yaml seed 380, condition 5e10), which failed the
                # whole triad. The lower order stands; with none, the check below says why.
                undetermined = candidate
                if chosen is not None:
                    break
                continue
            chi2_by_order[order] = candidate[3]
            if not better(candidate, chosen):
                break
            chosen = candidate
        if chosen is None and undetermined is not None:
            chosen = undetermined  # (refused below, naming its condition number)
        if chosen is None and unconverged is not None:
            raise CalibrationError(f"{problem.name}: the thermal fit did not converge ({unconverged})")
        if chosen is None:
            raise CalibrationError(f"{problem.name}: {n_resid} equations leave no room for a thermal model")
        return chosen, chi2_by_order

    # The weights are the residuals' covariance G Σ Gᵀ, G = ∂r/∂u at a solution: first at the
    # problem's guess, then again at the first fit's solution and its averages brought back to
    # T_ref (a warm gyro's guess may have its bias off by far more than the Earth rate it weighs).
    chosen, _ = select(_one_by_one(cast(Whitener, _residual_whitener(problem, theta_start, covariance))))
    theta, terms, drift = _split(chosen[2], chosen[0], chosen[1])
    corrected = _corrected(points, dt, theta, terms, drift)
    chosen, chi2_by_order = select(_one_by_one(_whitener_of(problem, _residual_covariance_at(problem, theta, corrected,
                                                                                          covariance))))
    order, scale, x, chi2, J, res, information, fold = chosen
    dof = n_resid - _layout(order, scale)
    why = _undetermined(chosen)
    if why:
        raise CalibrationError(f"{problem.name}: the thermal terms are not determined by these positions "
                               f"and temperatures ({why})")
    condition = _condition_number(chosen)
    cov = np.linalg.inv(information)
    scaled = bool(dof > 0 and chdtrc(dof, chi2) < _BIRGE_P)  # (no residual freedom: nothing to test)
    if scaled:
        cov *= chi2 / dof
    sigma = np.sqrt(np.diag(cov))
    theta, terms, drift = _split(x, order, scale)
    _, terms_sigma, drift_sigma = _split(sigma, order, scale)
    model = ThermalModel(reference_c=ref, range_c=(float(temperatures.min()), float(temperatures.max())),
                         bias_terms=terms, bias_terms_sigma=terms_sigma,
                         scale_drift=drift if scale else None, scale_drift_sigma=drift_sigma if scale else None)
    residuals = problem.residuals(theta, _corrected(points, dt, theta, terms, drift))
    calibration = Calibration(
        name=problem.name, kind=problem.kind, output_unit=problem.output_unit, method="lsq",
        theta=theta, covariance=cov[:N_PARAMS, :N_PARAMS], residuals=residuals,
        residual_labels=problem.residual_labels, thermal=model,
        diagnostics=SolverDiagnostics(iterations=int(res.nfev), evaluations=int(res.nfev), converged=True,
                                      message=str(res.message), search="lsq", chi2=chi2, dof=dof,
                                      scaled_by_residuals=scaled, condition_number=condition))
    return ThermalFit(calibration, chi2_by_order, cov)
