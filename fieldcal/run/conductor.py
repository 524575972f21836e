"""The one run loop: a conductor owning the engine, a bench and the conclusion of every run.

Every front end (headless run and resume, replay, the terminal UI on the simulator, a live
device or a replay) is a conductor with three kinds of parts plugged in, in the spirit of
bluesky's RunEngine and its subscribers:

- a **bench** gives sample chunks and turns the table (``next_chunks``, ``command_table``,
  ``get_state``/``set_state``, ``close``; a simulated one also ``move_to`` and ``bump``, the
  operator's hands);
- an **operator** says what to do next (``next_moves``): scripted (headless, with its
  mishaps), keys (the terminal UI) or the recorded actions and resume points (replay);
- **subscribers** see everything that happens (chunks, events, actions, notes, restarts, the
  end): the session recorder, the progress printer, the terminal UI's sink.

The conductor feeds each chunk to the engine, hands each event to the subscribers, then to the
bench (table commands) and the operator, and concludes a completed procedure once: solve,
the ``Solved`` event, the parameter file, the previous calibration of the same unit.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from fieldcal.procedure import events as ev
from fieldcal.procedure.engine import Engine
from fieldcal.run.outcome import Outcome, Status
from fieldcal.session.record import ResumePoint, StepDocument


class Bench(Protocol):
    def next_chunks(self) -> list: ...  # the chunks read since last asked ([]: none yet)

    def command_table(self, rate_deg_s: float) -> None: ...

    def get_state(self) -> dict: ...

    def set_state(self, state: dict) -> None: ...

    def close(self) -> None: ...


# Moves: what an operator asks the conductor to do, in order.

@dataclass(frozen=True)
class Act:
    name: str  # an engine action (fieldcal.procedure.events.ACTIONS)
    reason: str = ""  # for an abort: why (else the engine's "operator")
    position_id: int | None = None  # for a choice among positions gravity cannot tell apart


@dataclass(frozen=True)
class Place:
    """The operator's hands carry the unit to this attitude (a simulated bench only)."""
    attitude: np.ndarray


@dataclass(frozen=True)
class Bump:
    """A knock on the fixture (a simulated bench only)."""


@dataclass(frozen=True)
class Feed:
    """Recorded samples (replay)."""
    chunk: Any


@dataclass(frozen=True)
class Restart:
    """A recorded resume: restart the engine from the steps the resumed run kept."""
    point: ResumePoint


@dataclass(frozen=True)
class Say:
    """A line for the operator's log that is not an engine event."""
    text: str


Move = Act | Place | Bump | Feed | Restart | Say


class Operator:
    """What every operator may do; the defaults do nothing."""

    def begin(self, run: Conductor) -> None:
        """The run starts (after any restore)."""

    def next_moves(self, run: Conductor) -> Sequence[Move] | None:
        """The moves to make now; [] lets the bench run on; None ends the run (quit, end of capture)."""
        raise NotImplementedError

    def observe(self, e: ev.Event, run: Conductor) -> None:
        """Every event, after the subscribers have it."""

    def pace(self, chunk, run: Conductor) -> bool:
        """Called before each chunk is fed; may wait. False: stop now (the chunk is not fed)."""
        return True

    def after_chunk(self, chunk, run: Conductor) -> None:
        """Called after a chunk from the bench (not from a move) and its events."""

    def idle(self, run: Conductor) -> None:
        """The bench had nothing: wait a little (a live port) instead of spinning."""


class Subscriber:
    """What the conductor tells its subscribers; the defaults ignore it."""

    def chunk(self, chunk, run: Conductor) -> None: ...

    def event(self, e: ev.Event, run: Conductor) -> None: ...

    def action(self, action: ev.Action, run: Conductor) -> None: ...

    def note(self, text: str, run: Conductor) -> None: ...

    def resumed(self, point: ResumePoint, run: Conductor) -> None: ...

    def tick(self, run: Conductor) -> None:
        """After each chunk's events and each round of moves: a moment to show progress."""

    def parameters(self, pf, run: Conductor) -> Path | None: ...

    def end(self, status: str, run: Conductor) -> None: ...


class Reporter(Subscriber):
    """A plain ``report(event)`` callable (the progress printer) as a subscriber."""

    def __init__(self, report):
        self.report = report

    def event(self, e, run) -> None:
        self.report(e)


class Conductor:
    def __init__(self, spec, bench, operator: Operator, subscribers: Iterable = (), *,
                 session: Path | None = None, settings=None):
        """``session``: the directory being recorded (for the outcome and the previous calibration)."""
        self.spec = spec
        self.settings = spec.engine_settings() if settings is None else settings
        self.engine = Engine(spec.procedure, self.settings)
        self.bench = bench
        self.operator = operator
        self.subscribers = list(subscribers)
        self.session = Path(session) if session is not None else None
        self.outcome: Outcome | None = None
        self.samples = 0  # fed so far
        self._resume: ResumePoint | None = None
        self._stopped = False
        # Errors a bench raises that the operator can deal with (skip, abort), not run-ending.
        self._recoverable = tuple(getattr(bench, "recoverable_errors", ()))

    # --- setting up -------------------------------------------------------------------------

    def restore(self, steps: Sequence[StepDocument], skipped: Sequence[int] | None = None,
                why: str = "", dropped: Sequence[int] = ()) -> ResumePoint:
        """Continue after the last of these completed steps (resume): engine and bench as they were.
        ``skipped``: the steps skipped so far, if not the last step's (``why`` says why the steps
        ``dropped``, completed before, are not among ``steps``: they are measured again)."""
        if skipped is None:
            skipped = steps[-1].skipped if steps else ()
        self.engine.restore([s.record for s in steps], skipped)
        if steps:
            if steps[-1].bench is None:
                raise ValueError(f"step {steps[-1].record.step + 1}: the session holds no bench state "
                                 "after it, so the run cannot be continued exactly; replay it, or run again")
            self.bench.set_state(steps[-1].bench)
        self._resume = ResumePoint(tuple(sorted(self.engine.records)), tuple(sorted(self.engine.skipped)), why,
                                   tuple(sorted(dropped)))
        return self._resume

    # --- the loop ---------------------------------------------------------------------------

    def run(self) -> Outcome:
        """Until the procedure completes or is aborted, or the operator ends the run."""
        ended = False
        try:
            self.start()
            while self.step():
                pass
            if self.outcome is None:
                self.outcome = self._unfinished()
            ended = True
        finally:
            try:
                self.bench.close()
            finally:
                # After an error the session stays open to resume, as after a quit.
                self._tell("end", self.outcome.status if ended and self.outcome is not None else Status.ERROR)
        return self.outcome

    def start(self) -> None:
        if self._resume is not None:
            self._tell("resumed", self._resume)
        self.operator.begin(self)
        self._publish(self.engine.start())

    def step(self) -> bool:
        """One round: the operator's moves, or else what the bench has read. False: the run is over."""
        if self.outcome is not None or self._stopped:
            return False
        moves = self.operator.next_moves(self)
        if moves is None:
            return False
        if moves:
            for move in moves:
                if self.outcome is not None or self._stopped:
                    break
                self.do(move)
        else:
            chunks = self.bench.next_chunks()
            if not chunks:
                self.operator.idle(self)
            for chunk in chunks:
                if self.outcome is not None or not self.feed(chunk):
                    break
                self.operator.after_chunk(chunk, self)
        self._tell("tick")
        return self.outcome is None and not self._stopped

    def say(self, text: str) -> None:
        self._tell("note", text)

    def do(self, move: Move) -> None:
        if isinstance(move, Act):
            self.act(ev.Action(move.name, move.position_id), move.reason)
        elif isinstance(move, Feed):
            self.feed(move.chunk)
        elif isinstance(move, Say):
            self.say(move.text)
        elif isinstance(move, Restart):
            self._restart(move.point)
        else:
            for chunk in self.bench.move_to(move.attitude) if isinstance(move, Place) else self.bench.bump():
                if self.outcome is not None or not self.feed(chunk):
                    return

    def act(self, action: ev.Action, reason: str = "") -> None:
        self._tell("action", action)
        events = self.engine.act(action)
        if reason:
            events = [dataclasses.replace(e, reason=reason) if isinstance(e, ev.Aborted) else e for e in events]
        self._publish(events)

    def feed(self, chunk) -> bool:
        """Feed one chunk (paced by the operator); False if the operator stopped the run instead."""
        if not self.operator.pace(chunk, self):
            self._stopped = True
            return False
        self._tell("chunk", chunk)
        events = self.engine.feed(chunk)
        self.samples += len(chunk)
        self._publish(events)
        self._tell("tick")
        return True

    def _restart(self, point: ResumePoint) -> None:
        """A run starting over mid-way (a power cycle seen when the port came back, or its
        replay): the table stops first (the old engine's step may have it turning), then the engine
        restarts from the steps that run kept."""
        self._publish(self.engine.stop_table())
        keep = set(point.completed_steps)
        records = [r for step, r in self.engine.records.items() if step in keep]
        self.engine = Engine(self.spec.procedure, self.settings)
        self.engine.restore(records, point.skipped)
        self._tell("resumed", point)
        self._publish(self.engine.start())

    def _publish(self, events) -> None:
        for e in events:
            self._tell("event", e)
            if isinstance(e, ev.CommandTable):
                try:
                    self.bench.command_table(e.rate_deg_s)
                except self._recoverable as exc:  # the operator decides: skip or abort
                    self.say(f"ERROR: table: {exc}; skip this step (s) or abort (a)")
            self.operator.observe(e, self)
            if isinstance(e, ev.ProcedureComplete):
                self.conclude(e)
            elif isinstance(e, ev.Aborted):
                self.outcome = self._outcome(Status.ABORTED, message="aborted; the session is kept")

    def _tell(self, what: str, *args) -> None:
        for s in self.subscribers:
            getattr(s, what)(*args, self)

    # --- the end ----------------------------------------------------------------------------

    def solve(self, end_s: float | None = None):
        """The unit's solution and parameter file (None if nothing solved) from the completed steps;
        the bias at the end of calibration at ``end_s`` (default: the last sample fed)."""
        from fieldcal.solvers.solve import solve_unit

        spec = self.spec
        windows, averages = self.engine.windows_and_averages()
        models = {n: m for n, m in spec.models().items() if n in averages}
        unit = solve_unit(spec.procedure, windows, averages, models, spec.station, spec.rate_hz, spec.method,
                          spec.thermal, end_s=self.engine.t if end_s is None else end_s)
        return unit, unit.parameter_file(spec.procedure, spec.method, spec.station, device_name=spec.device_name,
                                         device_serial=spec.device_serial, simulation=spec.live is None,
                                         operator=spec.operator)

    def conclude(self, done: ev.ProcedureComplete) -> None:
        """Solve, say so, write the parameter file; the outcome, with the unit's previous calibration."""
        unit, pf = self.solve()
        self._publish([ev.Solved(self.engine.t, tuple(unit.solutions), dict(unit.failures))])
        path = None
        if pf is not None:
            for s in self.subscribers:
                path = s.parameters(pf, self) or path
        self.outcome = self._outcome(Status.COMPLETED, unit=unit, parameters=path, parameter_file=pf,
                                     previous=self._previous())

    def truth(self) -> dict:
        """The simulation's true parameters of the triads the completed steps measured."""
        truth = self.spec.truth()
        if self.engine.records:
            names = self.engine.windows_and_averages()[1]
            truth = {n: v for n, v in truth.items() if n in names}
        return truth

    def _bias_at_end(self) -> dict:
        """The simulated bench's true biases at the run's last sample, of the triads in truth()."""
        bias_at_end = getattr(self.bench, "bias_at_end", None)  # a real or replayed bench: none
        if bias_at_end is None:
            return {}
        names = self.truth()
        return {n: b for n, b in bias_at_end().items() if n in names}

    def _outcome(self, status: Status, **kw) -> Outcome:
        sim_thermal = getattr(self.spec, "sim_thermal", None)
        return Outcome(status, self.spec.procedure, truth=self.truth(), bias_at_end=self._bias_at_end(),
                       session=self.session,
                       thermal_truth=dict(sim_thermal.triads) if sim_thermal is not None else {},
                       completed=len(self.engine.records), skipped=len(self.engine.skipped), samples=self.samples, **kw)

    def _unfinished(self) -> Outcome:
        """The operator ended the run (quit; the end of a replayed capture) before the procedure did."""
        return self._outcome(Status.STOPPED, message="stopped before the end")

    def _previous(self):
        """The unit's last calibration among the sessions beside this one."""
        from fieldcal.session.history import previous_calibration

        if self.session is None:
            return None
        found, unreadable = previous_calibration(self.session.parent, self.spec.device_name,
                                                 self.spec.device_serial, exclude=self.session)
        if unreadable:
            self.say(f"{unreadable} unreadable parameter file(s) under {self.session.parent} "
                     "passed over when looking for the previous calibration")
        return found
