"""The procedure screen: tiles, step, instruction, cube, live panel and the event log."""
from __future__ import annotations

import time
from typing import ClassVar, NamedTuple

from textual import events
from textual.app import ComposeResult
from textual.binding import Binding, BindingType
from textual.containers import Horizontal
from textual.screen import Screen
from textual.timer import Timer
from textual.widgets import Footer, Static

from fieldcal.procedure.engine import PLACE
from fieldcal.tui.widgets.cube import top_view
from fieldcal.tui.widgets.eventlog import EventLog
from fieldcal.tui.widgets.live import LivePanel
from fieldcal.tui.widgets.plan import PlanPanel
from fieldcal.tui.widgets.shown import show
from fieldcal.tui.readings import Telemetry
from fieldcal.tui.widgets.tiles import PositionTiles
from fieldcal.tui.widgets.toosmall import TooSmall
from fieldcal.tui.view import PROGRESS_STYLES, RunView

OPERATOR_ACTIONS = ("ready", "redo", "skip", "abort", "unskip")
SIM_ACTIONS = ("bump", "misplace")
QUIT_KEYS = ("ctrl+q", "ctrl+c")  # the app's: they ask as q does, and answer its question
BIG = (110, 34)  # columns and rows from which the cube and the live bars grow
# Pressed again: confirmed. Redo is on o, away from s and a (a slip between neighbours asks anyway).
CONFIRM_KEYS = {"skip": "s", "abort": "a", "quit": "q", "unskip": "u", "redo": "o"}
# Readings, bars, the log and a banner that only says how the run goes (settling, dwelling, the
# table: view.PROGRESS_STYLES) are repainted at most this often (wall clock): a person reads no
# faster, and each repaint costs a re-layout and re-render of the screen. A new step, the
# operator's turn, a banner that asks for something or reports a fault, a fault event (motion, a
# wrong position, an error), the end of the run and the keys' own effects are shown at once.
DISPLAY_S = 0.25


class Turn(NamedTuple):
    """What the operator acts on or must know of at once (the screen shows a change of it at once)."""

    step: int
    waiting: bool  # the run waits for the operator
    asks: tuple[str, str] | None  # the banner when it asks for something or reports a fault
    faults: int  # fault events so far (view.faults)

    def news_since(self, painted: Turn | None) -> bool:
        """Whether this turn differs from the one ``painted`` in what must be shown at once. The
        end of the operator's turn alone is not: the key that ended it showed its effect (the
        simulator's carry), and a banner that asked changes with it (``asks``)."""
        if painted is None:
            return True
        return (self.step != painted.step or (self.waiting and not painted.waiting)
                or self.asks != painted.asks or self.faults != painted.faults)


class ProcedureScreen(Screen):
    CSS_PATH = "procedure.tcss"
    BINDINGS: ClassVar[list[BindingType]] = [
        Binding("r", "command('ready')", "ready"),
        Binding("s", "ask('skip')", "skip"),
        Binding("u", "ask('unskip')", "back"),
        Binding("o", "ask('redo')", "redo"),
        Binding("a", "ask('abort')", "abort"),
        Binding("b", "command('bump')", "bump"),
        Binding("w", "command('misplace')", "misplace", show=False),
        Binding("v", "results", "results"),
        Binding("q", "ask('quit')", "quit"),
        # Which of positions gravity cannot tell apart the unit is in (the banner lists them).
        *(Binding(str(n), f"choose({n})", "which", show=False) for n in range(1, 10)),
    ]

    def __init__(self, view: RunView, title: str, mode: str, clock=time.monotonic) -> None:
        """``clock``: the wall clock the display rate is counted on (the app's)."""
        super().__init__()
        self.clock = clock
        self._painted_at = -float("inf")  # the clock at the last repaint
        self._painted_turn: Turn | None = None  # and the operator's turn it showed
        self._repaint_timer: Timer | None = None  # the repaint put off to the end of DISPLAY_S
        self.view = view
        self.title_text = title
        self.mode = mode  # "sim" or "replay"
        self._shown_step: tuple[int, bool] | None = None  # what the cube shows: (step, big)
        self._can_go_back = False
        self.pending: str | None = None  # the action waiting for the operator's confirmation
        # Log lines and items not yet on the widgets (before the screen is mounted; see _showing)
        self._unshown: list = []
        self._unfed: list = []

    def compose(self) -> ComposeResult:
        yield Static(self.title_text, id="title")
        yield PositionTiles([p.id for p in self.view.procedure.positions], id="tiles")
        yield Static("", id="job")
        yield Static("", id="step")
        yield Static("", id="banner")
        yield Static("", id="confirm")  # a question, in the banner's place while it is asked
        if self.view.procedure.targets:  # a planned procedure: time left, σ against its targets
            yield PlanPanel(id="plan")
        with Horizontal(id="body"):
            yield Static("", id="cube")
            yield LivePanel(id="live")
        yield EventLog(id="log", wrap=True, max_lines=5000, markup=False, min_width=20)
        yield Footer()
        yield TooSmall()

    def on_mount(self) -> None:
        # Found once: refresh_view runs several times a second during a run.
        self._job, self._step, self._banner, self._cube = (
            self.query_one(f"#{name}", Static) for name in ("job", "step", "banner", "cube"))
        self._tiles, self._live, self._log = (self.query_one(PositionTiles), self.query_one(LivePanel),
                                              self.query_one("#log", EventLog))
        self._plan = self.query(PlanPanel).first() if self.query(PlanPanel) else None
        self.query_one("#live").border_title = "live"
        self.query_one("#log").border_title = "events"
        self.query_one("#confirm").display = False
        self._show_items()

    def on_resize(self) -> None:
        """A big terminal gives its room to the cube and the live bars, not only to the log."""
        size = self.app.size
        big = size.width >= BIG[0] and size.height >= BIG[1]
        if big != self.has_class("big"):
            self.set_class(big, "big")
            self.refresh_view()

    # --- fed by the app ---------------------------------------------------------------------

    def add_items(self, items, telemetry: Telemetry) -> None:
        self.view.set_telemetry(telemetry)
        self._unshown.extend(line for item in items if (line := self.view.apply(item)) is not None)
        self._unfed.extend(items)
        self._repaint()

    def set_telemetry(self, telemetry: Telemetry) -> None:
        self.view.set_telemetry(telemetry)
        self._repaint()

    def finished(self, status: str) -> None:
        self.view.finished = status
        if self._showing():
            self._ask(None)
            self._show_items()
            self.refresh_bindings()

    def _showing(self) -> bool:
        """Whether the widgets are there to update: not before the screen is mounted, nor once the
        app is closing, when a run's last messages can still arrive (under load CI saw one find no
        PositionTiles). The view takes every item and reading either way; on_mount shows them."""
        return self.is_mounted and self.is_attached

    # --- the display rate -------------------------------------------------------------------

    def _banner_now(self) -> tuple[str, str]:
        return self.view.banner(sim=self.mode == "sim")

    def _turn(self, banner: tuple[str, str]) -> Turn:
        view, tel = self.view, self.view.telemetry
        return Turn(view.step, tel is not None and tel.waiting,
                    None if banner[1] in PROGRESS_STYLES else banner, view.faults)

    def _repaint(self) -> None:
        """Show what the view holds now if the operator's turn changed (Turn: they act on it,
        and tests wait for it) or DISPLAY_S has passed since the last repaint; else at the end
        of that period (a timer: the last readings and banner are always shown). Only the
        repaint waits: the view, the app's events and telemetry take every batch as it comes."""
        if not self._showing():
            return
        wait = self._painted_at + DISPLAY_S - self.clock()
        if wait <= 0 or self._turn(self._banner_now()).news_since(self._painted_turn):
            self._show_items()
        elif self._repaint_timer is None:
            self._repaint_timer = self.set_timer(wait, self._repaint_due, name="repaint")

    def _repaint_due(self) -> None:
        self._repaint_timer = None
        if self._showing():
            self._show_items()

    def _show_items(self) -> None:
        if self._repaint_timer is not None:
            self._repaint_timer.stop()
            self._repaint_timer = None
        if self._unshown:
            self._log.write_lines(self._unshown)
        if self._plan is not None:
            self._plan.feed(self._unfed)
        self._unshown, self._unfed = [], []
        self.refresh_view()

    def refresh_view(self) -> None:
        """Show the view: each widget only when its text changes, and a re-layout of the screen
        only for those whose height follows their text (the step, the banner, the cube)."""
        banner = self._banner_now()
        self._painted_at, self._painted_turn = self.clock(), self._turn(banner)
        view = self.view
        self._tiles.update(view.tiles)
        show(self._job, view.job_text(), fixed_size=True)  # one line (#job), changing every reading
        show(self._step, view.step_text())
        text, style = banner
        show(self._banner, text)
        self._banner.set_classes(style)
        big = self.has_class("big")
        if (view.step, big) != self._shown_step and view.step < view.total_steps:
            self._shown_step = (view.step, big)
            self._cube.update("\n".join(top_view(view.position, large=big)))
            self._cube.border_title = f"position {view.position.id}"
        self._live.update(view, bar_width=32 if big else 16)
        running = view.finished is None and view.step < view.total_steps
        if self._plan is not None:
            self._plan.show(view.remaining_s() if running else None)
        can_go_back = view.unskip_target() is not None
        if can_go_back != self._can_go_back:  # the footer offers u only when it can act
            self._can_go_back = can_go_back
            self.refresh_bindings()

    # --- keys -------------------------------------------------------------------------------

    def check_action(self, action: str, parameters: tuple[object, ...]) -> bool | None:
        if action == "choose":
            return self.mode != "replay" and 1 <= int(str(parameters[0])) <= len(self.view.alike)
        if action == "results":
            return self.view.finished is not None
        if action not in ("command", "ask") or parameters == ("quit",):
            return True
        if self.mode == "replay" or self.view.finished is not None:
            return False  # a replay applies the recorded actions; a finished run takes none
        if parameters and parameters[0] in SIM_ACTIONS:
            return self.mode == "sim"
        if parameters == ("unskip",):
            return self.view.unskip_target() is not None
        return True

    def action_command(self, name: str) -> None:
        view = self.view
        if name == "ready" and self.mode == "sim" and view.phase == PLACE and view.finished is None:
            view.carrying = True  # said at once: the carrying takes seconds of samples at 1×
            self.refresh_view()
        self.app.send_command(name)

    def action_choose(self, n: int) -> None:
        """The operator says the unit is in the n-th of the positions gravity cannot tell apart."""
        from fieldcal.tui.source import choose_command

        self.app.send_command(choose_command(self.view.alike[n - 1]))

    async def action_ask(self, name: str) -> None:
        """Abort, skip, redo, quit (and going back, when it drops a step begun) wait for a
        confirmation that says what they would lose: one slip of a finger must not cost the run."""
        if name == "quit" and self.pending == "quit":
            await self._do(name)  # ctrl+q (or ctrl+c) pressed again while its question is asked
            return
        resume = self.app.resume_prospect() if name == "quit" else ""
        question = self.view.confirmation(name, running=self.mode != "replay", resume=resume)
        if question is None:
            await self._do(name)
        else:
            key = CONFIRM_KEYS[name]
            self._ask(name, f"{question}  {key} or y: {self.view.verb(name)} · other key: no")

    def _ask(self, name: str | None, text: str = "") -> None:
        self.pending = name
        bar = self.query_one("#confirm", Static)
        bar.update(text)
        bar.display = name is not None
        self.query_one("#banner").display = name is None

    async def _do(self, name: str) -> None:
        if name == "quit":
            await self.app.action_quit()
        else:
            self.action_command(name)

    async def on_key(self, event: events.Key) -> None:
        """While a confirmation is asked, the next key answers it (and does nothing else)."""
        name = self.pending
        if name is None:
            return
        event.stop()
        event.prevent_default()
        self._ask(None)
        if event.key in (CONFIRM_KEYS[name], "y") or (name == "quit" and event.key in QUIT_KEYS):
            await self._do(name)

    def action_results(self) -> None:
        self.app.show_results()
