"""The Powell norm estimator reaches the Cramér-Rao bound (orientations as nuisance parameters).

Averages are drawn from their exact distribution (noise-free simulator means plus Gaussian noise
with the exact covariance of the window means), which is what averaging the samples gives; the
full sample-level Monte Carlo is benchmarks/accuracy.py.
"""
import numpy as np
import pytest

from fieldcal.solvers.crb import angular_rate_bound, specific_force_bound
from fieldcal.earth import EARTH_RATE
from fieldcal.run.simcal import DEFAULT_STATION
from fieldcal.solvers import solve_norm


def bound(run, name):
    theta, up = run.truth[name], run.plan.attitudes[:, 2, :]
    if name != "gyroscope":
        return specific_force_bound(theta, up, DEFAULT_STATION.gravity, run.covariances[name])
    angle = run.angles
    north = np.einsum("nij,ni->nj", run.plan.attitudes,
                      np.column_stack([np.sin(angle), np.cos(angle), np.zeros_like(angle)]))
    return angular_rate_bound(theta, up, np.radians(10), north, EARTH_RATE,
                              DEFAULT_STATION.latitude_rad, run.covariances[name])


@pytest.mark.parametrize("name, draws", [("accelerometer", 150), ("gyroscope", 100)])
def test_rms_error_matches_the_bound_within_sampling_error(field18, name, draws):
    rng = np.random.default_rng(99)
    crb = np.sqrt(np.diag(bound(field18, name)))
    errors, sigmas = [], []
    for _ in range(draws):
        sol = solve_norm(field18.problem(name, rng), field18.covariances[name])
        errors.append(sol.theta - field18.truth[name])
        sigmas.append(sol.sigma)
    rms = np.sqrt(np.mean(np.square(errors), axis=0))
    # The reported σ is the bound itself (to first order), and the realised scatter matches it.
    # With 100-150 draws an RMS scatters by about ±6-7 % (1σ), so this checks efficiency to
    # within sampling error; the 1.10 target is checked with 200 full sample-level runs in
    # benchmarks/accuracy.py.
    np.testing.assert_allclose(np.mean(sigmas, axis=0), crb, rtol=0.02)
    assert np.all(rms / crb < 1.16), rms / crb
    assert np.all(rms / crb > 0.84), rms / crb
