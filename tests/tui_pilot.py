"""What the terminal UI's Pilot tests share: async bodies run with asyncio, waiting for a state
(on an event loop turn, never on a wall-clock threshold but a generous time-out)."""
from __future__ import annotations

import asyncio
import functools
import time


def run_async(test):
    """Run an async test body with asyncio (no pytest-asyncio needed)."""
    @functools.wraps(test)
    def wrapper(*args, **kwargs):
        return asyncio.run(test(*args, **kwargs))
    return wrapper


async def until(pilot, predicate, timeout_s: float = 120.0) -> None:
    # A hang detector, not a speed check: a live run with turns takes ~9 s quiet, and more than
    # 30 s was seen once while CI's two workers and other jobs shared the 2 cores.
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < deadline, "the UI did not get there in time"
        await pilot.pause(0.01)


def waiting_at(app, step: int) -> bool:
    """The run waits for the operator at ``step`` (0-based)."""
    t = app.telemetry
    return t is not None and t.waiting and t.step == step and app.outcome is None


def log_settled(app, last: str) -> bool:
    """The procedure screen's event log holds a line with ``last`` and is scrolled to its end
    (the log scrolls after it is written, a frame later on a loaded machine: a snapshot waits)."""
    logs = app.screen.query("#log")
    if not logs:
        return False
    log = logs.first()
    return any(last in line.text for line in log.lines) and log.scroll_y >= log.max_scroll_y
