"""The procedure screen's display rate: readings, and a banner that only says how the run goes,
are repainted at most once per DISPLAY_S of the app's clock (a human reads no faster; each
repaint re-lays-out and re-renders the screen); the operator's turn, a banner that asks for
something or reports a fault, a fault event and the run's end at once; and what the screen holds
(its view) takes every batch as it comes. The clock is injected: no wall-clock quantity decides
anything here."""
from __future__ import annotations

import contextlib

from textual.app import App

from tui_pilot import run_async, until
from fieldcal.procedure import events as ev
from fieldcal.procedure.engine import DWELL, PLACE, RATE_WAIT, SETTLING, WRONG
from fieldcal.procedure.positions import load_procedure
from fieldcal.tui.readings import Telemetry
from fieldcal.tui.screens.procedure import DISPLAY_S, ProcedureScreen
from fieldcal.tui.source import Note
from fieldcal.tui.view import RunView


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


class ScreenApp(App[None]):
    """Only the procedure screen, fed by the test as the app feeds it from a run."""

    def __init__(self, clock: Clock, mode: str = "replay") -> None:
        super().__init__()
        self.screen_under_test = ProcedureScreen(RunView(load_procedure("field-18")), "title", mode, clock=clock)
        self.sent: list[str] = []  # the operator's commands, which the app sends to the run

    def on_mount(self) -> None:
        self.push_screen(self.screen_under_test)

    def send_command(self, name: str) -> None:
        self.sent.append(name)


@contextlib.asynccontextmanager
async def mounted_screen(mode: str = "replay"):
    """The procedure screen alone at 80×24, mounted, on a clock the test moves:
    (app, pilot, screen, clock)."""
    clock = Clock()
    app = ScreenApp(clock, mode)
    async with app.run_test(size=(80, 24)) as pilot:
        screen = app.screen_under_test
        await until(pilot, lambda: screen.is_mounted)
        yield app, pilot, screen, clock


def reading(t: float, x_mg: float, waiting: bool = False, phase: str | None = None) -> Telemetry:
    return Telemetry(t=t, step=0, phase=phase or (PLACE if waiting else DWELL), waiting=waiting,
                     samples=int(t * 100), accel_mg=(x_mg, 0.0, 1000.0), gyro_deg_s=(0.0, 0.0, 0.0),
                     angle_deg=0.5, quiet=1.0)


def accel_row(screen: ProcedureScreen) -> str:
    return str(screen.query_one("#live-accel").render())


def banner(screen: ProcedureScreen) -> str:
    return str(screen.query_one("#banner").render())


def log_text(screen: ProcedureScreen) -> str:
    return "\n".join(line.text for line in screen.query_one("#log").lines)


@run_async
async def test_readings_within_the_display_period_wait_for_its_end_and_the_last_is_shown():
    async with mounted_screen() as (app, pilot, screen, clock):
        screen.set_telemetry(reading(1.0, 11.0, waiting=True))  # the first: at once
        assert "+11.0" in accel_row(screen)
        screen.set_telemetry(reading(1.1, 22.0))  # the operator's turn ends: at once
        assert "+22.0" in accel_row(screen)

        clock.now += DISPLAY_S / 2  # within the period: the view has it, the screen not yet
        screen.set_telemetry(reading(1.2, 33.0))
        screen.set_telemetry(reading(1.3, 44.0))
        assert screen.view.telemetry.accel_mg[0] == 44.0
        assert "+22.0" in accel_row(screen)
        # the end of the period (a timer): the last of them, not each
        await until(pilot, lambda: "+44.0" in accel_row(screen))

        clock.now += DISPLAY_S  # a period later: at once again
        screen.set_telemetry(reading(1.4, 55.0))
        assert "+55.0" in accel_row(screen)


@run_async
async def test_the_operators_turn_a_new_instruction_and_the_runs_end_are_shown_at_once():
    async with mounted_screen() as (app, pilot, screen, clock):
        screen.set_telemetry(reading(1.0, 11.0))
        screen.set_telemetry(reading(1.1, 22.0, waiting=True))  # same instant: the turn comes
        assert "+22.0" in accel_row(screen)
        # same instant: the banner's instruction changes (the device falls silent)
        silent = Telemetry(**{**reading(1.2, 33.0, waiting=True).__dict__, "silent_s": 3.0})
        screen.set_telemetry(silent)
        assert str(screen.query_one("#banner").render()).startswith("NO SAMPLES from the device for 3 s")
        screen.finished("aborted")  # same instant: the end
        assert str(screen.query_one("#banner").render()) == "Aborted: the session is kept"


@run_async
async def test_a_banner_that_only_says_how_the_run_goes_waits_for_the_display_period_like_the_readings():
    async with mounted_screen() as (app, pilot, screen, clock):
        screen.set_telemetry(reading(1.0, 11.0))  # the first: at once
        assert banner(screen) == "Dwelling: keep the unit still"

        clock.now += DISPLAY_S / 2  # within the period: the dwell ends and the table starts
        screen.add_items([ev.DwellComplete(1.1, 20.0), ev.CommandTable(1.1, 30.0)], reading(1.1, 22.0, phase=RATE_WAIT))
        assert screen.view.banner(sim=False)[0] == "Table turning to +30.0 °/s: waiting until steady"
        assert banner(screen) == "Dwelling: keep the unit still"  # the screen: not yet
        assert "+11.0" in accel_row(screen)
        assert "dwell complete" not in log_text(screen).lower()  # the log waits with them
        # the end of the period (a timer): banner, readings and log together
        await until(pilot, lambda: banner(screen).startswith("Table turning to +30.0 °/s"))
        assert "+22.0" in accel_row(screen)


@run_async
async def test_a_banner_that_asks_or_reports_a_fault_and_a_fault_event_are_shown_at_once():
    async with mounted_screen() as (app, pilot, screen, clock):
        screen.set_telemetry(reading(1.0, 11.0))
        assert banner(screen) == "Dwelling: keep the unit still"

        # within the period, the run not waiting for the operator (a live unit is checked again
        # once still): a wrong position, which the banner reports (its style "bad"), at once
        clock.now += DISPLAY_S / 4
        screen.set_telemetry(reading(1.1, 22.0, phase=WRONG))
        assert banner(screen).startswith("WRONG POSITION")
        assert "+22.0" in accel_row(screen)

        # the same instant: the position corrected, the banner no longer asks: at once too (the
        # screen must not ask for what is done)
        screen.set_telemetry(reading(1.2, 33.0))
        assert banner(screen) == "Dwelling: keep the unit still"
        # within the period: a bump's motion, whose banner ("hands off") is the same as a
        # placement's, is a fault: shown at once, with the restarted dwell and its log line
        clock.now += DISPLAY_S / 4
        screen.add_items([ev.MotionDetected(1.3, "dwell", True)], reading(1.3, 44.0, phase=SETTLING))
        assert banner(screen) == "Hands off: waiting for the unit to be still"
        assert "↺1" in str(screen.query_one("#live-dwell").render())
        assert "motion" in log_text(screen).lower()

        # an error the operator must act on (a table that did not turn) comes as a note: at once
        clock.now += DISPLAY_S / 4
        screen.add_items([Note(1.4, "ERROR: table: no reply; skip this step (s) or abort (a)")],
                         reading(1.4, 55.0, phase=SETTLING))
        assert "ERROR: table: no reply" in log_text(screen)
        assert "+55.0" in accel_row(screen)


@run_async
async def test_the_end_of_the_operators_turn_that_a_key_has_shown_waits_for_the_display_period():
    """r in a simulated run says the carry at once; the run going on after it (no longer
    waiting, no question asked) is nothing new for the operator: it waits like the readings."""
    async with mounted_screen(mode="sim") as (app, pilot, screen, clock):
        screen.set_telemetry(reading(1.0, 11.0, waiting=True))  # the operator's turn: at once
        assert banner(screen).startswith("Position 1: ")
        await pilot.press("r")
        assert app.sent == ["ready"]
        assert banner(screen).startswith("The simulator is carrying the unit into position 1")

        screen.set_telemetry(reading(1.1, 22.0, phase=PLACE))  # the run goes on, the same instant
        assert not screen.view.telemetry.waiting
        assert "+11.0" in accel_row(screen)
        await until(pilot, lambda: "+22.0" in accel_row(screen))
        assert banner(screen).startswith("The simulator is carrying the unit into position 1")
