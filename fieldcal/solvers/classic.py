"""The classic multi-position least-squares method (paper eqs. 4-8) for aligned lab runs.

With the unit aligned to a precise table the true inputs are known, U = [K | U0]·[A; 1], and each
output axis is an ordinary linear regression on the inputs. K here is the full 3x3 matrix: it also
holds the rotation of the triad relative to the table, which the norm method cannot see.
"""
from __future__ import annotations

import numpy as np

from fieldcal.calibration import CLASSIC_METHOD, Calibration, SolverDiagnostics
from fieldcal.model import FULL_PARAM_NAMES, SI_UNIT
from fieldcal.solvers.norm import CalibrationError


def _parameter_covariance(K: np.ndarray, row_cov: np.ndarray,
                          coef_cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Covariance and 1σ of FULL_PARAM_NAMES (bias, k, m_ij = K_ij / K_ii) from the coefficients'
    covariance (row i's [K_i0, K_i1, K_i2, U0_i] at 4i..4i+3) and its diagonal blocks.

    To first order, each term m_ij from K_ij alone (its K_ii part is of relative size m, below
    the σ's third digit). σ is computed from the row blocks as parameter files since version 1
    hold it, so a re-solved session writes the same bytes."""
    k = np.diag(K)
    rows, cols = np.nonzero(~np.eye(3, dtype=bool))  # m_xy, m_xz, m_yx, m_yz, m_zx, m_zy
    J = np.zeros((12, 12))  # the parameters as linear functions of the coefficients
    J[np.arange(3), 4 * np.arange(3) + 3] = 1.0  # bias
    J[3 + np.arange(3), 5 * np.arange(3)] = 1.0  # scale factor K_ii
    J[6 + np.arange(6), 4 * rows + cols] = 1.0 / k[rows]
    sigma = np.r_[np.sqrt(row_cov[:, 3, 3]), np.sqrt(row_cov[np.arange(3), np.arange(3), np.arange(3)]),
                  np.sqrt(row_cov[rows, cols, cols]) / k[rows]]
    return J @ coef_cov @ J.T, sigma


def solve_classic(means: np.ndarray, inputs: np.ndarray, name: str, kind: str,
                  output_unit: str | None = None, covariance=None) -> Calibration:
    """Least squares K̄ = U·Āᵀ(Ā·Āᵀ)⁻¹ (eq. 7) from outputs U and known SI inputs A, both (n, 3).

    Without ``covariance`` (of the flattened means, position-major) the uncertainty comes from the
    residual scatter, which cannot see noise common to all positions, such as a slow bias drift.
    """
    U = np.asarray(means, dtype=float)
    A = np.asarray(inputs, dtype=float)
    if U.shape != A.shape or U.ndim != 2 or U.shape[1] != 3:
        raise ValueError(f"{name}: outputs {U.shape} and inputs {A.shape} must both be (n, 3)")
    design = np.column_stack([A, np.ones(len(A))])  # Āᵀ
    if len(A) <= 4 or np.linalg.matrix_rank(design) < 4:
        raise CalibrationError(f"{name}: the inputs must span all three axes in both directions "
                         f"(got {len(A)} positions, rank {np.linalg.matrix_rank(design)} of 4)")
    normal_inv = np.linalg.inv(design.T @ design)
    coef = normal_inv @ design.T @ U  # (4, 3): column i is [K_i0, K_i1, K_i2, U0_i]
    residuals = U - design @ coef
    # Covariance of the 12 coefficients, row i's [K_i0, K_i1, K_i2, U0_i] at 4i..4i+3; the
    # diagonal blocks (row_cov) give σ exactly as before, the others the rows' correlation.
    if covariance is None:
        row_var = np.sum(residuals**2, axis=0) / (len(A) - 4)
        row_cov = row_var[:, None, None] * normal_inv[None]
        coef_cov = np.kron(residuals.T @ residuals / (len(A) - 4), normal_inv)
    else:
        cov = np.asarray(covariance, dtype=float)
        if cov.shape != (U.size, U.size):
            raise ValueError(f"{name}: covariance must be ({U.size}, {U.size}), got {cov.shape}")
        P = normal_inv @ design.T  # coefficients = P @ outputs, per output axis
        row_cov = np.stack([P @ cov[i::3, i::3] @ P.T for i in range(3)])
        coef_cov = np.block([[P @ cov[i::3, j::3] @ P.T for j in range(3)] for i in range(3)])
    K = coef[:3].T.copy()
    cov, sigma = _parameter_covariance(K, row_cov, coef_cov)
    output_unit = output_unit or SI_UNIT[kind]
    return Calibration(name=name, kind=kind, output_unit=output_unit, method=CLASSIC_METHOD, K=K,
                       bias=coef[3].copy(), covariance=cov, sigma=sigma, residuals=residuals,
                       parameter_names=FULL_PARAM_NAMES,
                       residual_unit=output_unit,
                       diagnostics=SolverDiagnostics(message="closed form (linear least squares)",
                                                     dof=U.size - 12))


# The six faces of an aligned six-position run, in this order: +x, +y, +z, −x, −y, −z.
SIX_FACES = np.vstack([np.eye(3), -np.eye(3)])


def six_position_map(gravity: float) -> np.ndarray:
    """(12, 18) matrix L: the coefficients (row i's [K_i0, K_i1, K_i2, U0_i] at 4i..4i+3) of
    Ferraris's closed form as a linear function of the six faces' flattened means (face-major,
    SIX_FACES order). Column j of K is half the difference of the faces ±j over g; output i's
    bias is the mean of its own axis's two faces, ±i, where that axis is vertical.

    Why not the mean of all six faces, the least-squares bias: on the four faces where axis i is
    horizontal its reading holds the placement's tilt at first order (g·sin of the tilt, 4 mg
    for a 0.23° slope of the table under the unit), along the vertical only at second order
    (g·(1 − cos)). The norm of a calibrated face, the one thing known exactly whatever the
    tilt, then misses g at first order; with the vertical pair it misses it at second order."""
    L = np.zeros((12, 18))
    for i in range(3):  # output axis
        for j in range(3):  # K's column j: (face +j − face −j) / 2g
            L[4 * i + j, 3 * j + i] = 0.5 / gravity
            L[4 * i + j, 3 * (j + 3) + i] = -0.5 / gravity
        L[4 * i + 3, [3 * i + i, 3 * (i + 3) + i]] = 0.5  # bias: (face +i + face −i) / 2
    return L


def fit_face_norms(K: np.ndarray, bias: np.ndarray, faces: np.ndarray, gravity: float,
                   iterations: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """K's diagonal and the bias moved so that each of the six faces' calibrated means has norm g
    exactly (six equations, six unknowns; K's off-diagonal terms held), by Newton's method from
    the closed form, which already fits them to second order in the cross terms and tilts."""
    start = (K, bias)
    K, bias = K.copy(), bias.copy()
    for _ in range(iterations):  # quadratic convergence from second-order-small misfits
        K_inv = np.linalg.inv(K)
        a = (faces - bias) @ K_inv.T  # (6, 3) calibrated faces
        norm = np.linalg.norm(a, axis=1)
        unit = a / norm[:, None]
        d_bias = -unit @ K_inv  # ∂|a|/∂b = −uᵀK⁻¹
        d_scale = -(unit @ K_inv) * a  # ∂|a|/∂K_ii = −(uᵀK⁻¹)_i a_i
        try:
            step = np.linalg.solve(np.column_stack([d_bias, d_scale]), gravity - norm)
        except np.linalg.LinAlgError:
            return start
        bias += step[:3]
        K[np.diag_indices(3)] += step[3:]
        if np.max(np.abs(step[3:])) < 1e-15 * np.max(np.abs(np.diag(K))):
            break
    # Faces too far from a six-position run for a second-order correction: the closed form.
    moved = np.abs(np.diag(K) / np.diag(start[0]) - 1)
    return (K, bias) if np.all(np.isfinite(K)) and np.all(np.isfinite(bias)) and moved.max() < 0.01 else start


def solve_six_position(faces: np.ndarray, gravity: float, name: str, kind: str, output_unit: str,
                       covariance: np.ndarray) -> tuple[Calibration, float]:
    """Ferraris's aligned six-position solution (see six_position_map) from the six faces' means
    (6, 3) in SIX_FACES order, refined to fit the faces' norms exactly (fit_face_norms, a change
    of second order: the σ of the closed form hold). ``covariance`` of the flattened face means.
    Returns the calibration, its σ from ``covariance`` alone, and χ²/dof of the faces' residuals
    (6 dof: each output's two horizontal pairs against its vertical pair), which the caller may
    use to widen the σ."""
    faces = np.asarray(faces, dtype=float)
    L = six_position_map(gravity)
    coef = (L @ faces.ravel()).reshape(3, 4)  # row i: [K_i0, K_i1, K_i2, U0_i]
    K, bias = fit_face_norms(coef[:, :3], coef[:, 3], faces, gravity)
    inputs = gravity * SIX_FACES
    residuals = faces - (inputs @ K.T + bias)
    # χ² of the residuals' linear part, r = (I − D·L)·U, D the prediction from the coefficients.
    design = np.column_stack([inputs, np.ones(6)])
    D = np.zeros((18, 12))
    for i in range(3):
        D[i::3, 4 * i:4 * i + 4] = design
    R = np.eye(18) - D @ L
    r = R @ faces.ravel()
    chi2 = float(r @ np.linalg.pinv(R @ covariance @ R.T, rcond=1e-10, hermitian=True) @ r)
    dof = 18 - 12
    coef_cov = L @ covariance @ L.T
    row_cov = np.stack([coef_cov[4 * i:4 * i + 4, 4 * i:4 * i + 4] for i in range(3)])
    cov, sigma = _parameter_covariance(K, row_cov, coef_cov)
    sol = Calibration(name=name, kind=kind, output_unit=output_unit, method=CLASSIC_METHOD, K=K, bias=bias,
                      covariance=cov, sigma=sigma, residuals=residuals, parameter_names=FULL_PARAM_NAMES,
                      residual_unit=output_unit,
                      diagnostics=SolverDiagnostics(
                          message="closed form (Ferraris: each axis's bias from its own up and down faces), "
                                  "the faces' norms fitted", chi2=chi2, dof=dof))
    return sol, chi2 / dof
