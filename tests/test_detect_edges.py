"""The detector's loops made numpy against their plain definitions: the edge search
(detect._first_loud: per run, the first k-sample window, going by ±1 from ``first``, whose mean z²
exceeds the threshold) and the choice of distinct poses (detect.distinct_poses)."""
from __future__ import annotations

import numpy as np
import pytest

from fieldcal.recording.detect import _first_loud, distinct_poses


def first_loud_by_definition(columns, inv_var, means, first, length, step, k, threshold):
    x = np.hstack(columns)
    out = []
    for r in range(len(first)):  # a loop over runs: the definition, not the product's code
        found = length[r] - k + 1
        for s in range(length[r] - k + 1):
            rows = np.clip(first[r] + step * (s + np.arange(k)), 0, len(x) - 1)
            if np.mean(((x[rows] - means[r]) ** 2) @ inv_var) > threshold:
                found = s
                break
        out.append(found)
    return np.array(out)


def test_a_window_by_hand():
    # One column, unit variance, mean 0: samples 0 0 0 3 3 0. With k = 2 and threshold 4, the
    # windows from sample 1 going up read z² means 0, 4.5 (samples 2-3): the second, at 1 step.
    x = np.array([[0.0], [0.0], [0.0], [3.0], [3.0], [0.0]])
    got = _first_loud((x,), np.array([1.0]), np.zeros((1, 1)), np.array([1]), np.array([5]), 1, 2, 4.0)
    assert got.tolist() == [1]
    # Going down from sample 4: samples 4-3 read 9 at once.
    got = _first_loud((x,), np.array([1.0]), np.zeros((1, 1)), np.array([4]), np.array([5]), -1, 2, 4.0)
    assert got.tolist() == [0]


@pytest.mark.parametrize("step", [1, -1])
def test_first_loud_is_its_definition_on_random_runs(step):
    rng = np.random.default_rng(7 + step)
    n = 600
    acc = rng.normal(0.0, 1.0, (n, 3)) + 32768.0
    gyro = rng.normal(0.0, 2.0, (n, 3))
    loud = rng.integers(0, n, 40)
    acc[loud] += rng.normal(0.0, 30.0, (40, 3))  # motions the windows run into
    runs = 150  # more than one batch of runs
    first = rng.integers(0, n, runs)
    length = rng.integers(5, 60, runs)  # some run past either end: the samples are clipped
    means = np.hstack([acc[first], gyro[first]]) + rng.normal(0.0, 0.5, (runs, 6))
    inv_var = 1.0 / np.r_[[1.0] * 3, [4.0] * 3]
    k, threshold = 5, 6.0 + 6.0 * np.sqrt(2.0 * 6 / 5)
    got = _first_loud((acc, gyro), inv_var, means, first, length, step, k, threshold)
    want = first_loud_by_definition((acc, gyro), inv_var, means, first, length, step, k, threshold)
    assert np.array_equal(got, want)
    assert 0 < np.sum(got < length - k + 1) < runs  # both found and not-found runs were tested


def distinct_by_definition(up: np.ndarray, min_separation_deg: float) -> list[bool]:
    """A pose is distinct when no earlier distinct pose lies within the separation."""
    out: list[bool] = []
    for i in range(len(up)):
        angles = [np.degrees(np.arccos(np.clip(up[i] @ up[j], -1, 1))) for j in range(i) if out[j]]
        out.append(all(a >= min_separation_deg for a in angles))
    return out


@pytest.mark.parametrize("seed", range(5))
def test_distinct_poses_is_its_definition(seed):
    rng = np.random.default_rng(seed)
    centres = rng.normal(size=(8, 3))
    up = centres[rng.integers(0, 8, 40)] + rng.normal(0.0, 0.15, (40, 3))  # clusters: repeats and near ones
    up /= np.linalg.norm(up, axis=1)[:, None]
    got = distinct_poses(up, 10.0)
    assert got.tolist() == distinct_by_definition(up, 10.0)
    assert 0 < got.sum() < len(up)


def test_distinct_poses_of_a_long_repeated_recording_are_its_definition():
    """A few poses held again and again (a long recording, or one joined to itself): the loop
    goes from one distinct pose to the next, and the far repeats, the last pose and a recording
    whose every pose is distinct come out as the definition says."""
    rng = np.random.default_rng(8)
    centres = rng.normal(size=(12, 3))
    centres /= np.linalg.norm(centres, axis=1)[:, None]
    up = np.tile(centres, (30, 1)) + rng.normal(0.0, 0.02, (360, 3))
    up = np.vstack([up, -centres[:1]])  # a last pose unlike any before it
    up /= np.linalg.norm(up, axis=1)[:, None]
    got = distinct_poses(up, 10.0)
    assert got.tolist() == distinct_by_definition(up, 10.0)
    assert got[-1] and got.sum() <= 13
    spread = up[got]
    assert distinct_poses(spread, 10.0).all()  # every pose distinct: each one visited
    assert distinct_poses(up[:1], 10.0).tolist() == [True]


def runs_by_definition(stat, levels, still_head):
    """Each level's runs of stat < level, the first still_head samples in them, level by level."""
    owners, edges = [], []
    for j, level in enumerate(levels):
        below = np.r_[False, stat < level, False]
        below[1:still_head + 1] = True
        change = np.flatnonzero(below[1:] != below[:-1])
        owners.append(np.full(len(change), j))
        edges.append(change)
    return np.concatenate(owners), np.concatenate(edges)


@pytest.mark.parametrize("seed", range(4))
def test_every_thresholds_runs_from_the_ranks_are_each_thresholds_own(seed):
    """The runs below each threshold, found where a sample's rank among the thresholds moves,
    are those of comparing every sample with every threshold: thresholds out of order and
    repeated, a statistic on a threshold exactly, NaN (never still), a still head."""
    from fieldcal.recording.detect import _level_edges

    rng = np.random.default_rng(seed)
    stat = np.exp(rng.normal(0.0, 1.0, 3000))
    stat[rng.integers(0, 3000, 30)] = np.nan
    levels = np.array([2.0, 0.5, 1.0, 8.0, 1.0, 3.0])
    stat[rng.integers(0, 3000, 30)] = levels[rng.integers(0, len(levels), 30)]
    for head in (0, 1, 137):
        got = _level_edges(stat, levels, head)
        want = runs_by_definition(stat, levels, head)
        np.testing.assert_array_equal(got[0], want[0])
        np.testing.assert_array_equal(got[1], want[1])
    assert len(_level_edges(np.full(5, np.nan), levels, 0)[1]) == 0
    owner, edges = _level_edges(np.zeros(5), levels, 0)  # still throughout: one run a threshold
    assert owner.tolist() == [0, 0, 1, 1, 2, 2, 3, 3, 4, 4, 5, 5] and edges.tolist() == [0, 5] * 6


def test_prefix_means_are_the_old_sums_bit_for_bit_and_the_means_by_hand():
    from fieldcal.recording.detect import PrefixMeans

    rng = np.random.default_rng(3)
    values = 32768.0 + rng.normal(0.0, 40.0, (5000, 3)).round()
    intervals = np.sort(rng.integers(0, 5001, (60, 2)), axis=1)
    intervals = intervals[intervals[:, 1] > intervals[:, 0]]
    cums = np.zeros((len(values) + 1, 3))  # the sums as made before (ed231b9): row by row
    np.cumsum(values - values[0], axis=0, out=cums[1:])
    old = values[0] + (cums[intervals[:, 1]] - cums[intervals[:, 0]]) / np.diff(intervals, axis=1)
    assert np.array_equal(PrefixMeans(values)(intervals), old)
    hand = PrefixMeans(np.array([[1.0, 10.0], [2.0, 20.0], [6.0, 60.0]]))
    assert hand(np.array([[0, 3], [1, 3], [2, 3]])).tolist() == [[3.0, 30.0], [4.0, 40.0], [6.0, 60.0]]


@pytest.mark.parametrize("to_end", [False, True])
def test_prefix_means_of_any_intervals_make_no_copy_of_the_samples(to_end):
    """Overlapping intervals in any order (as every threshold's runs are), the last one ending at
    the last sample or not: the means of each interval by hand (np.mean, fractional values), made
    without any allocation the size of the samples (the cumulative sum it replaced was two)."""
    import tracemalloc

    from fieldcal.recording.detect import PrefixMeans

    rng = np.random.default_rng(4)
    values = 1.0e4 + rng.normal(0.0, 3.0, (200_000, 3))
    intervals = np.sort(rng.integers(0, len(values) + 1, (300, 2)), axis=1)
    intervals = intervals[intervals[:, 1] > intervals[:, 0]]
    intervals[-1, 1] = len(values) if to_end else len(values) - 7
    tracemalloc.start()
    try:
        got = PrefixMeans(values)(intervals)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    want = np.array([values[a:b].mean(axis=0) for a, b in intervals])
    assert np.allclose(got, want, rtol=0.0, atol=1e-9)
    assert peak < values.nbytes / 20


def test_window_variances_are_np_vars_own_steps_without_a_copy_of_the_samples():
    """Per-window variance and mean bit for bit as the whole-array steps (np.var's), made some
    windows at a time: nothing the size of the samples is allocated (tracemalloc: no clock)."""
    import tracemalloc

    from fieldcal.recording.detect import window_variances

    rng = np.random.default_rng(7)
    counts = np.round(rng.normal(33000.0, 30.0, (400_003, 3)))
    si = rng.normal(9.81, 0.03, (400_003, 3))  # not integers: the order of the additions shows in the bits
    for values, window in ((counts, 101), (counts, 65_537), (si, 101), (si, 1201), (si[:3000], 1000)):
        k = len(values) // window
        blocks = values[:k * window].reshape(k, window, 3)
        means = blocks.sum(axis=1) / window
        deviations = blocks - means[:, None, :]
        want = np.einsum("kwd,kwd->kd", deviations, deviations) / window
        tracemalloc.start()
        try:
            variance, mean = window_variances(values, window)
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
        assert np.array_equal(variance, want) and np.array_equal(mean, means)
        np.testing.assert_allclose(variance, blocks.var(axis=1), rtol=1e-12)
        assert peak < 4 << 20  # two chunks of deviations (~1.5 MiB each) at most, whatever the length


def test_row_sums_are_numpys_row_sums_bit_for_bit():
    """Summed column by column, in numpy's own order: the same bits as ``sum(axis=1)`` on values
    of every magnitude (the other order, a0 + (a1 + a2), differs in some)."""
    from fieldcal.recording.detect import row_sums

    rng = np.random.default_rng(3)
    values = rng.normal(size=(100_000, 3)) * 10.0 ** rng.integers(-8, 8, size=(100_000, 3))
    assert np.array_equal(row_sums(values), values.sum(axis=1))
    assert not np.array_equal(values[:, 0] + (values[:, 1] + values[:, 2]), values.sum(axis=1))
    assert np.array_equal(row_sums(values[:, :1]), values[:, 0])


def window_statistic_by_definition(acc, half):
    """At sample i the norm over axes of the per-axis variance of samples i - half..i + half;
    within half a window of either end, the nearest full window's."""
    out = []
    for i in range(len(acc)):  # a loop over samples: the definition
        centre = min(max(i, half), len(acc) - 1 - half)
        out.append(np.linalg.norm(acc[centre - half:centre + half + 1].var(axis=0)))
    return np.array(out)


@pytest.mark.parametrize("n, rate_hz", [(60, 20.0), (400, 100.0)])
def test_window_statistic_is_its_definition(n, rate_hz):
    from fieldcal.recording.detect import DetectorSettings, _half_window, window_statistic

    rng = np.random.default_rng(n)
    acc = 32768.0 + rng.normal(0.0, 2.0, (n, 3))  # raw counts about mid-scale
    acc[n // 3:n // 2] += rng.normal(0.0, 300.0, (n // 2 - n // 3, 3))  # a motion
    settings = DetectorSettings()
    half = _half_window(rate_hz, settings)
    got = window_statistic(acc, rate_hz, settings)
    np.testing.assert_allclose(got, window_statistic_by_definition(acc, half), rtol=1e-9)
    with pytest.raises(ValueError, match="fewer than a window"):
        window_statistic(acc[:2 * half], rate_hz, settings)
