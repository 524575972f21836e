"""The rotation solve's search on the coarse integration (``_Steps.coarse``): its Jacobian is
the derivative of its own integration, the search takes only those, and the optimum the exact
polish then lands on is the one an exact search finds."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import fieldcal.solvers.rotation as rotation
from fieldcal.model import k_from_terms
from fieldcal.solvers.rotation import _Steps
from test_rotation_solver import GRADES, hand_recording, observe, solve


def test_the_coarse_steps_are_the_scans_coarse_integration_and_their_jacobian_its_derivative():
    """A coarse copy integrates as ``quaternions(group=8)`` does (the scale scan's coarse
    integration), and its exact Jacobian is the central-difference one of that integration:
    every element of K and of the bias, on two-axis turns in raw counts."""
    rec = hand_recording(3)
    obs = observe(rec, np.random.default_rng(7), **GRADES["counts"])
    steps = _Steps(obs["raw"], rec.t, rec.spans, offset=obs["b0"])
    coarse = steps.coarse(8)
    assert steps.coarse(8) is coarse and coarse.block == 8
    K = k_from_terms(obs["k"], obs["M"])
    delta_b = obs["b"] - obs["b0"]
    np.testing.assert_allclose(coarse.quaternions(np.linalg.inv(K), delta_b),
                               steps.quaternions(np.linalg.inv(K), delta_b, group=8), rtol=0, atol=1e-14)

    def turned(dK, d_bias):
        return Rotation.from_quat(coarse.quaternions(np.linalg.inv(K + dK), delta_b + d_bias))

    dK = np.zeros((12, 3, 3))
    dK[:9].reshape(9, 9)[:, :] = np.eye(9) * obs["nominal"]
    d_bias = np.zeros((12, 3))
    d_bias[9:] = np.eye(3)
    q, D = coarse.jacobian(np.linalg.inv(K), delta_b, dK, d_bias)
    np.testing.assert_allclose(q, coarse.quaternions(np.linalg.inv(K), delta_b), rtol=0, atol=1e-14)
    h = 1e-5
    here = turned(0 * dK[0], 0 * d_bias[0]).inv()
    for p in range(12):
        ahead = (here * turned(h * dK[p], h * d_bias[p])).as_rotvec()
        behind = (here * turned(-h * dK[p], -h * d_bias[p])).as_rotvec()
        np.testing.assert_allclose(D[:, :, p], (ahead - behind) / (2 * h), rtol=0, atol=1e-7 * np.abs(D[:, :, p]).max())
    # Coarse, not exact: it leaves out the coning inside each group of eight steps.
    exact = steps.jacobian(np.linalg.inv(K), delta_b, dK, d_bias)[1]
    assert 1e-6 < np.abs(D - exact).max() / np.abs(exact).max() < 0.1


def test_steps_taken_as_one_keep_the_coning_between_them():
    """A coarse copy's step is its group's steps summed plus ½·Σ_{i<j} φ_i × φ_j (the product of
    their exponentials to second order): on a rate whose axis turns (2 rad/s about an axis
    turning at 3 rad/s, and 1 rad/s along it), four steps as one stay within 1e-6 rad of the
    step-by-step integration over 4 s, and each halving of the group divides the error by more
    than 8 (the plain sum's error, some 6e-3 rad, fell by 4)."""
    t = np.arange(401) * 0.01
    omega = np.column_stack([2 * np.sin(3 * t), 2 * np.cos(3 * t), np.ones_like(t)])
    steps = _Steps(omega, t, np.array([[0, 400]]))
    exact = Rotation.from_quat(steps.quaternions(np.eye(3), np.zeros(3)))
    assert exact.magnitude()[0] > 0.5  # a turn of its own, not a wobble about the identity
    error = {group: (exact.inv() * Rotation.from_quat(steps.coarse(group).quaternions(np.eye(3), np.zeros(3))))
             .magnitude()[0] for group in (2, 4, 8)}
    assert error[4] < 1e-6
    assert error[8] > 8 * error[4] > 64 * error[2]
    # With a bias change δb (the bias cross terms): the same as integrating ω − δb step by step.
    delta_b = np.array([0.3, -0.2, 0.5])
    shifted = Rotation.from_quat(_Steps(omega - delta_b, t, np.array([[0, 400]])).quaternions(np.eye(3), np.zeros(3)))
    coarse = Rotation.from_quat(steps.coarse(4).quaternions(np.eye(3), delta_b))
    assert (shifted.inv() * coarse).magnitude()[0] < 1e-6


def test_a_coarse_steps_terms_are_the_double_sum_over_its_steps_in_time_order():
    """Made by pairing neighbours (log2(group) passes), a coarse step's terms are its group's
    terms summed plus ½·Σ_{i<j} of V_i × V_j (coning) and of h_i·V_j − h_j·V_i (bias cross),
    i before j in time: here summed pair by pair in a loop over one block's 64 steps, read at
    their bit-reversed places."""
    rng = np.random.default_rng(4)
    t = np.cumsum(np.r_[0.0, 0.01 + 0.002 * rng.random(80)])
    omega = rng.normal(size=(81, 3))
    steps = _Steps(omega, t, np.array([[5, 69]]))  # 64 steps: one whole block
    fine = steps.terms[:, rotation._bit_reversed(rotation._BLOCK)]  # (10, 64) in time order
    for group in (2, 4, 8, 16):
        coarse = steps.coarse(group).terms  # (10, 64 / group) at bit-reversed places
        in_time = coarse[:, rotation._bit_reversed(rotation._BLOCK // group)]
        for g in range(rotation._BLOCK // group):
            members = fine[:, g * group:(g + 1) * group]
            expected = members.sum(axis=1)
            for i in range(group):
                for j in range(i + 1, group):
                    V_i, V_j, h_i, h_j = members[0:3, i], members[0:3, j], members[9, i], members[9, j]
                    expected[3:6] += 0.5 * np.cross(V_i, V_j)
                    expected[6:9] += 0.5 * (h_i * V_j - h_j * V_i)
            np.testing.assert_allclose(in_time[:, g], expected, rtol=1e-12, atol=1e-15)


def test_the_pairs_are_made_as_they_are_read_and_not_kept():
    """The polish's pairs of steps (asked once a solve) are made span group by span group as
    they are read, the last one alone held, and nothing of them kept with the steps; they are
    the whole level's terms, and integrate and differentiate as its own copy does."""
    rng = np.random.default_rng(9)
    lengths = rng.integers(100, 400, 300)
    starts = np.cumsum(lengths + 5) - lengths
    n = int(starts[-1] + lengths[-1] + 3)
    t = np.cumsum(np.r_[0.0, 0.01 * np.ones(n - 1)])
    steps = _Steps(rng.normal(size=(n, 3)), t, np.column_stack([starts, starts + lengths]))
    assert len(steps.span_groups) > 2
    pairs = steps.coarse(2)
    assert steps.coarse(2) is not pairs and not any(key in steps._groups for key in (2, ("coarse", 2)))
    assert sum(1 for _ in pairs.parts) == len(steps.parts)
    whole = steps._grouped(2).reshape(10, rotation._BLOCK // 2, -1)
    read = np.concatenate([pairs.parts[i] for i in range(len(steps.parts))], axis=2)
    np.testing.assert_array_equal(read, whole)
    assert pairs.parts._last[0] == len(steps.parts) - 1  # the last one read, alone
    A, delta_b = np.diag([1.1, 0.9, 1.0]), np.array([0.01, 0.0, -0.02])
    np.testing.assert_array_equal(pairs.quaternions(A, delta_b), steps.quaternions(A, delta_b, group=2))


def _count_steps(monkeypatch) -> tuple[list[int], list[int]]:
    """The block (samples taken as one step) of every Jacobian the solve makes and of every
    integration it runs, in order, as two lists filled while it runs."""
    made, integrated = [], []
    jacobian, forward = _Steps.jacobian, _Steps._forward

    def counted(self, *args):
        made.append(self.block)
        return jacobian(self, *args)

    def counted_forward(self, *args):
        integrated.append(self.block)
        return forward(self, *args)

    monkeypatch.setattr(_Steps, "jacobian", counted)
    monkeypatch.setattr(_Steps, "_forward", counted_forward)
    return made, integrated


@pytest.mark.parametrize("estimate_bias", [False, True], ids=["bias-held", "bias-free"])
def test_the_search_takes_only_coarse_jacobians_and_lands_on_the_exact_searchs_optimum(monkeypatch, estimate_bias):
    """Started at the nominal sensitivity (2 % off, 0.9° of misalignment: hundreds of σ), the
    solve makes one Jacobian of pairs of steps, the polish's (the covariance), and the start's
    (it whitens and points the search) and the search's on the coarse steps, whose integration
    alone gives the search's residuals: the exact integration is asked only by the polish, a
    step or two, and no exact Jacobian at all. The solution is the one exact Jacobians
    throughout reach, within a thousandth of a σ, covariance alike; with an exact Jacobian in
    the polish alone, within 1e-5 σ."""
    rec = hand_recording(11)
    obs = observe(rec, np.random.default_rng(11), **GRADES["counts"])
    made, integrated = _count_steps(monkeypatch)
    sol = solve(rec, obs, estimate_bias=estimate_bias)
    coarse_block = rotation._BLOCK // rotation._SEARCH_GROUP
    pairs_block = rotation._BLOCK // rotation._POLISH_GROUP
    assert made.count(pairs_block) == 1 and made.count(coarse_block) >= 2 and rotation._BLOCK not in made, made
    assert integrated.count(rotation._BLOCK) <= 3, integrated  # the polish's start and chord steps

    monkeypatch.setattr(rotation, "_POLISH_GROUP", 1)
    made.clear()
    exact_polish = solve(rec, obs, estimate_bias=estimate_bias)
    assert made.count(rotation._BLOCK) == 1, made
    assert np.all(np.abs(sol.theta - exact_polish.theta) < 1e-5 * exact_polish.sigma)
    np.testing.assert_allclose(sol.sigma, exact_polish.sigma, rtol=1e-5)

    monkeypatch.setattr(rotation, "_SEARCH_GROUP", 1)
    made.clear()
    reference = solve(rec, obs, estimate_bias=estimate_bias)
    assert coarse_block not in made and made.count(rotation._BLOCK) > 2, made
    assert np.all(np.abs(sol.theta - reference.theta) < 1e-3 * reference.sigma)
    np.testing.assert_allclose(sol.sigma, reference.sigma, rtol=1e-3)
    truth = np.r_[obs["b"], obs["k"], obs["M"]]
    assert np.all(np.abs(sol.theta - truth) < 4 * sol.sigma)



def test_each_jacobian_and_its_residuals_take_one_pass_of_the_whitener(monkeypatch):
    """A pass of the block whitener costs its loop over the motions whatever the columns: a
    Jacobian and the residuals its integration gives are whitened together (the start's too),
    a residual vector alone only where no Jacobian gave it. The solution is the simulator's
    within 4σ."""
    from fieldcal.solvers.semiseparable import SemiseparableWhitener

    rec = hand_recording(11)
    obs = observe(rec, np.random.default_rng(11), **GRADES["counts"])
    passes = []
    whiten = SemiseparableWhitener.__matmul__

    def counted_pass(self, r):
        passes.append(np.ndim(r))
        return whiten(self, r)

    monkeypatch.setattr(SemiseparableWhitener, "__matmul__", counted_pass)
    made, integrated = _count_steps(monkeypatch)
    sol = solve(rec, obs)
    assert passes.count(2) == len(made) and passes.count(1) == len(integrated), (passes, made, integrated)
    truth = np.r_[obs["b"], obs["k"], obs["M"]]
    assert np.all(np.abs(sol.theta - truth)[3:] < 4 * sol.sigma[3:])


def test_a_steps_terms_are_the_hand_worked_ones_at_their_bit_reversed_places():
    """A rate linear in time, ω = a + b·t, on uneven steps, two spans (the second over 64 steps,
    so two blocks): its slope is b everywhere (so no Hermite correction), and step j's terms are
    h/2·(ω_j + ω_{j+1}), h²/12·ω_j × ω_{j+1}, h²/12·(ω_{j+1} − ω_j) and h, at position
    bit-reversed(k mod 64) of block k // 64 of its span (k the step's index in the span);
    padding steps are zero."""
    t = np.cumsum(np.r_[0.0, 0.01 + 0.002 * np.sin(np.arange(199))])
    a, b = np.array([0.3, -0.2, 0.1]), np.array([0.5, 0.25, -1.0])
    omega = a + t[:, None] * b
    spans = np.array([[3, 40], [50, 150]])
    steps = _Steps(omega, t, spans)
    terms = steps.terms.reshape(10, rotation._BLOCK, -1)
    reversed_ = rotation._bit_reversed(rotation._BLOCK)
    first_block = [0, 1]
    seen = np.zeros(terms.shape[1:], dtype=bool)
    for s, (i0, i1) in enumerate(spans):
        for k in range(i1 - i0):
            j = i0 + k
            h = t[j + 1] - t[j]
            expected = np.r_[h / 2 * (omega[j] + omega[j + 1]), h * h / 12 * np.cross(omega[j], omega[j + 1]),
                             h * h / 12 * (omega[j + 1] - omega[j]), h]
            place = reversed_[k % rotation._BLOCK], first_block[s] + k // rotation._BLOCK
            np.testing.assert_allclose(terms[(slice(None),) + place], expected, rtol=1e-12, atol=1e-15)
            seen[place] = True
    assert np.all(terms[:, ~seen] == 0.0) and seen.sum() == 137


def test_a_subset_of_the_steps_is_what_its_spans_make_from_the_samples():
    """The scan bounds its misfits on every sixth motion: those spans' steps copied out of all
    the motions' are the steps made anew from the samples of those spans alone, term for term,
    grouped and placed alike, and integrate to the same rotations. Spans of one to five blocks,
    enough of them for several span groups."""
    rng = np.random.default_rng(6)
    lengths = rng.integers(20, 300, 400)
    starts = np.cumsum(lengths + 5) - lengths
    n = int(starts[-1] + lengths[-1] + 3)
    t = np.cumsum(np.r_[0.0, 0.01 + 0.001 * rng.random(n - 1)])
    raw = rng.normal(size=(n, 3))
    spans = np.column_stack([starts, starts + lengths])
    steps = _Steps(raw, t, spans, offset=np.array([0.1, -0.2, 0.3]))
    assert len(steps.span_groups) > 2
    for rows in (np.arange(0, 400, 6), np.array([3]), np.array([0, 1, 2, 399]), np.arange(1, 400, 2)):
        subset = steps.subset(rows)
        assert len(subset.span_groups) > 1 or len(rows) < 200  # every other span: groups of its own
        fresh = _Steps(raw, t, spans[rows], offset=np.array([0.1, -0.2, 0.3]))
        np.testing.assert_array_equal(subset.terms, fresh.terms)
        assert subset.span_groups == fresh.span_groups
        np.testing.assert_array_equal(subset.gather, fresh.gather)
        np.testing.assert_array_equal(subset.duration, fresh.duration)
        A, delta_b = np.diag([1.1, 0.9, 1.0]), np.array([0.01, 0.0, -0.02])
        np.testing.assert_array_equal(subset.quaternions(A, delta_b), fresh.quaternions(A, delta_b))


def test_the_scan_integrates_exactly_the_best_and_only_the_neighbours_that_contend(monkeypatch):
    """The grid's best coarse scale is integrated exactly over every motion; how far its coarse
    misfit is from that tells how far the neighbours' may be, so a neighbour a grid step away
    (a third in scale) is no contender and is not integrated, one a hair away is. Either way
    the choice is the exhaustive exact scan's (as test_rotation_solver's scan test checks on
    more recordings)."""
    rec = hand_recording(3)
    obs = observe(rec, np.random.default_rng(3), **GRADES["counts"])
    whole = []
    forward = _Steps._forward

    def counted(self, *args):
        whole.append(len(self.duration) == len(rec.spans) and self.block == rotation._BLOCK)
        return forward(self, *args)

    monkeypatch.setattr(_Steps, "_forward", counted)
    up = obs["up"]

    def misfit(k):
        q = Rotation.from_quat(rotation.integrate((obs["raw"] - obs["b0"]) / k, rec.t, rec.spans))
        return np.sum((q.inv().apply(up[:-1]) - up[1:]) ** 2)

    scales = np.geomspace(1e-3, 1e6, 73)
    found = rotation.scan_scale(rec.t, obs["raw"], rec.spans, up[:-1], up[1:], obs["b0"], scales)
    assert whole.count(True) == 1, whole
    assert found == scales[np.argmin([misfit(k) for k in scales])]
    # A neighbour a hair from the best (1e-7 in scale): a contender, integrated exactly too.
    k = np.mean(obs["k"])
    tight = np.array([0.5 * k, k, k * (1 + 1e-7), 2 * k])
    whole.clear()
    found = rotation.scan_scale(rec.t, obs["raw"], rec.spans, up[:-1], up[1:], obs["b0"], tight)
    assert whole.count(True) == 2, whole
    assert found == tight[np.argmin([misfit(k) for k in tight])]