"""The unit of data that flows from every source (device, simulator, capture) into the station."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping

import numpy as np


@dataclass(frozen=True)
class SampleChunk:
    """A block of consecutive samples.

    ``t`` is sample time in seconds (device time where the protocol has it, else host monotonic
    receive time); ``triads`` maps a triad name to an (n, 3) array in the device's output units;
    ``extras`` holds other per-sample channels, (n,) each (packet counter, pressure, ...).
    """

    t: np.ndarray
    triads: Mapping[str, np.ndarray]
    temperature: np.ndarray | None = field(default=None)
    extras: Mapping[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        n = len(self.t)
        for name, values in self.triads.items():
            if values.shape != (n, 3):
                raise ValueError(f"triad {name!r}: expected shape ({n}, 3), got {values.shape}")
        for name, values in self.extras.items():
            if values.shape != (n,):
                raise ValueError(f"channel {name!r}: expected shape ({n},), got {values.shape}")
        if self.temperature is not None and self.temperature.shape != (n,):
            raise ValueError(f"temperature: expected shape ({n},), got {self.temperature.shape}")

    def __len__(self) -> int:
        return len(self.t)
