"""The terminal UI's side of a run: a conductor (``fieldcal.run.conductor``) whose operator is
the keys and whose subscriber is the screen.

A ``Source`` is both: it hands the conductor the operator's keys (commands on a queue) as moves,
and collects what the conductor reports into batches for a ``Sink``: log items plus a
``Telemetry`` snapshot at most every ``FLUSH_S`` of wall time (and whenever it waits for the
operator), and the final ``Outcome``. ``SimSource`` runs the in-process simulated bench,
``ReplaySource`` a captured session, ``fieldcal.tui.live_source.LiveSource`` a real device. The
loop, the session documents and the conclusion are the conductor's, the same as a headless
run's. Nothing here imports Textual, so a source can be driven directly in tests.

Pacing: sample time runs at ``speed`` times wall time (0: as fast as possible); keys pressed
while a chunk waits to be due are kept for after it. While the engine waits for the operator
(place the unit; a wrong placement), the simulated bench does not advance: the simulator stands
in for the operator's hands, so a run's samples depend only on the seed and the keys pressed,
never on how long the operator took. At speed 0 the same keys give, sample for sample, the
headless run of the same seed. Below speed 10 the simulator makes chunks of about 0.1 s of wall
time instead of 1 s (the carry into place and a bump too) so the display moves smoothly: the
same samples' statistics, summed in a different order, so the result equals the headless one
to rounding rather than bit for bit (the session still replays bit for bit).
"""
from __future__ import annotations

import queue
import threading
import time
import traceback
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import Protocol

from fieldcal.procedure import events as ev
from fieldcal.procedure.engine import PLACE, WAITING_FOR_OPERATOR, WRONG
from fieldcal.run.conductor import Act, Bump, Conductor, Operator, Place, Say, Subscriber
from fieldcal.run.operators import OperatorScript, ScriptedOperator, wrong_position
from fieldcal.run.outcome import Outcome, Status
from fieldcal.run.pacing import Pacer
from fieldcal.tui.readings import RecentSamples, Telemetry

__all__ = ["ABORT", "BUMP", "COMMANDS", "FLUSH_S", "MISPLACE", "QUIT", "READY", "REDO", "SKIP", "Mode",
           "Note", "Outcome", "ResumeNote", "Pacer", "ReplaySource", "SimSource", "Sink", "Source", "wrong_position"]

FLUSH_S = 0.1  # at most one UI update per this much wall time

# Operator commands (the keys); the engine's actions plus what the simulator's hands do.
READY, REDO, SKIP, ABORT, UNSKIP = ev.READY, ev.REDO, ev.SKIP, ev.ABORT, ev.UNSKIP
BUMP, MISPLACE, QUIT = "bump", "misplace", "quit"
COMMANDS = (READY, REDO, SKIP, ABORT, UNSKIP, BUMP, MISPLACE, QUIT)
CHOOSE_PREFIX = "choose:"  # and a position id: which of positions gravity cannot tell apart


def choose_command(position_id: int) -> str:
    return f"{CHOOSE_PREFIX}{position_id}"


def choice_moves(command: str) -> list:
    """The moves of a ``choose:ID`` command: the engine takes position ID for the dwell under way."""
    position_id = int(command.removeprefix(CHOOSE_PREFIX))
    return [Say(f"operator: the unit is in position {position_id}"), Act(ev.CHOOSE, position_id=position_id)]


class Mode(StrEnum):
    SIM = "sim"
    LIVE = "live"
    REPLAY = "replay"


@dataclass(frozen=True)
class Note:
    """A line for the operator's log that is not an engine event (keys, simulator, replay)."""

    t: float
    text: str


@dataclass(frozen=True)
class ResumeNote(Note):
    """Where a resumed run goes on: a log line, the banner's first line until the unit is placed
    (``warn``: completed steps are measured again), and the steps kept done and skipped."""

    banner: str = ""
    warn: bool = False
    done: tuple[int, ...] = ()
    skipped: tuple[int, ...] = ()
    elapsed_s: float | None = None  # the sample time the session had reached when it stopped


class Sink(Protocol):
    def update(self, items: tuple, telemetry: Telemetry) -> None: ...

    def finished(self, outcome: Outcome) -> None: ...


class Source(Operator, Subscriber):
    """The keys as the conductor's operator, the screen as its subscriber."""

    mode: Mode

    def __init__(self, spec, sink: Sink, speed: float, clock: Callable[[], float] = time.monotonic):
        self.spec = spec
        self.sink = sink
        self.clock = clock
        self.pacer = Pacer(speed, clock)
        self.settings = spec.engine_settings()
        self.recent = RecentSamples(self.settings)
        self.done = threading.Event()  # set when run() has returned
        self.conductor: Conductor | None = None
        self._commands: queue.Queue[str] = queue.Queue()
        self._deferred: deque[str] = deque()
        self._stop = threading.Event()
        self._cancelled: Callable[[], bool] = lambda: False
        self._items: list = []
        self._last_flush = -float("inf")
        self._waiting = False
        self.outcome: Outcome | None = None

    # --- called from the UI thread ----------------------------------------------------------

    def send(self, command: str) -> None:
        if command not in COMMANDS and not (command.startswith(CHOOSE_PREFIX)
                                            and command.removeprefix(CHOOSE_PREFIX).isdigit()):
            raise ValueError(f"command: expected one of {', '.join(COMMANDS)}, got {command!r}")
        self._commands.put(command)

    def stop(self) -> None:
        """Ask the source to stop (quit); the session is closed unstopped, so it can be resumed."""
        self._stop.set()
        self._commands.put(QUIT)

    # --- the worker thread ------------------------------------------------------------------

    def run(self, cancelled: Callable[[], bool] = lambda: False) -> Outcome:
        self._cancelled = cancelled
        try:
            self.conductor = self._conductor()
            self.outcome = self._ended(self.conductor.run())
        except Exception as exc:  # noqa: BLE001 -- shown to the operator instead of a crash
            message = "".join(traceback.format_exception_only(exc)).strip()
            self._items.append(Note(self._t(), f"ERROR: {message}"))
            self.outcome = Outcome(Status.ERROR, self.spec.procedure, message=message,
                                   session=self._session_after_error())
        finally:
            self._flush(force=True)
            if self.outcome is not None:
                self.sink.finished(self.outcome)
            self.done.set()
        return self.outcome

    def _conductor(self) -> Conductor:
        raise NotImplementedError

    def _ended(self, outcome: Outcome) -> Outcome:
        if outcome.status == Status.STOPPED:
            outcome.message = self._stopped_message()
        return outcome

    def _stopped_message(self) -> str:
        return "stopped before the end"

    def resume_prospect(self) -> str:
        """What a resume could continue if the run stopped now, for the quit question."""
        return ""

    def _session_after_error(self) -> Path | None:
        return None

    @property
    def stopping(self) -> bool:
        return self._stop.is_set() or self._cancelled()

    def _t(self) -> float:
        return self.conductor.engine.t if self.conductor is not None else 0.0

    def _next_command(self, wait: bool) -> str | None:
        """A pending command; with ``wait``, block until one comes (or the source is stopped)."""
        if self._deferred:
            return self._deferred.popleft()
        if not wait:
            try:
                return self._commands.get_nowait()
            except queue.Empty:
                return None
        self._waiting = True
        self._flush(force=True)
        try:
            while not self.stopping:
                try:
                    return self._commands.get(timeout=FLUSH_S)
                except queue.Empty:
                    continue
            return None
        finally:
            self._waiting = False
            self.pacer.hold()

    # --- as the operator ---------------------------------------------------------------------

    def pace(self, chunk, run: Conductor) -> bool:
        """Wait until the chunk's samples are due; keys pressed meanwhile are kept for later."""
        delay = self.pacer.delay(float(chunk.t[0]), float(chunk.t[-1]))
        deadline = self.clock() + delay
        while delay > 0 and not self.stopping:
            self._flush()
            try:
                command = self._commands.get(timeout=min(delay, FLUSH_S))
                if command == QUIT:
                    self._stop.set()
                    break
                self._deferred.append(command)
            except queue.Empty:
                pass
            delay = deadline - self.clock()
        return not self.stopping

    # --- as the subscriber -------------------------------------------------------------------

    def chunk(self, chunk, run: Conductor) -> None:
        self.recent.add(chunk)

    def event(self, e: ev.Event, run: Conductor) -> None:
        self._items.append(e)

    def note(self, text: str, run: Conductor) -> None:
        self._items.append(Note(run.engine.t, text))

    def tick(self, run: Conductor) -> None:
        self._flush()

    def _flush(self, force: bool = False) -> None:
        now = self.clock()
        if not force and now - self._last_flush < FLUSH_S:
            return
        self._last_flush = now
        items, self._items = tuple(self._items), []
        self.sink.update(items, self.telemetry())

    def telemetry(self) -> Telemetry:
        if self.conductor is None:
            return Telemetry(t=0.0, step=0, phase=PLACE, waiting=self._waiting, samples=0)
        e = self.conductor.engine
        up = e.position.up_body if e.step < len(e.procedure.positions) else None
        return Telemetry(t=e.t, step=e.step, phase=e.phase, waiting=self._waiting,
                         samples=self.conductor.samples, **self.recent.readings(up))


class SimSource(Source):
    """The simulated bench, moved by the operator's keys; captured like a headless run."""

    mode = Mode.SIM

    def __init__(self, spec, sink: Sink, speed: float, session_dir: Path | None,
                 clock: Callable[[], float] = time.monotonic, bench=None, resume=None,
                 hands: OperatorScript | None = None):
        """``resume``: the ``RunRecord`` of the unfinished session in ``session_dir`` to continue
        after its last completed step (see ``resuming``), not a new one. ``hands``: the simulator
        places the unit by itself at each step as the headless run's operator would (in a
        shuffled order, if the script says so and the procedure takes any order): no key."""
        super().__init__(spec, sink, speed, clock)
        self.hands = ScriptedOperator(hands, spec.procedure) if hands is not None else None
        self.session_dir = Path(session_dir) if session_dir is not None else None
        if resume is not None and self.session_dir is None:
            raise ValueError("resume: which session?")
        self.resume = resume
        self.recorder = None
        self.bench = bench if bench is not None else self._sim_bench(spec, speed)
        self.bump_times: list[float] = []  # sample time of each bump (OperatorScript.bump_at_s)

    @staticmethod
    def _sim_bench(spec, speed: float):
        from fieldcal.run.runner import SimulatedBench

        bench = SimulatedBench(spec)
        smooth = max(1, round(spec.rate_hz * FLUSH_S * speed))
        if speed <= 0 or smooth >= bench.chunk_n:
            return bench  # the headless run's chunks, so the same keys give the same samples
        bench.chunk_n = smooth  # chunks of about FLUSH_S wall time, so the display moves smoothly
        return SmoothHands(bench)

    @classmethod
    def resuming(cls, record, sink: Sink, speed: float,
                 clock: Callable[[], float] = time.monotonic) -> SimSource:
        """Continue the unfinished simulated session of ``record`` (its ``RunRecord``) after its
        last completed step, as ``fieldcal resume`` does headless: the run's spec is the
        session's, the bench's state that of the last completed step, and what follows is
        appended to the session."""
        if record.spec.live is not None:
            raise ValueError(f"{record.directory}: a live device's session; SimSource resumes simulated ones")
        return cls(record.spec, sink, speed, record.directory, clock, resume=record)

    def _metadata(self) -> dict:
        return self.spec.session_metadata("in-process", "tui")

    def _conductor(self) -> Conductor:
        from fieldcal.run.recorder import SessionRecorder

        if self.resume:
            return self._resumed_conductor()
        subscribers = [self]
        if self.session_dir is not None:
            self.recorder = SessionRecorder.create(self.session_dir, self._metadata())
            subscribers.insert(0, self.recorder)  # the session has each chunk before anyone reacts
        return Conductor(self.spec, self.bench, self, subscribers, session=self.session_dir,
                         settings=self.settings)

    def _resumed_conductor(self) -> Conductor:
        """The conductor after the session's last completed step (``fieldcal.run.resume``)."""
        from fieldcal.run.resume import resume_conductor

        conductor = resume_conductor(self.resume, self.bench, self, [self], settings=self.settings,
                                     attach=lambda recorder: setattr(self, "recorder", recorder))
        self.conductor = conductor
        done = len(self.resume.steps)
        self._items.append(ResumeNote(conductor.engine.t, f"resuming {self.session_dir.name} after {done} "
                                      f"completed step{'s' if done != 1 else ''}: place the unit for the next step",
                                      f"RESUMED after {done} completed step{'s' if done != 1 else ''}",
                                      done=tuple(conductor.engine.records), skipped=tuple(conductor.engine.skipped),
                                      elapsed_s=recorded_until(self.resume)))
        return conductor

    def _session_after_error(self) -> Path | None:
        return self.session_dir if self.recorder is not None else None

    def resume_prospect(self) -> str:
        if self.session_dir is None:
            return "Nothing is captured (no session directory): all of it is lost."
        return "The session is kept: a resume continues after the last completed step."

    def _stopped_message(self) -> str:
        if self.session_dir is None:
            return "stopped before the end"
        return ("stopped before the end; the session can be continued with "
                f"`fieldcal tui --resume {self.session_dir}` (or headless: `fieldcal resume {self.session_dir}`)")

    def _holds_for_keys(self, run: Conductor) -> bool:
        """Wait for a key, the bench standing still? (The simulator, while the engine waits for
        the operator's hands.)"""
        return run.engine.phase in WAITING_FOR_OPERATOR

    def observe(self, e: ev.Event, run: Conductor) -> None:
        if self.hands is not None:
            self.hands.observe(e, run)

    def next_moves(self, run: Conductor):
        placing = self.hands.next_moves(run) if self.hands is not None else []
        command = self._next_command(wait=not placing and self._holds_for_keys(run))
        if command == QUIT:
            self._stop.set()
        if self.stopping:
            return None
        return placing + ([] if command is None else self._moves(command, run))

    def _moves(self, command: str, run: Conductor) -> list:
        e = run.engine
        if command.startswith(CHOOSE_PREFIX):
            return choice_moves(command)
        if command in (READY, MISPLACE) and e.phase == PLACE:
            place = e.position if command == READY else wrong_position(e.procedure, e.step)
            where = f"position {place.id}" if place.id >= 0 else place.description
            return [Say(f"operator: ready; the simulator carries the unit to {where}"
                        f"{'' if command == READY else ' (the wrong one, on purpose)'}"),
                    Place(place.attitude), Act(ev.READY)]
        if command == READY and e.phase == WRONG:
            return [Say(f"operator: the simulator puts the unit in position {e.position.id} after all"),
                    Place(e.position.attitude)]
        if command in (READY, MISPLACE):
            return [Say(f"({command}: nothing to do while {_PHASE_WORDS.get(e.phase, e.phase)})")]
        if command in (REDO, SKIP, ABORT, UNSKIP):
            return [Say(f"operator: {command}"), Act(command)]
        self.bump_times.append(e.t)  # BUMP
        return [Say("operator: bump! (the simulator knocks the fixture)"), Bump()]


def recorded_until(reader) -> float | None:
    """The sample time a session's samples reach (its last chunk's last sample), None if it
    has none: the run went on past its last completed step, where a resume continues."""
    ends = [d["t_last"] for d in reader.documents("chunk") if isinstance(d.get("t_last"), (int, float))]
    return max(ends, default=None)


def _pieces(chunks, n: int) -> list:
    """The same samples in chunks of at most ``n``."""
    from drivers.chunk import SampleChunk

    out = []
    for c in chunks:
        for i in range(0, len(c), n):
            part = slice(i, i + n)
            out.append(SampleChunk(c.t[part], {k: v[part] for k, v in c.triads.items()},
                                   None if c.temperature is None else c.temperature[part],
                                   {k: v[part] for k, v in c.extras.items()}))
    return out


class SmoothHands:
    """The simulated bench, its hands' motions (the carry into place, a bump) in chunks as short
    as its others: at 1× a carry is seconds of samples, and the readings follow it as it
    happens instead of jumping once it is over. Everything else is the bench's own."""

    def __init__(self, bench):
        self.bench = bench

    def __getattr__(self, name: str):
        return getattr(self.bench, name)

    def move_to(self, nominal) -> list:
        return _pieces(self.bench.move_to(nominal), self.bench.chunk_n)

    def bump(self) -> list:
        return _pieces(self.bench.bump(), self.bench.chunk_n)


class ReplaySource(Source):
    """A captured session's chunks and actions, in recorded order, through the conductor."""

    mode = Mode.REPLAY

    def __init__(self, record, sink: Sink, speed: float,
                 clock: Callable[[], float] = time.monotonic):
        """``record``: the session's ``RunRecord`` (``fieldcal.run.runner.open_run``)."""
        from fieldcal.run.operators import ReplayOperator

        self.record = record
        self.directory = record.directory
        self.recorded = ReplayOperator(record)
        super().__init__(record.spec, sink, speed, clock)
        self.recorded.pacer = self.pacer  # a recorded resume re-anchors the pacing

    def send(self, command: str) -> None:
        """In a replay the recorded actions are applied; only quitting is up to the operator."""
        if command == QUIT:
            super().send(command)

    def _conductor(self) -> Conductor:
        from fieldcal.run.operators import NoBench

        return Conductor(self.spec, NoBench(), self, [self], settings=self.settings)

    def begin(self, run: Conductor) -> None:
        run.say(f"replaying {self.directory}: recorded samples and actions, keys ignored")

    def next_moves(self, run: Conductor):
        while (command := self._next_command(wait=False)) is not None:
            if command == QUIT:  # the only command a replay takes
                self._stop.set()
        if self.stopping:
            return None
        return self.recorded.next_moves(run)

    def _ended(self, outcome: Outcome) -> Outcome:
        from fieldcal.run.replay import finish_replay, later_resolves

        if self.stopping:  # quit: not the end of the capture
            return super()._ended(outcome)
        outcome = finish_replay(self.conductor, self.record, outcome)
        if outcome.comparison:
            self._items.append(Note(self.conductor.engine.t, outcome.comparison))
            for line in later_resolves(self.record):
                self._items.append(Note(self.conductor.engine.t, line))
        return outcome


_PHASE_WORDS = {"settling": "waiting for stillness", "checking": "checking the orientation",
                "dwell": "dwelling", "rate_wait": "the table settles", "rate_average": "averaging turns",
                "done": "finished", "aborted": "aborted", "wrong": "the unit is misplaced",
                "place": "placing"}
