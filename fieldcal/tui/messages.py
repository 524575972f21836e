"""Messages from the source's worker thread to the UI."""
from __future__ import annotations

from textual.message import Message

from fieldcal.tui.readings import Telemetry
from fieldcal.tui.source import Outcome


class RunItems(Message):
    """Engine events and notes, in order; never dropped. They carry the readings of the same
    moment, so the view never shows an event beside the phase from before it."""

    def __init__(self, items: tuple, telemetry: Telemetry) -> None:
        super().__init__()
        self.items, self.telemetry = items, telemetry


class RunTelemetry(Message):
    """The latest readings; a newer one waiting in the queue supersedes this one."""

    def __init__(self, telemetry: Telemetry) -> None:
        super().__init__()
        self.telemetry = telemetry

    def can_replace(self, message: Message) -> bool:
        return isinstance(message, RunTelemetry)


class RunFinished(Message):
    def __init__(self, outcome: Outcome) -> None:
        super().__init__()
        self.outcome = outcome
