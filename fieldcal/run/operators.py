"""Operators a conductor can take: the scripted one of headless runs, and the replay of a capture.

(The terminal UI's operator, the keys, lives with the UI: ``fieldcal.tui.source``.)
"""
from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass

from fieldcal.procedure import events as ev
from fieldcal.procedure.positions import Procedure
from fieldcal.run.conductor import Act, Bump, Conductor, Feed, Operator, Place, Restart, Say
from fieldcal.run.pacing import Pacer
from fieldcal.session.record import ResumePoint
from fieldcal.session.record import RunRecord


@dataclass(frozen=True)
class OperatorScript:
    placement_sigma_deg: float = 3.0
    handling_s: float = 4.0
    bump_step: int | None = None  # bump the unit halfway through this step's dwell (0-based)
    wrong_step: int | None = None  # first put the unit in a wrong position at this step
    skip_steps: tuple[int, ...] = ()
    # Bump after the first chunk that ends at or after each of these sample times (s): how a
    # headless run repeats the bumps an operator gave in the terminal UI.
    bump_at_s: tuple[float, ...] = ()
    # Place the positions of a procedure taken in any order in an order shuffled with this seed
    # (None: procedure order). A procedure in a fixed order is placed in that order regardless.
    shuffle_seed: int | None = None


def placing_order(procedure: Procedure, seed: int | None) -> list[int]:
    """The steps in the order the scripted operator places them: shuffled with ``seed``, else as listed."""
    import numpy as np

    steps = list(range(len(procedure.positions)))
    return steps if seed is None else [int(k) for k in np.random.default_rng(seed).permutation(steps)]


def wrong_position(procedure: Procedure, step: int):
    """A position whose gravity direction is far from the expected one (a plausible mix-up).

    In a procedure taken in any order, another planned position is no mistake: the face,
    edge or corner of the cube farthest from every planned up direction, named by no id."""
    import numpy as np

    from fieldcal.procedure.positions import Position, attitude_from_up_and_north

    if not procedure.any_order:
        expected = procedure.positions[step].up_body
        return max(procedure.positions, key=lambda p: -abs(float(p.up_body @ expected)) - 0.01 * p.id)
    sums = np.array([(a, b, c) for a in (-1, 0, 1) for b in (-1, 0, 1) for c in (-1, 0, 1) if (a, b, c) != (0, 0, 0)],
                    dtype=float)
    ups = sums / np.linalg.norm(sums, axis=1, keepdims=True)
    planned = np.array([p.up_body for p in procedure.positions])
    up = ups[int(np.argmin((ups @ planned.T).max(axis=1)))]  # (argmin: the first of equals)
    toward = np.eye(3)[int(np.argmin(np.abs(up)))]  # the axis farthest from up has a horizontal part
    attitude = attitude_from_up_and_north(up, toward)
    assert attitude is not None
    return Position(id=-1, description="like no position of the procedure", attitude=attitude)


class ScriptedOperator(Operator):
    """The headless operator: places the unit at each step, says ready, and makes the script's mishaps.

    The moves an event calls for are made after all the events of the same chunk (or action),
    in order; a bump at a given sample time comes after the moves of the chunk that reached it.
    """

    def __init__(self, script: OperatorScript, procedure: Procedure):
        self.script = script
        self.procedure = procedure
        self.pending: deque = deque()
        self.bumped = self.wrong_done = False
        self.bumps_due: list[float] = []
        self.order = placing_order(procedure, script.shuffle_seed)
        self.placed: set[int] = set()  # steps whose position this operator has placed the unit in
        # A step normally takes its dwell, its rate steps and the handling; ten times that with
        # no step completed means the run cannot make progress (say the unit never settles).
        # (the longest rate step of the procedure's)
        turning = max((2 * (rate.turns * 360.0 / rate.rate_deg_s + rate.ramp_s + rate.settle_s)
                       for rate in procedure.rate_steps), default=0.0)
        self.patience_s = 10 * (procedure.dwell_s + script.handling_s + turning)
        self.deadline = self.patience_s

    def begin(self, run: Conductor) -> None:
        t0 = run.engine.t  # after a resume, where the run continues
        self.bumps_due = sorted(t for t in self.script.bump_at_s if t > t0)
        self.deadline = t0 + self.patience_s

    def next_moves(self, run: Conductor):
        moves = list(self.pending)
        self.pending.clear()
        return moves

    def observe(self, e: ev.Event, run: Conductor) -> None:
        engine, script = run.engine, self.script
        if isinstance(e, (ev.StepComplete, ev.StepSkipped)):
            self.deadline = e.t + self.patience_s
        if isinstance(e, ev.PlaceUnit):
            step = engine.step
            if step in script.skip_steps:
                self.pending.append(Act(ev.SKIP))
                return
            if step == script.wrong_step and not self.wrong_done:
                self.wrong_done = True
                self.pending.append(Place(wrong_position(self.procedure, step).attitude))
            else:
                self.pending.append(Place(self._next_position(engine).attitude))
            if not self.procedure.any_order:  # (in any order, the engine sees the unit placed)
                self.pending.append(Act(ev.READY))
        elif isinstance(e, ev.WrongOrientation):
            self.pending.append(Place(self._next_position(engine).attitude))
        elif isinstance(e, ev.DwellProgress):
            if engine.step == script.bump_step and not self.bumped and e.done_s >= e.total_s / 2:
                self.bumped = True
                self.pending.append(Bump())

    def _next_position(self, engine):
        """Where to put the unit: the engine's step in procedure order; shuffled, the first
        position of this operator's order it has neither placed nor the engine closed (the
        engine may have taken a placement for a position gravity cannot tell from it)."""
        if self.script.shuffle_seed is None or not self.procedure.any_order:
            return engine.position
        closed = set(engine.records) | set(engine.skipped)
        step = next((k for k in self.order if k not in closed and k not in self.placed), engine.step)
        self.placed.add(step)
        return self.procedure.positions[step]

    def after_chunk(self, chunk, run: Conductor) -> None:
        t = float(chunk.t[-1])
        if t > self.deadline:  # before any move this chunk's events asked for
            self.pending.appendleft(Act(ev.ABORT, f"no step completed in {self.patience_s:.0f} s of samples "
                                                  f"(phase {run.engine.phase}): the run cannot make progress"))
        elif self.bumps_due and run.engine.t >= self.bumps_due[0]:
            self.bumps_due.pop(0)
            self.pending.append(Bump())  # after this chunk's moves, as the terminal UI does a key


class NoBench:
    """A replay's bench: the samples come from the capture, and no table turns."""

    def next_chunks(self) -> list:
        return []

    def command_table(self, rate_deg_s: float) -> None:
        pass

    def get_state(self) -> dict:
        return {}

    def set_state(self, state: dict) -> None:
        pass

    def close(self) -> None:
        pass


class ReplayOperator(Operator):
    """A captured run's chunks, actions and resume points, in the order they were recorded.

    ``speed``: None or 0 for as fast as possible, else that many times sample time (the pacing
    starts over at each resume: a resumed run's sample time continues from its last step).
    """

    def __init__(self, record: RunRecord, speed: float | None = None, pacer: Pacer | None = None):
        self.record = record
        self.items = record.replay_items(("chunk", "action", "resume"))
        self.pacer = pacer if pacer is not None else Pacer(speed or 0.0)

    def next_moves(self, run: Conductor):
        found = next(self.items, None)
        if found is None:
            return None  # the end of the capture
        kind, item = found
        if kind == "chunk":
            return [Feed(item)]
        if kind == "action":
            action = ev.action_from_dict(item)
            return [Say(f"recorded action: {action.name}"), Act(action.name, position_id=action.position_id)]
        self.pacer.hold()
        return [Say("the recorded run was resumed here"), Restart(ResumePoint.from_dict(item))]

    def pace(self, chunk, run: Conductor) -> bool:
        delay = self.pacer.delay(float(chunk.t[0]), float(chunk.t[-1]))
        if delay > 0:
            time.sleep(delay)
        return True
