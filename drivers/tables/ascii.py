"""Driver for tables speaking our line-based ASCII protocol (see ASCII_TABLE_PROTOCOL.md).

One command line out, one reply line back: ``ID?``, ``RATE <deg/s>``, ``STOP``, ``STATE?``,
``LIMITS?``, ``CLEAR``; errors come back as ``ERR <code> <text>``.
"""
from __future__ import annotations

import math
import re

from drivers.tables.base import (
    DEFAULT_SETTLE_TIMEOUT_S,
    DEFAULT_TOLERANCE_DEG_S,
    LinePort,
    PortOwner,
    TableError,
    TableState,
    format_number,
    wait_until_settled,
)

ERROR_MEANINGS = {1: "unknown command", 2: "bad argument", 3: "out of range", 4: "fault"}
STATUS_WORDS = {"IDLE": "idle", "ACCEL": "accelerating", "STEADY": "steady", "FAULT": "fault"}

_NUMBER = r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)"
_ERR = re.compile(r"ERR\s+(\d+)(?:\s+(.*))?")
_STATE = re.compile(rf"STATE\s+({_NUMBER})\s+({_NUMBER})\s+([A-Z]+)(?:\s+(.*))?")
_ID = re.compile(r"ID\s+(\S+)\s+(\S+)")
_LIMITS = re.compile(rf"LIMITS\s+({_NUMBER})\s+({_NUMBER})")


class AsciiRateTable(PortOwner):
    """A rate table on the fieldcal ASCII protocol, over an injected pyserial-like port.

    ``timeout_s`` bounds the wait for each reply (the device answers within 50 ms);
    ``poll_interval_s`` is the pause between ``STATE?`` polls in :meth:`wait_settled`.
    """

    label = "ASCII table"

    def __init__(self, port, timeout_s: float = 1.0, poll_interval_s: float = 0.05):
        self._io = LinePort(port, timeout_s, self.label)
        self.timeout_s = float(timeout_s)
        self.poll_interval_s = float(poll_interval_s)

    # -- one exchange ---------------------------------------------------------------------------
    def _transact(self, command: str) -> str:
        """Send one command line; return its reply line, raising TableError on ``ERR``."""
        self._io.write(command.encode("ascii") + b"\n")
        line = self._io.read_line(command)
        if line.startswith("ERR"):
            m = _ERR.fullmatch(line)
            if m is None:
                raise self._garbled(command, line)
            code = int(m.group(1))
            text = m.group(2) or ""
            meaning = ERROR_MEANINGS.get(code, "unknown error code")
            raise TableError(f"{self.label} refused {command!r}: ERR {code} ({meaning}): {text}",
                             command=command, reply=line, code=code)
        return line

    def _garbled(self, command: str, line: str) -> TableError:
        return TableError(f"{self.label}: garbled reply to {command!r}: {line!r}",
                          command=command, reply=line)

    def _expect_ok(self, command: str) -> None:
        line = self._transact(command)
        if line != "OK":
            raise self._garbled(command, line)

    # -- RateTable --------------------------------------------------------------------------------
    def identify(self) -> str:
        """``"<model> <firmware>"`` from ``ID?``."""
        line = self._transact("ID?")
        m = _ID.fullmatch(line)
        if m is None:
            raise self._garbled("ID?", line)
        return f"{m.group(1)} {m.group(2)}"

    def set_rate(self, deg_per_s: float) -> None:
        """``RATE <deg/s>`` (rounded to 0.001 deg/s); the device checks the range (ERR 3).

        ValueError, before anything is sent, for a non-finite rate or a non-zero one that
        rounds to zero (it would stop the table).
        """
        rate = float(deg_per_s)
        if not math.isfinite(rate):
            raise ValueError(f"rate must be finite, not {deg_per_s!r}")
        text = format_number(rate, 3)
        if rate != 0.0 and text == "0":
            raise ValueError(f"rate {rate:g} deg/s is below the protocol's 0.001 deg/s resolution")
        self._expect_ok(f"RATE {text}")

    def stop(self) -> None:
        self._expect_ok("STOP")

    def clear_fault(self) -> None:
        """``CLEAR``: leave FAULT (TableError with ERR 4 if the cause persists)."""
        self._expect_ok("CLEAR")

    def limits(self) -> tuple[float, float]:
        """(max |rate| in deg/s, acceleration in deg/s²) from ``LIMITS?``."""
        line = self._transact("LIMITS?")
        m = _LIMITS.fullmatch(line)
        if m is None:
            raise self._garbled("LIMITS?", line)
        return float(m.group(1)), float(m.group(2))

    def query(self) -> TableState:
        line = self._transact("STATE?")
        m = _STATE.fullmatch(line)
        if m is None:
            raise self._garbled("STATE?", line)
        angle, rate, word, extra = float(m.group(1)), float(m.group(2)), m.group(3), m.group(4)
        status = STATUS_WORDS.get(word)
        if (status is None or not 0.0 <= angle < 360.0 or not math.isfinite(rate)
                or (extra and status != "fault")):
            raise self._garbled("STATE?", line)
        message = (extra or "FAULT") if status == "fault" else None
        return TableState(angle_deg=angle, rate_deg_s=rate, status=status, message=message)

    def wait_settled(self, rate_deg_s: float, tolerance_deg_s: float = DEFAULT_TOLERANCE_DEG_S,
                     timeout_s: float = DEFAULT_SETTLE_TIMEOUT_S) -> TableState:
        return wait_until_settled(self.query, rate_deg_s, tolerance_deg_s, timeout_s,
                                  self.poll_interval_s)
