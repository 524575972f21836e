"""The results screen: per triad the solution beside the simulation truth, the residual of every
position, and where the session and the parameter file are."""
from __future__ import annotations

from typing import ClassVar

from rich.text import Text
from textual.app import ComposeResult
from textual.binding import Binding, BindingType
from textual.containers import VerticalScroll
from textual.screen import Screen
from textual.widgets import Footer, Static

from fieldcal.report import comparison_table, solution_header, solution_table, worst_error
from fieldcal.tui.widgets.residuals import residual_bars
from fieldcal.tui.source import Outcome


def headline(outcome: Outcome) -> tuple[str, str]:
    counts = (f"{outcome.completed} position{'' if outcome.completed == 1 else 's'} done, "
              f"{outcome.skipped} skipped")
    if outcome.status == "completed":
        if outcome.solved and not outcome.unit.failures:
            return f"Calibration complete · {outcome.procedure.name} · {counts}", "ok"
        return f"Procedure complete, not everything calibrated · {counts}", "warn"
    return {"aborted": (f"Aborted · {counts}", "bad"), "error": ("Stopped by an error", "bad"),
            "incomplete": (f"Capture incomplete · {counts}", "warn"),
            "stopped": (f"Stopped · {counts}", "warn")}.get(outcome.status, (outcome.status, "warn"))


def where(outcome: Outcome) -> Text:
    text = Text()
    if outcome.replay_of is not None:
        text.append(f"replayed session: {outcome.replay_of}\n")
        if outcome.parameters is not None:
            text.append(f"recorded parameter file: {outcome.parameters}\n")
        if outcome.identical is True:
            text.append("the replay gives the recorded parameter file byte for byte", style="green")
        elif outcome.identical is False:
            text.append("the replay's parameter file DIFFERS from the recorded one", style="bold red")
        else:
            text.append("no recorded parameter file to compare with", style="grey62")
        return text
    if outcome.session is None:
        text.append("session: not captured (no session directory)\n", style="yellow")
    else:
        text.append(f"session: {outcome.session}\n")
    if outcome.parameters is not None:
        text.append(f"parameter file: {outcome.parameters}", style="green")
    else:
        text.append("parameter file: not written" +
                    (" (nothing calibrated)" if outcome.status == "completed" else ""), style="yellow")
    return text


class ResultsScreen(Screen):
    CSS_PATH = "results.tcss"
    BINDINGS: ClassVar[list[BindingType]] = [Binding("escape", "back", "back to the run")]

    def __init__(self, outcome: Outcome) -> None:
        super().__init__()
        self.outcome = outcome

    def compose(self) -> ComposeResult:
        out = self.outcome
        text, style = headline(out)
        yield Static(text, id="headline", classes=style)
        with VerticalScroll(id="results"):
            if out.message:
                yield Static(out.message, classes="message")
            unit = out.unit
            for name, sol in (unit.solutions.items() if unit is not None else ()):
                truth = out.truth.get(name)
                yield Static(solution_header(sol, effort=False), classes="triad-head").with_tooltip(solution_header(sol))
                yield Static(Text(solution_table(sol, truth)), classes="table")
                yield Static(residual_bars(sol), classes="residuals")
                previous = out.previous
                if previous is not None and name in previous.parameters.names:
                    yield Static(f"  beside {previous.describe()}:", classes="previous-head")
                    yield Static(Text(comparison_table(sol, previous.parameters[name])), classes="table")
            for name, why in (unit.failures.items() if unit is not None else ()):
                yield Static(Text(f"{name}: not calibrated: {why}"), classes="failure")
            if unit is not None and unit.solutions and out.truth:
                worst = worst_error(unit.solutions, out.truth)
                yield Static(f"largest error against the simulation truth: {worst:.2f}σ", classes="worst")
            yield Static(where(out), id="where")
        yield Footer()

    def on_mount(self) -> None:
        self.query_one("#results").focus()

    def action_back(self) -> None:
        self.app.pop_screen()
