"""Turntable turns inside a recording: kept out of the static poses, and, at a known table rate,
turned into norm equations |K⁻¹(u − b)| = rate that the gyro's rotation solve takes as well.

On a turntable turning about the vertical the accelerometer sees gravity as still as in a pose;
only the gyro tells. So a stretch whose gyro mean (over half a second) leaves the still gyro's
level by more than a real unit's still reading ever moves is split out of the accelerometer's
static interval; where such a stretch holds one rate vector (within ``STEADY_FRACTION``) for
``MIN_TURN_S``, it is a turn.

The still level is the median over the accelerometer's quietest windows, not the initial rest's
mean: a real MEMS gyro's still reading moves by 0.02-0.17 °/s between poses (g-sensitivity,
bias shifts, warm-up), far beyond the white noise of a half-second mean. So a stretch is turning
only when its rate leaves the still level by more than all of: ``GATE_SIGMAS`` σ of the mean's
white noise, ``SHIFT_MULTIPLE`` times the typical shift of the quiet windows' means (what this
unit's still reading does), and ``MIN_TURN_DEG_S`` in a known rate unit (slower than any turntable
or hand turn, faster than any still reading): the angle a still pose can integrate is that of its
noise and its bias shift, not of a turn.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from fieldcal.earth import EARTH_RATE, Station
from fieldcal.model import calibrate_with
from fieldcal.recording.detect import (DetectorSettings, NoiseLevel, Poses, distinct_poses, interval_means,
                                       quiet_windows, row_sums, true_runs, up_directions)

GATE_SIGMAS = 20.0  # half-second gyro mean this many of its σ from the still level: turning
SHIFT_MULTIPLE = 5.0  # ... and this many times the quiet windows' typical shift
MIN_TURN_DEG_S = 0.5  # ... and, in a known unit, at least this rate
# In raw counts, when the median quiet window's distance from the still level is this many times
# the quietest quarter's (or the white noise's gate, if above), more than half of the windows
# turn (a turntable's steady turns read a hundred times a still reading's shift and more), and
# the still ones are those within that multiple.
STILL_GAP = 20.0
BESIDE_TURN = 0.5  # of min_static_s: the least a still piece beside a turn keeps
STEADY_FRACTION = 0.02  # a turn's rate vector stays within this fraction of its median
MIN_TURN_S = 2.0


def _moving_mean(values: np.ndarray, n: int, offset=0.0) -> np.ndarray:
    """Centred mean over n samples (shorter at the ends), per column, of ``values`` less
    ``offset`` (taken off in the sums' own array: no copy of the samples)."""
    length = len(values)
    cums = np.zeros((length + 1, values.shape[1]))
    np.subtract(values, offset, out=cums[1:])
    np.cumsum(cums[1:], axis=0, out=cums[1:])
    before, after = n // 2, n - n // 2  # sample i averages [i - before, i + after), clipped to the data
    if length < n:
        idx = np.arange(length)
        lo, hi = np.maximum(idx - before, 0), np.minimum(idx + after, length)
        return (cums[hi] - cums[lo]) / (hi - lo)[:, None]
    out = np.empty(values.shape)
    # Samples before..length-after see a whole window: slices, not gathers; the ends, a shorter one.
    np.subtract(cums[n:], cums[:length + 1 - n], out=out[before:length + 1 - after])
    out[before:length + 1 - after] /= n
    head, tail = np.arange(before), np.arange(length + 1 - after, length)
    out[:before] = cums[head + after] / (head + after)[:, None]
    out[length + 1 - after:] = (cums[length] - cums[tail - before]) / (length - tail + before)[:, None]
    return out


def turning(gyro: np.ndarray, acc: np.ndarray, rate_hz: float, noise: NoiseLevel, settings: DetectorSettings,
            units_per_rad_s: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(mask of samples whose gyro says the unit turns, the half-second means less the still
    level). ``units_per_rad_s``: the gyro's output unit per rad/s when known (not for counts)."""
    n = max(1, round(0.5 * rate_hz))
    window = 2 * max(1, round(settings.window_s * rate_hz) // 2) + 1
    means = noise.quiet_gyro_means  # made with the noise level's variances, when it was measured so
    if means is None:
        quiet = noise.quiet if noise.quiet is not None else quiet_windows(acc, rate_hz, settings)
        whole = len(gyro) // window * window  # the windows' means (as window_variances sums them); no variances
        means = (np.asarray(gyro[:whole], dtype=float).reshape(-1, window, gyro.shape[1]).sum(axis=1) / window)[quiet]
    level = np.median(means, axis=0)
    distance = np.linalg.norm(means - level, axis=1)
    shift = float(np.median(distance)) if len(distance) else 0.0
    still = ()
    if units_per_rad_s:
        still = distance[distance < math.radians(MIN_TURN_DEG_S) * units_per_rad_s]
    elif len(distance):  # raw counts, no rate to tell: see STILL_GAP
        quietest = max(float(np.percentile(distance, 25)),
                       GATE_SIGMAS * float(np.sqrt(np.mean(noise.gyro_variance) / n)))
        if shift > STILL_GAP * quietest:
            still = distance[distance <= STILL_GAP * quietest]
    if len(still):
        # On a turntable the accelerometer is quiet while the table turns, so in a Ferraris
        # session more than half of the quiet windows may be turning: in a known unit, windows
        # beyond MIN_TURN_DEG_S are no still reading's shift and are left out (in counts, those
        # beyond STILL_GAP); of the others the upper quartile, since a long
        # initial rest's windows all sit at the level.
        shift = float(np.percentile(still, 75))
    sigma = float(np.sqrt(np.mean(noise.gyro_variance)))
    low = max(GATE_SIGMAS * sigma / math.sqrt(n), SHIFT_MULTIPLE * shift)
    high = max(low, math.radians(MIN_TURN_DEG_S) * units_per_rad_s) if units_per_rad_s else low
    smooth = _moving_mean(gyro, n, offset=level)
    rate = np.sqrt(row_sums(np.square(smooth)))  # norm's own steps, its rows summed column by column
    # A turn is a stretch above the high gate, and all of it, down to the low one on either side
    # (its slow start and stop are still motion).
    runs = true_runs(rate > low)
    mask = np.zeros(len(rate), dtype=bool)
    if len(runs):
        peaks = np.maximum.reduceat(rate, runs[:, 0])
        for a, b in runs[peaks > high]:  # a loop over turns, not samples
            mask[a:b] = True
    return mask, smooth


_TURNING_SAMPLES = "turning samples"  # split_poses' memo: the mask's running count (an interval's key is (a, b))


def split_poses(poses: Poses, acc: np.ndarray, turn_mask: np.ndarray, smooth: np.ndarray,
                rate_hz: float, settings: DetectorSettings, zero=None,
                memo: dict | None = None) -> tuple[Poses, np.ndarray]:
    """The poses without the turning samples (pieces shorter than min_static_s dropped) and the
    steady turns found inside static intervals ((k, 2) [start, stop)). ``memo``: a dict kept
    across calls with the same mask, smooth rates and settings (every threshold's poses): an
    interval's pieces and turns, worked out once (the thresholds share most intervals), and the
    count of turning samples before each sample (an n-long sum: on imu_tk's recording joined
    16×, ten of them took as long as the rest of the split)."""
    memo = {} if memo is None else memo
    turning_samples = memo.get(_TURNING_SAMPLES)
    if turning_samples is None:
        turning_samples = memo[_TURNING_SAMPLES] = np.r_[0, np.cumsum(turn_mask)]
    touched = turning_samples[poses.intervals[:, 1]] > turning_samples[poses.intervals[:, 0]]
    if not touched.any():  # the usual case, no interval holds a turning sample: all at once
        return poses, np.zeros((0, 2), int)
    pieces, turns = [], []
    for (a, b), touches in zip(poses.intervals.tolist(), touched):  # a loop over poses
        if not touches:
            pieces.append((a, b))
            continue
        if (a, b) not in memo:
            memo[a, b] = _split_interval(a, b, turn_mask, smooth, rate_hz, settings)
        more_pieces, more_turns = memo[a, b]
        pieces += more_pieces
        turns += more_turns
    if len(pieces) == len(poses.intervals):
        return poses, np.zeros((0, 2), int)
    intervals = np.array(pieces, dtype=int).reshape(-1, 2)
    means = interval_means(acc, intervals)
    up = up_directions(means, zero)
    return replace(poses, intervals=intervals, means=means, up=up,
                   distinct=distinct_poses(up, settings.min_separation_deg)), np.array(turns, int).reshape(-1, 2)


def _split_interval(a: int, b: int, turn_mask: np.ndarray, smooth: np.ndarray, rate_hz: float,
                    settings: DetectorSettings) -> tuple[list, list]:
    """The still pieces and the steady turns of the static interval [a, b), which holds turning
    samples."""
    min_n, min_turn = round(settings.min_static_s * rate_hz), round(MIN_TURN_S * rate_hz)
    # A piece beside a turn inside one still pose is that pose's still reading for the turn:
    # the pose was still for min_static_s as a whole, and the turn's slow start takes some
    # of it (a 3 s pose before a slow table turn kept 1.95 s, and the turn was lost).
    pieces = [(a + s, a + e) for s, e in true_runs(~turn_mask[a:b]) if e - s >= min_n * BESIDE_TURN]
    turns = []
    for s, e in true_runs(turn_mask[a:b]):
        rate = smooth[a + s:a + e]
        median = np.median(rate, axis=0)
        steady = np.linalg.norm(rate - median, axis=1) < STEADY_FRACTION * np.linalg.norm(median)
        turns += [(a + s + i, a + s + j) for i, j in true_runs(steady) if j - i >= min_turn]
    return pieces, turns


def rate_residuals(gyro: np.ndarray, acc_values: np.ndarray, acc_theta: np.ndarray, turns: np.ndarray,
                   table_rate_deg_s: float, station: Station, b0: np.ndarray, k: float,
                   rest_var: np.ndarray):
    """extra_residuals(K_inv, bias) for the rotation solve: per turn, (|K⁻¹(u − b)| − ref)/σ with
    ref the table rate plus the vertical Earth rate in the turn's sense, σ the mean's white noise."""
    counts = np.diff(turns, axis=1)[:, 0]
    u = interval_means(gyro, turns)
    up = calibrate_with(acc_theta, interval_means(acc_values, turns))
    up /= np.linalg.norm(up, axis=1)[:, None]
    sense = np.sign(np.einsum("ij,ij->i", up, u - b0))
    ref = np.abs(sense * math.radians(table_rate_deg_s) + EARTH_RATE * math.sin(station.latitude_rad))
    sigma = np.sqrt(np.mean(rest_var) / counts) / k

    def residuals(K_inv, bias):
        return (np.linalg.norm((u - bias) @ K_inv.T, axis=1) - ref) / sigma
    return residuals
