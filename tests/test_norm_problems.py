"""The gyro norm problem's residuals and start on exact averages made from known parameters: every
kind of row at once (paired rate steps, one-way steps, a static dwell on a step's mount and one
alone), where each residual is zero at the truth or a hand-worked offset from it."""
import math

import numpy as np
import pytest

from fieldcal.model import k_from_params
from fieldcal.solvers.problems import RateNormProblem

EARTH = 7.292115e-5  # rad/s
LATITUDE = math.radians(45.0)
VERTICAL, HORIZONTAL = EARTH * math.sin(LATITUDE), EARTH * math.cos(LATITUDE)
THETA = np.array([2e-3, -1e-3, 4e-3, 1.02, 0.97, 1.05, 0.01, -0.02, 0.015])  # bias, k, dyz, dzy, dzx
K, BIAS = k_from_params(THETA), THETA[:3]
OMEGA = 0.5  # rad/s
AXES = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0], [0, 1, 1], [1, 0, 1]]) / np.sqrt(
    [1, 1, 1, 2, 2, 2])[:, None]


def _raw(true_rates):
    return true_rates @ K.T + BIAS


def _perpendicular(d):
    helper = np.array([0.0, 0.0, 1.0]) if abs(d[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    h = np.cross(d, helper)
    return h / np.linalg.norm(h)


def _problem(extra_across=0.0, as_lists=False):
    """6 paired steps, 2 one-way steps (about axes 0 and 4), one dwell on step 2's mount (its
    horizontal Earth rate `extra_across` above the truth's), one dwell alone."""
    plus = _raw((OMEGA + VERTICAL) * AXES)
    minus = _raw((-OMEGA + VERTICAL) * AXES)
    single_rate = np.array([0.3, -0.4])
    single = _raw((single_rate + VERTICAL)[:, None] * AXES[[0, 4]])
    on_mount = VERTICAL * AXES[2] + (HORIZONTAL + extra_across) * _perpendicular(AXES[2])
    alone = EARTH * np.array([0.6, 0.0, 0.8])
    static = _raw(np.array([on_mount, alone]))
    arrays = dict(plus=plus, minus=minus, single=single, static=static)
    if as_lists:
        arrays = {name: value.tolist() for name, value in arrays.items()}
    return RateNormProblem(table_rate=OMEGA, static_step=[2, -1], earth_rate=EARTH, earth_rate_vertical=VERTICAL,
                           single_rate=single_rate.tolist() if as_lists else single_rate, **arrays)


def test_every_residual_is_zero_at_the_true_parameters():
    problem = _problem()
    residuals = problem.residuals(THETA, problem.data)
    assert problem.residual_labels == (
        *(f"rate step {j}: |rate|" for j in range(1, 7)),
        *(f"rate step {j}: bias {axis}" for j in range(1, 7) for axis in "xyz"),
        "one-way step 1: |rate|", "one-way step 2: |rate|",
        "static 1: earth rate along axis", "static 1: earth rate across axis", "static 2: |earth rate|")
    assert residuals.shape == (6 + 18 + 2 + 3,)
    np.testing.assert_allclose(residuals, 0.0, atol=1e-15)


def test_the_across_axis_residual_is_the_dwells_extra_horizontal_rate():
    extra = 3e-6  # rad/s more across the mount's axis than the Earth gives: that residual alone
    problem = _problem(extra_across=extra)
    residuals = problem.residuals(THETA, problem.data)
    expected = np.zeros(29)
    expected[27] = extra
    np.testing.assert_allclose(residuals, expected, atol=1e-15)
    # near a pole the across term is left out: one row fewer, the rest still zero
    polar = RateNormProblem(problem.plus, problem.minus, OMEGA, problem.static, [2, -1], EARTH, EARTH * 0.99,
                            single=problem.single, single_rate=problem.single_rate)
    assert len(polar.residual_labels) == 28 and "static 1: earth rate across axis" not in polar.residual_labels


def test_stacked_parameter_vectors_of_any_batch_shape_give_each_ones_residuals():
    problem = _problem()
    thetas = THETA + np.arange(6 * 9).reshape(2, 3, 9) * 1e-4
    stacked = problem.residuals(thetas, problem.data)
    assert stacked.shape == (2, 3, 29)
    for index in np.ndindex(2, 3):
        np.testing.assert_allclose(stacked[index], problem.residuals(thetas[index], problem.data), rtol=1e-12,
                                   atol=1e-15)


def test_averages_given_as_lists_are_the_same_problem():
    from_lists, from_arrays = _problem(as_lists=True), _problem()
    np.testing.assert_array_equal(from_lists.data, from_arrays.data)
    assert isinstance(from_lists.plus, np.ndarray) and isinstance(from_lists.single, np.ndarray)
    np.testing.assert_allclose(from_lists.residuals(THETA, from_lists.data), 0.0, atol=1e-15)


def test_the_start_is_the_truth_on_exact_paired_steps():
    np.testing.assert_allclose(_problem().initial(), THETA, rtol=1e-9, atol=1e-12)


def test_the_start_from_one_way_steps_alone_is_the_truth_on_exact_averages():
    """At the equator every one-way step's norm is |ω|: the offset ellipsoid through them is exact."""
    directions = np.vstack([AXES, -AXES, [[1, 1, 1], [1, -1, 1], [-1, 1, 1]] / np.sqrt(3)])
    rates = np.where(np.arange(len(directions)) % 2 == 0, OMEGA, -OMEGA)
    single = _raw(rates[:, None] * directions)
    problem = RateNormProblem(np.empty((0, 3)), np.empty((0, 3)), np.empty(0), np.empty((0, 3)), np.empty(0, int),
                              EARTH, 0.0, single=single, single_rate=rates)
    np.testing.assert_allclose(problem.initial(), THETA, rtol=1e-9, atol=1e-12)
    assert problem.reference_scale == pytest.approx(OMEGA)


def test_bad_averages_are_refused_naming_the_triad_and_what_is_wrong():
    from fieldcal.solvers.problems import StaticNormProblem

    with pytest.raises(ValueError, match=r"^accel 2 averages: expected an \(n, 3\) array, got shape \(4, 2\)$"):
        StaticNormProblem(np.zeros((4, 2)), 9.8, name="accel 2")
    with pytest.raises(ValueError, match=r"^accel 2 averages: contains NaN or infinite values$"):
        StaticNormProblem([[0.0, 0.0, np.nan]], 9.8, name="accel 2")
    with pytest.raises(ValueError, match=r"^gyro one-way rate averages: contains NaN or infinite values$"):
        RateNormProblem(np.empty((0, 3)), np.empty((0, 3)), np.empty(0), np.empty((0, 3)), np.empty(0, int),
                        EARTH, 0.0, name="gyro", single=[[np.inf, 0.0, 0.0]], single_rate=[0.5])


def test_a_problems_own_refusals_word_for_word():
    from fieldcal.solvers.problems import StaticNormProblem

    problem = _problem()
    with pytest.raises(ValueError, match=r"^gyroscope: table rates must be positive \(the sign is in \+/-\)$"):
        RateNormProblem(problem.plus, problem.minus, 0.0, problem.static, [2, -1], EARTH, VERTICAL)
    # one pairing for two dwells (every index below the six steps): refused all the same
    with pytest.raises(ValueError, match=r"^gyroscope: static_step must give a rate step index or -1 per dwell$"):
        RateNormProblem(problem.plus, problem.minus, OMEGA, problem.static, [2], EARTH, VERTICAL)
    still = StaticNormProblem([[0.0, 0.0, 9.8], [9.8, 0.0, 0.0]], 9.8)
    assert isinstance(still.means, np.ndarray) and still.means.shape == (2, 3)
    np.testing.assert_array_equal(still.data, [0.0, 0.0, 9.8, 9.8, 0.0, 0.0])
