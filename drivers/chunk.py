"""The unit of data that flows from every source (device, simulator, capture) into the station."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping

import numpy as np


@dataclass(frozen=True)
class SampleChunk:
    """A block of consecutive samples.

    ``t`` is sample time in seconds (device time where the protocol has it, else host monotonic
    receive time); ``triads`` maps a triad name to an (n, 3) array in the device's output units.
    """

    t: np.ndarray
    triads: Mapping[str, np.ndarray]
    temperature: np.ndarray | None = field(default=None)

    def __post_init__(self) -> None:
        n = len(self.t)
        for name, values in self.triads.items():
            if values.shape != (n, 3):
                raise ValueError(f"triad {name!r}: expected shape ({n}, 3), got {values.shape}")

    def __len__(self) -> int:
        return len(self.t)
