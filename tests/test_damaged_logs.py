"""Issue 25, items 7, 8 and 16: a damaged binary log is refused or imported with its damage
counted and named, never as a short clean recording; the parsers' own noise is one line.

Truth: the intact real logs (pymavlink's test.BIN, PX4's sample ULog). Every sample imported
from a damaged copy must be a sample of the intact log, and what was lost must be said."""
from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("pymavlink")
pytest.importorskip("pyulog")
from pymavlink import DFReader  # noqa: E402

from fieldcal.cli.main import main  # noqa: E402
from fieldcal.recording.logs import _wild_timestamps, import_log  # noqa: E402
from xsens_logs import unpacked  # noqa: E402


@pytest.fixture(scope="module")
def real_bin(tmp_path_factory):
    return unpacked(tmp_path_factory.mktemp("df"), "pymavlink_test.BIN.gz", "test.BIN")


@pytest.fixture(scope="module")
def real_ulg(tmp_path_factory):
    return unpacked(tmp_path_factory.mktemp("ulg"), "px4_sample_log_small.ulg.gz", "log.ulg")


def _rows(recording):
    return np.column_stack([recording.t, recording.triads["accelerometer"], recording.triads["gyroscope"]])


def _subset_of(damaged, intact, fraction: float = 1.0) -> bool:
    """At least ``fraction`` of the rows of ``damaged`` are rows of ``intact``."""
    known = {tuple(r) for r in _rows(intact).tolist()}
    return sum(tuple(r) in known for r in _rows(damaged).tolist()) >= fraction * len(damaged.t)


def _imu_offsets(path):
    log = DFReader.DFReader_binary(str(path))
    offsets = list(log.offsets[log.name_to_id["IMU"]])
    unused = next(t for t in range(255, 0, -1) if t not in log.formats)
    log.close()
    return offsets, unused


def _import(argv, capfd):
    status = main(argv)
    out, err = capfd.readouterr()
    return status, out, err


def test_junk_between_dataflash_messages_is_counted_and_named(real_bin, tmp_path, capfd):
    data = real_bin.read_bytes()
    at = _imu_offsets(real_bin)[0][20]
    damaged = tmp_path / "junk.BIN"
    damaged.write_bytes(data[:at] + bytes(range(1, 32)) + data[at:])  # 31 bytes, no header among them
    status, out, err = _import(["import", str(damaged), "--out", str(tmp_path / "s")], capfd)
    assert status == 0 and err == ""  # no "bad header" line per byte from pymavlink's C indexer
    assert f"WARNING: {damaged}: DAMAGED" in out and "31 bytes between messages had no message header" in out
    assert f"the first at byte {at}" in out
    intact, _ = import_log(real_bin)
    recording, _ = import_log(damaged)
    assert _subset_of(recording, intact) and len(recording.t) == len(intact.t)


def test_an_unknown_message_type_stops_reading_and_says_how_much_was_lost(real_bin, tmp_path, capfd):
    """200 flipped bytes gave "2 samples of 2 lines ... no malformed lines", exit 0."""
    data = bytearray(real_bin.read_bytes())
    offsets, unused = _imu_offsets(real_bin)
    at = offsets[10]
    data[at + 2] = unused  # the message's type: one no FMT message defines
    damaged = tmp_path / "typed.BIN"
    damaged.write_bytes(bytes(data))
    status, out, err = _import(["import", str(damaged), "--out", str(tmp_path / "s")], capfd)
    assert status == 0 and err == ""
    assert f"reading stopped at byte {at}" in out and f"the last {len(data) - at} of its {len(data)} bytes" in out
    intact, _ = import_log(real_bin)
    recording, report = import_log(damaged)
    assert _subset_of(recording, intact) and len(recording.t) == 10 < len(intact.t)
    assert report.warnings and "DAMAGED" in report.warnings[0]


def test_a_dataflash_log_cut_in_half_says_so(real_bin, tmp_path, capfd):
    """Half the file gave 5 of 45 samples with no note."""
    data = real_bin.read_bytes()
    half = tmp_path / "half.BIN"
    half.write_bytes(data[:len(data) // 2])
    status, out, _ = _import(["import", str(half), "--out", str(tmp_path / "s")], capfd)
    assert status == 0 and "the log ends inside its last message" in out


def test_garbage_named_bin_is_one_line_without_pymavlinks_noise(tmp_path, capfd):
    rng = np.random.default_rng(3)
    for name, head in (("garbage.BIN", b""), ("headed.BIN", b"\xa3\x95\x80")):
        path = tmp_path / name
        path.write_bytes(head + rng.integers(0, 256, 60000, dtype=np.uint8).tobytes())
        status, out, err = _import(["import", str(path), "--out", str(tmp_path / "s")], capfd)
        assert status == 2 and out == "" and err.count("\n") == 1 and "bad header" not in err, err[:500]
        assert err.startswith(f"fieldcal: {path}: not a")


def test_a_damaged_ulog_keeps_its_real_time_and_says_it_is_damaged(real_ulg, tmp_path, capfd):
    """200 flipped bytes made a 580,000-year recording whose later samples were all dropped as
    "repeated timestamps", with an empty malformed list and no word of damage."""
    data = bytearray(real_ulg.read_bytes())
    rng = np.random.default_rng(1)
    for i in rng.choice(len(data), 200, replace=False):
        data[i] ^= 0xFF
    damaged = tmp_path / "damaged.ulg"
    damaged.write_bytes(bytes(data))
    intact, _ = import_log(real_ulg)
    status, out, err = _import(["import", str(damaged), "--out", str(tmp_path / "s")], capfd)
    if status == 2:  # refused: in one line that says it is damaged
        assert err.count("\n") == 1 and "damaged" in err
        return
    assert status == 0 and err == "" and "Warning: no subscription" not in out.split("WARNING")[0]
    assert f"WARNING: {damaged}: DAMAGED" in out
    recording, report = import_log(damaged)
    # bytes flipped inside a sample's values cannot be told (ULog has no checksum): the rest are the log's
    assert _subset_of(recording, intact, 0.95)
    assert recording.t[-1] <= intact.t[-1] and recording.t[0] >= intact.t[0]
    assert len(recording.t) > 0.5 * len(intact.t)  # one wild time no longer drops everything after it
    [file] = report.files
    assert file.malformed == file.lines - file.samples and len(file.malformed_lines) == min(file.malformed, 10)


def test_wild_timestamps_only_where_time_does_not_increase():
    t = np.r_[np.arange(0, 10, 0.01), 1e5 + np.arange(0, 0.1, 0.01)]  # a long gap: time still increases
    usable = np.ones(len(t), dtype=bool)
    assert not _wild_timestamps(t, usable).any()
    t_damaged = t[:1000].copy()
    t_damaged[[300, 700]] = [1.8e13, -5e9]
    wild = _wild_timestamps(t_damaged, np.ones(1000, dtype=bool))
    assert np.flatnonzero(wild).tolist() == [300, 700]


def test_a_zero_end_is_said_as_such_not_as_damage(real_bin, real_ulg, tmp_path):
    """A pre-allocated log file's unused end: the DataFlash log imports whole with a note; pyulog
    calls it corruption, which the warning then explains."""
    at = _imu_offsets(real_bin)[0][-1]  # a message's start: whole messages before it
    whole = tmp_path / "whole.BIN"
    whole.write_bytes(real_bin.read_bytes()[:at])
    path = tmp_path / "prealloc.BIN"
    path.write_bytes(whole.read_bytes() + bytes(40000))
    recording, report = import_log(path)
    assert np.array_equal(_rows(recording), _rows(import_log(whole)[0])) and report.warnings == ()
    assert "its last 40000 bytes are zeros (a pre-allocated file's unused end?): not read" in report.alignment
    path = tmp_path / "prealloc.ulg"
    path.write_bytes(real_ulg.read_bytes() + bytes(300000))
    recording, report = import_log(path)
    assert "its last 300000 bytes are zeros" in report.warnings[0]
    assert _subset_of(recording, import_log(real_ulg)[0])


def _message_ends(data: bytes) -> set[int]:
    """Where each ULog message ends, walked from the 16-byte file header by the format's own rule
    (a 3-byte header: msg_size uint16 little-endian, msg_type; then msg_size bytes)."""
    ends, at = set(), 16
    while at + 3 <= len(data):
        at += 3 + int.from_bytes(data[at:at + 2], "little")
        ends.add(at)
    return ends


@pytest.mark.parametrize("fraction", [0.25, 0.5, 0.9, 0.999])
def test_a_truncated_ulog_says_it_is_damaged(real_ulg, tmp_path, capfd, fraction):
    """Issue 25 round 4, item 3: a ULog cut short imported as a short clean recording ("595
    samples of 595 read ... every sample used", exit 0): pyulog stops there without a word."""
    data = real_ulg.read_bytes()
    cut = int(len(data) * fraction)
    assert cut not in _message_ends(data)  # the cut is inside a message (else it would be a whole, shorter log)
    path = tmp_path / "half.ulg"
    path.write_bytes(data[:cut])
    intact, _ = import_log(real_ulg)
    status, out, err = _import(["import", str(path), "--out", str(tmp_path / "s")], capfd)
    if status == 2:  # too little left to calibrate from: refused in one line that says why
        assert err.count("\n") == 1 and "the log ends inside its last message" in err
        return
    assert status == 0 and f"WARNING: {path}: DAMAGED" in out
    assert "the log ends inside its last message (at byte " in out and "cut short?)" in out
    recording, _ = import_log(path)
    assert _subset_of(recording, intact) and len(recording.t) < len(intact.t)


def test_a_ulog_cut_between_messages_is_no_cut_off_message(real_ulg, tmp_path):
    """The check is about a message cut in two, not about the log's length: cut exactly at a
    message's end, the log reads as a whole shorter log."""
    data = real_ulg.read_bytes()
    end = max(e for e in _message_ends(data) if e <= len(data) // 2)
    path = tmp_path / "whole-messages.ulg"
    path.write_bytes(data[:end])
    _, report = import_log(path)
    assert not any("ends inside its last message" in w for w in report.warnings)
    assert not import_log(real_ulg)[1].warnings  # nor the intact log
