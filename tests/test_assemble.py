"""fieldcal.solvers.assemble on a hand-laid run: which windows each triad's problem takes, in
which order, with which labels and inputs (the mutation run of fieldcal/solvers,
docs/benchmarks.md: the tests reached these only through whole solves)."""
import numpy as np
import pytest

from fieldcal.earth import EARTH_RATE, Station
from fieldcal.model import ANGULAR_RATE, SPECIFIC_FORCE
from fieldcal.procedure.windows import MINUS, PLUS, STATIC, Window
from fieldcal.solvers import CalibrationError
from fieldcal.solvers.assemble import build_problem, classic_inputs

STATION = Station(latitude_deg=45.0)
IDS = [11, 12, 13, 14]  # the procedure's position ids, by position index
# A dwell on position 0, a rate step pair and a dwell on position 1, a pair on 2, a dwell on 3.
WINDOWS = [Window(STATIC, 0, 0.0, 10.0), Window(PLUS, 1, 20.0, 5.0, 0.5), Window(MINUS, 1, 30.0, 5.0, 0.5),
           Window(STATIC, 1, 40.0, 10.0), Window(PLUS, 2, 60.0, 5.0, 1.0), Window(MINUS, 2, 70.0, 5.0, 1.0),
           Window(STATIC, 3, 80.0, 10.0)]
MEANS = np.arange(21.0).reshape(7, 3) + 0.5
UP = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.6, 0.0, 0.8]])


def test_a_specific_force_triad_takes_the_dwells_alone_labelled_by_position():
    problem, order = build_problem("accel", SPECIFIC_FORCE, "g", WINDOWS, MEANS, STATION, IDS)
    assert order == [0, 3, 6]
    assert problem.means.tolist() == MEANS[[0, 3, 6]].tolist()
    assert problem.gravity == STATION.gravity
    assert (problem.name, problem.output_unit) == ("accel", "g")
    assert problem.residual_labels == ("position 11", "position 12", "position 14")


def test_a_gyro_takes_its_steps_then_the_dwells_each_paired_with_the_step_on_its_mount():
    problem, order = build_problem("gyro", ANGULAR_RATE, "deg/s", WINDOWS, MEANS, STATION, IDS)
    assert order == [1, 4, 2, 5, 0, 3, 6]  # +steps, −steps, dwells: the data's order
    assert problem.plus.tolist() == MEANS[[1, 4]].tolist() and problem.minus.tolist() == MEANS[[2, 5]].tolist()
    assert problem.static.tolist() == MEANS[[0, 3, 6]].tolist()
    assert problem.table_rate.tolist() == [0.5, 1.0]
    assert problem.static_step.tolist() == [-1, 0, -1]  # only position 1's dwell shares a mount
    assert problem.earth_rate == EARTH_RATE and problem.earth_rate_vertical == STATION.earth_rate_vertical
    assert (problem.name, problem.output_unit) == ("gyro", "deg/s")
    assert problem.step_labels == ("position 12 rate", "position 13 rate")
    assert problem.static_labels == ("position 11 static", "position 12 static", "position 14 static")
    np.testing.assert_array_equal(problem.data, MEANS[order].ravel())


def test_a_triad_of_unknown_kind_is_refused():
    with pytest.raises(ValueError) as raised:
        build_problem("mag", "magnetic_field", "uT", WINDOWS, MEANS, STATION, IDS)
    assert str(raised.value) == "mag: unknown triad kind 'magnetic_field'"


def test_a_gyro_without_rate_steps_is_refused_saying_why():
    dwells = [w for w in WINDOWS if w.kind == STATIC]
    with pytest.raises(CalibrationError) as raised:
        build_problem("gyro", ANGULAR_RATE, "rad/s", dwells, MEANS[:3], STATION, IDS)
    assert str(raised.value) == ("gyro: the procedure has no rate steps, and a gyro's scale factors need them "
                                 "(Earth rate alone is too weak)")


def test_a_plus_step_whose_minus_is_on_another_mount_is_refused():
    crossed = list(WINDOWS)
    crossed[5] = Window(MINUS, 3, 70.0, 5.0, 1.0)
    with pytest.raises(ValueError) as raised:
        build_problem("gyro", ANGULAR_RATE, "rad/s", crossed, MEANS, STATION, IDS)
    assert str(raised.value) == "gyro: every +rate step needs a -rate step on the same mount"


def test_classic_inputs_are_gravity_along_up_for_the_dwells():
    used, inputs = classic_inputs(SPECIFIC_FORCE, WINDOWS, UP, STATION)
    assert used == [0, 3, 6]
    np.testing.assert_array_equal(inputs, STATION.gravity * UP[[0, 1, 3]])


def test_classic_inputs_of_a_gyro_are_the_signed_table_rate_plus_the_vertical_earth_rate_along_up():
    used, inputs = classic_inputs(ANGULAR_RATE, WINDOWS, UP, STATION)
    assert used == [1, 2, 4, 5]
    vertical = STATION.earth_rate_vertical
    expected = np.array([0.5 + vertical, -0.5 + vertical, 1.0 + vertical, -1.0 + vertical])[:, None] * UP[[1, 1, 2, 2]]
    np.testing.assert_array_equal(inputs, expected)
