import math

import numpy as np
import pytest

from fieldcal.earth import EARTH_RATE, Station, normal_gravity
from fieldcal.model import calibrate_with, distort_with, k_from_params, params_from_k


def test_calibrate_inverts_distort_for_large_errors():
    rng = np.random.default_rng(0)
    theta = np.array([0.3, -0.2, 0.5, 1.08, 0.93, 1.02, 0.05, -0.04, 0.03])
    true = rng.normal(size=(1000, 3))
    np.testing.assert_allclose(calibrate_with(theta, distort_with(theta, true)), true, atol=1e-12)


def test_paper_eq16_signs():
    # Paper eq. 16 with G = [g 0 0]: l = [(1+Sx) g, -Δyz g, Δzy g] + b.
    theta = np.array([0.1, 0.2, 0.3, 1.001, 1.002, 1.003, 1e-3, 2e-3, 3e-3])
    g = 9.8
    out = distort_with(theta, np.array([[g, 0.0, 0.0]]))[0]
    np.testing.assert_allclose(out, [1.001 * g + 0.1, -1e-3 * 1.002 * g + 0.2, 2e-3 * 1.003 * g + 0.3])


def test_params_round_trip_and_reject_upper_triangle():
    theta = np.array([1.0, 2.0, 3.0, 415.0, 420.0, 410.0, 0.01, -0.02, 0.03])
    np.testing.assert_allclose(params_from_k(k_from_params(theta), theta[:3]), theta)
    with pytest.raises(ValueError):
        params_from_k(np.ones((3, 3)), [0, 0, 0])


def _somigliana_closed_form(lat_deg: float) -> float:
    """Somigliana's formula in its original form, from WGS84 a, b, equatorial and polar gravity."""
    a = 6378137.0
    b = a * (1 - 1 / 298.257223563)
    gamma_e, gamma_p = 9.7803253359, 9.8321849378
    c2, s2 = math.cos(math.radians(lat_deg)) ** 2, math.sin(math.radians(lat_deg)) ** 2
    return (a * gamma_e * c2 + b * gamma_p * s2) / math.sqrt(a * a * c2 + b * b * s2)


@pytest.mark.parametrize("lat", [0.0, 23.5, 40.0, 45.0, -60.0, 90.0])
def test_normal_gravity_matches_somigliana_closed_form(lat):
    assert normal_gravity(lat) == pytest.approx(_somigliana_closed_form(lat), abs=1e-9)


def test_free_air_gradient():
    # About -3.086e-6 m/s² per metre near the surface.
    slope = (normal_gravity(40.0, 1000.0) - normal_gravity(40.0, 0.0)) / 1000.0
    assert slope == pytest.approx(-3.086e-6, rel=2e-3)


def test_station_override_and_earth_rate():
    s = Station(40.0, 50.0, gravity_m_s2=9.80123)
    assert s.gravity == 9.80123 and s.gravity_source == "measured"
    assert s.earth_rate_vertical == pytest.approx(EARTH_RATE * math.sin(math.radians(40.0)))
    with pytest.raises(ValueError, match="latitude_deg"):
        Station(95.0)
    with pytest.raises(ValueError, match="gravity_m_s2"):
        Station(10.0, gravity_m_s2=98.0)
