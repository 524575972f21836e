"""Per-triad error model of paper eq. 16: raw = K·true + b, K lower-triangular.

The nine parameters, in this order everywhere (solvers, covariances, files):
bias (3, output units), scale factor k = K_ii (3, output units per SI unit; 1 + S for a device
that already reports SI), and the non-orthogonality angles Δyz, Δzy, Δzx (rad), defined so that
K = [[kx, 0, 0], [-Δyz·ky, ky, 0], [Δzy·kz, -Δzx·kz, kz]] — the paper's names and signs when k ≈ 1.

A full K (the classic method's, which also holds the triad's rotation against the table, or the
gyro's from rotations, which holds its rotation against the accelerometer) is written
K = diag(k)·(I + M), with six small terms m_ij = M[i, j]; its lower-triangle terms are the named
angles (Δyz = −m_yx, Δzy = m_zx, Δzx = −m_zy). This module is the only place K and parameters
are converted into each other.
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
TERM_NAMES = ("m_xy", "m_xz", "m_yx", "m_yz", "m_zx", "m_zy")
FULL_PARAM_NAMES = PARAM_NAMES[:6] + TERM_NAMES  # bias, scale factor, the six terms of M
# Each named angle is one term of M, up to its sign.
ANGLE_TERMS = {"delta_yz": "m_yx", "delta_zy": "m_zx", "delta_zx": "m_zy"}
_OFF = (np.array([0, 0, 1, 1, 2, 2]), np.array([1, 2, 0, 2, 0, 1]))  # TERM_NAMES' cells


def k_from_params(theta) -> np.ndarray:
    kx, ky, kz, dyz, dzy, dzx = theta[3:9]
    return np.array([[kx, 0.0, 0.0], [-dyz * ky, ky, 0.0], [dzy * kz, -dzx * kz, kz]])


def params_from_k(K: np.ndarray, bias, *, full: bool = False) -> np.ndarray:
    """The nine parameters of PARAM_NAMES. K must be lower-triangular unless ``full``: then the
    angles are those of its lower triangle, and the upper one is left unnamed."""
    K = np.asarray(K, dtype=float)
    if K.shape != (3, 3) or (not full and np.any(np.triu(K, 1) != 0)):
        raise ValueError("K must be a " + ("" if full else "lower-triangular ") + "3x3 matrix")
    kx, ky, kz = np.diag(K)
    return np.array([*bias, kx, ky, kz, -K[1, 0] / ky, K[2, 0] / kz, -K[2, 1] / kz])


def k_from_terms(scale, terms) -> np.ndarray:
    """K = diag(k)·(I + M), M holding m_xy, m_xz, m_yx, m_yz, m_zx, m_zy off the diagonal."""
    M = np.zeros((3, 3))
    M[_OFF] = terms
    return np.asarray(scale, dtype=float)[:, None] * (np.eye(3) + M)


def terms_from_k(K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(k, the six terms of M) of a full K = diag(k)·(I + M)."""
    K = np.asarray(K, dtype=float)
    k = np.diag(K).copy()
    return k, (K / k[:, None] - np.eye(3))[_OFF]


def k_from(values, names: tuple[str, ...]) -> np.ndarray:
    """K from parameter values in PARAM_NAMES or FULL_PARAM_NAMES order."""
    if tuple(names) == PARAM_NAMES:
        return k_from_params(values)
    if tuple(names) == FULL_PARAM_NAMES:
        return k_from_terms(values[3:6], values[6:])
    raise ValueError(f"unknown parameter set {names}")


def params_from(K: np.ndarray, bias, names: tuple[str, ...]) -> np.ndarray:
    """Parameter values in PARAM_NAMES (named angles of the lower triangle) or FULL_PARAM_NAMES
    order from K and the bias."""
    if tuple(names) == PARAM_NAMES:
        return params_from_k(K, bias, full=True)
    if tuple(names) == FULL_PARAM_NAMES:
        return np.r_[bias, np.concatenate(terms_from_k(K))]
    raise ValueError(f"unknown parameter set {names}")


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

