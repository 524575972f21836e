"""The operator time a run still needs, folded from its engine events (sample time, no clock).

Each open position costs a placement (the operator's hands, then stillness and the orientation
check), its dwell and its rate steps. Each of the three is taken from the procedure until the run
has timed one, then from what this run's own steps took: placements as their mean, dwells and
rate steps as the mean ratio of taken to planned (an adaptive dwell's length follows the unit's
noise; a table's reversal ramps twice as far as its start). The step under way counts what its
phase has left (placement, dwell, rate steps) of its estimate, so the figure falls with sample
time instead of jumping at each event.
"""
from __future__ import annotations

from collections.abc import Iterable

from fieldcal.procedure import events as ev
from fieldcal.procedure.positions import Procedure


def rate_steps_s(procedure: Procedure, index: int) -> float:
    """Both rate steps of the position at ``index`` as the table makes them: up to +ω (ramp,
    settle, whole turns), reversed to −ω (twice the ramp, settle, whole turns); 0 without one."""
    r = procedure.rate_step_at(index)
    if r is None:
        return 0.0
    turns_s = r.turns * 360.0 / r.rate_deg_s
    return (r.ramp_s + r.settle_s + turns_s) + (2 * r.ramp_s + r.settle_s + turns_s)


class TimeToGo:
    """``apply(event)`` for every engine event of the run; ``remaining_s(t)`` at sample time t."""

    def __init__(self, procedure: Procedure, placing_prior_s: float):
        self.procedure = procedure
        self.placing_prior_s = placing_prior_s
        self.open = set(range(len(procedure.positions)))
        self.current: int | None = None
        self.step_t0 = 0.0
        self.placings: list[float] = []  # each step's start to the unit found still in place
        self.dwell_ratios: list[float] = []  # each dwell taken / planned
        self.rate_ratios: list[float] = []  # each position's rate steps taken / modelled
        self._placed = False
        self._still_t: float | None = None  # the dwell under way began (again) here
        self._dwell_end: float | None = None

    def resumed(self, done: Iterable[int], skipped: Iterable[int]) -> None:
        """A run continued after these steps (a power-cycled unit's later steps are open again)."""
        self.open = set(range(len(self.procedure.positions))) - set(done) - set(skipped)

    def apply(self, e: ev.Event) -> None:
        if isinstance(e, ev.StepStarted):
            self.current, self.step_t0, self._placed = e.step, e.t, False
            self._still_t = self._dwell_end = None
        elif isinstance(e, ev.PositionRecognised):
            self.current = e.step
        elif isinstance(e, ev.Still):
            if not self._placed:
                self._placed = True
                self.placings.append(e.t - self.step_t0)
            self._still_t = e.t
        elif isinstance(e, ev.DwellComplete):
            self.dwell_ratios.append(e.duration_s / self.procedure.dwell_s)
            self._dwell_end = e.t
        elif isinstance(e, (ev.StepComplete, ev.StepSkipped)):
            modelled = rate_steps_s(self.procedure, e.step)
            if isinstance(e, ev.StepComplete) and modelled and self._dwell_end is not None:
                self.rate_ratios.append((e.t - self._dwell_end) / modelled)
            self.open.discard(e.step)
            self.current = None
        elif isinstance(e, (ev.ProcedureComplete, ev.Aborted)):
            self.open, self.current = set(), None

    def parts_s(self, index: int) -> tuple[float, float, float]:
        """A step at the position ``index``: its placement, dwell and rate steps, as expected."""
        return (_mean(self.placings, self.placing_prior_s), self.procedure.dwell_s * _mean(self.dwell_ratios, 1.0),
                rate_steps_s(self.procedure, index) * _mean(self.rate_ratios, 1.0))

    def step_s(self, index: int) -> float:
        return sum(self.parts_s(index))

    def remaining_s(self, t: float) -> float:
        later = sum(self.step_s(k) for k in self.open if k != self.current)
        if self.current is None or self.current not in self.open:
            return later
        placing, dwell, rates = self.parts_s(self.current)
        if self._dwell_end is not None:
            return later + max(0.0, rates - (t - self._dwell_end))
        if self._still_t is not None:
            return later + max(0.0, dwell - (t - self._still_t)) + rates
        return later + max(0.0, placing - (t - self.step_t0)) + dwell + rates


def _mean(values: list[float], prior: float) -> float:
    return sum(values) / len(values) if values else prior
