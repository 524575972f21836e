"""Live readings for the operator, computed from the most recent samples (no Textual here).

The source keeps the last stillness window of the specific-force and angular-rate triads and,
once per UI update (not per chunk), turns it into operator units: mean specific force in mg,
mean rate in °/s, the angle between measured gravity and the expected up of the current
position, and a quietness figure: the largest per-axis (window std)/(expected σ), the same
ratio the stillness detector compares with its enter/leave factors. Where the device reports
the unit's temperature, also the latest one and the span seen so far (lowest, highest): a thermal
calibration (issue 28) needs the unit to warm through a range, and the operator watches it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fieldcal.procedure.engine import EngineSettings
from fieldcal.procedure.stillness import angle_between, gravity_direction
from fieldcal.units import STANDARD_GRAVITY


@dataclass(frozen=True)
class Telemetry:
    """A snapshot of the run for the screen, taken on the engine's thread."""

    t: float  # sample time of the last sample fed, s
    step: int  # the engine's current step (0-based; == number of positions when done)
    phase: str  # the engine's phase (fieldcal.procedure.engine PLACE, SETTLING, ...)
    waiting: bool  # the source waits for the operator (sim paused)
    samples: int  # samples fed so far
    accel_mg: tuple[float, float, float] | None = None
    gyro_deg_s: tuple[float, float, float] | None = None
    angle_deg: float | None = None  # measured gravity vs the current position's expected up
    quiet: float | None = None  # max per-axis (window std)/(expected σ); None until a window exists
    silent_s: float | None = None  # a live device: wall time without a sample, once past SILENT_S
    temperature_c: float | None = None  # the unit's latest temperature, where the device reports one
    temperature_span_c: tuple[float, float] | None = None  # the lowest and highest seen so far


class RecentSamples:
    """The last stillness window of the two triads the engine watches."""

    def __init__(self, settings: EngineSettings):
        self.settings = settings
        self.n = max(2, round(settings.stillness.window_s * settings.rate_hz))
        self._sf = np.empty((0, 3))
        self._rate = np.empty((0, 3))
        self._sigma = np.concatenate([np.asarray(settings.stillness.specific_force_sigma, float),
                                      np.asarray(settings.stillness.rate_sigma, float)])
        self._temperature: float | None = None
        self._span: tuple[float, float] | None = None

    def add(self, chunk) -> None:
        s = self.settings
        reported = getattr(chunk, "temperature", None)
        if reported is not None and len(reported) and np.isfinite(reported).any():
            t = np.asarray(reported, float)[np.isfinite(reported)]
            self._temperature = float(t[-1])
            low, high = float(t.min()), float(t.max())
            self._span = (low, high) if self._span is None else (min(self._span[0], low), max(self._span[1], high))
        if s.specific_force not in chunk.triads or s.angular_rate not in chunk.triads:
            return
        self._sf = np.concatenate([self._sf, np.asarray(chunk.triads[s.specific_force], float)[-self.n:]])[-self.n:]
        self._rate = np.concatenate([self._rate, np.asarray(chunk.triads[s.angular_rate], float)[-self.n:]])[-self.n:]

    def readings(self, expected_up: np.ndarray | None) -> dict:
        """accel_mg, gyro_deg_s, angle_deg, quiet and the temperature, as far as the samples allow."""
        if len(self._sf) == 0:
            return {}
        s = self.settings
        temperature = {} if self._span is None else {"temperature_c": self._temperature,
                                                      "temperature_span_c": self._span}
        sf = (self._sf.mean(axis=0) - np.array(s.sf_zero)) / np.array(s.sf_sensitivity)  # m/s²
        rate = (self._rate.mean(axis=0) - np.array(s.rate_zero)) / np.array(s.rate_sensitivity)  # rad/s
        out = {"accel_mg": tuple(float(v) for v in sf / STANDARD_GRAVITY * 1e3),
               "gyro_deg_s": tuple(float(math.degrees(v)) for v in rate), **temperature}
        if expected_up is not None and np.all(np.isfinite(sf)) and np.linalg.norm(sf) > 0:
            direction = gravity_direction(self._sf.mean(axis=0), zero=np.array(s.sf_zero),
                                          sensitivity=np.array(s.sf_sensitivity))
            out["angle_deg"] = float(angle_between(direction, expected_up))
        if len(self._sf) >= self.n:
            std = np.concatenate([self._sf.std(axis=0, ddof=1), self._rate.std(axis=0, ddof=1)])
            quiet = float(np.max(std / self._sigma))
            out["quiet"] = quiet if math.isfinite(quiet) else None
        return out
