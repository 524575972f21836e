"""What the procedure screen shows, folded from engine events and telemetry (no Textual here).

``RunView.apply(item)`` takes an engine event or a source ``Note`` and returns the log line for
it, if any; ``RunView.telemetry`` is the latest snapshot. The dwell and turn-averaging progress
move with sample time between the engine's 10 s progress events: a bar anchored at the event
that started (or re-synchronised) it, advanced by the telemetry's sample time.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

from fieldcal.procedure import engine as en
from fieldcal.procedure.engine import skipped_to_return_to
from fieldcal.procedure import events as ev
from fieldcal.procedure.positions import Procedure, position_words
from fieldcal.run.progress import describe
from fieldcal.run.timetogo import TimeToGo
from fieldcal.tui.guidance import names_heading, placement
from fieldcal.tui.readings import Telemetry
from fieldcal.tui.source import Note, ResumeNote

TODO, ACTIVE, DONE, SKIPPED, WRONG = "todo", "active", "done", "skipped", "wrong"
# Each tile's state as a symbol too, for a monochrome or colour-blind operator.
SYMBOLS = {DONE: "✓", SKIPPED: "–", ACTIVE: "▶", WRONG: "▶", TODO: "·"}
PLACING_GUESS_S = 30.0  # an operator's placement, until the run has timed one
# The banner's styles (its CSS classes) that only say how the run goes: "wait" (hands off,
# checking, carrying) and "run" (dwelling, the table's rate steps). The procedure screen may show
# a change among them a moment late (its display rate); the others at once: "act" asks the
# operator for something, "bad" and "warn" report a fault, "ok" the end.
PROGRESS_STYLES = frozenset({"wait", "run"})
# Events that report a fault, shown at once whatever the banner then says (a bump's motion leaves
# the same "hands off" banner as a placement does); and a source's "ERROR: ..." note (a table
# that failed to turn: the operator skips or aborts).
FAULT_EVENTS = (ev.MotionDetected, ev.WrongOrientation, ev.Aborted)


def clock_text(seconds: float) -> str:
    """Elapsed time as a clock: 4:05, 1:02:03."""
    s = max(0, int(seconds))
    h, m, sec = s // 3600, s // 60 % 60, s % 60
    return f"{h}:{m:02d}:{sec:02d}" if h else f"{m}:{sec:02d}"


def duration_words(seconds: float) -> str:
    """A remaining time as the operator says it: 40 s, 12 min, 1 h 05 min."""
    s = max(0.0, seconds)
    if s < 60:
        return f"{s:.0f} s"
    minutes = round(s / 60)
    return f"{minutes} min" if minutes < 60 else f"{minutes // 60} h {minutes % 60:02d} min"


def rate_step_s(procedure: Procedure, index: int = 0) -> float:
    """One rate step (one sign) of the position at ``index``: ramp, settle and the whole turns
    averaged; 0 for a position without one."""
    r = procedure.rate_step_at(index)
    return 0.0 if r is None else r.ramp_s + r.settle_s + r.turns * 360.0 / r.rate_deg_s


def job_duration_s(procedure: Procedure, placing_s: float = PLACING_GUESS_S) -> float:
    """The whole job as the setup screen sums it: a placement, the dwell and both rate steps
    (each as ``rate_step_s``) per position."""
    return sum(placing_s + procedure.dwell_s + 2 * rate_step_s(procedure, i) for i in range(len(procedure.positions)))


@dataclass
class Progress:
    """An average that accumulates while still: total, done at an anchor, running or not."""

    total: float = 0.0
    base: float = 0.0
    anchor: float | None = None  # sample time from which it runs; None when not running
    complete: bool = False

    def done(self, t: float) -> float:
        if self.complete:
            return self.total
        if self.anchor is None:
            return self.base
        return max(0.0, min(self.total, self.base + t - self.anchor))

    def start(self, t: float, total: float | None = None, keep: bool = False) -> None:
        if total is not None:
            self.total = total
        self.base = self.base if keep else 0.0
        self.anchor, self.complete = t, False

    def sync(self, t: float, done: float) -> None:
        self.base, self.anchor = done, t

    def interrupt(self, t: float, restart: bool) -> None:
        self.base = 0.0 if restart else self.done(t)
        self.anchor = None

    def finish(self) -> None:
        self.complete, self.anchor = True, None


@dataclass
class RunView:
    procedure: Procedure
    tolerance_deg: float = 15.0
    enter_factor: float = 2.0
    leave_factor: float = 3.0
    tiles: list[str] = field(default_factory=list)
    step: int = 0
    telemetry: Telemetry | None = None
    dwell: Progress = field(default_factory=Progress)
    turns: Progress = field(default_factory=Progress)
    table_rate: float = 0.0  # commanded, °/s
    table_state: str = "stopped"  # stopped, ramping, steady, disturbed, stopping
    wrong: str | None = None  # the engine's message while the unit is misplaced
    restarts: int = 0  # dwells restarted by motion in this step
    restarts_total: int = 0
    finished: str | None = None  # outcome status once the run has ended
    last_t: float = 0.0
    placing_s: list[float] = field(default_factory=list)  # each placement: step start to still
    step_t0: float = 0.0  # when the current step started (sample time)
    placed: bool = False  # the current step's unit has been found still in place
    rates_done: int = 0  # rate steps (±) completed in the current step
    held_while_waiting: bool = False  # the source stops sampling while it waits (the simulator)
    carry_from: int | None = None  # r pressed: the simulator carries the unit, from this many samples
    unit_at: object | None = None  # the Position the unit was last found still in
    looks_like: tuple[int, ...] = ()  # a misplaced unit: the ids of the positions it looks like
    alike: tuple[int, ...] = ()  # any order: positions gravity cannot tell from the one taken
    resumed: ResumeNote | None = None  # a resumed run, until its first unit is placed
    # "elapsed" never goes back: sample time the run's clock went back by (a resume continues
    # from its last completed step, not from where it was quit) is added to it.
    elapsed_offset: float = 0.0
    # An operator's placement until the run has timed one: a person's guess, or the configured
    # hands' time when the simulator places the unit by itself.
    placing_prior_s: float = PLACING_GUESS_S
    time_to_go: TimeToGo | None = None
    faults: int = 0  # fault events and error notes so far (FAULT_EVENTS): each is shown at once
    _telemetry_t: float | None = None

    def __post_init__(self) -> None:
        if not self.tiles:
            self.tiles = [TODO] * len(self.procedure.positions)
        self.dwell.total = self.procedure.dwell_s
        if self.time_to_go is None:
            self.time_to_go = TimeToGo(self.procedure, self.placing_prior_s)

    @property
    def total_steps(self) -> int:
        return len(self.procedure.positions)

    @property
    def t(self) -> float:
        return self.telemetry.t if self.telemetry is not None else self.last_t

    @property
    def elapsed(self) -> float:
        """The run's time so far, as the operator lived it: it never goes back."""
        return self.t + self.elapsed_offset

    @property
    def phase(self) -> str:
        return self.telemetry.phase if self.telemetry is not None else en.PLACE

    @property
    def position(self):
        return self.procedure.positions[min(self.step, self.total_steps - 1)]

    def apply(self, item) -> str | None:
        """Fold one event or note in; the log line for it (None if it has none)."""
        self.last_t = max(self.last_t, item.t)
        if isinstance(item, ResumeNote):  # (also mid-run: a power-cycled unit's steps are done again)
            self.resumed = item
            if item.elapsed_s is not None:
                self.elapsed_offset = max(self.elapsed_offset, item.elapsed_s - item.t)
            self.tiles = [DONE if step in item.done else SKIPPED if step in item.skipped else TODO
                          for step in range(self.total_steps)]
            self.time_to_go.resumed(item.done, item.skipped)
        if isinstance(item, FAULT_EVENTS) or (isinstance(item, Note) and item.text.startswith("ERROR")):
            self.faults += 1
        if isinstance(item, Note):
            return f"[{item.t:7.1f} s] {item.text}"
        self._fold(item)
        self.time_to_go.apply(item)
        text = describe(item)
        if text is None:
            return None
        return f"[{item.t:7.1f} s] {text}"

    def _fold(self, e: ev.Event) -> None:
        if isinstance(e, (ev.StepStarted, ev.StepComplete, ev.StepSkipped, ev.ProcedureComplete, ev.Aborted)) \
                and not self.table_rate:
            self.table_state = "stopped"  # the engine stopped it before any of these
        if isinstance(e, ev.WaitingForStillness):
            self.carrying = False
        if isinstance(e, ev.StepStarted):
            self.step = e.step
            # A step left unfinished (going back to a skipped one) is to do again.
            self.tiles = [TODO if s in (ACTIVE, WRONG) else s for s in self.tiles]
            self.tiles[e.step] = ACTIVE
            self.dwell, self.turns = Progress(total=self.procedure.dwell_s), Progress()
            self.step_t0, self.placed, self.rates_done = e.t, False, 0
            self.wrong, self.restarts, self.carrying, self.alike = None, 0, False, ()
        elif isinstance(e, ev.PositionRecognised):  # any order: the unit is in this one
            self.tiles = [TODO if s in (ACTIVE, WRONG) else s for s in self.tiles]
            self.step, self.tiles[e.step] = e.step, ACTIVE
            self.alike = e.alike if not e.chosen else ()
        elif isinstance(e, ev.WrongOrientation):
            self.wrong, self.looks_like = e.message, e.looks_like
            self.tiles[self.step] = WRONG
        elif isinstance(e, ev.Still):
            self.wrong, self.resumed = None, None
            self.tiles[self.step] = ACTIVE
            if not self.placed:
                self.placing_s.append(e.t - self.step_t0)
                self.placed = True
            self.unit_at = self.position
            self.dwell.start(e.t, keep=self.dwell.base > 0)
        elif isinstance(e, ev.DwellProgress):
            self.dwell.sync(e.t, e.done_s)
        elif isinstance(e, ev.MotionDetected):
            if e.phase == "dwell":
                self.dwell.interrupt(e.t, e.restarted)
                self.restarts += e.restarted
                self.restarts_total += e.restarted
            elif e.phase == "rate":
                self.turns.interrupt(e.t, True)
                self.table_state = "disturbed"
        elif isinstance(e, ev.DwellComplete):
            self.dwell.finish()
            self.alike = ()  # the choice is taken while the dwell runs
        elif isinstance(e, ev.CommandTable):
            self.table_rate = e.rate_deg_s
            self.table_state = "ramping" if e.rate_deg_s else "stopping"
            if e.rate_deg_s:
                self.turns = Progress()
        elif isinstance(e, ev.RateSettled):
            self.table_state = "steady"
            self.turns.start(e.t, e.window_s)
        elif isinstance(e, ev.RateStepComplete):
            self.turns.finish()
            self.rates_done += 1
        elif isinstance(e, ev.StepComplete):
            self.tiles[e.step] = DONE
        elif isinstance(e, ev.StepSkipped):
            self.tiles[e.step] = SKIPPED
        elif isinstance(e, ev.ProcedureComplete):
            self.step = self.total_steps
        elif isinstance(e, ev.Aborted):
            self.dwell.interrupt(e.t, restart=False)
            self.turns.interrupt(e.t, restart=False)
            if self.step < self.total_steps and self.tiles[self.step] in (ACTIVE, WRONG):
                self.tiles[self.step] = TODO  # not done (the engine did not skip it)

    @property
    def carrying(self) -> bool:
        """The simulator is carrying the unit into place (r pressed)."""
        return self.carry_from is not None

    @carrying.setter
    def carrying(self, value: bool) -> None:
        self.carry_from = (self.telemetry.samples if self.telemetry is not None else 0) if value else None

    def set_telemetry(self, telemetry: Telemetry) -> None:
        if self._telemetry_t is not None and telemetry.t < self._telemetry_t:
            self.elapsed_offset += self._telemetry_t - telemetry.t
        self._telemetry_t = telemetry.t
        self.telemetry = telemetry
        if telemetry.phase != en.PLACE:
            self.carrying = False

    def stale_reason(self) -> str | None:
        """Why the readings are not current, if they are not: they stay on screen, dimmed."""
        if self.finished is not None:
            return "the run has ended"
        tel = self.telemetry
        if tel is not None and tel.silent_s is not None:
            return f"no samples for {tel.silent_s:.0f} s" if tel.silent_s >= 1 else "no samples"
        if self.carrying and tel is not None and tel.samples == self.carry_from:
            return "the simulator is moving the unit"  # until its first samples come
        if self.held_while_waiting and tel is not None and tel.waiting:
            return "the simulator waits for r"
        return None

    # --- the whole job -------------------------------------------------------------------

    def rate_step_s(self, step: int | None = None) -> float:
        """One rate step (one sign) of a step (default: the current one): ramp, settle and the
        whole turns averaged; 0 for a position without one."""
        return rate_step_s(self.procedure, min(self.step if step is None else step, self.total_steps - 1))

    def remaining_s(self) -> float:
        """Sample time the open steps still need (``fieldcal.run.timetogo``): a placement, a
        dwell and the rate steps each, from the procedure until this run has timed them, less
        what the step under way has done."""
        if self.finished is not None or self.step >= self.total_steps:
            return 0.0
        return self.time_to_go.remaining_s(self.t)

    def job_text(self) -> str:
        """Counts beside the tiles' symbols (the legend), elapsed and remaining time."""
        n = {state: self.tiles.count(state) for state in (DONE, SKIPPED, TODO)}
        running = self.finished is None and self.step < self.total_steps
        legend = (f"✓{n[DONE]} done  –{n[SKIPPED]} skipped  {'▶ now  ' if running else ''}"
                  f"·{n[TODO]} to do   ")
        if not running:
            return f"{legend}{clock_text(self.elapsed)} in all"
        return f"{legend}{clock_text(self.elapsed)} elapsed, ≈{duration_words(self.remaining_s())} to go"

    def unskip_target(self) -> int | None:
        """The step that going back (unskip) returns to, as the engine chooses it."""
        if self.finished is not None or self.step >= self.total_steps:
            return None
        return skipped_to_return_to({i for i, s in enumerate(self.tiles) if s == SKIPPED}, self.step)

    def work_words(self) -> str:
        """The run's work so far, as quitting or aborting would cost it: "7 of 18 positions done
        in 35 min"."""
        done = self.tiles.count(DONE)
        return (f"{done} of {self.total_steps} position{'' if self.total_steps == 1 else 's'} done "
                f"in {duration_words(self.elapsed)}")

    def step_work_words(self) -> str | None:
        """What the current step has measured, which redo, skip and going back drop: "80 s of
        its 200 s dwell and 1 of 2 rate steps"; None before anything is measured."""
        if self.step >= self.total_steps or not self.placed:
            return None
        parts = []
        dwell = self.dwell.done(self.t)
        if dwell >= 1:
            parts.append(f"{dwell:.0f} s of its {self.dwell.total:g} s dwell")
        if self.rates_done:
            parts.append(f"{self.rates_done} of 2 rate steps")
        return " and ".join(parts) or None

    def confirmation(self, action: str, running: bool = True, resume: str = "") -> str | None:
        """The question to ask before ``action`` ("skip", "abort", "unskip", "redo", "quit"), in
        words that say what it would lose, or None when it loses nothing and needs no
        confirmation. ``resume``: what a resume of the run could do (the source knows), said
        with the quit question."""
        if self.finished is not None or not running or self.step >= self.total_steps:
            return None
        pid = self.position.id
        begun = self.phase not in (en.PLACE, en.DONE)
        measured = self.step_work_words()
        if action == "abort":
            return f"ABORT the run? {self.work_words()}; it ends for good, no resume (the session is kept)."
        if action == "quit":
            return f"Quit mid-run? {self.work_words()}. {resume}".rstrip()
        if action == "skip":
            lost = f" {measured[0].upper()}{measured[1:]} would be dropped." if measured else ""
            others = [i for i, s in enumerate(self.tiles) if i != self.step and s in (TODO, ACTIVE, WRONG)]
            if not others:
                return f"Skip position {pid}, the last one? The run then ends.{lost}"
            return f"Skip position {pid}?{lost} (u goes back to it)"
        if action == "redo":
            lost = f"{measured} would be lost" if measured else "nothing of it is measured yet"
            return f"Redo position {pid} from the placement? {lost[0].upper()}{lost[1:]}."
        if action == "unskip" and begun:
            back = self.unskip_target()
            back_id = self.procedure.positions[back].id if back is not None else "?"
            lost = f": {measured}" if measured else ""
            return f"Back to position {back_id}? Position {pid}'s progress is lost{lost}."
        return None

    @staticmethod
    def verb(action: str) -> str:
        return {"unskip": "go back"}.get(action, action)

    # --- text for the screen -------------------------------------------------------------

    def step_text(self) -> str:
        if self.step >= self.total_steps:
            return f"all {self.total_steps} steps done"
        p = self.position
        words = position_words(p)
        if p.description and not names_heading(p.description):  # "y-down": and its heading
            words += f" ({position_words(dataclasses.replace(p, description=''))})"
        return f"step {self.step + 1} of {self.total_steps} · position {p.id}: {words}"

    def choice_text(self) -> str:
        """The question when gravity cannot tell the remaining positions apart: which one it is."""
        by_id = {q.id: q for q in self.procedure.positions}
        options = " · ".join(f"{n}: position {i} ({position_words(by_id[i])})"
                             for n, i in enumerate(self.alike, start=1))
        return (f"Positions {', '.join(map(str, self.alike))} look the same to gravity; taken as position "
                f"{self.position.id}. Which is it? {options}")

    def banner(self, sim: bool) -> tuple[str, str]:
        """(instruction for the operator, style class)."""
        if self.finished is not None:
            return {"completed": ("Procedure complete: see the results (v)", "ok"),
                    "aborted": ("Aborted: the session is kept", "bad"),
                    "error": ("Stopped by an error: see the log", "bad"),
                    "incomplete": ("The capture ends here", "warn"),
                    "stopped": ("Stopped", "warn")}.get(self.finished, (self.finished, "warn"))
        phase = self.phase
        p = self.position
        tel = self.telemetry
        if tel is not None and tel.silent_s is not None:
            paused = "; the dwell is paused" if phase in (en.DWELL, en.RATE_AVERAGE, en.RATE_WAIT) else ""
            return (f"NO SAMPLES from the device for {tel.silent_s:.0f} s: check its cable and power"
                    f"{paused}; the readings shown are old", "bad")
        if phase == en.PLACE and self.carrying:
            return f"The simulator is carrying the unit into position {p.id}: hands off", "wait"
        if phase == en.PLACE:
            move = placement(self.unit_at, p)
            text = f"Position {p.id}: {move.text}" + ("; r: the simulator does it" if sim else ", then press r")
            if self.procedure.any_order:  # the station recognises the position: no key
                left = sum(s in (TODO, ACTIVE, WRONG) for s in self.tiles)
                text = (f"Any of the {left} remaining positions, e.g. position {p.id}: {move.text}; "
                        + ("r: the simulator does it" if sim else "taken once still, no key"))
            if move.heading_only and self.unit_at is not None:
                text += "\nOnly the heading changes, which the check cannot see: check it by eye"
            if self.resumed is not None:
                return f"{self.resumed.banner}\n{text}", "warn" if self.resumed.warn else "act"
            return text, "act"
        if phase == en.WRONG and self.procedure.any_order and self.wrong:
            return f"NO REMAINING POSITION: {self.wrong}", "bad"
        if phase == en.WRONG:
            by_id = {q.id: q for q in self.procedure.positions}
            seen = by_id.get(self.looks_like[0]) if self.looks_like else None
            move = placement(seen, p) if seen is not None else None
            text = (f"WRONG POSITION: it looks like position {seen.id}; {move.text}" if move else
                    f"WRONG POSITION: position {p.id} is {position_words(p)}")
            how = "r: the simulator corrects it" if sim else "checked again once still"
            return f"{text}; {how}", "bad"
        if phase == en.SETTLING:
            return "Hands off: waiting for the unit to be still", "wait"
        if phase == en.CHECKING:
            return "Still: checking the orientation", "wait"
        if phase == en.DWELL and self.alike:
            return f"Dwelling: keep the unit still\n{self.choice_text()}", "act"
        if phase == en.DWELL:
            return "Dwelling: keep the unit still", "run"
        if phase == en.RATE_WAIT:
            return f"Table turning to {self.table_rate:+.1f} °/s: waiting until steady", "run"
        if phase == en.RATE_AVERAGE:
            return f"Averaging whole turns at {self.table_rate:+.1f} °/s", "run"
        if phase == en.DONE:
            return "Procedure complete: solving", "ok"
        if phase == en.ABORTED:
            return "Aborted: the session is kept", "bad"
        return phase, "wait"
