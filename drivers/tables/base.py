"""What every single-axis rate-table driver provides, and the pieces the drivers share.

A driver talks to its table through an injected pyserial-like *port* (``write(bytes)``,
``read_until(b"\\n")`` or ``read(n)``, a ``timeout`` attribute in seconds). It never opens a port
itself; :func:`drivers.tables.open_table` does that from a pyserial URL. Tests inject fakes.

Units are the operator's: degrees and degrees per second. The sign of a rate is the direction
(positive = the angle increases).

Timeouts follow pyserial: a read that returns fewer bytes than asked for, or a line without its
``\\n``, means the port's ``timeout`` expired. The drivers set ``port.timeout = timeout_s`` and
report such a read as :class:`TableTimeout` at once, naming the command and the time waited.
"""
from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal, Protocol, runtime_checkable

try:  # pyserial's flush (tcdrain) on a port gone under it raises termios.error, not an OSError
    # (pyserial issue 417): a cable pulled between a command's write and its flush
    from termios import error as _TermiosError
    _PORT_GONE: tuple[type[BaseException], ...] = (_TermiosError,)
except ImportError:  # no termios (Windows): pyserial raises SerialException (an OSError) there
    _PORT_GONE = ()

Status = Literal["idle", "accelerating", "steady", "fault"]
STATUSES: tuple[str, ...] = ("idle", "accelerating", "steady", "fault")

DEFAULT_TOLERANCE_DEG_S = 0.05
DEFAULT_SETTLE_TIMEOUT_S = 30.0


class TableError(Exception):
    """The table refused a command, faulted, or answered something that is not the protocol.

    ``command`` is what was sent (text), ``reply`` the offending line as received (if any) and
    ``code`` the device's numeric error code (if it gave one). The message always quotes the
    device's own text.
    """

    def __init__(self, message: str, *, command: str | None = None, reply: str | None = None,
                 code: int | None = None):
        super().__init__(message)
        self.command = command
        self.reply = reply
        self.code = code


class TableTimeout(TableError, TimeoutError):
    """No (complete) answer within the timeout. Also a :class:`TableError`, so one ``except``
    catches every table failure; catch this first to tell a silent table from a refusing one."""


def wrap_angle(angle_deg: float) -> float:
    """``angle_deg`` folded into [0, 360) (``-1e-17 % 360`` is 360.0 in floating point)."""
    a = math.fmod(angle_deg, 360.0)
    if a < 0.0:
        a += 360.0
    return 0.0 if a >= 360.0 else a


@dataclass(frozen=True)
class TableState:
    """One snapshot of the table: angle in [0, 360) deg, signed rate in deg/s, status word."""

    angle_deg: float
    rate_deg_s: float
    status: Status
    message: str | None = None

    def __post_init__(self):
        if self.status not in STATUSES:
            raise ValueError(f"status must be one of {STATUSES}, not {self.status!r}")
        if not 0.0 <= self.angle_deg < 360.0:
            raise ValueError(f"angle_deg must be in [0, 360), not {self.angle_deg!r}")
        if not math.isfinite(self.rate_deg_s):
            raise ValueError(f"rate_deg_s must be finite, not {self.rate_deg_s!r}")


@runtime_checkable
class RateTable(Protocol):
    """A single-axis rate table."""

    def set_rate(self, deg_per_s: float) -> None:
        """Command a rate (sign = direction); returns once the table accepted it, not settled."""
        ...

    def stop(self) -> None:
        """Command a stop (the table ramps to rest); returns once accepted."""
        ...

    def query(self) -> TableState:
        """The table's present angle, rate and status."""
        ...

    def wait_settled(self, rate_deg_s: float, tolerance_deg_s: float = DEFAULT_TOLERANCE_DEG_S,
                     timeout_s: float = DEFAULT_SETTLE_TIMEOUT_S) -> TableState:
        """Poll until steady at ``rate_deg_s`` (idle, for 0); TableError on fault, TableTimeout."""
        ...

    def identify(self) -> str:
        """The table's model and firmware, as one line of text."""
        ...

    def close(self) -> None:
        """Close the port."""
        ...


def format_number(value: float, decimals: int = 3) -> str:
    """Fixed-point text without exponent or trailing zeros: 36000.0 -> '36000', -2.5 -> '-2.5'."""
    if not math.isfinite(value):
        raise ValueError(f"not a finite number: {value!r}")
    text = f"{value:.{decimals}f}"
    if "." in text:
        text = text.rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text


class LinePort:
    """Reads whole lines from a pyserial-like port, skipping blank ones; decodes as ASCII.

    ``label`` names the device in messages ("ASCII table", "GRBL"). After a timeout, the next
    ``write`` first discards pending input (``reset_input_buffer``, where the port has it), so
    a reply that arrives late is not taken for the answer to the next command.
    """

    MAX_BLANK_LINES = 64

    def __init__(self, port, timeout_s: float, label: str):
        self.port = port
        self.timeout_s = float(timeout_s)
        self.label = label
        self.stale = False  # a reply may still be on its way: discard input before next write
        try:
            port.timeout = self.timeout_s
        except AttributeError:  # a fake without the attribute: it never blocks anyway
            pass

    def write(self, data: bytes) -> None:
        if self.stale:
            self.stale = False
            discard = getattr(self.port, "reset_input_buffer", None)
            if discard is not None:
                discard()
        self.port.write(data)
        flush = getattr(self.port, "flush", None)
        if flush is not None:
            try:
                flush()
            except _PORT_GONE as exc:  # an OSError, as every other failure of a port gone
                raise OSError(*exc.args) from exc

    def _read_raw_line(self) -> bytes:
        read_until = getattr(self.port, "read_until", None)
        if read_until is not None:
            return read_until(b"\n")
        out = bytearray()
        while True:
            c = self.port.read(1)
            if not c:
                return bytes(out)
            out += c
            if c == b"\n":
                return bytes(out)

    def read_line(self, command: str) -> str:
        """The next non-blank line without its line end; TableTimeout if none in time."""
        for _ in range(self.MAX_BLANK_LINES):
            raw = self._read_raw_line()
            if not raw.endswith(b"\n"):
                self.stale = True
                got = f"; got only {raw!r}" if raw else ""
                raise TableTimeout(
                    f"{self.label}: no reply to {command!r} within {self.timeout_s:g} s{got}",
                    command=command, reply=raw.decode("ascii", "replace") if raw else None)
            line = raw.decode("ascii", errors="replace").strip()
            if line:
                return line
        raise TableError(f"{self.label}: only blank lines in reply to {command!r}", command=command)


def wait_until_settled(query: Callable[[], TableState], rate_deg_s: float,
                       tolerance_deg_s: float, timeout_s: float, poll_interval_s: float,
                       *, clock: Callable[[], float] = time.monotonic,
                       sleep: Callable[[float], None] = time.sleep) -> TableState:
    """Poll ``query`` until the table is steady within ``tolerance_deg_s`` of ``rate_deg_s``.

    For a rate of zero (within tolerance) the table must be ``idle``. A ``fault`` status raises
    TableError at once; not settled within ``timeout_s`` raises TableTimeout with the last state.
    """
    deadline = clock() + timeout_s
    while True:
        state = query()
        if state.status == "fault":
            raise TableError(f"table fault while waiting to settle at {rate_deg_s:+g} deg/s: "
                             f"{state.message or 'no reason given'}")
        close = abs(state.rate_deg_s - rate_deg_s) <= tolerance_deg_s
        if abs(rate_deg_s) <= tolerance_deg_s:
            if state.status == "idle" and close:
                return state
        elif state.status == "steady" and close:
            return state
        if clock() >= deadline:
            raise TableTimeout(f"wait_settled({rate_deg_s:+g} deg/s, tolerance {tolerance_deg_s:g}):"
                               f" not settled within {timeout_s:g} s; last state {state}")
        if poll_interval_s > 0:
            sleep(poll_interval_s)


class PortOwner:
    """Closing and context management for a driver that owns its port through ``self._io``."""

    _io: "LinePort"

    def close(self) -> None:
        self._io.port.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
