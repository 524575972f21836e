"""The live panel: readings, angle to the target, stillness, dwell and table progress; on its
bottom edge the unit's temperature and its span so far, where the device reports one (the panel
keeps its height, so 80×24 still holds every row)."""
from __future__ import annotations

from rich.text import Text
from textual.app import ComposeResult
from textual.containers import Vertical
from textual.widgets import Static

from fieldcal.tui.widgets.bars import bar
from fieldcal.tui.widgets.shown import show
from fieldcal.tui.view import RunView

ROWS = ("accel", "gyro", "target", "still", "dwell", "table", "turns")
BAR = 16


def _label(name: str) -> Text:
    return Text(f"{name:<9}", style="bold")


def _vector(values, fmt: str, style: str = "") -> Text:
    text = Text()
    for axis, v in zip("xyz", values):
        text.append(f"{axis} ", style="grey62")
        text.append(format(v, fmt) + " ", style=style)
    return text


def _progress(done: float, total: float, running: bool, complete: bool, style: str, width: int = BAR) -> Text:
    if total <= 0:
        return Text("—", style="grey50")
    text = bar(done / total, width, style=style)
    left = max(0.0, total - done)
    text.append(f" {done:4.0f}/{total:.0f} s", style="bold" if running else "")
    if complete:
        text.append("  done", style="green")
    elif running:
        text.append(f"  {left:.0f} s left")
    elif done > 0:
        text.append("  held", style="yellow")
    return text


def rows(view: RunView, bar_width: int = BAR) -> dict[str, Text]:
    """The panel's lines for the current state (a pure function, for tests). Readings that are
    not current (the simulator paused, the run ended) are dimmed and say why; stillness is not
    claimed from them."""
    tel = view.telemetry
    stale = view.stale_reason()
    dim = "grey50" if stale else ""
    out = {}
    if tel is None or tel.accel_mg is None:
        out["accel"] = _label("accel mg") + Text("no samples yet", style="grey50")
        out["gyro"] = _label("gyro °/s") + Text("")
    else:
        out["accel"] = _label("accel mg") + _vector(tel.accel_mg, "+9.1f", dim)
        out["gyro"] = _label("gyro °/s") + _vector(tel.gyro_deg_s, "+9.3f", dim)
    target = _label("target")
    if tel is not None and tel.angle_deg is not None and view.step < view.total_steps and not stale:
        ok = tel.angle_deg <= view.tolerance_deg
        target.append(f"{tel.angle_deg:5.1f}°", style="bold green" if ok else "bold red")
        target.append(f" from position {view.position.id}'s up, ")
        target.append("ok" if ok else f"over {view.tolerance_deg:.0f}°", style="green" if ok else "red")
    else:
        target.append("—", style="grey50")
    out["target"] = target
    still = _label("still")
    if stale:
        still.append(f"— ({stale})", style="grey50")
    elif tel is None or tel.quiet is None:
        still.append("— (filling the window)", style="grey50")
    else:
        q = tel.quiet
        turning = view.table_state != "stopped"
        state, style = ((("steady turn" if turning else "still"), "green") if q < view.enter_factor else
                        ("moving", "red") if q > view.leave_factor else ("settling", "yellow"))
        still.append_text(bar(q / (2 * view.leave_factor), bar_width * 5 // 8, style=style))
        still.append(f" {q:5.1f}σ ", style=style)
        still.append(state, style=f"bold {style}")
    out["still"] = still
    t = view.t
    d = view.dwell
    silent = tel is not None and tel.silent_s is not None  # no samples: the dwell and turns wait
    ended = view.finished is not None and view.finished != "completed"
    if ended:
        dwell = _label("dwell") + Text(f"— (run {view.finished})", style="grey50")
    else:
        dwell = _label("dwell") + _progress(d.done(t), d.total, d.anchor is not None and not silent, d.complete, "green",
                                            bar_width)
    if view.restarts:
        dwell.append(f"  ↺{view.restarts}", style="yellow")
    out["dwell"] = dwell
    table = _label("table")
    if view.table_rate:
        table.append(f"{view.table_rate:+.1f} °/s ", style="bold")
    else:
        table.append("0 °/s ", style="bold")
    table.append({"stopped": "stopped", "ramping": "ramping, waiting until steady",
                  "steady": "steady, averaging whole turns", "disturbed": "disturbed: waiting again",
                  "stopping": "stopping"}.get(view.table_state, view.table_state),
                 style={"steady": "green", "disturbed": "red", "ramping": "yellow"}.get(view.table_state, ""))
    out["table"] = table
    tr = view.turns
    if ended:
        out["turns"] = _label("turns") + Text("—", style="grey50")
    else:
        out["turns"] = _label("turns") + _progress(tr.done(t), tr.total, tr.anchor is not None and not silent, tr.complete,
                                                   "cyan", bar_width)
    return out


def temperature_text(view: RunView) -> str:
    """"23.4 °C · span 20.1 to 23.4 °C (3.3 K)", or "" where the device reports no temperature."""
    tel = view.telemetry
    if tel is None or tel.temperature_c is None or tel.temperature_span_c is None:
        return ""
    low, high = tel.temperature_span_c
    return f"{tel.temperature_c:.1f} °C · span {low:.1f} to {high:.1f} °C ({high - low:.1f} K)"


class LivePanel(Vertical):
    def __init__(self, **kw) -> None:
        super().__init__(**kw)
        self._rows = {name: Static("", id=f"live-{name}", classes="live-row") for name in ROWS}

    def compose(self) -> ComposeResult:
        yield from self._rows.values()

    def update(self, view: RunView, bar_width: int = BAR) -> None:
        for name, text in rows(view, bar_width).items():
            show(self._rows[name], text, fixed_size=True)  # a row is one line (.live-row), its text cut
        self.border_subtitle = temperature_text(view)
