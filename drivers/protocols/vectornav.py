"""VectorNav ASCII asynchronous output: ``$VNIMU`` and ``$VNYMR`` sentences.

Sources (checked, not guessed):

* VN-100 User Manual UM001, firmware v2.1.0.0, document revision 2.22 (VectorNav), seen at
  https://manualshive.com/en/manual/vectornav/vn-100/3752294 :

  - §3.8 "Checksum / CRC" (p. 29-30): the serial interface uses either an 8-bit checksum or a
    16-bit CRC, or neither ("both can be turned off by the user").  §3.8.2: the 8-bit checksum is
    the XOR of all bytes between, not including, ``$`` and ``*`` (commas included), written as two
    hexadecimal characters.  §3.8.3: the 16-bit CRC is CRC16-CCITT, written as four hexadecimal
    characters; the manual's C snippet (implemented verbatim in :func:`crc16_vn`) is the
    polynomial 0x1021, initial value 0 form (CRC-16/XMODEM).  §3.8.1: ``XX`` in place of the
    hex digits bypasses the check (documented for commands sent *to* the sensor; the VectorNav
    C++ library's ``Packet::isValid`` also accepts ``XX`` on received packets, so we do too,
    counting them in :attr:`VectorNavParser.unchecked_frames`).
  - §6.1.1 "IMU Measurements" (register 54, async header IMU, p. 79): MagX, MagY, MagZ [Gauss],
    AccelX..Z [m/s^2], GyroX..Z [rad/s], Temp [C], Pressure [kPa], in that order.  The table
    calls all three triads *uncompensated* (the register's one-line comment says "calibrated";
    the field table is the specific statement).
  - §7.2.3 "Yaw, Pitch, Roll, Magnetic, Acceleration, and Angular Rates" (register 27, async
    header YMR, p. 94): Yaw, Pitch, Roll [deg], MagX..Z [Gauss], AccelX..Z [m/s^2],
    GyroX..Z [rad/s], all *compensated*; example ``$VNRRG,27,+006.380,+000.023,-001.953,
    +1.0640,-0.2531,+3.0614,+00.005,+00.344,-09.758,-0.001222,-0.000450,-0.001218*4F``
    (its checksum verifies).
  - Lines end in ``\\r\\n`` (VN-200 manual UM004 §3.1, and VN-100 §4 example "End Line \\r\\n").

* Number formats.  The manual gives no printf formats, only examples.  Async sentences from
  devices and from VectorNav's own library use a sign, zero padding and fixed decimals:
  ``$VNYMR,+100.949,-007.330,+000.715,-00.0049,-00.2449,+00.5397,-01.258,-00.100,-09.701,
  -00.000018,+00.001122,-00.000551*69`` (VectorNav C++ library, UART protocol example) and
  ``$VNIMU,-00.0350,+00.4222,-00.6643,-00.015,+00.019,+09.948,+00.002066,-00.008442,-00.044656,
  +20.7,+084.322*66`` (a VN-200 capture quoted in S. Bruder's MATLAB reader).  The VN-100
  register-54 example shows the same widths for mag/accel/gyro and pressure as
  ``+00099.761``.  Hence the encoder writes angles ``%+08.3f``, magnetic ``%+08.4f``,
  acceleration ``%+07.3f``, angular rate ``%+010.6f``, temperature ``%+05.1f`` and pressure
  ``%+010.3f`` (the VN-100 form; the VN-200 capture has ``%+08.3f``).  The parser accepts any
  plain decimal number in every field.

Note the resolution that implies: 1e-3 m/s^2 (about 0.1 mg) and 1e-6 rad/s (about 0.2 deg/h)
per count, the same order as the paper's bias-instability figures; averaging noisy samples
dithers it away, but binary output is the better choice for a quiet unit.

No device time exists in these sentences: every sample completed in one ``feed`` call gets that
call's ``t_host``.  One parser yields one sentence type (a chunk never mixes them): pass
``sentence="VNIMU"`` or ``"VNYMR"``, or leave ``None`` and the parser locks onto the type of the
first one of them with a right checksum and the right number of fields; sentences of the other type are then skipped like any other
``$VN...`` sentence (their bytes count as discarded and their header in :attr:`skipped`).
"""
from __future__ import annotations

import itertools
import re
from collections import Counter
from typing import ClassVar

import numpy as np

from drivers.chunk import SampleChunk
from drivers.protocols.base import ParserCounters

# name -> (number of fields, printf formats of the encoder)
SENTENCES: dict[str, tuple[int, tuple[str, ...]]] = {
    "VNIMU": (11, ("%+08.4f",) * 3 + ("%+07.3f",) * 3 + ("%+010.6f",) * 3 + ("%+05.1f", "%+010.3f")),
    "VNYMR": (12, ("%+08.3f",) * 3 + ("%+08.4f",) * 3 + ("%+07.3f",) * 3 + ("%+010.6f",) * 3),
}
TRIADS = ("magnetometer", "accelerometer", "gyroscope")
NFIELDS = (SENTENCES["VNIMU"][0], SENTENCES["VNYMR"][0])  # by type code 1, 2
_TYPE_CODE = {"VNIMU": 1, "VNYMR": 2}
_CODE_TYPE = {1: "VNIMU", 2: "VNYMR"}

_DOLLAR, _STAR, _COMMA, _CR, _LF, _X = 36, 42, 44, 13, 10, 88

_HEX = np.full(256, -1, dtype=np.int32)
for _i, _c in enumerate(b"0123456789ABCDEF"):
    _HEX[_c] = _i
for _i, _c in enumerate(b"abcdef"):
    _HEX[_c] = 10 + _i

# bytes a numeric payload may hold (after the header comma, with "*" turned into ",")
_NUMERIC = np.zeros(256, dtype=bool)
_NUMERIC[np.frombuffer(b"0123456789+-.eE,", dtype=np.uint8)] = True
_NUMERIC_BYTES = b"0123456789+-.eE,"


def crc16_vn(body: bytes) -> int:
    """The manual's 16-bit CRC (UM001 §3.8.3 C snippet, transcribed)."""
    crc = 0
    for b in body:
        crc = ((crc >> 8) | (crc << 8)) & 0xFFFF
        crc ^= b
        crc ^= (crc & 0xFF) >> 4
        crc ^= (crc << 12) & 0xFFFF
        crc ^= ((crc & 0x00FF) << 5) & 0xFFFF
    return crc


_CRC_TABLE = np.zeros((0, 256), dtype=np.uint16)


def _crc_table(length: int) -> np.ndarray:
    """T[d, b] = CRC of byte b followed by d zero bytes, for d < length (grown on demand).

    This CRC starts from 0 and has no final XOR, so it is linear: the CRC of a message is the
    XOR of T[bytes after it, byte] over its bytes.  That turns the byte-serial CRC into one
    gather and one XOR-reduce per block of sentences.
    """
    global _CRC_TABLE
    if len(_CRC_TABLE) < length:
        table = np.zeros((length, 256), dtype=np.int64)
        crc = np.array([crc16_vn(bytes([b])) for b in range(256)], dtype=np.int64)
        for d in range(length):
            table[d] = crc
            c = ((crc >> 8) | (crc << 8)) & 0xFFFF  # one more zero byte
            c ^= (c & 0xFF) >> 4
            c ^= (c << 12) & 0xFFFF
            c ^= ((c & 0xFF) << 5) & 0xFFFF
            crc = c
        _CRC_TABLE = table.astype(np.uint16)
    return _CRC_TABLE


def _crc16_many(a: np.ndarray, starts: np.ndarray, stops: np.ndarray) -> np.ndarray:
    """CRC of a[starts[i]:stops[i]] (non-empty, disjoint, in order) for every i."""
    if len(starts) == 0:
        return np.zeros(0, dtype=np.int64)
    lengths = stops - starts
    table = _crc_table(int(lengths.max()))
    total = int(lengths.sum())
    first = np.cumsum(lengths) - lengths  # where each message begins in the concatenation
    pos = np.repeat(starts - first, lengths) + np.arange(total)  # byte positions in a
    dist = np.repeat(stops - 1, lengths) - pos  # bytes after each byte, within its message
    terms = table[dist, a[pos]]
    return np.bitwise_xor.reduceat(terms, first).astype(np.int64)


def _parse_numbers(payload: bytes, count: int) -> np.ndarray | None:
    """``count`` comma-terminated decimal numbers, or None if the text is anything else."""
    if payload.translate(None, _NUMERIC_BYTES):
        return None
    try:
        values = np.fromstring(payload, dtype=np.float64, sep=",")
    except ValueError:
        return None
    if values.size != count:
        return None
    return values


class VectorNavParser:
    """Stream parser for ``$VNIMU`` / ``$VNYMR`` (see the module notes); a StreamParser.

    ``counters`` follow :class:`ParserCounters`; besides them: ``unchecked_frames`` (accepted
    with ``*XX``), ``malformed_sentences`` (right checksum, wrong fields) and ``skipped``
    (sentence type such as ``"VNERR"`` -> count of sentences with a right checksum but another
    type; ``"other"`` for lines that are not ``$VNxxx`` at all).
    """

    def __init__(self, sentence: str | None = None, *, accept_unchecked: bool = True,
                 max_sentence_bytes: int = 512) -> None:
        if sentence is not None and sentence not in SENTENCES:
            raise ValueError(f"sentence: expected one of {', '.join(SENTENCES)}, got {sentence!r}")
        self.sentence = sentence
        self.accept_unchecked = accept_unchecked
        self.max_sentence_bytes = int(max_sentence_bytes)
        self.counters = ParserCounters()
        self.unchecked_frames = 0
        self.malformed_sentences = 0
        self.skipped: Counter[str] = Counter()
        self._buf = b""
        self._pending_lf = False  # an accepted sentence ended in "\r" at the end of the last feed

    device_time = False  # ASCII sentences carry no device time: ``t`` is the host's

    # -- the one public operation -----------------------------------------------------------
    def feed(self, data: bytes, t_host: float) -> SampleChunk | None:
        data = bytes(data)
        if self._pending_lf and data:
            self._pending_lf = False
            if data[:1] == b"\n":
                data = data[1:]  # the accepted frame's own line feed
        if not data:
            return None
        if b"$" not in data and b"\r" not in data and b"\n" not in data:
            # nothing can end or start here (small reads arrive this way): no numpy needed
            if not self._buf:
                self.counters.discarded_bytes += len(data)
                return None
            if len(self._buf) + len(data) <= self.max_sentence_bytes:
                self._buf += data
                return None
        buf = self._buf + data
        self._buf = b""
        a = np.frombuffer(buf, dtype=np.uint8)
        n = len(a)

        dollars = np.flatnonzero(a == _DOLLAR)
        if len(dollars) == 0:
            self.counters.discarded_bytes += n
            return None
        terms = np.flatnonzero((a == _CR) | (a == _LF))
        ti = np.searchsorted(terms, dollars)
        has_term = ti < len(terms)
        ends = terms[np.minimum(ti, max(len(terms) - 1, 0))] if len(terms) else np.full(len(dollars), n)
        ends = np.where(has_term, ends, n)
        next_dollar = np.append(dollars[1:], n)
        complete = has_term & (ends < next_dollar)

        # An unterminated last "$...": keep it for the next feed, unless it is already too long.
        consumed = n
        if not complete[-1] and next_dollar[-1] == n:
            tail = int(dollars[-1])
            if n - tail <= self.max_sentence_bytes:
                self._buf = buf[tail:]
                consumed = tail

        s = dollars[complete]
        e = ends[complete]
        chunk, frame_bytes, last_end = self._sentences(a, s, e, t_host)
        self.counters.discarded_bytes += consumed - frame_bytes
        if last_end == n - 1 and a[n - 1] == _CR:
            self._pending_lf = True
        return chunk

    # -- the vectorised core ---------------------------------------------------------------------
    def _sentences(self, a: np.ndarray, s: np.ndarray, e: np.ndarray, t_host: float):
        """Validate and decode the terminated lines a[s:e]; (chunk, accepted bytes, last end)."""
        n = len(a)
        if len(s) == 0:
            return None, 0, -1
        stars = np.flatnonzero(a == _STAR)
        si = np.searchsorted(stars, e) - 1
        star = stars[np.maximum(si, 0)] if len(stars) else np.zeros(len(s), dtype=np.int64)
        has_star = (si >= 0) & (star > s) if len(stars) else np.zeros(len(s), dtype=bool)
        star = np.where(has_star, star, s)
        cs_len = np.where(has_star & (e - s <= self.max_sentence_bytes), e - star - 1, 0)

        ap = np.concatenate([a, np.zeros(8, dtype=np.uint8)])  # reads past the end see zeros
        cs_bytes = ap[star[:, None] + np.arange(1, 5)]
        hv = _HEX[cs_bytes]
        h = [hv[:, k].astype(np.int64) for k in range(4)]
        x = [cs_bytes[:, k] == _X for k in range(4)]
        two = cs_len == 2
        four = cs_len == 4
        hex2 = two & (h[0] >= 0) & (h[1] >= 0)
        hex4 = four & (h[0] >= 0) & (h[1] >= 0) & (h[2] >= 0) & (h[3] >= 0)
        unchecked = (two & x[0] & x[1]) | (four & x[0] & x[1] & x[2] & x[3])

        prefix = np.zeros(n + 1, dtype=np.uint8)
        np.bitwise_xor.accumulate(a, out=prefix[1:])
        xor8 = (prefix[star] ^ prefix[np.minimum(s + 1, n)]).astype(np.int64)
        good = hex2 & (xor8 == (h[0] * 16 + h[1]))
        if hex4.any():
            idx = np.flatnonzero(hex4)
            crc = _crc16_many(a, s[idx] + 1, star[idx])
            want = ((h[0] * 16 + h[1]) * 16 + h[2]) * 16 + h[3]
            good[idx] = crc == want[idx]
        self.counters.checksum_failures += int(((hex2 | hex4) & ~good).sum())
        if self.accept_unchecked:
            good |= unchecked

        # header: "$VNIMU," or "$VNYMR,"
        head = ap[s[:, None] + np.arange(1, 7)]
        long_enough = star >= s + 7
        code = np.zeros(len(s), dtype=np.int64)
        for name, c in _TYPE_CODE.items():
            pattern = np.frombuffer(name.encode() + b",", dtype=np.uint8)
            code[long_enough & (head == pattern).all(axis=1)] = c
        commas = np.zeros(n + 1, dtype=np.int64)
        np.cumsum(a == _COMMA, out=commas[1:])
        field_commas = commas[star] - commas[np.minimum(s + 1, n)]  # header comma included

        ours = good & (code > 0) & (field_commas == np.array([0, *NFIELDS])[code])
        if self.sentence is None and ours.any():
            self.sentence = _CODE_TYPE[int(code[np.argmax(ours)])]
        want_code = _TYPE_CODE.get(self.sentence or "", -1)
        others = good & (code != want_code)
        if others.any():
            names = np.ascontiguousarray(head[others][:, :5]).view("S5").ravel()
            for name, count in zip(*np.unique(names, return_counts=True)):
                # "$VN" + three capitals is a sentence type; anything else is lumped together
                key = name.decode("ascii") if re.fullmatch(rb"VN[A-Z]{3}", name) else "other"
                self.skipped[key] += int(count)
        nf = SENTENCES[self.sentence][0] if self.sentence else 0
        cand = good & (code == want_code)
        shaped = cand & (field_commas == nf)
        self.malformed_sentences += int((cand & ~shaped).sum())

        keep = np.flatnonzero(shaped)
        values, ok = self._values(a, s[keep] + 7, star[keep], nf)
        self.malformed_sentences += int((~ok).sum())
        keep = keep[ok]
        if len(keep) == 0:
            return None, 0, -1
        self.unchecked_frames += int(unchecked[keep].sum())
        self.counters.frames += len(keep)
        ks, ke = s[keep], e[keep]
        crlf = (a[ke] == _CR) & (a[np.minimum(ke + 1, n - 1)] == _LF) & (ke + 1 < n)
        frame_bytes = int((ke + 1 + crlf - ks).sum())
        last_end = int(ke[-1] + crlf[-1])
        return self._chunk(values, t_host), frame_bytes, last_end

    def _values(self, a: np.ndarray, p0: np.ndarray, p1: np.ndarray, nf: int):
        """Numbers of payloads a[p0:p1] (nf each): (values (k, nf), ok mask over the inputs)."""
        m = len(p0)
        if m == 0:
            return np.zeros((0, nf)), np.zeros(0, dtype=bool)
        # One pass: select every payload plus its "*" (as a ",") and parse all numbers at once.
        mark = np.zeros(len(a) + 1, dtype=np.int8)
        mark[p0] = 1
        mark[p1 + 1] -= 1
        inside = np.cumsum(mark[:-1]) > 0
        b = a.copy()
        b[p1] = _COMMA
        text = b[inside]
        if _NUMERIC[text].all():
            try:
                flat = np.fromstring(text.tobytes(), dtype=np.float64, sep=",")
            except ValueError:
                flat = None
            if flat is not None and flat.size == m * nf:
                values = flat.reshape(m, nf)
                ok = np.isfinite(values).all(axis=1)
                return values[ok], ok
        # Slow path for a block holding a malformed field: sentence by sentence, same rules.
        raw = a.tobytes()
        rows, ok = [], np.zeros(m, dtype=bool)
        for i, (i0, i1) in enumerate(zip(p0.tolist(), p1.tolist())):
            v = _parse_numbers(raw[i0:i1] + b",", nf)
            if v is not None and np.isfinite(v).all():
                rows.append(v)
                ok[i] = True
        return (np.array(rows) if rows else np.zeros((0, nf))), ok

    def _chunk(self, v: np.ndarray, t_host: float) -> SampleChunk:
        k = len(v)
        t = np.full(k, float(t_host))
        if self.sentence == "VNIMU":
            triads = {"magnetometer": v[:, 0:3].copy(), "accelerometer": v[:, 3:6].copy(),
                      "gyroscope": v[:, 6:9].copy()}
            return SampleChunk(t=t, triads=triads, temperature=v[:, 9].copy(),
                               extras={"pressure": v[:, 10].copy()})
        triads = {"magnetometer": v[:, 3:6].copy(), "accelerometer": v[:, 6:9].copy(),
                  "gyroscope": v[:, 9:12].copy()}
        return SampleChunk(t=t, triads=triads, extras={"yaw": v[:, 0].copy(), "pitch": v[:, 1].copy(),
                                                       "roll": v[:, 2].copy()})


class VectorNavEncoder:
    """Sentences a VN-100 would send for a chunk (for the simulated device); a StreamEncoder.

    ``checksum`` is ``"xor8"`` (the factory setting), ``"crc16"`` or ``"off"`` (``*XX``).
    Channels missing from the chunk take ``defaults`` (magnetometer zero, 25 C, 101.325 kPa,
    zero attitude); accelerometer and gyroscope are required.
    """

    DEFAULTS: ClassVar[dict[str, float]] = {"temperature": 25.0, "pressure": 101.325, "yaw": 0.0, "pitch": 0.0, "roll": 0.0}

    def __init__(self, sentence: str = "VNIMU", checksum: str = "xor8",
                 defaults: dict[str, float] | None = None) -> None:
        if sentence not in SENTENCES:
            raise ValueError(f"sentence: expected one of {', '.join(SENTENCES)}, got {sentence!r}")
        if checksum not in ("xor8", "crc16", "off"):
            raise ValueError(f"checksum: expected 'xor8', 'crc16' or 'off', got {checksum!r}")
        self.sentence = sentence
        self.checksum = checksum
        self.defaults = {**self.DEFAULTS, **(defaults or {})}

    def _columns(self, chunk: SampleChunk) -> np.ndarray:
        n = len(chunk)

        def scalar(name: str, values) -> np.ndarray:
            return np.full(n, self.defaults[name]) if values is None else np.asarray(values, float)

        mag = chunk.triads.get("magnetometer")
        mag = np.zeros((n, 3)) if mag is None else np.asarray(mag, float)
        acc = np.asarray(chunk.triads["accelerometer"], float)
        gyr = np.asarray(chunk.triads["gyroscope"], float)
        if self.sentence == "VNIMU":
            cols = [mag, acc, gyr, scalar("temperature", chunk.temperature)[:, None],
                    scalar("pressure", chunk.extras.get("pressure"))[:, None]]
        else:
            ypr = np.stack([scalar(k, chunk.extras.get(k)) for k in ("yaw", "pitch", "roll")], axis=1)
            cols = [ypr, mag, acc, gyr]
        return np.hstack(cols)

    def encode(self, chunk: SampleChunk) -> bytes:
        n = len(chunk)
        if n == 0:
            return b""
        values = self._columns(chunk)
        fmts = SENTENCES[self.sentence][1]
        # One format pass for all bodies, "\n"-separated so checksums can be taken per line.
        line = self.sentence + "," + ",".join(fmts) + "\n"
        text = ((line * n) % tuple(values.ravel().tolist())).encode("ascii")
        a = np.frombuffer(text, dtype=np.uint8)
        nl = np.flatnonzero(a == _LF)
        starts = np.concatenate([[0], nl[:-1] + 1])
        bodies = text.split(b"\n")[:-1]
        if self.checksum == "xor8":
            prefix = np.zeros(len(a) + 1, dtype=np.uint8)
            np.bitwise_xor.accumulate(a, out=prefix[1:])
            sums = (prefix[nl] ^ prefix[starts]).tolist()
            fmt = b"$%s*%02X\r\n"
        elif self.checksum == "crc16":
            sums = _crc16_many(a, starts, nl).tolist()
            fmt = b"$%s*%04X\r\n"
        else:
            return (b"$%s*XX\r\n" * n) % tuple(bodies)
        return (fmt * n) % tuple(itertools.chain.from_iterable(zip(bodies, sums)))
