"""Fixed-point decimal text for whole arrays at once: CSV at numpy speed, no per-row formatting.

Each number becomes ``[-]digits.decimals``, right-aligned in a field as wide as the widest
allowed value (leading blanks, which every CSV reader strips from a number). Rounding is to the
nearest step of 10^-decimals; a value too large for its field is an error, never a wrong digit.
"""
from __future__ import annotations

import numpy as np

_SPACE, _MINUS, _DOT, _ZERO = (ord(c) for c in " -.0")


# The text of every 4-digit group 0000..9999: digits are looked up four at a time, so a
# 14-digit number costs four float divisions, not fourteen integer ones.
_GROUPS = np.array([[ord(c) for c in f"{i:04d}"] for i in range(10000)], dtype=np.uint8)


def _field(values: np.ndarray, decimals: int, digits: int) -> np.ndarray:
    """(n, m, width) uint8: the text of every value, width = 1 (sign) + digits + 1 + decimals."""
    scaled = np.rint(np.abs(values) * 10.0**decimals)  # whole numbers below 2^53: exact in float
    limit = 10.0 ** (digits + decimals)
    if not np.all(scaled < limit):  # NaN and inf fail here too
        bad = np.flatnonzero(~(scaled < limit).ravel())[0]
        raise ValueError(f"value {values.ravel()[bad]!r} does not fit {digits} digits before the point")
    ndig = digits + decimals
    groups = -(-ndig // 4)
    powers = 10000.0 ** np.arange(groups - 1, -1, -1)
    above = np.floor(scaled[..., None] / powers)  # the number's digits down to each group
    index = (above - 10000.0 * np.floor(above / 10000.0)).astype(np.intp)  # % without fmod's cost
    text = _GROUPS[index].reshape(values.shape + (4 * groups,))[..., 4 * groups - ndig:]
    # blank the leading zeros of the integer part (the units digit always shows)
    whole = np.floor(scaled / 10.0**decimals)
    shown = 1 + sum((whole >= 10.0**k).astype(np.int8) for k in range(1, digits))
    lead = digits - shown  # blanks before the first digit shown
    integer = np.where(np.arange(digits) < lead[..., None], np.uint8(_SPACE), text[..., :digits])
    sign = np.full(values.shape + (1,), _SPACE, np.uint8)
    body = np.concatenate([sign, integer, np.full_like(sign, _DOT), text[..., digits:]], -1)
    rows, cols = np.nonzero((values < 0) & (scaled > 0))
    body[rows, cols, lead[rows, cols]] = _MINUS  # just before the first digit shown
    return body


def format_rows(groups) -> bytes:
    """CSV lines of column groups: ``[(values (n, m), decimals, digits), ...]``, side by side."""
    fields = [_field(np.asarray(v, dtype=float), dec, dig) for v, dec, dig in groups]
    n = fields[0].shape[0]
    parts = []
    for f in fields:
        sep = np.full(f.shape[:2] + (1,), ord(","), np.uint8)
        parts.append(np.concatenate([f, sep], -1).reshape(n, -1))
    line = np.concatenate(parts, -1)
    line[:, -1] = ord("\n")  # the last separator ends the line
    return line.tobytes()
