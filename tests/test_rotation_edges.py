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


def _kink(at, offset, left, right):
    """r(z) = offset + left·(at − z) below ``at``, offset + right·(z − at) above: its least cost
    is offset², at the kink, where no Gauss-Newton step on either side's slope lowers it; and the
    exact one-sided Jacobian (the right side's at the kink)."""
    def residuals(z):
        return np.array([offset + (left * (at - z[0]) if z[0] < at else right * (z[0] - at))])

    def jacobian(z):
        return np.array([[-left if z[0] < at else right]])

    return residuals, jacobian


def test_broydens_search_at_a_kink_ends_when_a_fresh_jacobian_fails_too():
    # By hand, r = 1 + |z − 1| (slope 2 above 1) from z = 0 (Q = −1, the slope there): the step
    # 2 fails, its half lands on the kink (accepted; Broyden keeps the slope −1); from there
    # every halving of the stale step 1 fails, so the Jacobian is made afresh (2); every halving
    # of its step −1/2 fails too, and the search ends at the kink in its third iteration.
    residuals, jacobian = _kink(1.0, 1.0, 1.0, 2.0)
    z, iterations = _broyden_gauss_newton(residuals, jacobian, 1, np.array([[-1.0]]))
    assert z.tolist() == [1.0] and iterations == 3


def test_a_polish_whose_stale_jacobian_fails_makes_it_afresh_in_natural_units():
    # By hand, r = 0.01 + |θ − 0.01| (slope 0.5 above), natural unit 2, from θ = 0: the fresh
    # Jacobian −1·2 steps to 0.02 (0.02 σ, short: accepted, the Jacobian kept), its next step
    # raises the cost, so the Jacobian is made afresh at 0.02: 0.5·2 = 1 in natural units;
    # its step also raises it, and the polish ends at 0.02 with r = 0.015 and that Jacobian.
    residuals, slope = _kink(0.01, 0.01, 1.0, 0.5)
    made = []

    def jacobian(theta):
        made.append(float(theta[0]))
        return slope(theta)

    theta, r, J = _polish(residuals, jacobian, np.array([0.0]), np.array([2.0]))
    assert made == pytest.approx([0.0, 0.02], abs=1e-15)
    assert theta == pytest.approx([0.02], abs=1e-15) and r == pytest.approx([0.015], abs=1e-15)
    assert J.tolist() == [[1.0]]


def test_broydens_search_trusts_a_jacobian_made_where_a_long_step_landed():
    # By hand, r = 40 + |z − 40| (slope 2 above 40) from z = 0: the step 80 fails, its half (40 σ,
    # longer than _FAR) lands on the kink, the Jacobian made there (2) is fresh, and when every
    # halving of its step −20 fails the search ends in its second iteration, asking for no other.
    residuals, slope = _kink(40.0, 40.0, 1.0, 2.0)
    made = []

    def jacobian(z):
        made.append(float(z[0]))
        return slope(z)

    z, iterations = _broyden_gauss_newton(residuals, jacobian, 1, np.array([[-1.0]]))
    assert z.tolist() == [40.0] and iterations == 2
    assert made == [80.0, 40.0]  # where the long steps would land, before their residuals
