"""Driver for a rotary table driven by a GRBL v1.1 stepper controller on its X axis.

Many low-cost rate tables are a stepper, a belt or worm reduction and an Arduino running GRBL.
The table is GRBL's **X axis configured in degrees: 1 "mm" = 1 degree** (``$100`` = steps per
degree, ``$110`` = max rate in deg/min, ``$120`` = acceleration in deg/s²). So a feed rate of
``F600`` is 600 deg/min = 10 deg/s, and ``MPos`` X is the table's odometer in degrees.

How the rate-table verbs map onto GRBL v1.1 (gnea/grbl ``doc/markdown/jogging.md``,
``commands.md``, ``interface.md``, ``grbl/report.c``, ``grbl/protocol.c``):

- **Spin**: a jog ``$J=G91 G21 X<distance> F<deg/min>\\n`` answered ``ok`` (or ``error:N``).
  ``G91`` (incremental) and ``G21`` (mm, i.e. degrees) apply to that jog only and never change
  the g-code parser state. The distance is ``rate * max_run_s`` (default one hour): **the table
  stops by itself after ``max_run_s``** unless ``set_rate`` is called again with the same rate,
  which queues another identical jog behind the running one (GRBL accepts jogs in the ``Jog``
  state and blends same-direction blocks without stopping). A different rate or direction needs
  a stop first: the driver sends jog-cancel, polls ``?`` until ``Idle``, then jogs.
- **Stop**: the real-time jog-cancel byte ``0x85`` (no reply; ignored unless jogging). GRBL
  decelerates, flushes queued jogs and returns to ``Idle``; meanwhile reports still say ``Jog``.
- **Query**: the real-time ``?`` byte (no line end) answered by one status report such as
  ``<Jog|MPos:12.345,0.000,0.000|FS:600,0>``. Angle = MPos X mod 360 (or WPos X + the last
  ``WCO`` X when ``$10`` selects work positions); rate = feed / 60 with the sign of the jog this
  driver commanded (GRBL's feed is unsigned). ``F:`` replaces ``FS:`` on builds without
  variable spindle; ``Bf``, ``Ln``, ``Ov``, ``A``, ``Pn`` fields are ignored.
  Status: ``Idle`` -> idle; ``Jog``/``Run`` -> steady when the reported feed equals the
  commanded one to the report's resolution (GRBL prints mm/min feeds with 0 decimals, so the
  rate reads in steps of 1/60 deg/s), else accelerating; ``Alarm``, ``Hold``, ``Door``,
  ``Sleep``, ``Check`` -> fault; ``Home`` -> accelerating.
- **Alarms**: an unsolicited ``ALARM:N`` line is remembered (status fault, message names the
  alarm); ``clear_fault`` sends ``$X`` (kill alarm lock). In GRBL a hard-limit alarm needs a
  reset first (:meth:`reset`, the ``0x18`` byte).
- **Identify**: ``$I`` -> ``[VER:1.1h.20190825:<info>]``, ``[OPT:...]``, ``ok``. The start-up
  banner ``Grbl 1.1h ['$' for help]`` is only printed at power-up or after a soft reset (which
  aborts motion with ``ALARM:3`` if the table is turning), so :meth:`identify` asks ``$I``; the
  banner is recognised wherever it appears (``self.banner``) and returned by :meth:`reset`.

Controller settings this driver assumes: ``$13=0`` (report mm, i.e. degrees, not inches);
``$20=0`` (no soft limits, else long jogs fail with ``error:15``); ``$110`` >= 60 x
``max_rate_deg_s`` (GRBL silently clamps faster jogs to ``$110``). GRBL keeps positions as
float32 and int32 steps: the angle's resolution is about |MPos| x 1.2e-7 deg (0.004 deg after 100
turns), and ``$100`` x |MPos| must stay below 2**31 steps; MPos only returns to zero on power-up.
"""
from __future__ import annotations

import math
import re
import time
from dataclasses import dataclass

from drivers.tables.base import (
    DEFAULT_SETTLE_TIMEOUT_S,
    DEFAULT_TOLERANCE_DEG_S,
    LinePort,
    PortOwner,
    TableError,
    TableState,
    TableTimeout,
    format_number,
    wait_until_settled,
    wrap_angle,
)

JOG_CANCEL = b"\x85"
STATUS_QUERY = b"?"
SOFT_RESET = b"\x18"

# Short meanings of GRBL v1.1 error and alarm codes (doc/csv/error_codes_en_US.csv,
# alarm_codes_en_US.csv), for messages.
GRBL_ERRORS = {
    1: "expected command letter", 2: "bad number format", 3: "invalid statement",
    4: "negative value", 5: "setting disabled", 6: "step pulse < 3 us", 7: "EEPROM read fail",
    8: "not idle", 9: "g-code locked out during alarm or jog", 10: "soft limits need homing",
    11: "line overflow", 12: "step rate > 30 kHz", 13: "check door", 14: "line length exceeded",
    15: "jog target exceeds machine travel", 16: "invalid jog command", 17: "laser mode needs PWM",
    20: "unsupported g-code", 21: "modal group violation", 22: "undefined feed rate",
    23: "integer value required", 24: "two axis-word commands", 25: "repeated word",
    26: "no axis words", 27: "invalid line number", 28: "missing value word",
    29: "G59.x unsupported", 30: "G53 needs G0 or G1", 31: "unused axis words",
    32: "arc without in-plane axis", 33: "invalid motion target", 34: "invalid arc radius",
    35: "arc without in-plane offset", 36: "unused value words", 37: "G43.1 wrong axis",
    38: "tool number too large",
}
GRBL_ALARMS = {
    1: "hard limit triggered", 2: "soft limit: target exceeds travel",
    3: "reset while in motion", 4: "probe fail (initial state)", 5: "probe fail (no contact)",
    6: "homing fail (reset)", 7: "homing fail (door)", 8: "homing fail (pull-off)",
    9: "homing fail (switch not found)",
}

_NUM = r"-?\d+(?:\.\d+)?"
_NUM_RE = re.compile(_NUM)
_ERROR = re.compile(r"error:(\d+)")
_ALARM = re.compile(r"ALARM:(\d+)")
_BANNER = re.compile(r"Grbl (\S+) \['\$' for help\]")
_VER = re.compile(r"\[VER:([^:\]]+)(?::([^\]]*))?\]")
_STATES = {"Idle", "Run", "Hold", "Jog", "Alarm", "Door", "Check", "Home", "Sleep"}


def alarm_text(code: int) -> str:
    return f"ALARM:{code} ({GRBL_ALARMS.get(code, 'unknown alarm')})"


@dataclass(frozen=True)
class StatusReport:
    """One parsed ``<...>`` report. Positions in degrees, feed in deg/min (unsigned)."""

    state: str  # Idle, Jog, ...
    substate: str | None
    mpos_x: float | None
    wpos_x: float | None
    wco_x: float | None
    feed: float | None
    line: str


def parse_status_report(line: str) -> StatusReport:
    """Parse ``<State[:n]|MPos:x,y,z|FS:f,s|...>``; ValueError if it is not one."""
    if not (line.startswith("<") and line.endswith(">")) or len(line) < 3:
        raise ValueError("not enclosed in <>")
    fields = line[1:-1].split("|")
    state, _, sub = fields[0].partition(":")
    if state not in _STATES or (sub and not sub.isdigit()):
        raise ValueError(f"unknown machine state {fields[0]!r}")
    values: dict[str, list[float]] = {}
    for f in fields[1:]:
        key, sep, val = f.partition(":")
        if not sep or not key:
            raise ValueError(f"field {f!r} is not type:value")
        if key in ("MPos", "WPos", "WCO", "FS", "F"):
            parts = val.split(",")
            if not all(_NUM_RE.fullmatch(p) for p in parts):
                raise ValueError(f"bad number in {f!r}")
            values[key] = [float(p) for p in parts]
            if not all(math.isfinite(v) for v in values[key]):
                raise ValueError(f"number out of range in {f!r}")
    if "MPos" not in values and "WPos" not in values:
        raise ValueError("no MPos or WPos field")
    def first(key: str) -> float | None:
        return values[key][0] if key in values else None

    feed = first("FS") if "FS" in values else first("F")
    return StatusReport(state, sub or None, first("MPos"), first("WPos"), first("WCO"), feed, line)


class GrblRateTable(PortOwner):
    """A GRBL v1.1 controller turning a rotary table on X (1 mm = 1 degree), see module doc.

    ``timeout_s`` bounds each reply; ``max_rate_deg_s`` is the largest rate accepted (keep it
    within the controller's ``$110``/60); ``max_run_s`` how long one jog lasts;
    ``poll_interval_s`` the pause between ``?`` polls; ``stop_timeout_s`` how long a change of
    rate may wait for the previous jog to decelerate to ``Idle``.
    """

    label = "GRBL"

    def __init__(self, port, timeout_s: float = 1.0, max_rate_deg_s: float = 60.0,
                 max_run_s: float = 3600.0, poll_interval_s: float = 0.05,
                 stop_timeout_s: float = 30.0):
        if not (max_rate_deg_s > 0 and max_run_s > 0):
            raise ValueError("max_rate_deg_s and max_run_s must be positive")
        self._io = LinePort(port, timeout_s, self.label)
        self.timeout_s = float(timeout_s)
        self.max_rate_deg_s = float(max_rate_deg_s)
        self.max_run_s = float(max_run_s)
        self.poll_interval_s = float(poll_interval_s)
        self.stop_timeout_s = float(stop_timeout_s)
        self.alarm: int | None = None  # last ALARM:N seen, until Idle or clear_fault
        self.banner: str | None = None  # last start-up banner seen
        self.feedback: list[str] = []  # [MSG:...] and other feedback lines seen, oldest first
        self._sign = 1  # direction of the last jog commanded
        self._feed: float | None = None  # feed (deg/min) of the jog commanded, None if none
        self._cancel_pending = False  # jog-cancel sent, Idle not yet seen
        self._wco_x = 0.0

    # -- line traffic ---------------------------------------------------------------------------
    def _note_line(self, line: str) -> bool:
        """Handle a line that may come at any time; True if it was one of those."""
        m = _ALARM.fullmatch(line)
        if m:
            self.alarm = int(m.group(1))
            self.feedback.append(line)
            return True
        m = _BANNER.fullmatch(line)
        if m:
            self.banner = line
            self._feed = None
            self._cancel_pending = False
            return True
        if line.startswith(("[", ">")):
            self.feedback.append(line)
            del self.feedback[:-50]
            return True
        return False

    def _command(self, command: str) -> list[str]:
        """Send one line; return the feedback lines before its ``ok``; TableError on error:N."""
        self._io.write(command.encode("ascii") + b"\n")
        alarm_before = self.alarm
        collected: list[str] = []
        while True:
            try:
                line = self._io.read_line(command)
            except TableTimeout as exc:
                if self.alarm is not None and self.alarm != alarm_before:
                    raise TableError(f"{self.label} raised {alarm_text(self.alarm)} and did not "
                                     f"answer {command!r}: {exc}", command=command,
                                     code=self.alarm) from exc
                raise
            if line == "ok":
                return collected
            m = _ERROR.fullmatch(line)
            if m:
                code = int(m.group(1))
                alarm = f" after {alarm_text(self.alarm)}" if self.alarm is not None else ""
                raise TableError(f"{self.label} refused {command!r}: {line} "
                                 f"({GRBL_ERRORS.get(code, 'unknown error')}){alarm}",
                                 command=command, reply=line, code=code)
            if _BANNER.fullmatch(line):
                self._note_line(line)
                raise TableError(f"{self.label} restarted ({line!r}) before answering "
                                 f"{command!r}; the command was lost", command=command, reply=line)
            if self._note_line(line):
                collected.append(line)
                continue
            if line.startswith("<"):  # a late status report: harmless
                continue
            raise self._garbled(command, line)

    def _garbled(self, command: str, line: str) -> TableError:
        return TableError(f"{self.label}: garbled reply to {command!r}: {line!r}",
                          command=command, reply=line)

    def status_report(self) -> StatusReport:
        """Send ``?`` and return the parsed report (alarms and feedback on the way are noted)."""
        self._io.write(STATUS_QUERY)
        while True:
            try:
                line = self._io.read_line("?")
            except TableTimeout as exc:
                if self.alarm is not None:
                    raise TableTimeout(f"{exc} (after {alarm_text(self.alarm)}; a hard-limit "
                                       f"alarm needs a reset)", command="?") from exc
                raise
            if line.startswith("<"):
                try:
                    report = parse_status_report(line)
                except ValueError as exc:
                    raise TableError(f"{self.label}: garbled status report {line!r}: {exc}",
                                     command="?", reply=line) from exc
                if report.wco_x is not None:
                    self._wco_x = report.wco_x
                return report
            if self._note_line(line) or line == "ok" or _ERROR.fullmatch(line):
                continue  # unsolicited, or a stale reply to an earlier line
            raise self._garbled("?", line)

    # -- RateTable --------------------------------------------------------------------------------
    def query(self) -> TableState:
        rep = self.status_report()
        x = rep.mpos_x if rep.mpos_x is not None else rep.wpos_x + self._wco_x
        angle = wrap_angle(x)
        feed = rep.feed
        if rep.state == "Idle":
            self.alarm = None
            self._feed = None
            self._cancel_pending = False
            return TableState(angle, 0.0, "idle")
        rate = self._sign * (feed if feed is not None else (self._feed or 0.0)) / 60.0
        if rep.state in ("Jog", "Run"):
            if self._cancel_pending:
                return TableState(angle, rate, "accelerating", "stopping (jog cancelled)")
            if self._feed is None:
                return TableState(angle, rate, "accelerating", "jog not commanded by this driver")
            # GRBL prints feeds in mm/min with 0 decimals: equal to that resolution = steady
            steady = feed is None or abs(feed - self._feed) <= 0.5 + 1e-9
            return TableState(angle, rate, "steady" if steady else "accelerating")
        if rep.state == "Home":
            return TableState(angle, rate, "accelerating", "homing")
        if rep.state == "Alarm":
            text = alarm_text(self.alarm) if self.alarm is not None else "Alarm state"
            return TableState(angle, rate, "fault", f"{text}; clear_fault() sends $X")
        return TableState(angle, rate, "fault", f"GRBL state {rep.line[1:-1].split('|')[0]}")

    def set_rate(self, deg_per_s: float) -> None:
        """Jog at ``deg_per_s`` for ``max_run_s``; 0 stops. Stops first if the rate changes.

        ValueError, before anything is sent, beyond ``max_rate_deg_s``, for a non-finite rate
        or a non-zero one below GRBL's feed resolution.
        """
        rate = float(deg_per_s)
        if not math.isfinite(rate):
            raise ValueError(f"rate must be finite, not {deg_per_s!r}")
        if abs(rate) > self.max_rate_deg_s * (1 + 1e-12):
            raise ValueError(f"|rate| {abs(rate):g} deg/s exceeds max_rate_deg_s "
                             f"{self.max_rate_deg_s:g} (the controller's $110 / 60)")
        if rate == 0.0:
            self.stop()
            return
        sign = 1 if rate > 0 else -1
        feed_text = format_number(abs(rate) * 60.0, 3)
        feed = float(feed_text)
        if feed <= 0.0:
            raise ValueError(f"rate {rate:g} deg/s is below the 0.001 deg/min feed resolution")
        dist_text = format_number(sign * abs(rate) * self.max_run_s, 3)
        if self._cancel_pending or (self._feed is not None
                                    and (self._sign != sign or self._feed != feed)):
            if not self._cancel_pending:
                self._io.write(JOG_CANCEL)
                self._cancel_pending = True
            self._wait_idle(f"set_rate({rate:+g})")
        self._command(f"$J=G91 G21 X{dist_text} F{feed_text}")
        self._sign, self._feed = sign, feed

    def _wait_idle(self, context: str) -> None:
        deadline = time.monotonic() + self.stop_timeout_s
        while True:
            state = self.query()
            if state.status == "idle":
                return
            if state.status == "fault":
                raise TableError(f"{context}: table fault while stopping: {state.message}")
            if time.monotonic() >= deadline:
                raise TableTimeout(f"{context}: {self.label} not Idle within "
                                   f"{self.stop_timeout_s:g} s after jog cancel; last {state}")
            if self.poll_interval_s > 0:
                time.sleep(self.poll_interval_s)

    def stop(self) -> None:
        """Send jog-cancel (0x85); GRBL decelerates and flushes queued jogs. No reply."""
        self._io.write(JOG_CANCEL)
        self._cancel_pending = True
        self._feed = None

    def wait_settled(self, rate_deg_s: float, tolerance_deg_s: float = DEFAULT_TOLERANCE_DEG_S,
                     timeout_s: float = DEFAULT_SETTLE_TIMEOUT_S) -> TableState:
        return wait_until_settled(self.query, rate_deg_s, tolerance_deg_s, timeout_s,
                                  self.poll_interval_s)

    def identify(self) -> str:
        """``"Grbl <version> build <date>[ <info>]"`` from ``$I``."""
        lines = self._command("$I")
        for line in lines:
            m = _VER.fullmatch(line)
            if m:
                version, _, build = m.group(1).rpartition(".")
                if not version:
                    version, build = build, ""
                text = f"Grbl {version}" + (f" build {build}" if build else "")
                info = (m.group(2) or "").strip()
                return f"{text} {info}" if info else text
        raise TableError(f"{self.label}: no [VER:...] line in reply to '$I': {lines!r}",
                         command="$I")

    def clear_fault(self) -> None:
        """``$X``: kill the alarm lock (after a hard-limit alarm, :meth:`reset` first)."""
        self._command("$X")
        self.alarm = None

    def reset(self) -> str:
        """Soft reset (0x18); return the start-up banner. Aborts motion (ALARM:3 if turning)."""
        self._io.write(SOFT_RESET)
        self.banner = None
        while True:
            line = self._io.read_line("soft reset (0x18)")
            if self._note_line(line):
                if self.banner is not None:
                    return self.banner
                continue
            if line.startswith("<") or line == "ok" or _ERROR.fullmatch(line):
                continue
            raise self._garbled("soft reset (0x18)", line)
