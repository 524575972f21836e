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

import functools

import numpy as np

_EXACT_POWERS = 10.0 ** np.arange(23)  # 10^0 .. 10^22: exact in binary64 (5^22 < 2^53)
_INT_POWERS = 10 ** np.arange(19, dtype=np.int64)
_MAX_EXACT = 2 ** 53  # every integer up to this is an exact double
_MAX_DIGITS = 18  # mantissa and exponent digits read as one int64 (< 2^63)
_PLUS, _MINUS, _POINT = 43, 45, 46
_PLAIN = bytes(b if b in b" \t\r\n0123456789.eE+-" else 0 for b in range(256))  # the rest: NUL


def solid_runs(blank: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """[start, stop) of the runs of False (the tokens) in the mask ``blank``, which ends True."""
    edges = np.flatnonzero(blank[1:] != blank[:-1]) + 1
    if len(blank) and not blank[0]:
        edges = np.concatenate([[0], edges])
    return edges[0::2], edges[1::2]


def blank_runs(a: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(a <= 32, and solid_runs of it) for bytes ``a`` that end with a blank, with no shifted
    copy of the edges: the mask is made behind one blank byte, so that its changes are the
    runs' edges as they are."""
    behind = np.empty(len(a) + 1, dtype=bool)
    behind[0] = True
    blank = np.less_equal(a, 32, out=behind[1:])
    edges = np.flatnonzero(behind[1:] != behind[:-1])
    return blank, edges[0::2], edges[1::2]


def plain_digits(text: bytes) -> bytes | None:
    """``text`` without its points, exponent letters and signs (what :func:`plain_decimals` reads
    as integers), or None if it holds any byte but blanks (space, tab, CR, LF) and ``0-9 + - . e
    E``: one pass, in which every other byte becomes a NUL."""
    digits = text.translate(_PLAIN, b".eE+-")
    return None if b"\0" in digits else digits


def plain_decimals(text: bytes, digits: bytes | None = None, start: np.ndarray | None = None,
                   stop: np.ndarray | None = None, fields: int | None = None) -> np.ndarray | None:
    """The numbers of ``text`` in order, or None unless each is a plain decimal in the fast path.

    ``text`` ends with a blank; ``digits``: ``plain_digits(text)``, ``start``/``stop``: its
    tokens, ``blank_runs(bytes)`` (each computed if not given); ``fields``: the tokens
    come in rows of so many (a block of lines of that many fields), a hint that lets a file
    whose one field with a point is the same in every row skip the search for the points."""
    if text[-1:] not in (b" ", b"\t", b"\r", b"\n"):
        return None if text else np.zeros(0)
    if digits is None:
        digits = plain_digits(text)
        if digits is None:
            return None
    a = np.frombuffer(text, dtype=np.uint8)
    if start is None or stop is None:
        _, start, stop = blank_runs(a)  # (text ends with a blank, as blank_runs needs)
    n = len(start)
    if n == 0:
        return np.zeros(0)
    # The points and exponent letters (at most one of each per token), each by its own scan:
    # one scan for both and a split costs twice as much (boolean indexing is slow).
    points = np.flatnonzero(a == _POINT)
    if not (b"e" in text or b"E" in text):
        value = _short_fixed_point(text, a, digits, start, stop, points, fields)
        if value is not _NOT_SHORT:
            return value
    letters = np.flatnonzero((a | 32) == ord("e")) if b"e" in text or b"E" in text else points[:0]
    signs = len(text) - len(digits) - len(points) - len(letters)  # the other bytes deleted
    pi = _token_of_each(points, start, stop)
    ei = _token_of_each(letters, start, stop)
    if pi is None or ei is None:
        return None
    lead = a[start]
    lead_sign = lead < _POINT  # + 43, - 45
    mantissa_end = stop.copy()
    mantissa_end[ei] = letters
    count = mantissa_end - start - lead_sign  # mantissa digits (the sign goes)...
    fraction = np.zeros(n, dtype=np.int64)  # digits after the point
    if len(points):
        after = mantissa_end[pi] - points - 1
        if (after < 0).any():  # a point in the exponent
            return None
        count[pi] -= 1  # ...and so does the point
        fraction[pi] = after
    if (count < 1).any():
        return None
    tail, exponent_signs = None, 0  # 10^(exponent digits) of each token
    if len(letters):
        first = a[letters + 1]
        signed = (first == _PLUS) | (first == _MINUS)
        exponent_signs = np.count_nonzero(signed)
        exponent_digits = stop[ei] - letters - 1 - signed
        if (exponent_digits < 1).any():  # "1e", "1e+"
            return None
        count[ei] += exponent_digits
        tail = np.ones(n, dtype=np.int64)
        tail[ei] = _INT_POWERS[np.minimum(exponent_digits, _MAX_DIGITS)]
    # A sign stands first in its token or right after its exponent letter: then those are all.
    if signs != np.count_nonzero(lead_sign) + exponent_signs or (count > _MAX_DIGITS).any():
        return None
    # Every token keeps at least one digit, so the tokens stay where they were, one int each.
    # Read as unsigned (the signs are gone, and 18 digits fit either way): numpy 2.4 reads uint64
    # text some 1.7× faster than int64, the largest single cost of a text recording's import.
    ints = np.fromstring(digits, dtype=np.uint64, sep=" ").view(np.int64)
    if ints.size != n:
        return None
    if tail is None:
        mantissa, exponent = ints, -fraction
    else:
        mantissa = ints // tail
        exponent = ints - mantissa * tail
        if (first == _MINUS).any():
            exponent[ei] *= np.where(first == _MINUS, -1, 1)
        exponent -= fraction
    if not ((mantissa <= _MAX_EXACT).all() and (exponent >= -22).all() and (exponent <= 22).all()):
        return None
    m = mantissa.astype(np.float64)
    if (exponent <= 0).all():  # the usual file: no multiplications needed
        value = np.divide(m, _EXACT_POWERS[-exponent], out=m)
    else:
        value = np.where(exponent >= 0, m * _EXACT_POWERS[np.maximum(exponent, 0)],
                         m / _EXACT_POWERS[np.maximum(-exponent, 0)])
    return np.negative(value, out=value, where=lead == _MINUS)  # -0 stays -0.0, as strtod reads it


_NOT_SHORT = object()
_SHORT_TOKEN = 15  # bytes: sign and point included, at most 15 digits, < 10^15 < 2^53, |exponent| < 22


def _short_fixed_point(text: bytes, a: np.ndarray, digits: bytes, start: np.ndarray, stop: np.ndarray,
                       points: np.ndarray, fields: int | None):
    """The usual log's numbers (no exponent, tokens of at most _SHORT_TOKEN bytes, no point or
    one in the same field of every row of ``fields`` tokens) by fewer passes than the general
    path: such a token is inside the exact range by its length alone, and the points' tokens are
    a slice, checked, not searched. The same values bit for bit; None for a token that is no
    plain decimal; _NOT_SHORT for text of any other shape (the general path reads it)."""
    length = stop - start
    if int(length.max()) > _SHORT_TOKEN:
        return _NOT_SHORT
    holders = _one_point_a_row(points, start, stop, fields) if len(points) else slice(0, 0)
    if holders is None:
        return _NOT_SHORT
    lead = a[start]
    lead_sign = lead < _POINT  # + 43, - 45
    signs = len(text) - len(digits) - len(points)  # the bytes deleted that are no point
    if signs and signs != np.count_nonzero(lead_sign):  # a sign that does not stand first
        return None
    if int(length.min()) < 3:  # "-", ".", "-." have no digit: only a token this short can be one
        count = length - lead_sign
        count[holders] -= 1
        if (count < 1).any():
            return None
    ints = np.fromstring(digits, dtype=np.uint64, sep=" ")
    if ints.size != len(start):
        return None
    value = ints.astype(np.float64)
    if len(points):  # each point's token: the digits after it, fewer than _SHORT_TOKEN
        value[holders] /= _EXACT_POWERS[stop[holders] - points - 1]
    if signs:
        np.negative(value, out=value, where=lead == _MINUS)  # -0 stays -0.0, as strtod reads it
    return value


def _one_point_a_row(points: np.ndarray, start: np.ndarray, stop: np.ndarray, fields: int | None):
    """The tokens holding ``points`` as a slice when every row of ``fields`` tokens holds one
    point, in the same field; else None."""
    n = len(start)
    if not fields or n % fields or len(points) != n // fields:
        return None
    field = int(np.searchsorted(start, points[0], side="right")) - 1
    if not 0 <= field < fields:
        return None
    holders = slice(field, None, fields)
    return holders if ((start[holders] <= points) & (points < stop[holders])).all() else None


def _token_of_each(positions: np.ndarray, start: np.ndarray, stop: np.ndarray):
    """Which token holds each of the sorted ``positions`` (all inside tokens): a slice when every
    token holds exactly one (the usual file, no search), None when some token holds two."""
    if len(positions) == len(start) and ((start <= positions) & (positions < stop)).all():
        return slice(None)
    token = np.searchsorted(start, positions, side="right") - 1
    if len(token) > 1 and (token[1:] <= token[:-1]).any():
        return None
    return token


# Fixed-width lines: the columns of the first line say where every line's blanks, points,
# exponent letters and digits are; each line is then checked against that layout and its numbers
# made from its digit bytes by arithmetic, with no token search and no text-to-number conversion.
_SEPARATOR = np.zeros(256, dtype=bool)
_SEPARATOR[[9, 13, 32]] = True  # tab, CR, space: the blanks plain_digits lets through (LF ends a line)
_LETTER = ord("e")
_PAD = _SEPARATOR.copy()
_PAD[[_PLUS, _MINUS]] = True  # the blank before a right-aligned field: a sign or a blank
_LAYOUT_CLASSES = bytes(32 if _SEPARATOR[b] else b if b in (_POINT, _LETTER) else _LETTER if b == ord("E")
                        else _MINUS if b == _PLUS else b if b == _MINUS else 48
                        for b in range(256))  # " ", ".", "e", "-" or "0": all a layout depends on
_WRAPPED_PLUS, _WRAPPED_MINUS = (_PLUS - 48) % 256, (_MINUS - 48) % 256  # a sign less "0", as uint8
_FIXED_DIGITS = 15  # a mantissa's columns: its integer below 10^15 < 2^53, exact as a double
_EXPONENT_DIGITS = 3
_PRODUCTS_PER_CALL = 1 << 17  # rows × columns × groups in one matmul: below OpenBLAS's threshold
# for threads (2^18), whose waiting would cost CPU for nothing on a product this small


def fixed_width_decimals(text: bytes, nlines: int) -> np.ndarray | None:
    """(nlines, fields) numbers of ``text``, ``nlines`` lines each ending in LF, when its lines
    are alike: all the same length, their separators (space, tab, CR), points and exponent
    letters in the same columns as the first line's, every other byte a digit, or a sign where
    one may stand (first in a mantissa or an exponent of two columns or more; in a right-aligned
    field's blank, as printf's ``%15.7e`` puts it), at most 15 mantissa columns and 3 exponent
    digits a field, each value within Clinger's exact range. The usual fixed-format log
    (``%.6f`` times, counts of so many digits, ``%15.7e``). Else None: the caller reads the text
    token by token; nothing here guesses.

    A field's mantissa digits make one integer, exactly (products of a digit and a power of ten,
    and their sums, are integers below 2^53: every double operation on them is exact); scaled
    by 10^(exponent - digits after its point), a power of at most 22 and so exact, in one
    correctly rounded multiplication or division, the value is bit for bit the one strtod
    reads (as plain_decimals' exact path)."""
    width = len(text) // nlines if nlines else 0
    if width < 2 or width * nlines != len(text):
        return None
    layout = _fixed_layout(text[:width - 1].translate(_LAYOUT_CLASSES))
    if layout is None:
        return None
    (separators, points, letters, digit_columns, weights, fraction, plain_fields, exponent_fields, leads,
     lead_groups, blank_leads, pads, padded, pad_lead) = layout
    lines = np.frombuffer(text, dtype=np.uint8).reshape(nlines, width)
    # Each column's bytes of a class it allows (each kind of column by one gather: a few
    # columns each; a digit column's by the digits' values, below).
    if not ((lines[:, -1] == 10).all() and _SEPARATOR[lines[:, separators]].all()  # LF: the only line ends
            and (lines[:, points] == _POINT).all() and ((lines[:, letters] | 32) == _LETTER).all()
            and _PAD[lines[:, pads]].all()):
        return None
    digits = lines[:, digit_columns]  # a copy, made digits' values in place: any other byte wraps above 9
    digits -= 48
    # A sign (or, right-aligned, a blank) where a group's first digit may be adds nothing to it;
    # a sign in the blank before a field (no digit column) nothing either; both is no number ("- 1").
    held, pad = digits[:, leads], lines[:, pads]
    no_digit, pad_sign = held > 9, pad > 32
    minus = None
    if no_digit.any() or pad_sign.any():
        sign = (held == _WRAPPED_MINUS) | (held == _WRAPPED_PLUS)
        if (no_digit & ~sign & ~(_SEPARATOR[(held + 48) & 255] & blank_leads)).any():
            return None
        linked = pad_lead >= 0
        if (pad_sign[:, linked] & no_digit[:, pad_lead[linked]]).any():
            return None
        minus = np.zeros((nlines, weights.shape[1]), dtype=bool)
        minus[:, lead_groups] = held == _WRAPPED_MINUS
        minus[:, padded] |= pad == _MINUS
        held[no_digit] = 0
        digits[:, leads] = held
    if digits.max() > 9:
        return None
    floats = digits.astype(np.float64)
    groups = np.empty((nlines, weights.shape[1]))  # each mantissa's integer, then each exponent
    step = max(1, _PRODUCTS_PER_CALL // weights.size)
    for lo in range(0, nlines, step):  # blocks of rows, a few per piece of text
        np.matmul(floats[lo:lo + step], weights, out=groups[lo:lo + step])
    if minus is not None:
        np.negative(groups, out=groups, where=minus)  # -0 stays -0.0, as strtod reads it
    values = groups[:, :len(fraction)]
    if len(exponent_fields) == 0:
        _scaled_down(values, fraction, np.arange(len(fraction)))
        return values
    _scaled_down(values, fraction, plain_fields)
    power = (groups[:, len(fraction):] - fraction[exponent_fields]).astype(np.int64)
    if not (np.abs(power) <= 22).all():
        return None
    mantissa = values[:, exponent_fields]
    up = power >= 0
    if up.all():
        values[:, exponent_fields] = mantissa * _EXACT_POWERS[power]
    elif not up.any():
        values[:, exponent_fields] = mantissa / _EXACT_POWERS[-power]
    else:
        values[:, exponent_fields] = np.where(up, mantissa * _EXACT_POWERS[np.maximum(power, 0)],
                                              mantissa / _EXACT_POWERS[np.maximum(-power, 0)])
    return values


def _scaled_down(values: np.ndarray, fraction: np.ndarray, fields: np.ndarray) -> None:
    """values[:, f] /= 10^fraction[f] in place for the ``fields`` with digits after a point; a
    field of none (counts) is left as it is (x / 1 is x: the same bits), not divided (a log of
    a time and three counts: a quarter of the divisions, a column at a time)."""
    fields = np.asarray(fields, dtype=np.intp)
    fields = fields[fraction[fields] > 0]
    if len(fields) == len(fraction):
        values /= _EXACT_POWERS[fraction]
        return
    for field in fields.tolist():  # a loop over a line's fields, not its samples
        values[:, field] /= _EXACT_POWERS[fraction[field]]


@functools.lru_cache(maxsize=64)  # a file's pieces share a layout or a few: worked out once each
def _fixed_layout(line: bytes):
    """How to read lines laid out as ``line``, given as its byte classes (``_LAYOUT_CLASSES``:
    the pieces of one file share them, and so the layout): the separator, point and letter
    columns; the digit columns and the weight of each in its group (digit columns × groups,
    10^k in the group's column; a group is a field's mantissa, or an exponent, the fields'
    mantissas first); each field's digits after its point; the fields without and with an
    exponent; which digit columns may hold a sign instead (by index), their groups, and which
    of them a blank too; the blanks before fields that may hold a sign, their fields, and the
    index of each such field's own sign-capable first column (-1: none). None for a field with
    two points or letters, a point after its letter, a mantissa of no digit column or more
    than 15, an exponent of no digit or more than 3."""
    row = np.frombuffer(line, dtype=np.uint8)
    separator = _SEPARATOR[row]
    edges = np.flatnonzero(np.diff(np.concatenate([[1], separator.view(np.int8), [1]])))
    start, stop = edges[0::2], edges[1::2]
    fields = len(start)
    if fields == 0:
        return None
    point, letter = np.flatnonzero(row == _POINT), np.flatnonzero(row == _LETTER)
    point_field = np.searchsorted(start, point, side="right") - 1
    letter_field = np.searchsorted(start, letter, side="right") - 1
    if (np.diff(point_field) == 0).any() or (np.diff(letter_field) == 0).any():
        return None
    mantissa_stop = stop.copy()
    mantissa_stop[letter_field] = letter
    if (point >= mantissa_stop[point_field]).any():  # a point in an exponent
        return None
    columns = np.flatnonzero((row == 48) | (row == _MINUS))  # digit columns (a sign here: one that may be a digit)
    field = np.searchsorted(start, columns, side="right") - 1
    in_exponent = columns > mantissa_stop[field]
    exponent_group = np.full(fields, -1)
    exponent_group[letter_field] = fields + np.arange(len(letter))
    group = np.where(in_exponent, exponent_group[field], field)
    count = np.bincount(group, minlength=fields + len(letter))
    if ((count == 0).any() or (count[:fields] > _FIXED_DIGITS).any()
            or (count[fields:] > _EXPONENT_DIGITS).any()):
        return None
    order = np.argsort(group, kind="stable")  # the columns by group (each exponent after all mantissas)
    first = np.concatenate([[0], np.cumsum(count)[:-1]])  # each group's first column, by rank
    rank = np.empty(len(columns), dtype=np.int64)
    rank[order] = np.arange(len(columns))
    power = count[group] - 1 - (rank - first[group])
    weights = np.zeros((len(row), len(count)))
    weights[columns, group] = _EXACT_POWERS[power]
    fraction = np.zeros(fields, dtype=np.int64)
    fraction[point_field] = mantissa_stop[point_field] - point - 1
    # A sign may stand first in a mantissa or an exponent of two columns or more, where other
    # lines have a digit ("-1.5" and "12.5"; a mantissa that starts with a point has none).
    # Right-aligned fields ("  1.5e+00" and " -1.5e+00") have it where other lines have a
    # blank: the blank before a field when one more blank (or the line's start) keeps it apart
    # from the field before, and the first column of a field that starts with a sign after a
    # blank or at the line's start (a blank there: a digit column fewer for that line).
    lead = (power == count[group] - 1) & (count[group] >= 2) & ((columns == start[field]) | in_exponent)
    signed_start = lead & ~in_exponent & (row[columns] == _MINUS) & (
        (columns == 0) | separator[np.maximum(columns - 1, 0)])
    padded = np.flatnonzero((start >= 1) & separator[np.maximum(start - 1, 0)]
                            & ((start == 1) | separator[np.maximum(start - 2, 0)]))
    mantissa_leads = np.flatnonzero(lead & ~in_exponent)
    pad_lead = np.full(len(padded), -1)  # which of the leads is the first column of a padded field's mantissa
    has = np.isin(padded, field[mantissa_leads])
    pad_lead[has] = np.searchsorted(np.flatnonzero(lead),
                                    mantissa_leads[np.searchsorted(field[mantissa_leads], padded[has])])
    exponent_fields = np.flatnonzero(exponent_group >= 0)
    return (np.setdiff1d(np.flatnonzero(separator), start[padded] - 1), point, letter, columns, weights[columns],
            fraction, np.setdiff1d(np.arange(fields), exponent_fields), exponent_fields, np.flatnonzero(lead),
            group[lead], signed_start[lead], start[padded] - 1, padded, pad_lead)


