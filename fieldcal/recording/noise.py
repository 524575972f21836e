"""Third-party parsers' own noise on damaged input, kept off the terminal and summed up.

pymavlink's DataFlash indexer (C, ``fprintf(stderr)``) writes a line per byte it skips ("bad
header 0x.. at N"): 53,000 lines for a garbage file, before fieldcal's one line. pyulog prints
its warnings with ``print``. ``captured_output()`` points the process's file descriptors 1 and
2 at /dev/null for the duration (what C writes there is lost: the caller measures the damage
from what the parser indexed instead; a pipe read by a thread would deadlock, as the indexer
holds the GIL while its write waits), and Python's sys.stdout/sys.stderr at a counter of
lines: memory is a few counters whatever the volume, and what was said is summed up in ``Noise``.
Not for a process whose terminal another thread is drawing (the TUI): its output would be lost
for the duration. No front end imports logs on a thread today.
"""
from __future__ import annotations

import contextlib
import io
import os
import re
import sys
from dataclasses import dataclass, field

_LONGEST = 1 << 16  # characters of a line without end kept before it is counted
_KEPT = 3  # kinds of line named in the summary, the most frequent first


@dataclass
class Noise:
    """What a parser wrote while it was silenced."""
    lines: int = 0
    counts: dict[str, int] = field(default_factory=dict)  # per kind of line (its words before a number)
    first: dict[str, str] = field(default_factory=dict)  # the first line of each kind
    last: dict[str, str] = field(default_factory=dict)

    def add(self, line: str) -> None:
        self.lines += 1
        kind = _kind(line)
        if kind not in self.counts and len(self.counts) >= 16:
            kind = "other"
        self.counts[kind] = self.counts.get(kind, 0) + 1
        self.first.setdefault(kind, line[:200])
        self.last[kind] = line[:200]

    def count(self, kind: str) -> int:
        return self.counts.get(kind, 0)

    def summary(self, who: str) -> str | None:
        """One line: how many lines of each kind, the first of each; None if it said nothing."""
        if not self.lines:
            return None
        parts = [f"{n} × \"{self.first[k]}\"" + (f" .. \"{self.last[k]}\"" if n > 1 else "")
                 for k, n in sorted(self.counts.items(), key=lambda kv: -kv[1])[:_KEPT]]
        return f"{who} said {self.lines} line{'s' * (self.lines != 1)} (not shown): {'; '.join(parts)}"


def _kind(line: str) -> str:
    return re.split(r"\s(?:0x[0-9a-fA-F]+|\d+)", line, maxsplit=1)[0].strip()[:60]


class _LineSink(io.TextIOBase):
    """A text stream whose lines go to ``noise`` (Python-level prints)."""

    def __init__(self, noise: Noise) -> None:
        self.noise, self.carry = noise, ""

    def writable(self) -> bool:
        return True

    def write(self, text: str) -> int:
        *lines, self.carry = (self.carry + text).split("\n")
        for line in lines:
            if line.strip():
                self.noise.add(line)
        if len(self.carry) > _LONGEST:  # a line without end: count it, keep no more
            self.noise.add(self.carry)
            self.carry = ""
        return len(text)

    def close_lines(self) -> None:
        if self.carry.strip():
            self.noise.add(self.carry)
        self.carry = ""


@contextlib.contextmanager
def captured_output():
    """Silence file descriptors 1 and 2 and sys.stdout/sys.stderr; yields the Noise of what was
    printed from Python."""
    noise = Noise()
    sink = _LineSink(noise)
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    null = os.open(os.devnull, os.O_WRONLY)
    saved = []
    try:
        for fd in (1, 2):
            try:
                saved.append((fd, os.dup(fd)))
            except OSError:  # closed (started with >&-): closed again afterwards
                saved.append((fd, None))
            os.dup2(null, fd)
    finally:
        os.close(null)
    try:
        with contextlib.redirect_stdout(sink), contextlib.redirect_stderr(sink):
            yield noise
    finally:
        for fd, copy in saved:
            if copy is None:
                os.close(fd)
            else:
                os.dup2(copy, fd)
                os.close(copy)
        sink.close_lines()
