"""The norm solvers against synthetic truth: convergence from the closed-form start, failures."""
import math

import numpy as np
import pytest
from scipy import optimize
from scipy.spatial.transform import Rotation

from fieldcal.model import calibrate_with, distort_with, k_from_params
from fieldcal.procedure.positions import load_procedure
from fieldcal.solvers import CalibrationError, RateNormProblem, StaticNormProblem, solve_norm

G = 9.80
UP18 = np.array([p.up_body for p in load_procedure("field-18").positions])
UP12 = np.array([p.up_body for p in load_procedure("classic-12").positions])


def placed(up, rng, sigma_deg=3.0):
    tilts = Rotation.from_rotvec(rng.normal(0, math.radians(sigma_deg), (len(up), 3)))
    return tilts.apply(up)


def large_errors(rng, sensitivity=1.0, zero=0.0):
    bias = rng.uniform(-0.5, 0.5, 3) * G
    scale = 1 + rng.uniform(-0.1, 0.1, 3)
    mis = rng.uniform(-1, 1, 3) * math.radians(3)
    return np.r_[zero + bias * sensitivity, scale * sensitivity, mis]


def assert_z_scores_standard(z: np.ndarray, second_moment: float = 1.0) -> None:
    """(draws, 9) errors in units of their reported σ, one row per independent draw: each
    parameter's mean near 0 and mean square near ``second_moment`` (1 for N(0, 1); ν/(ν − 2)
    for Student's t with ν dof, σ from a residual scatter), within ~4 standard errors."""
    n = len(z)
    assert n >= 100, "too few draws to judge σ"
    mean, square = z.mean(axis=0), np.mean(z**2, axis=0)
    assert np.all(np.abs(mean) < 4.0 * np.sqrt(second_moment / n)), mean
    # z² of Student's t has a heavy tail: its mean wanders more than χ²'s (±35 % over 100 draws)
    assert np.all((square > 0.6 * second_moment) & (square < 1.5 * second_moment)), square
    assert 0.8 * second_moment < square.mean() < 1.25 * second_moment, square


def optimum_from_truth(problem, noise, truth):
    """An independent optimiser started at the truth: where the weighted optimum really is.

    A residual |K⁻¹(u − b)| − g moves by âᵀK⁻¹·δu for a change δu of the average, so with
    isotropic noise its σ is noise·|K⁻ᵀâ|, â the calibrated direction.
    """
    K_inv = np.linalg.inv(k_from_params(truth))
    a = calibrate_with(truth, problem.means)
    sigma = noise * np.linalg.norm((a / np.linalg.norm(a, axis=1, keepdims=True)) @ K_inv, axis=1)
    res = optimize.least_squares(lambda th: problem.residuals(th, problem.data) / sigma, truth,
                                 x_scale=np.abs(truth) * 1e-4 + 1e-6, xtol=1e-15, ftol=1e-15, gtol=1e-15)
    return res.x


@pytest.mark.parametrize("sensitivity, zero, noise", [(1.0, 0.0, 5e-4), (415.0, 32768.0, 0.2)],
                         ids=["si", "raw-16-bit-counts"])
def test_powell_converges_from_closed_form_start_in_every_draw(sensitivity, zero, noise):
    rng = np.random.default_rng(2024)
    z = []
    for draw in range(100):
        truth = large_errors(rng, sensitivity, zero)
        means = distort_with(truth, G * placed(UP18, rng)) + rng.normal(0, noise, (18, 3))
        problem = StaticNormProblem(means, G, output_unit="count" if zero else "m/s^2")
        sol = solve_norm(problem, np.full((18, 3), noise))
        # The radial σ of a residual is about noise / k; the optimum is where a truth-started
        # optimiser lands, and Powell must land there too, to a small fraction of 1σ.
        optimum = optimum_from_truth(problem, noise, truth)
        assert np.all(np.abs(sol.theta - optimum) < 1e-3 * sol.sigma), f"draw {draw}"
        z.append((sol.theta - truth) / sol.sigma)
    assert_z_scores_standard(np.array(z))


def test_powell_and_least_squares_agree():
    rng = np.random.default_rng(5)
    truth = large_errors(rng)
    problem = StaticNormProblem(distort_with(truth, G * placed(UP18, rng)) + rng.normal(0, 5e-4, (18, 3)), G)
    powell = solve_norm(problem, np.full((18, 3), 5e-4), method="powell")
    lsq = solve_norm(problem, np.full((18, 3), 5e-4), method="lsq")
    assert np.all(np.abs(powell.theta - lsq.theta) < 1e-3 * lsq.sigma)
    np.testing.assert_allclose(powell.sigma, lsq.sigma, rtol=1e-3)
    fit = powell.diagnostics
    assert fit.converged and fit.iterations >= 1 and fit.evaluations > fit.iterations


def test_solution_reports_residual_per_position_and_unweighted_sigma():
    rng = np.random.default_rng(6)
    truth = large_errors(rng)
    noise = 5e-4
    problem = StaticNormProblem(distort_with(truth, G * placed(UP18, rng)) + rng.normal(0, noise, (18, 3)), G)
    sol = solve_norm(problem)  # no σ given: uncertainty from the residual scatter
    assert sol.diagnostics.scaled_by_residuals and len(sol.residuals) == 18 and sol.diagnostics.dof == 9
    assert sol.residual_labels[0] == "static 1"
    # The residual RMS is of the order of the noise along gravity (with 9 of 18 dof used).
    assert 0.3 * noise < sol.residual_rms < 1.5 * noise
    # (whether that σ is honest: test_sigma_from_the_residual_scatter_is_honest_over_seeded_draws)


def moderate_errors(rng):
    """A unit near its nominal (bias 0.05 g, scale ±1 %, angles of a few mrad): the solve is
    close to linear over the noise, so z follows the distribution the linear theory gives."""
    return np.r_[rng.uniform(-0.05, 0.05, 3) * G, 1 + rng.uniform(-0.01, 0.01, 3), rng.uniform(-3e-3, 3e-3, 3)]


@pytest.mark.parametrize("stated", [None, 0.1], ids=["no-noise-model", "scatter-10x-the-stated-noise"])
def test_sigma_from_the_residual_scatter_is_honest_over_seeded_draws(stated):
    """σ-honesty of the solve that takes its σ from the residual scatter: without a noise model,
    and when the positions scatter ten times more than the stated noise (χ²/dof ≈ 100, Birge
    scaling). 18 positions leave ν = 9 dof: z = error/σ follows Student's t₉, E[z²] = 9/7 (as it
    is for any least-squares fit whose σ² is χ²/ν). A σ² from χ²/n instead (n = 18: the
    scatter divided by n, not n − 9) would make E[z²] 18/7."""
    rng = np.random.default_rng(2607)
    noise, z = 5e-4, []
    for _ in range(200):
        truth = moderate_errors(rng)
        problem = StaticNormProblem(distort_with(truth, G * placed(UP18, rng)) + rng.normal(0, noise, (18, 3)), G)
        sol = solve_norm(problem, None if stated is None else np.full((18, 3), stated * noise))
        assert sol.diagnostics.scaled_by_residuals and sol.diagnostics.dof == 9
        z.append((sol.theta - truth) / sol.sigma)
    assert_z_scores_standard(np.array(z), second_moment=9 / 7)


def test_too_few_positions_says_how_many_more():
    rng = np.random.default_rng(1)
    means = distort_with(large_errors(rng), G * placed(UP18[:7], rng))
    with pytest.raises(CalibrationError, match="add at least 2 more positions"):
        solve_norm(StaticNormProblem(means, G))


def test_nine_positions_without_sigma_is_refused():
    rng = np.random.default_rng(1)
    means = distort_with(large_errors(rng), G * placed(UP18[:9], rng))
    with pytest.raises(CalibrationError, match="no scatter"):
        solve_norm(StaticNormProblem(means, G))


def test_six_directions_of_the_classic_test_are_degenerate_for_the_norm_method():
    # The 12 classic positions point gravity along only ±x, ±y, ±z: the norm equations cannot
    # separate misalignment from the unknown orientations.
    rng = np.random.default_rng(3)
    truth = np.array([0.01, 0.02, 0.03, 1.0001, 1.0002, 1.0003, 2e-4, -3e-4, 4e-4])
    means = distort_with(truth, G * UP12) + rng.normal(0, 5e-4, (12, 3))
    with pytest.raises(CalibrationError, match="degenerate"):
        solve_norm(StaticNormProblem(means, G), np.full((12, 3), 5e-4))


def test_bad_inputs_are_clear_errors():
    with pytest.raises(ValueError, match=r"\(n, 3\)"):
        StaticNormProblem(np.zeros((5, 2)), G)
    with pytest.raises(ValueError, match="NaN"):
        StaticNormProblem(np.full((18, 3), np.nan), G)
    problem = StaticNormProblem(distort_with(large_errors(np.random.default_rng(0)), G * UP18), G)
    with pytest.raises(ValueError, match="method"):
        solve_norm(problem, method="newton")
    with pytest.raises(ValueError, match="covariance"):
        solve_norm(problem, np.ones((4, 4)))


def gyro_problem(rng, truth, rate=math.radians(10), noise=5e-6, n=18, static=True):
    d = placed(UP18[:n], rng)
    omega_e, lat = 7.292115e-5, math.radians(40)
    vertical = omega_e * math.sin(lat)
    plus = distort_with(truth, (rate + vertical) * d) + rng.normal(0, noise, (n, 3))
    minus = distort_with(truth, (-rate + vertical) * d) + rng.normal(0, noise, (n, 3))
    north = np.cross(d, rng.normal(size=(n, 3)))
    north /= np.linalg.norm(north, axis=1, keepdims=True)
    still = distort_with(truth, omega_e * (math.sin(lat) * d + math.cos(lat) * north)) \
        + rng.normal(0, noise, (n, 3))
    return RateNormProblem(plus, minus, rate, still if static else np.empty((0, 3)),
                           np.arange(n) if static else np.empty(0, int), omega_e, vertical)


def test_gyro_converges_with_large_errors():
    rng = np.random.default_rng(11)
    z = []
    for draw in range(30):
        truth = np.r_[rng.uniform(-1, 1, 3) * math.radians(5), 1 + rng.uniform(-0.1, 0.1, 3),
                      rng.uniform(-1, 1, 3) * math.radians(3)]
        problem = gyro_problem(rng, truth)
        sol = solve_norm(problem, np.full((54, 3), 5e-6))
        lsq = solve_norm(problem, np.full((54, 3), 5e-6), method="lsq")
        # Levenberg-Marquardt stops a few thousandths of σ short; Powell's χ² is never higher.
        assert np.all(np.abs(sol.theta - lsq.theta) < 1e-2 * sol.sigma), f"draw {draw}"
        assert sol.diagnostics.chi2 <= lsq.diagnostics.chi2 + 1e-6, f"draw {draw}"
        z.append((sol.theta - truth) / sol.sigma)
    # 30 draws: the nine parameters' z pooled (270 values) for the mean square, N(0, 1)'s being 1
    z = np.array(z)
    assert np.all(np.abs(z.mean(axis=0)) < 4.0 / np.sqrt(len(z))), z.mean(axis=0)
    assert 0.7 < np.mean(z**2) < 1.4, np.mean(z**2, axis=0)


def test_gyro_needs_rate_steps_about_six_axes():
    rng = np.random.default_rng(12)
    truth = np.array([1e-4, 2e-4, 3e-4, 1.0001, 1.0002, 1.0003, 2e-4, -3e-4, 4e-4])
    problem = gyro_problem(rng, truth, n=5)
    with pytest.raises(CalibrationError, match="degenerate"):
        solve_norm(problem, np.full((15, 3), 5e-6))


def test_residual_scatter_alone_under_reports_the_bias_sigma(field18):
    """Flicker bias instability moves every position's average alike; only the covariance of the
    averages (from the noise model and the timeline) knows that, the residual scatter cannot."""
    run = field18
    problem = run.problem("accelerometer", np.random.default_rng(4))
    with_model = solve_norm(problem, run.covariances["accelerometer"])
    scatter_only = solve_norm(problem)
    assert np.all(scatter_only.sigma[:3] < 0.7 * with_model.sigma[:3])


@pytest.mark.parametrize("name", ["accelerometer", "gyroscope"])
def test_powell_lands_on_the_weighted_optimum_of_field18(field18, name):
    """Field-18 with the full covariance of the averages, as the station solves: Powell's answer
    is where a tightly converged least-squares fit of the same weighted residuals lands, to a
    thousandth of σ, in every draw (with and without the covariance)."""
    from fieldcal.solvers.norm import _residual_whitener

    truth = field18.truth[name]
    for seed in range(4):
        problem = field18.problem(name, np.random.default_rng(seed))
        for covariance in (field18.covariances[name], None):
            sol = solve_norm(problem, covariance)
            # The solver's weights: the residual covariance at the closed-form start.
            weight = _residual_whitener(problem, problem.initial(), covariance)
            weight = np.eye(len(problem.residual_labels)) if weight is None else weight.matrix()
            ref = optimize.least_squares(lambda th: weight @ problem.residuals(th, problem.data),
                                         truth, x_scale=np.abs(truth) * 1e-4 + 1e-9,
                                         xtol=1e-15, ftol=1e-15, gtol=1e-15)
            assert np.all(np.abs(sol.theta - ref.x) < 1e-3 * sol.sigma), (seed, covariance is None)


def test_rate_residuals_evaluate_many_parameter_vectors_at_once():
    """The solvers' Jacobians evaluate a stack of parameter vectors (and of averages) in one call;
    each row must be the single evaluation."""
    rng = np.random.default_rng(3)
    truth = np.r_[rng.uniform(-1, 1, 3) * 1e-3, 1 + rng.uniform(-0.1, 0.1, 3), rng.uniform(-1, 1, 3) * 0.01]
    problem = gyro_problem(rng, truth)
    thetas = truth + rng.normal(0, 1e-3, (4, 9))
    data = problem.data + rng.normal(0, 1e-6, (4, len(problem.data)))
    stacked = problem.residuals(thetas, problem.data)
    assert stacked.shape == (4, len(problem.residual_labels))
    for i in range(4):
        np.testing.assert_array_equal(stacked[i], problem.residuals(thetas[i], problem.data))
        np.testing.assert_array_equal(problem.residuals(truth, data)[i], problem.residuals(truth, data[i]))
    # Against the model's own forward substitution: the norm of K⁻¹(u₊ − u₋)/2 is the table rate.
    half = 0.5 * (problem.plus - problem.minus)
    np.testing.assert_allclose(problem.residuals(truth, problem.data)[:18],
                               np.linalg.norm(calibrate_with(np.r_[0, 0, 0, truth[3:]], half), axis=1)
                               - problem.table_rate, rtol=0, atol=1e-12)


def test_one_parameter_vector_gives_the_stacked_evaluations_numbers_bit_for_bit():
    """K⁻¹ and −K⁻¹b of one parameter vector (what Powell evaluates, point by point) made from
    its nine numbers directly, against the stacked evaluation of the same vectors, at points
    around a raw-count triad's solution; the residuals Powell sees, and a hand-worked point."""
    from fieldcal.solvers.problems import StaticNormProblem, _inverse_affine

    rng = np.random.default_rng(12)
    up = rng.normal(size=(14, 3))
    up /= np.linalg.norm(up, axis=1)[:, None]
    K = np.array([[415.0, 0.0, 0.0], [2.1, 409.0, 0.0], [-3.3, 4.4, 421.0]])  # count per m/s²
    means = 9.81 * up @ K.T + 32768.0 + rng.normal(0.0, 0.3, (14, 3))
    problem = StaticNormProblem(means, 9.81, output_unit="count")
    theta0 = np.r_[32768.0, 32768.0, 32768.0, 415.0, 409.0, 421.0, 0.005, -0.008, 0.01]
    points = theta0 + rng.normal(size=(50, 9)) * np.r_[[0.5] * 3, [0.2] * 3, [1e-3] * 3]
    A_all, c_all = _inverse_affine(points)
    stacked = problem.residuals(points, problem.data)
    for theta, A, c, r in zip(points, A_all, c_all, stacked):
        one_A, one_c = _inverse_affine(theta)
        assert np.array_equal(one_A, A) and np.array_equal(one_c, c)
        assert np.array_equal(problem.residuals(theta, problem.data), r)
    # and a hand-worked point: K = I, no bias, no misalignment, so the residual is |mean| - g
    hand = StaticNormProblem(np.array([[3.0, 4.0, 0.0], [0.0, 0.0, 9.0]]), 5.0)
    assert hand.residuals(np.r_[0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0], hand.data).tolist() == [0.0, 4.0]


def _dense_whitener(problem, theta0, covariance):
    """The whitening as it was made before the per-average structure was used (the oracle):
    G = ∂r/∂u by 3n + 1 forward differences, the dense G·Σ·Gᵀ, its Cholesky factor inverted."""
    u = problem.data
    cov = np.asarray(covariance, dtype=float)
    if cov.shape == (len(u) // 3, 3):
        cov = np.diag(cov.ravel() ** 2)
    steps = 1e-6 * np.maximum(np.abs(u), np.abs(theta0[3:6]).max() * problem.reference_scale)
    values = problem.residuals(theta0, np.vstack([u, u + np.diag(steps)]))
    G = ((values[1:] - values[0]) / steps[:, None]).T
    return np.linalg.inv(np.linalg.cholesky(G @ cov @ G.T))


@pytest.mark.parametrize("form", ["per-axis sigmas", "full covariance"])
def test_the_per_average_whitening_is_the_dense_one(form):
    """Each norm residual depends on its own average alone: the whitening made from each
    residual's 3-vector gradient (no dense n×3n Jacobian, no O(n³) product) is the dense one's,
    to the forward differences' precision, and so is the solution, in raw counts as in SI."""
    from fieldcal.solvers.norm import _residual_whitener

    rng = np.random.default_rng(11)
    for sensitivity, zero in ((1.0, 0.0), (415.0, 32768.0)):
        truth, up = large_errors(rng, sensitivity, zero), placed(UP18, rng)
        means = distort_with(truth, G * up) + rng.normal(0, 0.01 * sensitivity, up.shape)
        problem = StaticNormProblem(means, G)
        sigmas = rng.uniform(0.005, 0.02, means.shape) * sensitivity
        if form == "per-axis sigmas":
            covariance = sigmas
        else:  # pose means that share a drift: every pair correlated
            shared = np.kron(np.full((len(means), len(means)), 0.3), np.eye(3)) + np.kron(
                np.eye(len(means)), np.eye(3) * 0.7)
            covariance = shared * np.outer(sigmas.ravel(), sigmas.ravel())
        theta0 = problem.initial()
        ours = _residual_whitener(problem, theta0, covariance).matrix()
        dense = _dense_whitener(problem, theta0, covariance)
        np.testing.assert_allclose(ours, dense, rtol=1e-5, atol=1e-5 * np.abs(dense).max())
        solved = solve_norm(problem, covariance)
        weight = dense
        ref = optimize.least_squares(lambda th: weight @ problem.residuals(th, problem.data), solved.theta,
                                     x_scale=solved.sigma, xtol=1e-15, ftol=1e-15, gtol=1e-15)
        assert np.all(np.abs(solved.theta - ref.x) < 1e-3 * solved.sigma)
