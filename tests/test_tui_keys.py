"""The operator's keys in the terminal UI, driven with Textual's Pilot: help everywhere, a
confirmation before the keys that lose work, skip undone, and the layout at odd terminal sizes."""
from __future__ import annotations

import asyncio
import functools
import time

from fieldcal.earth import Station
from fieldcal.procedure.positions import parse_procedure
from fieldcal.run.runner import RunSpec
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


def run_async(test):
    @functools.wraps(test)
    def wrapper(*args, **kwargs):
        return asyncio.run(test(*args, **kwargs))
    return wrapper


async def until(pilot, predicate, timeout_s: float = 30.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < deadline, "the UI did not get there in time"
        await pilot.pause(0.01)


def three_positions():
    return parse_procedure(THREE_POSITIONS, "three.yaml")


def waiting_at(app: FieldcalApp, step: int) -> bool:
    t = app.telemetry
    return t is not None and t.waiting and t.step == step and app.outcome is None


@run_async
async def test_help_on_the_setup_screen_shows_the_setup_keys(tmp_path, monkeypatch):
    """`?` on the setup screen (no run prepared yet) used to raise AttributeError."""
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "xdg"))

    def make_run(config, procedure):  # pragma: no cover - the test never starts
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
