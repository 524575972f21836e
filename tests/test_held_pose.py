"""fieldcal.solvers.held's problem on hand-worked numbers: two windows of a triad held still, the
six pins after them (the mutation run of fieldcal/solvers, docs/benchmarks.md: only the PX4
thermal-log tests reached it, through a whole fit)."""
import math

import numpy as np
import pytest

from fieldcal.solvers.held import HeldPoseProblem

AVERAGES = [[1.0, 2.0, 3.0], [1.5, 2.5, 3.5]]


def held(averages=AVERAGES) -> HeldPoseProblem:
    return HeldPoseProblem(averages, "accel", "specific_force", "m/s^2")


def test_the_data_are_the_averages_then_the_pins_k_one_and_angles_zero():
    problem = held()
    assert problem.data.tolist() == [1.0, 2.0, 3.0, 1.5, 2.5, 3.5, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0]
    assert problem.pin_count == 2
    assert problem.initial().tolist() == [1.25, 2.25, 3.25, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0]


def test_each_residual_is_labelled_by_its_window_and_axis_then_its_pin():
    assert held().residual_labels == (
        "window 1 x", "window 1 y", "window 1 z", "window 2 x", "window 2 y", "window 2 z",
        "pinned k_x", "pinned k_y", "pinned k_z", "pinned delta_yz", "pinned delta_zy", "pinned delta_zx")


def test_residuals_are_each_window_less_the_reading_at_reference_then_each_pin_less_its_parameter():
    problem = held()
    theta = np.array([0.5, 1.0, 1.5, 1.25, 0.5, 1.0, 0.25, -0.5, 0.125])
    expected = [0.5, 1.0, 1.5, 1.0, 1.5, 2.0, -0.25, 0.5, 0.0, -0.25, 0.5, -0.125]
    assert problem.residuals(theta, problem.data).tolist() == expected
    # A stack of parameter vectors with a stack of data gives one row each (the thermal fit's
    # Jacobian columns).
    stacked = problem.residuals(np.vstack([theta, problem.initial()]), np.tile(problem.data, (2, 1)))
    assert stacked.shape == (2, 12)
    assert stacked[0].tolist() == expected
    assert stacked[1].tolist() == [-0.25, -0.25, -0.25, 0.25, 0.25, 0.25] + [0.0] * 6


@pytest.mark.parametrize("averages, scale", [
    (AVERAGES, math.sqrt(1.25**2 + 2.25**2 + 3.25**2)),  # the mean reading's size
    ([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]], 2.0),  # a mean of zero: the spread of the readings
    ([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]], 1e-9),  # nothing at all: a floor, never zero
])
def test_the_reference_scale_is_the_readings_size_or_spread(averages, scale):
    assert held(averages).reference_scale == pytest.approx(scale, rel=1e-15, abs=0)


@pytest.mark.parametrize("averages, shape", [
    ([[1.0, 2.0, 3.0]], "(1, 3)"), ([[1.0, 2.0], [3.0, 4.0]], "(2, 2)"), ([1.0, 2.0, 3.0], "(3,)"),
    ([[1.0, 2.0, 3.0], [1.0, float("nan"), 3.0]], "(2, 3)"),
    ([[1.0, 2.0, 3.0], [1.0, float("inf"), 3.0]], "(2, 3)"),
])
def test_averages_that_are_not_two_or_more_finite_triples_are_refused_in_one_line(averages, shape):
    with pytest.raises(ValueError) as raised:
        held(averages)
    assert str(raised.value) == f"accel: expected (n, 3) finite averages, n >= 2, got shape {shape}"


def test_the_averages_are_a_read_only_float_copy():
    given = np.array([[1, 2, 3], [2, 3, 4]])  # raw integer counts
    problem = held(given)
    given[0, 0] = 99
    assert problem.averages.dtype == np.float64 and problem.averages.tolist() == [[1, 2, 3], [2, 3, 4]]
    with pytest.raises(ValueError):
        problem.averages[0, 0] = 5.0
