"""What the procedure engine says (events) and what a front end may tell it (actions).

Events and actions are small frozen dataclasses; ``to_dict`` gives the JSON-able document the
session log stores, and ``action_from_dict`` reads an action back for replay.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field


@dataclass(frozen=True)
class Event:
    t: float  # sample time at which it happened, s

    @property
    def kind(self) -> str:
        return _snake(type(self).__name__)

    def to_dict(self) -> dict:
        """The document as the session stores it (JSON shapes: a tuple is a list)."""
        return {"event": self.kind, **{k: list(v) if isinstance(v, tuple) else v
                                        for k, v in asdict(self).items()}}


@dataclass(frozen=True)
class StepStarted(Event):
    step: int  # 0-based index into the procedure's positions
    position_id: int
    description: str
    total_steps: int


@dataclass(frozen=True)
class PlaceUnit(Event):
    """The operator should put the unit in this position, then say ready."""
    position_id: int
    description: str


@dataclass(frozen=True)
class PositionRecognised(Event):
    """A procedure taking positions in any order: the unit is still in this remaining position,
    whose step it now is (its dwell next). ``alike``: the remaining positions gravity cannot tell
    apart from it (same up direction; this one is the first in procedure order unless the
    operator chose), which the operator may choose among while the dwell runs."""
    step: int
    position_id: int
    description: str
    alike: tuple[int, ...] = ()
    chosen: bool = False  # the operator chose it among ``alike``


@dataclass(frozen=True)
class WaitingForStillness(Event):
    pass


@dataclass(frozen=True)
class Still(Event):
    angle_to_expected_deg: float


@dataclass(frozen=True)
class MotionDetected(Event):
    phase: str  # what was interrupted: "dwell", "rate", "waiting"
    restarted: bool  # the interrupted average starts again


@dataclass(frozen=True)
class WrongOrientation(Event):
    position_id: int
    looks_like: tuple[int, ...]  # ids of the positions the unit looks like
    angle_deg: float
    message: str


@dataclass(frozen=True)
class TableTurning(Event):
    """Still, but turning: the table must stop before a static dwell."""
    rate_deg_s: float


@dataclass(frozen=True)
class DwellProgress(Event):
    done_s: float
    total_s: float


@dataclass(frozen=True)
class DwellComplete(Event):
    duration_s: float


@dataclass(frozen=True)
class CommandTable(Event):
    """The front end should set the table to this rate (°/s; 0 stops it)."""
    rate_deg_s: float


@dataclass(frozen=True)
class RateSettled(Event):
    rate_deg_s: float
    window_s: float  # the whole turns that will be averaged


@dataclass(frozen=True)
class RateStepComplete(Event):
    rate_deg_s: float


@dataclass(frozen=True)
class StepComplete(Event):
    step: int
    position_id: int


@dataclass(frozen=True)
class StepSkipped(Event):
    step: int
    position_id: int


@dataclass(frozen=True)
class ProcedureComplete(Event):
    completed: int
    skipped: int


@dataclass(frozen=True)
class Aborted(Event):
    reason: str


@dataclass(frozen=True)
class Solved(Event):
    solved: tuple[str, ...]  # triads calibrated
    failures: dict = field(default_factory=dict)  # triad -> why not


# Actions --------------------------------------------------------------------------------------

READY, REDO, SKIP, ABORT = "ready", "redo", "skip", "abort"
UNSKIP = "unskip"  # go back to a skipped position (Engine.skipped_to_return_to says which)
CHOOSE = "choose"  # which of positions gravity cannot tell apart the unit is in (with position_id)
ACTIONS = (READY, REDO, SKIP, ABORT, UNSKIP, CHOOSE)


@dataclass(frozen=True)
class Action:
    name: str  # one of ACTIONS
    position_id: int | None = None  # CHOOSE's position, and only its

    def __post_init__(self) -> None:
        if self.name not in ACTIONS:
            raise ValueError(f"action: expected one of {', '.join(ACTIONS)}, got {self.name!r}")
        if (self.name == CHOOSE) != (self.position_id is not None):
            raise ValueError(f"action {self.name}: a position id goes with {CHOOSE!r}, and only with it")

    def to_dict(self) -> dict:
        # (the plain form for every other action: sessions written before CHOOSE read the same)
        return {"action": self.name} if self.position_id is None else {"action": self.name,
                                                                       "position_id": self.position_id}


def action_from_dict(doc: dict) -> Action:
    return Action(doc["action"], doc.get("position_id"))


def _snake(name: str) -> str:
    return "".join(f"_{c.lower()}" if c.isupper() else c for c in name).lstrip("_")
