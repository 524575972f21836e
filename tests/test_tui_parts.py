"""The terminal UI's pure parts: the orientation drawing, the progress bookkeeping, pacing, and the
source driven without Textual."""
from __future__ import annotations

import itertools

import pytest

from fieldcal.procedure import events as ev
from fieldcal.earth import Station
from fieldcal.procedure.positions import load_procedure, parse_procedure
from fieldcal.run.runner import RunSpec
from fieldcal.tui.widgets.bars import bar, signed_bar
from fieldcal.tui.widgets.cube import top_view
from fieldcal.tui.source import READY, Pacer, SimSource
from fieldcal.tui.readings import Telemetry
from fieldcal.tui.view import RunView


def test_the_top_view_draws_the_papers_positions():
    positions = load_procedure("field-18").positions
    one = "\n".join(top_view(positions[0]))  # z-upward, x-south, y-east
    assert "⊙z" in one and "↓x" in one and "y→" in one
    thirteen = "\n".join(top_view(positions[12]))  # y-east, z north-up 45°, x south-up 45°
    assert "↑z⊙" in thirteen and "↓x⊙" in thirteen and "y→" in thirteen
    assert all(len(line) <= 22 for p in positions for line in top_view(p))


def test_bars_fill_in_eighths_and_centre_signed_values():
    assert bar(0.5, 4).plain == "██░░"
    assert bar(0.25, 2).plain == "▌░" and bar(1 / 16, 2).plain == "▏░"
    assert bar(2.0, 3).plain == "███"
    assert signed_bar(-1.0, 1.0, 4).plain == "██│  "
    assert signed_bar(0.5, 1.0, 4).plain == "  │█ "


def test_the_dwell_bar_restarts_on_motion_and_moves_with_sample_time():
    view = RunView(load_procedure("field-18"))
    for e in (ev.StepStarted(0.0, 0, 1, "z-upward", 18), ev.Still(5.0, 3.0), ev.DwellProgress(15.0, 10.0, 200.0)):
        view.apply(e)
    assert view.dwell.done(20.0) == pytest.approx(15.0)
    view.apply(ev.MotionDetected(21.0, "dwell", True))
    assert view.dwell.done(30.0) == 0.0 and view.restarts == 1
    view.apply(ev.Still(22.0, 3.1))
    assert view.dwell.done(32.0) == pytest.approx(10.0)
    view.apply(ev.StepComplete(300.0, 0, 1))
    view.apply(ev.StepStarted(300.0, 1, 2, "z-upward", 18))
    assert view.tiles[:3] == ["done", "active", "todo"] and view.restarts == 0 and view.restarts_total == 1


TWO_WITH_TURNS = """\
name: two
title: two positions with turns
dwell_s: 20
positions:
  - {id: 1, description: "z-upward, x-south, y-east", axes: {x: south, y: east, z: up}}
  - {id: 2, description: "z-upward, x-north, y-west", axes: {x: north, y: west, z: up}}
rate_step: {rate_deg_s: 10, turns: 1, ramp_s: 2, settle_s: 1}
"""


def test_the_time_to_go_counts_dwells_turns_and_this_runs_placements():
    """Worked by hand: the rate step up to +10 °/s is 2 s ramp + 1 s settle + 36 s for one turn =
    39 s, the reversal to −10 °/s ramps twice as far: 4 + 1 + 36 = 41 s; a position is 20 s dwell
    + 80 s + its placement."""
    from fieldcal.tui.view import PLACING_GUESS_S

    view = RunView(parse_procedure(TWO_WITH_TURNS, "two.yaml"))
    view.apply(ev.StepStarted(0.0, 0, 1, "z-upward", 2))
    assert view.remaining_s() == pytest.approx(2 * (100 + PLACING_GUESS_S))
    view.apply(ev.Still(10.0, 2.0))  # placed in 10 s: the next placement is reckoned at 10 s
    view.last_t = 15.0  # 5 s dwelt
    assert view.remaining_s() == pytest.approx((15 + 80) + (100 + 10))
    for e in (ev.DwellComplete(30.0, 20.0), ev.CommandTable(30.0, 10.0), ev.RateSettled(33.0, 10.0, 36.0),
              ev.RateStepComplete(69.0, 10.0)):
        view.apply(e)
    assert view.remaining_s() == pytest.approx(41 + 110)  # the minus rate step, then position 2
    assert view.job_text() == "✓0 done  –0 skipped  ▶ now  ·1 to do   1:09 elapsed, ≈3 min to go"
    view.apply(ev.StepSkipped(69.0, 0, 1))
    view.apply(ev.StepStarted(69.0, 1, 2, "z-upward", 2))
    view.apply(ev.StepComplete(200.0, 1, 2))
    view.apply(ev.ProcedureComplete(200.0, 1, 1))
    assert view.remaining_s() == 0.0
    assert view.job_text() == "✓1 done  –1 skipped  ·0 to do   3:20 in all"


def test_the_banner_says_how_to_move_the_unit_in_the_operators_words():
    """The moves between field-18's positions, read off procedures/field-18.yaml's axes."""
    from fieldcal.tui.guidance import placement

    p = {q.id: q for q in load_procedure("field-18").positions}
    assert placement(p[1], p[2]).text == "rotate it 180° about the vertical so that x points north"
    assert placement(p[1], p[2]).heading_only
    assert placement(p[2], p[3]).text == "turn it over: z must point down, x north"
    assert placement(p[4], p[5]).text == "tip it 90° over: y must point up, x east"
    assert not placement(p[2], p[3]).heading_only
    assert placement(p[12], p[13]).text == "tip it 135° over: y east, x south-up, z north-up"
    quarter = parse_procedure(TWO_WITH_TURNS.replace("x: north, y: west", "x: west, y: south"), "q.yaml")
    one, two = quarter.positions  # x from south to west: a quarter turn clockwise from above
    assert placement(one, two).text == "rotate it 90° clockwise (seen from above) so that x points west"

    view = RunView(load_procedure("field-18"))
    for e in (ev.StepStarted(0.0, 0, 1, "z-upward", 18), ev.Still(5.0, 3.0), ev.StepComplete(30.0, 0, 1),
              ev.StepStarted(30.0, 1, 2, "z-upward", 18)):
        view.apply(e)
    view.telemetry = Telemetry(30.0, 1, "place", True, 100)
    text, _ = view.banner(sim=False)
    assert text.startswith("Position 2: rotate it 180° about the vertical so that x points north, then press r")
    assert "\nOnly the heading changes" in text
    view.apply(ev.WrongOrientation(40.0, 2, (5,), 90.0, "the engine's words"))
    view.telemetry = Telemetry(40.0, 1, "wrong", True, 200)
    assert view.banner(sim=False)[0] == ("WRONG POSITION: it looks like position 5; tip it 90° over: "
                                         "z must point up, x north; checked again once still")


def test_readings_that_are_not_current_say_so_and_progress_ends_with_the_run():
    from fieldcal.tui.widgets.live import rows

    view = RunView(parse_procedure(TWO_WITH_TURNS, "two.yaml"), held_while_waiting=True)
    for e in (ev.StepStarted(0.0, 0, 1, "z-upward", 2), ev.Still(5.0, 2.0), ev.DwellComplete(25.0, 20.0),
              ev.CommandTable(25.0, 10.0), ev.RateSettled(28.0, 10.0, 36.0)):
        view.apply(e)
    turning = Telemetry(30.0, 0, "rate_average", False, 6000, (0.0, 0.0, 1000.0), (0.0, 0.0, -9.9), 1.0, 1.1)
    view.set_telemetry(turning)
    assert rows(view)["still"].plain.endswith("steady turn")  # not "still" beside -9.9 °/s
    for e in (ev.RateStepComplete(64.0, 10.0), ev.CommandTable(64.0, -10.0), ev.RateSettled(67.0, -10.0, 36.0),
              ev.RateStepComplete(103.0, -10.0), ev.CommandTable(103.0, 0.0)):
        view.apply(e)
    assert "stopping" in rows(view)["table"].plain
    view.apply(ev.StepComplete(103.0, 0, 1))
    assert rows(view)["table"].plain.endswith("stopped")
    view.apply(ev.StepStarted(103.0, 1, 2, "z-upward", 2))
    # The simulator waits for r: its last samples (the turning table) are held, and said to be.
    view.set_telemetry(Telemetry(103.0, 1, "place", True, 20000, (0.0, 0.0, 1000.0), (0.0, 0.0, -9.9), 1.0, 1.1))
    lines = rows(view)
    assert lines["still"].plain.endswith("— (the simulator waits for r)")
    assert lines["target"].plain.endswith("—")
    assert any(span.style == "grey50" for span in lines["gyro"].spans)
    # Aborted mid-dwell: the dwell stops where it was and the panel says the run ended.
    for e in (ev.WaitingForStillness(104.0), ev.Still(110.0, 2.0), ev.DwellProgress(120.0, 10.0, 20.0),
              ev.Aborted(122.0, "operator")):
        view.apply(e)
    view.finished = "aborted"
    assert view.dwell.done(500.0) == pytest.approx(12.0)
    lines = rows(view)
    assert lines["dwell"].plain.endswith("— (run aborted)") and lines["turns"].plain.endswith("—")
    assert lines["still"].plain.endswith("— (the run has ended)")


def test_the_pacer_holds_sample_time_to_speed_times_wall_time():
    now = iter(itertools.count(0.0, 0.0))  # a clock that never moves
    pacer = Pacer(10.0, clock=lambda: next(now))
    assert pacer.delay(0.0, 1.0) == pytest.approx(0.1)
    assert pacer.delay(1.0, 5.0) == pytest.approx(0.5)
    pacer.hold()  # after waiting for the operator, pacing starts again from there
    assert pacer.delay(100.0, 101.0) == pytest.approx(0.1)
    assert Pacer(0.0).delay(0.0, 1e6) == 0.0
    with pytest.raises(ValueError):
        Pacer(-1.0)


class Operator:
    """A sink that presses ready whenever the source waits for it."""

    def __init__(self):
        self.items, self.telemetry, self.outcome, self.source = [], [], None, None

    def update(self, items, telemetry):
        self.items.extend(items)
        self.telemetry.append(telemetry)
        if telemetry.waiting:
            self.source.send(READY)

    def finished(self, outcome):
        self.outcome = outcome


def test_the_sim_source_waits_for_the_operator_and_runs_without_a_ui():
    text = load_procedure("field-18").text.replace("dwell_s: 200", "dwell_s: 5").replace("rate_deg_s: 10", "rate_deg_s: 30")
    procedure = parse_procedure(text, "x.yaml")
    sink = Operator()
    source = sink.source = SimSource(RunSpec(procedure, Station(40.0, 50.0), seed=2), sink, speed=0,
                                     session_dir=None)
    outcome = source.run()
    assert outcome is sink.outcome and outcome.status == "completed" and outcome.session is None
    assert outcome.parameters is None and set(outcome.unit.solutions) == {"accelerometer", "gyroscope",
                                                                           "inclinometer"}
    assert sum(isinstance(i, ev.StepComplete) for i in sink.items) == 18
    assert sink.telemetry[-1].accel_mg is not None and sink.telemetry[-1].quiet is not None
