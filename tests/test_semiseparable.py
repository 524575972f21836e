"""The gyro solve's whitening by its parts (fieldcal.solvers.semiseparable) is the dense Cholesky
factor's, to rounding: the same L⁻¹ (the Cholesky factor is unique), made in O(m) instead of
O(m³). The oracles are the dense constructions that were there before it: ``TriadNoise.
window_covariance`` for the windows, ``rotation._dense_whitening`` (a dense covariance, LAPACK's
Cholesky) for the residuals."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from drivers.noise import TriadNoise
from fieldcal.recording.up_covariance import UpCovariance
from fieldcal.solvers import CalibrationError
from fieldcal.solvers.rotation import (Motions, RotationNoise, RotationStart, _bias_map, _dense_whitening,
                                       _Residuals, _whitening)
from fieldcal.solvers.semiseparable import BlockSemiseparable, MarkovWindows


def _windows(rng, m, gap=(0.5, 40.0), duration=(0.3, 300.0)):
    """m windows in time order: lengths and gaps from a third of the shortest correlation time to
    far beyond the longest, so every term of the bank decays from nothing to everything."""
    T = np.exp(rng.uniform(*np.log(duration), m))
    gaps = np.exp(rng.uniform(*np.log(gap), m))
    starts = np.cumsum(gaps + np.r_[0.0, T[:-1]])
    return starts, T


@pytest.mark.parametrize("tau_max", [20.0, 5000.0, 1e6])
def test_the_windows_by_their_parts_are_the_noise_models_window_covariance(tau_max):
    rng = np.random.default_rng(int(tau_max))
    starts, T = _windows(rng, 40)
    noise = TriadNoise(white=3e-3, bias_instability=2e-3, flicker_tau_max_s=tau_max)
    parts = MarkovWindows.of(noise, starts, T)
    expected = noise.window_covariance(starts, T)
    np.testing.assert_allclose(parts.dense(), expected, rtol=1e-12, atol=1e-15 * np.abs(expected).max())


def test_windows_out_of_order_or_overlapping_or_with_a_random_walk_have_no_parts():
    noise = TriadNoise(white=1e-3, bias_instability=1e-3)
    assert MarkovWindows.of(noise, [0.0, 10.0, 5.0], [1.0, 1.0, 1.0]) is None
    assert MarkovWindows.of(noise, [0.0, 10.0], [10.5, 1.0]) is None
    assert MarkovWindows.of(TriadNoise(white=1e-3, rate_random_walk=1e-5), [0.0, 10.0], [1.0, 1.0]) is None
    assert MarkovWindows.of(noise, [0.0, 10.0], [10.0 + 1e-12, 1.0]) is not None  # touching, to rounding


def _chain(seed, m):
    """A rotation model of m motions between m + 1 random poses (the residuals' values do not
    matter here: only their covariance, which the directions and rotations make)."""
    rng = np.random.default_rng(seed)
    n_per = 20
    t = np.arange((m + 1) * n_per) * 0.01
    raw = rng.normal(0.0, 0.5, (len(t), 3))
    spans = np.column_stack([np.arange(m) * n_per + n_per - 1, np.arange(m) * n_per + n_per + 5])
    up = Rotation.random(m + 1, random_state=seed).apply([0.0, 0.0, 1.0])
    return rng, Motions(t, raw, spans, up[:-1], up[1:])


def _up_covariance(rng, m, windows):
    D = rng.normal(size=(m + 1, 3, 3))
    own_root = rng.normal(size=(m + 1, 3, 3)) * 0.1
    shared = rng.normal(size=(m + 1, 3, 9)) * 0.01
    theta_cov = np.cov(rng.normal(size=(9, 30)))
    return UpCovariance(D, windows, own_root @ np.swapaxes(own_root, 1, 2), shared, theta_cov)


def _both(motions, noise, start, extra=None):
    """(the structured whitening's L⁻¹, the dense one's) of one model at its start."""
    n_side = 0 if extra is None else len(extra(np.eye(3), start.b0))
    model = _Residuals(motions, start, noise.bias_sigma, extra)
    r, J, q = model.jacobian(model.theta0)
    structured = _whitening(model, J, q, noise, n_side, "gyro")
    C = Rotation.from_quat(q).as_matrix()
    held = noise.bias_sigma is not None and not start.estimate_bias
    G = _bias_map(model, J, noise) if held else None  # the held bias's error: one map for both
    dense_noise = noise
    if isinstance(getattr(noise.up_covariance, "windows", None), MarkovWindows):
        u = noise.up_covariance
        dense_noise = RotationNoise(noise.bias_sigma, noise.up_sigma, noise.rate_noise, noise.motion_variance,
                                    UpCovariance(u.D, u.windows.dense(), u.own, u.shared, u.theta_covariance))
    dense = _dense_whitening(model, C, dense_noise, G, n_side, "gyro")
    return structured.matrix_dense(), dense


@pytest.mark.parametrize("seed", [1, 2, 3])
@pytest.mark.parametrize("held", [True, False], ids=["bias-held", "bias-estimated"])
def test_the_whitening_by_parts_is_the_dense_cholesky_factors(seed, held):
    """Flicker, white, each pose's own noise, the calibration's shared error, the Earth rate
    and angle random walk per motion, and a held bias's error: L⁻¹ to rounding."""
    m = 12
    rng, motions = _chain(seed, m)
    starts, T = _windows(rng, m + 1)
    noise_model = TriadNoise(white=2e-3, bias_instability=3e-3, flicker_tau_max_s=float(rng.choice([50.0, 5000.0])))
    up = _up_covariance(rng, m, MarkovWindows.of(noise_model, starts, T))
    noise = RotationNoise(bias_sigma=np.array([0.02, 0.01, 0.03]), rate_noise=1e-3, up_covariance=up,
                          motion_variance=rng.uniform(1e-6, 1e-5, m))
    start = RotationStart.of(1.0, rng.normal(0, 0.01, 3), estimate_bias=not held)
    structured, dense = _both(motions, noise, start)
    np.testing.assert_allclose(structured, dense, rtol=0, atol=1e-9 * np.abs(dense).max())


@pytest.mark.parametrize("m", [2, 3, 5])
@pytest.mark.parametrize("bias_instability", [0.0, 1e-3], ids=["white", "flicker"])
def test_the_whitening_by_parts_holds_for_the_shortest_chains(m, bias_instability):
    """Two motions (no block two apart), three (one), and white noise alone (no generators)."""
    rng, motions = _chain(11, m)
    starts, T = _windows(rng, m + 1)
    up = _up_covariance(rng, m, MarkovWindows.of(TriadNoise(white=2e-3, bias_instability=bias_instability), starts, T))
    noise = RotationNoise(bias_sigma=0.01, rate_noise=1e-3, up_covariance=up)
    structured, dense = _both(motions, noise, RotationStart.of(1.0, np.zeros(3)))
    np.testing.assert_allclose(structured, dense, rtol=0, atol=1e-9 * np.abs(dense).max())


def test_the_whitening_by_parts_takes_side_residuals_and_shared_pose_directions():
    """Side residuals (a prior on the scale, whitened already) tied to the rotations by the held
    bias; up_sigma's correlation of two motions around one pose; and white noise alone (no
    windows): L⁻¹ to rounding."""
    m = 10
    rng, motions = _chain(7, m)
    start = RotationStart.of(1.0, np.zeros(3))

    def prior(K_inv, bias):
        return np.r_[np.diag(np.linalg.inv(K_inv)) - 1.0, bias[:1] * 30.0] / 1e-3

    for noise in (RotationNoise(bias_sigma=0.01, up_sigma=2e-3, rate_noise=1e-3),
                  RotationNoise(bias_sigma=0.01, rate_noise=1e-3, up_covariance=_up_covariance(rng, m, None))):
        structured, dense = _both(motions, noise, start, prior)
        np.testing.assert_allclose(structured, dense, rtol=0, atol=1e-9 * np.abs(dense).max())


def test_a_covariance_that_is_not_positive_definite_is_named():
    m = 6
    rng, motions = _chain(4, m)
    up = _up_covariance(rng, m, None)
    broken = UpCovariance(up.D, None, -up.own - 1.0 * np.eye(3), up.shared, up.theta_covariance)
    model = _Residuals(motions, RotationStart.of(1.0, np.zeros(3)), None, None)
    r, J, q = model.jacobian(model.theta0)
    with pytest.raises(CalibrationError, match="gyro: the residual covariance is not positive definite"):
        _whitening(model, J, q, RotationNoise(rate_noise=1e-3, up_covariance=broken), 0, "gyro")


def _random_blocks(rng, with_tail_low=True):
    """Random generators, decays, neighbour blocks, low rank and a tail, and S built entry by entry
    from its definition (a tail without tail_low: no cross terms)."""
    n, b, g, c, t = 11, 2, 5, 3, 3
    left, right = rng.normal(size=(n, b, g)), rng.normal(size=(n, g, b))
    decay, low = rng.uniform(0.2, 1.0, (n, g)), rng.normal(size=(n, b, c))
    sub, tail_low = rng.normal(size=(n - 1, b, b)), rng.normal(size=(t, c)) if with_tail_low else np.zeros((t, c))
    N = n * b + t
    S = np.zeros((N, N))
    for i in range(n):
        for j in range(i):
            if j == i - 1:
                block = sub[j]
            else:
                block = left[i] @ (np.prod(decay[j + 2:i], axis=0)[:, None] * right[j])
            S[i * b:i * b + b, j * b:j * b + b] = block + low[i] @ low[j].T
        S[n * b:, i * b:i * b + b] = tail_low @ low[i].T
    S = S + S.T
    S += (np.abs(np.linalg.eigvalsh(S)).max() + 1.0) * np.eye(N)
    diagonal = np.array([S[i * b:i * b + b, i * b:i * b + b] for i in range(n)])
    parts = BlockSemiseparable(diagonal, sub, left, right, decay, low, S[n * b:, n * b:],
                               tail_low if with_tail_low else None)
    return parts, S


def test_the_recursion_on_random_blocks_is_the_dense_cholesky():
    """The block recursion alone, on random generators, decays, neighbour blocks, low rank and a
    tail: S built entry by entry here from its definition, factored densely."""
    rng = np.random.default_rng(5)
    parts, S = _random_blocks(rng)
    N = len(S)
    whitener = parts.factor()
    x = rng.normal(size=(N, 4))
    expected = np.linalg.solve(np.linalg.cholesky(S), x)
    np.testing.assert_allclose(whitener @ x, expected, rtol=0, atol=1e-12 * np.abs(expected).max())
    np.testing.assert_allclose(whitener @ x[:, 0], expected[:, 0], rtol=0, atol=1e-12 * np.abs(expected).max())


def test_a_blocks_inverse_factor_is_numpys_and_a_singular_block_is_named():
    """The factor's 2×2 blocks (a motion's two residual components) in closed form: L⁻¹ as
    numpy's inv(cholesky) gives it, L⁻¹·S·L⁻ᵀ the identity, for blocks from near-singular to
    wide; a 3×3 goes through numpy; a block that is not positive definite is named."""
    from fieldcal.solvers.semiseparable import _inverse_cholesky

    rng = np.random.default_rng(8)
    for size, spread in ((2, 1.0), (2, 1e-6), (2, 1e6), (3, 1.0)):
        A = rng.normal(size=(size, size))
        S = A @ A.T + spread * np.eye(size)
        inverse = _inverse_cholesky(S, 0)
        np.testing.assert_allclose(inverse, np.linalg.inv(np.linalg.cholesky(S)), rtol=1e-10,
                                   atol=1e-12 * np.abs(inverse).max())
        np.testing.assert_allclose(inverse @ S @ inverse.T, np.eye(size), atol=1e-9)
        assert np.all(np.triu(inverse, 1) == 0.0)
    for singular in (np.array([[1.0, 1.0], [1.0, 1.0]]), np.array([[0.0, 0.0], [0.0, 1.0]]),
                     np.array([[1.0, 2.0], [2.0, 1.0]]), np.diag([1.0, -1.0, 1.0])):
        with pytest.raises(ValueError, match="not positive definite at block 7"):
            _inverse_cholesky(singular, 7)


@pytest.mark.parametrize("with_tail_low", [True, False])
def test_the_blocks_dense_matrix_is_the_one_built_from_its_definition(with_tail_low):
    parts, S = _random_blocks(np.random.default_rng(8), with_tail_low)
    np.testing.assert_allclose(parts.dense(), S, rtol=1e-13, atol=1e-13 * np.abs(S).max())
    whitener = parts.factor()
    assert whitener.shape == S.shape
    # L⁻¹·S·L⁻ᵀ = I for L the factor
    inverse = whitener.matrix_dense()
    np.testing.assert_allclose(inverse @ S @ inverse.T, np.eye(len(S)), atol=1e-10)


def test_a_block_that_is_not_positive_definite_is_named_by_its_index():
    parts, _ = _random_blocks(np.random.default_rng(9))
    diagonal = parts.diagonal.copy()
    diagonal[4] = -np.eye(2)  # blocks 0-3 factor; block 4 cannot
    broken = BlockSemiseparable(diagonal, parts.sub, parts.left, parts.right, parts.decay, parts.low,
                                parts.tail_diagonal, parts.tail_low)
    with pytest.raises(ValueError, match=r"^not positive definite at block 4$"):
        broken.factor()
    # The tail (the side equations after the n blocks) is block n when it cannot be factored.
    n, t = len(parts.diagonal), len(parts.tail_diagonal)
    assert t > 0
    bad_tail = BlockSemiseparable(parts.diagonal, parts.sub, parts.left, parts.right, parts.decay, parts.low,
                                  -np.eye(t), parts.tail_low)
    with pytest.raises(ValueError, match=rf"^not positive definite at block {n}$"):
        bad_tail.factor()


def test_chained_poses_with_dense_windows_refuse_blocks_by_name():
    """A dense window covariance has no Markov generators to put into a BlockSemiseparable:
    ``blocks`` refuses it in words (its caller then takes the dense path)."""
    from fieldcal.solvers.semiseparable import ChainedPoses

    k = 2
    chained = ChainedPoses(start=np.ones((k, 2, 1)), end=np.ones((k, 2, 1)), shared=np.zeros((k, 2, 9)),
                           theta_covariance=np.eye(9), own_diagonal=np.tile(np.eye(2), (k, 1, 1)),
                           own_sub=np.zeros((k - 1, 2, 2)), windows=np.eye(k + 1))
    with pytest.raises(ValueError, match="^dense windows have no generators$"):
        chained.blocks()
