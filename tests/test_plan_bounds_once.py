"""The planner takes each design's bound once: a design asked for again (the bisection's dwell,
then its plan) gives the same σ as a fresh evaluation, without evaluating it again, and what a
caller does to the σ it was given does not reach the next caller."""
from __future__ import annotations

import numpy as np

from fieldcal.earth import Station
from fieldcal.procedure.positions import load_procedure

STATION = Station(40.0, 50.0)


def test_a_design_asked_for_twice_is_bounded_once_with_the_fresh_bounds_sigmas(monkeypatch):
    from drivers.sim.device import paper_mimu
    from fieldcal.planning import search
    from fieldcal.planning.design import Design, OperatorModel, bound_sigmas
    from fieldcal.solvers.solve import models_from_truth

    models = {"accelerometer": models_from_truth(paper_mimu())["accelerometer"]}
    operator = OperatorModel()
    attitudes = tuple(p.attitude for p in load_procedure("field-18").positions)
    calls = []

    def counted(design, *args):
        calls.append(design)
        return bound_sigmas(design, *args)

    monkeypatch.setattr(search, "bound_sigmas", counted)
    planner = search.Planner(models, STATION, 250.0, operator, {"accelerometer": np.ones(9)}, 20.0)
    design = Design(attitudes, 20.0, 20.0, 1)
    first = planner.sigmas(design)
    first["accelerometer"][:] = np.nan  # a caller's change stays its own
    again = planner.sigmas(Design(tuple(a.copy() for a in attitudes), 20.0, 20.0, 1))
    fresh = bound_sigmas(design, operator, models, STATION, 250.0)
    assert len(calls) == 1
    assert np.array_equal(again["accelerometer"], fresh["accelerometer"])
    planner.sigmas(Design(attitudes, 21.0, 20.0, 1))  # another dwell is another design
    planner.sigmas(Design(attitudes[:-2], 20.0, 20.0, 1))  # and fewer positions
    assert len(calls) == 3
