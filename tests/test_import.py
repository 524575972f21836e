"""``fieldcal import``: text files -> Recording -> session, checked against data written here.

Every file is made in tmp_path from known arrays; the expected values, line numbers and
messages are worked out by hand in each test, not by the code under test.
"""
from __future__ import annotations

import argparse
import hashlib
import math
import re

import numpy as np
import pytest
import yaml

from fieldcal import __version__
from fieldcal.recording import Recording
from fieldcal.cli.importing import add_import_parser, main
from fieldcal.recording.import_map import ImportMapError, load_import_map
from fieldcal.recording import importer
from fieldcal.recording.importer import (
    RecordingImportError,
    import_recording,
    import_with_report,
)
from fieldcal.recording.store import (
    RecordingSessionError,
    load_recording,
    save_recording,
)
from fieldcal.session.capture import SessionError, SessionReader, SessionWriter


def triad(name, columns, kind="specific_force", unit="count", **extra):
    return {name: {"columns": columns, "kind": kind, "unit": unit, **extra}}


def entry(name, triads, time=None, delimiter=None, **extra):
    return {"name": name, "delimiter": delimiter, "time": time or {"column": 0, "unit": "s"},
            "triads": triads, **extra}


ACC = entry("accelerometer file", triad("accelerometer", [1, 2, 3]))
GYRO = entry("gyroscope file", triad("gyroscope", [1, 2, 3], kind="angular_rate"))


def write_map(tmp_path, files, name="map.yaml"):
    path = tmp_path / name
    path.write_text(yaml.safe_dump({"files": files}, sort_keys=False))
    return path


def write_rows(path, t, values, time_fmt="%r", value_fmt="%d", sep=" ", head=b""):
    """One line per sample: time then the three values, formatted with % (no numpy printing)."""
    line = sep.join([time_fmt] + [value_fmt] * 3) + "\n"
    rows = np.column_stack([np.asarray(t, float), values]).tolist()
    text = "".join(line % (r[0], *(int(x) if value_fmt == "%d" else x for x in r[1:])) for r in rows)
    path.write_bytes(head + text.encode("ascii"))
    return path


# ------------------------------------------------------------------------------------------
# values


def test_raw_integer_counts_come_back_exactly(tmp_path):
    rng = np.random.default_rng(1)
    n = 500
    t = 12.5 + np.arange(n) * 0.01 + rng.uniform(0, 1e-4, n)  # any doubles: written with repr
    counts = rng.integers(-2**31, 2**31, size=(n, 3))
    data = write_rows(tmp_path / "acc.txt", t, counts)
    rec = import_recording([data], write_map(tmp_path, [ACC]))
    assert np.array_equal(rec.t, t)  # repr round-trips a double exactly, and the scale is 1
    assert np.array_equal(rec.triads["accelerometer"], counts.astype(float))
    assert rec.kinds == {"accelerometer": "specific_force"} and rec.units == {"accelerometer": "count"}
    assert rec.sources == (str(data),) and rec.malformed == {str(data): (0, ())}


def test_csv_in_physical_units_with_scale_and_header(tmp_path):
    rng = np.random.default_rng(2)
    n = 300
    t_ms = 1000 + 4 * np.arange(n)  # 250 Hz in integer milliseconds
    acc_mg = np.round(rng.normal(0, 1000, (n, 3)), 3)
    gyro_dps = np.round(rng.normal(0, 30, (n, 3)), 4)
    lines = ["t_ms,ax_mg,ay_mg,az_mg,gx_dps,gy_dps,gz_dps,temp_C"]
    lines += [f"{t_ms[i]},{acc_mg[i, 0]:.3f},{acc_mg[i, 1]:.3f},{acc_mg[i, 2]:.3f},{gyro_dps[i, 0]:.4f},"
              f"{gyro_dps[i, 1]:.4f},{gyro_dps[i, 2]:.4f},25.0" for i in range(n)]
    data = tmp_path / "log.csv"
    data.write_text("\r\n".join(lines) + "\r\n")
    rec, report = import_with_report([data], "single-csv")  # the shipped example, by name
    np.testing.assert_allclose(rec.t, t_ms / 1000, rtol=1e-15)
    np.testing.assert_allclose(rec.triads["accelerometer"], acc_mg / 1000, rtol=1e-14, atol=0)
    np.testing.assert_allclose(rec.triads["gyroscope"], np.radians(gyro_dps), rtol=1e-14, atol=0)
    assert rec.units == {"accelerometer": "g", "gyroscope": "rad/s"}
    assert rec.kinds == {"accelerometer": "specific_force", "gyroscope": "angular_rate"}
    assert report.files[0].header_lines == 1 and report.files[0].malformed == 0
    assert rec.rate_hz == pytest.approx(250.0)


@pytest.mark.parametrize(("unit", "factor"), [("ms", 1e-3), ("us", 1e-6), ("ns", 1e-9)])
def test_time_units(tmp_path, unit, factor):
    ticks = 5_000_000_000 + np.arange(200) * round(0.01 / factor)  # 100 Hz, whole ticks
    data = write_rows(tmp_path / "a.txt", ticks, np.ones((200, 3)), time_fmt="%d")
    rec = import_recording([data], write_map(tmp_path, [entry("a", ACC["triads"],
                                                                {"column": 0, "unit": unit})]))
    np.testing.assert_allclose(rec.t, ticks * factor, rtol=1e-15)
    assert rec.rate_hz == pytest.approx(100.0, rel=1e-6)  # 5e6 s (ms) leaves ~1e-9 s resolution


def test_time_scale_instead_of_unit(tmp_path):
    ticks = np.arange(100) * 25  # 100 µs ticks: 400 Hz
    data = write_rows(tmp_path / "a.txt", ticks, np.zeros((100, 3)), time_fmt="%d")
    rec = import_recording([data], write_map(tmp_path, [entry("a", ACC["triads"],
                                                                {"column": 0, "scale": 1.0e-4})]))
    assert rec.rate_hz == pytest.approx(400.0)


# ------------------------------------------------------------------------------------------
# two files


def two_files(tmp_path, t_acc, t_gyro, acc, gyro, fmt="%.17g"):
    return [write_rows(tmp_path / "acc.txt", t_acc, acc, time_fmt="%r", value_fmt=fmt),
            write_rows(tmp_path / "gyro.txt", t_gyro, gyro, time_fmt="%r", value_fmt=fmt)]


def test_imu_tk_identical_timestamps_are_not_interpolated(tmp_path):
    rng = np.random.default_rng(3)
    t = np.arange(400) * 0.01
    acc, gyro = rng.normal(size=(400, 3)), rng.normal(size=(400, 3)) * 1e-3
    rec, report = import_with_report(two_files(tmp_path, t, t, acc, gyro), "imu_tk")
    assert np.array_equal(rec.t, t)
    assert np.array_equal(rec.triads["accelerometer"], acc)  # %.17g: bit for bit
    assert np.array_equal(rec.triads["gyroscope"], gyro)
    assert report.alignment == ("time base: accelerometer file",
                                "gyroscope file: same timestamps, values used as they are")


def test_imu_tk_offset_timestamps_are_interpolated_onto_the_first_file(tmp_path):
    # The gyroscope runs at its own 97 Hz, starting 0.123 s later; its signal is linear in time,
    # so linear interpolation must give it exactly (to rounding) at the accelerometer's times.
    t_acc = np.arange(1000) * 0.01  # 0 .. 9.99 s
    t_gyro = 0.123 + np.arange(900) / 97.0  # 0.123 .. 9.391 s
    slope, offset = np.array([0.5, -2.0, 3.0]), np.array([1.0, 2.0, -3.0])
    gyro = offset + np.outer(t_gyro, slope)
    acc = np.tile([1.0, 2.0, 3.0], (1000, 1))
    rec, report = import_with_report(two_files(tmp_path, t_acc, t_gyro, acc, gyro), "imu_tk")
    inside = (t_acc >= t_gyro[0]) & (t_acc <= t_gyro[-1])
    assert np.array_equal(rec.t, t_acc[13:940])  # 0.13 .. 9.39 s
    np.testing.assert_allclose(rec.triads["gyroscope"], offset + np.outer(rec.t, slope), rtol=0, atol=1e-12)
    assert np.array_equal(rec.triads["accelerometer"], acc[inside])
    assert "interpolated linearly" in report.alignment[1]
    assert "73 samples outside" in report.alignment[0]  # 13 before 0.123 s and 60 after 9.391 s


def test_files_that_barely_overlap_are_refused(tmp_path):
    t = np.arange(100) * 0.01
    files = two_files(tmp_path, t, t + 0.9, np.zeros((100, 3)), np.zeros((100, 3)))
    with pytest.raises(RecordingImportError, match=r"overlap in time for only 0\.09 s"):
        import_recording(files, "imu_tk")
    files = two_files(tmp_path, t, t + 100, np.zeros((100, 3)), np.zeros((100, 3)))
    with pytest.raises(RecordingImportError, match=r"overlap in time for only 0 s"):
        import_recording(files, "imu_tk")


def test_file_count_must_match_the_map(tmp_path):
    data = write_rows(tmp_path / "a.txt", np.arange(3), np.zeros((3, 3)))
    with pytest.raises(RecordingImportError) as exc:
        import_recording([data], "imu_tk")
    assert str(exc.value) == "imu_tk.yaml expects 2 files (accelerometer file, gyroscope file), got 1"
    with pytest.raises(RecordingImportError, match="given twice"):
        import_recording([data, data], "imu_tk")


# ------------------------------------------------------------------------------------------
# bad lines and bad time


def test_malformed_lines_are_counted_with_their_line_numbers(tmp_path):
    lines = [
        b"\x00\x01\x02",            # 1  binary junk before the data: malformed, not a header
        b"# logger 1.0",            # 2  comment
        b"time ax ay az",           # 3  header
        b"0.00 1 2 3",              # 4  sample
        b"",                        # 5  blank
        b"0.01 4 5 6",              # 6  sample
        b"hello world foo bar",     # 7  text after the data (the parser alone: a header)
        b"0.02 7 8",                # 8  a field missing
        b"0.03 nan 1 2",            # 9  NaN
        b"0.04 \x00\xff\xfe 1 2",   # 10 binary bytes in a field
        b"\xff\xfe\xfd\xfc",        # 11 not UTF-8 at all
        b"0.05 1e999 1 2",          # 12 overflows to inf
        b"0.06 10 11 12",           # 13 sample
        b"0.07,13,14,15",           # 14 wrong delimiter
        b"   # indented comment",   # 15 comment
        b"\x00\x00\x00\x00",        # 16 NULs
        b"0.08 16 17 18\r",         # 17 sample, CRLF
        b"0.09 19 20 21",           # 18 no final newline: cut off mid-write, malformed
    ]
    data = tmp_path / "acc.txt"
    data.write_bytes(b"\n".join(lines))
    rec, report = import_with_report([data], write_map(tmp_path, [ACC]))
    expected_bad = (1, 7, 8, 9, 10, 11, 12, 14, 16, 18)
    assert rec.malformed == {str(data): (10, expected_bad)}
    assert np.array_equal(rec.t, [0.0, 0.01, 0.06, 0.08])
    assert np.array_equal(rec.triads["accelerometer"], [[1, 2, 3], [4, 5, 6], [10, 11, 12],
                                                        [16, 17, 18]])
    f = report.files[0]
    assert (f.lines, f.samples, f.header_lines, f.malformed, f.cut_off) == (18, 4, 1, 10, True)
    assert report.warnings and report.warnings[0].startswith(f"{data}: 10 of 14 data lines (71.4 %)")


NUMBER = re.compile(rb"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?")
CONTROL = re.compile(rb"[\x00-\x08\x0a-\x0c\x0e-\x1f\x7f]")


def reference_lines(data: bytes, delimiter: str | None, comment: str | None):
    """Per line, by str methods and a regex: (line, time) of the samples, malformed line
    numbers, and header lines (text with no number in a mapped field, before any sample)."""

    def number(f):
        return f is not None and NUMBER.fullmatch(f) is not None and math.isfinite(float(f))

    def floatable(f):  # a line of numbers only is a sample line with too few columns, no header
        try:
            float(f)
        except ValueError:
            return False
        return True

    samples, bad, headers = [], [], 0
    for no, line in enumerate(data.split(b"\n")[:-1], 1):
        bare = line.strip(b" \t\r")
        if not bare or (comment and bare.startswith(comment.encode())):
            continue
        fields = (re.split(rb"[ \t\r]+", bare) if delimiter is None
                  else [f.strip(b" \t\r") for f in line.rstrip(b"\r").split(delimiter.encode())])
        mapped = [fields[c] if c < len(fields) else None for c in range(4)]
        if all(number(f) for f in mapped):
            samples.append((no, float(mapped[0])))
        elif not samples and not CONTROL.search(line) \
                and line.decode("utf-8", "replace") == line.decode("utf-8", "ignore") \
                and any(f and not floatable(f) for f in fields):
            headers += 1  # text before the data, with a word in it: a header or metadata line
        else:
            bad.append(no)
    return samples, bad, headers


def test_random_junk_is_classified_line_by_line_like_a_reference(tmp_path):
    rng = np.random.default_rng(6)
    junk = [b"", b" ", b"\t", b"#", b"//", b"/", b",", b";", b"nan", b"inf", b"1e999", b"-", b".",
            b"+", b"e", b"\x00", b"\xff", b"\xc3\xa9", b"abc", b"1", b"2.5", b"-3"]
    layouts = [(d, c) for d in (None, ",", ";") for c in ("#", "//", None)]
    maps = [write_map(tmp_path, [entry("f", ACC["triads"], delimiter=d, comment=c)], f"m{i}.yaml")
            for i, (d, c) in enumerate(layouts)]
    for trial in range(300):
        delimiter, comment = layouts[trial % len(layouts)]
        import_map = load_import_map(maps[trial % len(layouts)])
        sep = (delimiter or " ").encode()
        lines = [sep.join([repr(i / 64).encode(), b"1", b"-2.5", b"3e2"]) + b"\r" * (rng.random() < 0.2)
                 if rng.random() < 0.6 else b"".join(rng.choice(junk, rng.integers(0, 8)))
                 for i in range(rng.integers(2, 30))]
        data = b"\n".join(lines) + b"\n" * (rng.random() < 0.5)
        (tmp_path / "f.txt").write_bytes(data)
        last = data.rsplit(b"\n", 1)[-1].strip(b" \t\r")
        cut_off = bool(last) and not (comment and last.startswith(comment.encode()))
        # A last line with no line end is cut off: malformed, whatever it holds.
        samples, bad, headers = reference_lines(data.rsplit(b"\n", 1)[0] + b"\n" if cut_off else
                                                data if data.endswith(b"\n") else data + b"\n",
                                                delimiter, comment)
        if cut_off:
            bad.append(data.count(b"\n") + 1)
        if len(samples) < 2:
            with pytest.raises(RecordingImportError, match="valid sample"):
                import_recording([tmp_path / "f.txt"], import_map)
            continue
        rec, report = import_with_report([tmp_path / "f.txt"], import_map)
        f = report.files[0]
        assert np.array_equal(rec.t, [t for _, t in samples]), data
        assert (f.malformed, f.malformed_lines, f.header_lines) == (len(bad), tuple(bad[:10]), headers), data


def test_files_parsed_in_pieces_are_classified_as_whole(tmp_path, monkeypatch):
    """A file bigger than FEED_BYTES is fed to the parser in pieces of whole lines: with pieces
    of 16 bytes (one line or two each) every line is still classified like the reference."""
    monkeypatch.setattr(importer, "FEED_BYTES", 16)
    test_random_junk_is_classified_line_by_line_like_a_reference(tmp_path)
    test_malformed_lines_are_counted_with_their_line_numbers(tmp_path)


def test_only_the_first_few_malformed_line_numbers_are_kept_but_all_are_counted(tmp_path):
    good = [f"{i * 0.01!r} 1 2 3" for i in range(1000)]
    for k in range(25):  # a garbage line after every 40th sample
        good.insert(40 * k + k + 1, "garbage!")
    data = tmp_path / "a.txt"
    data.write_text("\n".join(good) + "\n")
    rec = import_recording([data], write_map(tmp_path, [ACC]))
    count, first = rec.malformed[str(data)]
    assert count == 25 and first == tuple(41 * k + 2 for k in range(10))
    assert len(rec.t) == 1000


@pytest.mark.parametrize(("bad", "warns"), [(10, False), (11, True)])  # of 1000 data lines: 1 % is fine
def test_more_than_one_percent_malformed_warns(tmp_path, bad, warns):
    rows = [f"{i * 0.01!r} 1 2 3" for i in range(1000 - bad)] + ["1 2"] * bad
    data = tmp_path / "a.txt"
    data.write_text("\n".join(rows) + "\n")
    _, report = import_with_report([data], write_map(tmp_path, [ACC]))
    assert report.files[0].malformed == bad
    assert bool(report.warnings) == warns


@pytest.mark.parametrize(("times", "line", "count"), [
    ([0.0, 0.01, 0.02, 0.02, 0.03], 5, 1),   # a repeated timestamp (after the header line)
    ([0.0, 0.01, 0.02, 0.015, 0.03], 5, 1),  # backwards
    ([0.0, 0.01, 0.0, 0.0, 0.02], 4, 2),     # back, then repeated: the first is named, both counted
])
def test_time_must_increase_strictly(tmp_path, times, line, count):
    data = write_rows(tmp_path / "a.txt", times, np.zeros((5, 3)), head=b"t x y z\n")
    with pytest.raises(RecordingImportError) as exc:
        import_recording([data], write_map(tmp_path, [ACC]))
    message = str(exc.value)
    assert message.startswith(f"{data}: line {line}: time ") and "\n" not in message
    assert f"({count} such line" in message and exc.value.line == line


def test_a_file_without_samples_is_an_error_naming_it(tmp_path):
    data = tmp_path / "empty.txt"
    data.write_bytes(b"time,x,y,z\n1,2,3,4\n")  # commas, but the map says blanks
    with pytest.raises(RecordingImportError, match=rf"^{data}: no valid sample for accelerometer file"):
        import_recording([data], write_map(tmp_path, [ACC]))
    (tmp_path / "nothing.txt").write_bytes(b"")
    with pytest.raises(RecordingImportError, match="nothing.txt: no valid sample"):
        import_recording([tmp_path / "nothing.txt"], write_map(tmp_path, [ACC]))


def test_gaps_are_reported(tmp_path):
    t = np.concatenate([np.arange(100) * 0.01, 1.5 + np.arange(100) * 0.01, 3.0 + np.arange(10) * 0.01])
    data = write_rows(tmp_path / "a.txt", t, np.zeros((210, 3)))
    rec, report = import_with_report([data], write_map(tmp_path, [ACC]))
    f = report.files[0]
    assert f.gaps == 2 and f.largest_gap_s == pytest.approx(0.51) and f.largest_gap_line == 101
    assert len(rec.t) == 210


# ------------------------------------------------------------------------------------------
# the map


GOOD = [ACC, GYRO]


def mutate(path, value):
    files = yaml.safe_load(yaml.safe_dump(GOOD))
    node = files
    for key in path[:-1]:
        node = node[key]
    if value is KeyError:
        del node[path[-1]]
    else:
        node[path[-1]] = value
    return files


@pytest.mark.parametrize(("path", "value", "field"), [
    ((0, "time", "column"), "", "files[0].time.column: expected a column number"),
    ((0, "rate_hz"), 100, "files[0].rate_hz: expected no rate_hz when the file has a time column"),
    ((0, "time", "unit"), "minutes", "files[0].time.unit: expected 's' or 'ms'"),
    ((0, "time", "scale"), 1.0e-3, "files[0].time: expected either unit"),
    ((1, "time", "column"), -1, "files[1].time.column: expected a column number"),
    ((0, "triads", "accelerometer", "kind"), "acceleration", "files[0].triads.accelerometer.kind"),
    ((0, "triads", "accelerometer", "columns"), [1, 2], "files[0].triads.accelerometer.columns: expected 3"),
    ((0, "triads", "accelerometer", "columns"), [0, 2, 3],
     "files[0].triads.accelerometer.columns[0]: expected a column not used elsewhere"),
    ((1, "triads", "gyroscope", "columns"), [1, 2, 2], "files[1].triads.gyroscope.columns[2]"),
    ((1, "triads", "gyroscope", "unit"), "m/s^2", "files[1].triads.gyroscope.unit: expected a unit of angular rate"),
    ((1, "triads", "gyroscope", "scale"), "1e-3", "files[1].triads.gyroscope.scale"),
    ((0, "triads", "accelerometer", "units"), "g", "files[0].triads.accelerometer.units: unknown key 'units'; did you mean 'unit'?"),
    ((0, "delimiter"), ";;", "files[0].delimiter: expected one ASCII character"),
    ((1, "triads"), {"accelerometer": {"columns": [1, 2, 3], "kind": "specific_force", "unit": "g"}},
     "files[1].triads.accelerometer: expected a triad name not used by another file"),
    ((1, "name"), "accelerometer file", "files[1].name: expected a name not used by another file"),
])
def test_map_errors_name_the_file_and_field(tmp_path, path, value, field):
    map_path = write_map(tmp_path, mutate(path, value))
    with pytest.raises(ImportMapError) as exc:
        load_import_map(map_path)
    message = str(exc.value)
    assert message.startswith(f"{map_path}: {field}") and "\n" not in message


@pytest.mark.parametrize(("text", "expected"), [
    ("files: []\n", "files: expected a list of files"),
    ("file:\n  - {}\n", "file: unknown key 'file'; did you mean 'files'? (line 1)"),
    ("files:\n  - name: a\n    name: b\n", "not valid YAML (line 3: key 'name' appears twice"),
    ("files: [\n", "not valid YAML (line 2"),
])
def test_map_document_errors(tmp_path, text, expected):
    (tmp_path / "m.yaml").write_text(text)
    with pytest.raises(ImportMapError) as exc:
        load_import_map(tmp_path / "m.yaml")
    assert str(exc.value).startswith(f"{tmp_path / 'm.yaml'}: {expected}")


def test_shipped_maps_load_by_name_and_unknown_names_list_them():
    assert load_import_map("imu_tk").file_names == ("accelerometer file", "gyroscope file")
    assert load_import_map("single-csv").file_names == ("CSV log",)
    with pytest.raises(ImportMapError, match=r"^imu-tk: no such import map .*imu_tk, imucal, mpu6050, single-csv"):
        load_import_map("imu-tk")


# ------------------------------------------------------------------------------------------
# sessions


def bits(a):
    return np.ascontiguousarray(a).view(np.uint64)


def test_session_round_trip_is_bit_identical(tmp_path):
    rng = np.random.default_rng(4)
    n = 25_001  # three whole chunks and a partial one
    values = rng.normal(size=(n, 3)) * 10.0 ** rng.integers(-300, 300, (n, 3))
    values[0] = [-0.0, 5e-324, np.nextafter(1.0, 2.0)]
    rec = Recording(t=np.cumsum(rng.uniform(0.001, 0.01, n)), triads={"acc": values, "gyro": values[::-1].copy()},
                    kinds={"acc": "specific_force", "gyro": "angular_rate"}, units={"acc": "g", "gyro": "count"},
                    sources=("a.txt", "b.txt"), malformed={"a.txt": (3, (4, 5, 9)), "b.txt": (0, ())})
    save_recording(rec, tmp_path / "s", {"operator": "test"})
    back = load_recording(tmp_path / "s")
    assert np.array_equal(bits(back.t), bits(rec.t))
    for name in rec.triads:
        assert np.array_equal(bits(back.triads[name]), bits(rec.triads[name]))
    assert (back.kinds, back.units, back.sources, back.malformed) == (rec.kinds, rec.units, rec.sources,
                                                                      rec.malformed)
    reader = SessionReader(tmp_path / "s")
    assert reader.n_chunks == 3 and reader.stop_reason == "imported"
    assert reader.start["operator"] == "test" and reader.start["kind"] == "recording"


def test_session_metadata_traces_the_sources(tmp_path):
    t = np.arange(50) * 0.01
    files = two_files(tmp_path, t, t, np.ones((50, 3)), np.zeros((50, 3)))
    rec, report = import_with_report(files, "imu_tk")
    save_recording(rec, tmp_path / "s", report=report)
    meta = SessionReader(tmp_path / "s").start
    assert meta["software"] == f"fieldcal {__version__}"
    assert meta["triads"] == {"accelerometer": {"kind": "specific_force", "unit": "count"},
                              "gyroscope": {"kind": "angular_rate", "unit": "count"}}
    assert [s["sha256"] for s in meta["sources"]] == [hashlib.sha256(f.read_bytes()).hexdigest() for f in files]
    assert [s["malformed"] for s in meta["sources"]] == [0, 0]
    assert meta["import_map"]["text"].startswith("# imu_tk layout")
    assert meta["rate_hz"] == pytest.approx(100.0) and meta["n_samples"] == 50


def test_loading_other_directories_is_a_one_line_error(tmp_path):
    with SessionWriter.create(tmp_path / "proc", {"procedure": {"name": "field-18"}}) as w:
        w.stop("completed")
    with pytest.raises(RecordingSessionError, match=r"not a recording session \(a procedure session "
                                                    r"\(field-18\)\)"):
        load_recording(tmp_path / "proc")
    (tmp_path / "plain").mkdir()
    with pytest.raises(SessionError, match="not a session directory"):
        load_recording(tmp_path / "plain")
    with SessionWriter.create(tmp_path / "broken", {"kind": "recording"}):
        pass  # an import that never stopped
    with pytest.raises(RecordingSessionError, match="the import did not finish"):
        load_recording(tmp_path / "broken")


# ------------------------------------------------------------------------------------------
# the command


def test_parser_wiring(tmp_path):
    parser = argparse.ArgumentParser()
    add_import_parser(parser.add_subparsers())
    t = np.arange(20) * 0.01
    files = two_files(tmp_path, t, t, np.ones((20, 3)), np.zeros((20, 3)))
    args = parser.parse_args(["import", *map(str, files), "--map", "imu_tk", "--out", str(tmp_path / "s")])
    assert args.func(args) == 0
    assert len(load_recording(tmp_path / "s").t) == 20


def test_cli_summary(tmp_path, capsys):
    t_acc, t_gyro = np.arange(300) * 0.01, 0.005 + np.arange(300) * 0.01
    files = two_files(tmp_path, t_acc, t_gyro, np.ones((300, 3)), np.zeros((300, 3)), fmt="%d")
    with open(files[1], "ab") as fh:
        fh.write(b"junk\n")  # line 301
    assert main([*map(str, files), "--map", "imu_tk", "--out", str(tmp_path / "s")]) == 0
    out = capsys.readouterr().out
    assert f"accelerometer file: {files[0]}: 300 samples of 300 lines, 100 Hz, t 0 .. 2.99 s" in out
    assert "gyroscope file: " in out and "1 malformed line not used: 301\n" in out
    assert "gyroscope file: other timestamps (100 Hz), interpolated linearly" in out
    assert "recording: 299 samples, 100 Hz, 2.98 s; accelerometer (specific_force, count)" in out
    assert out.rstrip().endswith(f"session: {tmp_path / 's'}")


def run_failing(capsys, argv):
    code = main(argv)
    captured = capsys.readouterr()
    assert code == 2 and captured.out == ""
    lines = captured.err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("fieldcal: ") and "Traceback" not in captured.err
    return lines[0]


def test_cli_errors_are_one_line(tmp_path, capsys):
    t = np.arange(20) * 0.01
    files = [str(f) for f in two_files(tmp_path, t, t, np.ones((20, 3)), np.zeros((20, 3)))]
    (tmp_path / "taken").mkdir()
    (tmp_path / "taken" / "x").write_text("")
    assert "taken: already exists and is not empty" in run_failing(
        capsys, [*files, "--map", "imu_tk", "--out", str(tmp_path / "taken")])
    bad_map = write_map(tmp_path, mutate((1, "triads", "gyroscope", "kind"), "rate"), "bad.yaml")
    assert f"{bad_map}: files[1].triads.gyroscope.kind: expected" in run_failing(
        capsys, [*files, "--map", str(bad_map), "--out", str(tmp_path / "s1")])
    assert "missing.txt: cannot read gyroscope file (No such file or directory)" in run_failing(
        capsys, [files[0], str(tmp_path / "missing.txt"), "--map", "imu_tk", "--out", str(tmp_path / "s2")])
    assert "expects 2 files" in run_failing(capsys, [files[0], "--map", "imu_tk", "--out", str(tmp_path / "s3")])
    assert not any((tmp_path / d).exists() for d in ("s1", "s2", "s3"))  # nothing written on failure


def test_cli_help_has_an_example(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert "fieldcal import acc.txt gyro.txt --map imu_tk --out" in out and "--map MAP" in out


# ------------------------------------------------------------------------------------------
# two files on two clocks (import speed: benchmarks/io.py)


def test_two_files_join_on_the_later_start(tmp_path):
    n = 600
    rng = np.random.default_rng(5)
    t = np.arange(n) * 0.01
    files = [write_rows(tmp_path / "acc.txt", t, rng.integers(-32768, 32768, (n, 3)), time_fmt="%.4f"),
             write_rows(tmp_path / "gyro.txt", t + 0.002, rng.integers(-32768, 32768, (n, 3)), time_fmt="%.4f")]
    rec = import_recording(files, "imu_tk")
    assert len(rec.t) == n - 1  # the first accelerometer sample is before the gyroscope's first


def test_metadata_lines_named_columns_and_no_time_column(tmp_path):
    """A logger's export: metadata lines, then a header naming the columns, no time column.
    The columns are found by name wherever they are, the samples are 1 / rate apart."""
    rng = np.random.default_rng(3)
    acc, gyro = rng.normal(0, 1, (50, 3)), rng.normal(0, 1, (50, 3))
    rows = "".join(f"{i},{g[0]!r},{g[1]!r},{g[2]!r},{a[0]!r},{a[1]!r},{a[2]!r}\n"
                   for i, (a, g) in enumerate(zip(acc.tolist(), gyro.tolist())))
    data = tmp_path / "log.csv"
    data.write_text("Fs,100\nDevice,unit 7\nn,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z\n" + rows)
    named = {"name": "log", "delimiter": ",",
             "triads": {"accelerometer": {"columns": ["acc_x", "acc_y", "acc_z"], "kind": "specific_force",
                                          "unit": "g", "scale": 1e-3},
                        "gyroscope": {"columns": ["gyr_x", "gyr_y", "gyr_z"], "kind": "angular_rate",
                                      "unit": "deg/s"}}}
    rec, report = import_with_report([data], write_map(tmp_path, [dict(named, rate_hz=100)]))
    np.testing.assert_array_equal(rec.triads["accelerometer"], acc * 1e-3)
    np.testing.assert_array_equal(rec.triads["gyroscope"], gyro)
    np.testing.assert_allclose(rec.t, np.arange(50) / 100, rtol=0, atol=1e-15)
    assert (report.files[0].header_lines, report.files[0].malformed) == (3, 0)
    assert rec.units == {"accelerometer": "g", "gyroscope": "deg/s"}
    # The rate given at import overrides the map's; without either the file cannot be timed.
    assert import_recording([data], write_map(tmp_path, [named], "bare.yaml"), rate_hz=50).rate_hz == pytest.approx(50)
    with pytest.raises(RecordingImportError, match=r"has no time column: give its sample rate \(--rate HZ"):
        import_recording([data], write_map(tmp_path, [named], "bare.yaml"))
    wrong = dict(named, triads={"accelerometer": dict(named["triads"]["accelerometer"], columns=["ax", "ay", "az"])})
    with pytest.raises(RecordingImportError, match=r"no header line names the columns ax, ay, az"):
        import_recording([data], write_map(tmp_path, [wrong], "wrong.yaml"), rate_hz=100)


def test_fieldcal_import_reports_a_cut_off_last_line(tmp_path, capsys):
    data = write_rows(tmp_path / "acc.txt", [0.0, 0.01, 0.02], [[1, 2, 3]] * 3)
    data.write_bytes(data.read_bytes() + b"0.03 1 2 3.")  # cut off mid-write
    assert main([str(data), "--map", str(write_map(tmp_path, [ACC])), "--out", str(tmp_path / "s")]) == 0
    out = capsys.readouterr().out
    assert "1 malformed line not used: 4 (line 4 has no line end: cut off mid-write?)" in out


def test_stray_text_lines_are_found_in_one_parse(tmp_path, monkeypatch):
    """Issue 25 round 4, item 5: a text line after every other sample made the import quadratic
    (13.7 MB: 176 s, 423 MB): the header lines were found again by re-parsing halves of the file
    per stray line. The parser now says which lines it calls headers as it reads them: every byte
    is parsed once, and the stray lines are still malformed, by number."""
    from drivers.protocols.delimited import DelimitedTextParser

    fed = []
    feed = DelimitedTextParser.feed
    monkeypatch.setattr(DelimitedTextParser, "feed", lambda self, data, t: fed.append(len(data)) or feed(self, data, t))
    rows = []
    for i in range(4000):
        rows.append(f"{i * 0.01:.3f},1,2,3,4,5,6\n")
        if i % 2:
            rows.append("abc\n")
    path = tmp_path / "interleaved.csv"
    path.write_text("".join(rows))
    rec, report = import_with_report([path], "single-csv")
    assert sum(fed) == path.stat().st_size  # once, not once per halving
    [file] = report.files
    assert file.samples == 4000 and file.malformed == 2000 and file.header_lines == 0
    assert file.malformed_lines == tuple(3 * k + 3 for k in range(10))  # "abc" after samples 2, 4, ...: lines 3, 6, ...
    np.testing.assert_allclose(rec.t, np.arange(4000) * 1e-5)  # the map reads time in ms
