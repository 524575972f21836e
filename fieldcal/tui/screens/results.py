"""The results screen: first the verdict per triad (and PASS/FAIL against the product spec when
one is given), the positions skipped and where the session and the parameter file are; then per
triad the solution beside the simulation truth, each parameter's PASS/FAIL with the reason, and
the residual of every position. PASS and FAIL are words with a mark (✓, ✗), not only colours."""
from __future__ import annotations

from typing import ClassVar

from rich.text import Text
from textual.app import ComposeResult
from textual.binding import Binding, BindingType
from textual.containers import Horizontal, Vertical, VerticalScroll
from textual.screen import Screen
from fieldcal.tui.widgets.toosmall import TooSmall
from textual.widgets import Footer, Static

from fieldcal.report import comparison_table, solution_header, solution_table, worst_error
from fieldcal.residuals import per_position, position_list, positions_phrase  # noqa: F401 (tests' import)
from fieldcal.tui.widgets.residuals import residual_bars
from fieldcal.tui.source import Outcome


PASS_MARK, FAIL_MARK = "✓ PASS", "✗ FAIL"


def acceptance(outcome: Outcome, spec) -> tuple[object | None, str]:
    """(the ``acceptance.Verdict`` of the run's parameter file against the product ``spec``, or
    None; why there is none, when a spec was given). The drift is against the unit's previous
    calibration, when the run found one."""
    if spec is None:
        return None, ""
    if outcome.parameter_file is None:
        return None, "acceptance not checked: nothing was calibrated"
    from fieldcal.acceptance import SpecError, evaluate

    previous = outcome.previous.parameters if outcome.previous is not None else None
    try:
        return evaluate(spec, outcome.parameter_file, previous), ""
    except SpecError as exc:  # a spec for another product (units that do not fit): say so, run on
        return None, f"acceptance not checked: {str(exc).splitlines()[0]}"


def triad_verdict(verdict, name: str) -> tuple[str, str]:
    """(mark, style) of one triad: PASS, FAIL, or "not in spec"."""
    checks = [c for c in verdict.checks if c.triad == name]
    if not checks:
        return "–", "grey62"  # the summary's notes say the triad is not in the spec
    return (PASS_MARK, "bold green") if all(c.passed for c in checks) else (FAIL_MARK, "bold red")


def verdict_column(table: str, sol, verdict) -> Text:
    """``solution_table``'s lines, each parameter's row followed by its PASS/FAIL; then one line
    per failed check of the triad with the reason (out of range, σ, residual, drift)."""
    checks = {c.parameter: c for c in verdict.checks if c.triad == sol.name}
    if not checks:
        return Text(table)
    lines = table.splitlines()
    width = max(map(len, lines), default=0)
    text = Text()
    for i, line in enumerate(lines):
        text.append(f"{line:<{width}}  ")
        if i == 0:
            text.append("result", style="bold")
        elif i - 1 < len(sol.parameter_names):
            c = checks.get(sol.parameter_names[i - 1])
            if c is not None:
                text.append(*((PASS_MARK, "green") if c.passed else (FAIL_MARK, "bold red")))
        text.append("\n")
    residual = checks.get("residual")
    if residual is not None:
        text.append(f"  residual RMS {residual.value:.3g} {residual.unit}  ")
        text.append(*((PASS_MARK, "green") if residual.passed else (FAIL_MARK, "bold red")))
        text.append("\n")
    from fieldcal.report import label

    for c in checks.values():
        if not c.passed:
            what = "residual" if c.parameter == "residual" else label(c.parameter)
            text.append(f"  ✗ {what}: {'; '.join(c.reasons)}\n", style="red")
    text.rstrip()
    return text


def headline(outcome: Outcome, verdict=None) -> tuple[str, str]:
    text, style = _headline(outcome)
    if verdict is None:
        return text, style
    # the verdict first: at 80 columns the end of the line may be cut
    if verdict.passed:
        return f"{PASS_MARK} {verdict.product} · {text}", style
    return f"{FAIL_MARK} {verdict.product} ({len(verdict.failures)} failed) · {text}", "bad"


def _headline(outcome: Outcome) -> tuple[str, str]:
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
        why = (" (no session)" if outcome.session is None else
               " (nothing calibrated)" if outcome.status == "completed" and not outcome.solved else "")
        text.append("parameter file: not written" + why, style="yellow")
    return text


def summary(outcome: Outcome, skipped: list[int], not_done: list[int], verdict=None,
            unchecked: str = "") -> Text:
    """The verdict per triad first (against the product spec, when given; solved, or refused and
    why; its worst residual; against the simulation truth, its largest error), then the positions
    skipped or not done."""
    text = Text()
    unit = outcome.unit
    solutions = unit.solutions if unit is not None else {}
    failures = unit.failures if unit is not None else {}
    width = max((len(n) for n in (*solutions, *failures)), default=0)
    for name, sol in solutions.items():
        rows, res_unit = per_position(sol)
        text.append(f"{name:<{width}}  ")
        if verdict is not None:  # PASS or FAIL says it was solved: the room goes to the residual
            mark, style = triad_verdict(verdict, name)
            text.append(f"{mark:<6}", style=style)
            text.append(" ")
        else:
            text.append("solved ", style="bold green")
        if rows:
            label, value, _ = max(rows, key=lambda r: abs(r[1]))
            text.append(f" worst residual {abs(value):.2g} {res_unit} ({label})")
        truth = outcome.truth.get(name)
        if truth is not None:
            worst = worst_error({name: sol}, {name: truth})
            text.append(f" · truth within {worst:.1f}σ", style="grey62")
        text.append("\n")
    for name, why in failures.items():
        text.append(f"{name:<{width}}  ")
        if verdict is not None:
            mark, style = triad_verdict(verdict, name)
            text.append(f"{mark:<6}", style=style)
            text.append("  ")
        text.append("refused", style="bold yellow")
        text.append(f"  {' '.join(str(why).split()).removeprefix(name + ': ')}\n")
    if outcome.status == "completed" and not solutions and not failures:
        text.append("nothing was solved\n", style="yellow")
    if outcome.procedure.targets and (solutions or failures):  # a planned procedure: its targets
        from fieldcal.tui.widgets.plan import solved_standings, target_text

        for standing in solved_standings(outcome.procedure, solutions):
            text.append(f"plan · {target_text(standing)}\n", style="green" if standing.met else "bold red")
    if verdict is not None:
        for c in verdict.checks:  # a triad the spec names that the run neither solved nor refused
            if c.parameter == "triad" and c.triad not in solutions and c.triad not in failures:
                text.append(f"{c.triad:<{width}}  ")
                text.append(FAIL_MARK, style="bold red")
                text.append(f"  {'; '.join(c.reasons)}\n")
        for note in verdict.notes:
            text.append(f"{note}\n", style="grey62")
    if unchecked:
        text.append(f"{unchecked}\n", style="bold red")
    text.append(f"skipped: {positions_phrase(skipped) if skipped else 'none'}", style="yellow" if skipped else "")
    if not_done:
        text.append(f" · not done: {positions_phrase(not_done)}", style="yellow")
    return text


WIDE = 110  # columns from which each triad's residuals sit beside its table


class ResultsScreen(Screen):
    """The summary (verdicts, skipped positions, where the files are) stays on top; each triad's
    parameters and residuals scroll below it, side by side on a wide terminal."""

    CSS_PATH = "results.tcss"
    BINDINGS: ClassVar[list[BindingType]] = [Binding("escape", "back", "back to the run")]

    def __init__(self, outcome: Outcome, skipped: list[int] = (), not_done: list[int] = (),
                 product_spec=None) -> None:
        """``skipped``, ``not_done``: position ids, as the run's tiles show them. ``product_spec``:
        an ``acceptance.ProductSpec`` to give PASS/FAIL against, or None."""
        super().__init__()
        self.outcome = outcome
        self.verdict, self.unchecked = acceptance(outcome, product_spec)
        self.skipped, self.not_done = list(skipped), list(not_done)
        self._wide: bool | None = None

    def compose(self) -> ComposeResult:
        out = self.outcome
        self._wide = self.app.size.width >= WIDE
        text, style = headline(out, self.verdict)
        yield Static(text, id="headline", classes=style)
        with Vertical(id="summary"):
            if out.message:
                yield Static(out.message, classes="message")
            yield Static(summary(out, self.skipped, self.not_done, self.verdict, self.unchecked),
                         id="verdicts")
            yield Static(where(out), id="where")
        unit = out.unit
        solutions = unit.solutions if unit is not None else {}
        if solutions:
            yield Static("parameters and residuals per triad below: ↑ ↓ PgUp PgDn scroll", id="scroll-hint")
        with VerticalScroll(id="results"):
            for name, sol in solutions.items():
                truth = out.truth.get(name)
                yield Static(solution_header(sol, effort=False), classes="triad-head").with_tooltip(solution_header(sol))
                with Horizontal(classes="triad-body wide" if self._wide else "triad-body"):
                    table = solution_table(sol, truth)
                    shown = Text(table) if self.verdict is None else verdict_column(table, sol, self.verdict)
                    yield Static(shown, classes="table")
                    yield Static(residual_bars(sol, columns=1 if self._wide else 2,
                                               bar_width=16 if self._wide else 10), classes="residuals")
                previous = out.previous
                if previous is not None and name in previous.parameters.names:
                    yield Static(f"  beside {previous.describe()}:", classes="previous-head")
                    yield Static(Text(comparison_table(sol, previous.parameters[name])), classes="table")
        yield Footer()
        yield TooSmall()

    def on_mount(self) -> None:
        self.query_one("#results").focus()

    def on_resize(self) -> None:
        if self._wide is not None and (self.app.size.width >= WIDE) != self._wide:
            self.refresh(recompose=True)

    def action_back(self) -> None:
        self.app.pop_screen()
