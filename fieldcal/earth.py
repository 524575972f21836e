"""Local gravity (WGS84 normal gravity with the free-air term) and Earth rotation."""
from __future__ import annotations

import math
from dataclasses import dataclass

# WGS84 defining and derived constants (NIMA TR8350.2).
_A = 6378137.0  # semi-major axis, m
_F = 1 / 298.257223563  # flattening
_GAMMA_E = 9.7803253359  # normal gravity at the equator, m/s²
_K = 0.00193185265241  # Somigliana constant
_E2 = 0.00669437999013  # first eccentricity squared
_M = 0.00344978650684  # ω²a²b/GM
EARTH_RATE = 7.292115e-5  # rad/s
# Where a station can be: on land, below Everest (the free-air formula is for the surface), and
# the gravity such a place has. Parameter files are held to the same bounds when read.
HEIGHT_RANGE_M = (-500.0, 9000.0)
GRAVITY_RANGE_M_S2 = (9.7, 9.9)
MEASURED, NORMAL_GRAVITY = "measured", "WGS84 normal gravity"
GRAVITY_SOURCES = (MEASURED, NORMAL_GRAVITY)


def normal_gravity(latitude_deg: float, height_m: float = 0.0) -> float:
    """WGS84 normal gravity at geodetic latitude and ellipsoidal height, in m/s²."""
    s2 = math.sin(math.radians(latitude_deg)) ** 2
    gamma0 = _GAMMA_E * (1 + _K * s2) / math.sqrt(1 - _E2 * s2)
    free_air = 1 - 2 / _A * (1 + _F + _M - 2 * _F * s2) * height_m + 3 / _A**2 * height_m**2
    return gamma0 * free_air


@dataclass(frozen=True)
class Station:
    """Where the calibration happens. ``gravity_m_s2`` overrides the normal-gravity model."""

    latitude_deg: float
    height_m: float = 0.0
    gravity_m_s2: float | None = None

    def __post_init__(self) -> None:
        if not -90.0 <= self.latitude_deg <= 90.0:
            raise ValueError(f"latitude_deg: expected -90..90, got {self.latitude_deg}")
        if not HEIGHT_RANGE_M[0] <= self.height_m <= HEIGHT_RANGE_M[1]:
            raise ValueError(f"height_m: expected -500..9000 m above the ellipsoid, got {self.height_m}")
        if self.gravity_m_s2 is not None and not GRAVITY_RANGE_M_S2[0] < self.gravity_m_s2 < GRAVITY_RANGE_M_S2[1]:
            raise ValueError(f"gravity_m_s2: expected 9.7..9.9 m/s², got {self.gravity_m_s2}")

    @property
    def gravity(self) -> float:
        if self.gravity_m_s2 is not None:
            return self.gravity_m_s2
        return normal_gravity(self.latitude_deg, self.height_m)

    @property
    def gravity_source(self) -> str:
        return MEASURED if self.gravity_m_s2 is not None else NORMAL_GRAVITY

    @property
    def latitude_rad(self) -> float:
        return math.radians(self.latitude_deg)

    @property
    def earth_rate_vertical(self) -> float:
        """Earth rate along local up (a vertical table axis), rad/s."""
        return EARTH_RATE * math.sin(self.latitude_rad)

    @property
    def earth_rate_horizontal(self) -> float:
        return EARTH_RATE * math.cos(self.latitude_rad)
