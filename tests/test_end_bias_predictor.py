"""fieldcal.solvers.endbias against plain Gaussian conditioning: on a problem whose residuals are
linear (r = u − Aθ, so its derivatives are exact), the bias at the end and its error covariance
must be the posterior mean and covariance of b + K·p(t_end) given the averages as θ's prior
widens (the mutation run of fieldcal/solvers, docs/benchmarks.md: only the slow statistical
test checked the predictor's covariance)."""
from types import SimpleNamespace

import numpy as np
import pytest

from drivers.noise import TriadNoise
from fieldcal.solvers.endbias import bias_at_end

NOISE = TriadNoise(white=1e-3, bias_instability=2e-4, flicker_tau_max_s=1e5)
K = np.array([[1.02, 0.0, 0.0], [0.01, 0.97, 0.0], [-0.02, 0.015, 1.01]])
STARTS, DURATIONS = 100.0 * np.arange(8), np.full(8, 50.0)  # the last window ends at 750 s


class LinearProblem:
    """r(θ, u) = u − Aθ: the averages' mean is Aθ (θ's bias, scale and angle slots only matter
    for the difference steps, which are exact here)."""

    reference_scale = 1.0

    def __init__(self, A: np.ndarray, u: np.ndarray):
        self.A, self.data = A, u

    def residual_function(self, u):
        return lambda theta: u - theta @ self.A.T

    def residuals(self, theta, u):
        return u - self.A @ theta


def _case(seed: int = 4):
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((24, 9))
    sigma = np.kron(NOISE.window_covariance(STARTS, DURATIONS), K @ K.T)
    truth = np.r_[0.1, -0.2, 0.3, 1.02, 0.97, 1.01, 0.01, -0.02, 0.015]
    u = A @ truth + np.linalg.cholesky(sigma) @ rng.standard_normal(24)
    # θ̂: generalised least squares, as the norm method's weighted solve gives for a linear problem
    theta = np.linalg.solve(A.T @ np.linalg.solve(sigma, A), A.T @ np.linalg.solve(sigma, u))
    return LinearProblem(A, u), sigma, theta


def _calibration(theta, scaled=False, chi2=None, dof=15):
    diagnostics = SimpleNamespace(scaled_by_residuals=scaled, dof=dof, chi2=chi2)
    return SimpleNamespace(theta=theta, diagnostics=diagnostics)


def _posterior(problem, sigma, end_s, prior=1e-2):
    """E·x + f given y = A·x + n, x ~ N(0, prior·I) and (n, f) jointly Gaussian: the flat-prior
    limit is the best linear unbiased predictor."""
    cross = np.kron(NOISE.point_covariance(STARTS, DURATIONS, end_s)[:, None], K @ K.T)  # cov(n, f)
    V = NOISE.bias_variance() * K @ K.T
    A, E = problem.A, np.eye(3, 9)
    s_yy = prior * A @ A.T + sigma
    s_fy = prior * E @ A.T + cross.T
    mean = s_fy @ np.linalg.solve(s_yy, problem.data)
    return mean, prior * E @ E.T + V - s_fy @ np.linalg.solve(s_yy, s_fy.T)


def test_the_bias_at_the_end_is_the_posterior_of_gaussian_conditioning():
    problem, sigma, theta = _case()
    end = bias_at_end(problem, _calibration(theta), NOISE, K, STARTS, DURATIONS, 1000.0, sigma)
    mean, covariance = _posterior(problem, sigma, 1000.0)
    assert end.time_s == 1000.0
    # (the prior of 1e-2 shrinks the mean toward 0 by some 1e-3 σ)
    np.testing.assert_allclose(end.value, mean, rtol=0, atol=1e-2 * np.sqrt(np.diag(covariance)).min())
    np.testing.assert_allclose(end.covariance, covariance, rtol=1e-5)
    # and not the turn-on constant's: the end carries the bias process's own variance
    assert np.all(np.diag(end.covariance) > np.diag(np.linalg.inv(problem.A.T @ np.linalg.solve(sigma, problem.A)))[:3])


def test_an_end_before_the_last_window_is_taken_at_that_windows_end():
    problem, sigma, theta = _case()
    early = bias_at_end(problem, _calibration(theta), NOISE, K, STARTS, DURATIONS, 0.0, sigma)
    mean, covariance = _posterior(problem, sigma, 750.0)
    assert early.time_s == 750.0
    np.testing.assert_allclose(early.covariance, covariance, rtol=1e-5)


@pytest.mark.parametrize("scaled, factor", [(True, 4.0), (False, 1.0)])
def test_a_covariance_scaled_by_the_residuals_scales_the_end_alike(scaled, factor):
    # Birge: a solve whose χ²/dof (here 4) made it trust the scatter widens the end's error alike.
    problem, sigma, theta = _case()
    plain = bias_at_end(problem, _calibration(theta), NOISE, K, STARTS, DURATIONS, 1000.0, sigma)
    birge = bias_at_end(problem, _calibration(theta, scaled=scaled, chi2=60.0), NOISE, K, STARTS, DURATIONS,
                        1000.0, sigma)
    np.testing.assert_allclose(birge.covariance, factor * plain.covariance, rtol=1e-12)
    np.testing.assert_array_equal(birge.value, plain.value)
