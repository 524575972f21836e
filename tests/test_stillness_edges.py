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
