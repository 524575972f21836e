"""Is the unit still, and is it in the orientation the procedure asked for?

Stillness follows the flight-stack calibrators (PX4 ``detect_orientation``, ArduPilot
``AccelCalibrator``): the unit is still when the dispersion of every axis over a trailing window is
small, with hysteresis so that a noisy window does not make the state flicker. Here the dispersion
is the window standard deviation divided by the triad's expected per-sample white noise, so one pair
of factors serves every device and every output unit:

* a sample becomes **still** when its trailing window (``window_s`` of samples) is complete and every
  axis of both triads has a ratio below ``enter_factor``;
* it becomes **moving** as soon as any axis of either triad has a ratio above ``leave_factor``;
* in between, the previous state is kept.

"Still" means *steady*, not *at rest*: a constant table rate has as little variance as no rate at
all, so a unit spinning steadily on the rate table is still, and the moment it turns still after a
rate command is the moment the table rate has settled. The engine tells rest from rotation by the
window mean of the gyroscope, not by this detector. A slow steady drift also passes (a tilt at
under about 1 °/s keeps the accelerometer ratios below 3); the orientation check catches the
result.

Time comes from the samples only. The window is ``round(window_s · rate_hz)`` samples; the sample
timestamps are used to see gaps: a pause longer than ``max_gap_s`` (a dropped link, a resumed
capture) or a timestamp going backwards restarts the window, since the unit may have moved while
no one was looking. A non-finite sample does the same.

Orientation: at rest the specific force points up, so its direction in body axes is compared with
each position's expected up direction (``Position.up_body``). Positions that differ only in heading
(field-18 positions 1 and 2) share an up direction; gravity cannot tell them apart, and they are
reported together.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from drivers.chunk import SampleChunk
from fieldcal.procedure.sliding import sliding_std

# Position names a type here only: positions (procedure files, YAML) is imported by the functions
# whose messages name positions.
if TYPE_CHECKING:
    from fieldcal.procedure.positions import Position


def _per_axis(value, name: str) -> tuple[float, float, float]:
    try:
        arr = np.broadcast_to(np.asarray(value, dtype=float), (3,))
    except (TypeError, ValueError):  # a word, two numbers: numpy's message would not name the setting
        arr = np.full(3, np.nan)
    if not np.all(np.isfinite(arr)) or np.any(arr <= 0):
        raise ValueError(f"{name}: expected a positive number or three, got {value!r}")
    return float(arr[0]), float(arr[1]), float(arr[2])


def _row_gain(k) -> np.ndarray:
    """Per-output-axis gain of a scale factor given as a scalar, a diagonal (3,) or a matrix (3, 3).

    With noise entering before K (raw = K·(true + noise) + b, independent per input axis), output
    axis i sees the noise times the norm of row i of K.
    """
    if k is None:
        return np.ones(3)
    k = np.asarray(k, dtype=float)
    if k.shape == (3, 3):
        return np.linalg.norm(k, axis=1)
    return np.abs(np.broadcast_to(k, (3,)))


@dataclass(frozen=True, kw_only=True)
class StillnessSettings:
    """Thresholds of the stillness detector.

    ``specific_force_sigma`` and ``rate_sigma``: expected per-sample 1σ white noise of the
    specific-force and angular-rate triads in the device's output units (a number, or one per
    axis). ``enter_factor`` / ``leave_factor``: hysteresis on the ratio (window standard deviation)
    / (expected σ), per axis. ``max_gap_s``: a longer pause between sample timestamps restarts the
    window.
    """

    specific_force_sigma: float | tuple[float, float, float]
    rate_sigma: float | tuple[float, float, float]
    window_s: float = 1.0
    enter_factor: float = 2.0
    leave_factor: float = 3.0
    max_gap_s: float = 0.5

    def __post_init__(self) -> None:
        object.__setattr__(self, "specific_force_sigma",
                           _per_axis(self.specific_force_sigma, "specific_force_sigma"))
        object.__setattr__(self, "rate_sigma", _per_axis(self.rate_sigma, "rate_sigma"))
        if not (math.isfinite(self.window_s) and self.window_s > 0):
            raise ValueError(f"window_s: expected a positive duration, got {self.window_s!r}")
        if not (math.isfinite(self.enter_factor) and self.enter_factor > 0):
            raise ValueError(f"enter_factor: expected a positive number, got {self.enter_factor!r}")
        if not (math.isfinite(self.leave_factor) and self.leave_factor >= self.enter_factor):
            raise ValueError(f"leave_factor: expected a number >= enter_factor "
                             f"({self.enter_factor:g}), got {self.leave_factor!r}")
        if not self.max_gap_s > 0:
            raise ValueError(f"max_gap_s: expected a positive duration, got {self.max_gap_s!r}")

    @classmethod
    def from_noise(cls, white_sf, white_rate, rate_hz: float, k_sf=None, k_rate=None,
                   lsb_sf: float = 0.0, lsb_rate: float = 0.0, **kw) -> StillnessSettings:
        """Settings from SI noise: random-walk coefficients (VRW in m/s²·√s, ARW in rad/s·√s).

        The per-sample white σ at ``rate_hz`` is white·√rate_hz; it is carried to output units by
        the scale factors ``k_sf`` / ``k_rate`` (output units per SI unit: a number, a diagonal
        (3,), or a full K (3, 3); default 1) and widened by quantisation, lsb²/12. Other keywords
        go to the constructor.
        """
        if not rate_hz > 0:
            raise ValueError(f"rate_hz: expected a positive rate, got {rate_hz!r}")

        def sigma(white, k, lsb):
            white = np.broadcast_to(np.asarray(white, dtype=float), (3,))
            return np.sqrt((_row_gain(k) * white * math.sqrt(rate_hz)) ** 2 + lsb**2 / 12.0)

        return cls(specific_force_sigma=tuple(sigma(white_sf, k_sf, lsb_sf)),
                   rate_sigma=tuple(sigma(white_rate, k_rate, lsb_rate)), **kw)


def _trailing_std(x: np.ndarray, n: int) -> np.ndarray:
    """``sliding_std(x, n)`` for the detector's steady path, where x is n − 1 carried rows and
    then the new ones: up to n new rows at a time, every window holds row n − 1 of its piece,
    which serves as the reference (the error scales with the spread around it, as in
    sliding_std), so one pair of cumulative sums per piece does."""
    out = np.empty((len(x) - n + 1, x.shape[1]))
    for first in range(0, len(out), n):
        piece = x[first:first + 2 * n - 1]
        d = piece - piece[n - 1]
        sums = np.zeros((2, len(piece) + 1, x.shape[1]))
        np.cumsum(d, axis=0, out=sums[0, 1:])
        np.cumsum(d * d, axis=0, out=sums[1, 1:])
        s1, s2 = sums[:, n:] - sums[:, :-n]
        var = (s2 - s1 * s1 / n) / (n - 1)
        out[first:first + len(var)] = var
    np.maximum(out, 0.0, out=out)
    return np.sqrt(out, out=out)


class StillnessDetector:
    """Per-sample stillness of a stream of chunks; state carried across chunks of any size.

    ``feed(chunk)`` returns a bool per sample: still at that sample, judged on the trailing window
    ending at it. Not still until a full window has been seen (and again after a gap). Pure: no
    clock, no I/O; the same samples give the same answer however they are chunked.
    ``angular_rate=None`` watches the specific-force triad alone.
    """

    def __init__(self, settings: StillnessSettings, rate_hz: float,
                 specific_force: str = "accelerometer", angular_rate: str | None = "gyroscope"):
        if not rate_hz > 0:
            raise ValueError(f"rate_hz: expected a positive rate, got {rate_hz!r}")
        self.settings = settings
        self.rate_hz = float(rate_hz)
        self.window_samples = round(settings.window_s * rate_hz)
        if self.window_samples < 2:
            raise ValueError(f"window_s={settings.window_s:g} s at {rate_hz:g} Hz is "
                             f"{self.window_samples} sample(s); need at least 2")
        self.names = (specific_force,) + ((angular_rate,) if angular_rate else ())
        sigmas = [settings.specific_force_sigma] + ([settings.rate_sigma] if angular_rate else [])
        self._inv_sigma = 1.0 / np.concatenate([np.asarray(s, dtype=float) for s in sigmas])
        self.reset()

    def reset(self) -> None:
        """Forget everything: as if no sample had been seen."""
        self._carry = np.empty((0, len(self._inv_sigma)))
        self._run = 0  # consecutive usable samples (no gap) up to the last one fed, capped at N
        self._t_last: float | None = None
        self._still = False
        self._ratios = np.full(len(self._inv_sigma), np.nan)

    @property
    def still(self) -> bool:
        """The state at the last sample fed."""
        return self._still

    @property
    def last_ratios(self) -> dict[str, np.ndarray]:
        """Per triad, the ratio (window std)/(expected σ) per axis at the last sample fed; NaN
        until a full window exists. A live "how quiet is it" meter for the operator."""
        return {name: self._ratios[3 * k:3 * k + 3].copy() for k, name in enumerate(self.names)}

    def feed(self, chunk: SampleChunk) -> np.ndarray:
        """Bool (n,): still at each sample of the chunk, judged on the trailing window ending there
        (samples of earlier chunks included)."""
        n = len(chunk)
        if n == 0:
            return np.zeros(0, dtype=bool)
        missing = [name for name in self.names if name not in chunk.triads]
        if missing:
            raise ValueError(f"chunk has no triad {missing[0]!r} (has {sorted(chunk.triads)})")
        N = self.window_samples
        # The carried samples, then the new ones in units of their expected σ, in one array.
        m0 = len(self._carry)
        x = np.empty((m0 + n, len(self._inv_sigma)))
        x[:m0] = self._carry
        new = x[m0:]
        for k, name in enumerate(self.names):
            new[:, 3 * k:3 * k + 3] = chunk.triads[name]
        new *= self._inv_sigma
        t = np.asarray(chunk.t, dtype=float)
        dt = np.empty(n)
        dt[0] = t[0] - (t[0] if self._t_last is None else self._t_last)
        np.subtract(t[1:], t[:-1], out=dt[1:])
        if self._run == N and 0.0 <= dt.min() and dt.max() <= self.settings.max_gap_s \
                and math.isfinite(float(new.sum())):
            # No gap, no bad sample (a NaN or infinity reaches the sum; an overflow of the sum
            # merely takes the general path), a full window before: nearly every chunk.
            return self._feed_steady(x, t, n)
        bad = ~np.all(np.isfinite(new), axis=1)
        if bad.any():
            new[bad] = 0.0  # every window holding it is invalid below; keep the sums finite
        gap = ~(dt <= self.settings.max_gap_s) | (dt < 0)  # NaN time counts as a gap

        idx = m0 + np.arange(n)
        # Start of the unbroken stretch each sample belongs to (in concatenation indices): a gap
        # before a sample starts a stretch at it; a bad sample starts one after it.
        starts = np.full(n, m0 - self._run)
        starts = np.where(gap, idx, starts)
        starts = np.where(bad, idx + 1, starts)
        starts = np.maximum.accumulate(starts)
        valid = idx - starts + 1 >= N

        ratios = np.full((n, len(self._inv_sigma)), np.nan)
        std = sliding_std(x, N)  # row r = window ending at concatenation index r + N - 1
        have = idx >= N - 1
        ratios[have] = std[idx[have] - (N - 1)]
        quiet = valid & np.all(ratios < self.settings.enter_factor, axis=1)
        loud = valid & np.any(ratios > self.settings.leave_factor, axis=1)
        decisive = quiet | loud | ~valid  # an incomplete window counts as moving
        last = np.maximum.accumulate(np.where(decisive, np.arange(n), -1))
        out = np.where(last >= 0, quiet[np.maximum(last, 0)], self._still)

        self._still = bool(out[-1])
        self._carry = x[-(N - 1):].copy()
        self._run = int(min(N, max(0, idx[-1] - starts[-1] + 1)))
        self._t_last = float(t[-1])
        self._ratios = ratios[-1] if valid[-1] else np.full(len(self._inv_sigma), np.nan)
        return out

    def _feed_steady(self, x: np.ndarray, t: np.ndarray, n: int) -> np.ndarray:
        """``feed`` when a full unbroken window precedes the chunk and the chunk has no gap and
        no bad sample (nearly every chunk): every window is valid; the same answer, fewer steps."""
        N = self.window_samples
        ratios = _trailing_std(x, N)  # n rows: the window ending at each new sample
        if ratios.max() < self.settings.enter_factor:
            # Still throughout (a dwell, most chunks of a run): one reduction over the whole
            # array instead of a row-by-row one (np.all along rows of 6 costs ~5× as much). A NaN
            # ratio fails the test here and goes the general way, as it fails "quiet" there.
            out = np.ones(n, dtype=bool)
        else:
            quiet = np.all(ratios < self.settings.enter_factor, axis=1)
            decisive = quiet | np.any(ratios > self.settings.leave_factor, axis=1)
            last = np.maximum.accumulate(np.where(decisive, np.arange(n), -1))
            out = np.where(last >= 0, quiet[np.maximum(last, 0)], self._still)
        self._still = bool(out[-1])
        self._carry = x[-(N - 1):].copy()
        self._t_last = float(t[-1])
        self._ratios = ratios[-1]
        return out


# ---------------------------------------------------------------------------------------------
# Orientation


def gravity_direction(mean_specific_force, zero=None, sensitivity=None) -> np.ndarray:
    """Unit vector of the mean specific force in body axes: local up, as ``Position.up_body``.

    The output axes are taken as the body axes (misalignments are milliradians). A device that
    reports raw counts needs its nominal ``zero`` (offset, output units) and ``sensitivity``
    (output units per m/s²), a number or one per axis; only their ratio between axes matters.
    """
    f = np.asarray(mean_specific_force, dtype=float)
    if zero is not None:
        f = f - np.asarray(zero, dtype=float)
    if sensitivity is not None:
        f = f / np.asarray(sensitivity, dtype=float)
    norm = np.linalg.norm(f, axis=-1, keepdims=True)
    if not np.all(np.isfinite(norm)) or np.any(norm == 0):
        raise ValueError("specific force has no direction (zero or not finite)")
    return f / norm


def angle_between(a, b) -> np.ndarray | float:
    """Angle between vectors in degrees (0..180), accurate near 0 and 180; broadcasts."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    angle = np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1)))
    return float(angle) if np.ndim(angle) == 0 else angle


def closest_positions(direction, positions: Sequence[Position],
                      tolerance_deg: float = 15.0) -> list[tuple[Position, float]]:
    """Positions whose expected up direction is within ``tolerance_deg`` of ``direction``,
    nearest first (procedure order among equals: positions sharing an up direction all appear)."""
    if not positions:
        return []
    ups = np.array([p.up_body for p in positions])
    angles = np.atleast_1d(angle_between(ups, np.asarray(direction, dtype=float)))  # (one per position)
    order = np.argsort(angles, kind="stable")
    return [(positions[i], float(angles[i])) for i in order if angles[i] <= tolerance_deg]


@dataclass(frozen=True)
class OrientationCheck:
    """Outcome of comparing the measured up direction with the one a position expects.

    ``tilt_axis``: body axis (unit vector) about which to tilt the unit by ``angle_deg``
    (right-hand rule) to bring it to the expected up direction; zeros if already there.
    """

    ok: bool
    angle_deg: float
    looks_like: tuple[tuple[Position, float], ...]
    message: str
    tilt_axis: tuple[float, float, float] = (0.0, 0.0, 0.0)


_AXES = "xyz"


def _body_direction_name(v: np.ndarray) -> str:
    """'-x' for an axis, 'x+z' or '-x-y-z' for a diagonal (within 10°), else the components."""
    from fieldcal.procedure.positions import body_direction_name

    v = v / np.linalg.norm(v)
    return body_direction_name(v) or "(" + ", ".join(f"{c:.2f}" for c in v) + ")"


def describe_up(direction) -> str:
    """Which body axes point up or down, in the words of the procedure files: 'z-upward',
    or 'x-upward 45°, z-upward 45°' (elevation of each axis above the horizontal)."""
    u = np.asarray(direction, dtype=float)
    u = u / np.linalg.norm(u)
    elevation = np.degrees(np.arcsin(np.clip(np.abs(u), 0.0, 1.0)))
    order = np.argsort(-elevation, kind="stable")

    def word(i):
        return f"{_AXES[i]}-{'upward' if u[i] > 0 else 'downward'}"

    if elevation[order[0]] >= 75:
        return word(order[0])
    return ", ".join(f"{word(i)} {elevation[i]:.0f}°" for i in order if elevation[i] >= 10)


def _tilt_axis(measured: np.ndarray, expected: np.ndarray) -> np.ndarray:
    """Body axis to tilt about, right-hand rule, to carry the measured up onto the expected one.

    The up vector is fixed in space, so in body axes it turns opposite to the body: rotating the
    body by +θ about a turns up by -θ about a. Turning m onto e is +θ about m×e, so a = e×m.
    """
    axis = np.cross(expected, measured)
    norm = np.linalg.norm(axis)
    if norm > 1e-9:
        return axis / norm
    if np.dot(measured, expected) > 0:
        return np.zeros(3)
    # Upside down: any axis perpendicular to the expected up will do; take the nearest body axis.
    e = np.zeros(3)
    e[int(np.argmin(np.abs(expected)))] = 1.0
    axis = e - np.dot(e, expected) * expected
    return axis / np.linalg.norm(axis)


def _or_list(ids: list[int]) -> str:
    words = [str(i) for i in ids]
    return words[0] if len(words) == 1 else ", ".join(words[:-1]) + " or " + words[-1]


def check_orientation(direction, expected: Position, positions: Sequence[Position],
                      tolerance_deg: float = 15.0) -> OrientationCheck:
    """Is the measured up ``direction`` (body axes) that of ``expected``? If not, which positions
    does it look like, and which way to tilt. Heading is not checked: gravity cannot see it."""
    from fieldcal.procedure.positions import position_words

    m = np.asarray(direction, dtype=float)
    m = m / np.linalg.norm(m)
    e = expected.up_body / np.linalg.norm(expected.up_body)
    angle = float(angle_between(m, e))  # (two vectors: one angle)
    looks_like = tuple(closest_positions(m, positions, tolerance_deg))
    axis = _tilt_axis(m, e)
    tilt = float(axis[0]), float(axis[1]), float(axis[2])
    if angle <= tolerance_deg:
        return OrientationCheck(True, angle, looks_like,
                                f"position {expected.id} ({position_words(expected)}): orientation ok, "
                                f"{angle:.0f}° from the expected up direction", tilt)
    if looks_like:
        ids = [p.id for p, _ in looks_like]
        seen = f"the unit looks like position {_or_list(ids)} ({describe_up(looks_like[0][0].up_body)})"
    else:
        seen = f"the unit is {describe_up(m)}, like no position"
    how = (f"tilt it {angle:.0f}° about the body {_body_direction_name(axis)} axis (right-hand rule) "
           f"until {_body_direction_name(e)} points up")
    message = (f"position {expected.id} expects {position_words(expected)}, but {seen}, "
               f"{angle:.0f}° away; {how}")
    return OrientationCheck(False, angle, looks_like, message, tilt)
