"""The operator's terminal UI: the same procedure engine as headless runs, against the simulated
bench at a chosen speed, or over a captured session (replay).

The sample source (``fieldcal.tui.source``) runs in a thread worker that alone calls the
engine, the bench and the session writer; it posts batched events and telemetry here at most
ten times a second, and the keys go back to it as commands on a queue.
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING, ClassVar

from textual.app import App
from textual.binding import Binding, BindingType

from fieldcal.procedure import events as ev
from fieldcal.tui.screens.help import HelpScreen
from fieldcal.tui.messages import RunFinished, RunItems, RunTelemetry
from fieldcal.tui.screens.procedure import ProcedureScreen
from fieldcal.tui.readings import Telemetry
from fieldcal.tui.screens.results import ResultsScreen
from fieldcal.tui.source import Outcome, ReplaySource, SimSource, Source
from fieldcal.tui.widgets.toosmall import MIN_COLUMNS, MIN_ROWS
from fieldcal.tui.view import DONE, SKIPPED, RunView

if TYPE_CHECKING:
    from fieldcal.session.record import RunRecord


STEP_ENDS = (ev.StepComplete, ev.StepSkipped, ev.ProcedureComplete)  # then the operator acts


def _speed_words(speed: float) -> str:
    return "as fast as possible" if speed <= 0 else f"{speed:g}× real time"


class FieldcalApp(App[int]):
    """``FieldcalApp(spec, speed, session_dir)`` runs the simulated bench;
    ``FieldcalApp(None, speed, replay=RECORD)`` replays a capture (``RECORD``: its ``RunRecord``)."""

    CSS_PATH = "app.tcss"
    TITLE = "fieldcal"
    ENABLE_COMMAND_PALETTE = False
    BINDINGS: ClassVar[list[BindingType]] = [
        Binding("question_mark", "help", "help"),
        Binding("q", "quit", "quit"),
        # Textual's ctrl+q quits at once and its ctrl+c only says "press ctrl+q": mid-run both
        # ask first, as q does. ctrl+c is no priority, so that a text field's copy keeps it.
        Binding("ctrl+q", "request_quit", "quit", show=False, priority=True),
        Binding("ctrl+c", "request_quit", "quit", show=False, system=True),
    ]

    def __init__(self, spec=None, speed: float = 10.0, session_dir: Path | None = None,
                 replay: RunRecord | None = None, clock=time.monotonic, config=None, setup=None,
                 resume: RunRecord | None = None, product_spec=None, wall_clock=time.time,
                 hands=None, silence_clock=None) -> None:
        """``product_spec``: an ``acceptance.ProductSpec``: the results say PASS/FAIL against it,
        and the exit status is 3 (as the headless run's) when a check fails.

        ``resume``: continue this unfinished session after its last completed step (``spec``
        and ``session_dir`` are then the session's own; give neither); a live device's session
        on the device of ``config``.

        ``config``: the station config of a real device (``spec.live``), for its ports.
        ``wall_clock``: the host's Unix time, beside a real device's own clock (resume).
        ``silence_clock``: what a real device's silence is measured in (default ``clock``; see
        ``LiveSource``).
        ``hands``: an ``OperatorScript``: the simulator places the unit at each step by itself.

        ``setup``: instead of a run, ``(initial, make_run)``: the setup screen opens with the
        ``SetupChoice`` ``initial`` (or none), and the operator's choice, resolved to a config and
        a procedure, goes to ``make_run(config, procedure, choice) -> (spec, session_dir, speed)``
        (the choice: its operator and sessions directory), whose ValueError goes back to the setup
        screen; the product spec becomes the choice's. ``(initial, make_run, sessions, make_resume)``:
        the setup screen also offers the unfinished sessions in the directory ``sessions``, and
        one chosen goes to ``make_resume(session, config) -> (speed, config, record)`` (the config of a
        live session's ports, None for a simulated one).
        """
        super().__init__()
        self.speed = float(speed)
        self.clock = clock
        self.wall_clock = wall_clock
        self.silence_clock = silence_clock
        self.source: Source | None = None
        self.outcome: Outcome | None = None
        self.events: list[ev.Event] = []  # every engine event shown, in order (for tests)
        self.telemetry: Telemetry | None = None
        self.setup = setup
        self.mode = "setup"  # until a run is prepared: the source's "sim", "live" or "replay"
        self.product_spec = product_spec
        self.verdict = None  # the results' acceptance.Verdict, when a product spec was given
        self.hands = hands
        if setup is None:
            self._prepare(spec, session_dir, replay, config, resume)

    def _prepare(self, spec, session_dir: Path | None, replay: RunRecord | None, config,
                 resume: RunRecord | None = None) -> None:
        clock = self.clock
        if resume is not None and resume.spec.live is not None:
            from fieldcal.tui.live_source import LiveSource

            if config is None:
                raise ValueError(f"{resume}: a live device's session: resuming it needs the station config "
                                 "of that device (its ports)")
            self.source = LiveSource.resuming(resume, config, self, clock, self.wall_clock, self.silence_clock)
            live = self.source.spec.live
            title = (f"fieldcal · {self.source.spec.procedure.name} · resuming {resume.directory.name} · "
                     f"{live.name} on {config.device.port.url}")
        elif resume is not None:
            self.source = SimSource.resuming(resume, self, self.speed, clock)
            title = (f"fieldcal · {self.source.spec.procedure.name} · resuming {resume.directory.name} · "
                     f"simulated MIMU, seed {self.source.spec.seed} · {_speed_words(self.speed)}")
        elif replay is not None:
            self.source = ReplaySource(replay, self, self.speed, clock)
            title = f"fieldcal · replay of {replay.directory.name} · {_speed_words(self.speed)}"
        elif spec is not None and spec.live is not None:
            from fieldcal.tui.live_source import LiveSource

            self.source = LiveSource(spec, config, self, session_dir, clock, wall_clock=self.wall_clock,
                                     silence_clock=self.silence_clock)
            title = f"fieldcal · {spec.procedure.name} · {spec.live.name} on {spec.live.url}"
        else:
            if spec is None:
                raise ValueError("FieldcalApp: give a RunSpec, or a session to replay")
            self.source = SimSource(spec, self, self.speed, session_dir, clock, hands=self.hands)
            title = (f"fieldcal · {spec.procedure.name} · simulated MIMU, seed {spec.seed} · "
                     f"{_speed_words(self.speed)}")
        self.spec = self.source.spec
        self.mode = self.source.mode
        settings = self.source.settings
        # The simulator's own hands place in a known time; a person's placement is a guess.
        hands_s = None if self.hands is None or self.mode != "sim" else \
            self.hands.handling_s + settings.stillness.window_s + settings.check_s
        self.view = RunView(self.spec.procedure, tolerance_deg=settings.tolerance_deg,
                            enter_factor=settings.stillness.enter_factor,
                            leave_factor=settings.stillness.leave_factor,
                            held_while_waiting=self.mode == "sim",
                            **({"placing_prior_s": hands_s} if hands_s is not None else {}))
        self.procedure_screen = ProcedureScreen(self.view, title, self.mode, clock=clock)

    def on_resize(self, event) -> None:
        self.set_class(event.size.width < MIN_COLUMNS or event.size.height < MIN_ROWS, "-too-small")

    def on_mount(self) -> None:
        if self.source is None:
            self._ask_setup(self.setup[0])
        else:
            self._begin()

    def _begin(self) -> None:
        self.push_screen(self.procedure_screen)  # (a default screen would not load its CSS_PATH)
        self.run_worker(self._run_source, thread=True, name="sample source", exit_on_error=False)

    def _ask_setup(self, initial, error: str = "") -> None:
        from fieldcal.tui.screens.setup import SetupScreen

        sessions = self.setup[2] if len(self.setup) > 2 else None
        screen = SetupScreen(initial, sessions=sessions)
        self.push_screen(screen, callback=lambda choice: self._chosen(screen, choice))
        if error:
            self.call_after_refresh(screen.set_error, error)

    def _chosen(self, screen, choice) -> None:
        if choice is None:
            self.exit(1)
            return
        from fieldcal.tui.screens.setup import ResumeChoice

        if isinstance(choice, ResumeChoice):
            self._resume_chosen(screen, choice)
            return
        config, procedure = screen.resolved
        self.product_spec = screen.product_spec  # the spec field's (the command line's --spec shown there)
        try:
            spec, session_dir, speed = self.setup[1](config, procedure, choice)
            self.speed = float(speed)
            self._prepare(spec, session_dir, None, config)
        except ValueError as exc:
            self._ask_setup(choice, str(exc).splitlines()[0])
            return
        self._begin()

    def _resume_chosen(self, screen, choice) -> None:
        try:
            chosen = screen.resolved[0] if choice.live and screen.resolved is not None else None
            speed, config, record = self.setup[3](choice.session, chosen)
            self.speed = float(speed)
            self._prepare(None, None, None, config, resume=record)
        except ValueError as exc:
            self._ask_setup(self.setup[0], str(exc).splitlines()[0])
            return
        self._begin()

    def _run_source(self) -> None:
        from textual.worker import get_current_worker

        worker = get_current_worker()
        self.source.run(cancelled=lambda: worker.is_cancelled)

    # --- the source's Sink (called on the worker thread) -----------------------------------

    def update(self, items: tuple, telemetry: Telemetry) -> None:
        self.post_message(RunItems(items, telemetry) if items else RunTelemetry(telemetry))

    def finished(self, outcome: Outcome) -> None:
        self.post_message(RunFinished(outcome))

    # --- messages (UI thread) ---------------------------------------------------------------

    def on_run_items(self, message: RunItems) -> None:
        self.events.extend(i for i in message.items if isinstance(i, ev.Event))
        self.telemetry = message.telemetry
        self.procedure_screen.add_items(message.items, message.telemetry)
        if self.mode != "replay" and any(isinstance(i, STEP_ENDS) for i in message.items):
            self.bell()  # the operator's turn (the banner says what next): heard from across the bench

    def on_run_telemetry(self, message: RunTelemetry) -> None:
        self.telemetry = message.telemetry
        self.procedure_screen.set_telemetry(message.telemetry)

    def on_run_finished(self, message: RunFinished) -> None:
        self.outcome = message.outcome
        self.procedure_screen.finished(message.outcome.status)
        self.show_results()

    # --- actions ------------------------------------------------------------------------------

    def send_command(self, name: str) -> None:
        if self.outcome is None and self.source is not None:
            self.source.send(name)

    def show_results(self) -> None:
        if self.outcome is not None and not isinstance(self.screen, ResultsScreen):
            tiles = zip((p.id for p in self.spec.procedure.positions), self.view.tiles)
            skipped, not_done = [], []
            for ident, state in tiles:
                (skipped if state == SKIPPED else not_done if state != DONE else []).append(ident)
            results = ResultsScreen(self.outcome, skipped, not_done, self.product_spec)
            self.verdict = results.verdict
            self.push_screen(results)

    def action_help(self) -> None:
        if not isinstance(self.screen, HelpScreen):
            self.push_screen(HelpScreen(self.mode))

    def running(self) -> bool:
        """A run is under way (prepared and not ended): quitting now would cut it short."""
        return self.source is not None and self.outcome is None and self.mode != "replay"

    async def action_request_quit(self) -> None:
        """ctrl+q, ctrl+c: mid-run, the procedure screen (brought back from over it) asks first
        and says what quitting would lose; otherwise quit at once."""
        if not self.running():
            await self.action_quit()
            return
        while self.screen is not self.procedure_screen and len(self.screen_stack) > 1:
            self.pop_screen()  # (the help, or the results of an ended run: not here mid-run)
        await self.procedure_screen.action_ask("quit")

    def resume_prospect(self) -> str:
        """What quitting now leaves to resume, in the operator's words (the source knows)."""
        return self.source.resume_prospect() if self.source is not None else ""

    async def action_quit(self) -> None:
        if self.source is not None:
            self.source.stop()
        code = self.return_code_for(self.outcome)
        if code == 0 and self.verdict is not None and not self.verdict.passed:
            from fieldcal.exit_status import EXIT_FAILED_SPEC
            code = EXIT_FAILED_SPEC
        self.exit(code)

    @staticmethod
    def return_code_for(outcome: Outcome | None) -> int:
        if outcome is None or outcome.status != "completed":
            return 1
        return 0 if outcome.solved and not outcome.unit.failures and outcome.identical is not False else 1


def run_tui(spec, speed: float, session_dir: Path | None, replay: RunRecord | None, config=None,
            setup=None, resume: RunRecord | None = None, product_spec=None) -> int:
    """Run the terminal UI until the operator quits; the exit status (0: calibrated).

    ``spec``: the run (procedure, station, seed, ...), simulated or on a real device (with its
    ``config``); ignored with ``replay`` (the session says what it was). ``speed``: sample time
    per wall time, 0 = as fast as possible. ``session_dir``: where to capture the session (None:
    no capture). ``replay``: a session (its ``RunRecord``) to replay through the same screens.
    ``setup``: open the setup screen first (see ``FieldcalApp``). ``resume``: continue this
    unfinished simulated session instead (see ``FieldcalApp``). ``product_spec``: PASS/FAIL
    against it on the results screen; exit status 3 when a check fails.
    """
    if replay is None and resume is None and session_dir is not None and Path(session_dir).exists() \
            and any(Path(session_dir).iterdir()):
        raise ValueError(f"{session_dir}: already exists and is not empty (a new session needs a "
                         "new directory)")
    app = FieldcalApp(spec, speed, session_dir, replay, config=config, setup=setup, resume=resume,
                      product_spec=product_spec)
    code = app.run()
    if app.source is None:  # quit on the setup screen
        return 1
    app.source.stop()
    app.source.done.wait(10.0)  # the session is closed by the worker thread
    outcome = app.source.outcome
    if outcome is not None:
        if outcome.session is not None:
            print(f"session: {outcome.session}")
        if outcome.parameters is not None:
            print(f"parameter file: {outcome.parameters}")
        if outcome.message:
            print(outcome.message)
    return 1 if code is None else code
