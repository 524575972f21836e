"""A procedure played on the simulator: timeline, sample generation, window averages.

This stands in for the procedure engine (a later issue) in headless demos, tests and benchmarks:
it knows the windows in advance instead of detecting stillness.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from drivers.sim import MimuSimulator, Segment, TriadTruth
from drivers.sim.rotations import rotvec_matrix, z_rotation
from fieldcal.procedure.averaging import WindowAverager
from fieldcal.earth import EARTH_RATE, Station
from fieldcal.procedure.positions import Procedure
from fieldcal.procedure.windows import MINUS, PLUS, STATIC, Window


@dataclass(frozen=True)
class Plan:
    segments: tuple[Segment, ...]
    windows: tuple[Window, ...]
    attitudes: np.ndarray  # (n_positions, 3, 3) true body -> ENU at table angle zero


def placed_attitude(nominal: np.ndarray, rng: np.random.Generator, sigma_deg: float) -> np.ndarray:
    """Where a person actually puts the cube: a random heading on the table and a small tilt."""
    tilt = rotvec_matrix(rng.normal(0.0, math.radians(sigma_deg), 3))
    heading = z_rotation(rng.uniform(0, 2 * math.pi))
    return heading @ nominal @ tilt


def _whole_samples(seconds: float, rate_hz: float) -> float:
    return round(seconds * rate_hz) / rate_hz


def plan_procedure(procedure: Procedure, rate_hz: float, rng: np.random.Generator,
                   placement_sigma_deg: float = 3.0, with_rate_steps: bool = True) -> Plan:
    """Segments and averaging windows for every position; placement errors unless aligned."""
    segments, windows, attitudes = [], [], []
    t = 0.0
    for index, position in enumerate(procedure.positions):
        step = procedure.rate_step_at(index) if with_rate_steps else None
        attitude = position.attitude
        if not procedure.aligned:
            attitude = placed_attitude(attitude, rng, placement_sigma_deg)
        attitudes.append(attitude)
        ramp = _whole_samples(step.ramp_s, rate_hz) if step else 0.0
        settle = _whole_samples(step.settle_s if step else 1.0, rate_hz)
        dwell = _whole_samples(procedure.dwell_s, rate_hz)
        segments.append(Segment(ramp + settle + dwell, attitude, 0.0, ramp, f"{position.id} static"))
        windows.append(Window(STATIC, index, t + ramp + settle, dwell))
        t += ramp + settle + dwell
        if step:
            rate = math.radians(step.rate_deg_s)
            spin = _whole_samples(step.turns * 2 * math.pi / rate, rate_hz)
            for kind, sign in ((PLUS, 1.0), (MINUS, -1.0)):
                duration = ramp + settle + spin
                segments.append(Segment(duration, attitude, sign * rate, ramp, f"{position.id} {kind}"))
                windows.append(Window(kind, index, t + ramp + settle, spin, rate))
                t += duration
    return Plan(tuple(segments), tuple(windows), np.array(attitudes))


def simulate_averages(plan: Plan, device: dict[str, TriadTruth], station: Station,
                      rate_hz: float = 250.0, seed: int | np.random.SeedSequence = 0,
                      progress=None) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Run the simulator over the plan; per-triad (n_windows, 3) means and the static table angles.

    ``progress(done, total, label)`` is called after each segment, if given.
    """
    sim = MimuSimulator(device, gravity=station.gravity, latitude_rad=station.latitude_rad,
                        earth_rate=EARTH_RATE, rate_hz=rate_hz, seed=seed)
    averager = WindowAverager([w.start for w in plan.windows],
                              [w.start + w.duration for w in plan.windows])
    static_angles = []
    for done, (segment, window) in enumerate(zip(plan.segments, plan.windows), start=1):
        for chunk in sim.run_segment(segment):
            averager.feed(chunk)
        if window.kind == STATIC:
            static_angles.append(sim.table_angle)
        if progress:
            progress(done, len(plan.segments), segment.label)
    return {name: averager.means(name) for name in device}, np.array(static_angles)
