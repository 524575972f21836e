"""The sample source behind the terminal UI: one thread owns the engine, the bench and the session.

A ``SimSource`` drives the procedure engine with the in-process simulated bench, the operator's
keys arriving as commands on a queue; a ``ReplaySource`` feeds a captured session's chunks and
actions through a fresh engine. Either runs in a Textual thread worker (``run()``) and reports
through a ``Sink``: a batch of log items plus a ``Telemetry`` snapshot at most every
``FLUSH_S`` of wall time (and whenever it stops to wait for the operator), and a final
``Outcome``. Nothing here imports Textual, so a source can be driven directly in tests.

Pacing: sample time runs at ``speed`` times wall time (0: as fast as possible). While the engine
waits for the operator (place the unit; a wrong placement), the simulated bench does not
advance: the simulator stands in for the operator's hands, so a run's samples depend only on the
seed and the keys pressed, never on how long the operator took. At speed 0 the same keys give,
sample for sample, the headless run of the same seed (``fieldcal.run.runner._drive``). Below speed
10 the simulator makes chunks of about 0.1 s of wall time instead of 1 s so the display moves
smoothly: the same samples' statistics, summed in a different order, so the result equals the
headless one to rounding rather than bit for bit (the session still replays bit for bit).
"""
from __future__ import annotations

import queue
import threading
import time
import traceback
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

from fieldcal.procedure import events as ev
from fieldcal.procedure.engine import ABORTED, DONE, PLACE, WRONG, Engine
from fieldcal.procedure.positions import Procedure
from fieldcal.tui.readings import RecentSamples, Telemetry

FLUSH_S = 0.1  # at most one UI update per this much wall time

# Operator commands (the keys); the engine's actions plus what the simulator's hands do.
READY, REDO, SKIP, ABORT, UNSKIP = ev.READY, ev.REDO, ev.SKIP, ev.ABORT, ev.UNSKIP
BUMP, MISPLACE, QUIT = "bump", "misplace", "quit"
COMMANDS = (READY, REDO, SKIP, ABORT, UNSKIP, BUMP, MISPLACE, QUIT)


@dataclass(frozen=True)
class Note:
    """A line for the operator's log that is not an engine event (keys, simulator, replay)."""

    t: float
    text: str


@dataclass
class Outcome:
    """How a run ended, and what it produced."""

    status: str  # "completed", "aborted", "stopped" (quit), "incomplete" (capture ended), "error"
    procedure: Procedure
    unit: object | None = None  # fieldcal.solvers.solve.UnitSolution
    truth: dict = field(default_factory=dict)  # triad -> true parameters (simulation)
    session: Path | None = None
    parameters: Path | None = None
    replay_of: Path | None = None
    identical: bool | None = None  # replay: the parameter file equals the recorded one
    completed: int = 0
    skipped: int = 0
    message: str = ""
    previous: object | None = None  # fieldcal.session.history.PreviousCalibration of the same unit

    @property
    def solved(self) -> bool:
        return self.unit is not None and bool(self.unit.solutions)


class Sink(Protocol):
    def update(self, items: tuple, telemetry: Telemetry) -> None: ...

    def finished(self, outcome: Outcome) -> None: ...


class Pacer:
    """Holds sample time to ``speed`` × wall time; re-anchored after every pause."""

    def __init__(self, speed: float, clock: Callable[[], float] = time.monotonic):
        if not speed >= 0:
            raise ValueError(f"speed: expected a number >= 0 (0 = as fast as possible), got {speed!r}")
        self.speed = float(speed)
        self.clock = clock
        self._anchor: tuple[float, float] | None = None  # (sample time, wall time)

    def hold(self) -> None:
        self._anchor = None

    def delay(self, t_first: float, t_last: float) -> float:
        """Seconds to wait before samples up to ``t_last`` are due (0 when unpaced)."""
        if self.speed <= 0:
            return 0.0
        now = self.clock()
        if self._anchor is None:
            self._anchor = (t_first, now)
        t0, wall0 = self._anchor
        return max(0.0, wall0 + (t_last - t0) / self.speed - now)


class Source:
    """What both sources share: commands in, batched log items and telemetry out."""

    def __init__(self, spec, sink: Sink, speed: float, clock: Callable[[], float] = time.monotonic):
        self.spec = spec
        self.sink = sink
        self.clock = clock
        self.pacer = Pacer(speed, clock)
        self.settings = spec.engine_settings()
        self.engine = Engine(spec.procedure, self.settings)
        self.recent = RecentSamples(self.settings)
        self.done = threading.Event()  # set when run() has returned
        self._commands: queue.Queue[str] = queue.Queue()
        self._deferred: deque[str] = deque()
        self._stop = threading.Event()
        self._cancelled: Callable[[], bool] = lambda: False
        self._items: list = []
        self._last_flush = -float("inf")
        self._samples = 0
        self._waiting = False
        self.outcome: Outcome | None = None

    # --- called from the UI thread ----------------------------------------------------------

    def send(self, command: str) -> None:
        if command not in COMMANDS:
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
            self._run()
            if self.outcome is None:
                self.outcome = self._stopped()
        except Exception as exc:  # noqa: BLE001 -- shown to the operator instead of a crash
            message = "".join(traceback.format_exception_only(exc)).strip()
            self._items.append(Note(self.engine.t, f"ERROR: {message}"))
            self.outcome = Outcome("error", self.spec.procedure, message=message,
                                   session=self._close_after_error())
        finally:
            self._flush(force=True)
            if self.outcome is not None:
                self.sink.finished(self.outcome)
            self.done.set()
        return self.outcome

    def _run(self) -> None:
        raise NotImplementedError

    def _stopped(self) -> Outcome:
        return Outcome("stopped", self.spec.procedure, completed=len(self.engine.records),
                       skipped=len(self.engine.skipped), message="stopped before the end")

    def _close_after_error(self) -> Path | None:
        """Close what can be closed; the session directory, if one was started."""
        return None

    @property
    def stopping(self) -> bool:
        return self._stop.is_set() or self._cancelled()

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

    def _pace(self, chunk) -> None:
        """Wait until the chunk's samples are due; keys pressed meanwhile are kept for later."""
        delay = self.pacer.delay(float(chunk.t[0]), float(chunk.t[-1]))
        deadline = self.clock() + delay
        while delay > 0 and not self.stopping:
            self._flush()
            try:
                command = self._commands.get(timeout=min(delay, FLUSH_S))
                if command == QUIT:
                    self._stop.set()
                    return
                self._deferred.append(command)
            except queue.Empty:
                pass
            delay = deadline - self.clock()

    def _note(self, text: str) -> None:
        self._items.append(Note(self.engine.t, text))

    def _flush(self, force: bool = False) -> None:
        now = self.clock()
        if not force and now - self._last_flush < FLUSH_S:
            return
        self._last_flush = now
        items, self._items = tuple(self._items), []
        self.sink.update(items, self.telemetry())

    def telemetry(self) -> Telemetry:
        e = self.engine
        up = e.position.up_body if e.step < len(e.procedure.positions) else None
        return Telemetry(t=e.t, step=e.step, phase=e.phase, waiting=self._waiting,
                         samples=self._samples, **self.recent.readings(up))

    def _fed(self, chunk) -> None:
        self.recent.add(chunk)
        self._samples += len(chunk)

    def _truth(self) -> dict:
        truth = self.spec.truth()
        if self.engine.records:
            names = self.engine.windows_and_averages()[1]
            truth = {n: v for n, v in truth.items() if n in names}
        return truth


def wrong_position(procedure: Procedure, step: int):
    """A position whose gravity direction is far from the expected one (a plausible mix-up);
    the same choice as the headless operator's ``wrong_step``."""
    expected = procedure.positions[step].up_body
    return max(procedure.positions, key=lambda p: -abs(float(p.up_body @ expected)) - 0.01 * p.id)


class SimSource(Source):
    """The simulated bench, moved by the operator's keys; captured like a headless run."""

    mode = "sim"

    def __init__(self, spec, sink: Sink, speed: float, session_dir: Path | None,
                 clock: Callable[[], float] = time.monotonic, bench=None):
        from fieldcal.run.runner import SimulatedBench

        super().__init__(spec, sink, speed, clock)
        self.session_dir = Path(session_dir) if session_dir is not None else None
        self.session = None
        self.bench = SimulatedBench(spec) if bench is None else bench
        self.bump_times: list[float] = []  # sample time of each bump (OperatorScript.bump_at_s)
        if speed > 0 and bench is None:  # chunks of about FLUSH_S wall time, so the display moves smoothly
            self.bench.chunk_n = max(1, min(self.bench.chunk_n, round(spec.rate_hz * FLUSH_S * speed)))

    def _run(self) -> None:
        from fieldcal.session.capture import SessionWriter

        if self.session_dir is not None:
            metadata = self.spec.to_metadata()
            metadata["device"]["link"] = "in-process"
            metadata["front_end"] = "tui"
            self.session = SessionWriter.create(self.session_dir, metadata)
        try:
            self._handle(self.engine.start())
            while self.outcome is None and not self.stopping:
                waiting = self.engine.phase in (PLACE, WRONG)
                command = self._next_command(wait=waiting)
                if command is not None:
                    self._do(command)
                elif not waiting and not self.stopping:
                    self._feed([self.bench.next_chunk()])
                self._flush()
        finally:
            self.bench.close()
            if self.session is not None and not self.session.closed:
                self.session.close()  # not stopped: `fieldcal resume` can continue it

    def _close_after_error(self) -> Path | None:
        if self.session is None:
            return None
        if not self.session.closed:
            self.session.close()
        return self.session_dir

    def _feed(self, chunks) -> None:
        for chunk in chunks:
            if self.outcome is not None:
                return
            self._pace(chunk)
            if self.stopping:
                return
            if self.session is not None:
                self.session.chunk(chunk)
            events = self.engine.feed(chunk)
            self._fed(chunk)
            self._handle(events)
            self._flush()

    def _act(self, name: str) -> None:
        action = ev.Action(name)
        if self.session is not None:
            self.session.action(action.to_dict())
        self._handle(self.engine.act(action))

    def _do(self, command: str) -> None:
        e = self.engine
        if command == QUIT:
            self._stop.set()
        elif command in (READY, MISPLACE) and e.phase == PLACE:
            place = e.position if command == READY else wrong_position(e.procedure, e.step)
            self._note(f"operator: ready; the simulator carries the unit to position {place.id}"
                       f"{'' if command == READY else ' (the wrong one, on purpose)'}")
            self._feed(self.bench.move_to(place.attitude))
            if not self.stopping:
                self._act(ev.READY)
        elif command == READY and e.phase == WRONG:
            self._note(f"operator: the simulator puts the unit in position {e.position.id} after all")
            self._feed(self.bench.move_to(e.position.attitude))
        elif command in (READY, MISPLACE):
            self._note(f"({command}: nothing to do while {_PHASE_WORDS.get(e.phase, e.phase)})")
        elif command in (REDO, SKIP, ABORT, UNSKIP):
            self._note(f"operator: {command}")
            self._act(command)
        elif command == BUMP:
            self._note("operator: bump! (the simulator knocks the fixture)")
            self.bump_times.append(e.t)
            self._feed(self.bench.bump())

    def _handle(self, events) -> None:
        """What ``runner._drive`` does with each event, minus the automatic operator."""
        for e in events:
            self._items.append(e)
            if self.session is not None:
                self.session.event(e.to_dict())
            if isinstance(e, ev.CommandTable):
                self.bench.command_table(e.rate_deg_s)
            elif isinstance(e, ev.StepComplete) and self.session is not None:
                self.session.step(self.engine.records[e.step])
                self.session.checkpoint({"step": e.step, "bench": self.bench.get_state()})
            elif isinstance(e, ev.ProcedureComplete):
                self._conclude(e)
            elif isinstance(e, ev.Aborted):
                self._abort()

    def _abort(self) -> None:
        if self.session is not None:
            self.session.stop("aborted")
            self.session.close()
        self.outcome = Outcome("aborted", self.spec.procedure, truth=self._truth(),
                               session=self.session_dir, completed=len(self.engine.records),
                               skipped=len(self.engine.skipped),
                               message="aborted by the operator; the session is kept")

    def _conclude(self, done: ev.ProcedureComplete) -> None:
        """Solve and write the parameter file exactly as ``runner._finish`` does."""
        from fieldcal.run.runner import _solve

        truth = self._truth()
        unit, pf = _solve(self.spec, self.engine)
        solved = ev.Solved(self.engine.t, tuple(unit.solutions), dict(unit.failures))
        self._items.append(solved)
        path = None
        if self.session is not None:
            self.session.event(solved.to_dict())
            if pf is not None:
                self.session.write_parameters(pf)
                path = self.session_dir / "parameters.yaml"
            self.session.stop("completed")
            self.session.close()
        self.outcome = Outcome("completed", self.spec.procedure, unit=unit, truth=truth,
                               session=self.session_dir, parameters=path,
                               completed=done.completed, skipped=done.skipped,
                               previous=self._previous())

    def _previous(self):
        """The unit's last calibration among the sessions beside this one."""
        from fieldcal.session.history import previous_calibration

        if self.session_dir is None:
            return None
        found, unreadable = previous_calibration(self.session_dir.parent, self.spec.device_name,
                                                 self.spec.device_serial, exclude=self.session_dir)
        if unreadable:
            self._note(f"{unreadable} unreadable parameter file(s) under {self.session_dir.parent} "
                       "passed over when looking for the previous calibration")
        return found

    def _stopped(self) -> Outcome:
        out = super()._stopped()
        out.session = self.session_dir
        out.message = "stopped before the end; the session can be continued with `fieldcal resume`" \
            if self.session_dir is not None else "stopped before the end"
        return out


class ReplaySource(Source):
    """A captured session's chunks and actions, in recorded order, through a fresh engine."""

    mode = "replay"

    def __init__(self, directory: Path, sink: Sink, speed: float,
                 clock: Callable[[], float] = time.monotonic):
        from fieldcal.run.runner import RunSpec
        from fieldcal.session.capture import SessionReader

        self.directory = Path(directory)
        self.reader = SessionReader(self.directory)
        super().__init__(RunSpec.from_metadata(self.reader.start), sink, speed, clock)

    def send(self, command: str) -> None:
        """In a replay the recorded actions are applied; only quitting is up to the operator."""
        if command == QUIT:
            super().send(command)

    def _run(self) -> None:
        self._note(f"replaying {self.directory}: recorded samples and actions, keys ignored")
        self._handle(self.engine.start())
        for kind, item in self.reader.replay_items(("chunk", "action", "resume")):
            while (command := self._next_command(wait=False)) is not None:
                if command == QUIT:  # the only command a replay takes
                    self._stop.set()
            if self.stopping:
                return
            if kind == "chunk":
                self._pace(item)
                if self.stopping:
                    return
                events = self.engine.feed(item)
                self._fed(item)
            elif kind == "action":
                action = ev.action_from_dict(item)
                self._note(f"recorded action: {action.name}")
                events = self.engine.act(action)
            else:  # a resumed run restarted its engine from the completed steps (replay_session)
                records, skipped = list(self.engine.records.values()), sorted(self.engine.skipped)
                self.engine = Engine(self.spec.procedure, self.settings)
                self.engine.restore(records, skipped)
                self._note("the recorded run was resumed here")
                events = self.engine.start()
            self._handle(events)
            self._flush()
        self._conclude()

    def _handle(self, events) -> None:
        self._items.extend(events)

    def _conclude(self) -> None:
        from fieldcal.paramfile import dump
        from fieldcal.run.replay import recorded_parameters
        from fieldcal.run.runner import _solve

        e = self.engine
        common = {"replay_of": self.directory, "completed": len(e.records), "skipped": len(e.skipped),
                  "truth": self._truth()}
        if e.phase == ABORTED:
            self.outcome = Outcome("aborted", self.spec.procedure, message="the recorded run was aborted",
                                   **common)
            return
        if e.phase != DONE:
            self.outcome = Outcome("incomplete", self.spec.procedure, **common,
                                   message=f"the capture ends during step {e.step + 1} of "
                                           f"{len(e.procedure.positions)}")
            return
        unit, pf = _solve(self.spec, e)
        solved = ev.Solved(e.t, tuple(unit.solutions), dict(unit.failures))
        self._items.append(solved)
        recorded = recorded_parameters(self.directory)
        identical = None if pf is None or recorded is None else dump(pf).encode() == recorded
        self.outcome = Outcome("completed", self.spec.procedure, unit=unit, identical=identical,
                               parameters=self.reader.parameters_path, **common)


_PHASE_WORDS = {"settling": "waiting for stillness", "checking": "checking the orientation",
                "dwell": "dwelling", "rate_wait": "the table settles", "rate_average": "averaging turns",
                "done": "finished", "aborted": "aborted", "wrong": "the unit is misplaced",
                "place": "placing"}
