"""Rotation matrices from rotation vectors and back, numpy only.

The simulator turns the fixture by hand and places it with a small tilt at every step; scipy's
``Rotation`` would do, but importing ``scipy.spatial`` costs a headless run more than all its
rotations together.
"""
from __future__ import annotations

import numpy as np


def rotvec_matrix(rotvec) -> np.ndarray:
    """Rodrigues: the rotation matrices of rotation vectors (..., 3) (axis times angle, rad)."""
    v = np.asarray(rotvec, dtype=float)
    angle = np.linalg.norm(v, axis=-1)[..., None, None]
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    zero = np.zeros_like(x)
    k = np.stack([np.stack([zero, -z, y], -1), np.stack([z, zero, -x], -1),
                  np.stack([-y, x, zero], -1)], -2)  # [v]x
    # sin(a)/a and (1 - cos(a))/a², by their series near zero.
    small = angle < 1e-4
    safe = np.where(small, 1.0, angle)
    a2 = angle * angle
    sinc = np.where(small, 1.0 - a2 / 6.0, np.sin(safe) / safe)
    cosc = np.where(small, 0.5 - a2 / 24.0, (1.0 - np.cos(safe)) / (safe * safe))
    return np.eye(3) + sinc * k + cosc * (k @ k)


def matrix_rotvec(matrix) -> np.ndarray:
    """The rotation vector (3,) of a rotation matrix (3, 3), angle in [0, π], through its
    quaternion (Shepperd's choice of the largest component keeps it accurate at any angle)."""
    m = np.asarray(matrix, dtype=float)
    trace = np.trace(m)
    diag = np.diag(m)
    i = int(np.argmax(np.append(diag, trace)))
    if i == 3:
        w = 0.5 * np.sqrt(1.0 + trace)
        v = np.array([m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1]]) / (4.0 * w)
    else:
        j, k = (i + 1) % 3, (i + 2) % 3
        v = np.empty(3)
        v[i] = 0.5 * np.sqrt(1.0 + m[i, i] - m[j, j] - m[k, k])
        v[j] = (m[j, i] + m[i, j]) / (4.0 * v[i])
        v[k] = (m[k, i] + m[i, k]) / (4.0 * v[i])
        w = (m[k, j] - m[j, k]) / (4.0 * v[i])
    if w < 0:  # the same rotation, with the angle in [0, π]
        w, v = -w, -v
    norm = np.linalg.norm(v)
    if norm == 0.0:
        return np.zeros(3)
    return 2.0 * np.arctan2(norm, w) * v / norm


def z_rotation(angle: float) -> np.ndarray:
    """Rotation by ``angle`` (rad) about z."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
