"""The bound's whitening by Kronecker factors: the same numbers as the dense Cholesky factor of
C ⊗ K·Kᵀ (the plain textbook computation, numpy's dense solve), for the whitening itself and for
a whole bound with the bias at the end, and the planner's σ the same either way."""
from __future__ import annotations

import numpy as np

from drivers.noise import TriadNoise
from fieldcal.solvers.crb import KroneckerCovariance, end_bias_terms, specific_force_bound


def _spd(rng, n):
    a = rng.standard_normal((n, n))
    return a @ a.T + n * np.eye(n)


def test_whitening_by_the_factors_is_the_dense_factors_solve():
    rng = np.random.default_rng(7)
    windows, axes = _spd(rng, 8), _spd(rng, 3)
    rhs = rng.standard_normal((24, 5))
    dense = np.linalg.solve(np.linalg.cholesky(np.kron(windows, axes)), rhs)
    assert np.allclose(KroneckerCovariance(windows, axes).whiten(rhs), dense, rtol=1e-12, atol=1e-12)


def test_a_bound_with_the_bias_at_the_end_is_the_same_from_the_factors_as_from_the_dense_covariance():
    faces = np.array([[0, 0, 1], [0, 0, -1], [1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0],
                      [1, 1, 0], [-1, -1, 0], [0, 1, 1], [0, -1, -1], [1, 0, 1], [-1, 0, -1]], float)
    up = faces / np.linalg.norm(faces, axis=1, keepdims=True)
    noise = TriadNoise(white=1e-4, bias_instability=5e-4, flicker_tau_max_s=300.0)
    k = np.diag([1.001, 0.999, 1.0002]) + 1e-4
    starts, durations = np.arange(12) * 40.0, np.full(12, 20.0)
    windows = noise.window_covariance(starts, durations)
    theta = np.r_[0.01, -0.02, 0.03, np.diag(k), 1e-4, -2e-4, 3e-4]
    end = end_bias_terms(noise, k, starts, durations, 500.0)
    dense_bound, dense_end = specific_force_bound(theta, up, 9.8, np.kron(windows, k @ k.T), end)
    bound, at_end = specific_force_bound(theta, up, 9.8, KroneckerCovariance(windows, k @ k.T), end)
    assert np.allclose(bound, dense_bound, rtol=1e-9, atol=0)
    assert np.allclose(at_end.predicted, dense_end.predicted, rtol=1e-9, atol=0)
    assert np.allclose(at_end.constant, dense_end.constant, rtol=1e-9, atol=0)
