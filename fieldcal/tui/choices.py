"""What the operator chose on the setup screen, remembered between runs, and turned into a run.

No Textual here: ``SetupChoice`` is plain data, ``load_last_choice`` / ``save_last_choice`` keep the
last one in ``$XDG_CONFIG_HOME/fieldcal/last-setup.yaml`` (default ``~/.config/fieldcal/``), and
``resolve_choice`` loads the config and procedure it names, every problem a one-line ValueError.
"""
from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass
from pathlib import Path

import yaml

from fieldcal.atomic import write_atomically
from fieldcal.config import StationConfig, load_config
from fieldcal.earth import Station
from fieldcal.paths import find_named, shipped_names
from fieldcal.procedure.positions import Procedure, load_procedure
from fieldcal.validation import read_yaml_file

LAST_SETUP_NAME = "last-setup.yaml"
LATITUDE_RANGE = (-90.0, 90.0)
HEIGHT_RANGE = (-500.0, 9000.0)  # what fieldcal.earth.Station accepts
_FIELDS = ("config", "port", "procedure", "latitude_deg", "height_m")


@dataclass(frozen=True)
class SetupChoice:
    """A run as the operator picked it.

    ``config``: a config name (``configs/NAME.yaml``) or a path. ``port``: a pyserial URL that
    overrides the config's device port, None to keep the config's (always None for the
    simulator); ``table_port`` the same for the table's. ``procedure``: a procedure name (``procedures/NAME.yaml``) or a path.
    """

    config: str
    port: str | None
    procedure: str
    latitude_deg: float
    height_m: float
    table_port: str | None = None  # overrides the config's table port, like ``port``
    operator: str | None = None  # who calibrates (None: the command line's --operator, if any)
    unit_serial: str | None = None  # into the config's device.serial ("": none; None: the config's); never remembered
    out: str | None = None  # the sessions directory (None: the command line's --out)
    spec: str | None = None  # the product spec (acceptance limits) file; None: none


def last_choice_path() -> Path:
    """``$XDG_CONFIG_HOME/fieldcal/last-setup.yaml``; ``~/.config`` when the variable is unset,
    empty or relative (as the XDG base-directory specification says)."""
    base = os.environ.get("XDG_CONFIG_HOME", "")
    root = Path(base) if base and os.path.isabs(base) else Path.home() / ".config"
    return root / "fieldcal" / LAST_SETUP_NAME


def _number(value) -> float | None:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    value = float(value)
    return value if math.isfinite(value) else None


def _choice_from(raw) -> SetupChoice | None:
    """A SetupChoice from a parsed mapping, or None if anything is missing or of the wrong kind."""
    if not isinstance(raw, dict) or any(k not in raw for k in _FIELDS):
        return None
    config, port, procedure = raw["config"], raw["port"], raw["procedure"]
    if not isinstance(config, str) or not config.strip():
        return None
    if not isinstance(procedure, str) or not procedure.strip():
        return None
    if port is not None and (not isinstance(port, str) or not port.strip()):
        return None
    table_port = raw.get("table_port")  # absent in files written before the table had a field
    if table_port is not None and (not isinstance(table_port, str) or not table_port.strip()):
        return None
    latitude, height = _number(raw["latitude_deg"]), _number(raw["height_m"])
    if latitude is None or height is None:
        return None
    if not LATITUDE_RANGE[0] <= latitude <= LATITUDE_RANGE[1] or not HEIGHT_RANGE[0] <= height <= HEIGHT_RANGE[1]:
        return None
    extras = {key: raw.get(key) for key in _REMEMBERED_EXTRAS}  # absent in older files
    if any(v is not None and (not isinstance(v, str) or not v.strip()) for v in extras.values()):
        return None
    return SetupChoice(config, port, procedure, latitude, height, table_port, **extras)


# Remembered with the choice when given; the unit's serial never is (the next unit is another),
# nor the sessions directory (the command line's --out, default ./sessions, says it each time).
_REMEMBERED_EXTRAS = ("operator", "spec")


def load_last_choice(path: str | os.PathLike | None = None) -> SetupChoice | None:
    """The remembered choice, or None when there is none or the file is damaged or unreadable
    (a remembered choice is a convenience: it never stops the station from starting)."""
    path = Path(path) if path is not None else last_choice_path()
    try:
        raw = read_yaml_file(path, ValueError, "remembered setup")  # the strict loader: no alias bombs
    except ValueError:
        return None
    return _choice_from(raw)


def save_last_choice(choice: SetupChoice, path: str | os.PathLike | None = None) -> Path:
    """Write the choice atomically (a temporary file beside it, then os.replace); the path.
    Raises OSError if it cannot be written."""
    path = Path(path) if path is not None else last_choice_path()
    path.parent.mkdir(parents=True, exist_ok=True)
    data = {"config": choice.config, "port": choice.port, "table_port": choice.table_port,
            "procedure": choice.procedure, "latitude_deg": float(choice.latitude_deg),
            "height_m": float(choice.height_m)}
    data.update({key: getattr(choice, key) for key in _REMEMBERED_EXTRAS if getattr(choice, key) is not None})
    text = ("# the last setup chosen in `fieldcal tui`; delete this file to forget it\n"
            + yaml.safe_dump(data, sort_keys=False, allow_unicode=True))
    return write_atomically(path, text.encode("utf-8"), state=True)


def available_configs() -> list[str]:
    """Names of the shipped configs (sorted)."""
    return shipped_names("config")


def available_procedures() -> list[str]:
    """Names of the shipped procedures (sorted)."""
    return shipped_names("procedure")


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split())


def _looks_like_name(text: str) -> bool:
    return not Path(text).suffix and "/" not in text and os.sep not in text


def load_choice_config(config: str) -> StationConfig:
    """The config a choice names; a one-line ValueError otherwise."""
    name = config.strip()
    if not name:
        raise ValueError("config: choose a config or give the path of one")
    if _looks_like_name(name) and find_named(name, "config") is None:
        known = ", ".join(available_configs()) or "none"
        raise ValueError(f"config: no config named {name!r} (none here, and the shipped configs: {known})")
    try:
        return load_config(name)
    except (ValueError, OSError) as exc:
        raise ValueError(f"config: {_one_line(exc)}") from None


def load_choice_procedure(procedure: str) -> Procedure:
    """The procedure a choice names; a one-line ValueError otherwise."""
    name = procedure.strip()
    if not name:
        raise ValueError("procedure: choose a procedure or give the path of one")
    if _looks_like_name(name) and find_named(name, "procedure") is None:
        known = ", ".join(available_procedures()) or "none"
        raise ValueError(f"procedure: no procedure named {name!r} (none here, and the shipped procedures: {known})")
    try:
        return load_procedure(name)
    except (ValueError, OSError) as exc:
        raise ValueError(f"procedure: {_one_line(exc)}") from None


def _shown(value) -> str:
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return f"{value:g}" if math.isfinite(value) else str(value)
    return repr(value)


def check_station(latitude_deg: float, height_m: float) -> None:
    """Latitude and height in the ranges Station accepts; a one-line ValueError naming the field."""
    lo, hi = LATITUDE_RANGE
    if isinstance(latitude_deg, bool) or not isinstance(latitude_deg, (int, float)) \
            or not lo <= latitude_deg <= hi:
        raise ValueError(f"latitude: expected {lo:g} to {hi:g}°, got {_shown(latitude_deg)}")
    lo, hi = HEIGHT_RANGE
    if isinstance(height_m, bool) or not isinstance(height_m, (int, float)) or not lo <= height_m <= hi:
        raise ValueError(f"height: expected {lo:g} to {hi:g} m above the ellipsoid, got {_shown(height_m)}")


def resolve_choice(choice: SetupChoice) -> tuple[StationConfig, Procedure]:
    """The config (with the port override and the chosen station) and the procedure of a choice.

    Raises ValueError with a one-line message naming the field: an unknown or invalid config or
    procedure, a latitude outside -90..90°, a height outside -500..9000 m, a port given for the
    simulator (or a table port for no table) or a port that is not one line. A measured gravity in the config
    (``station.gravity_m_s2``) is kept.
    """
    check_station(choice.latitude_deg, choice.height_m)
    config = load_choice_config(choice.config)
    procedure = load_choice_procedure(choice.procedure)
    device = config.device
    if choice.port is not None:
        port = choice.port.strip()
        if device.port is None:
            raise ValueError(f"port: {device.name} is simulated ({config.path}): it has no port to "
                             f"override, got {choice.port!r}")
        if not port or any(c.isspace() for c in port):
            raise ValueError(f"port: expected a pyserial URL such as /dev/ttyUSB0 or "
                             f"socket://host:4001, got {choice.port!r}")
        device = dataclasses.replace(device, port=dataclasses.replace(device.port, url=port))
    table = config.table
    if choice.table_port is not None:
        port = choice.table_port.strip()
        if table is None or table.port is None:
            what = "has no table" if table is None else "has a simulated table"
            raise ValueError(f"table port: {config.path} {what}: no port to override, got {choice.table_port!r}")
        if not port or any(c.isspace() for c in port):
            raise ValueError(f"table port: expected a pyserial URL such as /dev/ttyACM0, got {choice.table_port!r}")
        table = dataclasses.replace(table, port=dataclasses.replace(table.port, url=port))
    if choice.unit_serial is not None:  # "": the config's serial cleared (not this unit's)
        serial = checked_unit_serial(choice.unit_serial) if choice.unit_serial else None
        device = dataclasses.replace(device, serial=serial)
    if choice.operator is not None:
        check_operator(choice.operator)
    if choice.out is not None and Path(choice.out).exists() and not Path(choice.out).is_dir():
        raise ValueError(f"sessions directory: {choice.out} is not a directory")
    try:
        station = Station(float(choice.latitude_deg), float(choice.height_m), config.station.gravity_m_s2)
    except ValueError as exc:  # pragma: no cover - check_station has the same bounds
        raise ValueError(f"station: {_one_line(exc)}") from None
    return dataclasses.replace(config, device=device, table=table, station=station), procedure


def checked_unit_serial(text: str) -> str:
    """A unit's serial as typed, checked as the config's device.serial is: one-line ValueError."""
    serial = text.strip()
    if not serial or not serial.isprintable():
        raise ValueError(f"unit serial: expected the serial printed on the unit (printable "
                         f"characters), got {text!r}"[:200])
    return serial


def check_operator(name: str) -> None:
    from fieldcal.paramfile.document import OPERATOR_MAX, valid_operator

    if not valid_operator(name):
        raise ValueError(f"operator: expected a name of 1 to {OPERATOR_MAX} printable characters "
                         f"without blanks around it, got {name!r}"[:200])


def config_for_session(live, chosen: StationConfig | None) -> StationConfig:
    """The station config a live session (its ``LiveDevice``) is resumed on: the one chosen on the
    setup screen if it is of the session's device (name and protocol), else the first shipped
    config that is, on the port the session was recorded on; with the session's own serial (it
    is the same unit). A one-line ValueError, short enough for the setup screen, when none is."""
    def same_device(config: StationConfig) -> bool:
        return (config.device.name, config.device.protocol) == (live.name, live.protocol)

    found = chosen if chosen is not None and same_device(chosen) else None
    if found is None:
        for name in available_configs():
            try:
                config = load_config(name)
            except (ValueError, OSError):
                continue
            if same_device(config) and config.device.port is not None:
                port = dataclasses.replace(config.device.port, url=live.url)
                found = dataclasses.replace(config, device=dataclasses.replace(config.device, port=port))
                break
    if found is None:
        raise ValueError(f"resume: the session is of {live.name} ({live.protocol}); choose that unit's "
                         "config above (its ports), then resume")
    return dataclasses.replace(found, device=dataclasses.replace(found.device, serial=live.serial))


# --- unfinished sessions, to resume --------------------------------------------------------

UNFINISHED_LISTED = 12  # the newest sessions looked at (each one's log is read)
LOG_TAIL_BYTES = 65536  # where a log's stop document is looked for first


@dataclass(frozen=True)
class UnfinishedSession:
    """A session the setup screen offers to resume."""

    path: Path
    procedure: str
    done: int  # completed steps
    total: int  # the procedure's positions
    device: str | None  # a real device's name; None: the simulator

    @property
    def label(self) -> str:
        return f"{self.path.name} ({self.done}/{self.total} done)"  # the name says sim or live


def resume_refusal(record) -> str | None:
    """Why a session (its ``RunRecord``) cannot be resumed, or None if it can."""
    if record.stopped:
        return (f"already ended ({record.stop_reason}); "
                + ("a completed session is never resumed: replay it with `fieldcal tui --replay`"
                   if record.stop_reason == "completed" else "nothing to resume"))
    if record.start.get("device", {}).get("link") == "pty":
        return "ran through a serial device, which cannot be rewound; replay it, or run again"
    return None


def _ends_stopped(log: Path) -> bool:
    """Does the log's tail hold a ``stop`` after any ``resume``? A cheap look, so that ended runs
    (most of a sessions directory, with logs of many megabytes) are passed over unread; a stop
    beyond the tail is found by reading the whole log."""
    with open(log, "rb") as fh:
        fh.seek(max(0, fh.seek(0, os.SEEK_END) - LOG_TAIL_BYTES))
        tail = fh.read()
    return tail.rfind(b'"type":"stop"') > tail.rfind(b'"type":"resume"')


def unfinished_sessions(directory: str | os.PathLike) -> list[UnfinishedSession]:
    """The sessions under ``directory`` that can be resumed, newest first: not ended, not being
    written by another process, and procedure runs (of the newest ``UNFINISHED_LISTED``).
    A session that cannot be read is passed over: the list is an offer, not a check."""
    from fieldcal.run.runner import open_run
    from fieldcal.session.capture import LOG
    from fieldcal.session.lock import is_held

    def modified(path: Path) -> float:
        try:
            return path.stat().st_mtime
        except OSError:  # gone meanwhile
            return -1.0

    try:
        logs = [p for p in Path(directory).glob(f"*/{LOG}") if p.is_file()]
    except OSError:
        return []
    logs.sort(key=modified, reverse=True)
    found = []
    for log in logs[:UNFINISHED_LISTED]:
        session = log.parent
        try:
            if _ends_stopped(log) or is_held(session):
                continue
            record = open_run(session, log_only=True)
            if resume_refusal(record) is not None:
                continue
            spec = record.spec
            done = len({s.record.step for s in record.steps})
        except (ValueError, KeyError, TypeError, OSError):
            continue
        found.append(UnfinishedSession(session, spec.procedure.name, done, len(spec.procedure.positions),
                                       spec.live.name if spec.live is not None else None))
    return found
