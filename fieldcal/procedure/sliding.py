"""Standard deviation over a sliding window: the kernel of the live stillness detector
(fieldcal.procedure.stillness) and of a recording's pose detector (fieldcal.recording.detect).

A module of its own so that the recording detector loads only this, not the live detector, its
settings and the orientation checks.
"""
from __future__ import annotations

import numpy as np


def sliding_std(values, n: int, ddof: int = 1) -> np.ndarray:
    """Standard deviation of every window of ``n`` consecutive rows, per column.

    Row j of the result is the window ending at row j + n - 1 (``len(values) - n + 1`` rows; none
    if there are fewer than ``n``). O(len) with cumulative sums, computed in blocks of ``n`` rows
    against a reference sample that always lies inside the window, so a large offset (raw counts
    around mid-scale, gravity on one axis) costs no precision: the error scales with the spread
    inside the window, not with the offset nor the length of the input. Long inputs are worked in
    pieces of about 16k rows so that the temporaries stay small.
    """
    x = _as_columns(values, n)
    m, c = x.shape
    if m < n:
        return np.empty((0, c))
    out = np.empty((m - n + 1, c))
    for first, rows in _pieces(x, n):
        out[first:first + len(rows) - n + 1] = _window_var(rows, n, ddof)
    return np.sqrt(out, out=out)


def sliding_variance_by_column(values: np.ndarray, n: int, ddof: int = 1) -> np.ndarray:
    """(c, m - n + 1): the variance of every window of ``n`` consecutive rows of ``values`` (m, c),
    as ``sliding_std`` squared, laid out a column's windows side by side (as they are made): a
    caller that combines the columns (the recording detector's norm over axes) reads each one
    contiguously, with no square root taken and squared again."""
    x = _as_columns(values, n)
    m, c = x.shape
    out = np.empty((c, max(m - n + 1, 0)))
    for first, rows in _pieces(x, n):
        out[:, first:first + len(rows) - n + 1] = _window_var_by_column(rows, n, ddof)
    return out


def _as_columns(values, n: int) -> np.ndarray:
    """``values`` as float rows (m, c), a single series as one column; a window under 2 refused."""
    x = np.asarray(values, dtype=float)
    if x.ndim == 1:
        x = x[:, None]
    if n < 2:
        raise ValueError(f"window of {n} samples: need at least 2")
    return x


def _pieces(x: np.ndarray, n: int):
    """(first window, its rows): x's windows of n rows, about _PIECE_ROWS rows' worth at a time."""
    step = max(1, _PIECE_ROWS // n) * n
    for first in range(0, len(x) - n + 1, step):
        yield first, x[first:first + step + n - 1]


_PIECE_ROWS = 1 << 14


def _window_var(x: np.ndarray, n: int, ddof: int) -> np.ndarray:
    """(m - n + 1, c): variance of every window of n rows of x (m, c; at least n rows)."""
    return _window_var_by_column(x, n, ddof).T


def _window_var_by_column(x: np.ndarray, n: int, ddof: int) -> np.ndarray:
    """(c, m - n + 1): variance of every window of n rows of x (m, c; at least n rows), by blocks
    of n rows."""
    m, c = x.shape
    blocks_n = -(-m // n)
    # Worked column by column (x transposed: each column's samples side by side), so that every
    # step below runs along n samples at a time instead of along the c columns of one sample.
    xt = np.empty((c, blocks_n * n))
    xt[:, :m] = x.T
    xt[:, m:] = x[-1:].T  # the last block padded with the last sample
    blocks = xt.reshape(c, blocks_n, n)
    ref = blocks[:, :, :1]  # (c, B, 1): first sample of each block
    d = blocks - ref
    p1 = np.cumsum(d, axis=2)
    p2 = np.cumsum(np.square(d, out=d), axis=2)
    # The window ending at position i of block b (b >= 1) is positions i+1..n-1 of block b-1 (none
    # when i = n-1), then positions 0..i of block b. Its first part is moved from block b-1's
    # reference to block b's, which lies inside the window.
    tail = np.arange(n - 1, -1, -1, dtype=float)
    delta = ref[:, :-1] - ref[:, 1:]
    # s1 = p1[1:] + a1 + tail·δ and s2 = p2[1:] + a2 + 2δ·a1 + tail·δ·δ, a = the block before's
    # sums from i+1 on, worked in place in the order written (the same numbers). Column 0 is the
    # first window, block 0 itself.
    s1, s2 = np.empty((2, c, blocks_n * n - n + 1))
    s1[:, 0], s2[:, 0] = p1[:, 0, -1], p2[:, 0, -1]
    a1 = np.subtract(p1[:, :-1, -1:], p1[:, :-1], out=d[:, :-1])
    a2 = p2[:, :-1, -1:] - p2[:, :-1]
    body1, body2 = s1[:, 1:].reshape(c, blocks_n - 1, n), s2[:, 1:].reshape(c, blocks_n - 1, n)
    np.add(p1[:, 1:], a1, out=body1)
    tail_delta = tail * delta
    body1 += tail_delta
    np.add(p2[:, 1:], a2, out=body2)
    np.multiply(2.0 * delta, a1, out=a2)
    body2 += a2
    body2 += np.multiply(tail_delta, delta, out=tail_delta)
    s1, s2 = s1[:, : m - n + 1], s2[:, : m - n + 1]
    # (s2 - s1·s1/n)/(n - ddof), clipped at 0, in s2.
    np.multiply(s1, s1, out=s1)
    s1 /= n
    s2 -= s1
    s2 /= n - ddof
    return np.maximum(s2, 0.0, out=s2)
