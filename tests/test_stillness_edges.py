"""The stillness detector's edges on hand-worked signals: a window whose ratio is exactly a
threshold, settings given in odd forms. Small integers in units of σ keep every window's standard
deviation exact, so ``ratio == factor`` really happens."""
from __future__ import annotations

from itertools import pairwise

import numpy as np
import pytest

from drivers.chunk import SampleChunk
from fieldcal.procedure.stillness import StillnessDetector, StillnessSettings

RATE_HZ = 10.0
WINDOW_S = 0.3  # three samples at 10 Hz
CYCLE = [-1.0, 0.0, 1.0]  # any three consecutive samples of it: std (ddof 1) exactly 1


def chunks(values, sizes):
    """Accelerometer samples (the same on every axis, σ = 1) in chunks of the given sizes."""
    x = np.asarray(values, dtype=float)
    t = np.arange(len(x)) / RATE_HZ
    edges = np.cumsum([0, *sizes])
    assert edges[-1] == len(x)
    return [SampleChunk(t=t[a:b], triads={"accelerometer": np.repeat(x[a:b, None], 3, axis=1)})
            for a, b in pairwise(edges)]


def run(values, sizes, enter, leave):
    settings = StillnessSettings(specific_force_sigma=1.0, rate_sigma=1.0, window_s=WINDOW_S,
                                 enter_factor=enter, leave_factor=leave)
    detector = StillnessDetector(settings, RATE_HZ, angular_rate=None)
    assert detector.window_samples == 3
    return np.concatenate([detector.feed(c) for c in chunks(values, sizes)])


# One chunk (the general path) and a first window then the rest (the steady path).
SPLITS = [lambda n: [n], lambda n: [4, n - 4]]


@pytest.mark.parametrize("split", SPLITS, ids=["one chunk", "steady path"])
def test_a_ratio_equal_to_the_enter_factor_does_not_make_the_unit_still(split):
    values = CYCLE * 4  # every complete window: ratio exactly 1
    out = run(values, split(len(values)), enter=1.0, leave=2.0)
    assert not out.any()  # not below enter, not above leave: stays as it began, moving


@pytest.mark.parametrize("split", SPLITS, ids=["one chunk", "steady path"])
def test_a_ratio_equal_to_the_leave_factor_does_not_make_the_unit_moving(split):
    # Still on zeros (ratio 0); then windows [0, 0, -1] and [0, -1, 0] (ratio 1/√3) and from
    # then on one of each of the cycle (ratio exactly 1 = leave): between the factors, kept.
    values = [0.0] * 5 + CYCLE * 3
    out = run(values, split(len(values)), enter=0.5, leave=1.0)
    np.testing.assert_array_equal(out, [False, False] + [True] * (len(values) - 2))


def test_a_ratio_just_above_the_leave_factor_makes_the_unit_moving():
    # The same signal, leave a hair below 1: the first full cycle window turns it moving (a check
    # that the test above could fail).
    values = [0.0] * 5 + CYCLE * 3
    out = run(values, [len(values)], enter=0.5, leave=0.999)
    np.testing.assert_array_equal(out, [False, False, True, True, True, True, True] + [False] * 7)


@pytest.mark.parametrize("value", [None, "three", [1.0, None, 1.0], [1.0, 2.0]])
def test_a_sigma_that_is_not_a_number_is_refused_naming_the_setting(value):
    with pytest.raises(ValueError, match="^specific_force_sigma: expected a positive number or three"):
        StillnessSettings(specific_force_sigma=value, rate_sigma=1.0)


def test_a_sigma_per_axis_keeps_each_axis_its_own():
    settings = StillnessSettings(specific_force_sigma=(1.0, 2.0, 3.0), rate_sigma=[0.5, 0.25, 0.125])
    assert settings.specific_force_sigma == (1.0, 2.0, 3.0)
    assert settings.rate_sigma == (0.5, 0.25, 0.125)
    assert StillnessSettings(specific_force_sigma=2, rate_sigma=1).specific_force_sigma == (2.0, 2.0, 2.0)


def test_from_noise_carries_the_white_noise_through_each_row_of_a_full_scale_factor():
    # White 0.1 per √Hz at 100 Hz: 1.0 per sample; output axis i sees it times |row i of K|.
    k = [[2.0, 0.0, 0.0], [0.0, 3.0, 4.0], [0.0, 0.0, -1.0]]
    s = StillnessSettings.from_noise(0.1, 0.01, 100.0, k_sf=k, k_rate=[-2.0, 1.0, 0.5], lsb_rate=0.6)
    np.testing.assert_allclose(s.specific_force_sigma, (2.0, 5.0, 1.0), rtol=1e-12)
    # 0.01·√100 = 0.1 times |k|, widened by 0.6²/12 = 0.03.
    np.testing.assert_allclose(s.rate_sigma, np.sqrt(np.array([0.2, 0.1, 0.05]) ** 2 + 0.03), rtol=1e-12)
    with pytest.raises(ValueError, match="^rate_hz: expected a positive rate, got 0"):
        StillnessSettings.from_noise(0.1, 0.01, 0.0)


def test_a_detector_refuses_a_window_of_fewer_than_two_samples_or_no_rate():
    settings = StillnessSettings(specific_force_sigma=1.0, rate_sigma=1.0, window_s=0.3)
    with pytest.raises(ValueError, match=r"^window_s=0.3 s at 4 Hz is 1 sample\(s\); need at least 2$"):
        StillnessDetector(settings, 4.0)
    assert StillnessDetector(settings, 5.0).window_samples == 2  # round(1.5): 2
    with pytest.raises(ValueError, match="^rate_hz: expected a positive rate, got -1"):
        StillnessDetector(settings, -1.0)


def test_last_ratios_are_each_triads_window_std_over_sigma_and_reset_forgets():
    settings = StillnessSettings(specific_force_sigma=(1.0, 1.0, 2.0), rate_sigma=0.5, window_s=WINDOW_S)
    detector = StillnessDetector(settings, RATE_HZ)
    t = np.arange(4) / RATE_HZ
    accel = np.array([[0.0, 5.0, 0.0], [0.0, 5.0, 0.0], [0.0, 5.0, 0.0], [0.0, 5.0, 2.0]])
    gyro = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    first = SampleChunk(t=t[:2], triads={"accelerometer": accel[:2], "gyroscope": gyro[:2]})
    detector.feed(first)
    assert all(np.isnan(v).all() for v in detector.last_ratios.values())  # no full window yet
    detector.feed(SampleChunk(t=t[2:], triads={"accelerometer": accel[2:], "gyroscope": gyro[2:]}))
    ratios = detector.last_ratios
    assert set(ratios) == {"accelerometer", "gyroscope"}
    # Last window, rows 1-3: accel z (0, 0, 2)/2 has std 1/√3; gyro x (0, -1, 0)/0.5 has std 2/√3.
    np.testing.assert_allclose(ratios["accelerometer"], [0.0, 0.0, 1 / np.sqrt(3)], atol=1e-12)
    np.testing.assert_allclose(ratios["gyroscope"], [2 / np.sqrt(3), 0.0, 0.0], atol=1e-12)
    assert detector.still  # every ratio below 2
    detector.reset()
    assert not detector.still and np.isnan(detector.last_ratios["gyroscope"]).all()
    assert not detector.feed(first).any()  # as new: the window starts again


# --------------------------------------------------------------------------------- orientation

THREE_ALIKE = """name: alike
dwell_s: 5
positions:
  - {id: 4, axes: {x: east, y: north, z: up}}
  - {id: 7, axes: {x: north, y: west, z: up}}
  - {id: 9, axes: {x: west, y: south, z: up}}
  - {id: 11, axes: {x: up, y: north, z: west}}
"""


def test_describe_up_names_the_axes_above_ten_degrees_highest_first():
    from fieldcal.procedure.stillness import describe_up

    assert describe_up([0.0, 0.0, -3.0]) == "z-downward"
    assert describe_up([-1.0, 0.0, 0.2]) == "x-downward"  # 78.7° below the horizontal
    assert describe_up([1.0, 0.0, 1.0]) == "x-upward 45°, z-upward 45°"  # a tie keeps axis order
    assert describe_up([0.1, -1.0, 0.5]) == "y-downward 63°, z-upward 26°"  # asin(0.5/√1.26); x at 5°: left out


def test_gravity_direction_takes_off_the_zero_and_divides_by_the_sensitivity():
    from fieldcal.procedure.stillness import gravity_direction

    np.testing.assert_allclose(gravity_direction([12.0, 10.0, 13.0], zero=10.0, sensitivity=(2.0, 1.0, 3.0)),
                               [1 / np.sqrt(2), 0.0, 1 / np.sqrt(2)], atol=1e-15)
    # Several means at once: each row its own unit vector.
    np.testing.assert_allclose(gravity_direction([[0.0, 3.0, 4.0], [0.0, 0.0, -2.0]]),
                               [[0.0, 0.6, 0.8], [0.0, 0.0, -1.0]], atol=1e-15)
    for bad in ([10.0, 10.0, 10.0], [np.nan, 0.0, 1.0]):
        with pytest.raises(ValueError, match="^specific force has no direction"):
            gravity_direction(bad, zero=(10.0, 10.0, 10.0) if bad[0] == 10.0 else None)


def test_three_positions_sharing_up_are_listed_and_an_upside_down_unit_tilts_about_the_first_level_axis():
    from fieldcal.procedure.positions import parse_procedure
    from fieldcal.procedure.stillness import check_orientation

    positions = parse_procedure(THREE_ALIKE, "alike.yaml").positions
    x_up = positions[3]
    check = check_orientation([0.0, 0.0, 1.0], x_up, positions)
    assert check.message.startswith("position 11 expects x-upward, y-north, z-west, but the unit looks like "
                                    "position 4, 7 or 9 (z-upward), 90° away; ")
    assert check.message.endswith("tilt it 90° about the body -y axis (right-hand rule) until x points up")
    assert check.tilt_axis == (0.0, -1.0, 0.0)
    ok = check_orientation([0.0, 0.0, 1.0], positions[0], positions)
    assert ok.ok and ok.angle_deg == 0.0 and ok.tilt_axis == (0.0, 0.0, 0.0)
    assert ok.message == "position 4 (z-upward, x-east, y-north): orientation ok, 0° from the expected up direction"
    # Upside down: every level axis would do; the one nearest level, x, in procedure-file order.
    flipped = check_orientation([0.0, 0.0, -1.0], positions[0], positions)
    assert flipped.tilt_axis == (1.0, 0.0, 0.0) and flipped.angle_deg == 180.0
    assert "tilt it 180° about the body x axis" in flipped.message


@pytest.mark.parametrize("kw, refused", [
    ({"window_s": -1.0}, "window_s: expected a positive duration"),
    ({"window_s": float("inf")}, "window_s: expected a positive duration"),
    ({"enter_factor": 0.0}, "enter_factor: expected a positive number"),
    ({"enter_factor": float("inf"), "leave_factor": float("inf")}, "enter_factor: expected a positive number"),
    ({"leave_factor": float("inf")}, r"leave_factor: expected a number >= enter_factor \(2\)"),
    ({"max_gap_s": 0.0}, "max_gap_s: expected a positive duration"),
    ({"rate_sigma": 0.0}, "rate_sigma: expected a positive number or three"),
])
def test_each_setting_out_of_range_is_refused_by_name(kw, refused):
    with pytest.raises(ValueError, match="^" + refused):
        StillnessSettings(**{"specific_force_sigma": 1.0, "rate_sigma": 1.0, **kw})


def test_the_edges_of_the_settings_that_are_allowed():
    s = StillnessSettings(specific_force_sigma=1.0, rate_sigma=1.0, enter_factor=2.5, leave_factor=2.5)
    assert (s.enter_factor, s.leave_factor) == (2.5, 2.5)  # no hysteresis: allowed
    # from_noise: no quantisation unless given; other keywords reach the settings; any rate > 0.
    plain = StillnessSettings.from_noise(0.1, 0.01, 0.25, window_s=8.0)
    assert plain.rate_sigma == (0.005, 0.005, 0.005) and plain.specific_force_sigma == (0.05, 0.05, 0.05)
    assert plain.window_s == 8.0
    slow = StillnessDetector(plain, 0.25)  # 8 s at 0.25 Hz: two samples
    assert (slow.rate_hz, slow.window_samples) == (0.25, 2)
    with pytest.raises(ValueError, match="^rate_hz: expected a positive rate, got 0"):
        StillnessDetector(plain, 0.0)


def test_a_window_decided_on_the_first_sample_of_a_steady_chunk_holds_for_the_chunk():
    # Moving at the end of the first chunk (windows holding the 9); the second chunk's first
    # window is all zeros (ratio 0: still), then two windows of ratio 1/√3, between the factors.
    out = run([0.0, 0.0, 9.0, 0.0, 0.0, 0.0, 1.0, 0.0], [5, 3], enter=0.5, leave=1.5)
    np.testing.assert_array_equal(out, [False] * 5 + [True] * 3)


def test_last_ratios_are_unknown_again_right_after_a_gap():
    settings = StillnessSettings(specific_force_sigma=1.0, rate_sigma=1.0, window_s=WINDOW_S)
    detector = StillnessDetector(settings, RATE_HZ, angular_rate=None)
    [first] = chunks([0.0, 1.0, 0.0, 1.0], [4])
    detector.feed(first)
    assert np.isfinite(detector.last_ratios["accelerometer"]).all()
    after_gap = SampleChunk(t=np.array([5.0, 5.1]), triads={"accelerometer": np.zeros((2, 3))})
    assert not detector.feed(after_gap).any()
    assert np.isnan(detector.last_ratios["accelerometer"]).all()  # two samples since the gap: no window


def test_a_gap_after_a_steady_chunk_restarts_the_window():
    settings = StillnessSettings(specific_force_sigma=1.0, rate_sigma=1.0, window_s=WINDOW_S)
    detector = StillnessDetector(settings, RATE_HZ, angular_rate=None)
    first, steady = chunks([0.0] * 6, [4, 2])
    assert detector.feed(first).tolist() == [False, False, True, True]
    assert detector.feed(steady).all()  # a full window before it, no gap: the steady path
    after_gap = SampleChunk(t=np.array([3.0, 3.1, 3.2]), triads={"accelerometer": np.zeros((3, 3))})
    assert detector.feed(after_gap).tolist() == [False, False, True]  # 2.5 s unseen: a new window


def test_angle_between_two_vectors_is_a_plain_float():
    from fieldcal.procedure.stillness import angle_between

    angle = angle_between([1, 0, 0], [1, 1, 0])
    assert type(angle) is float and angle == pytest.approx(45.0, abs=1e-12)


def test_a_tilt_about_no_named_axis_is_given_by_its_components():
    from fieldcal.procedure.positions import parse_procedure
    from fieldcal.procedure.stillness import check_orientation, closest_positions

    positions = parse_procedure(THREE_ALIKE, "alike.yaml").positions
    # Up measured along (0.1, 0.5, 1): 27° from z (atan(√0.26)); the tilt axis z × m, normalised,
    # is (-0.5, 0.1, 0)/√0.26, within 10° of no axis or diagonal.
    check = check_orientation([0.1, 0.5, 1.0], positions[0], positions)
    np.testing.assert_allclose(check.tilt_axis, np.array([-0.5, 0.1, 0.0]) / np.sqrt(0.26), atol=1e-12)
    assert check.message == ("position 4 expects z-upward, x-east, y-north, but the unit is z-upward 63°, "
                             "y-upward 26°, like no position, 27° away; tilt it 27° about the body "
                             "(-0.98, 0.20, 0.00) axis (right-hand rule) until z points up")
    # x up turned over: the nearest level body axis to x's up is y.
    assert check_orientation([-1.0, 0.0, 0.0], positions[3], positions).tilt_axis == (0.0, 1.0, 0.0)
    # The default tolerance is 15°: 15.5° from z up is no position.
    tilted = [np.sin(np.radians(15.5)), 0.0, np.cos(np.radians(15.5))]
    assert closest_positions(tilted, positions) == []
    assert [p.id for p, _ in closest_positions(tilted, positions, tolerance_deg=16.0)] == [4, 7, 9]


def test_a_corner_turned_over_and_a_passing_tilt_still_get_their_tilt_axis():
    from fieldcal.procedure.positions import parse_procedure
    from fieldcal.procedure.stillness import check_orientation

    corner = parse_procedure("dwell_s: 5\npositions:\n  - {id: 1, up: x+y+z, north: x}\n", "c.yaml").positions
    flipped = check_orientation([-1.0, -1.0, -1.0], corner[0], corner, tolerance_deg=5.0)
    assert flipped.ok is False and flipped.looks_like == ()
    # x, the first axis nearest level, less its part along up: (1, 0, 0) - (1, 1, 1)/3.
    np.testing.assert_allclose(flipped.tilt_axis, np.array([2.0, -1.0, -1.0]) / np.sqrt(6.0), atol=1e-12)
    # 10° off, within the tolerance: ok, and the way to level it still given: up measured towards
    # +x, so turn about e × m = z × x = +y.
    near = check_orientation([np.sin(np.radians(10.0)), 0.0, np.cos(np.radians(10.0))],
                             parse_procedure(THREE_ALIKE, "alike.yaml").positions[0],
                             parse_procedure(THREE_ALIKE, "alike.yaml").positions, tolerance_deg=12.0)
    assert near.ok is True and [p.id for p, _ in near.looks_like] == [4, 7, 9]
    np.testing.assert_allclose(near.tilt_axis, [0.0, 1.0, 0.0], atol=1e-12)
    strict = check_orientation([np.sin(np.radians(10.0)), 0.0, np.cos(np.radians(10.0))],
                               parse_procedure(THREE_ALIKE, "alike.yaml").positions[0],
                               parse_procedure(THREE_ALIKE, "alike.yaml").positions, tolerance_deg=8.0)
    assert strict.ok is False and strict.looks_like == ()
