"""The Cramér-Rao bound extended to the thermal model (issue 28), checked against an independent
computation of the same information and against the joint solver's own σ."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import null_space
from scipy.spatial.transform import Rotation

from drivers.noise import TriadNoise
from drivers.sim.thermal import ThermalTruth
from fieldcal.model import N_PARAMS, k_from_params
from fieldcal.procedure.positions import load_procedure
from fieldcal.solvers import StaticNormProblem
from fieldcal.solvers.crb import ThermalTerms, specific_force_bound
from fieldcal.solvers.thermal import solve_thermal_norm

G = 9.80154
MG = 9.80665e-3
UP = np.array([p.up_body for p in load_procedure("field-18").positions], dtype=float)
UP /= np.linalg.norm(UP, axis=1, keepdims=True)
THETA = np.r_[np.array([1.0, 2.0, 3.0]) * MG, 1.0001, 1.0002, 1.0003, 2e-4, -3e-4, 4e-4]
B1 = np.array([0.3, -0.5, 0.8]) * MG  # per K
S1 = np.array([50.0, -30.0, 40.0]) * 1e-6  # per K
# field-18 on a unit warming up: one 200 s dwell every 283 s, 20 °C + 13 K (1 − exp(−t/1 h))
STARTS = 100.0 + 283.0 * np.arange(18)
TEMPERATURES = 20.0 + 13.0 * -np.expm1(-(STARTS + 100.0) / 3600.0)
REF_C = float(TEMPERATURES.mean())
# _independent_mean's tangent basis at each face's up: the same for every x, so made once
# (the Hessian below evaluates the mean 5,304 times: 95,000 SVDs when made at each call)
TANGENTS = np.array([null_space(d[None, :]) for d in UP])  # (18, 3, 2)


def _paper_covariance() -> np.ndarray:
    """White + flicker covariance of the 18 averages (the paper's accelerometer), window-major."""
    noise = TriadNoise(white=0.06 / 60.0, bias_instability=0.05 * MG)
    K = k_from_params(THETA)
    return np.kron(noise.window_covariance(STARTS, np.full(18, 200.0)), K @ K.T)


def _independent_mean(x: np.ndarray) -> np.ndarray:
    """The averages written from the simulator's thermal truth, the orientations perturbed by
    rotation vectors in a tangent basis of its own (a different nuisance parametrisation from
    crb.py's, which leaves the bound on the parameters of interest unchanged)."""
    theta, b1, s1, angles = x[:9], x[9:12], x[12:15], x[15:].reshape(18, 2)
    rotated = Rotation.from_rotvec(np.einsum("nij,nj->ni", TANGENTS, angles)).apply(UP)
    offset, ratio = ThermalTruth(REF_C, b1[None, :], s1).offset_and_ratio(TEMPERATURES)
    return (ratio * (G * rotated @ k_from_params(theta).T) + theta[:3] + offset).ravel()


def test_the_bound_is_the_inverse_hessian_of_the_log_likelihood():
    # −log L = ½ rᵀΣ⁻¹r (+ a constant) for noise-free data; its Hessian at the truth, by second
    # differences, is the Fisher information: its inverse's first 15×15 block is the bound.
    cov = _paper_covariance()
    precision = np.linalg.inv(cov)
    x0 = np.r_[THETA, B1, S1, np.zeros(36)]
    y0 = _independent_mean(x0)
    scale = np.r_[np.full(3, 1e-4), np.full(6, 1e-5), np.full(3, 1e-5), np.full(3, 1e-6), np.full(36, 1e-5)]

    def nll(z):
        r = y0 - _independent_mean(x0 + scale * z)
        return 0.5 * r @ precision @ r

    n, h = len(x0), 0.5
    eye = np.eye(n) * h
    hessian = np.empty((n, n))
    for i in range(n):
        for j in range(i, n):
            hessian[i, j] = hessian[j, i] = (nll(eye[i] + eye[j]) - nll(eye[i] - eye[j])
                                             - nll(eye[j] - eye[i]) + nll(-eye[i] - eye[j])) / (4 * h * h)
    expected = (np.linalg.inv(hessian) * np.outer(scale, scale))[:15, :15]
    bound = specific_force_bound(THETA, UP, G, cov, thermal=ThermalTerms(TEMPERATURES - REF_C, B1[None, :], S1))
    assert bound.shape == (15, 15)
    np.testing.assert_allclose(np.sqrt(np.diag(bound)), np.sqrt(np.diag(expected)), rtol=1e-3)
    def correlation(c):
        s = np.sqrt(np.diag(c))
        return c / np.outer(s, s)

    np.testing.assert_allclose(correlation(bound), correlation(expected), rtol=0, atol=1e-3)


def test_without_thermal_terms_it_is_the_static_bound():
    cov = _paper_covariance()
    plain = specific_force_bound(THETA, UP, G, cov)
    empty = specific_force_bound(THETA, UP, G, cov, thermal=ThermalTerms(TEMPERATURES - REF_C, np.zeros((0, 3))))
    np.testing.assert_allclose(empty, plain, rtol=1e-9)
    # the thermal terms take information from the biases (they move the same averages)
    joint = specific_force_bound(THETA, UP, G, cov, thermal=ThermalTerms(TEMPERATURES - REF_C, B1[None, :], S1))
    assert np.all(np.diag(joint)[:3] > 1.3 * np.diag(plain)[:3])


def test_the_joint_solvers_sigma_meets_the_bound():
    # A peer: the joint solver's σ comes from the norm residuals' information, with the
    # orientations eliminated by the norm rather than estimated; at this signal-to-noise both are
    # the same information, so its σ equals the bound to a few per cent.
    sigma = 7e-5
    rng = np.random.default_rng(5)
    dt = TEMPERATURES[:, None] - REF_C
    clean = G * UP @ k_from_params(THETA).T
    u = clean * (1 + S1 * dt) + THETA[:3] + B1 * dt + rng.normal(scale=sigma, size=(18, 3))
    fit = solve_thermal_norm(StaticNormProblem(u, G), TEMPERATURES, np.full((18, 3), sigma), max_order=1)
    model = fit.calibration.thermal
    assert model.order == 1 and model.scale_drift is not None and model.reference_c == pytest.approx(REF_C)
    bound = specific_force_bound(THETA, UP, G, np.eye(54) * sigma**2,
                                 thermal=ThermalTerms(TEMPERATURES - REF_C, B1[None, :], S1))
    reported = np.r_[fit.calibration.sigma, model.bias_terms_sigma.ravel(), model.scale_drift_sigma]
    assert len(reported) == len(bound) == N_PARAMS + 6
    np.testing.assert_allclose(reported / np.sqrt(np.diag(bound)), 1.0, atol=0.03)


def test_a_stationary_triads_order_choice_stays_within_its_sigma():
    # configs/sim-warmup.yaml's inclinometer does not move with temperature (truth: order 0, no
    # drift), yet the order test picks order 2 for it in most runs (its omission rule fires on the
    # noise of a weakly determined quadratic), an exact fit with no χ² to check. Its spread must
    # still be in its σ: per draw the error's squared Mahalanobis distance under the fit's joint
    # covariance is χ² with as many degrees of freedom as the fit has parameters, so over the
    # draws the sum is χ² with their total, however correlated the parameters within a fit
    # (the 18 z of one exact fit share one weak direction: pooling them as independent draws
    # scatters far more than χ² of 18 per run says). 60 draws, a few seconds.
    from scipy.stats import chi2

    from fieldcal.model import distort_with

    noise = TriadNoise(white=0.08 / 60.0, bias_instability=0.06 * MG)  # the paper's inclinometer
    theta = np.r_[np.array([-1.0, -2.0, -3.0]) * MG, 0.9991, 0.9992, 0.9993, 1.0e-4, 2.5e-4, -2.0e-4]
    K = k_from_params(theta)
    cov = np.kron(noise.window_covariance(STARTS, np.full(18, 200.0)), K @ K.T)
    root = np.linalg.cholesky(cov)
    total, dof, orders = 0.0, 0, []
    for seed in range(60):
        u = distort_with(theta, G * UP) + (root @ np.random.default_rng(300 + seed).normal(size=54)).reshape(18, 3)
        fit = solve_thermal_norm(StaticNormProblem(u, G), TEMPERATURES, cov)
        model = fit.calibration.thermal
        err = np.r_[fit.calibration.theta - theta, model.bias_terms.ravel(), model.scale_drift]
        total += err @ np.linalg.solve(fit.covariance, err)
        dof += len(err)
        orders.append(model.order)
    assert max(orders) == 2 and min(orders) == 0  # the choice varies with the draw
    low, high = chi2.ppf([0.001, 0.999], dof)
    assert low < total < high, (total / dof, dof)


def _gyro_bound(delta_t, thermal=True):
    """The gyro bound of field-18 (every position turned at 10 °/s, then resting), white noise,
    with a linear thermal bias over the averages' temperatures ``delta_t`` (all +, all −, all static)."""
    from fieldcal.solvers.crb import angular_rate_bound

    helper = np.where(np.abs(UP[:, [0]]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    north = np.cross(UP, helper)
    north /= np.linalg.norm(north, axis=1, keepdims=True)
    terms = ThermalTerms(delta_t, np.array([[2e-6, -1e-6, 3e-6]])) if thermal else None
    return angular_rate_bound(THETA, UP, np.radians(10.0), north, 7.292115e-5, np.radians(45.0),
                              (1e-5) ** 2 * np.eye(3 * 54), thermal=terms)


def test_the_gyro_bound_of_a_thermal_bias_scales_with_the_temperatures_unit():
    # b₁·Δt is the same model as (b₁/2)·(2Δt): doubling every Δt must halve b₁'s σ exactly and
    # leave the nine parameters' bound as it was (a reparametrisation, not new information),
    # while the bias term still costs the biases information against the plain bound.
    delta_t = np.r_[TEMPERATURES, TEMPERATURES + 0.5, TEMPERATURES + 1.0] - REF_C
    bound, doubled = _gyro_bound(delta_t), _gyro_bound(2 * delta_t)
    plain = _gyro_bound(delta_t, thermal=False)
    assert bound.shape == doubled.shape == (12, 12)
    np.testing.assert_allclose(doubled[:9, :9], bound[:9, :9], rtol=1e-6, atol=1e-9 * np.abs(bound).max())
    np.testing.assert_allclose(np.sqrt(np.diag(doubled)[9:]), 0.5 * np.sqrt(np.diag(bound)[9:]), rtol=1e-6)
    assert np.all(np.diag(bound)[:3] > np.diag(plain)[:3])
