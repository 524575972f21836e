"""Xsens MTData2 parser and encoder, tested against the public wire format, not against itself.

Truth used here: messages packed by hand with ``struct`` from the public layout; real MTi
messages (with their checksums) and their decoded values from einride/xsens-go
``testdata/1/messages.golden`` and ``testdata/1/output.golden``; the Error and GoToConfig messages
of xsens-go ``message_test.go``; the FP16.32 vector of xsens-go ``mtdata2_test.go``; and a
deliberately plain, byte-at-a-time reference reader (``reference``) of the framing rules, written
here without numpy or the module under test.
"""
from __future__ import annotations

import math
import struct
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.chunk import SampleChunk
from drivers.protocols.xsens import MAX_MESSAGE_LENGTH, XsensMtData2Encoder, XsensMtData2Parser

# ---------------------------------------------------------------------------------------------
# Hand-packing from the public layout (independent of the module under test)


def item(xdi: int, payload: bytes) -> bytes:
    return struct.pack(">HB", xdi, len(payload)) + payload


def message(data: bytes, mid: int = 0x36) -> bytes:
    """FA | BID FF | MID | LEN (or FF + 2-byte big-endian length) | data | checksum."""
    if len(data) <= 254:
        head = bytes([0xFF, mid, len(data)])
    else:
        head = bytes([0xFF, mid, 0xFF]) + struct.pack(">H", len(data))
    body = head + data
    return b"\xfa" + body + bytes([(-sum(body)) % 256])


def basic_frame(pc: int, stf: int | None = None, acc=(0.0, 0.0, 9.8), gyr=(0.0, 0.0, 0.0),
                mag=None, temp=None) -> bytes:
    data = item(0x1020, struct.pack(">H", pc % 65536))
    if stf is not None:
        data += item(0x1060, struct.pack(">I", stf % 2**32))
    data += item(0x4020, struct.pack(">3f", *acc)) + item(0x8020, struct.pack(">3f", *gyr))
    if mag is not None:
        data += item(0xC020, struct.pack(">3f", *mag))
    if temp is not None:
        data += item(0x0810, struct.pack(">f", temp))
    return message(data)


def f32(x: float) -> float:
    return struct.unpack(">f", struct.pack(">f", x))[0]


# ---------------------------------------------------------------------------------------------
# A plain reference reader of the framing rules


def _norm(x) -> object:
    x = float(x)
    return "nan" if math.isnan(x) else x


_VEC = {0x4020: "accelerometer", 0x8020: "gyroscope", 0xC020: "magnetometer"}
_PSIZE = {0: 4, 1: 4, 2: 6, 3: 8}


def _real(q: bytes, prec: int) -> float:
    if prec == 0:
        return struct.unpack(">f", q)[0]
    if prec == 1:
        return struct.unpack(">i", q)[0] / 2**20
    if prec == 2:
        frac, whole = struct.unpack(">Ih", q)
        return whole + frac / 2**32
    return struct.unpack(">d", q)[0]


def _ref_items(data: bytes):
    items, o = [], 0
    while o < len(data):
        if o + 3 > len(data):
            return None
        xdi, size = struct.unpack_from(">HB", data, o)
        if o + 3 + size > len(data):
            return None
        items.append((xdi, data[o + 3:o + 3 + size]))
        o += 3 + size
    return items


def _ref_fields(items) -> dict:
    out = {}
    for xdi, p in items:
        base, prec = xdi & 0xFFF0, xdi & 3
        if xdi == 0x1020 and len(p) == 2:
            out.setdefault("packet_counter", struct.unpack(">H", p)[0])
        elif xdi == 0x1060 and len(p) == 4:
            out.setdefault("stf", struct.unpack(">I", p)[0])
        elif xdi in (0xA010, 0xA011) and len(p) == 20:
            out.setdefault("raw", struct.unpack(">9Hh" if xdi == 0xA010 else ">9hh", p))
        elif base in _VEC and len(p) == 3 * _PSIZE[prec]:
            s = _PSIZE[prec]
            out.setdefault(_VEC[base], tuple(_real(p[j * s:(j + 1) * s], prec) for j in range(3)))
        elif base == 0x0810 and len(p) == _PSIZE[prec]:
            out.setdefault("temperature", _real(p, prec))
    return out


def reference(stream: bytes, t_host: float = 0.0):
    """Read ``stream`` one byte at a time: (samples, counters) as the public rules say."""
    samples = []
    cnt = dict(frames=0, discarded_bytes=0, checksum_failures=0, sequence_gaps=0, missing_frames=0)
    accepted = 0
    pc_prev = stf_prev = None
    wraps = 0
    i, n = 0, len(stream)
    while i < n:
        if stream[i] != 0xFA or (i + 1 < n and stream[i + 1] != 0xFF):
            i += 1
            continue
        if i + 4 > n:
            break  # header not complete: wait
        mid, length, hdr = stream[i + 2], stream[i + 3], 4
        if length == 0xFF:
            if i + 6 > n:
                break
            length, hdr = struct.unpack(">H", stream[i + 4:i + 6])[0], 6
            if length > 8192 - 7:
                i += 1
                continue
        total = hdr + length + 1
        if i + total > n:
            break
        if sum(stream[i + 1:i + total]) % 256:
            cnt["checksum_failures"] += 1
            i += 1
            continue
        items = _ref_items(stream[i + hdr:i + hdr + length]) if mid == 0x36 else None
        if items is not None:
            cnt["frames"] += 1
            accepted += total
            f = _ref_fields(items)
            if "packet_counter" in f:
                if pc_prev is not None:
                    d = (f["packet_counter"] - pc_prev) % 65536
                    if d != 1:
                        cnt["sequence_gaps"] += 1
                        cnt["missing_frames"] += d - 1 if 2 <= d <= 32768 else 0
                pc_prev = f["packet_counter"]
            t = t_host
            if "stf" in f:
                if stf_prev is not None and f["stf"] - stf_prev < -2**31:
                    wraps += 1
                stf_prev = f["stf"]
                t = (f["stf"] + wraps * 2**32) / 1e4
            s = {"t": _norm(t)}
            for name in ("accelerometer", "gyroscope", "magnetometer"):
                if name in f:
                    s[name] = tuple(_norm(v) for v in f[name])
            if "raw" in f:
                r = f["raw"]
                s["accelerometer_raw"] = tuple(float(v) for v in r[0:3])
                s["gyroscope_raw"] = tuple(float(v) for v in r[3:6])
                s["magnetometer_raw"] = tuple(float(v) for v in r[6:9])
                s["temperature_raw"] = float(r[9])
            if "temperature" in f:
                s["temperature"] = _norm(f["temperature"])
            if len(s) > 1:  # some data channel, not just time
                if "packet_counter" in f:
                    s["packet_counter"] = float(f["packet_counter"])
                samples.append(s)
        i += total
    cnt["discarded_bytes"] = i - accepted
    return samples, cnt


def rows(chunk: SampleChunk) -> list[dict]:
    out = []
    for i in range(len(chunk)):
        r = {"t": _norm(chunk.t[i])}
        for name, v in chunk.triads.items():
            r[name] = tuple(_norm(x) for x in v[i])
        if chunk.temperature is not None:
            r["temperature"] = _norm(chunk.temperature[i])
        for name, v in chunk.extras.items():
            r[name] = _norm(v[i])
        out.append(r)
    return out


def run_parser(pieces, t_host: float = 0.0, parser=None):
    parser = parser or XsensMtData2Parser()
    out = []
    for piece in pieces:
        chunk = parser.feed(piece, t_host)
        if chunk is not None:
            assert len(chunk) > 0
            out += rows(chunk)
        assert parser.buffered < MAX_MESSAGE_LENGTH
    while (chunk := parser.feed(b"", t_host)) is not None:
        out += rows(chunk)
    return out, parser


def split(stream: bytes, cuts) -> list[bytes]:
    cuts = sorted({c % (len(stream) + 1) for c in cuts}) if stream else []
    edges = [0] + cuts + [len(stream)]
    return [stream[a:b] for a, b in zip(edges[:-1], edges[1:])]


# ---------------------------------------------------------------------------------------------
# Known messages

# PacketCounter 0x1234, SampleTimeFine 123456, Acceleration (0.5, -9.81, 1.25),
# RateOfTurn (0.01, -0.02, 0.03), Temperature 25.5. LEN = 5 + 7 + 15 + 15 + 7 = 49 = 0x31.
# Checksum: the bytes FF 36 31 ... 00 00 sum to 0xF6B; 0xF6B mod 256 = 0x6B, so CS = 0x100 - 0x6B
# = 0x95.
HAND_BUILT = bytes.fromhex(
    "fa ff 36 31"
    " 10 20 02 12 34"
    " 10 60 04 00 01 e2 40"
    " 40 20 0c 3f 00 00 00 c1 1c f5 c3 3f a0 00 00"
    " 80 20 0c 3c 23 d7 0a bc a3 d7 0a 3c f5 c2 8f"
    " 08 10 04 41 cc 00 00"
    " 95")

# Real MTi output (einride/xsens-go testdata/1/messages.golden, lines 1, 2, 18, 19, 20; decoded
# values from testdata/1/output.golden). Line 19 is a GNSS PVT MTData2 message (0x7010, UTC time,
# SampleTimeFine, PacketCounter, no inertial data).
GOLDEN = [bytes.fromhex(h) for h in (
    ("faff3662102002a9861060040314ed5310100c07440be007e301140d2f1837e020040180000740200cbc8e54"
     "66c0e82f10bf9ad29e40100cb935269fbd949930bc46234680200cbb425c343b1068df3ae1c7e58030103f80"
     "0001b778c7f03738d82737107feef7"),
    ("faff3671102002a9871060040314edb710100c07dca26007e301140d2f1837e020040000000520300cc2c6ec"
     "743e083f53c33330cb40200c3ce7e9cbc11a8e2fbfd04d0c40100c39931323bdc5d49bbc8552c480200c3ab2"
     "1f42bb513ab9bb51e94c8030103f80000136e3ff0cb785e822b78657df19"),
    ("faff3671102002a9971060040314f3f710100c11660a6007e301140d2f1837e020040000000520300cc2c6eb"
     "0a3df0b7c9c3332cd940200c3cecc6a1c11abaabbfd2ac0540100c3995fc3fbdc60ddabc86d00080200cbb11"
     "434739027a1ebb471f178030103f800001b739efb6352702b6b77ee01b8e"),
    ("faff367c70105e02f5c92a07e301140d2f1837000000050ee32a2403010b00071522e822612f5500013f7100"
     "00a92a000008d300000818ffffffe50000000afffffffe0000001d000000000000015e00e5519a0002000000"
     "9a008b0044007000530037003e10100c0ee6b28007e301140d2f18371060040314f254102002a99808"),
    ("faff3671102002a9991060040314f45b10100c11fea0e007e301140d2f1837e020040000000520300cc2c6ea"
     "dd3de9df88c3332c9d40200c3cac6249c11aadd5bfd0f22340100c395790b8bdc5fd2cbc85bb2c80200c3a40"
     "4a4bba212141bba7cf5e8030103f800000367621a7b64e3f0cb7d6cc009e"),
)]


def test_hand_built_message_from_the_spec():
    assert HAND_BUILT == message(
        item(0x1020, struct.pack(">H", 0x1234)) + item(0x1060, struct.pack(">I", 123456))
        + item(0x4020, struct.pack(">3f", 0.5, -9.81, 1.25))
        + item(0x8020, struct.pack(">3f", 0.01, -0.02, 0.03))
        + item(0x0810, struct.pack(">f", 25.5)))
    assert sum(HAND_BUILT[1:]) % 256 == 0
    parser = XsensMtData2Parser()
    chunk = parser.feed(HAND_BUILT, t_host=99.0)
    assert len(chunk) == 1
    assert chunk.t[0] == 12.3456  # 123456 ticks of 10 kHz, not the host time
    assert chunk.extras["packet_counter"].tolist() == [0x1234]
    assert chunk.triads["accelerometer"].tolist() == [[0.5, f32(-9.81), 1.25]]
    assert chunk.triads["gyroscope"].tolist() == [[f32(0.01), f32(-0.02), f32(0.03)]]
    assert chunk.temperature.tolist() == [25.5]
    assert set(chunk.triads) == {"accelerometer", "gyroscope"}
    assert parser.counters.as_dict() == dict(frames=1, discarded_bytes=0, checksum_failures=0,
                                             sequence_gaps=0, missing_frames=0)


def test_real_device_messages_decode_to_the_published_values():
    for m in GOLDEN:
        assert sum(m[1:]) % 256 == 0  # the published checksums hold under our reading of the rule
    parser = XsensMtData2Parser()
    chunk = parser.feed(GOLDEN[0] + GOLDEN[1], 0.0)  # two layouts (EulerAngles added), one chunk
    assert chunk.extras["packet_counter"].tolist() == [43398, 43399]
    assert chunk.t.tolist() == [51703123 / 1e4, 51703223 / 1e4]
    assert chunk.triads["accelerometer"].tolist() == [
        [-0.017374228686094284, -7.255744934082031, -1.209552526473999],
        [0.028309723362326622, -9.659712791442871, -1.6273512840270996]]
    assert chunk.triads["gyroscope"].tolist() == [
        [-0.002965700812637806, 0.0022035164292901754, 0.0017225710907950997],
        [0.0013589637819677591, -0.0031925870571285486, -0.0032029924914240837]]
    assert chunk.temperature is None and "magnetometer" not in chunk.triads

    parser = XsensMtData2Parser()
    chunk = parser.feed(GOLDEN[2] + GOLDEN[3] + GOLDEN[4], 0.0)
    # The GNSS message is accepted (its counter 43416 closes the sequence) but has no samples.
    assert chunk.extras["packet_counter"].tolist() == [43415, 43417]
    assert chunk.t.tolist() == [51704823 / 1e4, 51704923 / 1e4]
    assert chunk.triads["accelerometer"][1].tolist() == [0.0210429597645998, -9.667439460754395,
                                                         -1.6323894262313843]
    assert parser.counters.as_dict() == dict(frames=3, discarded_bytes=0, checksum_failures=0,
                                             sequence_gaps=0, missing_frames=0)


def test_other_message_ids_are_skipped_whole_and_counted():
    error = bytes.fromhex("fa ff 42 01 04 ba")  # xsens-go message_test.go: Error(InvalidMessage)
    goto_config = bytes.fromhex("fa ff 30 00 d1")  # xsens-go message_test.go: GotoConfig
    parser = XsensMtData2Parser()
    chunk = parser.feed(error + HAND_BUILT + goto_config, 0.0)
    assert len(chunk) == 1
    assert parser.counters.as_dict() == dict(frames=1, discarded_bytes=11, checksum_failures=0,
                                             sequence_gaps=0, missing_frames=0)


def test_fixed_point_16_32_vector_from_public_source():
    # xsens-go mtdata2_test.go: bytes 24 39 58 10 00 03 -> 3.1415 (fraction first, then integer).
    fp = bytes.fromhex("243958100003")
    parser = XsensMtData2Parser()
    chunk = parser.feed(message(item(0x4022, fp * 3)), 0.0)
    assert chunk.triads["accelerometer"][0] == pytest.approx([3.1415] * 3, abs=1e-5)
    assert chunk.triads["accelerometer"][0, 0] == 3 + 0x24395810 / 2**32


def test_all_precisions_and_coordinate_bits():
    v = (1.5, -2.25, 0.125)
    payloads = {0x0: struct.pack(">3f", *v), 0x1: struct.pack(">3i", *(int(x * 2**20) for x in v)),
                0x3: struct.pack(">3d", *v),
                0x2: b"".join(struct.pack(">Ih", int((x % 1) * 2**32), math.floor(x)) for x in v)}
    for prec, payload in payloads.items():
        for coord in (0x0, 0x4, 0x8):  # ENU, NED, NWU: calibrated data is not rotated
            chunk = XsensMtData2Parser().feed(message(item(0x8020 | coord | prec, payload)), 0.0)
            assert chunk.triads["gyroscope"].tolist() == [list(v)], (prec, coord)


def test_known_items_of_the_wrong_size_are_skipped_and_the_first_occurrence_wins():
    data = (item(0x4020, struct.pack(">3f", 9, 9, 9) + b"\x00")  # 13 bytes: not an Acceleration
            + item(0x4020, struct.pack(">3f", 1, 2, 3)) + item(0x4020, struct.pack(">3f", 4, 5, 6))
            + item(0x0810, b"\x41\xcc") + item(0x1020, b"\x00\x05"))
    parser = XsensMtData2Parser()
    chunk = parser.feed(message(data), 0.0)
    assert chunk.triads["accelerometer"].tolist() == [[1, 2, 3]]
    assert chunk.temperature is None and chunk.extras["packet_counter"].tolist() == [5]
    assert parser.counters.frames == 1 and parser.counters.discarded_bytes == 0


def test_a_malformed_item_list_is_not_accepted_even_with_a_valid_checksum():
    overrun = message(item(0x1020, b"\x00\x01") + b"\x40\x20\x0c\x00\x00")  # 12 bytes announced
    parser = XsensMtData2Parser()
    chunk = parser.feed(overrun + HAND_BUILT, 0.0)
    assert len(chunk) == 1 and chunk.extras["packet_counter"].tolist() == [0x1234]
    assert parser.counters.as_dict() == dict(frames=1, discarded_bytes=len(overrun),
                                             checksum_failures=0, sequence_gaps=0, missing_frames=0)


def test_raw_adc_item():
    raw = struct.pack(">9Hh", 1, 2, 3, 40000, 5, 6, 7, 8, 65535, -300)
    chunk = XsensMtData2Parser().feed(message(item(0x1020, b"\x00\x07") + item(0xA010, raw)), 0.0)
    assert chunk.triads["accelerometer_raw"].tolist() == [[1, 2, 3]]
    assert chunk.triads["gyroscope_raw"].tolist() == [[40000, 5, 6]]
    assert chunk.triads["magnetometer_raw"].tolist() == [[7, 8, 65535]]
    assert chunk.extras["temperature_raw"].tolist() == [-300]
    assert chunk.temperature is None
    # XDI_RawSigned (0xA011): the same 20 bytes read as signed counts
    chunk = XsensMtData2Parser().feed(message(item(0xA011, raw)), 0.0)
    assert chunk.triads["gyroscope_raw"].tolist() == [[40000 - 65536, 5, 6]]
    assert chunk.triads["magnetometer_raw"].tolist() == [[7, 8, -1]]


# ---------------------------------------------------------------------------------------------
# Robustness


def test_wrong_checksum_is_rejected_counted_and_the_next_frame_parses():
    bad = bytearray(basic_frame(1, stf=100, acc=(1.0, 2.0, 3.0)))
    bad[-1] ^= 0x01
    good = basic_frame(2, stf=200, acc=(4.0, 5.0, 6.0))
    parser = XsensMtData2Parser()
    chunk = parser.feed(bytes(bad) + good, 0.0)
    assert chunk.triads["accelerometer"].tolist() == [[4.0, 5.0, 6.0]]
    assert parser.counters.checksum_failures == 1
    assert parser.counters.frames == 1
    assert parser.counters.discarded_bytes == len(bad)


def test_resync_starts_one_byte_after_a_bad_preamble():
    inner = basic_frame(7, stf=70, acc=(7.0, 7.0, 7.0))  # a whole valid message inside a payload
    outer = message(item(0x1020, b"\x00\x01") + item(0x4020, struct.pack(">3f", 1, 2, 3))
                    + item(0x7777, inner))
    parser = XsensMtData2Parser()
    chunk = parser.feed(outer, 0.0)  # a false preamble inside an accepted frame is data
    assert chunk.triads["accelerometer"].tolist() == [[1, 2, 3]]
    assert parser.counters.as_dict()["frames"] == 1 and parser.counters.discarded_bytes == 0

    broken = bytearray(outer)
    broken[-1] ^= 0xFF
    parser = XsensMtData2Parser()
    chunk = parser.feed(bytes(broken), 0.0)  # searching from the byte after the bad preamble
    assert chunk.triads["accelerometer"].tolist() == [[7.0, 7.0, 7.0]]  # finds the inner message
    assert parser.counters.checksum_failures == 1
    assert parser.counters.discarded_bytes == len(outer) - len(inner)


def test_extended_length_message():
    data = (item(0x1020, b"\x01\x02") + item(0x4020, struct.pack(">3f", 0.25, 0.5, -1.0))
            + item(0x7010, bytes(range(250))))  # an unknown item pushes LEN past 254
    assert len(data) == 273  # 5 + 15 + 253 = 0x0111
    msg = b"\xfa\xff\x36\xff\x01\x11" + data
    msg += bytes([(-sum(msg[1:])) % 256])  # the extended length bytes count in the checksum
    assert msg == message(data)
    parser = XsensMtData2Parser()
    chunk = parser.feed(msg, 3.0)
    assert chunk.triads["accelerometer"].tolist() == [[0.25, 0.5, -1.0]]
    assert chunk.extras["packet_counter"].tolist() == [0x0102]
    assert chunk.t.tolist() == [3.0]  # no SampleTimeFine: host time
    assert parser.counters.frames == 1 and parser.counters.discarded_bytes == 0


def test_unterminated_and_absurd_frames_keep_the_buffer_bounded():
    parser = XsensMtData2Parser()
    # LEN FF, extended length 8185: the largest legal message, which will never complete.
    assert parser.feed(b"\xfa\xff\x36\xff\x1f\xf9", 0.0) is None
    for _ in range(20):
        assert parser.feed(b"\x00" * 1000, 0.0) is None
        assert parser.buffered < MAX_MESSAGE_LENGTH
    assert parser.counters.checksum_failures == 1  # judged once 8192 bytes were there
    # An extended length beyond the maximum is rejected at once, not waited for.
    parser = XsensMtData2Parser()
    chunk = parser.feed(b"\xfa\xff\x36\xff\xff\xff" + HAND_BUILT, 0.0)
    assert len(chunk) == 1 and parser.counters.discarded_bytes == 6
    # A megabyte of noise
    rng = np.random.default_rng(1)
    parser = XsensMtData2Parser()
    for _ in range(16):
        parser.feed(rng.integers(0, 256, 65536, dtype=np.uint8).tobytes(), 0.0)
        assert parser.buffered < MAX_MESSAGE_LENGTH


def test_packet_counter_gaps_and_wrap():
    parser = XsensMtData2Parser()
    stream = b"".join(basic_frame(pc) for pc in (8, 9, 10, 15, 16))
    chunk = parser.feed(stream, 0.0)
    assert chunk.extras["packet_counter"].tolist() == [8, 9, 10, 15, 16]
    assert parser.counters.sequence_gaps == 1 and parser.counters.missing_frames == 4

    parser = XsensMtData2Parser()
    parser.feed(basic_frame(65534) + basic_frame(65535), 0.0)
    parser.feed(basic_frame(0) + basic_frame(1), 0.0)  # wrap, across calls
    assert parser.counters.sequence_gaps == 0 and parser.counters.missing_frames == 0
    parser.feed(basic_frame(65533), 0.0)  # backwards (a reset): a gap of unknown size
    assert parser.counters.sequence_gaps == 1 and parser.counters.missing_frames == 0


def test_sample_time_fine_unwraps_across_the_32_bit_wrap_and_calls():
    top = 2**32
    parser = XsensMtData2Parser()
    a = parser.feed(basic_frame(0, stf=top - 20000) + basic_frame(1, stf=top - 100), 0.0)
    b = parser.feed(basic_frame(2, stf=50) + basic_frame(3, stf=10050), 0.0)
    c = parser.feed(basic_frame(4, stf=20050), 0.0)
    t = np.concatenate([a.t, b.t, c.t])
    expected = np.array([top - 20000, top - 100, top + 50, top + 10050, top + 20050]) / 1e4
    np.testing.assert_array_equal(t, expected)


def test_host_time_is_the_time_of_the_feed_that_completed_the_frame():
    frames = [basic_frame(i) for i in range(3)]
    stream = b"".join(frames)
    cut = len(frames[0]) + 10  # frame 1 straddles the two calls
    parser = XsensMtData2Parser()
    first = parser.feed(stream[:cut], 1.0)
    second = parser.feed(stream[cut:], 2.0)
    assert first.t.tolist() == [1.0] and second.t.tolist() == [2.0, 2.0]


def test_a_layout_change_never_mixes_channels():
    a = [basic_frame(i, stf=100 * i) for i in range(3)]
    b = [basic_frame(i, stf=100 * i, mag=(0.1, 0.2, 0.3)) for i in range(3, 5)]
    c = [basic_frame(5, stf=500, temp=30.0)]
    parser = XsensMtData2Parser()
    first = parser.feed(b"".join(a + b + c), 0.0)
    assert first.extras["packet_counter"].tolist() == [0, 1, 2]
    assert set(first.triads) == {"accelerometer", "gyroscope"} and first.temperature is None
    assert parser.pending == 2
    second = parser.feed(b"", 0.0)
    assert second.extras["packet_counter"].tolist() == [3, 4]
    assert second.triads["magnetometer"].tolist() == [[f32(0.1), f32(0.2), f32(0.3)]] * 2
    third = parser.feed(basic_frame(6, stf=600, temp=31.0), 0.0)  # merges with what was waiting
    assert third.extras["packet_counter"].tolist() == [5, 6]
    assert third.temperature.tolist() == [30.0, 31.0]
    assert parser.feed(b"", 0.0) is None
    assert parser.counters.frames == 7 and parser.counters.sequence_gaps == 0


def test_layouts_alternating_more_often_than_feed_calls_are_capped_and_counted():
    parser = XsensMtData2Parser()
    parser.MAX_PENDING_RUNS = 3
    stream = b"".join(basic_frame(i, mag=(1.0, 1.0, 1.0) if i % 2 else None) for i in range(8))
    first = parser.feed(stream, 0.0)  # 8 one-sample runs: the 5 oldest beyond the cap are dropped
    assert first.extras["packet_counter"].tolist() == [5]
    assert parser.overflow_samples == 5 and parser.pending == 2
    assert parser.counters.frames == 8


def _mixed_stream():
    rng = np.random.default_rng(3)
    frames = [basic_frame(0, stf=0), basic_frame(1, stf=100, mag=(1.0, 2.0, 3.0)),
              basic_frame(2, acc=(0.5, 0.5, 0.5)), message(item(0x1020, b"\x00\x03")),
              basic_frame(4, stf=400, temp=21.5)]
    junk = [rng.integers(0, 256, 7, dtype=np.uint8).tobytes(), b"\xfa", b"\xfa\xff",
            b"\xfa\xff\x36\x05\x00", b"", b"\x00\xfa"]
    stream = b""
    for f, g in zip(frames, junk):
        stream += g + f
    return stream + junk[-1]


def test_garbage_and_every_split_point_give_exactly_the_sent_samples():
    stream = _mixed_stream()
    expected, counts = reference(stream, t_host=-1.0)
    assert [s["packet_counter"] for s in expected] == [0, 1, 2, 4]  # frame 3 has no data channel
    assert counts["frames"] == 5
    whole, parser = run_parser([stream], -1.0)
    assert whole == expected
    assert parser.counters.as_dict() == counts
    for cut in range(len(stream) + 1):
        got, parser = run_parser([stream[:cut], stream[cut:]], -1.0)
        assert got == expected, cut
        assert parser.counters.as_dict() == counts, cut
    got, parser = run_parser([stream[i:i + 1] for i in range(len(stream))], -1.0)
    assert got == expected
    assert parser.counters.as_dict() == counts


# ---------------------------------------------------------------------------------------------
# Encoder


@pytest.mark.parametrize("precision", ["float32", "fp1220", "fp1632", "float64"])
def test_round_trip(precision):
    rng = np.random.default_rng(5)
    n = 300
    chunk = SampleChunk(
        t=1000.0 + np.arange(n) * 0.004,
        triads={"accelerometer": rng.normal(0, 9.8, (n, 3)), "gyroscope": rng.normal(0, 1, (n, 3)),
                "magnetometer": rng.normal(0, 1, (n, 3)),
                "accelerometer_raw": rng.integers(0, 65536, (n, 3)).astype(float),
                "gyroscope_raw": rng.integers(0, 65536, (n, 3)).astype(float),
                "magnetometer_raw": rng.integers(0, 65536, (n, 3)).astype(float)},
        temperature=rng.normal(30, 2, n),
        extras={"packet_counter": (65500 + np.arange(n)) % 65536.0,
                "temperature_raw": rng.integers(-2000, 2000, n).astype(float)})
    items = ("packet_counter", "sample_time_fine", "acceleration", "rate_of_turn",
             "magnetic_field", "temperature")
    encoder = XsensMtData2Encoder(items=items, raw=True, precision=precision)
    data = encoder.encode(chunk)
    parser = XsensMtData2Parser()
    got = parser.feed(data, 0.0)
    assert parser.counters.as_dict() == dict(frames=n, discarded_bytes=0, checksum_failures=0,
                                             sequence_gaps=0, missing_frames=0)
    np.testing.assert_allclose(got.t, chunk.t, rtol=0, atol=0.5e-4)
    tol = {"float32": None, "fp1220": 2.0**-21, "fp1632": 2.0**-33, "float64": 0.0}[precision]
    for name in ("accelerometer", "gyroscope", "magnetometer"):
        if tol is None:
            np.testing.assert_array_equal(got.triads[name], chunk.triads[name].astype(np.float32))
        else:
            np.testing.assert_allclose(got.triads[name], chunk.triads[name], rtol=0, atol=tol)
    for name in ("accelerometer_raw", "gyroscope_raw", "magnetometer_raw"):
        np.testing.assert_array_equal(got.triads[name], chunk.triads[name])
    np.testing.assert_array_equal(got.extras["packet_counter"], chunk.extras["packet_counter"])
    np.testing.assert_array_equal(got.extras["temperature_raw"], chunk.extras["temperature_raw"])
    if tol is None:
        np.testing.assert_array_equal(got.temperature, chunk.temperature.astype(np.float32))
    else:
        np.testing.assert_allclose(got.temperature, chunk.temperature, rtol=0, atol=tol)


def test_encoder_default_message_matches_the_hand_built_one():
    chunk = SampleChunk(t=np.array([12.3456]),
                        triads={"accelerometer": np.array([[0.5, -9.81, 1.25]]),
                                "gyroscope": np.array([[0.01, -0.02, 0.03]])},
                        temperature=np.array([25.5]), extras={"packet_counter": np.array([0x1234])})
    assert XsensMtData2Encoder().encode(chunk) == HAND_BUILT


def test_encoder_running_counter_and_wrap():
    encoder = XsensMtData2Encoder(items=("packet_counter", "acceleration"))
    chunk = SampleChunk(t=np.zeros(3), triads={"accelerometer": np.zeros((3, 3))})
    parser = XsensMtData2Parser()
    counters = []
    for _ in range(3):
        counters += parser.feed(encoder.encode(chunk), 0.0).extras["packet_counter"].tolist()
    assert counters == list(range(9))
    encoder = XsensMtData2Encoder(items=("sample_time_fine", "acceleration"))
    big = SampleChunk(t=np.array([429496.7295, 429496.7296]),
                      triads={"accelerometer": np.ones((2, 3))})
    data = encoder.encode(big)
    assert len(data) == 2 * 27  # 4 header + (3 + 4) + (3 + 12) data + 1 checksum
    assert data[7:11] == b"\xff\xff\xff\xff" and data[27 + 7:27 + 11] == b"\x00\x00\x00\x00"
    with pytest.raises(ValueError):
        XsensMtData2Encoder(items=("acceleration", "nonsense"))
    with pytest.raises(ValueError):
        XsensMtData2Encoder(items=("magnetic_field",)).encode(chunk)


# ---------------------------------------------------------------------------------------------
# Property tests


@st.composite
def frames(draw):
    """The data field of one MTData2 message with a random layout, and the sample it carries
    (None when it has no data channel)."""
    kinds = draw(st.lists(st.sampled_from(["pc", "acc", "gyr", "mag", "temp", "raw", "unknown",
                                           "bad"]), unique=True, max_size=5))
    data, sample = b"", {}
    for kind in kinds:
        if kind == "pc":
            pc = draw(st.integers(0, 65535))
            data += item(0x1020, struct.pack(">H", pc))
            sample["packet_counter"] = float(pc)
        elif kind == "bad":  # a known identifier with a size that does not fit it: skipped
            xdi, size = draw(st.sampled_from([(0x4020, 12), (0x8020, 12), (0x0810, 4), (0x1020, 2),
                                              (0x1060, 4), (0xA010, 20), (0xC023, 24)]))
            payload = draw(st.binary(max_size=30).filter(lambda p, size=size: len(p) != size))
            data += item(xdi, payload)
        elif kind == "unknown":
            data += item(draw(st.sampled_from([0x2010, 0x7010, 0xE020, 0x4030])),
                         draw(st.binary(max_size=260 if draw(st.booleans()) else 8)))
        elif kind == "raw":
            v = draw(st.tuples(*[st.integers(0, 65535)] * 9, st.integers(-32768, 32767)))
            data += item(0xA010, struct.pack(">9Hh", *v))
            for j, name in enumerate(("accelerometer_raw", "gyroscope_raw", "magnetometer_raw")):
                sample[name] = tuple(float(x) for x in v[3 * j:3 * j + 3])
            sample["temperature_raw"] = float(v[9])
        else:
            count = 1 if kind == "temp" else 3
            prec = draw(st.integers(0, 3))
            if prec == 0:
                vals = draw(st.lists(st.floats(width=32, allow_nan=False), min_size=count,
                                     max_size=count))
                payload = struct.pack(f">{count}f", *vals)
            elif prec == 1:
                ints = draw(st.lists(st.integers(-2**31, 2**31 - 1), min_size=count,
                                     max_size=count))
                payload, vals = struct.pack(f">{count}i", *ints), [i / 2**20 for i in ints]
            elif prec == 2:
                fp = st.tuples(st.integers(0, 2**32 - 1), st.integers(-32768, 32767))
                parts = draw(st.lists(fp, min_size=count, max_size=count))
                payload = b"".join(struct.pack(">Ih", f, w) for f, w in parts)
                vals = [w + f / 2**32 for f, w in parts]
            else:
                vals = draw(st.lists(st.floats(allow_nan=False), min_size=count, max_size=count))
                payload = struct.pack(f">{count}d", *vals)
            base = {"acc": 0x4020, "gyr": 0x8020, "mag": 0xC020, "temp": 0x0810}[kind]
            data += item(base | prec, payload)
            if kind == "temp":
                sample["temperature"] = vals[0]
            else:
                name = {"acc": "accelerometer", "gyr": "gyroscope", "mag": "magnetometer"}[kind]
                sample[name] = tuple(float(x) for x in vals)
    has_data = any(k in sample for k in ("accelerometer", "gyroscope", "magnetometer",
                                         "accelerometer_raw", "temperature"))
    return data, (sample if has_data else None)


no_preamble = st.binary(max_size=40).map(lambda s: s.replace(b"\xfa", b"\x00"))
cuts = st.lists(st.integers(0, 10**6), max_size=6)
FAST = settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _normed(sample: dict) -> dict:
    return {k: (tuple(_norm(x) for x in v) if isinstance(v, tuple) else _norm(v))
            for k, v in sample.items()}


@FAST
@given(st.lists(st.tuples(no_preamble, frames()), max_size=6), no_preamble, cuts,
       st.integers(0, 2**32 - 1))
def test_frames_between_soup_yield_exactly_what_was_sent(parts, tail, cut_points, stf0):
    stream, sent, framed = b"", [], 0
    for i, (soup, (data, sample)) in enumerate(parts):
        # every message gets a SampleTimeFine, stepping by 1 ms, possibly through the 2**32 wrap
        msg = message(data + item(0x1060, struct.pack(">I", (stf0 + 10 * i) % 2**32)))
        stream += soup + msg
        framed += len(msg)
        if sample is not None:
            sent.append(_normed(dict(sample, t=(stf0 + 10 * i) / 1e4)))
    stream += tail
    got, parser = run_parser(split(stream, cut_points), t_host=-1.0)
    assert got == sent
    c = parser.counters
    assert (c.frames, c.checksum_failures) == (len(parts), 0)
    assert c.discarded_bytes == len(stream) - framed
    assert c.as_dict() == reference(stream, -1.0)[1]  # gaps of the random packet counters


@FAST
@given(st.binary(max_size=600), cuts)
def test_arbitrary_soup_never_raises_and_agrees_with_the_reference(soup, cut_points):
    got, parser = run_parser(split(soup, cut_points))
    expected, counts = reference(soup)
    assert got == expected
    assert parser.counters.as_dict() == counts


@FAST
@given(st.lists(frames(), min_size=1, max_size=5),
       st.lists(st.tuples(st.integers(0, 10**6), st.binary(min_size=1, max_size=30)), max_size=4),
       cuts)
def test_soup_spliced_anywhere_yields_only_sent_or_genuinely_valid(msgs, splices, cut_points):
    stream = b"".join(message(data) for data, _ in msgs)
    for place, piece in splices:  # also inside messages, corrupting them
        place %= len(stream) + 1
        stream = stream[:place] + piece + stream[place:]
    got, parser = run_parser(split(stream, cut_points))
    expected, counts = reference(stream)
    assert got == expected
    assert parser.counters.as_dict() == counts
    # Whatever is yielded is a sample we sent or a message that the plain reader also finds
    # checksum-valid in the stream (an 8-bit checksum lets 1 in 256 corruptions through).
    sent = [_normed(s) for _, s in msgs if s is not None]
    for row in got:
        assert {k: v for k, v in row.items() if k != "t"} in sent or row in expected


# ---------------------------------------------------------------------------------------------
# Layering (parsing speed: benchmarks/parse.py)


def test_drivers_do_not_import_fieldcal():
    code = ("import sys, drivers.protocols.xsens; "
            "assert not [m for m in sys.modules if m.split('.')[0] == 'fieldcal']")
    subprocess.run([sys.executable, "-c", code], check=True)
