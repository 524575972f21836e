"""The operator's keys in the terminal UI, driven with Textual's Pilot: help everywhere, a
confirmation before the keys that lose work, skip undone, and the layout at odd terminal sizes."""
from __future__ import annotations

import re

from tui_pilot import ask, press_and_go_on, run_async, until, waiting_at
from fieldcal.earth import Station
from fieldcal.procedure.positions import parse_procedure
from fieldcal.run.operators import OperatorScript
from fieldcal.run.runner import RunSpec, open_run
from fieldcal.tui import FieldcalApp
from fieldcal.tui.choices import SetupChoice
from fieldcal.tui.screens.help import HelpScreen
from fieldcal.tui.screens.setup import SetupScreen

STATION = Station(40.0, 50.0)
THREE_POSITIONS = """\
name: three
title: three positions, 20 s dwells
dwell_s: 20
positions:
  - {id: 1, description: "z-upward, x-south, y-east", axes: {x: south, y: east, z: up}}
  - {id: 2, description: "z-upward, x-north, y-west", axes: {x: north, y: west, z: up}}
  - {id: 3, description: "z-downward, x-north, y-east", axes: {x: north, y: east, z: down}}
"""






def three_positions():
    return parse_procedure(THREE_POSITIONS, "three.yaml")




@run_async
async def test_help_on_the_setup_screen_shows_the_setup_keys(tmp_path, monkeypatch):
    """`?` on the setup screen (no run prepared yet) used to raise AttributeError."""
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "xdg"))

    def make_run(config, procedure, choice=None):  # pragma: no cover - the test never starts
        raise AssertionError("not started")

    app = FieldcalApp(setup=(SetupChoice("sim", None, "field-18", 45.0, 10.0), make_run))
    async with app.run_test(size=(80, 24)) as pilot:
        assert isinstance(app.screen, SetupScreen)
        await pilot.press("question_mark")
        await until(pilot, lambda: isinstance(app.screen, HelpScreen))
        text = str(app.screen.query_one("#help-text").render())
        assert "ctrl+s" in text and "start" in text
        await pilot.press("escape")
        await until(pilot, lambda: isinstance(app.screen, SetupScreen))


def confirm_text(app) -> str:
    bar = app.screen.query_one("#confirm")
    return str(bar.render()) if bar.display else ""


@run_async
async def test_abort_asks_first_and_any_other_key_carries_on(tmp_path):
    from fieldcal.session.capture import SessionReader
    from fieldcal.tui.screens.results import ResultsScreen

    app = FieldcalApp(RunSpec(three_positions(), STATION, seed=4), speed=0, session_dir=tmp_path / "s")
    async with app.run_test(size=(80, 24)) as pilot:
        await until(pilot, lambda: waiting_at(app, 0))
        await pilot.press("a")
        assert "ABORT" in confirm_text(app)
        await pilot.press("x")  # not a confirmation: nothing happens, the bar goes
        assert confirm_text(app) == ""
        await pilot.press("a")
        await pilot.press("r")  # neither: r answers the question (no), it does not place the unit
        assert confirm_text(app) == "" and waiting_at(app, 0)
        await pilot.press("a", "a")
        await until(pilot, lambda: isinstance(app.screen, ResultsScreen) and bool(app.screen.query("#verdicts")))
        verdicts = str(app.screen.query_one("#verdicts").render())
    assert app.outcome.status == "aborted"
    assert "skipped: none · not done: positions 1–3" in verdicts  # as the outcome counts them
    assert [a["action"] for a in SessionReader(tmp_path / "s").actions()] == ["abort"]


@run_async
async def test_a_skip_is_confirmed_and_undone_and_the_run_completes_all_positions(tmp_path):
    from fieldcal.run.replay import replay
    from fieldcal.session.capture import SessionReader
    from fieldcal.tui.screens.results import ResultsScreen

    app = FieldcalApp(RunSpec(three_positions(), STATION, seed=4), speed=0, session_dir=tmp_path / "s")
    async with app.run_test(size=(80, 24)) as pilot:
        view = app.screen.view
        await until(pilot, lambda: waiting_at(app, 0))
        await pilot.press("s")
        assert "Skip position 1?" in confirm_text(app)
        await pilot.press("y")
        await until(pilot, lambda: waiting_at(app, 1))
        assert view.tiles == ["skipped", "active", "todo"]
        await pilot.pause()
        assert [str(t.render()) for t in app.screen.query(".tile")] == ["– 1", "▶ 2", "· 3"]
        await pilot.press("u")  # nothing begun at step 2: back at once
        await until(pilot, lambda: waiting_at(app, 0))
        assert view.tiles == ["active", "todo", "todo"]
        await pilot.press("r")
        await until(pilot, lambda: waiting_at(app, 1))  # then on where the skip left off
        await pilot.press("r")
        await until(pilot, lambda: waiting_at(app, 2))
        await pilot.press("s")
        assert "the last one" in confirm_text(app)  # a skip here ends the run: said so
        await pilot.press("escape")
        await pilot.press("r")
        await until(pilot, lambda: isinstance(app.screen, ResultsScreen))
    assert app.outcome.status == "completed"
    assert (app.outcome.completed, app.outcome.skipped) == (3, 0)
    assert view.tiles == ["done"] * 3
    assert [a["action"] for a in SessionReader(tmp_path / "s").actions()] == \
        ["skip", "unskip", "ready", "ready", "ready"]
    replayed = []  # the recorded unskip replays to the same events
    replay(open_run(tmp_path / "s"), report=lambda e: replayed.append(e.to_dict()))
    assert replayed == SessionReader(tmp_path / "s").events()[:len(replayed)]
    assert [e["event"] for e in replayed].count("step_complete") == 3


@run_async
async def test_going_back_from_a_step_begun_asks_first(tmp_path):
    from tests.test_tui import VirtualClock, run_until

    # 20x on a virtual clock (test_tui's): the run moves only as the test advances the clock, so
    # the dwell is still running when u comes however slow the machine (in real time the test
    # idled 4 s of its 6 for the carry and the settling).
    clock = VirtualClock()
    app = FieldcalApp(RunSpec(three_positions(), STATION, seed=4), speed=20, session_dir=None, clock=clock)
    async with app.run_test(size=(80, 24)) as pilot:
        await until(pilot, lambda: waiting_at(app, 0))
        await ask(pilot, "s")
        await press_and_go_on(pilot, "s")
        await run_until(pilot, clock, lambda: waiting_at(app, 1), step_s=0.05)
        await press_and_go_on(pilot, "r")
        # begun (checked or dwelling: where the run stands when the clock does), never done
        await run_until(pilot, clock, lambda: app.telemetry.phase not in ("place", "settling"), step_s=0.05)
        assert "Back to position 1? Position 2's progress is lost" in await ask(pilot, "u")
        await press_and_go_on(pilot, "u")
        await run_until(pilot, clock, lambda: waiting_at(app, 0), step_s=0.05)
        assert app.screen.view.tiles == ["active", "todo", "todo"]


@run_async
async def test_quit_mid_run_asks_and_after_the_end_does_not(tmp_path):
    app = FieldcalApp(RunSpec(three_positions(), STATION, seed=4), speed=0, session_dir=tmp_path / "s")
    async with app.run_test(size=(80, 24)) as pilot:
        await until(pilot, lambda: waiting_at(app, 0))
        await pilot.press("q")
        assert "Quit mid-run?" in confirm_text(app)
        await pilot.press("escape")
        assert confirm_text(app) == "" and app.is_running
        await pilot.press("q", "y")
        await until(pilot, lambda: not app.is_running)
    assert app.source.done.wait(60.0), "the run's thread never ended"
    assert app.source.outcome.status == "stopped"


def test_the_engine_goes_back_to_the_nearest_skipped_step_before():
    from fieldcal.procedure.engine import skipped_to_return_to

    assert skipped_to_return_to(set(), 3) is None
    assert skipped_to_return_to({1, 2, 7}, 5) == 2
    assert skipped_to_return_to({7}, 5) == 7


class FrozenClock:
    """Wall time that never moves: the pacer holds the simulator's samples back for good."""

    def __call__(self) -> float:
        return 0.0


@run_async
async def test_r_changes_the_banner_at_once_even_while_the_samples_take_their_time():
    app = FieldcalApp(RunSpec(three_positions(), STATION, seed=4), speed=1, session_dir=None,
                      clock=FrozenClock())
    async with app.run_test(size=(80, 24)) as pilot:
        await until(pilot, lambda: waiting_at(app, 0))
        await pilot.press("r")
        banner = str(app.screen.query_one("#banner").render())
        assert banner.startswith("The simulator is carrying the unit into position 1")
        assert "moving the unit" in app.screen.query_one("#live-still").render().plain


@run_async
async def test_at_real_time_the_readings_follow_the_carry_as_it_happens():
    """Issue 15 item 9: at 1× the carry into place is 4 s of samples; they come in short chunks,
    so the live readings move during it (the old single chunk kept them frozen, then jumped)."""
    app = FieldcalApp(RunSpec(three_positions(), STATION, seed=4), speed=1, session_dir=None)
    carry_n = round(OperatorScript().handling_s * app.spec.rate_hz)
    seen = []

    def part_way() -> bool:
        view, t = app.screen.view, app.telemetry
        if view.carrying and t.phase == "place" and 0 < t.samples - view.carry_from < carry_n:
            seen.append(view.stale_reason())
        return bool(seen)

    async with app.run_test(size=(80, 24)) as pilot:
        await until(pilot, lambda: waiting_at(app, 0))
        await pilot.press("r")
        await until(pilot, part_way)
        assert seen[0] is None  # live readings, not dimmed as old
        assert str(app.screen.query_one("#banner").render()).startswith("The simulator is carrying")
        await pilot.press("q", "y")


def test_tui_help_lists_every_key_within_80_columns(capsys, monkeypatch):
    import pytest

    from fieldcal.cli.main import main
    from fieldcal.tui.screens.procedure import ProcedureScreen

    monkeypatch.setenv("COLUMNS", "200")  # a wide terminal: the help still fits 80 columns
    with pytest.raises(SystemExit):
        main(["tui", "--help"])
    text = capsys.readouterr().out
    assert max(len(line) for line in text.splitlines()) <= 80
    keys = {b.key for b in ProcedureScreen.BINDINGS} | {"?"}
    digits = set("123456789")  # which of positions alike to gravity: one line, "1-9"
    assert keys == set("rsuoabwvq?") | digits
    assert re.search(r"^  1-9 ", text, re.M)
    for key in keys - digits:
        assert re.search(rf"^  {re.escape(key)} ", text, re.M), key
    for key in ("ctrl+s", "Esc", "Tab"):
        assert re.search(rf"^  {re.escape(key)}", text, re.M), key
