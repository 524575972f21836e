"""Xsens MT binary protocol (Xbus): ``MTData2`` measurement messages, parsed and encoded.

Wire format (checked against public sources, not guessed):

* Message: ``PREAMBLE 0xFA | BID | MID | LEN | [EXT-LEN hi, lo] | DATA | CHECKSUM``. ``LEN == 0xFF``
  announces a 2-byte big-endian extended length. The checksum makes the sum of every byte from
  BID through the checksum 0 mod 256 (the preamble is excluded). Sources: einride/xsens-go
  ``message.go`` (field layout, ``Checksum``/``Validate``); Xsens xspublic ``xsmessage.h``
  (``XS_PREAMBLE 0xFA``, ``XS_EXTLENCODE 0xFF``, ext-length header ``{high, low}``,
  ``XS_MAXDATALEN = 8192 - 7``, ``XS_MAXMSGLEN = 8192``); ethz-asl/ethzasl_xsens_driver
  ``nodes/mtdevice.py`` ``read_msg`` (``'!H'`` extended length, checksum over BID..CS).
* Messages the MT emits by itself carry ``BID = 0xFF`` (xsens-go ``BusIdentifier`` doc); MTData2 is
  ``MID 0x36``. We only frame messages with ``BID == 0xFF``.
* MTData2 data is a sequence of items ``XDI (uint16 BE) | size (uint8) | payload`` (ethz
  ``parse_MTData2``: ``struct.unpack('!HB', ...)``). All numbers are big-endian.
* XDI layout (xsens-go ``dataidentifier.go``; Xsens ``xsdataidentifier.h``): group/type in
  ``xdi & 0xFFF0``, coordinate system in ``xdi & 0x000C`` (ENU 0, NED 4, NWU 8), precision in
  ``xdi & 0x0003``: 0 float32, 1 fixed 12.20 (int32 / 2**20), 2 fixed 16.32 (48 bits sent as the
  32-bit fraction then the 16-bit signed integer part, both big-endian: xsens-go
  ``fixedpoint.go``), 3 float64.
* Items decoded here (Xsens ``xsdataidentifier.h``): 0x1020 PacketCounter (uint16), 0x1060
  SampleTimeFine (uint32, 10 kHz ticks), 0x4020 Acceleration (3 reals, m/s^2), 0x8020 RateOfTurn
  (3 reals, rad/s), 0xC020 MagneticField (3 reals, a.u.), 0x0810 Temperature (1 real, deg C),
  0xA010 RawAccGyrMagTemp (9 x uint16 acc/gyr/mag counts + int16 temperature, 20 bytes: ethz
  ``parse_SCR`` ``"!9Hh"``; 0xA011 is the ``XDI_RawSigned`` variant with int16 counts). Every
  other item is skipped by its size byte: unknown items are legitimate, never errors. A known XDI
  whose size does not match its precision is treated as unknown rather than guessed at.

Output of the parser (a :class:`~drivers.chunk.SampleChunk` per call, device units):
triads ``accelerometer`` (m/s^2), ``gyroscope`` (rad/s), ``magnetometer`` (a.u.) and, from the raw
item, ``accelerometer_raw``, ``gyroscope_raw``, ``magnetometer_raw`` (counts as float64);
``temperature`` in deg C from 0x0810 (else None); extras ``packet_counter`` and, from the raw item,
``temperature_raw`` (counts). Time ``t`` is SampleTimeFine / 1e4 s, unwrapped across the 32-bit
wrap and across calls, when the message has it, else the host time of the ``feed`` call in which
the message completed.

Vectorised: candidate preambles are found with numpy, lengths and checksums validated for all of
them at once (a uint8 cumulative sum), the chain of accepted frames resolved by pointer doubling,
and the payloads of all frames of one item layout decoded through one big-endian structured dtype.
Python loops run only over distinct layouts, layout changes and chunk boundaries.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from drivers.chunk import SampleChunk
from drivers.protocols.base import ParserCounters

__all__ = ["MAX_DATA_LENGTH", "MAX_MESSAGE_LENGTH", "XsensMtData2Encoder", "XsensMtData2Parser"]

PREAMBLE = 0xFA
BID_MASTER = 0xFF
MID_MTDATA2 = 0x36
EXTENDED_LENGTH_CODE = 0xFF
MAX_MESSAGE_LENGTH = 8192  # xspublic XS_MAXMSGLEN
MAX_DATA_LENGTH = MAX_MESSAGE_LENGTH - 7  # xspublic XS_MAXDATALEN (extended header + checksum)
MAX_SHORT_DATA_LENGTH = 254  # xspublic XS_MAXSHORTDATALEN

XDI_TEMPERATURE = 0x0810
XDI_PACKET_COUNTER = 0x1020
XDI_SAMPLE_TIME_FINE = 0x1060
XDI_ACCELERATION = 0x4020
XDI_RATE_OF_TURN = 0x8020
XDI_MAGNETIC_FIELD = 0xC020
XDI_RAW_ACC_GYR_MAG_TEMP = 0xA010
XDI_RAW_SIGNED = 0x0001  # xsdataidentifier.h: "Tracker produces signed raw values"
XDI_TYPE_MASK = 0xFFF0
XDI_PRECISION_MASK = 0x0003

SAMPLE_TIME_FINE_HZ = 1e4

PRECISIONS = {"float32": 0, "fp1220": 1, "fp1632": 2, "float64": 3}
_PRECISION_SIZE = {0: 4, 1: 4, 2: 6, 3: 8}
_FP1632 = np.dtype([("frac", ">u4"), ("int", ">i2")])
_PRECISION_DTYPE = {0: np.dtype(">f4"), 1: np.dtype(">i4"), 2: _FP1632, 3: np.dtype(">f8")}
_VECTOR_ITEMS = {XDI_ACCELERATION: "accelerometer", XDI_RATE_OF_TURN: "gyroscope",
                 XDI_MAGNETIC_FIELD: "magnetometer"}
_RAW_TRIADS = ("accelerometer_raw", "gyroscope_raw", "magnetometer_raw")
_RAW_DTYPE_U = np.dtype([("v", ">u2", (9,)), ("temp", ">i2")])
_RAW_DTYPE_S = np.dtype([("v", ">i2", (9,)), ("temp", ">i2")])


def _to_float(values: np.ndarray, precision: int) -> np.ndarray:
    if precision == 1:
        return values.astype(np.float64) * 2.0**-20
    if precision == 2:
        return values["int"].astype(np.float64) + values["frac"].astype(np.float64) * 2.0**-32
    return values.astype(np.float64)


def _classify(xdi: int, size: int):
    """(kind, precision) of an item we decode, or None to skip it."""
    if xdi == XDI_PACKET_COUNTER and size == 2:
        return "packet_counter", 0
    if xdi == XDI_SAMPLE_TIME_FINE and size == 4:
        return "sample_time_fine", 0
    if xdi & ~XDI_RAW_SIGNED == XDI_RAW_ACC_GYR_MAG_TEMP and size == 20:
        return "raw", xdi & XDI_RAW_SIGNED
    base, precision = xdi & XDI_TYPE_MASK, xdi & XDI_PRECISION_MASK
    if base in _VECTOR_ITEMS and size == 3 * _PRECISION_SIZE[precision]:
        return _VECTOR_ITEMS[base], precision
    if base == XDI_TEMPERATURE and size == _PRECISION_SIZE[precision]:
        return "temperature", precision
    return None


def _walk_items(buf: bytes, start: int, length: int):
    """[(xdi, payload offset, size)] of one MTData2 data field, or None if the items overrun it."""
    items, off = [], 0
    while off < length:
        if off + 3 > length:
            return None
        p = start + off
        size = buf[p + 2]
        if off + 3 + size > length:
            return None
        items.append(((buf[p] << 8) | buf[p + 1], off + 3, size))
        off += 3 + size
    return items


class _Layout:
    """One MTData2 item layout: how to recognise it (item headers) and decode it (a dtype)."""

    def __init__(self, data_length: int, items) -> None:
        self.data_length = data_length
        cols, vals, names, formats, offsets = [], [], [], [], []
        self.kinds: dict[str, int] = {}  # kind -> precision, first occurrence wins
        for xdi, off, size in items:
            cols += [off - 3, off - 2, off - 1]
            vals += [xdi >> 8, xdi & 0xFF, size]
            kind = _classify(xdi, size)
            if kind is None or kind[0] in self.kinds:
                continue
            name, precision = kind
            self.kinds[name] = precision
            names.append(name)
            offsets.append(off)
            if name == "packet_counter":
                formats.append(np.dtype(">u2"))
            elif name == "sample_time_fine":
                formats.append(np.dtype(">u4"))
            elif name == "raw":
                formats.append(_RAW_DTYPE_S if precision else _RAW_DTYPE_U)
            elif name == "temperature":
                formats.append(_PRECISION_DTYPE[precision])
            else:
                formats.append(np.dtype((_PRECISION_DTYPE[precision], (3,))))
        self.header_cols = np.asarray(cols, dtype=np.intp)
        self.header_vals = np.asarray(vals, dtype=np.uint8)
        self.dtype = (np.dtype({"names": names, "formats": formats, "offsets": offsets,
                                "itemsize": data_length}) if names else None)
        triads = [n for n in _VECTOR_ITEMS.values() if n in self.kinds]
        if "raw" in self.kinds:
            triads += list(_RAW_TRIADS)
        extras = (["packet_counter"] if "packet_counter" in self.kinds else []) + (
            ["temperature_raw"] if "raw" in self.kinds else [])
        self.has_data = bool(triads) or "temperature" in self.kinds
        # Frames whose samples may share a chunk: same channels and the same time base.
        self.signature = ("sample_time_fine" in self.kinds, tuple(sorted(triads)),
                          "temperature" in self.kinds, tuple(sorted(extras)))

    def decode(self, b: np.ndarray, data_starts: np.ndarray) -> dict[str, np.ndarray]:
        if self.dtype is None:
            return {}
        mat = b[data_starts[:, None] + np.arange(self.data_length)]
        rec = mat.view(self.dtype)[:, 0]
        out = {}
        for name, precision in self.kinds.items():
            values = rec[name]
            if name in ("packet_counter", "sample_time_fine"):
                out[name] = values.astype(np.int64)
            elif name == "raw":
                counts = values["v"].astype(np.float64)
                for i, triad in enumerate(_RAW_TRIADS):
                    out[triad] = counts[:, 3 * i:3 * i + 3]
                out["temperature_raw"] = values["temp"].astype(np.float64)
            else:
                out[name] = _to_float(values, precision)
        return out


@dataclass
class _Run:
    """Consecutive samples sharing one signature, waiting to be returned as a chunk."""

    signature: tuple
    parts: list = field(default_factory=list)  # [(t, triads, temperature, extras)]

    def __len__(self) -> int:
        return sum(len(p[0]) for p in self.parts)

    def chunk(self) -> SampleChunk:
        if len(self.parts) == 1:
            t, triads, temperature, extras = self.parts[0]
        else:
            t = np.concatenate([p[0] for p in self.parts])
            triads = {k: np.concatenate([p[1][k] for p in self.parts]) for k in self.parts[0][1]}
            temperature = (None if self.parts[0][2] is None
                           else np.concatenate([p[2] for p in self.parts]))
            extras = {k: np.concatenate([p[3][k] for p in self.parts]) for k in self.parts[0][3]}
        return SampleChunk(t=t, triads=triads, temperature=temperature, extras=extras)


def _make_run(signature: tuple, t: np.ndarray, columns: dict, idx) -> _Run:
    _, triad_names, has_temperature, extra_names = signature
    triads = {name: columns[name][idx] for name in triad_names}
    temperature = columns["temperature"][idx] if has_temperature else None
    extras = {name: columns[name][idx] for name in extra_names}
    return _Run(signature, [(t, triads, temperature, extras)])


def _path_from_first(next_idx: np.ndarray) -> np.ndarray:
    """Nodes visited from node 0 following ``next_idx`` (strictly increasing; m = end), sorted.

    Pointer doubling: after step k the set holds the first 2**k nodes of the path, so the walk
    costs O(m log m) numpy work instead of one Python iteration per frame.
    """
    m = next_idx.size
    if np.array_equal(next_idx, np.arange(1, m + 1)):  # the common case: every candidate chains
        return np.arange(m)
    jump = np.append(next_idx, m)
    visited = np.zeros(1, dtype=np.intp)
    while True:
        frontier = jump[visited]
        frontier = frontier[frontier < m]
        if frontier.size == 0:
            return np.sort(visited)
        visited = np.concatenate([visited, frontier])
        jump = jump[jump]


class XsensMtData2Parser:
    """Stream parser for Xsens MTData2 messages (implements ``StreamParser``).

    ``feed(data, t_host)`` consumes any split of the byte stream and returns the samples of the
    frames completed so far as one chunk, or None. Samples of different channel sets are never
    mixed: if the layout changes, the first layout's samples are returned and the rest wait for
    the next call (``feed(b"", t)`` drains them). Never raises on device bytes.
    """

    MAX_PENDING_RUNS = 4096  # cap on queued chunks when the layout changes faster than feed() runs
    MAX_CACHED_LAYOUTS = 8

    def __init__(self) -> None:
        self.counters = ParserCounters()
        self.overflow_samples = 0  # samples dropped because MAX_PENDING_RUNS was exceeded
        self._buf = b""
        self._layouts: dict[tuple, _Layout] = {}
        self._recent: list[_Layout] = []
        self._pending: list[_Run] = []
        self._stf_prev: int | None = None
        self._stf_wraps = 0
        self._pc_prev: int | None = None

    @property
    def device_time(self) -> bool:
        """The samples' ``t`` is the device's SampleTimeFine (seen in the frames), not host time."""
        return self._stf_prev is not None

    @property
    def buffered(self) -> int:
        """Bytes held back for an unfinished frame (always < MAX_MESSAGE_LENGTH)."""
        return len(self._buf)

    @property
    def pending(self) -> int:
        """Chunks decoded but not yet returned (after a layout change)."""
        return len(self._pending)

    def feed(self, data: bytes, t_host: float) -> SampleChunk | None:
        buf = self._buf + bytes(data)
        for run in self._parse(buf, float(t_host)):
            if self._pending and self._pending[-1].signature == run.signature:
                self._pending[-1].parts.extend(run.parts)
            else:
                self._pending.append(run)
        while len(self._pending) > self.MAX_PENDING_RUNS:
            self.overflow_samples += len(self._pending.pop(0))
        return self._pending.pop(0).chunk() if self._pending else None

    # -- framing ---------------------------------------------------------------------------
    def _parse(self, buf: bytes, t_host: float) -> list[_Run]:
        b = np.frombuffer(buf, dtype=np.uint8)
        n = b.size
        fa = np.flatnonzero(b == PREAMBLE)
        keep = np.ones(fa.size, dtype=bool)
        inner = fa < n - 1
        keep[inner] = b[fa[inner] + 1] == BID_MASTER  # a preamble as last byte may yet be a frame
        c = fa[keep].astype(np.int64)
        m = c.size
        if m == 0:
            self.counters.discarded_bytes += n
            self._buf = b""
            return []

        header_ok = c + 3 < n
        length = np.zeros(m, dtype=np.int64)
        length[header_ok] = b[c[header_ok] + 3]
        extended = header_ok & (length == EXTENDED_LENGTH_CODE)
        ext_ok = extended & (c + 5 < n)
        ce = c[ext_ok]
        length[ext_ok] = (b[ce + 4].astype(np.int64) << 8) | b[ce + 5]
        header = np.where(extended, 6, 4)
        end = c + header + length + 1
        absurd = ext_ok & (length > MAX_DATA_LENGTH)
        incomplete = ~header_ok | (extended & ~ext_ok) | (~absurd & (end > n))
        complete = ~incomplete & ~absurd

        csum = np.zeros(n + 1, dtype=np.uint8)
        np.cumsum(b, dtype=np.uint8, out=csum[1:])  # wraps mod 256, as the checksum does
        good = np.zeros(m, dtype=bool)
        ci = np.flatnonzero(complete)
        good[ci] = (csum[end[ci]] - csum[c[ci] + 1]) == 0

        next_pos = np.where(good, end, c + 1)  # resync one byte after a rejected preamble
        next_idx = np.searchsorted(c, next_pos, side="left")
        next_idx[incomplete] = m
        path = _path_from_first(next_idx)

        last = path[-1]
        if incomplete[last]:
            consumed = int(c[last])
            path = path[:-1]
        else:
            consumed = n
        self._buf = buf[consumed:]

        self.counters.checksum_failures += int(np.count_nonzero(complete[path] & ~good[path]))
        frames = path[good[path] & (b[c[path] + 2] == MID_MTDATA2)]
        starts = c[frames]
        data_starts = starts + header[frames]
        data_lengths = length[frames]
        runs, accepted_bytes = self._decode(buf, b, data_starts, data_lengths, end[frames] - starts,
                                            t_host)
        self.counters.discarded_bytes += consumed - accepted_bytes
        return runs

    # -- decoding --------------------------------------------------------------------------
    def _layout_for(self, data_length: int, items) -> _Layout:
        key = (data_length, tuple(items))
        layout = self._layouts.get(key)
        if layout is None:
            if len(self._layouts) > 64:
                self._layouts.clear()
            layout = self._layouts[key] = _Layout(data_length, items)
        return layout

    def _assign_layouts(self, buf, b, data_starts, data_lengths):
        k = data_starts.size
        layout_id = np.full(k, -1, dtype=np.intp)
        used: list[_Layout] = []
        remaining = np.arange(k)

        def claim(layout: _Layout) -> np.ndarray:
            sel = remaining[data_lengths[remaining] == layout.data_length]
            if sel.size and layout.header_cols.size:
                heads = b[data_starts[sel, None] + layout.header_cols]
                sel = sel[(heads == layout.header_vals).all(axis=1)]
            if sel.size:
                layout_id[sel] = len(used)
                used.append(layout)
            return remaining[layout_id[remaining] < 0]

        for layout in self._recent:
            if remaining.size == 0:
                break
            remaining = claim(layout)
        while remaining.size:  # a layout not seen recently: walk one frame, claim all its kind
            f = remaining[0]
            items = _walk_items(buf, int(data_starts[f]), int(data_lengths[f]))
            if items is None:  # checksum-valid but malformed item list: not accepted
                layout_id[f] = -2
                remaining = remaining[1:]
                continue
            remaining = claim(self._layout_for(int(data_lengths[f]), items))
        self._recent = (used + [x for x in self._recent if x not in used])[:self.MAX_CACHED_LAYOUTS]
        return layout_id, used

    def _decode(self, buf, b, data_starts, data_lengths, totals, t_host):
        layout_id, used = self._assign_layouts(buf, b, data_starts, data_lengths)
        accepted = layout_id >= 0
        n_accepted = int(np.count_nonzero(accepted))
        self.counters.frames += n_accepted
        accepted_bytes = int(totals[accepted].sum())
        if not used:
            return [], accepted_bytes
        k = data_starts.size

        if len(used) == 1 and n_accepted == k:  # the common case: one layout, nothing malformed
            layout = used[0]
            columns = layout.decode(b, data_starts)
            stf = columns.pop("sample_time_fine", None)
            if "packet_counter" in columns:
                self._count_sequence(columns["packet_counter"])
                columns["packet_counter"] = columns["packet_counter"].astype(np.float64)
            t = np.full(k, t_host) if stf is None else self._unwrap_time(stf)
            if not layout.has_data:
                return [], accepted_bytes
            return [_make_run(layout.signature, t, columns, slice(None))], accepted_bytes

        stf = np.full(k, -1, dtype=np.int64)
        pc = np.full(k, -1, dtype=np.int64)
        columns: dict[str, np.ndarray] = {}
        has_data = np.zeros(k, dtype=bool)
        signature_id = np.full(k, -1, dtype=np.intp)
        signatures: list[tuple] = []
        for j, layout in enumerate(used):
            sel = np.flatnonzero(layout_id == j)
            decoded = layout.decode(b, data_starts[sel])
            if "sample_time_fine" in decoded:
                stf[sel] = decoded.pop("sample_time_fine")
            if "packet_counter" in decoded:
                pc[sel] = decoded["packet_counter"]
                decoded["packet_counter"] = decoded["packet_counter"].astype(np.float64)
            for name, values in decoded.items():
                if name not in columns:
                    columns[name] = np.empty((k,) + values.shape[1:], dtype=np.float64)
                columns[name][sel] = values
            if layout.has_data:
                has_data[sel] = True
                if layout.signature not in signatures:
                    signatures.append(layout.signature)
                signature_id[sel] = signatures.index(layout.signature)

        self._count_sequence(pc[pc >= 0])
        t = np.full(k, t_host, dtype=np.float64)
        timed = np.flatnonzero(stf >= 0)
        if timed.size:
            t[timed] = self._unwrap_time(stf[timed])

        yielding = np.flatnonzero(has_data)
        if yielding.size == 0:
            return [], accepted_bytes
        sig = signature_id[yielding]
        bounds = np.concatenate([[0], np.flatnonzero(np.diff(sig)) + 1, [yielding.size]])
        runs = []
        for a, z in zip(bounds[:-1], bounds[1:]):  # one iteration per layout change
            idx = yielding[a:z]
            runs.append(_make_run(signatures[sig[a]], t[idx], columns, idx))
        return runs, accepted_bytes

    def _count_sequence(self, counters: np.ndarray) -> None:
        """Gaps in the uint16 packet counter. A forward jump of d (2 <= d <= 32768, modulo 65536)
        is one gap and d - 1 missing frames; a repeat or a backward jump (device reset) is a gap
        whose size the counter cannot tell, so it adds no missing frames."""
        if counters.size == 0:
            return
        seq = counters if self._pc_prev is None else np.concatenate([[self._pc_prev], counters])
        step = (seq[1:] - seq[:-1]) % 65536
        jumps = step[step != 1]
        self.counters.sequence_gaps += int(jumps.size)
        forward = jumps[(jumps >= 2) & (jumps <= 32768)]
        self.counters.missing_frames += int((forward - 1).sum())
        self._pc_prev = int(counters[-1])

    def _unwrap_time(self, ticks: np.ndarray) -> np.ndarray:
        """SampleTimeFine ticks -> seconds, continuing across the 2**32 wrap and across calls."""
        prev = ticks[0] if self._stf_prev is None else self._stf_prev
        steps = ticks - np.concatenate([[prev], ticks[:-1]])
        wraps = self._stf_wraps + np.cumsum(steps < -(1 << 31))
        self._stf_prev = int(ticks[-1])
        self._stf_wraps = int(wraps[-1])
        return (ticks + wraps * float(1 << 32)) / SAMPLE_TIME_FINE_HZ


# -- encoder -------------------------------------------------------------------------------
ENCODER_ITEMS = ("packet_counter", "sample_time_fine", "acceleration", "rate_of_turn",
                 "magnetic_field", "temperature", "raw_acc_gyr_mag_temp")
_ENCODER_VECTORS = {"acceleration": (XDI_ACCELERATION, "accelerometer"),
                    "rate_of_turn": (XDI_RATE_OF_TURN, "gyroscope"),
                    "magnetic_field": (XDI_MAGNETIC_FIELD, "magnetometer")}


def _encode_real(target: np.ndarray, values: np.ndarray, precision: int, what: str) -> None:
    values = np.asarray(values, dtype=np.float64)
    if precision in (0, 3):
        target[...] = values
        return
    if not np.all(np.isfinite(values)):
        raise ValueError(f"{what}: fixed-point output needs finite values")
    scaled = np.rint(values * (2.0**20 if precision == 1 else 2.0**32))
    limit = 2.0**31 if precision == 1 else 2.0**47
    if np.any(scaled < -limit) or np.any(scaled > limit - 1):
        raise ValueError(f"{what}: value out of the fixed-point range")
    ints = scaled.astype(np.int64)
    if precision == 1:
        target[...] = ints
    else:
        target["frac"] = ints & 0xFFFFFFFF
        target["int"] = ints >> 32


class XsensMtData2Encoder:
    """Bytes an MT would send for a chunk: one MTData2 message per sample (``StreamEncoder``).

    ``items`` name the MTData2 items in message order (see ``ENCODER_ITEMS``); ``raw=True``
    appends RawAccGyrMagTemp built from the ``*_raw`` triads (``magnetometer_raw`` and the
    ``temperature_raw`` extra default to 0). The packet counter comes from
    ``chunk.extras["packet_counter"]`` if present, else from a running counter; SampleTimeFine is
    ``round(t * 1e4) mod 2**32``. ``precision`` is the real-number format of the vector and
    temperature items: float32, fp1220, fp1632 or float64.
    """

    def __init__(self, items=("packet_counter", "sample_time_fine", "acceleration",
                              "rate_of_turn", "temperature"), raw: bool = False,
                 precision: str = "float32") -> None:
        items = tuple(items)
        if raw and "raw_acc_gyr_mag_temp" not in items:
            items += ("raw_acc_gyr_mag_temp",)
        unknown = [i for i in items if i not in ENCODER_ITEMS]
        if unknown or len(set(items)) != len(items):
            raise ValueError(f"items must be distinct names from {ENCODER_ITEMS}, got {items}")
        if precision not in PRECISIONS:
            raise ValueError(f"precision must be one of {tuple(PRECISIONS)}, got {precision!r}")
        self.items = items
        self.precision = PRECISIONS[precision]
        self._counter = 0
        real = _PRECISION_DTYPE[self.precision]
        fields, self._xdi, data_length = [], [], 0
        for i, item in enumerate(items):
            if item == "packet_counter":
                xdi, fmt = XDI_PACKET_COUNTER, np.dtype(">u2")
            elif item == "sample_time_fine":
                xdi, fmt = XDI_SAMPLE_TIME_FINE, np.dtype(">u4")
            elif item == "temperature":
                xdi, fmt = XDI_TEMPERATURE | self.precision, real
            elif item == "raw_acc_gyr_mag_temp":
                xdi, fmt = XDI_RAW_ACC_GYR_MAG_TEMP, _RAW_DTYPE_U
            else:
                xdi, fmt = _ENCODER_VECTORS[item][0] | self.precision, np.dtype((real, (3,)))
            fields += [(f"x{i}", ">u2"), (f"s{i}", "u1"), (f"p{i}", fmt)]
            self._xdi.append((xdi, fmt.itemsize))
            data_length += 3 + fmt.itemsize
        self._extended = data_length > MAX_SHORT_DATA_LENGTH
        head = [("pre", "u1"), ("bid", "u1"), ("mid", "u1"), ("len", "u1")]
        if self._extended:
            head.append(("xlen", ">u2"))
        self._dtype = np.dtype(head + fields + [("cs", "u1")])
        self.data_length = data_length

    def encode(self, chunk: SampleChunk) -> bytes:
        n = len(chunk)
        if n == 0:
            return b""
        msg = np.zeros(n, dtype=self._dtype)
        msg["pre"], msg["bid"], msg["mid"] = PREAMBLE, BID_MASTER, MID_MTDATA2
        if self._extended:
            msg["len"], msg["xlen"] = EXTENDED_LENGTH_CODE, self.data_length
        else:
            msg["len"] = self.data_length
        for i, (item, (xdi, size)) in enumerate(zip(self.items, self._xdi)):
            msg[f"x{i}"], msg[f"s{i}"] = xdi, size
            target = msg[f"p{i}"]
            if item == "packet_counter":
                target[...] = self._packet_counters(chunk)
            elif item == "sample_time_fine":
                t = np.asarray(chunk.t, dtype=np.float64)
                if not np.all(np.isfinite(t)):
                    raise ValueError("sample_time_fine: t must be finite")
                target[...] = np.rint(t * SAMPLE_TIME_FINE_HZ).astype(np.int64) % (1 << 32)
            elif item == "temperature":
                if chunk.temperature is None:
                    raise ValueError("temperature item requested but the chunk has no temperature")
                _encode_real(target, chunk.temperature, self.precision, "temperature")
            elif item == "raw_acc_gyr_mag_temp":
                target["v"] = self._raw_counts(chunk, n)
                temp = np.rint(np.asarray(chunk.extras.get("temperature_raw", np.zeros(n))))
                if np.any(temp < -32768) or np.any(temp > 32767):
                    raise ValueError("temperature_raw out of int16 range")
                target["temp"] = temp.astype(np.int64)
            else:
                triad = _ENCODER_VECTORS[item][1]
                if triad not in chunk.triads:
                    raise ValueError(f"{item} item requested but the chunk has no {triad!r} triad")
                _encode_real(target, chunk.triads[triad], self.precision, triad)
        raw = msg.view(np.uint8).reshape(n, self._dtype.itemsize)
        total = raw[:, 1:-1].sum(axis=1, dtype=np.int64)
        raw[:, -1] = (-total) % 256
        return raw.tobytes()

    def _packet_counters(self, chunk: SampleChunk) -> np.ndarray:
        n = len(chunk)
        if "packet_counter" in chunk.extras:
            pc = np.rint(np.asarray(chunk.extras["packet_counter"], dtype=np.float64))
            pc = pc.astype(np.int64) % 65536
        else:
            pc = (self._counter + np.arange(n, dtype=np.int64)) % 65536
        self._counter = int(pc[-1] + 1) % 65536
        return pc

    @staticmethod
    def _raw_counts(chunk: SampleChunk, n: int) -> np.ndarray:
        parts = []
        for name in _RAW_TRIADS:
            if name in chunk.triads:
                parts.append(np.asarray(chunk.triads[name], dtype=np.float64))
            elif name == "magnetometer_raw":
                parts.append(np.zeros((n, 3)))
            else:
                raise ValueError(f"raw item requested but the chunk has no {name!r} triad")
        counts = np.rint(np.concatenate(parts, axis=1))
        if np.any(~np.isfinite(counts)) or np.any(counts < 0) or np.any(counts > 65535):
            raise ValueError("raw counts must be integers in 0..65535")
        return counts.astype(np.int64)
