"""During a planned run (a procedure with targets, from `fieldcal plan`): the time left, and per
triad the σ its completed positions reach against the plan's target, worst parameter shown."""
from __future__ import annotations

from textual.widgets import Static

from fieldcal.model import PARAM_NAMES
from fieldcal.planning.tracker import TargetTracker, TriadStanding
from fieldcal.tui.view import duration_words


UNDETERMINED = 100.0  # σ/target beyond which the positions so far barely tell the parameter apart


def standing_text(s: TriadStanding) -> str:
    if not s.ratio <= UNDETERMINED:
        return f"{s.triad}: σ not yet determined (more positions needed)"
    mark = "✓ met" if s.met else f"{s.ratio:.2f}× the target"
    unit = "" if s.unit == "1" else f" {s.unit}"  # a scale factor has no unit
    return f"{s.triad}: {s.parameter} σ {s.sigma:.3g}{unit} of {s.target:.3g}{unit} · {mark}"


def solved_standings(procedure, solutions: dict) -> list[TriadStanding]:
    """Per triad the plan has targets for: its worst parameter's σ as solved (the solution's own
    σ, in operator units; inf when the triad or the parameter was not calibrated) against its
    target."""
    from fieldcal.units import display_scale, param_unit

    targets: dict[str, list[tuple[str, float]]] = {}
    for triad, parameter, sigma in procedure.targets:
        targets.setdefault(triad, []).append((parameter, sigma))
    out = []
    for triad, wanted in targets.items():
        sol = solutions.get(triad)
        worst = None
        for parameter, target in wanted:
            j = PARAM_NAMES.index(parameter)
            if sol is None or parameter not in sol.parameter_names:
                sigma, unit = float("inf"), ""
            else:
                sigma = float(sol.sigma[sol.parameter_names.index(parameter)]) * \
                    display_scale(sol.kind, sol.output_unit, j)
                unit = param_unit(sol.kind, sol.output_unit, j)
            standing = TriadStanding(triad, parameter, sigma, target, unit)
            if worst is None or standing.ratio > worst.ratio:
                worst = standing
        out.append(worst)
    return out


def target_text(s: TriadStanding) -> str:
    """One triad's verdict against the plan's target, its worst parameter beside it."""
    if not s.ratio < float("inf"):
        return f"{s.triad}: ✗ target not met: {s.parameter} not calibrated"
    unit = "" if s.unit in ("", "1") else f" {s.unit}"
    mark = "✓ target met" if s.met else "✗ target not met"
    return f"{s.triad}: {mark} (worst: {s.parameter} σ {s.sigma:.2g} of {s.target:.2g}{unit})"


class PlanPanel(Static):
    """``feed(items)`` with what the event log gets; ``show(seconds_left)`` after each refresh."""

    DEFAULT_CSS = """
    PlanPanel {
        height: auto;
        padding: 0 1;
        color: $text-muted;
    }
    """

    def __init__(self, **kw) -> None:
        super().__init__("", **kw)
        self.tracker: TargetTracker | None = None
        self._left: str | None = None

    def _tracker(self) -> TargetTracker:
        if self.tracker is None:
            spec = self.app.spec  # the run's procedure, the station and what it knows of the unit
            self.tracker = TargetTracker(spec.procedure, spec.models(), spec.station, spec.rate_hz)
        return self.tracker

    def feed(self, items) -> None:
        tracker = self._tracker()
        for item in items:
            tracker.apply(item)

    def show(self, seconds_left: float | None) -> None:
        """``seconds_left``: None once the run has ended."""
        head = "plan: ended" if seconds_left is None else f"plan: ≈{duration_words(seconds_left)} left"
        lines = [head + " · σ reached against the target:"]
        lines += ["  " + standing_text(s) for s in self._tracker().standings()]
        text = "\n".join(lines)
        if text != self._left:
            self._left = text
            self.update(text)
