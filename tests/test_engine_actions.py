"""The operator's actions on the engine alone (no samples): skip, unskip, redo, abort, ready,
against the steps and counts worked by hand for a three-position procedure."""
from fieldcal.procedure import events as ev
from fieldcal.procedure.engine import ABORTED, DONE, PLACE, SETTLING, Engine, EngineSettings, skipped_to_return_to
from fieldcal.procedure.positions import parse_procedure
from fieldcal.procedure.stillness import StillnessSettings

THREE = """name: three
dwell_s: 10
positions:
  - {id: 11, description: "z-upward", axes: {x: east, y: north, z: up}}
  - {id: 12, description: "z-downward", axes: {x: west, y: north, z: down}}
  - {id: 13, description: "y-upward", axes: {x: east, y: up, z: south}}
"""


def engine():
    return Engine(parse_procedure(THREE, "three.yaml"),
                  EngineSettings(rate_hz=100.0, stillness=StillnessSettings(specific_force_sigma=2e-3, rate_sigma=1e-4)))


def steps(events):
    """(kind, step, position id) of the events that name a step."""
    return [(e.kind, getattr(e, "step", None), getattr(e, "position_id", None)) for e in events
            if e.kind in ("step_started", "step_skipped", "place_unit")]


def act(e, name):
    return e.act(ev.Action(name))


def test_skipping_every_position_completes_the_procedure_with_three_skipped():
    e = engine()
    assert steps(e.start()) == [("step_started", 0, 11), ("place_unit", None, 11)]
    assert e.start()[0].total_steps == 3
    assert steps(act(e, ev.SKIP)) == [("step_skipped", 0, 11), ("step_started", 1, 12), ("place_unit", None, 12)]
    assert steps(act(e, ev.SKIP)) == [("step_skipped", 1, 12), ("step_started", 2, 13), ("place_unit", None, 13)]
    last = act(e, ev.SKIP)
    assert steps(last) == [("step_skipped", 2, 13)]
    assert last[-1] == ev.ProcedureComplete(0.0, 0, 3)
    assert (e.phase, e.skipped) == (DONE, {0, 1, 2})
    assert act(e, ev.SKIP) == [] and act(e, ev.ABORT) == []  # a finished procedure takes no action


def test_unskip_goes_back_to_the_skipped_step_nearest_before_and_reopens_it():
    e = engine()
    e.start()
    act(e, ev.SKIP)
    act(e, ev.SKIP)  # now at step 2, steps 0 and 1 skipped
    assert steps(act(e, ev.UNSKIP)) == [("step_started", 1, 12), ("place_unit", None, 12)]
    assert (e.step, e.skipped) == (1, {0})
    assert steps(act(e, ev.UNSKIP)) == [("step_started", 0, 11), ("place_unit", None, 11)]
    assert (e.step, e.skipped) == (0, set())
    assert act(e, ev.UNSKIP) == []  # nothing skipped: nothing to go back to
    assert e.step == 0


def test_the_step_unskip_returns_to():
    assert skipped_to_return_to({0, 3}, 2) == 0
    assert skipped_to_return_to({0, 1, 4}, 3) == 1  # the nearest before
    assert skipped_to_return_to({3, 4}, 1) == 4  # none before: the last one after
    assert skipped_to_return_to(set(), 1) is None
    assert skipped_to_return_to({2}, 2) == 2  # the current step counts as "after"


def test_ready_starts_the_watch_only_while_placing_and_redo_starts_the_step_again():
    e = engine()
    e.start()
    assert act(e, ev.READY) == [ev.WaitingForStillness(0.0)]
    assert e.phase == SETTLING
    assert act(e, ev.READY) == []  # already watching
    assert steps(act(e, ev.REDO)) == [("step_started", 0, 11), ("place_unit", None, 11)]
    assert e.phase == PLACE


def test_abort_ends_the_procedure_and_names_the_operator():
    e = engine()
    e.start()
    act(e, ev.SKIP)
    assert act(e, ev.ABORT) == [ev.Aborted(0.0, "operator")]
    assert e.phase == ABORTED
    assert act(e, ev.READY) == []
