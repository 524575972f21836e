"""The turntable split of the detector's poses (recording.turns) against the definitions it
replaced: the centred moving mean by its plain gather formula, and every threshold's split with
one memo shared across the thresholds against each threshold split on its own."""
from __future__ import annotations

from functools import cache

import numpy as np
import pytest

from drivers.sim.handheld import simulate_handheld
from fieldcal.recording.detect import DetectorSettings, noise_level, pose_candidates
from fieldcal.recording.turns import _moving_mean, split_poses, turning


def moving_mean_by_gather(values: np.ndarray, n: int) -> np.ndarray:
    """The old definition: every sample's [i - n//2, i + n - n//2) clipped, by gathers."""
    cums = np.cumsum(np.r_[np.zeros((1, values.shape[1])), values], axis=0)
    idx = np.arange(len(values))
    lo, hi = np.maximum(idx - n // 2, 0), np.minimum(idx + n - n // 2, len(values))
    return (cums[hi] - cums[lo]) / (hi - lo)[:, None]


@pytest.mark.parametrize("length, n", [(1, 1), (7, 3), (50, 50), (49, 50), (51, 50), (1000, 50), (1000, 51),
                                       (333, 2)])
def test_moving_mean_is_the_gather_formula_bit_for_bit(length, n):
    values = np.random.default_rng(length + n).normal(32768.0, 40.0, (length, 3))
    assert np.array_equal(_moving_mean(values, n), moving_mean_by_gather(values, n))


def test_moving_mean_by_hand():
    values = np.array([[1.0], [2.0], [3.0], [4.0], [5.0]])
    # n = 2: sample i averages [i - 1, i + 1); sample 0 has only itself.
    assert _moving_mean(values, 2)[:, 0].tolist() == [1.0, 1.5, 2.5, 3.5, 4.5]
    # n = 3: [i - 1, i + 2), clipped at both ends.
    assert _moving_mean(values, 3)[:, 0].tolist() == [1.5, 2.0, 3.0, 4.0, 4.5]


@cache
def _turntable():
    sim = simulate_handheld(4, table_turns=((3, 10.0, 8.0), (9, -10.0, 8.0)))
    return sim.triads["accelerometer"], sim.triads["gyroscope"], float(round(1 / np.median(np.diff(sim.t))))


def test_a_memo_shared_by_every_threshold_splits_as_each_threshold_alone():
    acc, gyro, rate_hz = _turntable()
    settings = DetectorSettings()
    noise = noise_level(acc, rate_hz, settings, gyro)
    mask, smooth = turning(gyro, acc, rate_hz, noise, settings)
    memo: dict = {}
    split_any = False
    for found in pose_candidates(acc, rate_hz, settings, gyro=gyro, noise=noise):
        shared = split_poses(found, acc, mask, smooth, rate_hz, settings, memo=memo)
        alone = split_poses(found, acc, mask, smooth, rate_hz, settings)
        split_any |= len(alone[1]) > 0
        assert np.array_equal(shared[1], alone[1])
        for name in ("intervals", "means", "up", "distinct", "short_s"):
            assert np.array_equal(getattr(shared[0], name), getattr(alone[0], name))
    assert split_any and memo  # the turns were found inside poses, and the memo served


def test_moving_mean_takes_the_offset_off_without_copying_the_samples():
    """The still level is taken off in the sums' own array: the same numbers as the mean of the
    samples less it, bit for bit, with no third n-long array (tracemalloc: no clock)."""
    import tracemalloc

    rng = np.random.default_rng(5)
    values = np.round(rng.normal(32768.0, 300.0, (100_000, 3)))
    level = np.array([32700.25, 32810.5, 32768.125])
    want = _moving_mean(values - level, 51)
    tracemalloc.start()
    try:
        got = _moving_mean(values, 51, offset=level)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert np.array_equal(got, want)
    assert peak < 2.2 * values.nbytes  # the sums and the result, nothing else that long
