"""Blank-separated plain decimal numbers -> float64, exactly as strtod reads them, fast.

numpy's text-to-float conversion (``np.fromstring(..., sep=" ")``, ``np.loadtxt``, ``float()``)
costs about 200 ns a number, most of a text recording's import. This module reads the usual
numbers of an IMU log (``-1.25``, ``3.3108000e+04``, ``1234.5678``) at a fraction of that:

- every token is checked, vectorised, to be one plain decimal: optional sign, digits with at
  most one point, at least one digit, optional exponent (``e``/``E``, optional sign, digits);
- the point, the exponent letter and the signs are deleted (one ``bytes.translate``) and each
  token's remaining digits are read as one integer by numpy's integer parser (~8× faster than
  its float parser): mantissa digits followed by exponent digits, split again by a division;
- the value is ``mantissa × 10^k`` or ``mantissa / 10^-k``. When the mantissa is at most 2^53
  and |k| <= 22, both operands are exact doubles and IEEE arithmetic rounds the one operation
  correctly: the result is the correctly rounded value, bit for bit what strtod returns
  (Clinger's fast path, the first case of every correct strtod).

Anything else (more than 18 digits, |k| > 22, a token that is not a plain decimal) gives None:
the caller then uses the general, slower conversion. Nothing here guesses.
"""
from __future__ import annotations

import numpy as np

_EXACT_POWERS = 10.0 ** np.arange(23)  # 10^0 .. 10^22: exact in binary64 (5^22 < 2^53)
_INT_POWERS = 10 ** np.arange(19, dtype=np.int64)
_MAX_EXACT = 2 ** 53  # every integer up to this is an exact double
_MAX_DIGITS = 18  # mantissa and exponent digits read as one int64 (< 2^63)
_PLUS, _MINUS, _POINT = 43, 45, 46


def solid_runs(blank: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """[start, stop) of the runs of False (the tokens) in the mask ``blank``, which ends True."""
    edges = np.flatnonzero(blank[1:] != blank[:-1]) + 1
    if len(blank) and not blank[0]:
        edges = np.concatenate([[0], edges])
    return edges[0::2], edges[1::2]


def plain_decimals(text: bytes, start: np.ndarray | None = None,
                   stop: np.ndarray | None = None) -> np.ndarray | None:
    """The numbers of ``text`` in order, or None unless each is a plain decimal in the fast path.

    ``text`` holds only blanks (space, tab, CR, LF) and the bytes ``0-9 + - . e E``, and ends
    with a blank; ``start``/``stop``: its tokens, ``solid_runs(bytes <= 32)`` (computed if not
    given)."""
    a = np.frombuffer(text, dtype=np.uint8)
    if start is None or stop is None:
        start, stop = solid_runs(a <= 32)
    n = len(start)
    if n == 0:
        return np.zeros(0)
    # A sign stands first in its token or right after the exponent letter: never after a sign,
    # a digit or a point. Shifted by 33, the signs are the bytes below 13 (+ 10, - 12), and
    # those three below 36 ("E" 36, "e" 68; blanks wrap round to 223 and above).
    shifted = a - np.uint8(33)
    if ((shifted[1:] < 13) & (shifted[:-1] < 36)).any():
        return None
    points = np.flatnonzero(a == _POINT)
    letters = np.flatnonzero((a | 32) == ord("e"))
    pi = _token_of_each(points, start, stop)
    ei = _token_of_each(letters, start, stop)
    if pi is None or ei is None:
        return None
    mantissa_end = stop.copy()
    mantissa_end[ei] = letters
    digits = mantissa_end - start - (a[start] < _POINT)  # less a leading sign (+ 43, - 45)
    fraction = np.zeros(n, dtype=np.int64)  # digits after the point
    if len(points):
        after = mantissa_end[pi] - points - 1
        if (after < 0).any():  # a point in the exponent
            return None
        digits[pi] -= 1
        fraction[pi] = after
    exponent_digits = np.zeros(n, dtype=np.int64)
    negative_exponent = None
    if len(letters):
        first = a[letters + 1]
        signed = (first == _PLUS) | (first == _MINUS)
        counted = stop[ei] - letters - 1 - signed
        if (counted < 1).any():  # "1e", "1e+"
            return None
        exponent_digits[ei] = counted
        negative_exponent = np.zeros(n, dtype=bool)
        negative_exponent[ei] = first == _MINUS
    if (digits < 1).any() or (digits + exponent_digits > _MAX_DIGITS).any():
        return None
    # Every token keeps at least one digit, so the tokens stay where they were, one int each.
    ints = np.fromstring(text.translate(None, b".eE+-"), dtype=np.int64, sep=" ")
    if ints.size != n:
        return None
    tail = _INT_POWERS[exponent_digits]
    mantissa = ints // tail
    exponent = ints - mantissa * tail
    if negative_exponent is not None:
        exponent = np.where(negative_exponent, -exponent, exponent)
    exponent -= fraction
    if not ((mantissa <= _MAX_EXACT) & (np.abs(exponent) <= 22)).all():
        return None
    m = mantissa.astype(np.float64)
    value = np.where(exponent >= 0, m * _EXACT_POWERS[np.maximum(exponent, 0)],
                     m / _EXACT_POWERS[np.maximum(-exponent, 0)])
    return np.where(a[start] == _MINUS, -value, value)  # -0 stays -0.0, as strtod reads it


def _token_of_each(positions: np.ndarray, start: np.ndarray, stop: np.ndarray):
    """Which token holds each of the sorted ``positions`` (all inside tokens): a slice when every
    token holds exactly one (the usual file, no search), None when some token holds two."""
    if len(positions) == len(start) and ((start <= positions) & (positions < stop)).all():
        return slice(None)
    token = np.searchsorted(start, positions, side="right") - 1
    if len(token) > 1 and (token[1:] <= token[:-1]).any():
        return None
    return token
