"""Positions in any order: the engine recognises which remaining position the unit is in from
gravity and starts its dwell once the unit is still, with no "ready"; it waits while the unit
stays where the last step was measured, names positions gravity cannot tell apart and takes the
operator's choice among them. Fed synthetic samples whose up direction is known."""
import numpy as np
import pytest

from drivers.chunk import SampleChunk
from fieldcal.procedure import events as ev
from fieldcal.procedure.engine import DWELL, PLACE, WRONG, Engine, EngineSettings
from fieldcal.procedure.positions import ProcedureError, parse_procedure
from fieldcal.procedure.stillness import StillnessSettings

RATE_HZ = 100.0
G = 9.8
SF_WHITE, RATE_WHITE = 2e-3, 1e-4
# Positions 1 and 3 share their up direction (z up), differing by heading only: gravity cannot
# tell them apart. Position 2 is x up.
PROCEDURE = """name: anyorder
dwell_s: 5
{any_order}
positions:
  - {{id: 1, axes: {{x: east, y: north, z: up}}}}
  - {{id: 2, axes: {{x: up, y: north, z: west}}}}
  - {{id: 3, axes: {{x: north, y: west, z: up}}}}
"""
Z_UP, X_UP, Y_DOWN = (0.0, 0.0, 1.0), (1.0, 0.0, 0.0), (0.0, -1.0, 0.0)


class Bench:
    """One-second chunks of a unit held still with ``up`` pointing up, or being moved."""

    def __init__(self, engine: Engine, seed: int = 1):
        self.engine, self.rng, self.k, self.events = engine, np.random.default_rng(seed), 0, []

    def _chunk(self, sf, rate):
        n = int(RATE_HZ)
        t = (self.k * n + np.arange(n)) / RATE_HZ
        self.k += 1
        out = self.engine.feed(SampleChunk(t, {"accelerometer": sf + SF_WHITE * self.rng.standard_normal((n, 3)),
                                               "gyroscope": rate + RATE_WHITE * self.rng.standard_normal((n, 3))}))
        self.events += out
        return out

    def still(self, up, seconds=1):
        out = []
        for _ in range(seconds):
            out += self._chunk(np.tile(G * np.asarray(up), (int(RATE_HZ), 1)), np.zeros((int(RATE_HZ), 3)))
        return out

    def move(self, seconds=2):
        out = []
        n = int(RATE_HZ)
        for _ in range(seconds):
            wobble = np.sin(np.arange(n) / 5.0)[:, None] * np.array([3.0, -2.0, 1.0])
            out += self._chunk(G * np.array(Z_UP) + wobble, 0.5 * wobble)
        return out


def engine(any_order=True, **settings_kw) -> Engine:
    text = PROCEDURE.format(any_order=f"any_order: {str(any_order).lower()}")
    settings = EngineSettings(rate_hz=RATE_HZ, stillness=StillnessSettings(specific_force_sigma=SF_WHITE,
                                                                           rate_sigma=RATE_WHITE), **settings_kw)
    e = Engine(parse_procedure(text, "anyorder.yaml"), settings)
    e.start()
    return e


def of(kind, events):
    return [e for e in events if isinstance(e, kind)]


def test_the_position_the_unit_is_in_is_taken_with_no_ready_and_steps_keep_their_own_index():
    e = engine()
    bench = Bench(e)
    bench.move()
    out = bench.still(X_UP, 8)  # position 2 first: step 1, though step 0 is suggested
    recognised = of(ev.PositionRecognised, out)
    assert [(r.step, r.position_id, r.alike) for r in recognised] == [(1, 2, ())]
    assert of(ev.StepComplete, out) == [ev.StepComplete(of(ev.StepComplete, out)[0].t, 1, 2)]
    assert of(ev.WrongOrientation, bench.events) == []
    assert e.records[1].position_id == 2 and 0 not in e.records


def test_a_unit_left_where_the_last_step_was_measured_waits_for_the_operator_silently():
    e = engine()
    bench = Bench(e)
    bench.move()
    bench.still(X_UP, 8)
    assert 1 in e.records
    out = bench.still(X_UP, 20)  # the operator has not come yet
    assert e.phase == PLACE and out == [] and len(e.records) == 1
    bench.move()
    out = bench.still(Z_UP, 8)
    assert [r.position_id for r in of(ev.PositionRecognised, out)] == [1]
    assert set(e.records) == {0, 1}


def test_a_unit_in_no_remaining_position_is_told_which_remain():
    e = engine()
    bench = Bench(e)
    bench.move()
    bench.still(X_UP, 8)
    bench.move()
    out = bench.still(Y_DOWN, 3)
    [wrong] = of(ev.WrongOrientation, out)
    assert e.phase == WRONG
    assert 12.0 <= wrong.t <= 14.99  # told while it lay still in y down (the last three seconds fed)
    # Suggested: position 3 (z up), the first open step after the done one; y down is 90° from it
    # and like no position at all.
    assert (wrong.position_id, wrong.looks_like) == (3, ())
    assert wrong.angle_deg == pytest.approx(90.0, abs=0.5)
    assert wrong.message == "the unit is y-downward, like no remaining position; place it in one of positions 1, 3"
    bench.move()
    bench.still(X_UP, 3)  # back to the one already done: still no remaining position
    again = of(ev.WrongOrientation, bench.events)[-1]
    assert (again.position_id, again.looks_like) == (3, (2,))
    assert again.angle_deg == pytest.approx(90.0, abs=0.5)
    assert again.message == ("the unit is x-upward (position 2, done or skipped), like no remaining position; "
                             "place it in one of positions 1, 3")
    assert len(e.records) == 1


def test_the_orientation_tolerance_decides_recognition_and_the_looks_like_list():
    # 10° off x up: position 2 at the default 15°, no position at a 5° tolerance.
    tilted = (np.cos(np.radians(10.0)), 0.0, np.sin(np.radians(10.0)))
    e = engine(tolerance_deg=5.0)
    bench = Bench(e)
    bench.move()
    out = bench.still(tilted, 3)
    assert of(ev.PositionRecognised, out) == []
    [wrong] = of(ev.WrongOrientation, out)
    assert wrong.looks_like == () and "like no remaining position" in wrong.message
    wide = engine()
    bench = Bench(wide)
    bench.move()
    assert [r.position_id for r in of(ev.PositionRecognised, bench.still(tilted, 3))] == [2]


def test_positions_gravity_cannot_tell_apart_are_named_taken_in_procedure_order_and_chosen_by_the_operator():
    e = engine()
    bench = Bench(e)
    bench.move()
    out = bench.still(Z_UP, 2)
    [first] = of(ev.PositionRecognised, out)
    assert (first.position_id, first.alike, first.chosen) == (1, (1, 3), False)
    # Recognised while the unit lay still: within the two still seconds just fed (t 2.00-3.99 s).
    assert 2.0 <= first.t <= 3.99
    assert first.description == "z-upward, x-east, y-north"  # position 1's axes, in the files' words
    assert e.phase == DWELL
    assert e.act(ev.Action(ev.CHOOSE, position_id=2)) == []  # not among the alike: refused
    [chosen] = e.act(ev.Action(ev.CHOOSE, position_id=3))
    assert (chosen.step, chosen.position_id, chosen.chosen) == (2, 3, True)
    assert chosen.t == 3.99  # the choice is made at the engine's time: the last sample fed
    assert chosen.description == "z-upward, x-north, y-west"
    bench.still(Z_UP, 8)
    assert e.records[2].position_id == 3 and 0 not in e.records
    # The other heading: the same up direction, after the operator turned the unit.
    bench.still(Z_UP, 5)
    assert e.phase == PLACE and 0 not in e.records  # not taken before the unit moves
    bench.move()
    out = bench.still(Z_UP, 8)
    assert [(r.position_id, r.alike) for r in of(ev.PositionRecognised, out)] == [(1, ())]
    assert set(e.records) == {0, 2}


def test_a_choice_survives_a_bump_during_the_dwell():
    e = engine()
    bench = Bench(e)
    bench.move()
    bench.still(Z_UP, 2)
    e.act(ev.Action(ev.CHOOSE, position_id=3))
    bench.move(1)
    out = bench.still(Z_UP, 8)
    assert [(r.position_id, r.chosen) for r in of(ev.PositionRecognised, out)] == [(3, True)]
    assert e.records[2].position_id == 3


def test_in_procedure_order_the_next_position_is_still_required():
    e = engine(any_order=False)
    bench = Bench(e)
    e.act(ev.Action(ev.READY))
    out = bench.still(X_UP, 3)
    assert of(ev.PositionRecognised, out) == [] and of(ev.WrongOrientation, out)[0].position_id == 1


def test_resumed_engine_waits_for_the_unit_to_leave_the_last_measured_position():
    first = engine()
    bench = Bench(first)
    bench.move()
    bench.still(X_UP, 8)
    resumed = engine()
    resumed.restore(first.records.values())
    resumed.start()
    bench.engine = resumed
    assert bench.still(X_UP, 5) == [] and resumed.phase == PLACE


def test_choose_is_an_action_with_a_position_and_other_actions_keep_their_plain_form():
    assert ev.Action(ev.READY).to_dict() == {"action": "ready"}
    choose = ev.Action(ev.CHOOSE, position_id=7)
    assert ev.action_from_dict(choose.to_dict()) == choose
    with pytest.raises(ValueError):
        ev.Action(ev.CHOOSE)
    with pytest.raises(ValueError):
        ev.Action(ev.READY, position_id=3)


@pytest.mark.parametrize("line, message", [("any_order: \"true\"", "true or false"),
                                           ("any_ordr: true", "any_order")])
def test_a_bad_any_order_key_is_a_one_line_error(line, message):
    with pytest.raises(ProcedureError) as caught:
        parse_procedure(PROCEDURE.format(any_order=line), "anyorder.yaml")
    assert message in str(caught.value) and "\n" not in str(caught.value)


def test_shuffle_on_a_procedure_in_a_fixed_order_is_a_one_line_error(tmp_path, capsys):
    from fieldcal.cli.main import main

    code = main(["run", "--headless", "--config", "sim", "--procedure", "field-18", "--shuffle", "3",
                 "--out", str(tmp_path)])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "\n" not in err and "--shuffle" in err and "any_order: true" in err
    assert list(tmp_path.iterdir()) == []  # refused before any session
