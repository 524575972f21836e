"""Closed-form starting points: algebraic ellipsoid fits, solved as linear least squares."""
from __future__ import annotations

import numpy as np

from fieldcal.model import params_from_k


class DegenerateError(ValueError):
    pass


def _k_from_shape(M: np.ndarray) -> np.ndarray:
    """Lower-triangular K with (K⁻¹)ᵀK⁻¹ = M, i.e. |K⁻¹v|² = vᵀMv."""
    if np.any(np.linalg.eigvalsh(M) <= 0):
        raise DegenerateError("the averages do not lie on an ellipsoid (shape matrix not positive definite)")
    P = np.eye(3)[::-1]
    C = np.linalg.cholesky(P @ M @ P)  # P M P = C Cᵀ, so M = (P Cᵀ P)ᵀ (P Cᵀ P)
    inverse_k = P @ C.T @ P  # lower-triangular
    return np.tril(np.linalg.inv(inverse_k))  # exact zeros above the diagonal


def _normalise(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    centre = points.mean(axis=0)
    spread = float(np.sqrt(np.mean(np.sum((points - centre) ** 2, axis=1))))
    if spread == 0:
        raise DegenerateError("all averages are identical")
    return (points - centre) / spread, centre, spread


def fit_offset_ellipsoid(points: np.ndarray, radius: float) -> np.ndarray:
    """Parameters (paper order) of the ellipsoid |K⁻¹(u − b)| = radius through the points."""
    x, centre, spread = _normalise(np.asarray(points, dtype=float))
    design = np.column_stack([x**2, 2 * x[:, 0] * x[:, 1], 2 * x[:, 0] * x[:, 2],
                              2 * x[:, 1] * x[:, 2], 2 * x])
    rank = np.linalg.matrix_rank(design, tol=1e-9 * len(x))
    if rank < 9:
        raise DegenerateError(f"the averages determine only {rank} of the 9 ellipsoid coefficients")
    v = np.linalg.lstsq(design, np.ones(len(x)), rcond=None)[0]
    A = np.array([[v[0], v[3], v[4]], [v[3], v[1], v[5]], [v[4], v[5], v[2]]])
    local_centre = -np.linalg.solve(A, v[6:9])
    gamma = 1 + local_centre @ A @ local_centre
    M = A * radius**2 / (gamma * spread**2)
    return params_from_k(_k_from_shape(M), centre + spread * local_centre)


def fit_centred_ellipsoid(points: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """Lower-triangular K with |K⁻¹ p_i| = r_i for points on an ellipsoid centred on zero."""
    points = np.asarray(points, dtype=float)
    spread = float(np.sqrt(np.mean(np.sum(points**2, axis=1))))
    x = points / spread
    design = np.column_stack([x**2, 2 * x[:, 0] * x[:, 1], 2 * x[:, 0] * x[:, 2], 2 * x[:, 1] * x[:, 2]])
    rank = np.linalg.matrix_rank(design, tol=1e-9 * len(x))
    if rank < 6:
        raise DegenerateError(f"the rate steps determine only {rank} of the 6 ellipsoid coefficients")
    v = np.linalg.lstsq(design, np.asarray(radii, dtype=float) ** 2, rcond=None)[0]
    M = np.array([[v[0], v[3], v[4]], [v[3], v[1], v[5]], [v[4], v[5], v[2]]]) / spread**2
    return _k_from_shape(M)
