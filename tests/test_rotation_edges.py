"""Edges of the rotation solver's searches that the end-to-end tests do not reach (issue 26's
mutation survivors): each against a hand-worked answer, on problems small enough to solve by hand."""
from __future__ import annotations

import numpy as np

from fieldcal.solvers.rotation import _polish, _search


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
