"""solve_norm's weights and searches at their edges, each against a hand-worked value: the
residuals' covariance of independent averages, by the gradients and by differences; a covariance
kept by its parts never made dense; Powell's box, its second search and a start already at a
zero-residual minimum; Gauss-Newton's stopping rule in σ of the solution and its refusal of a step
that raises χ²; the search's start at the Gauss-Newton step (the mutation sample of
fieldcal/solvers/norm.py of 2026-11-28, docs/benchmarks.md, found these unguarded)."""
import warnings
from types import SimpleNamespace

import numpy as np
import pytest
import scipy.optimize

from fieldcal.model import distort_with
from fieldcal.procedure.positions import load_procedure
from fieldcal.recording.up_covariance import MeansCovariance
from fieldcal.solvers import StaticNormProblem, norm, solve_norm

G = 9.8
IDENTITY = np.array([0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0])  # no bias, unit scales, no angles
# Three averages of |g| = 9.8 along (3, 4, 0)/5, z and (0, 6, 8)/10, each axis its own 1σ
MEANS = np.array([[5.88, 7.84, 0.0], [0.0, 0.0, 9.8], [0.0, 5.88, 7.84]])
SIGMAS = np.array([[1e-3, 2e-3, 3e-3], [4e-3, 5e-3, 6e-3], [7e-3, 8e-3, 9e-3]])
# With no calibration, r_i = |u_i| − g, whose gradient in u_i is its direction: the residuals'
# variances are Σ_a (u_ia/|u_i|)² σ_ia², worked by hand.
VARIANCES = np.array([0.36 * 1e-6 + 0.64 * 4e-6, 36e-6, 0.36 * 64e-6 + 0.64 * 81e-6])


def test_independent_averages_give_the_hand_worked_residual_variances():
    problem = StaticNormProblem(MEANS, G)
    variances = norm._residual_covariance(problem, IDENTITY, problem.data, SIGMAS)
    assert variances.shape == (3,)  # one number a residual: no 3×3 matrix made
    np.testing.assert_allclose(variances, VARIANCES, rtol=1e-13)


def test_a_problem_without_gradients_gets_the_same_variances_by_differences():
    # The averages off the sphere by 0.1 %, −0.1 %, 0.05 % (residuals of some 0.01 m/s², not
    # zero): each gradient is still its average's direction, the variances as worked above.
    problem = StaticNormProblem(MEANS * np.array([[1.001], [0.999], [1.0005]]), G)
    hidden = SimpleNamespace(residuals=problem.residuals, reference_scale=problem.reference_scale)
    covariance = norm._residual_covariance(hidden, IDENTITY, problem.data, SIGMAS)
    np.testing.assert_allclose(np.diag(covariance), VARIANCES, rtol=1e-5)
    off = covariance - np.diag(np.diag(covariance))
    assert np.abs(off).max() < 1e-6 * VARIANCES.min()  # each residual reads its own average alone


class PartsOnly(MeansCovariance):
    def dense(self):
        raise AssertionError("a covariance kept by its parts was made dense")


def test_a_covariance_kept_by_its_parts_weighs_as_its_dense_matrix_without_making_it():
    rng = np.random.default_rng(5)
    up = np.array([p.up_body for p in load_procedure("field-18").positions])
    truth = np.array([0.3, -0.2, 0.1, 1.02, 0.97, 1.01, 0.01, -0.02, 0.015])
    i = np.arange(18)
    windows = 1e-7 * 0.5 ** np.abs(i[:, None] - i[None, :])  # neighbouring windows correlated
    parts = PartsOnly(windows, np.diag([1.02, 0.97, 1.01]), np.full((18, 3), 2.5e-7))
    means = distort_with(truth, G * up) + rng.normal(0, 5e-4, up.shape)
    problem = StaticNormProblem(means, G)
    theta0 = problem.initial()
    weights = norm._residual_whitener(problem, theta0, parts).matrix()
    dense_weights = norm._residual_whitener(problem, theta0, MeansCovariance.dense(parts)).matrix()
    np.testing.assert_allclose(weights, dense_weights, rtol=1e-9, atol=1e-9 * np.abs(dense_weights).max())
    by_parts = solve_norm(problem, parts)
    dense = solve_norm(problem, MeansCovariance.dense(parts))
    assert np.all(np.abs(by_parts.theta - dense.theta) < 1e-4 * dense.sigma)  # Powell's tolerance
    np.testing.assert_allclose(by_parts.sigma, dense.sigma, rtol=1e-8)


def counting_minimize(monkeypatch) -> list:
    calls = []
    real = scipy.optimize.minimize

    def minimize(fun, x0, **kw):
        assert kw.get("method", "").lower() == "powell"  # each search is Powell's
        calls.append(kw.get("bounds") is not None)
        return real(fun, x0, **kw)

    monkeypatch.setattr(scipy.optimize, "minimize", minimize)
    return calls


def test_powell_searches_again_without_its_box_only_when_it_ends_near_the_edge(monkeypatch):
    # χ² = |z − c|², 1σ a unit of z: the box is ±100σ around the start.
    calls = counting_minimize(monkeypatch)
    start = np.full(9, 60.0)
    near = start + np.arange(9) * 0.3  # the minimum within 2.4σ of the start
    res = norm._powell(lambda z: z - near, start, per_sigma=True, dof=5)
    np.testing.assert_allclose(res.x, near, atol=1e-3)
    assert calls == [True]  # one bounded search
    calls.clear()
    far = np.r_[150.0, np.zeros(8)]  # beyond the box: the bounded search stops at its edge
    res = norm._powell(lambda z: z - far, np.zeros(9), per_sigma=True, dof=5)
    np.testing.assert_allclose(res.x, far, atol=1e-3)
    assert calls == [True, False]


def test_powell_from_a_start_with_no_residual_stays_there():
    # Unweighted, the residuals already zero at the start: no scatter to scale by, χ² is taken as
    # it is, and the start is the minimum.
    start = np.linspace(-1.0, 1.0, 9)
    res = norm._powell(lambda z: z - start, start.copy(), per_sigma=False, dof=3)
    assert res.success
    np.testing.assert_allclose(res.x, start, atol=1e-9)


def quadratic(s: float):
    """r(z) = s·(z² − 4, 1, …, 1) (100 ones): one unknown, dof 100, the minimum at z = 2."""
    def residuals(z):
        z = np.asarray(z, dtype=float)
        return s * np.concatenate([z[..., :1] ** 2 - 4.0, np.ones(z.shape[:-1] + (100,))], axis=-1)
    return residuals


@pytest.mark.parametrize("s", [1e-3, 1.0])
def test_gauss_newton_stops_at_a_step_below_its_tolerance_in_sigma_of_the_solution(s):
    # From z = 3 Newton's steps on z² = 4 are −0.83, −0.16, −6.4e-3, −1.0e-5, −2.5e-11. Unweighted,
    # σ in z is √(χ²/dof) = s·√1.25 at the start, the tolerance 1e-4 of it: the steps stop once
    # one is below 1.1e-4·s, and the search ends at 2 within 1e-10 whatever the residuals' unit.
    res = norm._gauss_newton(quadratic(s), np.array([3.0]), per_sigma=False, dof=100)
    assert res.success is True
    assert abs(res.x[0] - 2.0) < 1e-10
    assert res.nit == (5 if s == 1e-3 else 4)


def test_gauss_newton_keeps_its_start_when_a_step_raises_chi2():
    # r = atan z from z = 2: Newton's step lands at z = 2 − 5·atan 2 = −3.5, where |atan z| is larger.
    res = norm._gauss_newton(lambda z: np.arctan(np.asarray(z, dtype=float)), np.array([2.0]), per_sigma=True, dof=0)
    assert res.success is False
    assert res.x[0] == 2.0 and res.nit == 1
    assert res.message == "a Gauss-Newton step did not lower χ²"


def test_the_search_starts_at_the_gauss_newton_step(monkeypatch):
    # χ² is nearly quadratic in z around the start θ₀: the linearised step from θ₀ lands within a
    # millionth of the way from θ₀'s χ² down to the minimum's (found by Gauss-Newton, solved apart).
    rng = np.random.default_rng(11)
    up = np.array([p.up_body for p in load_procedure("field-18").positions])
    means = distort_with(np.array([0.3, -0.2, 0.1, 1.02, 0.97, 1.01, 0.01, -0.02, 0.015]), G * up)
    problem = StaticNormProblem(means + rng.normal(0, 5e-3, up.shape), G)
    sigmas = np.full((18, 3), 5e-3)
    starts = []
    real = norm._powell

    def powell(residuals_of_z, z_start, **kw):
        starts.append((residuals_of_z(z_start), residuals_of_z(np.zeros(9))))
        return real(residuals_of_z, z_start, **kw)

    monkeypatch.setattr(norm, "_powell", powell)
    solve_norm(problem, sigmas)
    minimum = solve_norm(problem, sigmas, norm.SCREEN).diagnostics.chi2
    (at_start, at_theta0), = starts
    assert at_theta0 @ at_theta0 - minimum > 1e-3  # (the point: θ₀ itself is not the minimum)
    assert at_start @ at_start - minimum < 1e-6 * (at_theta0 @ at_theta0 - minimum)


def test_sigmas_given_in_single_precision_are_squared_in_double():
    # A device's float32 σ are taken at their value: the weights are those of the same numbers
    # held as float64, to the last bit (squaring in float32 would round each to 24 bits).
    problem = StaticNormProblem(MEANS, G)
    single = SIGMAS.astype(np.float32)
    weights = norm._residual_whitener(problem, IDENTITY, single).matrix()
    np.testing.assert_array_equal(weights, norm._residual_whitener(problem, IDENTITY, single.astype(float)).matrix())


def test_gauss_newton_from_a_start_with_no_residual_stays_there():
    # Unweighted and already at a zero-residual minimum: no scatter to measure σ by, so the steps
    # are taken in the residuals' own unit, and the first one is nothing.
    start = np.linspace(-1.0, 1.0, 9)
    res = norm._gauss_newton(lambda z: z - start, start.copy(), per_sigma=False, dof=3)
    assert res.success is True
    np.testing.assert_array_equal(res.x, start)


def test_a_covariance_by_its_parts_that_is_not_positive_definite_is_refused_in_one_line():
    # Windows of variance −1e-6: no covariance at all. The refusal names the triad.
    up = np.array([p.up_body for p in load_procedure("field-18").positions])
    negative = MeansCovariance(-1e-6 * np.eye(18), np.eye(3), np.zeros((18, 3)))
    with pytest.raises(norm.CalibrationError) as raised:
        solve_norm(StaticNormProblem(G * up, G), negative)
    assert str(raised.value) == "accelerometer: the covariance of the averages is not positive definite"


def test_a_solve_warns_of_nothing():
    # Every option given to scipy's Powell is one it knows (an unknown one is an OptimizeWarning
    # on the operator's terminal, and its limit silently another).
    up = np.array([p.up_body for p in load_procedure("field-18").positions])
    problem = StaticNormProblem(distort_with(np.array([0.3, -0.2, 0.1, 1.02, 0.97, 1.01, 0.01, -0.02, 0.015]),
                                             G * up) + np.random.default_rng(2).normal(0, 5e-4, up.shape), G)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for method in ("powell", "lsq", norm.SCREEN):
            solve_norm(problem, np.full((18, 3), 5e-4), method)
            solve_norm(problem, None, method)


@pytest.mark.parametrize("counts_per_si", [1.0, 415.0])
@pytest.mark.parametrize("repeats", [1, 16])
def test_positions_tilted_a_hair_from_the_cube_faces_are_refused_on_their_geometry_however_often_measured(
        repeats, counts_per_si):
    # The six faces and each tilted by 1e-4 rad towards the next axis: the spread is nothing, and
    # measuring every position 16 times over does not change the directions, so the refusal
    # (and its condition number) is the same either way; and the same in raw counts (415 a m/s²
    # around 32768) as in m/s², the geometry being the same.
    faces = np.vstack([np.eye(3), -np.eye(3)])
    directions = np.vstack([faces, faces + 1e-4 * np.roll(faces, 1, axis=1)])
    directions = np.repeat(directions / np.linalg.norm(directions, axis=1, keepdims=True), repeats, axis=0)
    truth = np.array([0.3, -0.2, 0.1, 1.02, 0.97, 1.01, 0.01, -0.02, 0.015])
    if counts_per_si != 1.0:
        truth = np.r_[32768.0 + counts_per_si * truth[:3], counts_per_si * truth[3:6], truth[6:]]
    with pytest.raises(norm.CalibrationError) as raised:
        solve_norm(StaticNormProblem(distort_with(truth, G * directions), G),
                   np.full(directions.shape, 5e-4 * counts_per_si))
    assert str(raised.value).startswith("accelerometer: positions are degenerate (condition number 2.05e+04); "
                                        f"{12 * repeats} measurements point along only 3 distinct axes")


def test_gauss_newton_gives_up_after_its_twenty_steps():
    # r = z²⁰: Newton's step takes z to 0.95 z, never a step below 1e-4 from z = 1 in 20 steps
    # (the 20th is 0.05·0.95¹⁹ = 0.019), each lowering χ²: no convergence, and the last z kept.
    res = norm._gauss_newton(lambda z: np.asarray(z, dtype=float) ** 20, np.array([1.0]), per_sigma=True, dof=0)
    assert res.success is False and res.nit == 20
    assert res.message == "no convergence in 20 Gauss-Newton steps"
    assert res.x[0] == pytest.approx(0.95 ** 20, rel=1e-3)


def test_gauss_newton_with_one_degree_of_freedom_takes_sigma_from_the_scatter():
    # r(z) = 1e-3·(z² − 4, 1), dof 1: σ in z is √(χ²/1) = 1e-3·√26 at z = 3, the tolerance 5.1e-7;
    # Newton's steps −0.83, −0.16, −6.4e-3, −1.0e-5 go on to −2.5e-11, which ends it at 2.
    res = norm._gauss_newton(lambda z: 1e-3 * np.concatenate([np.asarray(z)[..., :1] ** 2 - 4.0,
                                                              np.ones(np.shape(z)[:-1] + (1,))], axis=-1),
                             np.array([3.0]), per_sigma=False, dof=1)
    assert res.success is True and res.nit == 5
    assert abs(res.x[0] - 2.0) < 1e-12
