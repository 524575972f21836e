"""Edges of the joint thermal fit that the warm-up runs reach only slowly (issue 26's mutation
survivors): each against a hand-worked value, the simulated truth or the plain norm solve."""
from __future__ import annotations

import numpy as np
import pytest

from fieldcal.solvers import StaticNormProblem
from fieldcal.solvers.thermal import _SQRT_EPS, _forward_jacobian_of_lm, _residual_covariance_at, solve_thermal_norm
from test_thermal_solver import B1, B2, G, SIGMA, TEMPERATURES, THETA, TRUTH_REF_C, _averages


class _HeldPose:
    """A problem whose residual i moves with average number i only, r = 2u − c (a held pose's
    u − c, doubled so that G = ∂r/∂u = 2I is no identity)."""

    reference_scale = 1.0

    def __init__(self, c):
        self.c = c

    def residuals(self, theta, u):
        return 2.0 * u - self.c


def test_a_residual_moving_with_one_average_has_the_hand_worked_covariance():
    rng = np.random.default_rng(4)
    u = rng.normal(size=12) + 5.0
    per_axis = rng.uniform(1e-4, 1e-3, size=(4, 3))  # one σ per average and axis
    problem = _HeldPose(rng.normal(size=12))
    diagonal = _residual_covariance_at(problem, THETA, u, per_axis)
    # G Σ Gᵀ = 2I · diag(σ²) · 2I: each residual's variance is 4σ², and only the diagonal is made
    assert diagonal.shape == (12,)
    np.testing.assert_allclose(diagonal, 4.0 * per_axis.ravel() ** 2, rtol=1e-8)
    # the same covariance given as its dense matrix goes the general way: the same numbers as a matrix
    dense = _residual_covariance_at(problem, THETA, u, np.diag(per_axis.ravel() ** 2))
    np.testing.assert_allclose(dense, np.diag(4.0 * per_axis.ravel() ** 2), rtol=1e-8, atol=1e-20)


def test_the_levenberg_marquardt_jacobian_steps_by_scipys_two_point_rule():
    # scipy's '2-point' rule: h = √ε · sign(z) · max(1, |z|) (sign(0) taken as +), and the step
    # actually taken (z + h) − z; a stack of the p + 1 points in one call
    z = np.array([3.0, -0.5, 0.0, -7.0])
    asked = []

    def fun(points):
        asked.append(points.copy())
        return points ** 2

    J = _forward_jacobian_of_lm(fun, z)
    assert len(asked) == 1 and asked[0].shape == (5, 4)
    h = _SQRT_EPS * np.array([3.0, -1.0, 1.0, -7.0])
    np.testing.assert_array_equal(asked[0][0], z)
    np.testing.assert_allclose(asked[0][1:] - z, np.diag(h), rtol=1e-9, atol=0)
    # (z + h)² − z² over the step: 2z + h, up to the rounding of z + h
    np.testing.assert_allclose(np.diag(J), 2 * z + h, rtol=1e-6)
    assert not np.any(J[~np.eye(4, dtype=bool)])


def test_a_reference_temperature_given_is_the_models_and_its_bias_the_truths_there():
    # The truth's b₀ at 30 °C: the polynomial about 25 °C re-centred by hand (b₀ + b₁·5 + b₂·25).
    fit = solve_thermal_norm(StaticNormProblem(_averages(7), G), TEMPERATURES, np.full((18, 3), SIGMA),
                             reference_c=30.0, max_order=2, scale=False)
    model = fit.calibration.thermal
    assert model.reference_c == 30.0 and model.order == 2
    d = 30.0 - TRUTH_REF_C
    z = (fit.calibration.theta[:3] - (THETA[:3] + B1 * d + B2 * d ** 2)) / fit.calibration.sigma[:3]
    assert np.all(np.abs(z) < 4.0), z.round(2)


def test_each_orders_chi2_is_reported_the_true_orders_a_chi2_of_its_freedom():
    # The truth has b₂ (order 2): orders 0 and 1 misfit by far more than noise, order 2 leaves a
    # χ² of its 3 degrees of freedom (below their 99.9 % point, 16.27), and it is the one chosen.
    fit = solve_thermal_norm(StaticNormProblem(_averages(7), G), TEMPERATURES, np.full((18, 3), SIGMA),
                             max_order=2, scale=False)
    chi2 = fit.chi2_by_order
    assert sorted(chi2) == [0, 1, 2] and fit.calibration.thermal.order == 2
    assert chi2[0] > chi2[1] > 100.0 > 16.27 > chi2[2] > 0.0
    assert chi2[2] == fit.calibration.diagnostics.chi2


def test_the_diagnostics_say_the_search_its_end_and_whether_the_scatter_set_sigma():
    u = _averages(7)
    honest = solve_thermal_norm(StaticNormProblem(u, G), TEMPERATURES, np.full((18, 3), SIGMA),
                                max_order=2, scale=False)
    # the stated noise ten times too small: χ² a hundred times larger, on the same estimate, and
    # improbable on its 3 degrees of freedom (order 2: 15 unknowns), so σ is set by the residuals' scatter instead,
    # σ·√(χ²/dof): the honest run's σ/10 times √(100 χ²/dof)
    small = solve_thermal_norm(StaticNormProblem(u, G), TEMPERATURES, np.full((18, 3), SIGMA / 10),
                               max_order=2, scale=False)
    for fit in (honest, small):
        diagnostics = fit.calibration.diagnostics
        assert diagnostics.search == "lsq" and diagnostics.dof == 3
        assert "termination condition is satisfied" in diagnostics.message
    assert not honest.calibration.diagnostics.scaled_by_residuals
    assert small.calibration.diagnostics.scaled_by_residuals
    np.testing.assert_allclose(small.calibration.theta, honest.calibration.theta, rtol=0, atol=1e-3 * SIGMA)
    chi2 = honest.calibration.diagnostics.chi2
    np.testing.assert_allclose(small.calibration.sigma, honest.calibration.sigma / 10 * np.sqrt(100 * chi2 / 3),
                               rtol=1e-3)


def test_noise_free_averages_give_the_cramer_rao_bound_to_a_few_parts_in_ten_thousand():
    # test_thermal_crb's peer, without the noise draw: on the true averages the joint fit's
    # information is the bound's (orientations eliminated by the norm or estimated, the same
    # linearised information), so σ agrees to 1.6e-4; a Jacobian differenced at the wrong step
    # moves them by 5e-3.
    import test_thermal_crb as crb

    sigma = 7e-5
    dt = crb.TEMPERATURES[:, None] - crb.REF_C
    clean = crb.G * crb.UP @ crb.k_from_params(crb.THETA).T
    u = clean * (1 + crb.S1 * dt) + crb.THETA[:3] + crb.B1 * dt
    fit = solve_thermal_norm(StaticNormProblem(u, crb.G), crb.TEMPERATURES, np.full((18, 3), sigma), max_order=1)
    model = fit.calibration.thermal
    assert model.order == 1 and model.scale_drift is not None
    bound = crb.specific_force_bound(crb.THETA, crb.UP, crb.G, np.eye(54) * sigma ** 2,
                                     thermal=crb.ThermalTerms(crb.TEMPERATURES - crb.REF_C, crb.B1[None, :], crb.S1))
    reported = np.r_[fit.calibration.sigma, model.bias_terms_sigma.ravel(), model.scale_drift_sigma]
    np.testing.assert_allclose(reported, np.sqrt(np.diag(bound)), rtol=1e-3)


def _seed380_accelerometer():
    """configs/sim-warmup.yaml seed 380's accelerometer as the conductor gave it to the solve
    (tests/data/sim_warmup_seed380_accelerometer.json: the inputs at full precision and the
    simulator's truth, so this fold is met in milliseconds instead of a run)."""
    import json
    from pathlib import Path

    doc = json.loads((Path(__file__).parent / "data" / "sim_warmup_seed380_accelerometer.json").read_text())
    problem = StaticNormProblem(np.array(doc["averages"]), doc["gravity"])
    return problem, np.array(doc["temperatures_c"]), np.array(doc["covariance"]), doc


def test_a_fold_akaike_prefers_is_kept_with_the_observed_informations_condition():
    # Seed 380's accelerometer: order 2 with the drift is an exact fit of its 18 norms (9 + 6 + 3
    # unknowns) that stops on a fold with χ² 0.15 left, 8.2 below order 1's: more
    # than Akaike's 2·3 for its three coefficients, so the fold is kept (the truth has b₂). Its
    # condition number is the observed information's, √(λmax/λmin), not JᵀJ's (singular there).
    problem, temperatures, covariance, doc = _seed380_accelerometer()
    fit = solve_thermal_norm(problem, temperatures, covariance)
    chi2, calibration = fit.chi2_by_order, fit.calibration
    assert calibration.thermal.order == 2 and calibration.diagnostics.chi2 > 1e-6  # a fold
    assert 6.0 < chi2[1] - chi2[2] < 9.0
    eig = np.linalg.eigvalsh(np.linalg.inv(fit.covariance))
    assert calibration.diagnostics.condition_number == pytest.approx(np.sqrt(eig[-1] / eig[0]), rel=1e-6)
    # and the fold's estimates hold the simulator's truth within 4σ
    z = (calibration.theta - np.array(doc["truth_theta"])) / calibration.sigma
    assert np.all(np.abs(z) < 4.0), z.round(2)
