"""The engine's events and the front ends' actions as the session log stores them: the documents
are written out here by hand (the log's format), not taken from the code."""
import json

import pytest

from fieldcal.procedure import events as ev


def test_an_event_is_stored_under_its_snake_case_name_with_every_field():
    doc = ev.StepStarted(t=12.5, step=2, position_id=7, description="x up", total_steps=18).to_dict()
    assert doc == {"event": "step_started", "t": 12.5, "step": 2, "position_id": 7, "description": "x up",
                   "total_steps": 18}
    assert list(doc) == ["event", "t", "step", "position_id", "description", "total_steps"]
    assert ev.Aborted(t=0.0, reason="operator").to_dict() == {"event": "aborted", "t": 0.0, "reason": "operator"}
    assert ev.WaitingForStillness(t=3.0).to_dict() == {"event": "waiting_for_stillness", "t": 3.0}


def test_a_tuple_field_is_stored_as_a_json_list():
    doc = ev.WrongOrientation(t=1.0, position_id=3, looks_like=(4, 9), angle_deg=88.5, message="turn it").to_dict()
    assert doc == {"event": "wrong_orientation", "t": 1.0, "position_id": 3, "looks_like": [4, 9],
                   "angle_deg": 88.5, "message": "turn it"}
    assert json.loads(json.dumps(doc)) == doc  # what the log reads back is what was written
    solved = ev.Solved(t=2.0, solved=("accelerometer", "gyroscope")).to_dict()
    assert solved == {"event": "solved", "t": 2.0, "solved": ["accelerometer", "gyroscope"], "failures": {}}


def test_defaults_of_a_recognised_position_and_of_a_solve():
    recognised = ev.PositionRecognised(t=0.5, step=1, position_id=2, description="y up")
    assert recognised.alike == () and recognised.chosen is False
    assert recognised.to_dict() == {"event": "position_recognised", "t": 0.5, "step": 1, "position_id": 2,
                                    "description": "y up", "alike": [], "chosen": False}
    a, b = ev.Solved(t=0.0, solved=()), ev.Solved(t=0.0, solved=())
    assert a.failures == {} and a.failures is not b.failures  # each its own dict


@pytest.mark.parametrize("name", ["ready", "redo", "skip", "abort", "unskip"])
def test_a_plain_action_is_stored_as_its_name_alone_and_read_back(name):
    action = ev.Action(name)
    assert action.to_dict() == {"action": name}
    assert ev.action_from_dict({"action": name}) == action


def test_choose_carries_its_position_and_reads_back():
    action = ev.Action("choose", 5)
    assert action.to_dict() == {"action": "choose", "position_id": 5}
    assert ev.action_from_dict({"action": "choose", "position_id": 5}) == ev.Action("choose", 5)
    assert ev.ACTIONS == ("ready", "redo", "skip", "abort", "unskip", "choose")


def test_an_unknown_action_is_refused_in_one_line_naming_the_choices():
    with pytest.raises(ValueError) as refused:
        ev.Action("jump")
    assert str(refused.value) == "action: expected one of ready, redo, skip, abort, unskip, choose, got 'jump'"


@pytest.mark.parametrize("name, position_id", [("choose", None), ("ready", 3), ("skip", 0)])
def test_a_position_id_goes_with_choose_and_only_with_it(name, position_id):
    with pytest.raises(ValueError) as refused:
        ev.Action(name, position_id)
    assert str(refused.value) == f"action {name}: a position id goes with 'choose', and only with it"
