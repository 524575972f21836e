"""Edges of the rotation solver's searches that the end-to-end tests do not reach (issue 26's
mutation survivors): each against a hand-worked answer, on problems small enough to solve by hand."""
from __future__ import annotations

import numpy as np
import pytest

from fieldcal.solvers.rotation import Motions, _broyden_gauss_newton, _polish, _search, scan_scale


def test_powells_search_ends_at_the_least_squares_solution_not_at_scipys_default_tolerance():
    # A linear problem: its least-squares solution is lstsq's, and σ is (AᵀA)^-½'s diagonal.
    # Powell's default ftol (1e-4) stops 8e-7 σ off it; the search's own 1e-13 reaches 2e-8 σ.
    rng = np.random.default_rng(3)
    A, b = rng.normal(size=(12, 4)), rng.normal(size=12)
    solution = np.linalg.lstsq(A, b, rcond=None)[0]
    sigma = np.sqrt(np.diag(np.linalg.inv(A.T @ A)))
    theta, converged, _, _ = _search(lambda theta: A @ theta - b, None, np.zeros(4), np.eye(4), None, "powell")
    assert converged
    assert np.max(np.abs(theta - solution) / sigma) < 1e-7


def test_the_polish_stops_after_twenty_steps_that_never_shrink_below_its_tolerance():
    # r(θ) = θ with a Jacobian twice the truth: each Gauss-Newton step halves θ exactly (powers of
    # two), so from 2³⁰ twenty steps leave 2¹⁰, far above the step tolerance, and the cap ends it.
    made = []

    def jacobian(theta):
        made.append(theta.copy())
        return np.array([[2.0]])

    theta, residuals, J = _polish(lambda theta: theta.copy(), jacobian, np.array([2.0 ** 30]), np.ones(1))
    assert theta.tolist() == [2.0 ** 10] and residuals.tolist() == [2.0 ** 10]
    # every step is longer than 0.1 σ, so each one's Jacobian is made afresh at its end point
    assert [m.tolist() for m in made] == [[2.0 ** k] for k in range(30, 9, -1)]


def test_broydens_search_solves_a_linear_problem_in_one_step_and_stops_at_the_next():
    # r(z) = Qz − b with Q's columns orthonormal: the least-squares solution is Qᵀb, Gauss-Newton
    # reaches it in one step (4 σ, no fresh Jacobian), and Broyden's update of an exact Jacobian
    # of a linear function changes nothing, so the second step is zero and the search ends there.
    rng = np.random.default_rng(5)
    Q = np.linalg.qr(rng.normal(size=(10, 3)))[0]
    b = 3 * rng.normal(size=10)
    z, iterations = _broyden_gauss_newton(lambda z: Q @ z - b, lambda z: Q, 3, Q)
    np.testing.assert_allclose(z, Q.T @ b, rtol=0, atol=1e-12)
    assert iterations == 2


def test_the_scan_integrates_with_the_bias_it_is_given_even_when_the_motions_hold_other_steps():
    # A 90° turn about z in raw counts of 1/1000 rad/s (so the scale is 1000) with a bias on z
    # that, left in, reads as 1.585 times the turn: the grid's 10^3.2. Motions whose steps were
    # made with offset 0 must not be used for the scan at the bias: it makes its own.
    t = np.arange(200) * 0.01
    spans = np.array([[40, 160]])  # 1.2 s, the turn's 1 s inside
    bias = np.array([0.0, 0.0, 0.585 * 1000.0 * (np.pi / 2) / 1.2])
    raw = np.zeros((200, 3)) + bias
    raw[50:150, 2] += 1000.0 * (np.pi / 2)
    start, end = np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, -1.0, 0.0]])
    scales = np.geomspace(10.0, 1e5, 41)  # 1000 and 10^3.2 among them
    assert scan_scale(t, raw, spans, start, end, np.zeros(3), scales) == pytest.approx(10 ** 3.2)
    motions = Motions.of(t, raw, spans, start, end)
    at_zero = motions.steps(np.zeros(3))
    assert scan_scale(t, raw, spans, start, end, bias, scales, motions=motions) == pytest.approx(1000.0)
    assert motions.steps(bias) is at_zero  # (the Motions keep their own steps)
    at_bias = Motions.of(t, raw, spans, start, end)
    at_bias.steps(bias)
    assert scan_scale(t, raw, spans, start, end, bias, scales, motions=at_bias) == pytest.approx(1000.0)
