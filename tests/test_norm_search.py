"""solve_norm's search and its messages, each against a hand-worked value or a peer optimiser
(the mutation run of fieldcal/solvers/norm.py, docs/benchmarks.md, found these unguarded)."""
import math

import numpy as np
import pytest
from scipy import optimize

from fieldcal.model import distort_with
from fieldcal.procedure.positions import load_procedure
from fieldcal.solvers import CalibrationError, StaticNormProblem, solve_norm

G = 9.80
UP18 = np.array([p.up_body for p in load_procedure("field-18").positions])
# bias (m/s²), scale factors, misalignment angles (rad)
TRUTH = np.array([0.3, -0.2, 0.1, 1.02, 0.97, 1.01, 0.01, -0.02, 0.015])
UP12 = np.array([p.up_body for p in load_procedure("classic-12").positions])


def test_degenerate_positions_say_how_many_distinct_axes_they_span():
    # classic-12 points gravity along +x, +y, +z, -x, -y, -z, twice each: 12 measurements,
    # and ±x is one axis, so 3 distinct axes.
    rng = np.random.default_rng(3)
    truth = np.array([0.01, 0.02, 0.03, 1.0001, 1.0002, 1.0003, 2e-4, -3e-4, 4e-4])
    means = distort_with(truth, G * UP12) + rng.normal(0, 5e-4, (12, 3))
    with pytest.raises(CalibrationError) as raised:
        solve_norm(StaticNormProblem(means, G), np.full((12, 3), 5e-4))
    assert ("12 measurements point along only 3 distinct axes (10° apart); add positions with an axis "
            "between the cube faces (paper Table 2, positions 13-18)") in str(raised.value)


def field18_accelerometer(seed: int = 7, noise: float = 5e-4) -> StaticNormProblem:
    rng = np.random.default_rng(seed)
    up = UP18 + rng.normal(0, 0.03, UP18.shape)
    up /= np.linalg.norm(up, axis=1, keepdims=True)
    return StaticNormProblem(distort_with(TRUTH, G * up) + rng.normal(0, noise, up.shape), G)


def test_sigma_scales_with_the_stated_noise_while_the_scatter_agrees_with_it():
    # Weights 1/c² give the same solution and a covariance c² times as large: stating twice the
    # noise doubles every σ (and χ² drops to a quarter, still consistent, so nothing is rescaled).
    problem = field18_accelerometer()
    stated = solve_norm(problem, np.full((18, 3), 5e-4))
    doubled = solve_norm(problem, np.full((18, 3), 1e-3))
    assert not stated.diagnostics.scaled_by_residuals and not doubled.diagnostics.scaled_by_residuals
    np.testing.assert_allclose(doubled.sigma, 2 * stated.sigma, rtol=1e-4)
    np.testing.assert_allclose(doubled.diagnostics.chi2, stated.diagnostics.chi2 / 4, rtol=1e-4)
    np.testing.assert_allclose(doubled.theta, stated.theta, rtol=0, atol=1e-3 * stated.sigma.min())


def test_noise_stated_far_below_the_scatter_gives_the_scatters_sigma():
    # χ² = 100·dof and 400·dof (noise stated 10 and 20 times too small) is far beyond chance: σ then
    # come from the scatter (Birge), the same whichever too-small noise was stated, and equal to
    # the honest statement's σ times √(χ²/dof) of that honest solve.
    problem = field18_accelerometer()
    honest = solve_norm(problem, np.full((18, 3), 5e-4))
    tenth, twentieth = (solve_norm(problem, np.full((18, 3), 5e-4 / c)) for c in (10, 20))
    assert tenth.diagnostics.scaled_by_residuals and twentieth.diagnostics.scaled_by_residuals
    expected = honest.sigma * np.sqrt(honest.diagnostics.chi2 / honest.diagnostics.dof)
    np.testing.assert_allclose(tenth.sigma, expected, rtol=1e-4)
    np.testing.assert_allclose(twentieth.sigma, expected, rtol=1e-4)


def test_one_degree_of_freedom_is_enough_to_see_a_scatter_far_beyond_the_stated_noise():
    # Ten positions, nine unknowns: one degree of freedom (a draw whose honest χ² is 0.71), and
    # noise stated 100 times too small.
    problem = field18_accelerometer(seed=3)
    problem = StaticNormProblem(problem.means[:10], G)
    honest = solve_norm(problem, np.full((10, 3), 5e-4))
    understated = solve_norm(problem, np.full((10, 3), 5e-6))
    assert understated.diagnostics.dof == 1 and understated.diagnostics.scaled_by_residuals
    np.testing.assert_allclose(understated.sigma,
                               honest.sigma * np.sqrt(honest.diagnostics.chi2 / honest.diagnostics.dof), rtol=1e-4)


@pytest.mark.parametrize("positions", [18, 10])
@pytest.mark.parametrize("method", ["gauss-newton", "powell"])
def test_the_search_without_a_noise_model_lands_on_the_least_squares_optimum(method, positions):
    # Without a stated noise both searches measure their steps, tolerances and box in σ of the
    # residual scatter (the Gauss-Newton screen is the pose chooser's); scipy's least_squares,
    # started at the truth with tolerances at rounding, is the peer that says where the
    # unweighted optimum is. Ten positions leave one degree of freedom.
    problem = field18_accelerometer(seed=3)
    problem = StaticNormProblem(problem.means[:positions], G)
    solved = solve_norm(problem, None, method=method)
    peer = optimize.least_squares(lambda th: problem.residuals(th, problem.data), TRUTH,
                                  x_scale=np.abs(TRUTH) * 1e-4 + 1e-6, xtol=1e-15, ftol=1e-15, gtol=1e-15).x
    assert solved.method == ("lsq" if method == "gauss-newton" else method) and solved.diagnostics.search == method
    assert solved.diagnostics.scaled_by_residuals and solved.diagnostics.dof == positions - 9
    np.testing.assert_allclose(solved.theta, peer, rtol=0, atol=1e-3 * solved.sigma.min())


def test_each_refusal_is_one_line_naming_the_triad_and_the_count():
    means = field18_accelerometer().means
    refusals = {
        "accelerometer: 7 equations for 9 unknowns; add at least 2 more positions":
            lambda: solve_norm(StaticNormProblem(means[:7], G)),
        "accelerometer: 9 equations fit exactly and leave no scatter to estimate the uncertainty; "
        "add a position or give σ": lambda: solve_norm(StaticNormProblem(means[:9], G)),
        "accelerometer: covariance must be (54, 54) or (18, 3) sigmas, got (4, 4)":
            lambda: solve_norm(StaticNormProblem(means, G), np.ones((4, 4))),
        "method: expected one of powell, lsq, got 'newton'":
            lambda: solve_norm(StaticNormProblem(means, G), method="newton"),
        "accelerometer: positions are degenerate: all averages are identical":
            lambda: solve_norm(StaticNormProblem(np.ones((18, 3)), G)),
    }
    for message, refused in refusals.items():
        with pytest.raises(ValueError) as raised:
            refused()
        assert str(raised.value) == message


@pytest.mark.parametrize("form", ["per-axis sigmas", "full covariance"])
def test_an_average_without_noise_is_refused_as_a_covariance_not_positive_definite(form):
    # One average stated exact (σ 0 on every axis): its residual has zero variance and no weight exists.
    means = field18_accelerometer().means
    sigmas = np.full((18, 3), 5e-4)
    sigmas[4] = 0.0
    covariance = sigmas if form == "per-axis sigmas" else np.diag(sigmas.ravel() ** 2)
    with pytest.raises(CalibrationError) as raised:
        solve_norm(StaticNormProblem(means, G), covariance)
    assert str(raised.value) == "accelerometer: the covariance of the averages is not positive definite"


class _Directions:
    """What _spread_hint reads of a problem: its measured directions."""

    def __init__(self, *tilts_deg):
        # math's sin and cos, as _spread_hint's threshold is math.cos(math.radians(10)): the 10°
        # case then sits on the edge to the bit on any machine (numpy's SIMD cos may differ by an ulp)
        self.rows = np.array([[0.0, math.sin(math.radians(t)), math.cos(math.radians(t))] for t in tilts_deg])

    def directions(self):
        return self.rows


@pytest.mark.parametrize("tilts_deg, axes", [((0, 10.5), 2), ((0, 9.5), 1), ((0, 10), 1), ((0, 180), 1),
                                             ((0, 90, 45, 135), 4)])
def test_the_hint_counts_axes_more_than_ten_degrees_apart(tilts_deg, axes):
    from fieldcal.solvers.norm import _spread_hint

    assert _spread_hint(_Directions(*tilts_deg)).startswith(
        f"{len(tilts_deg)} measurements point along only {axes} distinct axes (10° apart)")


def test_the_screen_counts_its_iterations_and_evaluations():
    # It starts at the linearised optimum, so its first Gauss-Newton step is rounding-small: one
    # iteration, which evaluates the start, 2 × 9 central differences and the stepped point.
    for covariance in (None, np.full((18, 3), 5e-4)):
        screened = solve_norm(field18_accelerometer(), covariance, method="gauss-newton")
        assert (screened.diagnostics.iterations, screened.diagnostics.evaluations) == (1, 1 + 2 * 9 + 1)
        assert screened.diagnostics.message == "the Gauss-Newton step is below 1e-4 σ"


# Gauss-Newton on problems worked by hand (residuals_of_z takes a stack of points (k, n)).
def _square(z):  # r = z²: the Jacobian 2z makes every step −z/2, so z halves each iteration
    return z**2


def _arctan(z):  # r = arctan z: from |z| > 1.39 the step −(1 + z²)·arctan z overshoots (χ² grows)
    return np.arctan(z)


def test_gauss_newton_halving_stops_once_a_step_is_below_its_tolerance():
    from fieldcal.solvers.norm import _gauss_newton

    # From z = 1 the k-th step is 2⁻ᵏ, first below 1e-4 at k = 14 (2¹⁴ = 16384); it is taken.
    res = _gauss_newton(_square, np.array([1.0]), per_sigma=True, dof=1)
    assert res.success and res.nit == 14 and res.nfev == 1 + 14 * 3
    np.testing.assert_allclose(res.x, [2.0**-14], rtol=1e-9)


def test_gauss_newton_gives_up_after_twenty_steps():
    from fieldcal.solvers.norm import _gauss_newton

    # From z = 1000 the 20th step is still 1000·2⁻²⁰ ≈ 1e-3: no convergence, z after 20 halvings.
    res = _gauss_newton(_square, np.array([1000.0]), per_sigma=True, dof=1)
    assert not res.success and res.nit == 20 and res.nfev == 1 + 20 * 3
    assert res.message == "no convergence in 20 Gauss-Newton steps"
    np.testing.assert_allclose(res.x, [1000.0 * 2.0**-20], rtol=1e-9)


def test_gauss_newton_refuses_a_step_that_raises_chi2_and_stays_where_it_was():
    from fieldcal.solvers.norm import _gauss_newton

    res = _gauss_newton(_arctan, np.array([2.0]), per_sigma=True, dof=1)  # the step lands at -3.53
    assert not res.success and res.nit == 1 and res.nfev == 1 + 3
    assert res.message == "a Gauss-Newton step did not lower χ²" and res.x.tolist() == [2.0]
    converged = _gauss_newton(_arctan, np.array([1.0]), per_sigma=True, dof=1)
    assert converged.success and abs(converged.x[0]) < 1e-4


def test_a_covariance_kept_by_its_parts_weighs_as_its_dense_form():
    # Means sharing a slow bias (each pair of windows correlated by half their common-mode
    # variance) plus each its own white noise: the parts' residual covariance, made in O(m²)
    # without the (3m, 3m) matrix, must give the solve its dense Kronecker form gives.
    from fieldcal.recording.up_covariance import MeansCovariance

    problem = field18_accelerometer()
    parts = MeansCovariance(windows=(2e-4) ** 2 * (0.5 + 0.5 * np.eye(18)), K=np.diag([1.02, 0.97, 1.01]),
                            own=np.full((18, 3), (5e-4) ** 2))
    by_parts, dense = solve_norm(problem, parts), solve_norm(problem, parts.dense())
    np.testing.assert_allclose(by_parts.theta, dense.theta, rtol=0, atol=1e-4 * dense.sigma.min())
    np.testing.assert_allclose(by_parts.sigma, dense.sigma, rtol=1e-6)
    np.testing.assert_allclose(by_parts.diagnostics.chi2, dense.diagnostics.chi2, rtol=1e-6)


def _tilted_up(rng):
    """field-18's up directions, each tilted by some 2° at random (a hand-placed unit)."""
    up = UP18 + rng.normal(0, 0.03, UP18.shape)
    return up / np.linalg.norm(up, axis=1, keepdims=True)


def _rate_problem(up, plus_noise, minus_noise):
    """A gyro's norm problem: turned at +10 °/s and -10 °/s about each ``up`` at 40° latitude,
    read through GYRO_TRUTH, with the noise given added to each turn's averages."""
    from fieldcal.solvers import RateNormProblem

    rate, earth, vertical = np.radians(10), 7.292115e-5, 7.292115e-5 * np.sin(np.radians(40))
    plus = distort_with(GYRO_TRUTH, (rate + vertical) * up) + plus_noise
    minus = distort_with(GYRO_TRUTH, (vertical - rate) * up) + minus_noise
    return RateNormProblem(plus, minus, rate, np.empty((0, 3)), np.empty(0, int), earth, vertical)


GYRO_TRUTH = np.array([1e-3, -2e-3, 5e-4, 1.02, 0.97, 1.01, 0.01, -0.02, 0.015])


def test_a_gyros_covariance_kept_by_its_parts_weighs_as_its_dense_form():
    # A gyro's norm residuals have no per-average gradient (point_gradients): its parts are made
    # dense, and must weigh as the dense form given directly.
    from fieldcal.recording.up_covariance import MeansCovariance

    rng = np.random.default_rng(5)
    up = _tilted_up(rng)
    noise = 5e-6
    problem = _rate_problem(up, rng.normal(0, noise, up.shape), rng.normal(0, noise, up.shape))
    parts = MeansCovariance(windows=(2e-6) ** 2 * (0.5 + 0.5 * np.eye(36)), K=np.diag([1.02, 0.97, 1.01]),
                            own=np.full((36, 3), noise**2))
    by_parts, dense = solve_norm(problem, parts), solve_norm(problem, parts.dense())
    np.testing.assert_allclose(by_parts.theta, dense.theta, rtol=0, atol=1e-6 * dense.sigma.min())
    np.testing.assert_allclose(by_parts.sigma, dense.sigma, rtol=1e-9)


def test_axis_aligned_positions_are_refused_by_their_geometry_before_any_search():
    # classic-12's six directions leave a singular value some 1e-6 of the largest (the module's
    # comment); the geometry check (ratio 1e-4) refuses them, naming a condition number above 1e4,
    # not the σ check after the search.
    rng = np.random.default_rng(3)
    means = distort_with(TRUTH, G * UP12) + rng.normal(0, 5e-4, (12, 3))
    with pytest.raises(CalibrationError) as raised:
        solve_norm(StaticNormProblem(means, G), np.full((12, 3), 5e-4))
    message = str(raised.value)
    assert message.startswith("accelerometer: positions are degenerate (condition number ")
    assert float(message.split("condition number ")[1].split(")")[0]) > 1e4


def test_a_parameter_known_worse_than_a_hundredth_of_its_scale_is_refused_naming_it():
    # Noise-free averages (χ² 0: nothing rescaled) solved with a stated noise: every σ is
    # proportional to it. At 1 mm/s² all are far below 1 % of their natural unit (k·g for a bias,
    # k for a scale factor, 1 rad for an angle); stated so that the worst reaches 1.5 %, the solve
    # must refuse, naming that parameter, its σ in its unit, and the geometry's condition number
    # (which the noise does not change).
    means = distort_with(TRUTH, G * UP18)
    small = solve_norm(StaticNormProblem(means, G), np.full((18, 3), 1e-3))
    natural = np.r_[TRUTH[3:6] * G, TRUTH[3:6], np.ones(3)]
    relative = small.sigma / natural
    worst = int(np.argmax(relative))
    factor = 0.015 / relative[worst]
    with pytest.raises(CalibrationError) as raised:
        solve_norm(StaticNormProblem(means, G), np.full((18, 3), 1e-3 * factor))
    from fieldcal.model import PARAM_NAMES

    message = str(raised.value)
    assert message.startswith(
        f"accelerometer: positions are degenerate: {PARAM_NAMES[worst]} is determined only to ±0.015 of its "
        f"scale (condition number {small.diagnostics.condition_number:.3g}); 18 measurements point along only ")
    assert message.endswith("add positions with an axis between the cube faces (paper Table 2, positions 13-18)")


def test_nine_positions_with_a_stated_noise_are_solved_with_sigma_from_that_noise_alone():
    # Nine equations, nine unknowns: no scatter is left (χ² ~ 0 on 0 degrees of freedom), so σ
    # can only come from the stated noise, proportional to it, and nothing is rescaled.
    problem = StaticNormProblem(field18_accelerometer(seed=3).means[:9], G)
    stated = solve_norm(problem, np.full((9, 3), 5e-5))  # (at 5e-4 an angle is known only to 1.4 %)
    doubled = solve_norm(problem, np.full((9, 3), 1e-4))
    assert stated.diagnostics.dof == 0 and not stated.diagnostics.scaled_by_residuals
    assert np.all(np.isfinite(stated.sigma)) and stated.diagnostics.chi2 < 1e-6
    np.testing.assert_allclose(doubled.sigma, 2 * stated.sigma, rtol=1e-4)


def test_a_gyros_per_axis_sigmas_weigh_as_their_diagonal_covariance():
    # A gyro's residuals have no per-average gradient, so per-axis σ (n, 3) are made the diagonal
    # covariance whose variances they are (σ², each its own): the same solve as that matrix given.

    rng = np.random.default_rng(6)
    up = _tilted_up(rng)
    sigmas = 5e-6 * rng.uniform(0.5, 2.0, (36, 3))
    problem = _rate_problem(up, rng.normal(0, 1.0, up.shape) * sigmas[:18],
                            rng.normal(0, 1.0, up.shape) * sigmas[18:])
    per_axis, dense = solve_norm(problem, sigmas), solve_norm(problem, np.diag(sigmas.ravel() ** 2))
    np.testing.assert_allclose(per_axis.theta, dense.theta, rtol=0, atol=1e-6 * dense.sigma.min())
    np.testing.assert_allclose(per_axis.sigma, dense.sigma, rtol=1e-9)
    np.testing.assert_allclose(per_axis.diagnostics.chi2, dense.diagnostics.chi2, rtol=1e-9)
