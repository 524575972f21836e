"""The classic least-squares and six-position solutions' σ, covariance and diagnostics, against
hand-worked values (six faces, residuals chosen orthogonal to the design) and against the scatter
of the estimates over seeded noise draws (the truth the stated covariance claims)."""
import numpy as np
import pytest

from fieldcal.solvers.classic import solve_classic, solve_six_position

G = 9.8
FACES = np.vstack([np.eye(3), -np.eye(3)])  # +x, +y, +z, −x, −y, −z
# counts per m/s²: a k far from 1, so a term's σ divided by k and one multiplied by it differ
K_TRUE = np.array([[1000.0, 12.0, -7.0], [5.0, 980.0, 9.0], [-4.0, 6.0, 1020.0]])
B_TRUE = np.array([30.0, -12.0, 8.0])
# Orthogonal to every column of the design [±g on each axis, 1]: moves no coefficient
PATTERN = np.array([1.0, -1.0, 0.0, 1.0, -1.0, 0.0])


def _parameters(K, bias):
    """bias, K_ii and m_ij = K_ij / K_ii in FULL_PARAM_NAMES' order."""
    rows, cols = np.nonzero(~np.eye(3, dtype=bool))
    k = np.diagonal(K, axis1=-2, axis2=-1)
    return np.concatenate([bias, k, K[..., rows, cols] / k[..., rows]], axis=-1)


def test_residual_scatter_sigma_and_covariance_by_hand_on_six_faces():
    c = np.array([0.6, -1.5, 2.4])  # each output axis's residual size
    inputs = G * FACES
    means = inputs @ K_TRUE.T + B_TRUE + PATTERN[:, None] * c
    sol = solve_classic(means, inputs, "accelerometer", "specific_force", output_unit="counts")
    np.testing.assert_allclose(sol.K, K_TRUE, rtol=1e-12)
    np.testing.assert_allclose(sol.bias, B_TRUE, rtol=1e-12)
    # s_i² = Σe²/(n − 4) = 4c²/2 = 2c²; DᵀD = diag(2g², 2g², 2g², 6)
    sigma_bias = np.abs(c) / np.sqrt(3)  # √(2c²/6)
    sigma_k = np.abs(c) / G  # √(2c²/2g²)
    rows, cols = np.nonzero(~np.eye(3, dtype=bool))
    sigma_m = sigma_k[rows] / np.diag(K_TRUE)[rows]
    expected = np.concatenate([sigma_bias, sigma_k, sigma_m])
    np.testing.assert_allclose(sol.sigma, expected, rtol=1e-10)
    np.testing.assert_allclose(np.sqrt(np.diag(sol.covariance)), expected, rtol=1e-10)
    # the axes' residuals are correlated: cov(bias_x, bias_y) = c_x c_y·(4/2)/6
    assert sol.covariance[0, 1] == pytest.approx(c[0] * c[1] / 3, rel=1e-10)
    assert sol.covariance[3, 4] == 0.0  # K_xx and K_yy: different inputs, DᵀD diagonal
    # K_xx and K_yx (same input x): c_x c_y·(4/2)/(2g²), m_yx = K_yx / K_yy
    assert sol.covariance[3, 8] == pytest.approx(c[0] * c[1] / G**2 / K_TRUE[1, 1], rel=1e-10)
    assert sol.diagnostics.message == "closed form (linear least squares)"
    assert sol.diagnostics.dof == 18 - 12  # six positions of three outputs, twelve coefficients


def test_stated_covariance_is_the_scatter_of_the_estimates_over_noise_draws():
    inputs = G * np.vstack([FACES, [[0.6, 0.8, 0.0], [0.0, -0.6, 0.8]]])
    n = len(inputs)
    rng = np.random.default_rng(26)
    root = rng.normal(size=(3 * n, 3 * n)) * 0.3 + np.eye(3 * n)
    covariance = root @ root.T  # correlated across positions and axes
    sol = solve_classic(inputs @ K_TRUE.T + B_TRUE, inputs, "accelerometer", "specific_force",
                        output_unit="counts", covariance=covariance)
    assert sol.diagnostics.dof == 3 * n - 12
    draws = 4000
    noise = rng.normal(size=(draws, 3 * n)) @ np.linalg.cholesky(covariance).T
    means = inputs @ K_TRUE.T + B_TRUE + noise.reshape(draws, n, 3)
    design = np.column_stack([inputs, np.ones(n)])
    coef = np.linalg.pinv(design) @ means  # (draws, 4, 3): each draw's own least squares
    estimates = _parameters(np.transpose(coef[:, :3], (0, 2, 1)), coef[:, 3])
    scatter = np.cov(estimates, rowvar=False)
    spread = np.sqrt(np.diag(scatter))
    np.testing.assert_allclose(sol.sigma, spread, rtol=0.08)  # 4000 draws: σ's own error ~1.1 %
    np.testing.assert_allclose(np.sqrt(np.diag(sol.covariance)), spread, rtol=0.08)
    correlation = sol.covariance / np.outer(spread, spread)
    np.testing.assert_allclose(correlation, scatter / np.outer(spread, spread), atol=0.08)


def test_outputs_of_four_columns_are_refused_even_when_both_shapes_agree():
    with pytest.raises(ValueError, match=r"^gyro: outputs \(6, 4\) and inputs \(6, 4\) must both be \(n, 3\)$"):
        solve_classic(np.ones((6, 4)), np.ones((6, 4)), "gyro", "angular_rate")


def _six_faces_covariance(rng):
    root = np.diag(rng.uniform(0.5, 2.0, 18)) + 0.1 * rng.normal(size=(18, 18))
    return root @ root.T


def test_six_position_chi2_is_chi2_distributed_with_six_dof_over_noise_draws():
    """r = (I − D·L)·U has rank 6: χ² over seeded draws has mean 6 and variance 12."""
    rng = np.random.default_rng(7)
    covariance = _six_faces_covariance(rng)
    exact = G * FACES @ K_TRUE.T + B_TRUE
    chi2s, reduced = [], []
    chol = np.linalg.cholesky(covariance)
    for noise in rng.normal(size=(300, 18)) @ chol.T:
        sol, ratio = solve_six_position(exact + noise.reshape(6, 3), G, "accelerometer", "specific_force",
                                        "counts", covariance)
        assert sol.diagnostics.dof == 6  # 18 face means, 12 coefficients
        assert ratio == pytest.approx(sol.diagnostics.chi2 / 6, rel=1e-12)
        chi2s.append(sol.diagnostics.chi2)
        reduced.append(ratio)
    # mean of 300 χ²₆: 6 ± √(12/300) = 0.2
    assert np.mean(chi2s) == pytest.approx(6.0, abs=0.8)
    assert np.mean(reduced) == pytest.approx(1.0, abs=0.8 / 6)


def test_six_position_sigma_is_the_scatter_of_its_closed_form_over_noise_draws():
    rng = np.random.default_rng(11)
    covariance = _six_faces_covariance(rng) * 1e-2
    exact = G * FACES @ K_TRUE.T + B_TRUE
    sol, _ = solve_six_position(exact, G, "accelerometer", "specific_force", "counts", covariance)
    assert sol.diagnostics.message == ("closed form (Ferraris: each axis's bias from its own up and down "
                                       "faces), the faces' norms fitted")
    draws = rng.normal(size=(3000, 18)) @ np.linalg.cholesky(covariance).T
    faces = exact + draws.reshape(-1, 6, 3)
    # Ferraris by hand: column j of K is (face +j − face −j)/2g; bias i is (face +i + face −i)/2 of axis i
    K = np.transpose((faces[:, :3] - faces[:, 3:]) / (2 * G), (0, 2, 1))
    bias = (np.diagonal(faces[:, :3], axis1=1, axis2=2) + np.diagonal(faces[:, 3:], axis1=1, axis2=2)) / 2
    spread = np.std(_parameters(K, bias), axis=0, ddof=1)
    np.testing.assert_allclose(sol.sigma, spread, rtol=0.1)
    np.testing.assert_allclose(np.sqrt(np.diag(sol.covariance)), spread, rtol=0.1)


def test_residuals_are_in_the_output_unit_and_a_covariance_of_the_wrong_size_is_one_line():
    inputs = G * FACES
    means = inputs @ K_TRUE.T + B_TRUE + PATTERN[:, None] * 0.5
    sol = solve_classic(means, inputs, "accelerometer", "specific_force", output_unit="counts")
    assert sol.residual_unit == "counts"
    six, _ = solve_six_position(means, G, "accelerometer", "specific_force", "counts", np.eye(18))
    assert six.residual_unit == "counts"
    with pytest.raises(ValueError, match=r"^accel: covariance must be \(18, 18\), got \(17, 17\)$"):
        solve_classic(means, inputs, "accel", "specific_force", covariance=np.eye(17))


def test_faces_too_far_from_a_six_position_run_keep_the_closed_form():
    """Faces whose norms miss g by 5 %: fitting them would move K's diagonal by 5 %, beyond the 1 %
    a second-order correction may: the closed form is returned as it was."""
    from fieldcal.solvers.classic import fit_face_norms

    faces = G * FACES @ K_TRUE.T + B_TRUE
    K0, b0 = np.diag(np.diag(K_TRUE)) / 1.0, B_TRUE.copy()
    K, bias = fit_face_norms(K0, b0, faces, 1.05 * G)
    np.testing.assert_array_equal(K, K0)
    np.testing.assert_array_equal(bias, b0)
    K, bias = fit_face_norms(K0, b0, faces, 1.001 * G)  # 0.1 %: fitted, each face's norm g
    calibrated = (faces - bias) @ np.linalg.inv(K).T
    np.testing.assert_allclose(np.linalg.norm(calibrated, axis=1), 1.001 * G, rtol=1e-12)
