"""Virtual rate tables that speak our ASCII protocol and GRBL v1.1 at the byte level.

Both operate on one shared :class:`TableMotion`: the table's physics (rate ramping toward a
target at a fixed acceleration, angle integrated). The simulator owns time: it calls
``motion.advance(dt_s)`` (or reads ``rate_deg_s`` / ``angle_deg`` after someone else did); the
virtual tables only set ``target_rate_deg_s`` and read the rest. Each has
``receive(data: bytes) -> bytes``: feed it whatever bytes the host wrote, in any split; it
returns the reply bytes for every complete command (partial lines are buffered), answers garbage
with the protocol's error reply and never raises. ``receive(b"")`` is a *tick*: it returns
anything the table says on its own (a GRBL ``ALARM:``, replies held back during a jog cancel).

Thread safety: ``TableMotion.lock`` (re-entrant) is held by ``advance`` and by ``receive``, so a
serving thread and a simulation thread may share one motion.
"""
from __future__ import annotations

import math
import re
import threading
from dataclasses import dataclass, field

from drivers.tables.base import wrap_angle

STEADY_TOL = 1e-9  # |rate - target| below this is "at the target"


@dataclass
class TableMotion:
    """The turning table, in degrees and seconds; sign of a rate = direction (angle increases).

    Fields (all plain, read and write them freely under ``lock``):

    - ``target_rate_deg_s``: the commanded rate; the tables set it, ``advance`` ramps toward it.
    - ``accel_deg_s2``: ramp acceleration magnitude (20 deg/s²); <= 0 means instantaneous.
    - ``rate_deg_s``: the present rate.
    - ``angle_deg``: the present angle in [0, 360).
    - ``position_deg``: the same angle unwrapped (an odometer; GRBL reports it as MPos X).
      ``advance`` moves both; if you set one by hand, set the other too.
    - ``fault`` / ``fault_reason``: set ``fault`` to simulate a drive fault; ``advance`` then
      zeroes the target and the table ramps to rest. The ASCII table reports FAULT (``CLEAR``
      resets the flag); the GRBL table raises ``ALARM:1`` (``$X`` resets it).
    """

    target_rate_deg_s: float = 0.0
    accel_deg_s2: float = 20.0
    rate_deg_s: float = 0.0
    angle_deg: float = 0.0
    position_deg: float = 0.0
    fault: bool = False
    fault_reason: str = ""
    lock: threading.RLock = field(default_factory=threading.RLock, repr=False, compare=False)

    @property
    def status(self) -> str:
        """"fault"; "idle" (rate and target zero); "steady" (at a non-zero target) or
        "accelerating" (anything else, including slowing down and reversing)."""
        if self.fault:
            return "fault"
        at_target = abs(self.rate_deg_s - self.target_rate_deg_s) < STEADY_TOL
        if at_target and self.target_rate_deg_s != 0.0:
            return "steady"
        if self.rate_deg_s == 0.0 and self.target_rate_deg_s == 0.0:
            return "idle"
        return "accelerating"

    def advance(self, dt_s: float) -> None:
        """Move time on by ``dt_s``: ramp the rate toward the target, integrate the angle
        exactly (trapezoid while ramping, rectangle after); the rate lands on the target."""
        if not dt_s > 0.0:
            return
        with self.lock:
            if self.fault:
                self.target_rate_deg_s = 0.0
            target = float(self.target_rate_deg_s)
            r0 = float(self.rate_deg_s)
            diff = target - r0
            a = float(self.accel_deg_s2)
            if diff == 0.0 or not a > 0.0 or not math.isfinite(a):
                r1, disp = target, target * dt_s
            else:
                t_ramp = abs(diff) / a
                if t_ramp >= dt_s:
                    r1 = r0 + math.copysign(a * dt_s, diff)
                    disp = 0.5 * (r0 + r1) * dt_s
                else:
                    r1 = target
                    disp = 0.5 * (r0 + target) * t_ramp + target * (dt_s - t_ramp)
            if abs(r1 - target) < STEADY_TOL:
                r1 = target
            self.rate_deg_s = r1
            self.position_deg += disp
            self.angle_deg = wrap_angle(self.angle_deg + disp)


def _fmt3(x: float) -> str:
    text = f"{x:.3f}"
    return "0.000" if text == "-0.000" else text


# ---------------------------------------------------------------------------------------------
# ASCII protocol (drivers/tables/ASCII_TABLE_PROTOCOL.md)

_ASCII_STATUS_WORDS = {"idle": "IDLE", "accelerating": "ACCEL", "steady": "STEADY",
                       "fault": "FAULT"}
_ASCII_NUMBER = re.compile(r"[+-]?(?:\d+(?:\.\d{0,6})?|\.\d{1,6})")


class VirtualAsciiTable:
    """A table speaking the fieldcal ASCII protocol over ``receive``."""

    MAX_LINE = 64

    def __init__(self, state: TableMotion, *, model: str = "FCT-1", firmware: str = "1.0.0",
                 max_rate_deg_s: float = 100.0):
        self.state = state
        self.model = model
        self.firmware = firmware
        self.max_rate_deg_s = float(max_rate_deg_s)
        self._buf = bytearray()
        self._overflow = False

    def receive(self, data: bytes) -> bytes:
        out: list[str] = []
        with self.state.lock:
            for byte in bytes(data):
                if byte == 0x0A:
                    reply = self._line(bytes(self._buf), self._overflow)
                    self._buf.clear()
                    self._overflow = False
                    if reply is not None:
                        out.append(reply + "\r\n")
                elif byte == 0x0D:
                    continue
                elif len(self._buf) >= self.MAX_LINE:
                    self._overflow = True
                else:
                    self._buf.append(byte)
        return "".join(out).encode("ascii")

    def _line(self, raw: bytes, overflow: bool) -> str | None:
        if overflow:
            return "ERR 2 line too long"
        if any(b < 0x20 or b > 0x7E for b in raw):
            return "ERR 1 unknown command (control or non-ASCII bytes)"
        tokens = raw.decode("ascii").split(" ")
        tokens = [t for t in tokens if t]
        if not tokens:
            return None
        cmd, args = tokens[0].upper(), tokens[1:]
        m = self.state
        if cmd == "RATE":
            if len(args) != 1:
                return "ERR 2 RATE takes one number"
            text = args[0]
            if len(text) > 16 or not _ASCII_NUMBER.fullmatch(text):
                return f"ERR 2 bad number {text[:16]}"
            rate = round(float(text), 3) + 0.0  # + 0.0 turns -0.0 into 0.0
            if abs(rate) > self.max_rate_deg_s:
                return f"ERR 3 rate {_fmt3(rate)} outside +-{_fmt3(self.max_rate_deg_s)} deg/s"
            if m.fault:
                return f"ERR 4 fault: {m.fault_reason or 'table fault'}; send CLEAR"
            m.target_rate_deg_s = rate
            return "OK"
        no_args = {"ID?", "STOP", "STATE?", "LIMITS?", "CLEAR"}
        if cmd not in no_args:
            return f"ERR 1 unknown command {tokens[0][:16]}"
        if args:
            return f"ERR 2 {cmd} takes no argument"
        if cmd == "ID?":
            return f"ID {self.model} {self.firmware}"
        if cmd == "STOP":
            m.target_rate_deg_s = 0.0
            return "OK"
        if cmd == "CLEAR":
            m.fault = False
            m.fault_reason = ""
            return "OK"
        if cmd == "LIMITS?":
            return f"LIMITS {_fmt3(self.max_rate_deg_s)} {_fmt3(m.accel_deg_s2)}"
        angle = round(m.angle_deg, 3)
        if angle >= 360.0:
            angle -= 360.0
        word = _ASCII_STATUS_WORDS[m.status]
        reason = f" {m.fault_reason}" if m.fault and m.fault_reason else ""
        return f"STATE {_fmt3(angle)} {_fmt3(m.rate_deg_s)} {word}{reason}"


# ---------------------------------------------------------------------------------------------
# GRBL v1.1, rotary table on X, 1 mm = 1 degree

_GRBL_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)")


class VirtualGrblTable:
    """A GRBL 1.1 controller turning the table on its X axis (1 mm = 1 degree).

    Modelled as GRBL does it: real-time bytes (``?``, ``0x85`` jog cancel, ``0x18`` soft reset,
    ``!`` feed hold, ``~`` resume) act at once, even inside a line; other bytes >= 0x80 are
    dropped; lines end at ``\\n`` *or* ``\\r`` (so ``\\r\\n`` is a line plus an empty line, and an
    empty line gets its own ``ok``, as in GRBL); spaces and control characters are removed,
    letters upper-cased, ``(...)`` and ``;`` comments skipped; 80-character line buffer
    (``error:11`` beyond). Replies end with ``\\r\\n``. Lines arriving during a jog cancel wait
    until the table is at rest, as GRBL's main loop is suspended meanwhile.

    Commands: ``$J=`` jogs (G20/G21, G90/G91, G53, X/Y/Z, F, N; Y and Z are accepted and
    ignored; feeds above ``max_rate_deg_s`` are clamped like ``$110``), ``$I``, ``$X``, ``$G``,
    ``$$`` (a short settings list), ``$`` (help). Jogs queue; a same-direction successor takes
    over without stopping; the last one decelerates to end on its target (approximately: the
    decision is taken at ticks, so at coarse ticks it overshoots a little).

    Simplifications: other g-code lines are refused with ``error:20`` (``error:9`` while
    jogging or in alarm); a drive fault (``TableMotion.fault``) raises ``ALARM:1`` (as a hard
    limit would) but, unlike GRBL, ``$X`` clears it without a reset; error codes for malformed
    jogs follow GRBL's meanings but not every corner of its parser.
    """

    LINE_BUFFER_SIZE = 80  # as GRBL: at most 79 characters in a line

    def __init__(self, state: TableMotion, *, version: str = "1.1h", build: str = "20190825",
                 max_rate_deg_s: float = 100.0, steps_per_deg: float = 800.0,
                 report_wpos: bool = False, wco_x: float = 0.0):
        self.state = state
        self.version = version
        self.build = build
        self.max_rate_deg_s = float(max_rate_deg_s)
        self.steps_per_deg = float(steps_per_deg)
        self.report_wpos = report_wpos
        self.wco_x = float(wco_x)
        self.alarm: int | None = None
        self.hold = False
        self._buf = bytearray()
        self._paren = False
        self._semicolon = False
        self._overflow = False
        self._jogs: list[tuple[float, float]] = []  # (end position deg, signed rate deg/s)
        self._cancelling = False
        self._deferred: list[tuple[str, bool]] = []
        self._reports = 0

    # -- public -----------------------------------------------------------------------------------
    def startup(self) -> bytes:
        """What GRBL prints at power-up (send it when the simulated port opens)."""
        return f"\r\nGrbl {self.version} ['$' for help]\r\n".encode("ascii")

    @property
    def machine_state(self) -> str:
        m = self.state
        if self.alarm is not None:
            return "Alarm"
        if self.hold:
            return "Hold:0" if m.rate_deg_s == 0.0 else "Hold:1"
        if self._jogs or self._cancelling:
            return "Jog"
        return "Run" if m.rate_deg_s != 0.0 else "Idle"

    def receive(self, data: bytes) -> bytes:
        out: list[str] = []
        with self.state.lock:
            self._tick(out)
            for byte in bytes(data):
                self._byte(byte, out)
            self._tick(out)
        return "".join(out).encode("ascii")

    # -- bytes --------------------------------------------------------------------------------------
    def _byte(self, byte: int, out: list[str]) -> None:
        if byte == 0x3F:  # '?'
            self._tick(out)
            out.append(self._status_report())
        elif byte == 0x85:
            if self._jogs:
                self._cancel()
        elif byte == 0x18:
            self._soft_reset(out)
        elif byte == 0x21:  # '!' feed hold: cancels a jog, else suspends
            if self._jogs:
                self._cancel()
            elif self.alarm is None and not self._cancelling:
                self.hold = True
                self.state.target_rate_deg_s = 0.0
        elif byte == 0x7E:  # '~' cycle start / resume
            self.hold = False
        elif byte >= 0x80:
            pass  # other real-time commands (overrides...) do not concern the table
        elif byte in (0x0A, 0x0D):
            line = self._buf.decode("ascii")
            overflow = self._overflow
            self._buf.clear()
            self._paren = self._semicolon = self._overflow = False
            if self._cancelling:
                self._deferred.append((line, overflow))
            else:
                out.append(self._execute(line, overflow))
        elif self._paren or self._semicolon or self._overflow:
            if byte == 0x29 and self._paren:  # ')'
                self._paren = False
        elif byte <= 0x20 or byte == 0x2F:  # whitespace, control, '/' (block delete)
            pass
        elif byte == 0x28:  # '('
            self._paren = True
        elif byte == 0x3B:  # ';'
            self._semicolon = True
        elif len(self._buf) >= self.LINE_BUFFER_SIZE - 1:
            self._overflow = True
        else:
            self._buf.append(byte - 32 if 0x61 <= byte <= 0x7A else byte)

    def _cancel(self) -> None:
        self._jogs.clear()
        self._cancelling = True
        self.state.target_rate_deg_s = 0.0

    def _soft_reset(self, out: list[str]) -> None:
        m = self.state
        moving = m.rate_deg_s != 0.0 or bool(self._jogs)
        self._jogs.clear()
        self._cancelling = False
        self._deferred.clear()
        self._buf.clear()
        self._paren = self._semicolon = self._overflow = False
        self.hold = False
        m.target_rate_deg_s = 0.0
        if moving:  # steps lost: GRBL cannot vouch for the position
            m.rate_deg_s = 0.0
            self.alarm = 3
            out.append("ALARM:3\r\n")
        out.append(self.startup().decode("ascii"))
        if self.alarm is not None:
            out.append("[MSG:'$H'|'$X' to unlock]\r\n")
        self._reports = 0

    # -- time ---------------------------------------------------------------------------------------
    def _tick(self, out: list[str]) -> None:
        m = self.state
        if m.fault and self.alarm is None:
            self.alarm = 1
            self._jogs.clear()
            self._cancelling = False
            self.hold = False
            m.target_rate_deg_s = 0.0
            out.append("ALARM:1\r\n")
        if self._cancelling and m.rate_deg_s == 0.0:
            self._cancelling = False
            deferred, self._deferred = self._deferred, []
            for line, overflow in deferred:
                if self._cancelling:
                    self._deferred.append((line, overflow))
                else:
                    out.append(self._execute(line, overflow))
        while self._jogs and not self._cancelling:
            end, rate = self._jogs[0]
            sign = 1.0 if rate > 0 else -1.0
            remaining = (end - m.position_deg) * sign
            nxt = self._jogs[1] if len(self._jogs) > 1 else None
            if nxt is not None and (nxt[1] > 0) == (rate > 0):
                if remaining <= 0.0:
                    self._jogs.pop(0)
                    m.target_rate_deg_s = nxt[1]
                    continue
                break
            a = m.accel_deg_s2
            stopping = m.rate_deg_s ** 2 / (2 * a) if a > 0 else 0.0
            if remaining <= stopping + 1e-9:
                m.target_rate_deg_s = 0.0
                if m.rate_deg_s == 0.0:
                    self._jogs.pop(0)
                    if nxt is not None:
                        m.target_rate_deg_s = nxt[1]
                    continue
            break

    # -- reports ------------------------------------------------------------------------------------
    def _status_report(self) -> str:
        m = self.state
        x = m.position_deg
        pos = f"WPos:{x - self.wco_x:.3f},0.000,0.000" if self.report_wpos else \
            f"MPos:{x:.3f},0.000,0.000"
        fields = [self.machine_state, pos, f"FS:{abs(m.rate_deg_s) * 60.0:.0f},0"]
        if self._reports % 10 == 0:
            fields.append(f"WCO:{self.wco_x:.3f},0.000,0.000")
        elif self._reports % 10 == 1:
            fields.append("Ov:100,100,100")
        self._reports += 1
        return "<" + "|".join(fields) + ">\r\n"

    # -- lines --------------------------------------------------------------------------------------
    def _execute(self, line: str, overflow: bool) -> str:
        if overflow:
            return "error:11\r\n"
        if line == "":
            return "ok\r\n"
        if line[0] != "$":
            if self.alarm is not None or self._jogs:
                return "error:9\r\n"
            return "error:20\r\n"
        if line == "$":
            return ("[HLP:$$ $# $G $I $N $x=val $Nx=line $J=line $SLP $C $X $H ~ ! ? ctrl-x]\r\n"
                    "ok\r\n")
        if line.startswith("$J"):
            if self.alarm is not None or self.hold:
                return "error:8\r\n"
            if line[2:3] != "=":
                return "error:3\r\n"
            return f"error:{code}\r\n" if (code := self._jog(line[3:])) else "ok\r\n"
        if line == "$I":
            return f"[VER:{self.version}.{self.build}:]\r\n[OPT:V,15,128]\r\nok\r\n"
        if line == "$X":
            if self.alarm is not None:
                self.alarm = None
                self.state.fault = False
                self.state.fault_reason = ""
                return "[MSG:Caution: Unlocked]\r\nok\r\n"
            return "ok\r\n"
        if line == "$G":
            return "[GC:G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0]\r\nok\r\n"
        if line == "$$":
            if self._jogs:
                return "error:8\r\n"
            m = self.state
            settings = [f"$10={0 if self.report_wpos else 1}", "$13=0", "$20=0", "$21=0", "$22=0",
                        f"$100={self.steps_per_deg:.3f}", f"$110={self.max_rate_deg_s * 60:.3f}",
                        f"$120={m.accel_deg_s2:.3f}", "$130=1000.000"]
            return "".join(s + "\r\n" for s in settings) + "ok\r\n"
        return "error:3\r\n"

    def _jog(self, text: str) -> int:
        """Execute the words after ``$J=``; return 0 (ok) or a GRBL error code."""
        words: dict[str, float] = {}
        units = distance = None
        machine = False
        i = 0
        while i < len(text):
            letter = text[i]
            if not "A" <= letter <= "Z":
                return 1
            match = _GRBL_NUMBER.match(text, i + 1)
            if match is None:
                return 2
            value = float(match.group())
            i = match.end()
            if letter == "G":
                if value in (20.0, 21.0):
                    if units is not None:
                        return 21
                    units = value
                elif value in (90.0, 91.0):
                    if distance is not None:
                        return 21
                    distance = value
                elif value == 53.0:
                    machine = True
                else:
                    return 16
            elif letter in "XYZFN":
                if letter in words:
                    return 25
                words[letter] = value
            else:
                return 16
        if "F" not in words:
            return 22
        if words["F"] < 0:
            return 4
        if words["F"] == 0:
            return 22
        if not any(k in words for k in "XYZ"):
            return 26
        scale = 25.4 if units == 20.0 else 1.0
        rate = min(words["F"] * scale / 60.0, self.max_rate_deg_s)
        if "X" not in words:
            return 0
        x = words["X"] * scale
        base = self._jogs[-1][0] if self._jogs else self.state.position_deg
        if distance == 91.0 and not machine:
            end = base + x
        else:  # absolute: work coordinates, or machine coordinates with G53
            end = x if machine else x + self.wco_x
        if abs(end - base) * self.steps_per_deg < 0.5:
            return 0  # shorter than a step: GRBL plans nothing
        signed = rate if end > base else -rate
        if not self._jogs:
            self.state.target_rate_deg_s = signed
        self._jogs.append((end, signed))
        return 0


VIRTUAL_TABLES = {"ascii": VirtualAsciiTable, "grbl": VirtualGrblTable}  # as drivers.tables.PROTOCOLS
