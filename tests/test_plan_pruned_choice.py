"""The search's comparisons bound a design's triads only as far as the comparison needs: the
choice is the one every triad's bound gives (the first design with the smallest worst σ/target,
as ``min`` picks it, ties included), whatever triad is asked first, and fewer bounds are taken.

The bounds here are a table of σ per (design, triad), so that the brute-force choice over every
bound is the independent answer."""
from __future__ import annotations

import numpy as np
import pytest

from fieldcal.planning import search
from fieldcal.planning.design import Design, OperatorModel

TRIADS = ("accelerometer", "gyroscope", "inclinometer")


def _planner(monkeypatch, table: dict[float, dict[str, np.ndarray]], targets: dict[str, np.ndarray]):
    """A Planner whose bound of the design with dwell d is table[d] (one σ row per triad)."""
    taken = []

    def bound_sigmas(design, operator, models, station, rate_hz, bias_at_end=False):
        taken.extend((design.dwell_s, name) for name in models)
        return {name: table[design.dwell_s][name].copy() for name in models}

    monkeypatch.setattr(search, "bound_sigmas", bound_sigmas)
    planner = search.Planner(dict.fromkeys(TRIADS), None, 250.0, OperatorModel(), targets, 20.0)
    return planner, taken


def _designs(count: int) -> list[Design]:
    return [Design((np.eye(3),), float(dwell), 20.0, 1) for dwell in range(count)]


@pytest.mark.parametrize("seed", range(20))
def test_the_pruned_choice_is_the_brute_force_choice_with_fewer_bounds(monkeypatch, seed):
    rng = np.random.default_rng(seed)
    count = 9
    # Each triad's worst ratio from 0.3 to 2.5 in steps of 0.1 (ties between designs and between
    # triads happen), now and then one undetermined (inf) or not told apart (nan).
    def row():
        sigma = np.round(rng.uniform(0.3, 2.5), 1) * rng.uniform(0.5, 1.0, size=9)
        sigma[rng.integers(9)] = np.round(rng.uniform(0.3, 2.5), 1)
        return np.where(rng.random(9) < 0.02, rng.choice([np.inf, np.nan]), sigma)
    table = {float(d): {n: row() for n in TRIADS} for d in range(count)}
    targets = {n: np.ones(9) for n in TRIADS}
    with np.errstate(invalid="ignore"):
        full = [max(float(np.max(np.nan_to_num(table[float(d)][n], nan=np.inf))) for n in TRIADS)
                for d in range(count)]
    expected = min(range(count), key=full.__getitem__)

    planner, taken = _planner(monkeypatch, table, targets)
    planner._lead = TRIADS[seed % 3]  # whichever triad is asked first
    chosen, ratio = planner._least(_designs(count))
    assert (chosen, ratio) == (expected, full[expected])
    assert len(taken) == len(set(taken)) <= count * len(TRIADS)  # each bound once at most

    # With a bar (turn_where_it_pays: only a design at or under 1 is of use): the same choice
    # when one is under it; otherwise a ratio over it.
    planner, _ = _planner(monkeypatch, table, targets)
    chosen, ratio = planner._least(_designs(count), search.ABOVE_ONE)
    if full[expected] <= 1.0:
        assert (chosen, ratio) == (expected, full[expected])
    else:
        assert ratio > 1.0


def test_a_design_under_target_everywhere_is_bounded_in_full_and_one_over_it_stops_at_its_first_miss(monkeypatch):
    table = {0.0: {n: np.full(9, 0.5) for n in TRIADS},
             1.0: {"accelerometer": np.full(9, 0.5), "gyroscope": np.full(9, 3.0), "inclinometer": np.full(9, 0.5)}}
    planner, taken = _planner(monkeypatch, table, {n: np.ones(9) for n in TRIADS})
    assert planner.worst_ratio(_designs(2)[0], search.ABOVE_ONE) == 0.5
    assert sorted(name for _, name in taken) == sorted(TRIADS)
    taken.clear()
    assert planner.worst_ratio(_designs(2)[1], search.ABOVE_ONE) == 3.0
    assert [name for _, name in taken] == ["accelerometer", "gyroscope"]  # the inclinometer's not taken
    taken.clear()
    planner.worst_ratio(_designs(2)[1], search.ABOVE_ONE)  # the gyroscope, worst last time, first
    assert taken == []  # and cached
    assert planner.sigmas(_designs(2)[1])["inclinometer"] == pytest.approx(np.full(9, 0.5))


def test_a_design_that_cannot_beat_the_best_so_far_is_bounded_no_further_than_its_first_triad(monkeypatch):
    half = {n: np.full(9, 0.5) for n in TRIADS}
    gyro_binds = {**half, "gyroscope": np.full(9, 2.0)}
    table = {0.0: half, 1.0: gyro_binds, 2.0: half, 3.0: gyro_binds}  # 2.0: a tie, the first wins
    planner, taken = _planner(monkeypatch, table, {n: np.ones(9) for n in TRIADS})
    planner._lead = "gyroscope"
    assert planner._least(_designs(4)) == (0, 0.5)
    assert len(taken) == 3 + 1 + 1 + 1
