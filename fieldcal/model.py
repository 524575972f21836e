"""Per-triad error model of paper eq. 16: raw = K·true + b, K lower-triangular.

The nine parameters, in this order everywhere (solvers, covariances, files):
bias (3, output units), scale factor k = K_ii (3, output units per SI unit; 1 + S for a device
that already reports SI), and the non-orthogonality angles Δyz, Δzy, Δzx (rad), defined so that
K = [[kx, 0, 0], [-Δyz·ky, ky, 0], [Δzy·kz, -Δzx·kz, kz]] — the paper's names and signs when k ≈ 1.
"""
from __future__ import annotations

import numpy as np

SPECIFIC_FORCE = "specific_force"
ANGULAR_RATE = "angular_rate"
KINDS = (SPECIFIC_FORCE, ANGULAR_RATE)
SI_UNIT = {SPECIFIC_FORCE: "m/s^2", ANGULAR_RATE: "rad/s"}

PARAM_NAMES = ("bias_x", "bias_y", "bias_z", "scale_x", "scale_y", "scale_z",
               "delta_yz", "delta_zy", "delta_zx")
N_PARAMS = len(PARAM_NAMES)


def k_from_params(theta) -> np.ndarray:
    kx, ky, kz, dyz, dzy, dzx = theta[3:9]
    return np.array([[kx, 0.0, 0.0], [-dyz * ky, ky, 0.0], [dzy * kz, -dzx * kz, kz]])


def params_from_k(K: np.ndarray, bias) -> np.ndarray:
    K = np.asarray(K, dtype=float)
    if K.shape != (3, 3) or np.any(np.triu(K, 1) != 0):
        raise ValueError("K must be a lower-triangular 3x3 matrix")
    kx, ky, kz = np.diag(K)
    return np.array([*bias, kx, ky, kz, -K[1, 0] / ky, K[2, 0] / kz, -K[2, 1] / kz])


def calibrate_with(theta, raw: np.ndarray) -> np.ndarray:
    """K⁻¹(raw − b) for an (n, 3) array, by forward substitution (K is lower-triangular)."""
    kx, ky, kz, dyz, dzy, dzx = theta[3:9]
    v = raw - theta[:3]
    out = np.empty_like(v, dtype=float)
    out[:, 0] = v[:, 0] / kx
    out[:, 1] = v[:, 1] / ky + dyz * out[:, 0]
    out[:, 2] = v[:, 2] / kz - dzy * out[:, 0] + dzx * out[:, 1]
    return out


def distort_with(theta, true: np.ndarray) -> np.ndarray:
    """K·true + b for an (n, 3) array: what the triad reports for a true input."""
    return true @ k_from_params(theta).T + theta[:3]

