"""Sample time held to a multiple of wall time (a replay at 10×, the terminal UI's simulator)."""
from __future__ import annotations

import time
from collections.abc import Callable


class Pacer:
    """Holds sample time to ``speed`` × wall time; re-anchored after every pause."""

    def __init__(self, speed: float, clock: Callable[[], float] = time.monotonic):
        if not speed >= 0:
            raise ValueError(f"speed: expected a number >= 0 (0 = as fast as possible), got {speed!r}")
        self.speed = float(speed)
        self.clock = clock
        self._anchor: tuple[float, float] | None = None  # (sample time, wall time)

    def hold(self) -> None:
        self._anchor = None

    def delay(self, t_first: float, t_last: float) -> float:
        """Seconds to wait before samples up to ``t_last`` are due (0 when unpaced)."""
        if self.speed <= 0:
            return 0.0
        now = self.clock()
        if self._anchor is None:
            self._anchor = (t_first, now)
        t0, wall0 = self._anchor
        return max(0.0, wall0 + (t_last - t0) / self.speed - now)
