"""The gyro Cramér–Rao bound with positions that have no rate step (they see only the Earth rate,
their heading free): the bound depends on the north direction given, not on its length."""
import math

import numpy as np

from fieldcal.model import params_from_k
from fieldcal.procedure.positions import load_procedure
from fieldcal.solvers.crb import angular_rate_bound

EARTH_RATE = 7.292115e-5


def _bound(north_scale):
    up = np.array([p.up_body for p in load_procedure("field-18").positions])
    # any horizontal direction per position: perpendicular to its up
    helper = np.where(np.abs(up[:, [0]]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    north = np.cross(up, helper)
    north /= np.linalg.norm(north, axis=1, keepdims=True)
    theta = params_from_k(np.diag([1.001, 0.999, 1.002]), np.array([1e-4, -2e-4, 3e-4]))
    turning = np.arange(0, 18, 2)  # every other position has a rate step; the rest rest
    n_data = 3 * 2 * len(turning) + 3 * 18
    covariance = (1e-5) ** 2 * np.eye(n_data)
    return angular_rate_bound(theta, up, math.radians(10.0), north * north_scale, EARTH_RATE, math.radians(45.0),
                              covariance, turning=turning)


def test_a_resting_positions_north_is_a_direction_whatever_its_length():
    unit, longer = _bound(1.0), _bound(2.0)
    assert unit.shape == (9, 9)
    scale = np.abs(unit).max()
    np.testing.assert_allclose(unit, unit.T, rtol=1e-6, atol=1e-9 * scale)
    assert np.all(np.linalg.eigvalsh(unit) > 0)
    np.testing.assert_allclose(longer, unit, rtol=1e-6, atol=1e-9 * scale)
