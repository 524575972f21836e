"""The device's real sample rate against the config's, measured before any dwell counts.

The engine counts samples at the configured rate (``EngineSettings.rate_hz``): a dwell of 200 s
is 200·rate samples, a turn window turns·360/rate_deg_s·rate of them. A device sending at
another rate makes every such count the wrong length of time (a VN-100 at 400 Hz against a
200 Hz config: dwells of half their time, "whole turns" of half a turn). So the rate is measured
from the first frames and a run whose device is more than ``TOLERANCE`` off is held before its
first dwell, with both rates and the config key in one line.

Measured from the device's own clock where its frames carry one (Xsens SampleTimeFine, a
delimited time column): the median sample interval, which a dropped frame does not move. Else
from the host's arrival times: samples over time between the promptest reads early and late
in the measure (the first reads may hold a backlog the port buffered before the run; a loaded
host reads late, never early).
A simulator served faster than real time (``device.sim.speed``) is expected that much faster in
host time; served as fast as it is read (speed 0) it has no rate in host time to check.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

TOLERANCE = 0.01  # more than 1 % off: held
MEASURE_S = 3.0  # host time the arrival rate is measured over
SETTLE_S = 0.5  # reads in the first half second after the port opened may be a buffered backlog
MIN_DEVICE_SAMPLES = 50  # of the device's own clock


@dataclass(frozen=True)
class MeasuredRate:
    rate_hz: float
    source: str  # how it was measured, in the operator's words

    def describe(self) -> str:
        return f"{self.rate_hz:.5g} Hz ({self.source})"


def rate_from_device_time(t: np.ndarray) -> float | None:
    """The device's rate from its own sample times: 1 / the median interval (None: too few, or
    a clock that does not advance)."""
    dt = np.diff(np.asarray(t, dtype=float))
    dt = dt[dt > 0]
    if dt.size < MIN_DEVICE_SAMPLES - 1:
        return None
    return float(1.0 / np.median(dt))


def rate_from_arrivals(arrivals: np.ndarray, counts: np.ndarray) -> float | None:
    """The rate from the host's arrival time of each read (``arrivals``, s) and how many samples
    each brought (``counts``): the samples after the first read over the time since it, then
    again between the two promptest reads, one in each half. A read is never early, only late
    (a loaded host, a USB adapter's latency timer): the promptest ones lie on the device's own
    time line, so one late last read does not shorten the measure."""
    arrivals, counts = np.asarray(arrivals, dtype=float), np.asarray(counts)
    if arrivals.size < 2 or not arrivals[-1] > arrivals[0]:
        return None
    rough = float(counts[1:].sum() / (arrivals[-1] - arrivals[0]))
    if arrivals.size < 4 or rough <= 0:
        return rough
    through = np.cumsum(counts)  # samples up to the end of each read
    late = arrivals - through / rough  # how late each read is, up to a constant
    half = arrivals.size // 2
    i, j = int(np.argmin(late[:half])), half + int(np.argmin(late[half:]))
    return float((through[j] - through[i]) / (arrivals[j] - arrivals[i]))


def held_line(measured: MeasuredRate, expected_hz: float, config_path, speed: float | None = None) -> str | None:
    """The one line that holds the run, or None when ``measured`` is within TOLERANCE of
    ``expected_hz`` (the config's device.rate_hz, times a simulator's ``speed`` in host time)."""
    off = measured.rate_hz / expected_hz - 1.0
    if abs(off) <= TOLERANCE:
        return None
    served = f" (device.rate_hz × device.sim.speed {speed:g})" if speed not in (None, 1.0) else ""
    return (f"HELD before the first dwell: the device sends {measured.describe()}, {config_path}'s "
            f"device.rate_hz gives {expected_hz:g} Hz{served}, {100 * off:+.1f} %; every dwell and turn "
            "would be timed wrong: set device.rate_hz to the device's rate (or the device's output "
            "rate to the config's), then start again")
