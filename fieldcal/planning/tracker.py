"""During a planned run: the σ the data gathered so far can reach, against the plan's targets.

Folded from the engine's events (no clock, no I/O): each completed position's averaging windows,
as the engine measured them (a dwell that was lengthened or restarted counts with its real
length and time). The σ is the Cramér-Rao bound of those windows at the positions' nominal
attitudes, the same bound `fieldcal plan` planned with; it falls towards the planned σ as the
positions complete, and is infinite until enough positions tell the parameters apart.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fieldcal.earth import Station
from fieldcal.model import ANGULAR_RATE, PARAM_NAMES
from fieldcal.planning.design import window_sigmas
from fieldcal.procedure import events as ev
from fieldcal.procedure.positions import Procedure
from fieldcal.procedure.windows import MINUS, PLUS, STATIC, Window
from fieldcal.solvers.solve import TriadModel
from fieldcal.units import display_scale, param_unit


@dataclass(frozen=True)
class TriadStanding:
    """One triad's worst parameter: the σ reached (inf: not yet determined) against its target."""

    triad: str
    parameter: str
    sigma: float  # operator units
    target: float  # operator units
    unit: str

    @property
    def ratio(self) -> float:
        return self.sigma / self.target

    @property
    def met(self) -> bool:
        return self.sigma <= self.target


class TargetTracker:
    """``apply(event)`` for every engine event of the run; ``standings()`` per triad with targets."""

    def __init__(self, procedure: Procedure, models: dict[str, TriadModel], station: Station,
                 rate_hz: float):
        self.procedure, self.station, self.rate_hz = procedure, station, rate_hz
        self.models = {n: m for n, m in models.items() if any(t == n for t, _, _ in procedure.targets)}
        self.targets = {n: np.full(len(PARAM_NAMES), np.inf) for n in self.models}
        for triad, parameter, sigma in procedure.targets:
            if triad in self.targets:
                self.targets[triad][PARAM_NAMES.index(parameter)] = sigma
        self._step: int | None = None
        self._current: list[Window] = []
        self._rate_window: tuple[float, float, float] | None = None  # start, duration, signed rate
        self.completed: dict[int, list[Window]] = {}  # step -> its windows (position index = step)
        self._standings: list[TriadStanding] = []
        self._update()

    def apply(self, event: ev.Event) -> bool:
        """Fold one event; True when the σ changed (a position completed or was dropped)."""
        if isinstance(event, ev.StepStarted):
            self._step, self._current, self._rate_window = event.step, [], None
        elif isinstance(event, ev.PositionRecognised):  # any order: the step the unit is in (no window yet)
            self._step = event.step
        elif isinstance(event, ev.DwellComplete) and self._step is not None:
            self._current = [w for w in self._current if w.kind != STATIC]  # a dwell done again
            self._current.append(Window(STATIC, self._step, event.t - event.duration_s, event.duration_s))
        elif isinstance(event, ev.RateSettled):
            self._rate_window = (event.t, event.window_s, event.rate_deg_s)
        elif isinstance(event, ev.RateStepComplete) and self._rate_window is not None:
            start, duration, rate = self._rate_window
            kind = PLUS if rate > 0 else MINUS
            self._current = [w for w in self._current if w.kind != kind]
            self._current.append(Window(kind, self._step, start, duration, np.radians(abs(rate))))
            self._rate_window = None
        elif isinstance(event, ev.StepComplete):
            self.completed[event.step] = list(self._current)
            self._current = []
            self._update()
            return True
        elif isinstance(event, ev.StepSkipped) and self.completed.pop(event.step, None) is not None:
            self._update()
            return True
        return False

    def standings(self) -> list[TriadStanding]:
        return self._standings

    def _update(self) -> None:
        steps = sorted(s for s, w in self.completed.items()
                       if len(w) == (1 if self.procedure.rate_step_at(s) is None else 3))
        sigmas = self._sigmas(steps)
        out = []
        for name, model in self.models.items():
            scale = np.array([display_scale(model.kind, model.output_unit, j) for j in range(len(PARAM_NAMES))])
            sigma = np.where(np.isfinite(sigmas[name]), sigmas[name] * scale, np.inf)  # nan: not told apart
            targeted = np.isfinite(self.targets[name])  # an untargeted parameter (inf) never leads
            ratio = np.divide(sigma, self.targets[name], out=np.full(sigma.shape, -1.0), where=targeted)
            j = int(np.argmax(ratio))
            out.append(TriadStanding(name, PARAM_NAMES[j], float(sigma[j]), float(self.targets[name][j]),
                                     param_unit(model.kind, model.output_unit, j)))
        self._standings = out

    def _sigmas(self, steps: list[int]) -> dict[str, np.ndarray]:
        """CRB σ (solver units) of the completed steps' windows; inf with fewer than 3 positions."""
        if len(steps) < 3:
            return {n: np.full(len(PARAM_NAMES), np.inf) for n in self.models}
        index = {step: i for i, step in enumerate(steps)}
        windows = [Window(w.kind, index[s], w.start, w.duration, w.table_rate)
                   for s in steps for w in self.completed[s]]
        attitudes = np.array([self.procedure.positions[s].attitude for s in steps])
        turning = [self.procedure.rate_step_at(s) for s in steps if self.procedure.rate_step_at(s) is not None]
        rate = turning[0].rate_deg_s if turning else 0.0  # (each rate window carries its own)
        models = self.models if turning else {n: m for n, m in self.models.items() if m.kind != ANGULAR_RATE}
        out = {n: np.full(len(PARAM_NAMES), np.inf) for n in self.models}
        try:
            out.update(window_sigmas(windows, attitudes, rate, models, self.station, self.rate_hz))
        except ValueError:  # windows that overlap (a clock step in a device's time): not shown
            pass
        for name, model in self.models.items():
            # One norm equation per position for a specific-force triad: fewer positions than
            # parameters determine nothing, whatever finite number a near-singular inverse gives.
            if model.kind != ANGULAR_RATE and len(steps) < len(PARAM_NAMES):
                out[name] = np.full(len(PARAM_NAMES), np.inf)
        return out
