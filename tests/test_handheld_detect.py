"""The hand-held recording simulator and the static-pose detector, against the simulator's truth."""
from __future__ import annotations

from dataclasses import replace
from functools import cache

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from drivers.sim.handheld import (CONSUMER_NOISE, SPREAD_UP, handheld_truth, simulate_handheld,
                                  to_text)
from fieldcal.recording.detect import (DetectionError, DetectorSettings, check_spread, distinct_poses,
                                       noise_level, pose_candidates, require_poses, true_runs, window_variances)

SETTINGS = DetectorSettings(init_rest_s=30.0)  # the simulator starts with 30 s still


def find_poses(acc, rate_hz, settings, multiple, noise=None, zero=None, sensitivity=None, gyro=None):
    """The poses found at one threshold multiple alone (the calibration tries several)."""
    return pose_candidates(acc, rate_hz, replace(settings, multiples=(multiple,)), zero, sensitivity, gyro,
                           noise)[0]


@cache
def recording(seed: int, **kw):
    return simulate_handheld(seed, **kw)


def angle_between(a: np.ndarray, b: np.ndarray) -> float:
    """Angle (rad) of the rotation taking matrix a to matrix b."""
    return float(Rotation.from_matrix(a.T @ b).magnitude())


def integrate(start: np.ndarray, omega_at, duration: float, steps: int = 40_000) -> np.ndarray:
    """Attitude after integrating body rate omega_at(t) (n, 3) from ``start`` by the midpoint rule;
    the increments are composed pairwise (vectorised), keeping their order."""
    dt = duration / steps
    increments = Rotation.from_rotvec(omega_at((np.arange(steps) + 0.5) * dt) * dt)
    while len(increments) > 1:
        if len(increments) % 2:
            increments = Rotation.concatenate([increments, Rotation.identity()])
        increments = increments[0::2] * increments[1::2]
    return start @ increments[0].as_matrix()


# --- simulator ------------------------------------------------------------------------------------

def test_integrated_rate_carries_each_pose_to_the_next():
    rec = recording(1, n_poses=8)
    for i, motion in enumerate(rec.motions):
        end = integrate(motion.start, lambda t, m=motion: m.evaluate(t)[1], motion.duration_s)
        assert angle_between(end, rec.attitudes[i + 1]) < 1e-6
        np.testing.assert_allclose(motion.start, rec.attitudes[i], atol=1e-12)


def test_motions_do_not_commute():
    # The rate's direction changes during a motion: summing it as a vector misses the next pose.
    rec = recording(1, n_poses=8)
    for i, motion in enumerate(rec.motions):
        t = np.linspace(0.0, motion.duration_s, 20_001)
        summed = np.trapezoid(motion.evaluate(t)[1], t, axis=0)
        assert angle_between(motion.start @ Rotation.from_rotvec(summed).as_matrix(), rec.attitudes[i + 1]) > 0.02


def test_static_intervals_are_exactly_at_rest_and_motions_move():
    rec = recording(2, n_poses=10)
    earth = rec.earth_rate_enu
    for (start, stop), attitude in zip(rec.static, rec.attitudes):
        np.testing.assert_allclose(rec.true_rate[start:stop], np.tile(attitude.T @ earth, (stop - start, 1)),
                                   atol=1e-15)
        np.testing.assert_allclose(rec.true_force[start:stop], np.tile(rec.gravity * attitude[2], (stop - start, 1)),
                                   atol=1e-12)
    for i, motion in enumerate(rec.motions):
        first, last = rec.static[i, 1], rec.static[i + 1, 0] - 1
        assert last - first >= 0
        # The sample data are the motion's analytic values plus Earth rate.
        t = (np.arange(first, last + 1) - first + 1) / rec.rate_hz
        attitude, omega, _ = motion.evaluate(t)
        np.testing.assert_allclose(rec.true_rate[first:last + 1], omega + np.einsum("nji,j->ni", attitude, earth),
                                   atol=1e-12)
        relative = np.linalg.norm(omega, axis=1)
        assert relative[0] > 0 and relative[-1] > 0  # every sample between poses is moving
    peak = np.degrees(np.abs(rec.true_rate).max())
    assert 60 < peak < 400
    assert np.abs(rec.true_force).max() < 3 * rec.gravity


def test_raw_counts_are_integers_and_deterministic():
    a, b = simulate_handheld(7, n_poses=5), simulate_handheld(7, n_poses=5)
    for name in ("accelerometer", "gyroscope"):
        values = a.triads[name]
        assert np.array_equal(values, np.round(values))
        assert 0 < values.min() and values.max() < 65535  # nothing saturated
        np.testing.assert_array_equal(values, b.triads[name])
    assert a.units == {"accelerometer": "count", "gyroscope": "count"}
    assert not np.array_equal(a.accelerometer, simulate_handheld(8, n_poses=5).accelerometer)
    si = simulate_handheld(7, n_poses=5, raw_counts=False)
    assert si.units == {"accelerometer": "m/s^2", "gyroscope": "rad/s"}
    assert not np.array_equal(si.accelerometer, np.round(si.accelerometer))


def test_default_gyro_k_is_full_and_accelerometer_k_lower_triangular():
    truth = handheld_truth(raw_counts=False)
    assert np.all(np.triu(truth["accelerometer"].K, 1) == 0)
    k = truth["gyroscope"].K
    off = k[~np.eye(3, dtype=bool)]
    assert np.all(np.abs(off) >= 1e-3) and np.all(np.abs(off) <= 5.1e-3)


@pytest.mark.parametrize("raw_counts", [True, False])
def test_static_means_match_truth_within_noise(raw_counts):
    rec = recording(3, n_poses=10, raw_counts=raw_counts)
    for name, inputs in (("accelerometer", rec.true_force), ("gyroscope", rec.true_rate)):
        truth = rec.truth[name]
        gain = np.linalg.norm(truth.K, axis=1)  # noise enters before K
        for start, stop in rec.static:
            n = stop - start
            mean = rec.triads[name][start:stop].mean(axis=0)
            expected = truth.K @ inputs[start] + truth.bias
            sigma = gain * (truth.noise.white * np.sqrt(rec.rate_hz / n) + truth.noise.bias_instability)
            tolerance = 5 * sigma + truth.lsb / np.sqrt(n)
            assert np.all(np.abs(mean - expected) < tolerance), (name, start, mean - expected, tolerance)


def test_to_text_writes_the_imu_tk_layout(tmp_path):
    rec = recording(4, n_poses=3)
    acc_path, gyro_path = to_text(rec, tmp_path)
    assert (acc_path.name, gyro_path.name) == ("acc.txt", "gyro.txt")
    first = acc_path.read_text().splitlines()[0].split(" ")
    assert len(first) == 4 and all(v.isdigit() for v in first[1:])
    for path, values in ((acc_path, rec.accelerometer), (gyro_path, rec.gyroscope)):
        data = np.loadtxt(path)
        np.testing.assert_allclose(data[:, 0], rec.t, atol=1e-6)
        np.testing.assert_array_equal(data[:, 1:], values)
    si = simulate_handheld(4, n_poses=3, raw_counts=False)
    data = np.loadtxt(to_text(si, tmp_path / "si")[0])
    np.testing.assert_allclose(data[:, 1:], si.accelerometer, rtol=1e-8)


# --- detector -------------------------------------------------------------------------------------

def assert_matches_truth(intervals, rec, max_edge_s=0.3):
    true = rec.static
    assert len(intervals) == len(true), (len(intervals), len(true))
    assert np.all(intervals[:, 0] >= true[:, 0]) and np.all(intervals[:, 1] <= true[:, 1])  # no moving sample
    covered = (intervals[:, 1] - intervals[:, 0]) / (true[:, 1] - true[:, 0])
    assert covered.min() >= 0.8
    assert np.abs(intervals - true).max() <= max_edge_s * rec.rate_hz


@pytest.mark.parametrize("seed", [1, 2, 3, 4])
def test_detector_finds_every_pose_and_no_moving_sample(seed):
    rec = recording(seed)
    candidates = pose_candidates(rec.accelerometer, rec.rate_hz, SETTINGS, gyro=rec.gyroscope)
    for poses in candidates:
        if poses.multiple in (2, 3, 5, 8, 13, 20):
            assert_matches_truth(poses.intervals, rec)
    # Gravity directions from raw counts without nominal zero or sensitivity (sphere fit).
    error = np.degrees(np.arccos(np.clip(np.sum(candidates[3].up * rec.up, axis=1), -1, 1)))
    assert error.max() < 0.5
    assert require_poses(candidates[3], SETTINGS).ok


def test_detector_with_consumer_noise_and_si_units():
    rec = simulate_handheld(5, raw_counts=False, truth=handheld_truth(False, CONSUMER_NOISE))
    for multiple in (3, 6, 10):
        poses = find_poses(rec.accelerometer, rec.rate_hz, SETTINGS, multiple, gyro=rec.gyroscope)
        assert_matches_truth(poses.intervals, rec)


def test_accelerometer_alone_finds_the_poses():
    # Without the gyro, edges may take in motion the accelerometer cannot see (a turn about the
    # vertical), but each pose is still found once, in order, mostly covered.
    rec = recording(1)
    poses = find_poses(rec.accelerometer, rec.rate_hz, SETTINGS, 5)
    assert len(poses.intervals) == len(rec.static)
    overlap = np.minimum(poses.intervals[:, 1], rec.static[:, 1]) - np.maximum(poses.intervals[:, 0], rec.static[:, 0])
    assert np.all(overlap >= 0.8 * (rec.static[:, 1] - rec.static[:, 0]))


def test_nominal_zero_and_sensitivity_give_the_directions():
    rec = recording(2)
    poses = find_poses(rec.accelerometer, rec.rate_hz, SETTINGS, 5, zero=32768.0, sensitivity=415.0,
                       gyro=rec.gyroscope)
    error = np.degrees(np.arccos(np.clip(np.sum(poses.up * rec.up, axis=1), -1, 1)))
    assert error.max() < 1.0


def test_duplicate_poses_are_marked_not_distinct():
    tilt = Rotation.from_rotvec([0.0, np.radians(4.0), 0.0])
    directions = np.vstack([SPREAD_UP, tilt.apply(SPREAD_UP[2]), SPREAD_UP[5], SPREAD_UP[0]])
    rec = simulate_handheld(6, n_poses=len(directions), directions=directions)
    poses = find_poses(rec.accelerometer, rec.rate_hz, SETTINGS, 5, gyro=rec.gyroscope)
    assert len(poses.intervals) == len(directions)  # duplicates are still poses (rotation endpoints)
    np.testing.assert_array_equal(poses.distinct, [True] * 14 + [False] * 3)
    assert poses.count == 14 and require_poses(poses, SETTINGS).message == "14 distinct poses, well spread"


def test_a_pose_near_only_a_duplicate_is_distinct():
    """Hand-worked, 10° apart counts: b is 8° from a (a duplicate); c is 8° from b but 16° from a,
    so c is distinct, since only distinct poses are compared against."""
    def at(deg):
        return [np.cos(np.radians(deg)), np.sin(np.radians(deg)), 0.0]

    up = np.array([at(0), at(8), at(16), at(0.5), [0.0, 0.0, 1.0]])
    np.testing.assert_array_equal(distinct_poses(up, 10.0), [True, False, True, False, True])
    assert distinct_poses(np.zeros((0, 3)), 10.0).shape == (0,)


def test_true_runs_are_start_stop_pairs_of_each_run():
    mask = np.array([1, 1, 0, 0, 1, 0, 1, 1, 1], dtype=bool)
    np.testing.assert_array_equal(true_runs(mask), [[0, 2], [4, 5], [6, 9]])
    assert true_runs(np.zeros(4, dtype=bool)).shape == (0, 2)
    np.testing.assert_array_equal(true_runs(np.ones(3, dtype=bool)), [[0, 3]])


def test_too_few_poses_are_refused_naming_what_is_missing():
    rec = recording(7, n_poses=6)
    poses = find_poses(rec.accelerometer, rec.rate_hz, SETTINGS, 5, gyro=rec.gyroscope)
    assert len(poses.intervals) == 6
    with pytest.raises(DetectionError, match=r"^only 6 distinct poses \(need at least 9\): add poses with .*z down"):
        require_poses(poses, SETTINGS)
    # Every named direction is one the recording's true poses really lack (none within 60°).
    missing = check_spread(poses.up, 9).missing
    named = {"x up": [1, 0, 0], "y up": [0, 1, 0], "z up": [0, 0, 1],
             "x down": [-1, 0, 0], "y down": [0, -1, 0], "z down": [0, 0, -1]}
    for name, axis in named.items():
        assert (name in missing) == bool(np.all(rec.up @ axis < np.cos(np.radians(60))))


def test_poses_all_near_z_up_are_refused():
    # 15 poses within 40° of z up: z down is missing, and the set is degenerate for the norm method.
    tilt = np.radians(np.r_[0.0, np.full(6, 20.0), np.full(8, 40.0)])
    azimuth = np.radians(np.r_[0.0, np.arange(6) * 60.0, np.arange(8) * 45.0 + 10])
    directions = np.column_stack([np.sin(tilt) * np.cos(azimuth), np.sin(tilt) * np.sin(azimuth), np.cos(tilt)])
    rec = simulate_handheld(8, n_poses=len(directions), directions=directions)
    poses = find_poses(rec.accelerometer, rec.rate_hz, SETTINGS, 5, gyro=rec.gyroscope)
    assert poses.count == 15
    with pytest.raises(DetectionError, match=r"^15 distinct poses, but none with z down: add poses with z down"):
        require_poses(poses, SETTINGS)
    assert check_spread(poses.up, 9).design < SETTINGS.min_design


def test_spread_check_names_missing_axes_and_degenerate_sets():
    a = np.linspace(0, 2 * np.pi, 14, endpoint=False)
    circle = np.column_stack([np.zeros(14), np.cos(a), np.sin(a)])  # turned about x only
    report = check_spread(circle, 9)
    assert not report.ok and report.missing == ["x up", "x down"] and report.design < 1e-9
    axes = np.vstack([np.eye(3), -np.eye(3)])
    corners = check_spread(np.vstack([axes, SPREAD_UP[[1, 3, 5]]]), 9)
    assert corners.ok, corners.message
    flat = check_spread(np.vstack([axes, [[0.8, 0.6, 0], [0.6, -0.8, 0], [-0.6, 0.8, 0]]]), 9)
    assert not flat.ok and "too alike for the norm method" in flat.message  # no pose tilted toward z


def test_short_recording_is_refused():
    rec = recording(1, n_poses=3)
    with pytest.raises(DetectionError, match=r"^recording is 20\.0 s long, but it must start with 30 s of rest"):
        noise_level(rec.accelerometer[:2000], rec.rate_hz, SETTINGS)


def test_initial_rest_must_be_still():
    rec = recording(1, n_poses=3)  # 30 s of rest, then motion
    with pytest.raises(DetectionError, match=r"^the initial 40 s rest is not still"):
        noise_level(rec.accelerometer, rec.rate_hz, DetectorSettings(init_rest_s=40.0))
    drifting = rec.accelerometer.copy()
    drifting[:3000, 0] += np.linspace(0.0, 60.0, 3000)  # settling: about 0.8° of slow tilt
    with pytest.raises(DetectionError, match=r"^the initial 30 s rest drifts"):
        noise_level(drifting, rec.rate_hz, SETTINGS)
    assert noise_level(rec.accelerometer, rec.rate_hz, SETTINGS).base > 0


def test_error_messages_are_one_line():
    rec = recording(1, n_poses=3)
    for call in (lambda: noise_level(rec.accelerometer[:100], rec.rate_hz, SETTINGS),
                 lambda: noise_level(rec.accelerometer, rec.rate_hz, DetectorSettings(init_rest_s=40.0)),
                 lambda: require_poses(find_poses(rec.accelerometer, rec.rate_hz, SETTINGS, 5), SETTINGS)):
        with pytest.raises(DetectionError) as info:
            call()
        assert "\n" not in str(info.value)


def test_without_a_rest_the_noise_comes_from_the_quietest_windows():
    """No initial rest assumed: the still windows anywhere give the white noise, within the
    scatter of the rest's own estimate (a variance over n samples: ±√(2/n) relative)."""
    rec = recording(3)
    acc, gyro = rec.accelerometer, rec.gyroscope
    rest = noise_level(acc, rec.rate_hz, SETTINGS, gyro)
    quiet = noise_level(acc, rec.rate_hz, DetectorSettings(), gyro)
    np.testing.assert_allclose(quiet.variance, rest.variance, rtol=0.12)
    np.testing.assert_allclose(quiet.gyro_variance, rest.gyro_variance, rtol=0.12)
    assert quiet.rest_samples == 0 and "quietest" in quiet.source
    # Without the rest the start is no pose of its own unless it is still for min_static_s.
    short = simulate_handheld(3, initial_rest_s=3.0)
    poses = find_poses(short.accelerometer, short.rate_hz, DetectorSettings(), 5, gyro=short.gyroscope)
    assert len(poses.intervals) == len(short.static)
    assert np.all(poses.intervals[:, 0] >= short.static[:, 0])
    assert np.all(poses.intervals[:, 1] <= short.static[:, 1])


def test_window_variances_are_each_whole_windows_own_variance_and_mean():
    """Against the definition, window by window (the rows past the last whole window unused):
    raw counts about mid-scale, so a variance taken about the wrong mean would show."""
    values = 32768.0 + np.random.default_rng(5).normal(0.0, 3.0, (1013, 3)).cumsum(axis=0)
    variance, mean = window_variances(values, 101)
    assert variance.shape == mean.shape == (10, 3)
    for j in range(10):  # a loop over windows: the oracle
        window = values[101 * j:101 * (j + 1)]
        np.testing.assert_allclose(mean[j], window.mean(axis=0), rtol=1e-15)
        np.testing.assert_allclose(variance[j], np.var(window, axis=0), rtol=1e-12)


def test_a_too_short_recording_without_rest_names_the_option():
    rec = recording(1, n_poses=3)
    with pytest.raises(DetectionError, match=r"give --rest S if it starts with S seconds still"):
        noise_level(rec.accelerometer[:2000], rec.rate_hz, DetectorSettings())


def test_interval_means_are_each_intervals_own_mean():
    """interval_means sums intervals in order where they lie (and falls back to the prefix sums
    for any others): each is the plain mean of its samples, exactly for raw counts, whether the
    intervals touch, end at the last sample, overlap or come out of order."""
    from fieldcal.recording.detect import interval_means

    rng = np.random.default_rng(27)
    counts = rng.integers(30000, 36000, size=(5000, 3)).astype(float)
    cases = (np.array([[10, 400], [900, 1300], [1300, 1301], [2000, 5000]]),  # touching; to the end
             np.array([[0, 5000]]), np.array([[3, 9], [20, 4000]]),
             np.array([[100, 900], [50, 200]]), np.array([[400, 800], [10, 20]]))  # overlapping; out of order
    for number, intervals in enumerate(cases):
        expected = np.array([counts[a:b].mean(axis=0) for a, b in intervals])
        if number < 3:  # in order and apart: summed where they lie, exactly
            np.testing.assert_array_equal(interval_means(counts, intervals), expected)
        np.testing.assert_allclose(interval_means(counts, intervals), expected, rtol=1e-12)
    force = rng.normal(size=(5000, 3)) * 9.8
    np.testing.assert_allclose(interval_means(force, cases[0]), [force[a:b].mean(axis=0) for a, b in cases[0]],
                               rtol=1e-12, atol=1e-12)


def test_the_turns_still_level_reads_the_gyro_means_the_noise_level_made():
    """The quietest windows' gyro means, made once by the noise level with the gyro's variances,
    are each window's mean by hand; the turning mask and smoothed rates from them are those the
    turns' own means give (a noise level measured without them, over an initial rest)."""
    from fieldcal.recording.detect import noise_level
    from fieldcal.recording.turns import turning

    sim = simulate_handheld(6, n_poses=12)
    acc, gyro, settings = sim.accelerometer, sim.gyroscope, DetectorSettings()
    noise = noise_level(acc, sim.rate_hz, settings, gyro)
    window = 2 * max(1, round(settings.window_s * sim.rate_hz) // 2) + 1
    quiet_starts = np.flatnonzero(noise.quiet) * window
    by_hand = np.array([gyro[s:s + window].mean(axis=0) for s in quiet_starts])
    np.testing.assert_allclose(noise.quiet_gyro_means, by_hand, rtol=1e-12, atol=1e-9 * np.abs(by_hand).max())
    mask, smooth = turning(gyro, acc, sim.rate_hz, noise, settings)
    own_mask, own_smooth = turning(gyro, acc, sim.rate_hz, replace(noise, quiet_gyro_means=None), settings)
    np.testing.assert_array_equal(mask, own_mask)
    np.testing.assert_array_equal(smooth, own_smooth)
    assert mask.any() and not mask.all()


def test_every_thresholds_split_shares_one_count_of_turning_samples():
    """split_poses keeps the turn mask's running count in the memo every threshold's call shares:
    made once, it is the count by hand, and a threshold split with it is the one split afresh
    (an interval is touched when it holds a turning sample)."""
    from fieldcal.recording.detect import noise_level, pose_candidates
    from fieldcal.recording.turns import _TURNING_SAMPLES, split_poses, turning

    sim = simulate_handheld(6, n_poses=12)
    acc, gyro, settings = sim.accelerometer, sim.gyroscope, DetectorSettings()
    noise = noise_level(acc, sim.rate_hz, settings, gyro)
    found = pose_candidates(acc, sim.rate_hz, settings, gyro=gyro, noise=noise)
    mask, smooth = turning(gyro, acc, sim.rate_hz, noise, settings)
    memo: dict = {}
    shared = [split_poses(f, acc, mask, smooth, sim.rate_hz, settings, None, memo) for f in found]
    count = memo[_TURNING_SAMPLES]
    assert count[0] == 0 and np.array_equal(np.diff(count), mask.astype(int))
    for f, (poses, turns) in zip(found, shared):
        fresh, fresh_turns = split_poses(f, acc, mask, smooth, sim.rate_hz, settings)
        np.testing.assert_array_equal(poses.intervals, fresh.intervals)
        np.testing.assert_array_equal(turns, fresh_turns)
        held = [not mask[a:b].any() for a, b in f.intervals]  # by hand: no turning sample inside
        assert all(tuple(iv) in map(tuple, poses.intervals) for iv, ok in zip(f.intervals.tolist(), held) if ok)
