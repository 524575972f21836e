"""Delimited text with a channel map: hand-written files, a per-line reference parser written
here with str.split and float(), and the channel map's one-line validation errors."""
from __future__ import annotations

import dataclasses
import itertools
import re

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.chunk import SampleChunk
from drivers.protocols.delimited import (
    ChannelMap,
    DelimitedTextEncoder,
    DelimitedTextParser,
    TriadColumns,
)

G = 9.80665
NUMBER = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?")

CSV_MAP = {
    "delimiter": ",",
    "time_column": 0, "time_scale": 1e-3,  # milliseconds
    "triads": {"accelerometer": {"columns": [1, 2, 3], "scale": G * 1e-3, "unit": "m/s^2"},  # mg
               "gyroscope": {"columns": [4, 5, 6], "scale": np.pi / 180, "unit": "rad/s"}},  # deg/s
    "temperature_column": 7,
    "counter_column": 9, "counter_modulus": 256,
}

CSV = (b"# logger v1.2, 2024-05-01\r\n"
       b"time_ms,ax_mg,ay_mg,az_mg,gx_dps,gy_dps,gz_dps,temp_C,status,count\r\n"
       b"\r\n"
       b"1000,1.5,-2,1000.25,0.1,-0.2,0.3,25.5,OK,254\r\n"
       b"1004, 2.5 ,-3,1000.5,0.1,-0.2,0.3,25.5,OK,255\r\n"
       b"   # an indented comment\r\n"
       b"1008,3.5,-4,1000.75,0.1,oops,0.3,25.5,OK,0\r\n"
       b"1012,4.5,-5,1001,0.1,-0.2,0.3,25.5,,1\r\n"
       b"1016,5.5,-6,1001.25,0.1,-0.2\r\n"
       b"1020,6.5,-7,1001.5,0.1,-0.2,0.3,25.5,OK,4\r\n")


def csv_parser():
    return DelimitedTextParser(ChannelMap.from_mapping(CSV_MAP, "device.channels"))


def test_csv_with_header_comments_crlf_and_malformed_lines():
    p = csv_parser()
    c = p.feed(CSV, 99.0)
    np.testing.assert_allclose(c.t, [1.0, 1.004, 1.012, 1.020], rtol=0, atol=1e-12)
    np.testing.assert_allclose(c.triads["accelerometer"] / (G * 1e-3),
                               [[1.5, -2, 1000.25], [2.5, -3, 1000.5], [4.5, -5, 1001], [6.5, -7, 1001.5]])
    np.testing.assert_allclose(c.triads["gyroscope"], np.tile(np.radians([0.1, -0.2, 0.3]), (4, 1)))
    np.testing.assert_array_equal(c.temperature, [25.5] * 4)
    np.testing.assert_array_equal(c.extras["counter"], [254, 255, 1, 4])
    assert p.lines == 10 and p.header_lines == 1
    assert p.malformed_lines == 2 and list(p.malformed_line_numbers) == [7, 9]
    lines = CSV.split(b"\n")
    assert p.counters.discarded_bytes == sum(len(lines[i]) + 1 for i in (1, 6, 8))
    # 255 -> 0 wraps; 0 was lost (line 7), then 1; 2 and 3 lost (line 9 held 2, 3 never sent)
    assert p.counters.sequence_gaps == 2 and p.counters.missing_frames == 1 + 2
    assert p.counters.frames == 4 and p.counters.checksum_failures == 0


def test_every_split_point_and_byte_by_byte():
    whole = csv_parser()
    expected = whole.feed(CSV, 0.0)
    for pieces in [[CSV[:k], CSV[k:]] for k in range(len(CSV) + 1)] + [[CSV[i:i + 1] for i in range(len(CSV))]]:
        p = csv_parser()
        chunks = [c for c in (p.feed(x, 0.0) for x in pieces) if c is not None]
        t = np.concatenate([c.t for c in chunks])
        acc = np.concatenate([c.triads["accelerometer"] for c in chunks])
        np.testing.assert_array_equal(t, expected.t)
        np.testing.assert_array_equal(acc, expected.triads["accelerometer"])
        assert p.counters == whole.counters
        assert list(p.malformed_line_numbers) == [7, 9] and p.lines == whole.lines


def test_lf_and_crlf_give_the_same_samples():
    a = csv_parser().feed(CSV, 0.0)
    b = csv_parser().feed(CSV.replace(b"\r\n", b"\n"), 0.0)
    np.testing.assert_array_equal(a.t, b.t)
    np.testing.assert_array_equal(a.triads["gyroscope"], b.triads["gyroscope"])


def test_whitespace_delimited_without_time_column_uses_host_time():
    cm = ChannelMap.from_mapping({"delimiter": "whitespace",
                                  "triads": {"accelerometer": {"columns": [0, 1, 2]},
                                             "gyroscope": {"columns": [4, 5, 3], "scale": 0.5}}},
                                 "device.channels")
    text = (b"%  ax ay az\n"  # a header: no mapped field is a number
            b"  1.0\t2.0   3.0  9 10 11 extra words\n"
            b"\t-1 -2 -3 +9. .10 11e0\r\n"
            b"1 2 3 4 5\n"  # one column short
            b"# comment\n"
            b"4 5 6 7 8 9\n")
    p = DelimitedTextParser(cm)
    c = p.feed(text, 42.0)
    np.testing.assert_array_equal(c.t, [42.0] * 3)
    np.testing.assert_array_equal(c.triads["accelerometer"], [[1, 2, 3], [-1, -2, -3], [4, 5, 6]])
    np.testing.assert_array_equal(c.triads["gyroscope"], [[5, 5.5, 4.5], [0.05, 5.5, 4.5], [4, 4.5, 3.5]])
    assert p.header_lines == 1 and list(p.malformed_line_numbers) == [4]


def test_semicolon_and_tab_delimiters_and_text_in_unmapped_columns():
    for d in (";", "\t"):
        cm = ChannelMap(triads={"gyroscope": TriadColumns((1, 2, 3))}, delimiter=d, time_column=4)
        text = d.join(["label with, comma", "1", "2", "3", "0.5"]).encode() + b"\n"
        c = DelimitedTextParser(cm).feed(text * 3, 0.0)
        np.testing.assert_array_equal(c.triads["gyroscope"], [[1, 2, 3]] * 3)
        np.testing.assert_array_equal(c.t, [0.5] * 3)


def test_counter_without_modulus_and_a_reset():
    cm = ChannelMap.from_mapping({"triads": {"a": {"columns": [1, 2, 3]}}, "counter_column": 0}, "x")
    p = DelimitedTextParser(cm)
    lines = b"".join(b"%d,0,0,0\n" % k for k in [5, 6, 7, 10, 11, 0, 1])
    c = p.feed(lines, 0.0)
    np.testing.assert_array_equal(c.extras["counter"], [5, 6, 7, 10, 11, 0, 1])
    assert p.counters.sequence_gaps == 2 and p.counters.missing_frames == 2
    p.feed(b"3,0,0,0\n", 1.0)  # gaps are tracked across feeds
    assert p.counters.sequence_gaps == 3 and p.counters.missing_frames == 3


def test_overlong_line_is_bounded_and_reported_once():
    p = DelimitedTextParser(ChannelMap(triads={"a": TriadColumns((0, 1, 2))}), max_line_bytes=100)
    p.feed(b"1,2,3\n" + b"9" * 80, 0.0)
    for _ in range(10):
        p.feed(b"9" * 80, 0.0)
        assert len(p._buf) <= 100
    c = p.feed(b"99\n4,5,6\n", 1.0)
    np.testing.assert_array_equal(c.triads["a"], [[4, 5, 6]])
    assert p.malformed_lines == 1 and list(p.malformed_line_numbers) == [2] and p.lines == 3
    assert p.counters.discarded_bytes == 80 * 11 + 3


def test_round_trip_encoder_parser():
    cm = ChannelMap.from_mapping(CSV_MAP, "device.channels")
    rng = np.random.default_rng(4)
    n = 1000
    chunk = SampleChunk(t=100 + np.arange(n) * 0.004,
                        triads={"accelerometer": rng.normal(0, 9.8, (n, 3)), "gyroscope": rng.normal(0, 1, (n, 3))},
                        temperature=rng.normal(25, 2, n))
    for header in (False, True):
        for delimiter in (",", None):
            m = dict(cm.to_mapping(), delimiter=delimiter)
            enc = DelimitedTextEncoder(ChannelMap.from_mapping(m, "m"), header=header, line_end="\r\n")
            data = enc.encode(chunk)
            p = DelimitedTextParser(ChannelMap.from_mapping(m, "m"))
            out = p.feed(data, 0.0)
            assert len(out) == n
            np.testing.assert_allclose(out.t, chunk.t, rtol=1e-14)
            for name in ("accelerometer", "gyroscope"):
                np.testing.assert_allclose(out.triads[name], chunk.triads[name], rtol=1e-8, atol=1e-12)
            np.testing.assert_allclose(out.temperature, chunk.temperature, rtol=1e-8)
            np.testing.assert_array_equal(out.extras["counter"], np.arange(n) % 256)
            assert p.counters.frames == n and p.counters.sequence_gaps == 0
            assert p.malformed_lines == 0 and p.header_lines == int(header)
            assert p.counters.discarded_bytes == (len(enc.header_line()) if header else 0)


# -- the channel map ----------------------------------------------------------------------------

TRIADS = {"accelerometer": {"columns": [1, 2, 3]}}


@pytest.mark.parametrize("mapping, message", [
    ({"triads": {"accelerometer": {"columns": [1, 2]}}},
     "device.channels.triads.accelerometer.columns: expected 3 column numbers, got [1, 2]"),
    ({"triads": {"accelerometer": {"columns": [1, 2, -3]}}},
     "device.channels.triads.accelerometer.columns[2]: expected a column number (0-based integer >= 0), got -3"),
    ({"triads": {"accelerometer": {"columns": [1, 2, 3.0]}}},
     "device.channels.triads.accelerometer.columns[2]: expected a column number"),
    ({"triads": {"accelerometer": {"columns": [1, 2, 3], "scale": "1e-3"}}},
     "device.channels.triads.accelerometer.scale: expected a finite non-zero number"),
    ({"triads": {"accelerometer": {"columns": [1, 2, 3], "scale": 0}}},
     "device.channels.triads.accelerometer.scale: expected a finite non-zero number"),
    ({"triads": {"accelerometer": {"columns": [1, 2, 3], "units": "g"}}},
     "device.channels.triads.accelerometer.units: expected only the keys columns, scale, unit"),
    ({"triads": TRIADS, "time_column": 2},
     ("device.channels.triads.accelerometer.columns[1]: expected a column not used elsewhere, got 2 "
     "(also device.channels.time_column)")),
    ({"triads": TRIADS, "time_scale": -1}, "device.channels.time_scale: expected a finite number > 0"),
    ({"triads": TRIADS, "delimiter": ", "}, "device.channels.delimiter: expected one ASCII character"),
    ({"triads": TRIADS, "delimiter": "."}, "device.channels.delimiter: expected one ASCII character"),
    ({"triads": TRIADS, "comment": ""}, "device.channels.comment: expected a non-empty ASCII prefix"),
    ({"triads": TRIADS, "counter_modulus": 256},
     "device.channels.counter_modulus: expected null when counter_column is not given"),
    ({"triads": TRIADS, "counter_column": 0, "counter_modulus": 1},
     "device.channels.counter_modulus: expected an integer >= 2"),
    ({"triads": TRIADS, "temperature_column": True},
     "device.channels.temperature_column: expected a column number"),
    ({"triads": TRIADS, "colums": 1}, "device.channels.colums: expected only the keys"),
    ({}, "device.channels.triads: expected a mapping of triad name"),
    ({"triads": {"accelerometer": [1, 2, 3]}}, "device.channels.triads.accelerometer: expected a mapping"),
    ([1, 2], "device.channels: expected a mapping"),
])
def test_channel_map_errors_are_one_line_naming_the_field(mapping, message):
    with pytest.raises(ValueError) as info:
        ChannelMap.from_mapping(mapping, "device.channels")
    text = str(info.value)
    assert "\n" not in text
    assert text.startswith(message), text


def test_channel_map_is_frozen_and_constructible_directly():
    cm = ChannelMap.from_mapping({"triads": {"gyroscope": {"columns": [3, 4, 5], "scale": 2.0, "unit": "rad/s"}},
                                  "delimiter": None}, "x")
    assert cm.triads["gyroscope"] == TriadColumns((3, 4, 5), 2.0, "rad/s")
    assert cm.delimiter is None and cm.comment == "#"
    with pytest.raises(dataclasses.FrozenInstanceError):
        cm.delimiter = ","  # type: ignore[misc]
    with pytest.raises(TypeError):
        cm.triads["x"] = TriadColumns((0, 1, 2))  # type: ignore[index]
    assert ChannelMap.from_mapping(cm.to_mapping(), "y") == cm
    with pytest.raises(ValueError, match=r"^channel_map\.triads\.a\.columns: expected 3 column numbers"):
        ChannelMap(triads={"a": TriadColumns((1, 2))})  # type: ignore[arg-type]


# -- soup ---------------------------------------------------------------------------------------

SOUP_MAP = ChannelMap.from_mapping({"triads": {"a": {"columns": [0, 2, 3]}}, "time_column": 1}, "soup")
FIELDS = ["1", "-2.5", "+.5", "7.", "1e3", "", " 4 ", "x", "1.2.3", "nan", "1e999", "--1", "#", "12"]


def reference_rows(text: bytes, delimiter: str | None = ","):
    """(rows (t, ax, ay, az), malformed line numbers) by plain per-line Python; delimiter None:
    fields separated by runs of blanks."""
    rows, bad = [], []
    for no, raw in enumerate(text.split(b"\n")[:-1], start=1):
        line = raw.decode("latin-1").rstrip("\r")
        if not line.strip(" \t\r") or line.lstrip(" \t\r").startswith("#"):
            continue
        fields = ([f.strip(" \t\r") for f in line.split(",")] if delimiter else
                  re.split(r"[ \t\r]+", line.strip(" \t\r")))
        mapped = [fields[c] if c < len(fields) else None for c in (1, 0, 2, 3)]
        good = [f is not None and NUMBER.fullmatch(f) and np.isfinite(float(f)) for f in mapped]
        if all(good):
            rows.append([float(f) for f in mapped])
        elif not any(f is not None and NUMBER.fullmatch(f) and np.isfinite(float(f)) for f in mapped):
            pass  # a header line
        else:
            bad.append(no)
    return rows, bad


@st.composite
def soup_lines(draw, sep=","):
    kind = draw(st.sampled_from(["good", "good", "fields", "comment", "blank", "junk"]))
    if kind == "good":
        return sep.join(str(draw(st.integers(-999, 999)) / 8) for _ in range(draw(st.integers(4, 6)))).encode()
    if kind == "fields":
        return sep.join(draw(st.sampled_from(FIELDS)) for _ in range(draw(st.integers(1, 6)))).encode()
    if kind == "comment":
        return b"  # " + draw(st.binary(max_size=10)).replace(b"\n", b"")
    if kind == "blank":
        return draw(st.sampled_from([b"", b"  ", b"\t", b"\r"]))
    return draw(st.binary(max_size=20)).replace(b"\n", b"")


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.tuples(soup_lines(), st.sampled_from([b"\n", b"\r\n"])), max_size=15),
       st.lists(st.integers(0, 1000), max_size=5))
def test_line_soup_never_raises_and_matches_the_reference(lines, cuts):
    text = b"".join(a + b for a, b in lines)
    bounds = sorted({0, len(text), *[c % (len(text) + 1) for c in cuts]})
    p = DelimitedTextParser(SOUP_MAP, keep_malformed=1000)
    chunks = [c for c in (p.feed(text[a:b], 0.0) for a, b in itertools.pairwise(bounds)) if c is not None]
    got = [[t, *acc] for c in chunks for t, acc in zip(c.t.tolist(), c.triads["a"].tolist())]
    rows, bad = reference_rows(text)
    assert got == rows
    assert list(p.malformed_line_numbers) == bad
    assert p.counters.frames == len(rows) and p.lines == text.count(b"\n")


BLANK_SOUP_MAP = dataclasses.replace(SOUP_MAP, delimiter=None)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.tuples(soup_lines(sep=" "), st.sampled_from([b"\n", b"\r\n"])), max_size=15),
       st.integers(0, 1000))
def test_blank_separated_soup_matches_the_reference(lines, cut):
    """Blank-separated blocks of clean lines take a fast path (parsed where they lie): it must
    agree with plain Python on every mix of good lines, extra columns, comments, headers and junk."""
    text = b"".join(a + b for a, b in lines)
    cut %= len(text) + 1
    p = DelimitedTextParser(BLANK_SOUP_MAP, keep_malformed=1000)
    chunks = [c for c in (p.feed(text[:cut], 0.0), p.feed(text[cut:], 0.0)) if c is not None]
    got = [[t, *acc] for c in chunks for t, acc in zip(c.t.tolist(), c.triads["a"].tolist())]
    rows, bad = reference_rows(text, delimiter=None)
    assert got == rows
    assert list(p.malformed_line_numbers) == bad


@pytest.mark.parametrize("odd", [b"1-2", b"1..5", b"1e", b"+", b"1,5", b"0x10", b"inf"])
def test_a_clean_blank_separated_block_with_one_odd_number_loses_only_that_line(odd):
    lines = [b"%d  %d.5\t-%de3 1e%d" % (i, i, i, i % 5) for i in range(40)]
    lines[17] = b"17 " + odd + b" 3 4"
    p = DelimitedTextParser(BLANK_SOUP_MAP, keep_malformed=100)
    chunk = p.feed(b"\n".join(lines) + b"\n", 0.0)
    rows, bad = reference_rows(b"\n".join(lines) + b"\n", delimiter=None)
    assert bad == [18] and list(p.malformed_line_numbers) == [18]
    assert [[t, *a] for t, a in zip(chunk.t.tolist(), chunk.triads["a"].tolist())] == rows


@pytest.mark.parametrize("widths", [(5,), (4, 5), (5, 4, 4)])
def test_clean_blank_separated_blocks_with_unmapped_and_uneven_columns(widths):
    """A block of clean lines is parsed whole; lines of unequal width are not, and must agree."""
    lines = [b" ".join(b"%d.%d" % (i, j) for j in range(widths[i % len(widths)])) for i in range(50)]
    text = b"\r\n".join(lines) + b"\r\n"
    p = DelimitedTextParser(BLANK_SOUP_MAP)
    chunk = p.feed(text, 0.0)
    rows, bad = reference_rows(text, delimiter=None)
    assert bad == [] and p.malformed_lines == 0 and len(rows) == 50
    assert [[t, *a] for t, a in zip(chunk.t.tolist(), chunk.triads["a"].tolist())] == rows


@pytest.mark.parametrize("odd", [b"", b"1-2", b"1e", b"1 2", b" 5", b"nan", b"1;2"])
def test_a_clean_comma_block_after_its_header_with_one_odd_field_loses_only_that_line(odd):
    """A header, then comma-separated clean lines (taken whole, see _clean_delimited): an empty
    field, a field that is not one number or a blank inside a line must cost that line alone,
    and everything else must agree with plain Python."""
    lines = [b"t,a_x,a_y,a_z,T"] + [b"%d,%d.5,-%de3,1e%d,25" % (i, i, i, i % 5) for i in range(40)]
    lines[18] = b"17," + odd + b",3,4,25"
    text = b"\n".join(lines) + b"\n"
    p = DelimitedTextParser(SOUP_MAP, keep_malformed=100)
    chunk = p.feed(text, 0.0)
    rows, bad = reference_rows(text)
    assert [[t, *a] for t, a in zip(chunk.t.tolist(), chunk.triads["a"].tolist())] == rows
    assert list(p.malformed_line_numbers) == bad and p.header_lines == 1 and len(rows) >= 39


@pytest.mark.parametrize("line_end", [b"\n", b"\r\n", b" \n", b"\t \r\n", b"\r\r\n"])
def test_clean_blank_separated_lines_with_any_line_end_are_read_whole_and_alike(line_end):
    """The whole-block path knows a line's end by the "\\n" (or "\\r\\n") right after its last
    field, or, with blanks before it, by where the line ends are: every ending reads the same."""
    lines = [b"  %d.25 -%d.5e-3\t%de2 +%d" % (i, i, i, i) for i in range(30)]
    text = line_end.join(lines) + line_end
    p = DelimitedTextParser(BLANK_SOUP_MAP)
    chunk = p.feed(text, 0.0)
    rows, bad = reference_rows(text, delimiter=None)
    assert bad == [] and p.malformed_lines == 0 and len(rows) == 30
    assert [[t, *a] for t, a in zip(chunk.t.tolist(), chunk.triads["a"].tolist())] == rows
