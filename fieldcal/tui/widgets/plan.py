"""During a planned run (a procedure with targets, from `fieldcal plan`): the time left, and per
triad the σ its completed positions reach against the plan's target, worst parameter shown."""
from __future__ import annotations

from textual.widgets import Static

from fieldcal.planning.tracker import TargetTracker, TriadStanding
from fieldcal.tui.view import duration_words


UNDETERMINED = 100.0  # σ/target beyond which the positions so far barely tell the parameter apart


def standing_text(s: TriadStanding) -> str:
    if not s.ratio <= UNDETERMINED:
        return f"{s.triad}: σ not yet determined (more positions needed)"
    mark = "✓ met" if s.met else f"{s.ratio:.2f}× the target"
    unit = "" if s.unit == "1" else f" {s.unit}"  # a scale factor has no unit
    return f"{s.triad}: {s.parameter} σ {s.sigma:.3g}{unit} of {s.target:.3g}{unit} · {mark}"


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
