"""The operator's terminal UI, driven with Textual's Pilot: the same engine as the headless runs
(same seed and keys: the same parameter file), a bump restarting the dwell, replay through the
same screens, and snapshots of the procedure and results screens at 80x24."""
from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np
import pytest

from tui_pilot import (log_settled, press_and_go_on, run_async, show_hand_built_readings, show_hand_built_results, until,
                        waiting_at)
from fieldcal.procedure import events as ev
from fieldcal.earth import Station
from fieldcal.procedure.positions import load_procedure, parse_procedure
from fieldcal.run.replay import replay
from fieldcal.run.runner import OperatorScript, RunSpec, open_run, run_headless
from fieldcal.session.capture import SessionReader
from fieldcal.tui import FieldcalApp
from fieldcal.tui.screens.procedure import ProcedureScreen
from fieldcal.tui.screens.results import ResultsScreen

try:
    import pytest_textual_snapshot  # noqa: F401
    HAVE_SNAPSHOTS = True
except ImportError:  # pragma: no cover
    HAVE_SNAPSHOTS = False

STATION = Station(40.0, 50.0)
TWO_POSITIONS = """\
name: two
title: two positions, 20 s dwells
dwell_s: 20
positions:
  - {id: 1, description: "z-upward, x-south, y-east", axes: {x: south, y: east, z: up}}
  - {id: 2, description: "z-upward, x-north, y-west", axes: {x: north, y: west, z: up}}
"""
TWO_WITH_TURNS = TWO_POSITIONS + "rate_step: {rate_deg_s: 10, turns: 1, ramp_s: 2, settle_s: 1}\n"


def replay_identical(record) -> bool:
    """Does replaying the session give the run's parameter file (byte for byte here)?"""
    return replay(record).identical is True


def two_positions(tmp_path: Path, text: str = TWO_POSITIONS):
    path = tmp_path / "two.yaml"
    path.write_text(text)
    return parse_procedure(path.read_text(), path.name)


def field18_short():
    """field-18 with 20 s dwells and 30 °/s turns: everything solves, in a tenth of the samples."""
    text = load_procedure("field-18").text.replace("dwell_s: 200", "dwell_s: 20")
    return parse_procedure(text.replace("rate_deg_s: 10", "rate_deg_s: 30"), "field-18-short.yaml")




def on_results(app: FieldcalApp) -> bool:
    """The results screen is up and composed (its last widget mounted)."""
    return isinstance(app.screen, ResultsScreen) and bool(app.screen.query("#where"))




async def press_ready_through(pilot, app: FieldcalApp) -> None:
    """Press r at every PlaceUnit until the run ends on the results screen. (Each r waited for
    by what it does, the run at the next step, not by Pilot.press's waits for an idle process
    while the run measures the step: 0.1-0.2 s a key, 18 keys a run.)"""
    for step in range(len(app.spec.procedure.positions)):
        await until(pilot, lambda step=step: waiting_at(app, step))
        await press_and_go_on(pilot, "r")
    await until(pilot, lambda: app.outcome is not None and on_results(app))


@pytest.fixture(scope="module")
def headless_field18(tmp_path_factory):
    """The whole of field-18 (golden-mini: 3 s dwells at 20 Hz, every triad solved): what the
    runs through the keys are compared with. (field18_short's 265,000 samples at 250 Hz, read
    and shown at speed 0, took 2.7 s of CPU a run; the comparison is byte for byte either way.)"""
    spec = _golden_mini_spec(5)
    return spec, run_headless(spec, tmp_path_factory.mktemp("headless") / "session")


@pytest.fixture(scope="module")
def headless_classic12(tmp_path_factory):
    """classic-12 with 20 s dwells: solved by linear least squares, whose results agree across
    processors and BLAS builds to ~1e-15, far below the digits a screen shows (unlike Powell's
    search path), so a snapshot of its results is not numerically fragile."""
    text = load_procedure("classic-12").text.replace("dwell_s: 200", "dwell_s: 3")
    # The noise drawn the old way ("bank"), whose stream stays as it is for the sessions it
    # wrote: the snapshot's simulated digits do not move with the default generator. (3 s dwells
    # at 20 Hz: the snapshot shows hand-built numbers, and no figure of the session's length.)
    spec = RunSpec(parse_procedure(text, "classic-12-short.yaml"), STATION, seed=5, sim_noise="bank",
                   rate_hz=20.0)
    return spec, run_headless(spec, tmp_path_factory.mktemp("classic") / "session")


@run_async
async def test_a_run_equals_the_headless_run_of_the_same_seed(tmp_path, headless_field18):
    spec, headless = headless_field18
    app = FieldcalApp(spec, speed=0, session_dir=tmp_path / "session")
    async with app.run_test(size=(80, 24)) as pilot:
        await press_ready_through(pilot, app)
        outcome = app.outcome
    assert outcome.status == "completed" and not outcome.unit.failures
    assert set(outcome.unit.solutions) == set(headless.unit.solutions)
    for name, sol in outcome.unit.solutions.items():
        assert np.array_equal(sol.theta, headless.unit.solutions[name].theta), name
        assert np.array_equal(sol.sigma, headless.unit.solutions[name].sigma), name
    assert outcome.parameters.read_bytes() == headless.parameters.read_bytes()
    assert replay_identical(open_run(outcome.session))
    assert [e.kind for e in app.events] == \
        [e["event"] for e in SessionReader(headless.session).events()]
    assert FieldcalApp.return_code_for(outcome) == 0


class VirtualClock:
    """Wall time for the UI's pacer that moves only when the test says: the run stands still
    between advances, so a key lands exactly where the test means it to."""

    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


async def run_until(pilot, clock: VirtualClock, predicate, step_s: float, timeout_s: float = 120.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < deadline, "the UI did not get there in time"
        clock.now += step_s
        await pilot.pause(0.01)


@run_async
async def test_a_field18_run_with_a_wrong_position_and_a_bump_equals_the_headless_run(tmp_path):
    """The whole of field-18 through the keys (golden-mini's turns at 20 Hz, with 20 s dwells:
    the engine says a dwell's progress every 10 s, and the bump waits for half of it), at 10x
    virtual real time (one-second chunks, as headless): position 4 first placed wrongly,
    position 8 bumped mid-dwell. A headless run of the same seed whose operator does the same
    gives the same parameter file."""
    text = _golden_mini_spec(6).procedure.text.replace("dwell_s: 3", "dwell_s: 20")
    assert "dwell_s: 20" in text
    spec = RunSpec(parse_procedure(text, "golden-mini-20s.yaml"), STATION, seed=6, rate_hz=20.0)
    clock = VirtualClock()
    app = FieldcalApp(spec, speed=10, session_dir=tmp_path / "session", clock=clock)
    wrong_step, bump_step = 3, 7
    async with app.run_test(size=(80, 24)) as pilot:
        screen = app.screen
        for step in range(len(spec.procedure.positions)):
            await run_until(pilot, clock, lambda step=step: waiting_at(app, step), step_s=1e3)
            if step == wrong_step:
                await pilot.press("w")
                await run_until(pilot, clock, lambda: any(isinstance(e, ev.WrongOrientation)
                                                          for e in app.events), step_s=1e3)
                await until(pilot, lambda step=step: waiting_at(app, step))
                assert screen.view.tiles[step] == "wrong"
            await pilot.press("r")
            if step == bump_step:
                def half_dwelt():
                    return any(isinstance(e, ev.DwellProgress) and e.done_s >= e.total_s / 2
                               for e in app.events[-5:])
                await run_until(pilot, clock, half_dwelt, step_s=0.05)
                await pilot.press("b")
                await run_until(pilot, clock, lambda: screen.view.restarts == 1, step_s=0.05)
        await run_until(pilot, clock, lambda: on_results(app), step_s=1e3)
        await until(pilot, lambda: bool(app.screen.query("#headline")))  # composed
        outcome = app.outcome
        assert app.screen.query_one("#headline").render().plain.startswith("Calibration complete")
        assert screen.view.tiles == ["done"] * len(spec.procedure.positions)
    assert outcome.status == "completed" and not outcome.unit.failures
    assert len(app.source.bump_times) == 1
    kinds = [e.kind for e in app.events]
    assert kinds.count("wrong_orientation") == 1
    motion = [e for e in app.events if isinstance(e, ev.MotionDetected)]
    assert len(motion) == 1 and motion[0].phase == "dwell" and motion[0].restarted

    script = OperatorScript(wrong_step=wrong_step, bump_at_s=tuple(app.source.bump_times))
    headless = run_headless(RunSpec(spec.procedure, STATION, seed=6, rate_hz=20.0, script=script),
                            tmp_path / "headless")
    assert kinds == [e["event"] for e in SessionReader(headless.session).events()]
    for name, sol in outcome.unit.solutions.items():
        assert np.array_equal(sol.theta, headless.unit.solutions[name].theta), name
    assert outcome.parameters.read_bytes() == headless.parameters.read_bytes()
    assert replay_identical(open_run(outcome.session))


@run_async
async def test_a_bump_restarts_the_dwell_and_the_run_ends_on_the_results(tmp_path):
    spec = RunSpec(two_positions(tmp_path), STATION, seed=3)
    # 20× real time on a virtual clock: the run moves only as the test advances the clock, so
    # the bump lands mid-dwell however slow the machine is.
    clock = VirtualClock()
    app = FieldcalApp(spec, speed=20, session_dir=tmp_path / "session", clock=clock)
    async with app.run_test(size=(80, 24)) as pilot:
        screen = app.screen
        assert isinstance(screen, ProcedureScreen)
        await until(pilot, lambda: waiting_at(app, 0))
        await pilot.press("r")
        await run_until(pilot, clock, lambda: any(isinstance(e, ev.Still) for e in app.events), step_s=0.05)
        assert not any(isinstance(e, ev.DwellComplete) for e in app.events)
        await pilot.press("b")
        await run_until(pilot, clock, lambda: any(isinstance(e, ev.MotionDetected) for e in app.events),
                        step_s=0.05)
        await run_until(pilot, clock, lambda: screen.view.dwell.anchor is not None and screen.view.restarts == 1,
                        step_s=0.05)
        assert screen.view.dwell.done(screen.view.t) < 10.0  # the bar went back to the start
        await run_until(pilot, clock, lambda: waiting_at(app, 1), step_s=0.5)
        await pilot.press("r")
        await run_until(pilot, clock, lambda: on_results(app), step_s=1e3)
        outcome = app.outcome
        assert screen.view.restarts_total == 1
        assert screen.view.tiles == ["done", "done"]
    events = app.events
    bump = next(i for i, e in enumerate(events) if isinstance(e, ev.MotionDetected))
    assert events[bump].phase == "dwell" and events[bump].restarted
    still_again = next(e for e in events[bump:] if isinstance(e, ev.Still))
    complete = next(e for e in events[bump:] if isinstance(e, ev.DwellComplete))
    assert complete.t - still_again.t == pytest.approx(20.0, abs=0.01)  # a whole dwell again
    # Two positions cannot calibrate anything: the same verdicts as the headless run.
    headless = run_headless(spec, tmp_path / "headless")
    assert outcome.status == "completed" and not outcome.unit.solutions
    assert outcome.unit.failures == headless.unit.failures
    # The session has the bump's samples and replays to the same events.
    reader = SessionReader(outcome.session)
    assert reader.stop_reason == "completed"
    assert [a["action"] for a in reader.actions()] == ["ready", "ready"]


@run_async
async def test_replay_runs_through_the_same_screens_and_ignores_keys(headless_field18):
    _, headless = headless_field18
    app = FieldcalApp(None, speed=0, replay=open_run(headless.session))
    async with app.run_test(size=(80, 24)) as pilot:
        await pilot.press("a", "s", "d", "r", "b")  # ignored: the recorded actions apply
        await until(pilot, lambda: on_results(app))
        outcome = app.outcome
        assert app.screen.query_one("#where").render().plain.count("byte for byte") == 1
        # Powell's iteration and evaluation counts vary with the processor and BLAS: they are in
        # each triad's tooltip, not on the screen (nor in its snapshot).
        heads = list(app.screen.query(".triad-head"))
        shown = [str(h.render()) for h in heads]
    assert len(heads) == 3 and all("(powell; residual RMS" in text for text in shown), shown
    for head, (name, sol) in zip(heads, outcome.unit.solutions.items()):
        assert f"{sol.diagnostics.iterations} iterations, {sol.diagnostics.evaluations} evaluations" in str(head.tooltip), name
    assert outcome.status == "completed" and outcome.identical is True
    for name, sol in outcome.unit.solutions.items():
        assert np.array_equal(sol.theta, headless.unit.solutions[name].theta)
    assert [e.kind for e in app.events] == [e["event"] for e in SessionReader(headless.session).events()]


@run_async
async def test_abort_keeps_the_session(tmp_path):
    spec = RunSpec(two_positions(tmp_path), STATION, seed=4)
    app = FieldcalApp(spec, speed=0, session_dir=tmp_path / "session")
    async with app.run_test(size=(80, 24)) as pilot:
        await until(pilot, lambda: waiting_at(app, 0))
        await pilot.press("s", "y")  # each confirmed (tests/test_tui_keys.py has the questions)
        await until(pilot, lambda: waiting_at(app, 1))
        await pilot.press("a", "a")
        await until(pilot, lambda: on_results(app))
        await pilot.press("escape")  # back to the run: its tiles say what happened
        assert isinstance(app.screen, ProcedureScreen)
        assert app.screen.view.tiles == ["skipped", "todo"]  # position 2 was not done, not skipped
        await pilot.press("r")  # a finished run takes no more actions
        await pilot.press("v")  # and shows its results again
        assert isinstance(app.screen, ResultsScreen)
    assert app.outcome.status == "aborted"
    reader = SessionReader(tmp_path / "session")
    assert reader.stop_reason == "aborted"
    assert [a["action"] for a in reader.actions()] == ["skip", "abort"]


@pytest.mark.skipif(not HAVE_SNAPSHOTS, reason="pytest-textual-snapshot is not installed")
def test_snapshot_procedure_screen(snap_compare, tmp_path, monkeypatch):
    # The live readings are hand-built round numbers (tui_pilot), and the simulated operator
    # places the unit exactly: no simulated digits on the screen but the procedure's own.
    show_hand_built_readings(monkeypatch)
    spec = RunSpec(two_positions(tmp_path, TWO_WITH_TURNS), STATION, seed=3, sim_noise="bank",
                   script=OperatorScript(placement_sigma_deg=0.0))
    app = FieldcalApp(spec, speed=0, session_dir=None)

    async def second_step(pilot):
        await until(pilot, lambda: waiting_at(app, 0))
        await pilot.press("r")
        await until(pilot, lambda: waiting_at(app, 1))
        await until(pilot, lambda: log_settled(app, "step 2/2"))
        await pilot.pause()

    assert snap_compare(app, terminal_size=(80, 24), run_before=second_step)


@pytest.mark.skipif(not HAVE_SNAPSHOTS, reason="pytest-textual-snapshot is not installed")
def test_snapshot_results_screen(snap_compare, headless_classic12, tmp_path, monkeypatch):
    import shutil

    _, headless = headless_classic12
    shutil.copytree(headless.session, tmp_path / "session")
    monkeypatch.chdir(tmp_path)  # so that the paths shown do not depend on the temporary directory
    show_hand_built_results(monkeypatch)  # round numbers in place of the solved ones (tui_pilot)
    app = FieldcalApp(None, speed=0, replay=open_run(Path("session")))

    async def results(pilot):
        await until(pilot, lambda: on_results(app))

    assert snap_compare(app, terminal_size=(80, 24), run_before=results)


@run_async
async def test_the_results_show_the_previous_calibration_of_the_same_unit(tmp_path, headless_field18):
    """A second run beside an earlier session shows each parameter against the earlier file.
    The same unit: the same serial (a unit without one is compared with nothing: issue 23)."""
    from dataclasses import replace

    from fieldcal.paramfile import load, save

    spec, headless = headless_field18
    sessions = tmp_path / "sessions"
    earlier = sessions / "earlier"
    earlier.mkdir(parents=True)
    first = load(headless.parameters)
    save(replace(first, provenance=replace(first.provenance, device_serial="PAPER-7")), earlier / "parameters.yaml")
    (sessions / "damaged").mkdir()
    (sessions / "damaged" / "parameters.yaml").write_text("schema: nonsense\n")
    app = FieldcalApp(dataclasses.replace(spec, seed=7, unit_serial="PAPER-7"), speed=0,
                      session_dir=sessions / "today")
    async with app.run_test(size=(100, 40)) as pilot:
        await press_ready_through(pilot, app)
        await until(pilot, lambda: len(app.screen.query(".previous-head")) > 0)  # composed
        text = "\n".join(w.render().plain if hasattr(w.render(), "plain") else str(w.render())
                         for w in app.screen.query(".previous-head, .table"))
    previous = app.outcome.previous
    assert previous is not None and previous.path == earlier / "parameters.yaml"
    old = load(earlier / "parameters.yaml")["accelerometer"]
    new = app.outcome.unit.solutions["accelerometer"]
    assert str(earlier / "parameters.yaml") in text
    assert "not verified" in text  # a bare file: no session log recorded its checksum
    # The change column is the difference of the two files' values (bias x, in mg).
    change_mg = (new.theta[0] - old.theta[0]) / 9.80665e-3
    assert f"{change_mg:.3g} mg" in text


@run_async
async def test_the_setup_screen_starts_the_run_it_was_given(tmp_path, monkeypatch):
    """`fieldcal tui` opens on the setup screen; the choice (station included) builds the run,
    and a run that cannot be built sends the operator back to the setup with the reason."""
    from fieldcal.tui.choices import SetupChoice
    from fieldcal.tui.screens.setup import SetupScreen

    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "xdg"))
    asked = []

    def make_run(config, procedure, choice=None):
        asked.append((config, procedure))
        if len(asked) == 1:
            raise ValueError("the table is not answering (say)")
        return RunSpec(two_positions(tmp_path), config.station, seed=2), tmp_path / "session", 0

    initial = SetupChoice("sim", None, "field-18", 45.5, 120.0)
    app = FieldcalApp(setup=(initial, make_run))
    async with app.run_test(size=(80, 24)) as pilot:
        assert isinstance(app.screen, SetupScreen)
        await pilot.press("ctrl+s")
        await until(pilot, lambda: isinstance(app.screen, SetupScreen) and len(asked) == 1
                    and "not answering" in str(app.screen.query_one("#error").render()))
        await pilot.press("ctrl+s")
        await until(pilot, lambda: isinstance(app.screen, ProcedureScreen))
        config, procedure = asked[-1]
        assert procedure.name == "field-18"
        assert (config.station.latitude_deg, config.station.height_m) == (45.5, 120.0)
        await until(pilot, lambda: waiting_at(app, 0))
        await pilot.press("q", "y")
        await until(pilot, lambda: not app.is_running)
    assert app.spec.station.latitude_deg == 45.5


def _golden_mini_spec(seed: int) -> RunSpec:
    """tests/test_conductor.py's golden procedure: field-18 with 3 s dwells, at 20 Hz."""
    text = load_procedure("field-18").text.replace("name: field-18", "name: golden-mini") \
        .replace("dwell_s: 200", "dwell_s: 3") \
        .replace("rate_step: {rate_deg_s: 10, turns: 1, ramp_s: 2, settle_s: 1}",
                 "rate_step: {rate_deg_s: 60, turns: 1, ramp_s: 3, settle_s: 1}")
    return RunSpec(parse_procedure(text, "golden-mini.yaml"), STATION, seed=seed, rate_hz=20.0,
                   script=OperatorScript(handling_s=2.0))


@run_async
async def test_a_run_quit_half_way_resumes_in_the_tui_to_the_uninterrupted_run(tmp_path):
    """Issue 15 item 2: quit (q, y) after step 7, `tui --resume` continues after it; the parameter
    file is byte for byte the headless uninterrupted run's of the same seed."""
    spec = _golden_mini_spec(12)
    session = tmp_path / "session"
    app = FieldcalApp(spec, speed=0, session_dir=session)
    async with app.run_test(size=(80, 24)) as pilot:
        for step in range(7):
            await until(pilot, lambda step=step: waiting_at(app, step))
            await press_and_go_on(pilot, "r")  # (as press_ready_through)
        await until(pilot, lambda: waiting_at(app, 7))
        await pilot.press("q", "y")
    assert app.source.done.wait(60.0), "the run's thread never ended"
    assert app.source.outcome.status == "stopped"
    assert f"fieldcal tui --resume {session}" in app.source.outcome.message
    assert not SessionReader(session).stopped

    resumed = FieldcalApp(speed=0, resume=open_run(session))
    async with resumed.run_test(size=(80, 24)) as pilot:
        await until(pilot, lambda: waiting_at(resumed, 7))  # after the last completed step
        await press_ready_from(pilot, resumed, 7)
        outcome = resumed.outcome
    assert outcome.status == "completed" and not outcome.unit.failures
    whole = run_headless(spec, tmp_path / "whole")
    assert outcome.parameters.read_bytes() == whole.parameters.read_bytes()
    assert SessionReader(session).stop_reason == "completed"


async def press_ready_from(pilot, app: FieldcalApp, first: int) -> None:
    for step in range(first, len(app.spec.procedure.positions)):
        await until(pilot, lambda step=step: waiting_at(app, step))
        await press_and_go_on(pilot, "r")  # (as press_ready_through)
    await until(pilot, lambda: app.outcome is not None and on_results(app))


def test_tui_resume_refuses_in_one_line_what_it_cannot_continue(tmp_path):
    from fieldcal.cli.tui import resumable

    with pytest.raises(ValueError, match="not a session directory"):
        resumable(str(tmp_path))
    done = run_headless(_golden_mini_spec(3), tmp_path / "done")
    with pytest.raises(ValueError, match="already ended \\(completed\\); a completed session is never resumed") as e:
        resumable(str(done.session))
    assert "\n" not in str(e.value)
