"""The classic multi-position least-squares method (paper eqs. 4-8) for aligned lab runs.

With the unit aligned to a precise table the true inputs are known, U = [K | U0]·[A; 1], and each
output axis is an ordinary linear regression on the inputs. K here is the full 3x3 matrix: it also
holds the rotation of the triad relative to the table, which the norm method cannot see.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fieldcal.model import PARAM_NAMES, SI_UNIT
from fieldcal.solvers.norm import CalibrationError


@dataclass(frozen=True)
class ClassicSolution:
    name: str
    kind: str
    output_unit: str
    K: np.ndarray  # 3x3, output units per SI unit
    bias: np.ndarray  # U0, output units
    row_covariance: np.ndarray  # (3, 4, 4): covariance of [K_i0, K_i1, K_i2, U0_i] for row i
    residuals: np.ndarray  # (n, 3) output units
    method: str = "classic"

    @property
    def scale_factor(self) -> np.ndarray:
        return np.diag(self.K).copy()

    @property
    def misalignment(self) -> np.ndarray:
        """Δyz, Δzy, Δzx from the lower triangle, as for the norm method's K."""
        K = self.K
        return np.array([-K[1, 0] / K[1, 1], K[2, 0] / K[2, 2], -K[2, 1] / K[2, 2]])

    @property
    def theta(self) -> np.ndarray:
        return np.r_[self.bias, self.scale_factor, self.misalignment]

    @property
    def sigma(self) -> np.ndarray:
        var = self.row_covariance
        diag_k = np.sqrt([var[i, i, i] for i in range(3)])
        bias = np.sqrt(var[:, 3, 3])
        K = self.K
        mis = np.array([np.sqrt(var[1, 0, 0]) / K[1, 1], np.sqrt(var[2, 0, 0]) / K[2, 2],
                        np.sqrt(var[2, 1, 1]) / K[2, 2]])
        return np.r_[bias, diag_k, mis]

    @property
    def residual_unit(self) -> str:
        return self.output_unit

    @property
    def residual_rms(self) -> float:
        return float(np.sqrt(np.mean(self.residuals**2)))

    def calibrate(self, raw: np.ndarray) -> np.ndarray:
        return np.linalg.solve(self.K, (np.asarray(raw, dtype=float) - self.bias).T).T

    def named(self) -> dict[str, tuple[float, float]]:
        return {n: (float(v), float(s)) for n, v, s in zip(PARAM_NAMES, self.theta, self.sigma)}


def solve_classic(means: np.ndarray, inputs: np.ndarray, name: str, kind: str,
                  output_unit: str | None = None, covariance=None) -> ClassicSolution:
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
    if covariance is None:
        row_var = np.sum(residuals**2, axis=0) / (len(A) - 4)
        row_cov = row_var[:, None, None] * normal_inv[None]
    else:
        cov = np.asarray(covariance, dtype=float)
        if cov.shape != (U.size, U.size):
            raise ValueError(f"{name}: covariance must be ({U.size}, {U.size}), got {cov.shape}")
        P = normal_inv @ design.T  # coefficients = P @ outputs, per output axis
        row_cov = np.stack([P @ cov[i::3, i::3] @ P.T for i in range(3)])
    return ClassicSolution(name=name, kind=kind, output_unit=output_unit or SI_UNIT[kind],
                           K=coef[:3].T.copy(), bias=coef[3].copy(), row_covariance=row_cov,
                           residuals=residuals)
