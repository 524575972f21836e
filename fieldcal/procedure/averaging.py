"""Means of each triad over fixed windows of sample time, accumulated chunk by chunk."""
from __future__ import annotations

import numpy as np


class WindowAverager:
    """Accumulates per-window sums; windows are [start, end) in sample time, non-overlapping."""

    def __init__(self, starts, ends):
        starts, ends = np.asarray(starts, dtype=float), np.asarray(ends, dtype=float)
        order = np.argsort(starts)
        edges = np.column_stack([starts[order], ends[order]]).ravel()
        if np.any(np.diff(edges) < 0):
            raise ValueError("averaging windows overlap or end before they start")
        self._edges = edges
        self._order = order
        self._sums: dict[str, np.ndarray] = {}
        self._counts = np.zeros(len(starts), dtype=np.int64)

    def feed(self, chunk) -> None:
        slot = np.searchsorted(self._edges, chunk.t, side="right")
        inside = slot % 2 == 1  # between a start edge and its end edge
        window = (slot[inside] - 1) // 2
        n = len(self._counts)
        self._counts += np.bincount(window, minlength=n)
        for name, values in chunk.triads.items():
            sums = self._sums.setdefault(name, np.zeros((n, 3)))
            for axis in range(3):
                sums[:, axis] += np.bincount(window, weights=values[inside, axis], minlength=n)

    def means(self, name: str) -> np.ndarray:
        """(n_windows, 3) means in the order the windows were given."""
        if np.any(self._counts == 0):
            raise ValueError(f"{np.sum(self._counts == 0)} averaging windows received no samples")
        out = np.empty_like(self._sums[name])
        out[self._order] = self._sums[name] / self._counts[:, None]
        return out

    @property
    def counts(self) -> np.ndarray:
        out = np.empty_like(self._counts)
        out[self._order] = self._counts
        return out
