"""Delimited text (CSV, or whitespace-separated columns) with a channel map.

One sample per line.  Lines end in LF or CRLF; blank lines and lines starting with the comment
prefix (after optional leading blanks) are skipped.  A line none of whose mapped fields is a
number is a header line (skipped, its bytes counted as discarded, not reported as malformed);
any other line that cannot be read is *malformed*: its bytes are discarded, it is counted in
``malformed_lines`` and its 1-based line number (over the whole stream, every line counted)
is kept among the last few in ``malformed_line_numbers``.

Numbers are plain decimals: optional sign, digits with an optional point, optional exponent
(``-1.5``, ``+00.25``, ``.5``, ``3e-4``); blanks around a field are ignored.  Columns not
mapped may hold anything.
"""
from __future__ import annotations

import math
import re
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType

import numpy as np

from drivers.chunk import SampleChunk
from drivers.protocols.base import ParserCounters
from drivers.protocols.decimals import (blank_runs, fixed_width_decimals, plain_decimals, plain_digits,
                                        solid_runs)

_LF, _CR, _SP, _TAB = 10, 13, 32, 9
_NUMERIC_BYTES = b"0123456789+-.eE,"
_NUMERIC = np.zeros(256, dtype=bool)
_NUMERIC[np.frombuffer(_NUMERIC_BYTES, dtype=np.uint8)] = True
_NUMBER_BYTES = _NUMERIC_BYTES.replace(b",", b"")  # the bytes of one number
_NUMBER_BYTE = _NUMERIC.copy()
_NUMBER_BYTE[44] = False  # inside one field


@dataclass(frozen=True)
class TriadColumns:
    """Where a triad's x, y, z are (0-based column numbers), the factor from the text's value to
    ``unit`` (output = text value * scale), and that unit's name."""

    columns: tuple[int, int, int]
    scale: float = 1.0
    unit: str = ""


@dataclass(frozen=True)
class ChannelMap:
    """Which column holds what.  Column numbers are 0-based: the first field of a line is 0.

    ``delimiter``: one character (``","``, ``";"``, ``"\\t"``...) or None for runs of blanks
    (spaces and tabs).  ``comment``: prefix of lines to skip, or None.  ``time_column``: sample
    time, in seconds after multiplying by ``time_scale`` (e.g. 1e-3 for milliseconds); without
    it every sample of one ``feed`` gets that call's host time.  ``triads``: name ->
    :class:`TriadColumns`.  ``temperature_column`` (times ``temperature_scale``) feeds
    ``SampleChunk.temperature``.  ``counter_column``: the device's sample counter, checked for
    gaps and returned as extras["counter"]; it wraps to 0 after ``counter_modulus - 1`` when a
    modulus is given.
    """

    triads: Mapping[str, TriadColumns]
    delimiter: str | None = ","
    comment: str | None = "#"
    time_column: int | None = None
    time_scale: float = 1.0
    temperature_column: int | None = None
    temperature_scale: float = 1.0
    counter_column: int | None = None
    counter_modulus: int | None = None

    def __post_init__(self) -> None:
        # Programmatic construction gets the checks of from_mapping (named from "channel_map");
        # triads given as plain tuples or mappings become TriadColumns.
        checked = _validate(self.to_mapping(), "channel_map")
        for key, value in checked.items():
            object.__setattr__(self, key, value)

    def __hash__(self) -> int:
        return hash((tuple(self.triads.items()), self.delimiter, self.comment, self.time_column,
                     self.time_scale, self.temperature_column, self.temperature_scale,
                     self.counter_column, self.counter_modulus))

    @property
    def columns(self) -> list[tuple[str, int]]:
        """(role, column) of every mapped column, roles like ``accelerometer.x`` or ``time``."""
        out = []
        if self.time_column is not None:
            out.append(("time", self.time_column))
        for name, tc in self.triads.items():
            out.extend((f"{name}.{axis}", c) for axis, c in zip("xyz", tc.columns))
        if self.temperature_column is not None:
            out.append(("temperature", self.temperature_column))
        if self.counter_column is not None:
            out.append(("counter", self.counter_column))
        return out

    def to_mapping(self) -> dict:
        """The plain-dict form from_mapping reads (column lists, null for unset)."""

        def triad(tc):
            if isinstance(tc, TriadColumns):
                return {"columns": list(tc.columns), "scale": tc.scale, "unit": tc.unit}
            if isinstance(tc, (tuple, list)):
                return {"columns": list(tc)}
            return tc

        triads = ({name: triad(tc) for name, tc in self.triads.items()}
                  if isinstance(self.triads, Mapping) else self.triads)
        return {"delimiter": self.delimiter, "comment": self.comment, "time_column": self.time_column,
                "time_scale": self.time_scale, "triads": triads,
                "temperature_column": self.temperature_column,
                "temperature_scale": self.temperature_scale, "counter_column": self.counter_column,
                "counter_modulus": self.counter_modulus}

    @classmethod
    def from_mapping(cls, m, where: str) -> ChannelMap:
        """Validate a plain dict (as loaded from YAML); ValueError with one line naming the field.

        ``delimiter`` may also be ``"whitespace"`` (same as null).  Omitted keys take the
        defaults; ``triads`` is required, each with ``columns`` (three 0-based column numbers)
        and optional ``scale`` and ``unit``.
        """
        return cls(**_validate(m, where))


_KEYS = ("delimiter", "comment", "time_column", "time_scale", "triads", "temperature_column",
         "temperature_scale", "counter_column", "counter_modulus")
_TRIAD_KEYS = ("columns", "scale", "unit")


def _validate(m, where: str) -> dict:
    """ChannelMap keyword arguments from a plain mapping; one-line ValueError naming the field."""

    def fail(key: str, expected: str, got, described: str | None = None) -> None:
        got_text = _describe(got) if described is None else described
        raise ValueError(f"{_join(where, key)}: expected {expected}, got {got_text}")

    if not isinstance(m, Mapping):
        fail("", f"a mapping with keys {', '.join(_KEYS)}", m)
    for key in m:
        if key not in _KEYS:
            fail(str(key), f"only the keys {', '.join(_KEYS)}", key, f"the unknown key {_describe(key)}")

    delimiter = m.get("delimiter", ",")
    if delimiter == "whitespace":
        delimiter = None
    if delimiter is not None and (not isinstance(delimiter, str) or len(delimiter) != 1
                                  or delimiter in "\r\n0123456789+-.eE" or ord(delimiter) > 127):
            fail("delimiter", "one ASCII character that cannot be part of a number, or "
                 "'whitespace'/null", delimiter)
    comment = m.get("comment", "#")
    if comment is not None:
        if not isinstance(comment, str) or not comment or any(ord(c) > 127 or c in "\r\n"
                                                               for c in comment):
            fail("comment", "a non-empty ASCII prefix or null", comment)
        if comment[0] in "0123456789+-.eE \t" or (delimiter is not None and comment[0] == delimiter):
            fail("comment", "a prefix that cannot start a data line", comment)

    def column(key: str, value, here: str | None = None, nullable: bool = True) -> int | None:
        if value is None and nullable:
            return None
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            raise ValueError(f"{_join(where, here or key)}: expected a column number (0-based "
                             f"integer >= 0){' or null' if nullable else ''}, got {_describe(value)}")
        return value

    def number(key: str, value, here: str | None = None, positive: bool = False) -> float:
        ok = not isinstance(value, bool) and isinstance(value, (int, float))
        x = float(value) if ok else math.nan
        if not (ok and math.isfinite(x) and (x > 0 if positive else x != 0)):
            what = "a finite number > 0" if positive else "a finite non-zero number"
            if isinstance(value, str):
                what += " (YAML reads quoted or dot-less exponents as text; write e.g. 1.0e-3)"
            raise ValueError(f"{_join(where, here or key)}: expected {what}, got {_describe(value)}")
        return x

    time_column = column("time_column", m.get("time_column"))
    time_scale = number("time_scale", m.get("time_scale", 1.0), positive=True)
    temperature_column = column("temperature_column", m.get("temperature_column"))
    temperature_scale = number("temperature_scale", m.get("temperature_scale", 1.0))
    counter_column = column("counter_column", m.get("counter_column"))
    modulus = m.get("counter_modulus")
    if modulus is not None and (isinstance(modulus, bool) or not isinstance(modulus, int)
                                or modulus < 2):
        fail("counter_modulus", "an integer >= 2 or null", modulus)
    if modulus is not None and counter_column is None:
        fail("counter_modulus", "null when counter_column is not given", modulus)

    triads_in = m.get("triads")
    if not isinstance(triads_in, Mapping) or not triads_in:
        fail("triads", "a mapping of triad name -> {columns: [x, y, z], scale, unit}",
             "nothing (the key is missing)" if "triads" not in m else triads_in)
    triads: dict[str, TriadColumns] = {}
    for name, spec in triads_in.items():
        here = f"triads.{name}"
        if not isinstance(name, str) or not name:
            fail("triads", "triad names that are non-empty strings", name)
        if not isinstance(spec, Mapping):
            fail(here, "a mapping with keys columns, scale, unit", spec)
        for key in spec:
            if key not in _TRIAD_KEYS:
                fail(f"{here}.{key}", "only the keys columns, scale, unit", key,
                     f"the unknown key {_describe(key)}")
        cols = spec.get("columns")
        if not isinstance(cols, (list, tuple)) or len(cols) != 3:
            fail(f"{here}.columns", "3 column numbers",
                 "nothing (the key is missing)" if "columns" not in spec else cols)
        for i, c in enumerate(cols):
            column("", c, f"{here}.columns[{i}]", nullable=False)
        scale = number("", spec.get("scale", 1.0), f"{here}.scale")
        unit = spec.get("unit", "")
        if not isinstance(unit, str):
            fail(f"{here}.unit", "a string", unit)
        triads[name] = TriadColumns(tuple(int(c) for c in cols), scale, unit)

    seen: dict[int, str] = {}
    roles = [("time_column", time_column)]
    for name, tc in triads.items():
        roles.extend((f"triads.{name}.columns[{i}]", c) for i, c in enumerate(tc.columns))
    roles += [("temperature_column", temperature_column), ("counter_column", counter_column)]
    for role, c in roles:
        if c is None:
            continue
        if c in seen:
            raise ValueError(f"{_join(where, role)}: expected a column not used elsewhere, got {c} "
                             f"(also {_join(where, seen[c])})")
        seen[c] = role

    return {"triads": MappingProxyType(triads), "delimiter": delimiter, "comment": comment, "time_column": time_column,
                "time_scale": time_scale, "temperature_column": temperature_column,
                "temperature_scale": temperature_scale, "counter_column": counter_column,
                "counter_modulus": modulus}


def _join(where: str, key: str) -> str:
    if not key:
        return where
    return f"{where}.{key}" if where else key


def _describe(value) -> str:
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    text = repr(value) if not isinstance(value, (list, tuple, dict)) else _short(value)
    text = text.replace("\n", "\\n")
    return text if len(text) <= 60 else text[:57] + "..."


def _short(value) -> str:
    if isinstance(value, dict):
        return "a mapping" if value else "an empty mapping"
    return "[" + ", ".join(_describe(v) for v in value) + "]"


class DelimitedTextParser:
    """Stream parser for one-sample-per-line text in a :class:`ChannelMap` layout; a StreamParser.

    Besides ``counters`` (frames = data lines accepted; discarded_bytes = bytes of header and
    malformed lines; sequence gaps from the counter column): ``lines`` (lines seen),
    ``header_lines``, ``malformed_lines``, and ``malformed_line_numbers`` and
    ``header_line_numbers`` (the last ``keep_malformed`` of each, 1-based).
    """

    def __init__(self, channel_map: ChannelMap, *, max_line_bytes: int = 65536,
                 keep_malformed: int = 10) -> None:
        self.map = channel_map
        self.counters = ParserCounters()
        self.lines = 0
        self.header_lines = 0
        self.malformed_lines = 0
        self.malformed_line_numbers: deque[int] = deque(maxlen=keep_malformed)
        self.header_line_numbers: deque[int] = deque(maxlen=keep_malformed)
        self.max_line_bytes = int(max_line_bytes)
        self._buf = b""
        self._overlong = False  # dropping the rest of a line longer than max_line_bytes
        self._last_counter: int | None = None
        roles = channel_map.columns
        # parse the mapped columns in column order; _slot[role] = index in that order
        order = sorted(roles, key=lambda rc: rc[1])
        self._cols = np.array([c for _, c in order], dtype=np.int64)
        self._first_columns = bool((self._cols == np.arange(len(self._cols))).all())  # 0, 1, 2...
        self._slot = {role: i for i, (role, _) in enumerate(order)}
        self._need = int(self._cols.max()) + 1
        delim = channel_map.delimiter
        self._delim = None if delim is None else ord(delim)
        self._comment = None if channel_map.comment is None else np.frombuffer(
            channel_map.comment.encode("ascii"), dtype=np.uint8)
        # Blank-separated, and a comment (if any) starts with a byte no number has: a block of
        # clean lines can be recognised as such and parsed whole (see _clean_lines).
        self._runs_only = delim is None and (channel_map.comment is None or bool(
            channel_map.comment.encode("ascii")[:1].translate(None, _NUMBER_BYTES)))
        # A one-byte delimiter that no number contains (",", ";", "\t"): the same for blocks of
        # clean lines with no blanks at all (see _clean_delimited).
        self._clean_delim = (None if delim is None or delim.encode("ascii") in _NUMBER_BYTES + b" \r\n"
                             else delim.encode("ascii"))

    @property
    def device_time(self) -> bool:
        """The samples' ``t`` is the device's (a time column), not host time."""
        return self.map.time_column is not None

    def feed(self, data: bytes, t_host: float) -> SampleChunk | None:
        data = bytes(data)
        if not data:
            return None
        cut = data.rfind(b"\n")
        if cut < 0:
            self._hold(data)
            return None
        block = self._buf + data[: cut + 1]
        self._buf = b""
        self._hold(data[cut + 1:])
        if self.lines == 0 and (self._runs_only or self._clean_delim is not None):
            # A stream's first block starts with its header: read that line alone, so the clean
            # lines after it still take the whole-block path. (A header further on takes the
            # general path with its block: the same samples and counts, only slower.)
            head = block.find(b"\n") + 1
            if head < len(block) and not self._overlong and self._is_header(block[:head]):
                self._block(block[:head], t_host)  # counted as the header: no mapped field is a number
                block = block[head:]
        return self._block(block, t_host)

    def _hold(self, rest: bytes) -> None:
        """Keep an incomplete line; past max_line_bytes, drop it (one malformed line)."""
        if self._overlong:
            self.counters.discarded_bytes += len(rest)
            return
        self._buf += rest
        if len(self._buf) > self.max_line_bytes:
            self.counters.discarded_bytes += len(self._buf)
            self._buf = b""
            self._overlong = True

    def _block(self, block: bytes, t_host: float) -> SampleChunk | None:
        a = np.frombuffer(block, dtype=np.uint8)
        nlines = int(np.count_nonzero(a == _LF))  # one "\n" per line; the block ends with one
        first_line_no = self.lines + 1
        self.lines += nlines
        head_dropped = self._overlong  # the first line's head was dropped already: the rest goes too
        if head_dropped:
            self._overlong = False
            self.counters.discarded_bytes += block.find(b"\n") + 1
            self.malformed_lines += 1
            self.malformed_line_numbers.append(first_line_no)

        if self._clean_delim is not None and not head_dropped:  # (needs none of the blank runs below)
            values = _clean_delimited(block, a, np.flatnonzero(a == _LF), self._clean_delim, self._need)
            if values is not None:
                return self._whole_block(values, t_host)
        if self._runs_only and not head_dropped:  # lines all alike (a fixed-format log): by columns
            values = fixed_width_decimals(block, nlines)
            if values is not None and values.shape[1] >= self._need:
                return self._whole_block(values, t_host)
        # Only blanks and number bytes (the usual file): the blanks are the bytes up to 32.
        digits = plain_digits(block) if self._runs_only else None  # None: not plain
        plain = digits is not None
        if plain:  # runs of non-blank bytes: [run_start[i], run_stop[i])
            blank, run_start, run_stop = blank_runs(a)
        else:
            blank = (a == _SP) | (a == _TAB) | (a == _CR) | (a == _LF)
            run_start, run_stop = solid_runs(blank)
        if plain and not head_dropped:
            values = _clean_lines(block, digits, nlines, run_start, run_stop, self._need)
            if values is not None:
                return self._whole_block(values, t_host)

        # The general path: line by line, vectorised.
        ends = np.flatnonzero(a == _LF)
        starts = np.concatenate([[0], ends[:-1] + 1])
        line_no = first_line_no + np.arange(nlines)
        malformed = np.zeros(nlines, dtype=bool)
        malformed[0] = head_dropped
        stops = ends - ((ends > starts) & (a[np.maximum(ends - 1, 0)] == _CR))  # drop CR of CRLF
        first = _next_run(run_start, starts, stops)  # first non-blank byte of each line, or stop
        empty = first >= stops
        comment = np.zeros(nlines, dtype=bool)
        if self._comment is not None:
            k = len(self._comment)
            idx = first[:, None] + np.arange(k)
            fits = first + k <= stops
            comment = fits & (a[np.minimum(idx, len(a) - 1)] == self._comment).all(axis=1)
        data_line = ~(empty | comment | malformed)

        # field spans of the mapped columns, per data line
        li = np.flatnonzero(data_line)
        spans, enough = self._spans(a, blank, run_start, run_stop, starts[li], stops[li], first[li])
        bad_count = li[~enough]
        li, spans = li[enough], spans[enough]
        values, ok = self._values(a, spans)
        bad = np.concatenate([bad_count, li[~ok]])
        li = li[ok]
        if len(bad):
            self._reject(np.sort(bad), a, starts, ends, line_no)

        if len(li) == 0:
            return None
        self.counters.frames += len(li)
        return self._chunk(values, t_host)

    def _spans(self, a, blank, run_start, run_stop, starts, stops, first):
        """(m, k, 2) start/stop of the mapped fields, blanks trimmed; and which lines have them."""
        m, k = len(starts), len(self._cols)
        if m == 0:
            return np.zeros((0, k, 2), dtype=np.int64), np.zeros(0, dtype=bool)
        c = self._cols[None, :]
        if self._delim is not None:
            seps = np.flatnonzero(a == self._delim)
            f0 = np.searchsorted(seps, starts)  # index of the line's first separator
            nsep = np.searchsorted(seps, stops) - f0
            enough = nsep + 1 >= self._need
            if len(seps):
                last = len(seps) - 1
                lo = np.where(c == 0, starts[:, None], seps[np.minimum(np.maximum(f0[:, None] + c - 1, 0), last)] + 1)
                hi = np.where(c == nsep[:, None], stops[:, None], seps[np.minimum(f0[:, None] + c, last)])
            else:
                lo = np.broadcast_to(starts[:, None], (m, k))
                hi = np.broadcast_to(stops[:, None], (m, k))
            # trim blanks: first non-blank at or after lo, last non-blank before hi
            lo_t = np.where(blank[np.minimum(lo, len(a) - 1)], _next_run(run_start, lo, hi), lo)
            lo_t = np.minimum(lo_t, hi)
            hi_t = np.where(blank[np.maximum(hi - 1, 0)], _prev_run_stop(run_stop, hi, lo_t), hi)
            lo, hi = lo_t, np.maximum(hi_t, lo_t)
        else:
            # whitespace: fields are the runs of non-blank bytes
            f0 = np.searchsorted(run_start, first)
            ntok = np.searchsorted(run_start, stops) - f0
            enough = ntok >= self._need
            if len(run_start):
                ti = np.minimum(f0[:, None] + c, len(run_start) - 1)
                lo, hi = run_start[ti], run_stop[ti]
            else:
                lo = hi = np.zeros((m, k), dtype=np.int64)
        return np.stack([lo, hi], axis=2).astype(np.int64), enough

    def _values(self, a, spans):
        """Numbers of every span: (values (ok lines, k), ok mask over the lines)."""
        m, k = spans.shape[:2]
        got = _parse_spans(a, spans)
        if got is not None:
            return got
        # A bad line in the block.  Lines with an empty field or a byte that cannot be part of a
        # number are out at once; the rest are parsed in halves until the bad ones are isolated.
        lo, hi = spans[:, :, 0], spans[:, :, 1]
        odd = np.zeros(len(a) + 1, dtype=np.int64)
        np.cumsum(~_NUMBER_BYTE[a], out=odd[1:])
        ok = ~((hi <= lo) | (odd[hi] - odd[lo] > 0)).any(axis=1)
        values = np.zeros((m, k))
        _bisect(a, spans, np.flatnonzero(ok), values, ok)
        return values[ok], ok

    def _reject(self, bad, a, starts, ends, line_no) -> None:
        raw = a.tobytes()
        for i in bad.tolist():
            line = raw[starts[i]:ends[i] + 1]
            self.counters.discarded_bytes += len(line)
            if self._is_header(line):
                self.header_lines += 1
                self.header_line_numbers.append(int(line_no[i]))
            else:
                self.malformed_lines += 1
                self.malformed_line_numbers.append(int(line_no[i]))

    def _is_header(self, line: bytes) -> bool:
        """No mapped field holds a number (column names, units...)."""
        text = line.rstrip(b"\r\n")
        fields = (re.split(rb"[ \t\r]+", text.strip(b" \t\r")) if self._delim is None
                  else text.split(bytes([self._delim])))
        mapped = [fields[c] for c in self._cols.tolist() if c < len(fields)]
        return all(_numbers([f]) is None for f in mapped)

    def _whole_block(self, values: np.ndarray, t_host: float) -> SampleChunk:
        """A block of clean lines, every one a sample (``values``: its lines × fields)."""
        self.counters.frames += len(values)
        every = self._first_columns and values.shape[1] == len(self._cols)  # no column to leave out
        return self._chunk(values if every else values[:, self._cols], t_host)

    def _chunk(self, v: np.ndarray, t_host: float) -> SampleChunk:
        cm, slot, n = self.map, self._slot, len(v)
        t = _scaled(v, [slot["time"]], cm.time_scale)[:, 0] if cm.time_column is not None else np.full(n, float(t_host))
        triads = {name: _scaled(v, [slot[f"{name}.{ax}"] for ax in "xyz"], tc.scale) for name, tc in cm.triads.items()}
        temperature = None
        if cm.temperature_column is not None:
            temperature = _scaled(v, [slot["temperature"]], cm.temperature_scale)[:, 0]
        extras = {}
        if cm.counter_column is not None:
            counter = v[:, slot["counter"]]
            extras["counter"] = counter
            self._count_gaps(counter)
        return SampleChunk(t=t, triads=triads, temperature=temperature, extras=extras)

    def _count_gaps(self, counter: np.ndarray) -> None:
        c = np.round(np.minimum(np.maximum(counter, -2.0**62), 2.0**62)).astype(np.int64)
        prev = np.concatenate([[self._last_counter], c[:-1]]) if self._last_counter is not None else c[:-1]
        cur = c if self._last_counter is not None else c[1:]
        d = cur - prev
        mod = self.map.counter_modulus
        if mod is not None:
            d = np.mod(d, mod)
        jump = d != 1
        self.counters.sequence_gaps += int(jump.sum())
        self.counters.missing_frames += int(np.where(jump & (d > 1), d - 1, 0).sum())
        self._last_counter = int(c[-1])


def _scaled(v: np.ndarray, columns: list[int], scale: float) -> np.ndarray:
    """``v[:, columns] * scale``, with no copy that is not needed: columns side by side are a
    view, and a scale of 1 no product (x * 1.0 is x, bit for bit): a recording's text in counts
    or SI units is then copied once, into the recording's arrays, not three times on the way."""
    lo = columns[0]
    side_by_side = columns == list(range(lo, lo + len(columns)))
    picked = v[:, lo:lo + len(columns)] if side_by_side else v[:, columns]
    return picked if scale == 1.0 else picked * scale


def _parse_spans(a: np.ndarray, spans: np.ndarray):
    """All fields a[lo:hi] of spans (m, k, 2) by one fromstring call: (values of the good lines,
    good mask), or None if some field is not a plain number."""
    m, k = spans.shape[:2]
    if m == 0:
        return np.zeros((0, k)), np.zeros(0, dtype=bool)
    lo = spans[:, :, 0].ravel()
    hi = spans[:, :, 1].ravel()
    if not ((hi > lo).all() and (lo[1:] > hi[:-1]).all()):
        return None
    base, top = int(lo[0]), int(hi[-1]) + 1  # work on the stretch of bytes that holds the fields
    lo, hi = lo - base, hi - base
    # every field's bytes plus the byte after it (made a ","); fields are at least one byte apart
    mark = np.zeros(top - base + 1, dtype=np.int8)
    mark[lo] = 1
    mark[hi + 1] -= 1  # hi + 1 may be the next field's lo
    inside = np.cumsum(mark[:-1], dtype=np.int8).view(bool)
    b = a[base:top].copy()
    b[hi] = 44
    text = b[inside]
    if not (_NUMERIC[text].all() and np.count_nonzero(text == 44) == m * k):
        return None
    try:
        flat = np.fromstring(text.tobytes(), dtype=np.float64, sep=",")
    except ValueError:
        return None
    if flat.size != m * k:
        return None
    values = flat.reshape(m, k)
    ok = np.isfinite(values).all(axis=1)
    return values[ok], ok


def _clean_lines(block: bytes, digits: bytes, nlines: int, run_start, run_stop, need: int) -> np.ndarray | None:
    """(lines, T) numbers of a blank-separated block of only blanks and number bytes (its
    ``nlines`` lines) whose every line holds the same number T >= ``need`` of fields, all plain
    finite numbers (no blank line, comment, header or short line): the usual file, parsed whole
    (``digits``: plain_digits of the block). None for any other block (the general path then
    sorts its lines out)."""
    runs = len(run_start)
    if nlines == 0 or runs % nlines or runs // nlines < need:
        return None
    T = runs // nlines
    # Line i must hold runs i·T .. i·T + T - 1. Usually each T-th run ends its line ("\n" or
    # "\r\n" right after it): as many line ends as lines, so none falls inside one.
    a = np.frombuffer(block, dtype=np.uint8)
    last = run_stop[T - 1::T]
    after = a[last]  # the block ends with "\n": a run stops before it
    if not ((after == _LF) | ((after == _CR) & (a[np.minimum(last + 1, len(a) - 1)] == _LF))).all():
        # Else (blanks at line ends): each line's first run starts after the line before ends,
        # its last stops before its own end (runs are in order, so no line has more or fewer).
        ends = np.flatnonzero(a == _LF)
        if not ((run_start[T::T] > ends[:-1]).all() and (last <= ends).all()):
            return None
    return _numbers_of_block(block, nlines, T, digits, run_start, run_stop)


def _numbers_of_block(text: bytes, nlines: int, T: int, digits=None, run_start=None,
                      run_stop=None) -> np.ndarray | None:
    """(nlines, T) from blank-separated ``text`` (blanks and number bytes only), or None unless
    it holds exactly that many finite numbers. Plain decimals take plain_decimals' fast exact
    path; anything else one fromstring call (strtod), which reads plain decimals the same."""
    flat = plain_decimals(text, digits, run_start, run_stop, T)
    if flat is not None and flat.size == nlines * T:
        return flat.reshape(nlines, T)
    try:
        flat = np.fromstring(text, dtype=np.float64, sep=" ")
    except ValueError:  # a field that is not one number (e.g. "1-2", "1e")
        return None
    if flat.size != nlines * T or not np.isfinite(flat).all():
        return None
    return flat.reshape(nlines, T)


def _clean_delimited(block: bytes, a: np.ndarray, ends, delimiter: bytes, need: int) -> np.ndarray | None:
    """(lines, T) numbers of a block delimited by ``delimiter`` (one byte no number has) whose
    every line holds the same number T >= ``need`` of fields, each one plain finite number, with
    no blank anywhere but the line ends: parsed whole by one fromstring call once the delimiters
    are blanks. None for any other block (the general path then sorts its lines out).

    No blanks inside lines makes the count exact: every line has T - 1 delimiters, so it yields T
    numbers exactly when none of its fields is empty, and the block N·T exactly when no line has
    one; a field that is not one number fails fromstring or the count."""
    nlines = len(ends)
    if nlines == 0 or block.translate(None, b"\r\n" + _NUMBER_BYTES + delimiter):
        return None
    cuts = np.flatnonzero(a == delimiter[0])
    if len(cuts) % nlines or len(cuts) // nlines + 1 < need:
        return None
    T = len(cuts) // nlines + 1
    if (np.bincount(np.searchsorted(ends, cuts), minlength=nlines) != T - 1).any():
        return None
    return _numbers_of_block(block.replace(delimiter, b" "), nlines, T)


def _bisect(a, spans, idx, values, ok) -> None:
    """Parse the lines idx, halving a failing set until each bad line stands alone."""
    if len(idx) == 0:
        return
    got = _parse_spans(a, spans[idx])
    if got is not None:
        v, good = got
        values[idx[good]] = v
        ok[idx[~good]] = False
        return
    if len(idx) == 1:
        ok[idx] = False
        return
    half = len(idx) // 2
    _bisect(a, spans, idx[:half], values, ok)
    _bisect(a, spans, idx[half:], values, ok)


def _next_run(run_start: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """First run start at or after lo (hi where there is none before hi)."""
    if len(run_start) == 0:
        return np.asarray(hi).copy()
    j = np.searchsorted(run_start, lo)
    found = run_start[np.minimum(j, len(run_start) - 1)]
    return np.where((j < len(run_start)) & (found < hi), found, hi)


def _prev_run_stop(run_stop: np.ndarray, hi: np.ndarray, lo: np.ndarray) -> np.ndarray:
    """Last run stop at or before hi (lo where there is none after lo)."""
    if len(run_stop) == 0:
        return np.asarray(lo).copy()
    j = np.searchsorted(run_stop, hi, side="right") - 1
    found = run_stop[np.maximum(j, 0)]
    return np.where((j >= 0) & (found > lo), found, lo)


def _numbers(fields: list[bytes]) -> np.ndarray | None:
    """The fields as numbers (the fast path's rules), or None if any is not a plain number."""
    fields = [f.strip(b" \t") for f in fields]
    if any(not f or f.translate(None, _NUMERIC_BYTES) or b"," in f for f in fields):
        return None
    try:
        v = np.fromstring(b",".join(fields) + b",", dtype=np.float64, sep=",")
    except ValueError:
        return None
    if v.size != len(fields) or not np.isfinite(v).all():
        return None
    return v


class DelimitedTextEncoder:
    """Lines in a :class:`ChannelMap` layout, for the simulator and round-trip tests.

    Values are written as ``value / scale`` with ``float_format``; unmapped columns hold
    ``filler``.  ``header`` writes one line of column names before the first sample.  Without
    extras["counter"] a counter column counts the samples written (wrapping at the modulus).
    """

    def __init__(self, channel_map: ChannelMap, *, float_format: str = "%.9g",
                 time_format: str = "%.15g", header: bool = False, filler: str = "0",
                 line_end: str = "\n") -> None:
        self.map = channel_map
        self.float_format = float_format
        self.time_format = time_format
        self.header = header
        self.filler = filler
        self.line_end = line_end
        self._written = 0

    def _layout(self):
        cm = self.map
        roles = {c: r for r, c in cm.columns}
        ncol = max(roles) + 1
        sep = " " if cm.delimiter is None else cm.delimiter
        return roles, ncol, sep

    def header_line(self) -> bytes:
        roles, ncol, sep = self._layout()
        names = [roles.get(c, "unused").replace(".", "_") for c in range(ncol)]
        return (sep.join(names) + self.line_end).encode("ascii")

    def encode(self, chunk: SampleChunk) -> bytes:
        cm = self.map
        n = len(chunk)
        head = b""
        if self.header and self._written == 0:
            head = self.header_line()
        if n == 0:
            return head
        roles, ncol, sep = self._layout()
        cols, fmts = [], []
        for c in range(ncol):
            role = roles.get(c)
            if role is None:
                fmts.append(self.filler.replace("%", "%%"))
                continue
            if role == "time":
                cols.append(np.asarray(chunk.t, float) / cm.time_scale)
                fmts.append(self.time_format)
            elif role == "temperature":
                temp = chunk.temperature if chunk.temperature is not None else np.full(n, 25.0)
                cols.append(np.asarray(temp, float) / cm.temperature_scale)
                fmts.append(self.float_format)
            elif role == "counter":
                counter = chunk.extras.get("counter")
                if counter is None:
                    counter = self._written + np.arange(n)
                counter = np.asarray(counter).astype(np.int64)
                if cm.counter_modulus is not None:
                    counter = counter % cm.counter_modulus
                cols.append(counter)
                fmts.append("%d")
            else:
                name, axis = role.rsplit(".", 1)
                tc = cm.triads[name]
                cols.append(np.asarray(chunk.triads[name], float)[:, "xyz".index(axis)] / tc.scale)
                fmts.append(self.float_format)
        line = sep.join(fmts) + self.line_end
        flat = np.empty((n, len(cols)), dtype=object)
        for i, col in enumerate(cols):
            flat[:, i] = col.tolist()
        self._written += n
        return head + ((line * n) % tuple(flat.ravel().tolist())).encode("ascii")
