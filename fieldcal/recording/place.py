"""Where the recording was made, as far as the solve needs it: the station's g (and latitude, for
the Earth rate), or an unknown place whose g is normal gravity at 45° with the worldwide band as
its uncertainty, carried into every specific-force scale factor's σ."""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from fieldcal.calibration import Calibration
from fieldcal.earth import Station, normal_gravity

# Where nothing tells g: WGS84 normal gravity at 45°, within ±0.3 % of g anywhere people live
# (9.780 m/s² at the equator to 9.832 at the poles, less up a mountain). A place is as likely
# anywhere in that band, so its 1σ is the band's half-width over √3. Never the sensor's own norm:
# the uncalibrated norm at rest holds the very scale error the calibration is to find.
DEFAULT_LATITUDE_DEG = 45.0
GRAVITY_SPREAD = 0.003  # relative half-width of the worldwide band
DEFAULT_GRAVITY_SOURCE = (f"WGS84 normal gravity at {DEFAULT_LATITUDE_DEG:g}° (place unknown: g anywhere is within "
                          f"±{GRAVITY_SPREAD:.1%} of it, carried in every scale factor's σ; give --latitude "
                          "(and --height), or --gravity)")


@dataclass(frozen=True)
class UnknownPlace:
    """A recording whose place is not known: no latitude, so the Earth rate (7.29e-5 rad/s, its
    direction unknown) is an error term of Ω²/3 per axis instead of a known vertical part.
    ``gravity``: m/s^2 as given, or None: normal gravity at 45° (see place_gravity), whose
    relative 1σ ``gravity_relative_sigma`` widens every specific-force scale factor's σ.
    Written to a parameter file as latitude 0 with this g as a given ("measured") one: a file's
    gravity source is one of ``fieldcal.earth.GRAVITY_SOURCES`` (see recording.results)."""

    gravity: float | None = None
    gravity_source: str = "given (--gravity); place unknown"
    latitude_deg: float = 0.0
    height_m: float = 0.0
    gravity_relative_sigma: float = 0.0

    @property
    def latitude_rad(self) -> float:
        return 0.0


def with_gravity_uncertainty(solution: Calibration, relative_sigma: float) -> tuple[Calibration, str]:
    """A specific-force triad's solution with g's relative 1σ in its scale factors' σ, and a note
    when that is most of their σ (else ""). Every scale factor is output per m/s², so a g wrong by
    a fraction ε moves each by −ε·k and nothing else: to first order the covariance gains
    σ²·v·vᵀ with v = −k on the scale factors."""
    if relative_sigma <= 0:
        return solution, ""
    v = np.zeros(len(solution.theta))
    v[3:6] = -solution.theta[3:6]
    covariance = solution.covariance + relative_sigma**2 * np.outer(v, v)
    widened = replace(solution, covariance=covariance, sigma=None)
    own = np.sqrt(np.diag(solution.covariance)[3:6]) / np.abs(solution.theta[3:6])
    note = ""
    if np.all(own < relative_sigma):
        total = float(np.max(widened.sigma[3:6] / np.abs(solution.theta[3:6])))
        note = (f"{solution.name}: the scale factors' σ ({total:.2%}) is mostly the unknown g's "
                f"({relative_sigma:.2%}, 1σ of ±{GRAVITY_SPREAD:.1%} worldwide; the fit alone: "
                f"{float(np.max(own)) * 1e6:.3g} ppm): give --latitude (and --height), or --gravity")
    return widened, note


def place_gravity(station: Station | UnknownPlace) -> Station | UnknownPlace:
    """The station, an unknown place's g filled in as normal gravity at 45° with its spread."""
    if not (isinstance(station, UnknownPlace) and station.gravity is None):
        return station
    return replace(station, gravity=normal_gravity(DEFAULT_LATITUDE_DEG), gravity_source=DEFAULT_GRAVITY_SOURCE,
                   gravity_relative_sigma=GRAVITY_SPREAD / math.sqrt(3))
