"""VectorNav ASCII $VNIMU / $VNYMR: checked against published sentences and an independent
reference parser written here with re, functools.reduce and float()."""
from __future__ import annotations

import functools
import itertools
import operator
import re

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.chunk import SampleChunk
from drivers.protocols.base import ParserCounters, StreamEncoder, StreamParser
from drivers.protocols.vectornav import VectorNavEncoder, VectorNavParser, crc16_vn

# VN-100 User Manual UM001 rev 2.22, §7.2.3 (p. 94): example response of register 27 (YMR).
MANUAL_YMR_RRG = (b"$VNRRG,27,+006.380,+000.023,-001.953,+1.0640,-0.2531,+3.0614,+00.005,+00.344,"
                  b"-09.758,-0.001222,-0.000450,-0.001218*4F")
# VN-100 UM001 §5.2.7 (p. 63): example command.
MANUAL_WRG = b"$VNWRG,06,0*6C"
# VectorNav C++ library, UART protocol example: a mock asynchronous VNYMR and a VNERR.
LIBRARY_YMR = (b"$VNYMR,+100.949,-007.330,+000.715,-00.0049,-00.2449,+00.5397,-01.258,-00.100,"
               b"-09.701,-00.000018,+00.001122,-00.000551*69\r\n")
LIBRARY_ERR = b"$VNERR,12*72\r\n"
# A VN-200 $VNIMU capture quoted in S. Bruder's MATLAB reader (same layout as VN-100 reg. 54).
CAPTURED_IMU = (b"$VNIMU,-00.0350,+00.4222,-00.6643,-00.015,+00.019,+09.948,+00.002066,-00.008442,"
                b"-00.044656,+20.7,+084.322*66\r\n")

NUMBER = re.compile(rb"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?")
NFIELDS = {b"VNIMU": 11, b"VNYMR": 12}


def xor8(body: bytes) -> int:
    return functools.reduce(operator.xor, body, 0)


def crc_bitwise(body: bytes) -> int:
    """CRC16-CCITT (poly 0x1021, init 0, MSB first), written from the definition."""
    crc = 0
    for byte in body:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else (crc << 1)
            crc &= 0xFFFF
    return crc


def sentence(body: bytes, mode: str = "xor8") -> bytes:
    if mode == "xor8":
        return b"$%s*%02X\r\n" % (body, xor8(body))
    return b"$%s*%04X\r\n" % (body, crc_bitwise(body))


def imu_body(i: int) -> bytes:
    v = [0.1 * i, -0.2, 0.3, 0.01 * i, -9.8, 0.5, 1e-4 * i, -2e-4, 3e-4, 21.5, 99.5]
    return b"VNIMU," + b",".join(b"%+.6f" % x for x in v)


def reference(stream: bytes, want: bytes = b"VNIMU", accept_unchecked: bool = True):
    """Rows of every acceptable sentence: '$' to the first CR/LF with no '$' in between."""
    rows = []
    for m in re.finditer(rb"\$([^$\r\n]*)[\r\n]", stream):
        line = m.group(1)
        body, star, cs = line.rpartition(b"*")
        if not star or len(line) + 1 > 512:
            continue
        if cs in (b"XX", b"XXXX"):
            if not accept_unchecked:
                continue
        elif len(cs) == 2 and re.fullmatch(rb"[0-9A-Fa-f]{2}", cs):
            if int(cs, 16) != xor8(body):
                continue
        elif len(cs) == 4 and re.fullmatch(rb"[0-9A-Fa-f]{4}", cs):
            if int(cs, 16) != crc_bitwise(body):
                continue
        else:
            continue
        head, _, payload = body.partition(b",")
        if head != want:
            continue
        fields = payload.split(b",")
        if len(fields) != NFIELDS[want] or not all(NUMBER.fullmatch(f) for f in fields):
            continue
        values = [float(f) for f in fields]
        if all(np.isfinite(values)):
            rows.append(values)
    return rows


def rows_of(chunk: SampleChunk | None, kind: str = "VNIMU") -> list[list[float]]:
    if chunk is None:
        return []
    tr = chunk.triads
    if kind == "VNIMU":
        cols = [tr["magnetometer"], tr["accelerometer"], tr["gyroscope"], chunk.temperature[:, None],
                chunk.extras["pressure"][:, None]]
    else:
        cols = [np.stack([chunk.extras[k] for k in ("yaw", "pitch", "roll")], axis=1),
                tr["magnetometer"], tr["accelerometer"], tr["gyroscope"]]
    return np.hstack(cols).tolist()


def feed_all(parser, pieces, t0=0.0):
    rows = []
    for i, piece in enumerate(pieces):
        rows += rows_of(parser.feed(piece, t0 + i), parser.sentence or "VNIMU")
    return rows


# -- the manual's checksum and CRC ------------------------------------------------------------

def test_manual_examples_checksums_are_the_xor_between_dollar_and_star():
    for s in (MANUAL_YMR_RRG, MANUAL_WRG, LIBRARY_YMR.strip(), LIBRARY_ERR.strip(), CAPTURED_IMU.strip()):
        body, cs = s[1:].split(b"*")
        assert xor8(body) == int(cs, 16), s


def test_crc16_is_the_manuals_ccitt_form():
    assert crc_bitwise(b"123456789") == 0x31C3  # CRC-16/XMODEM check value
    rng = np.random.default_rng(5)
    for _ in range(50):
        body = bytes(rng.integers(0, 256, rng.integers(0, 120)))
        assert crc16_vn(body) == crc_bitwise(body)


def test_protocol_conformance():
    parser: StreamParser = VectorNavParser()  # base's Protocols are not runtime_checkable
    encoder: StreamEncoder = VectorNavEncoder()
    assert isinstance(parser.counters, ParserCounters) and callable(parser.feed)
    assert callable(encoder.encode)


# -- published sentences ------------------------------------------------------------------------

def test_captured_vnimu():
    p = VectorNavParser()
    c = p.feed(CAPTURED_IMU, 12.5)
    assert p.sentence == "VNIMU"
    np.testing.assert_array_equal(c.t, [12.5])
    np.testing.assert_array_equal(c.triads["magnetometer"], [[-0.035, 0.4222, -0.6643]])
    np.testing.assert_array_equal(c.triads["accelerometer"], [[-0.015, 0.019, 9.948]])
    np.testing.assert_array_equal(c.triads["gyroscope"], [[0.002066, -0.008442, -0.044656]])
    np.testing.assert_array_equal(c.temperature, [20.7])
    np.testing.assert_array_equal(c.extras["pressure"], [84.322])
    assert p.counters.as_dict() == {"frames": 1, "discarded_bytes": 0, "checksum_failures": 0,
                                        "sequence_gaps": 0, "missing_frames": 0}


def test_library_vnymr_and_the_encoder_reproduces_it_byte_for_byte():
    p = VectorNavParser("VNYMR")
    c = p.feed(LIBRARY_YMR, 1.0)
    assert c.temperature is None
    np.testing.assert_array_equal(c.extras["yaw"], [100.949])
    np.testing.assert_array_equal(c.extras["pitch"], [-7.33])
    np.testing.assert_array_equal(c.extras["roll"], [0.715])
    np.testing.assert_array_equal(c.triads["magnetometer"], [[-0.0049, -0.2449, 0.5397]])
    np.testing.assert_array_equal(c.triads["accelerometer"], [[-1.258, -0.1, -9.701]])
    np.testing.assert_array_equal(c.triads["gyroscope"], [[-0.000018, 0.001122, -0.000551]])
    assert VectorNavEncoder("VNYMR").encode(c) == LIBRARY_YMR


def test_encoder_number_formats():
    chunk = SampleChunk(t=np.zeros(1), triads={"magnetometer": np.array([[-0.035, 0.4222, -0.6643]]),
                                               "accelerometer": np.array([[-0.015, 0.019, 9.948]]),
                                               "gyroscope": np.array([[0.002066, -0.008442, -0.044656]])},
                        temperature=np.array([20.7]), extras={"pressure": np.array([99.761])})
    out = VectorNavEncoder("VNIMU").encode(chunk)
    body = (b"VNIMU,-00.0350,+00.4222,-00.6643,-00.015,+00.019,+09.948,+00.002066,-00.008442,"
            b"-00.044656,+20.7,+00099.761")
    assert out == b"$%s*%02X\r\n" % (body, xor8(body))


def test_other_vn_sentences_are_skipped_and_counted_as_discarded():
    stream = MANUAL_YMR_RRG + b"\r\n" + LIBRARY_ERR + CAPTURED_IMU + MANUAL_WRG + b"\r\n"
    p = VectorNavParser()
    c = p.feed(stream, 0.0)
    assert len(c) == 1 and p.counters.frames == 1
    assert dict(p.skipped) == {"VNRRG": 1, "VNERR": 1, "VNWRG": 1}
    assert p.counters.discarded_bytes == len(stream) - len(CAPTURED_IMU)
    assert p.counters.checksum_failures == 0


# -- damage ------------------------------------------------------------------------------------

def test_wrong_checksum_rejected_counted_and_next_sentence_parses():
    good = [sentence(imu_body(i)) for i in range(3)]
    bad = bytearray(good[1])
    bad[10] ^= 0x01  # a flipped bit in a digit
    p = VectorNavParser("VNIMU")
    rows = feed_all(p, [good[0] + bytes(bad) + good[2]])
    assert rows == reference(good[0] + good[2])
    assert p.counters.checksum_failures == 1
    assert p.counters.frames == 2
    assert p.counters.discarded_bytes == len(bad)


def test_crc16_sentences_and_a_bad_crc():
    good = sentence(imu_body(1), "crc16")
    bad = good[:-6] + (b"%04X" % (crc_bitwise(imu_body(1)) ^ 1)) + b"\r\n"
    p = VectorNavParser()
    rows = feed_all(p, [good + bad + good])
    assert len(rows) == 2 and rows == reference(good + good)
    assert p.counters.checksum_failures == 1


def test_unchecked_sentences_follow_the_setting():
    s = b"$" + imu_body(2) + b"*XX\r\n"
    p = VectorNavParser()
    assert len(p.feed(s, 0.0)) == 1 and p.unchecked_frames == 1
    strict = VectorNavParser(accept_unchecked=False)
    assert strict.feed(s, 0.0) is None and strict.counters.discarded_bytes == len(s)


def test_truncated_sentence_then_a_good_one():
    good = sentence(imu_body(4))
    p = VectorNavParser()
    rows = feed_all(p, [good[:40], good, good[:25] + b"\r\n", good])
    assert rows == reference(good + good)
    assert p.counters.discarded_bytes == 40 + 27
    assert p.counters.checksum_failures == 0


def test_non_numeric_fields_with_a_valid_checksum():
    bodies = [imu_body(0), imu_body(1).replace(b"-0.200000", b"-0.2x0000"), imu_body(2),
              imu_body(3).replace(b",+21.5", b",,+21.5"), imu_body(4).replace(b"+99.5", b"+1e999")]
    stream = b"".join(sentence(b) for b in bodies)
    p = VectorNavParser("VNIMU")
    rows = feed_all(p, [stream])
    assert b",," in stream and b"1e999" in stream
    assert rows == reference(stream) and len(rows) == 2
    assert p.malformed_sentences == 3 and p.counters.checksum_failures == 0


def test_garbage_interleaved():
    rng = np.random.default_rng(11)
    good = [sentence(imu_body(i)) for i in range(20)]
    junk = [bytes(rng.integers(0, 256, rng.integers(0, 40))).replace(b"$", b"") for _ in good]
    junk[3] = b"$$$***$VN"  # a stray "$" is cut short by the next sentence's "$"
    stream = b"".join(j + g for j, g in zip(junk, good))
    p = VectorNavParser()
    rows = feed_all(p, [stream])
    assert rows == reference(b"".join(good))
    assert p.counters.frames == 20
    assert p.counters.discarded_bytes == sum(map(len, junk))


STREAM = b"xx" + sentence(imu_body(1)) + b"\x00$junk\n" + sentence(imu_body(2), "crc16") + sentence(imu_body(3))


@pytest.mark.parametrize("kind", ["split", "bytes"])
def test_every_split_point_and_byte_by_byte(kind):
    whole = VectorNavParser()
    expected = feed_all(whole, [STREAM])
    assert len(expected) == 3
    splits = ([[STREAM[:k], STREAM[k:]] for k in range(len(STREAM) + 1)] if kind == "split"
              else [[STREAM[i:i + 1] for i in range(len(STREAM))]])
    for pieces in splits:
        p = VectorNavParser()
        assert feed_all(p, pieces) == expected
        assert p.counters == whole.counters


def test_time_is_the_host_time_of_the_feed_that_completed_the_sentence():
    a, b = sentence(imu_body(1)), sentence(imu_body(2))
    p = VectorNavParser()
    assert p.feed(a[:-5], 1.0) is None
    c = p.feed(a[-5:] + b + b[:3], 2.0)
    np.testing.assert_array_equal(c.t, [2.0, 2.0])
    np.testing.assert_array_equal(p.feed(b[3:], 3.0).t, [3.0])


def test_one_sentence_type_per_parser():
    imu = sentence(imu_body(1))
    ymr = LIBRARY_YMR
    auto = VectorNavParser()
    c = auto.feed(ymr + imu + ymr, 0.0)
    assert auto.sentence == "VNYMR" and len(c) == 2 and "yaw" in c.extras
    assert auto.skipped["VNIMU"] == 1 and auto.counters.discarded_bytes == len(imu)
    fixed = VectorNavParser("VNIMU")
    c = fixed.feed(ymr + imu + ymr, 0.0)
    assert len(c) == 1 and "pressure" in c.extras and fixed.skipped["VNYMR"] == 2


def test_buffer_is_bounded():
    p = VectorNavParser(max_sentence_bytes=512)
    for _ in range(100):
        p.feed(b"$VNIMU," + b"1" * 997, 0.0)
        assert len(p._buf) <= 512
    c = p.feed(b"\r\n" + sentence(imu_body(1)), 0.0)
    assert len(c) == 1 and p.counters.discarded_bytes == 100 * 1004 + 2


def test_round_trip_all_checksum_modes_and_both_sentences():
    rng = np.random.default_rng(2)
    n = 500
    chunk = SampleChunk(
        t=np.arange(n) * 0.01,
        triads={"magnetometer": rng.normal(0, 0.5, (n, 3)), "accelerometer": rng.normal(0, 9.8, (n, 3)),
                "gyroscope": rng.normal(0, 1.0, (n, 3))},
        temperature=rng.normal(25, 5, n),
        extras={"pressure": rng.normal(101, 1, n), "yaw": rng.uniform(-180, 180, n),
                "pitch": rng.uniform(-90, 90, n), "roll": rng.uniform(-180, 180, n)})
    # half a unit of the last written decimal
    tol = {"magnetometer": 0.5e-4, "accelerometer": 0.5e-3, "gyroscope": 0.5e-6, "temperature": 0.05,
           "pressure": 0.5e-3, "yaw": 0.5e-3, "pitch": 0.5e-3, "roll": 0.5e-3}
    for kind in ("VNIMU", "VNYMR"):
        for mode in ("xor8", "crc16", "off"):
            data = VectorNavEncoder(kind, checksum=mode).encode(chunk)
            p = VectorNavParser(kind)
            out = p.feed(data, 7.0)
            assert len(out) == n
            assert p.counters.as_dict() == {"frames": n, "discarded_bytes": 0, "checksum_failures": 0,
                                                "sequence_gaps": 0, "missing_frames": 0}
            for name in ("magnetometer", "accelerometer", "gyroscope"):
                assert np.abs(out.triads[name] - chunk.triads[name]).max() <= tol[name] * 1.0001
            for name in (("pressure",) if kind == "VNIMU" else ("yaw", "pitch", "roll")):
                assert np.abs(out.extras[name] - chunk.extras[name]).max() <= tol[name] * 1.0001
            if kind == "VNIMU":
                assert np.abs(out.temperature - chunk.temperature).max() <= tol["temperature"] * 1.0001
            assert reference(data, kind.encode()) == rows_of(out, kind)


# -- byte soup ----------------------------------------------------------------------------------

WEIRD = [b"1", b"-0.5", b"+.5", b"5.", b"1e3", b"1.e-2", b"", b"+", b"-", b"e5", b"1e", b"1.2.3",
         b"+-1", b" 1", b"nan", b"inf", b"0x1", b"1e999", b"1_0", b"\xff", b"*", b"00012"]


@st.composite
def fragments(draw):
    kind = draw(st.sampled_from(["good", "crc", "weird", "flip", "cut", "junk", "marks", "other"]))
    i = draw(st.integers(0, 99))
    if kind == "good":
        return sentence(imu_body(i))
    if kind == "crc":
        return sentence(imu_body(i), "crc16")
    if kind == "weird":
        fields = [draw(st.sampled_from(WEIRD)) for _ in range(draw(st.integers(9, 13)))]
        return sentence(draw(st.sampled_from([b"VNIMU", b"VNYMR"])) + b"," + b",".join(fields),
                        draw(st.sampled_from(["xor8", "crc16"])))
    if kind == "flip":
        s = bytearray(sentence(imu_body(i)))
        s[draw(st.integers(0, len(s) - 1))] ^= 1 << draw(st.integers(0, 7))
        return bytes(s)
    if kind == "cut":
        s = sentence(imu_body(i))
        return s[:draw(st.integers(0, len(s)))]
    if kind == "marks":
        return draw(st.text(alphabet="$*\r\nXVN,", max_size=8)).encode()
    if kind == "other":
        return LIBRARY_YMR if i % 2 else LIBRARY_ERR
    return draw(st.binary(max_size=30))


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(fragments(), max_size=12), st.lists(st.integers(0, 2000), max_size=6))
def test_byte_soup_never_raises_and_yields_only_sent_sentences(frags, cuts):
    stream = b"".join(frags)
    bounds = sorted({0, len(stream), *[c % (len(stream) + 1) for c in cuts]})
    pieces = [stream[a:b] for a, b in itertools.pairwise(bounds)]
    p = VectorNavParser("VNIMU")
    rows = feed_all(p, pieces)
    assert rows == reference(stream)
    assert p.counters.frames == len(rows)
    assert 0 <= p.counters.discarded_bytes <= len(stream)
    one = VectorNavParser("VNIMU")
    assert feed_all(one, [stream]) == rows and one.counters == p.counters


@pytest.mark.parametrize("text", WEIRD + [b"+1E+2", b"-00.000018", b"1.5e-3", b"+0"])
def test_number_grammar_matches_the_reference(text):
    fields = [b"+1.0"] * 11
    fields[4] = text
    s = sentence(b"VNIMU," + b",".join(fields))
    p = VectorNavParser("VNIMU")
    rows = rows_of(p.feed(s, 0.0))
    assert rows == reference(s)
    assert len(rows) == (1 if NUMBER.fullmatch(text) and np.isfinite(float(text)) else 0)
