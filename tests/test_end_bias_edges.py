"""fieldcal.solvers.endbias on a raw-count device (issue 26's mutation survivors: the difference
steps). A unit in counts is the same problem as one in SI units with every quantity multiplied by
its counts per unit: the bias at the end must be the SI one times that factor, its covariance the
factor squared times the SI one — the units' own scaling, not fieldcal's earlier output, is the
truth. Steps that ignore the data's size (divided by it, or too small for numbers of 1e5) lose
the differences to rounding and break this."""
import numpy as np
import pytest

from fieldcal.solvers.endbias import bias_at_end
from tests.test_end_bias_predictor import DURATIONS, K, NOISE, STARTS, _calibration, _case

COUNTS_PER_UNIT = 2.0 ** 17  # a 24-bit ADC's counts per m/s^2, roughly


class Scaled:
    """The linear problem r = u − Aθ in counts: u and θ times ``c`` (θ̂ of generalised least
    squares scales with the data); the natural scale of a bias is k·reference_scale, 9.81 here."""

    reference_scale = 9.81

    def __init__(self, problem, c: float):
        self.A, self.data = problem.A, c * problem.data

    def residual_function(self, u):
        return lambda theta: u - theta @ self.A.T

    def residuals(self, theta, u):
        return u - self.A @ theta


@pytest.mark.parametrize("c", [1.0, COUNTS_PER_UNIT])
def test_a_raw_count_device_gets_the_si_bias_at_the_end_times_its_scale(c):
    problem, sigma, theta = _case()
    si = bias_at_end(problem, _calibration(theta), NOISE, K, STARTS, DURATIONS, 1000.0, sigma)
    counts = bias_at_end(Scaled(problem, c), _calibration(c * theta), NOISE, c * K, STARTS, DURATIONS,
                         1000.0, c * c * sigma)
    np.testing.assert_allclose(counts.value / c, si.value, rtol=1e-7)
    # (the error covariance is a difference of terms some 1e3 times its size: compared to 1e-6 of
    # its largest element)
    np.testing.assert_allclose(counts.covariance / c ** 2, si.covariance, rtol=0,
                               atol=1e-6 * np.abs(si.covariance).max())
