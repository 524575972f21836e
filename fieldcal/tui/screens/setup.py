"""The setup screen: the device config, its and the table's ports (beside the serial ports
present), the procedure and the station, before a run.

``SetupScreen(initial)`` dismisses with the operator's ``SetupChoice`` (already checked by
``resolve_choice`` and remembered with ``save_last_choice``), or with None when the operator quits
(Esc, or q outside a text field). Start: ctrl+s anywhere or the button (Enter in a text field
moves to the next field). The operator, the unit's serial (into the config's device.serial),
the sessions directory and the product spec ride on the choice.

Given a sessions directory, it also offers the unfinished sessions there: Resume dismisses with a
``ResumeChoice`` (a live session's ports: the config chosen above, checked like Start's).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

from textual import on
from textual.app import ComposeResult
from textual.binding import Binding, BindingType
from textual.containers import Horizontal
from textual.screen import Screen
from fieldcal.tui.widgets.toosmall import TooSmall
from textual.widgets import Button, Footer, Input, Label, Select, Static

from fieldcal.config import CONFIGS_DIR, StationConfig
from fieldcal.procedure.positions import Procedure
from fieldcal.tui.view import PLACING_GUESS_S, duration_words, job_duration_s, rate_step_s
from fieldcal.tui.choices import (
    SetupChoice,
    available_configs,
    available_procedures,
    load_choice_config,
    load_choice_procedure,
    resolve_choice,
    save_last_choice,
    unfinished_sessions,
)

SIMULATED = "simulated"
DEFAULT_CONFIG = "sim"
DEFAULT_PROCEDURE = "field-18"


def config_summary(config: StationConfig) -> str:
    """One line: device name, protocol, rate, and the table's protocol or "no table"."""
    device = config.device
    table = f"table {config.table.protocol}" if config.table is not None else "no table"
    return f"{device.name} · {device.protocol} · {device.rate_hz:g} Hz · {table}"


def procedure_summary(procedure: Procedure) -> str:
    """One line: positions, dwell, and the table's rate step if any."""
    n = len(procedure.positions)
    text = f"{n} position{'' if n == 1 else 's'} · {procedure.dwell_s:g} s dwells"
    steps = procedure.rate_steps
    if steps:
        text += " · table ±" + "/".join(f"{rate:g}" for rate in sorted({s.rate_deg_s for s in steps})) + " °/s"
        turning = sum(procedure.rate_step_at(i) is not None for i in range(n))
        if turning < n:
            text += f" at {turning} of {n} positions"
    return text


def duration_summary(procedure: Procedure) -> str:
    """The whole job's expected time, and what it is made of."""
    n = len(procedure.positions)
    turning = sum(procedure.rate_step_at(i) is not None for i in range(n))
    every = turning == n and len(procedure.rate_steps) == 1  # one rate step, at every position
    rate = f" + 2 × {rate_step_s(procedure):.0f} s turning" if every else ""
    some = f", turning at {turning} of them" if turning and not every else ""
    return (f"whole job ≈ {duration_words(job_duration_s(procedure))}: {n} × "
            f"(≈{PLACING_GUESS_S:.0f} s placing + {procedure.dwell_s:g} s dwell{rate}){some}")


def load_spec_choice(path: str | None):
    """The product spec the spec field names (None: none); a one-line ValueError naming it."""
    if path is None:
        return None
    from fieldcal.acceptance import load_spec

    try:
        return load_spec(path)
    except (ValueError, OSError) as exc:
        raise ValueError(f"spec: {' '.join(str(exc).split())}") from None


def serial_ports_text() -> str:
    """One line: the serial ports present, with their USB descriptions (pyserial's list_ports)."""
    from serial.tools import list_ports

    try:
        ports = sorted(list_ports.comports(), key=lambda p: p.device)
    except OSError as exc:  # pragma: no cover - a system without the usual device directories
        return f"serial ports: cannot list them ({exc})"
    if not ports:
        return "serial ports here: none found"
    shown = [p.device if p.description in (None, "", "n/a", p.device) else f"{p.device} ({p.description})"
             for p in ports]
    return "serial ports here: " + ", ".join(shown)


def _format_number(value: float) -> str:
    """The shortest text that reads back as the same float: 40, 45.5, 45.123456789."""
    value = float(value)
    return str(int(value)) if value.is_integer() and abs(value) < 1e15 else repr(value)


def _config_name(config: str) -> str:
    """A path to one of the shipped configs is shown as its name."""
    path = Path(config)
    if path.suffix == ".yaml":
        try:
            if path.resolve() == (CONFIGS_DIR / path.name).resolve():
                return path.stem
        except OSError:  # pragma: no cover
            pass
    return config


@dataclass(frozen=True)
class ResumeChoice:
    """The operator chose to resume this unfinished session."""

    session: Path
    live: bool  # a real device's session (its ports: the screen's ``resolved`` config)


class SetupScreen(Screen[SetupChoice | ResumeChoice | None]):
    """Pick the device config, port, procedure and station; dismiss(SetupChoice) on Start, or
    dismiss(None) on Esc / q."""

    CSS_PATH = "setup.tcss"
    AUTO_FOCUS = "#config"
    BINDINGS: ClassVar[list[BindingType]] = [
        Binding("ctrl+s", "start", "start", priority=True),
        Binding("ctrl+r", "resume", "resume", priority=True),
        Binding("escape", "quit", "quit"),
        Binding("q", "quit", "quit", show=False),
    ]

    def __init__(self, initial: SetupChoice | None = None,
                 last_choice_path: str | Path | None = None, sessions: str | Path | None = None) -> None:
        """``initial``: the values to show first (the caller merges the command line and the
        remembered choice); None: the sim config and field-18 with the config's station.
        ``last_choice_path``: where Start remembers the choice (default: the XDG location).
        ``sessions``: the sessions directory, whose unfinished sessions are offered to resume."""
        super().__init__()
        self.unfinished = unfinished_sessions(sessions) if sessions is not None else []
        self.initial = initial
        self.last_choice_path = last_choice_path
        self.config: StationConfig | None = None  # the config currently chosen, if it loads
        self.procedure: Procedure | None = None
        self.resolved: tuple[StationConfig, Procedure] | None = None  # after a successful Start
        self.product_spec = None  # the spec file's ProductSpec, after a successful Start
        self._prefilled_from: Path | None = None  # the config the port and station came from
        self._selected_config: object = None  # the config list's value, to tell a new choice
        self._configs = available_configs()
        self._procedures = available_procedures()

    # --- layout -------------------------------------------------------------------------------

    def compose(self) -> ComposeResult:
        initial = self.initial
        config = _config_name(initial.config) if initial is not None else DEFAULT_CONFIG
        config_names = list(self._configs)
        config_path = ""
        if config not in config_names:
            config_path = config
            config = DEFAULT_CONFIG
        if config not in config_names and config_names:
            config = config_names[0]
        procedure = initial.procedure if initial is not None else DEFAULT_PROCEDURE
        procedure_names = list(self._procedures)
        if procedure not in procedure_names:
            if initial is not None and procedure.strip():
                procedure_names.append(procedure)  # a path: offered as it was given
            elif procedure_names:
                procedure = procedure_names[0]

        self._selected_config = config if config_names else Select.NULL
        yield Static("fieldcal · setup", id="title")
        # Compact fields (one line each): every one, the error and Start fit 80×24.
        with Horizontal(classes="row"):
            yield Label("Config", classes="label")
            yield Select([(n, n) for n in config_names], value=config if config_names else Select.NULL,
                         allow_blank=not config_names, id="config", compact=True)
            yield Label("or file", classes="label small")
            yield Input(config_path, placeholder="path/to/config.yaml", id="config-path", compact=True)
        yield Static("", id="config-summary", classes="summary")
        with Horizontal(classes="row"):
            yield Label("IMU port", classes="label")
            yield Input("", placeholder="pyserial URL, e.g. /dev/ttyUSB0", id="port", compact=True)
            yield Label("table", classes="label small")
            yield Input("", placeholder="e.g. /dev/ttyACM0", id="table-port", compact=True)
        yield Static(serial_ports_text(), id="ports", classes="summary")
        with Horizontal(classes="row"):
            yield Label("Procedure", classes="label")
            yield Select([(n, n) for n in procedure_names],
                         value=procedure if procedure_names else Select.NULL,
                         allow_blank=not procedure_names, id="procedure", compact=True)
            yield Static("", id="procedure-summary", classes="summary")
        yield Static("", id="duration", classes="summary")
        with Horizontal(classes="row"):
            yield Label("Latitude", classes="label")
            yield Input("", type="number", id="latitude", compact=True)
            yield Label("°", classes="unit")
            yield Label("Height", classes="label small")
            yield Input("", type="number", id="height", compact=True)
            yield Label("m", classes="unit")
        with Horizontal(classes="row"):
            yield Label("Operator", classes="label")
            yield Input(self._extra("operator"), placeholder="name or initials", id="operator", compact=True)
            yield Label("unit serial", classes="label small")
            yield Input("", placeholder="printed on the unit", id="unit-serial", compact=True)
        with Horizontal(classes="row"):
            yield Label("Sessions", classes="label")
            yield Input(self._extra("out"), placeholder="directory", id="out", compact=True)
            yield Label("spec", classes="label small")
            yield Input(self._extra("spec"), placeholder="limits file (optional)", id="spec", compact=True)
        if self.unfinished:
            with Horizontal(classes="row"):
                yield Label("Unfinished", classes="label")
                yield Select([(u.label, str(u.path)) for u in self.unfinished], prompt="a session to resume",
                             value=str(self.unfinished[0].path), id="unfinished", compact=True)
                yield Button("Resume", id="resume", compact=True)
        yield Static("", id="error")
        with Horizontal(id="actions"):
            start = Button("Start", id="start", variant="success")
            start.can_focus = False  # Enter moves between the fields; only ctrl+s or a click starts
            yield start
            yield Static("ctrl+s: start · Enter: next field · Esc: quit", id="hint")
        yield Footer()
        yield TooSmall()

    def _extra(self, name: str) -> str:
        value = getattr(self.initial, name, None) if self.initial is not None else None
        return value or ""

    def on_mount(self) -> None:
        initial = self.initial
        self._load_config()
        if initial is not None:
            port = self.query_one("#port", Input)
            if initial.port and not port.disabled:
                port.value = initial.port
            table = self.query_one("#table-port", Input)
            if initial.table_port and not table.disabled:
                table.value = initial.table_port
            self.query_one("#latitude", Input).value = _format_number(initial.latitude_deg)
            self.query_one("#height", Input).value = _format_number(initial.height_m)
        if initial is not None and initial.unit_serial:
            self.query_one("#unit-serial", Input).value = initial.unit_serial
        self._load_procedure()
        self.set_error("")

    # --- what is chosen -----------------------------------------------------------------------

    def config_text(self) -> str:
        """The config as chosen: the path if one is typed, else the selected name."""
        path = self.query_one("#config-path", Input).value.strip()
        if path:
            name = _config_name(path)
            if name == path and Path(path).is_file():
                return str(Path(path).resolve())  # remembered: valid from any directory
            return name
        value = self.query_one("#config", Select).value
        return "" if value is Select.NULL else str(value)

    def procedure_text(self) -> str:
        value = self.query_one("#procedure", Select).value
        return "" if value is Select.NULL else str(value)

    def _load_config(self) -> None:
        """Load the chosen config into the summary; a newly chosen one prefills port and station."""
        summary = self.query_one("#config-summary", Static)
        try:
            config = load_choice_config(self.config_text())
        except ValueError as exc:
            self.config = None
            summary.update(str(exc))
            summary.set_class(True, "bad")
            return
        summary.update(config_summary(config))
        summary.set_class(False, "bad")
        self.config = config
        where = Path(config.path).resolve()
        if where == self._prefilled_from:
            return  # the same config again (or back after a half-typed path): keep the fields
        self._prefilled_from = where
        port = self.query_one("#port", Input)
        if config.device.port is None:
            port.value, port.disabled = SIMULATED, True
        else:
            port.disabled = False
            port.value = config.device.port.url
        table = self.query_one("#table-port", Input)
        if config.table is None or config.table.port is None:
            table.value, table.disabled = "no table" if config.table is None else SIMULATED, True
        else:
            table.disabled = False
            table.value = config.table.port.url
        self.query_one("#latitude", Input).value = _format_number(config.station.latitude_deg)
        self.query_one("#height", Input).value = _format_number(config.station.height_m)
        self.query_one("#unit-serial", Input).value = config.device.serial or ""

    def _load_procedure(self) -> None:
        summary = self.query_one("#procedure-summary", Static)
        try:
            self.procedure = load_choice_procedure(self.procedure_text())
        except ValueError as exc:
            self.procedure = None
            summary.update(str(exc))
            summary.set_class(True, "bad")
            self.query_one("#duration", Static).update("")
            return
        summary.update(procedure_summary(self.procedure))
        summary.set_class(False, "bad")
        self.query_one("#duration", Static).update(duration_summary(self.procedure))

    def set_error(self, message: str) -> None:
        error = self.query_one("#error", Static)
        error.update(message)
        error.display = bool(message)

    def choice(self) -> SetupChoice:
        """The choice the fields show; ValueError (naming the field) if a number does not parse."""
        config = self.config
        own = config.device.port.url if config is not None and config.device.port else None
        port = self._override("#port", own)
        table = config.table if config is not None else None
        table_port = self._override("#table-port", table.port.url if table and table.port else None)
        numbers = []
        for field, name, unit in (("latitude", "latitude", "°"), ("height", "height", "m")):
            text = self.query_one(f"#{field}", Input).value.strip()
            try:
                numbers.append(float(text))
            except ValueError:
                raise ValueError(f"{name}: expected a number in {unit}, got {text!r}") from None
        config_serial = config.device.serial if config is not None else None
        serial = self._text("#unit-serial") or ""  # "": cleared, the unit has no serial given
        return SetupChoice(self.config_text(), port, self.procedure_text(), numbers[0], numbers[1], table_port,
                           operator=self._text("#operator"), out=self._text("#out"), spec=self._text("#spec"),
                           unit_serial=serial if serial != (config_serial or "") else None)

    def _text(self, field: str) -> str | None:
        """A text field's value, None when blank."""
        text = self.query_one(field, Input).value.strip()
        return text or None

    def _override(self, field: str, own: str | None) -> str | None:
        """A port field's text, if it differs from the config's own port (None: keep that)."""
        field_input = self.query_one(field, Input)
        if field_input.disabled:
            return None
        text = field_input.value.strip()
        return text if text and text != own else None

    # --- events -------------------------------------------------------------------------------

    @on(Select.Changed, "#config")
    def _config_selected(self, event: Select.Changed) -> None:
        if event.value == self._selected_config:
            return  # the initial selection being set up
        self._selected_config = event.value
        path = self.query_one("#config-path", Input)
        if path.value:
            path.value = ""  # choosing from the list replaces a typed path (its Changed reloads)
        else:
            self._load_config()

    @on(Input.Changed, "#config-path")
    def _config_path_changed(self) -> None:
        self._load_config()

    @on(Select.Changed, "#procedure")
    def _procedure_selected(self) -> None:
        self._load_procedure()

    @on(Input.Changed)
    def _edited(self) -> None:
        self.set_error("")

    @on(Input.Submitted)
    def _submitted(self) -> None:
        self.focus_next()  # Enter moves on: a run of 85 minutes starts on one explicit key only

    @on(Button.Pressed, "#start")
    def _start_pressed(self) -> None:
        self.action_start()

    @on(Button.Pressed, "#resume")
    def _resume_pressed(self) -> None:
        self.action_resume()

    # --- actions ------------------------------------------------------------------------------

    def action_start(self) -> None:
        try:
            choice = self.choice()
            self.resolved = resolve_choice(choice)
            self.product_spec = load_spec_choice(choice.spec)
        except ValueError as exc:
            self.set_error(" ".join(str(exc).split()))
            return
        try:
            save_last_choice(choice, self.last_choice_path)
        except (OSError, ValueError) as exc:  # ValueError: the write rule's refusal (a link)
            self.app.notify(f"could not remember this setup: {exc}", severity="warning")
        self.dismiss(choice)

    def check_action(self, action: str, parameters: tuple[object, ...]) -> bool | None:
        return bool(self.unfinished) if action == "resume" else True  # offered when there is one

    def action_resume(self) -> None:
        """Resume the unfinished session chosen; a live one on the ports the fields show."""
        value = self.query_one("#unfinished", Select).value
        if value is Select.NULL:
            self.set_error("resume: choose an unfinished session first")
            return
        session = next(u for u in self.unfinished if str(u.path) == value)
        self.resolved = None
        if session.device is not None:  # its ports: the fields', if they are of its device
            try:
                self.resolved = resolve_choice(self.choice())
            except ValueError:
                pass  # (the session's own config is found without them)
        self.dismiss(ResumeChoice(session.path, session.device is not None))

    def action_quit(self) -> None:
        self.dismiss(None)
