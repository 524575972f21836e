"""ArduPilot DataFlash logs, indexed by pymavlink's DFReader: pymavlink's own real test log (the
older layout, IMU and IMU2 by name; see tests/data/real/README.md) and logs written here in the
current layout (an instance column) from imu_tk's real Xsens recording."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pymavlink")
from pymavlink import DFReader  # noqa: E402

from fieldcal.cli.main import main  # noqa: E402
from fieldcal.recording.importer import RecordingImportError  # noqa: E402
from fieldcal.recording.logs import import_log  # noqa: E402
from xsens_logs import assert_calibrates_as_text, one_line_error, unpacked, xsens_in_units  # noqa: E402

FMT_TYPE = 128


def fmt_message(msg_type: int, name: str, fmt: str, columns: str, payload_bytes: int) -> bytes:
    """A DataFlash FMT message (header, type, length, name, format, columns: 'BBnNZ')."""
    return (bytes([0xA3, 0x95, FMT_TYPE, msg_type, 3 + payload_bytes]) + name.encode().ljust(4, b"\0")
            + fmt.encode().ljust(16, b"\0") + columns.encode().ljust(64, b"\0"))


def messages(msg_type: int, fields: list[tuple[str, str]], values: dict) -> np.ndarray:
    """Messages of one type as a structured array of their bytes (header first), in order."""
    dtype = np.dtype([("h1", "u1"), ("h2", "u1"), ("type", "u1"), *fields])
    n = len(next(iter(values.values())))
    out = np.zeros(n, dtype=dtype)
    out["h1"], out["h2"], out["type"] = 0xA3, 0x95, msg_type
    for name, column in values.items():
        out[name] = column
    return out


def write_imu_log(path: Path, t_s: np.ndarray, instances: list[tuple[np.ndarray, np.ndarray]]) -> Path:
    """A DataFlash log in today's layout: IMU messages (TimeUS, I, GyrX..Z rad/s, AccX..Z m/s²),
    the instances interleaved as a flight controller writes them."""
    fields = [("TimeUS", "<u8"), ("I", "u1")] + [(f"{s}{a}", "<f4") for s in ("Gyr", "Acc") for a in "XYZ"]
    per_instance = []
    for i, (accel, rate) in enumerate(instances):
        values = {"TimeUS": np.round(t_s * 1e6).astype(np.uint64), "I": np.full(len(t_s), i)}
        values |= {f"Gyr{a}": rate[:, k] for k, a in enumerate("XYZ")}
        values |= {f"Acc{a}": accel[:, k] for k, a in enumerate("XYZ")}
        per_instance.append(messages(133, fields, values))
    body = np.stack(per_instance, axis=1).ravel()  # sample 0 of instance 0, of 1, sample 1 ...
    head = fmt_message(133, "IMU", "QBffffff", "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ", body.dtype.itemsize - 3)
    path.write_bytes(head + body.tobytes())
    return path


@pytest.fixture(scope="module")
def real_log(tmp_path_factory) -> Path:
    return unpacked(tmp_path_factory.mktemp("df"), "pymavlink_test.BIN.gz", "test.BIN")


def decoded(path: Path, name: str):
    """TimeUS, AccX..Z, GyrX..Z of every ``name`` message, decoded one by one by DFReader."""
    log = DFReader.DFReader_binary(str(path))
    rows = []
    while (m := log.recv_match(type=name)) is not None:
        rows.append([m.TimeUS, m.AccX, m.AccY, m.AccZ, m.GyrX, m.GyrY, m.GyrZ])
    log.close()
    return np.array(rows)


@pytest.mark.parametrize("instance, name", [(0, "IMU"), (1, "IMU2")])
def test_real_log_reads_each_imu_as_dfreader_decodes_it(real_log, instance, name):
    recording, report = import_log(real_log, imu=instance)
    truth = decoded(real_log, name)
    assert len(truth) == 45
    np.testing.assert_array_equal(recording.t, truth[:, 0] * 1e-6)
    np.testing.assert_array_equal(recording.triads["accelerometer"], truth[:, 1:4])
    np.testing.assert_array_equal(recording.triads["gyroscope"], truth[:, 4:7])
    assert report.files[0].name == f"ArduPilot DataFlash: {name} (instance {instance})"
    # On the ground: the specific force is about g.
    assert abs(np.linalg.norm(recording.triads["accelerometer"], axis=1).mean() - 9.8) < 0.3


def test_real_log_too_short_to_calibrate_is_refused_in_one_line(real_log, tmp_path, capsys):
    code = main(["calibrate", str(real_log), "--out", str(tmp_path / "c")])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert "record the poses for longer" in err or "distinct poses" in err


def test_log_errors_are_one_line(real_log, tmp_path, capsys):
    out = ["--out", str(tmp_path / "s")]
    assert "no IMU instance 2; the log has 0, 1 (choose with --imu N)" in one_line_error(
        ["import", str(real_log), "--imu", "2", *out], capsys)
    assert "--topic is for ROS bags" in one_line_error(["import", str(real_log), "--topic", "/imu", *out], capsys)
    junk = tmp_path / "junk.bin"
    junk.write_bytes(b"\x00\x01 not a log " * 100)
    assert "junk.bin: not a DataFlash log: it does not start with a message header (A3 95)" in one_line_error(
        ["import", str(junk), *out], capsys)
    empty = tmp_path / "empty.bin"
    empty.write_bytes(b"")
    assert "empty.bin: not a readable DataFlash log" in one_line_error(["calibrate", str(empty), *out], capsys)


@pytest.fixture(scope="module")
def xsens(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("xsens")
    paths, text, acc_scale, accel, rate = xsens_in_units(tmp)
    # Instance 1 is a second IMU mounted upside down about x: y and z change sign.
    flip = np.array([1.0, -1.0, -1.0])
    log = write_imu_log(tmp / "xsens.bin", text.t, [(accel, rate), (accel * flip, rate * flip)])
    return paths, text, acc_scale, accel, rate, log


def test_instances_are_chosen_by_their_column(xsens):
    paths, text, acc_scale, accel, rate, log = xsens
    first, report = import_log(log)
    second, _ = import_log(log, imu=1)
    np.testing.assert_array_equal(first.triads["accelerometer"], accel.astype(np.float32))
    np.testing.assert_array_equal(second.triads["gyroscope"], (rate * [1, -1, -1]).astype(np.float32))
    np.testing.assert_allclose(first.t, text.t, atol=0.6e-6)  # TimeUS: whole microseconds
    assert report.files[0].name == "ArduPilot DataFlash: IMU instance 0"
    with pytest.raises(RecordingImportError, match=r"no IMU instance 3; the log has 0, 1"):
        import_log(log, imu=3)


def test_xsens_log_calibrates_as_its_text_files_do(xsens, tmp_path, capsys):
    """As for the ROS bag: the text's poses, and its parameters through the unit map; float32
    samples and whole-microsecond times move the accelerometer's by far less than 1e-2 σ."""
    paths, text, acc_scale, accel, rate, log = xsens
    out = assert_calibrates_as_text(log, paths, acc_scale, 1e-2, tmp_path, capsys)
    assert "ArduPilot DataFlash: IMU instance 0" in out


def test_acc_and_gyr_messages_are_read_when_there_is_no_imu(tmp_path):
    """Logs of the fast-sampling kind: ACC and GYR with their sample times; the gyro put on the
    accelerometer's time (here the same times, so its values are kept exactly)."""
    n = 40
    rng = np.random.default_rng(5)
    accel, rate = rng.normal(size=(n, 3)).astype(np.float32), rng.normal(size=(n, 3)).astype(np.float32)
    sample_us = 1_000_000 + np.arange(n, dtype=np.uint64) * 2500  # 400 Hz
    fields = lambda s: [("TimeUS", "<u8"), ("I", "u1"), ("SampleUS", "<u8")] + [(f"{s}{a}", "<f4") for a in "XYZ"]
    blocks = []
    for msg_type, s, values in ((140, "Acc", accel), (141, "Gyr", rate)):
        blocks.append(messages(msg_type, fields(s), {"TimeUS": sample_us + 7000, "I": np.zeros(n),
                                                    "SampleUS": sample_us,
                                                    **{f"{s}{a}": values[:, k] for k, a in enumerate("XYZ")}}))
    head = b"".join(fmt_message(t, name, "QBQfff", f"TimeUS,I,SampleUS,{s}X,{s}Y,{s}Z", blocks[0].dtype.itemsize - 3)
                    for t, name, s in ((140, "ACC", "Acc"), (141, "GYR", "Gyr")))
    path = tmp_path / "fast.bin"
    path.write_bytes(head + b"".join(b.tobytes() for b in blocks))
    recording, report = import_log(path)
    np.testing.assert_array_equal(recording.triads["accelerometer"], accel)
    np.testing.assert_array_equal(recording.triads["gyroscope"], rate)
    np.testing.assert_allclose(recording.t, sample_us * 1e-6)
    assert report.files[0].name == "ArduPilot DataFlash: ACC + GYR instance 0"


def test_old_logs_with_millisecond_time_are_read(tmp_path):
    """Logs older than ArduPilot 3.3 stamp IMU messages with TimeMS (ms, 32-bit)."""
    n = 20
    rate, accel = np.full((n, 3), 0.01, dtype=np.float32), np.tile(np.float32([0.1, 0.2, -9.8]), (n, 1))
    fields = [("TimeMS", "<u4")] + [(f"{s}{a}", "<f4") for s in ("Gyr", "Acc") for a in "XYZ"]
    values = {"TimeMS": 5000 + np.arange(n) * 20, **{f"Gyr{a}": rate[:, k] for k, a in enumerate("XYZ")},
              **{f"Acc{a}": accel[:, k] for k, a in enumerate("XYZ")}}
    body = messages(129, fields, values)
    head = fmt_message(129, "IMU", "Iffffff", "TimeMS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ", body.dtype.itemsize - 3)
    (tmp_path / "old.bin").write_bytes(head + body.tobytes())
    recording, _ = import_log(tmp_path / "old.bin")
    np.testing.assert_allclose(recording.t, 5.0 + np.arange(n) * 0.02)
    np.testing.assert_array_equal(recording.triads["accelerometer"], accel)


def _edited(real_log: Path, tmp_path: Path, name: bytes, old: bytes, new: bytes) -> Path:
    """The real log with one message type's FMT changed: ``old`` → ``new`` (same length) inside
    the FMT message that defines ``name`` (its 4-byte name field)."""
    data = bytearray(real_log.read_bytes())
    start = data.index(b"\xa3\x95\x80" + bytes([data[data.index(name) - 2]]))  # FMT header, type
    start = data.index(name, start)
    stop = start + 4 + 16 + 64  # name, format, columns
    data[start:stop] = data[start:stop].replace(old, new, 1)
    path = tmp_path / f"edited-{new.decode().strip(chr(0))}.bin"
    path.write_bytes(bytes(data))
    return path


def test_real_log_without_a_column_names_the_file_message_and_column(real_log, tmp_path, capsys):
    """pymavlink's log with its IMU's AccY column renamed in the FMT: one line naming the file,
    the message, the column, what it has, and what fieldcal reads."""
    log = _edited(real_log, tmp_path, b"IMU\0", b"AccY", b"AccQ")
    err = one_line_error(["import", str(log), "--out", str(tmp_path / "s")], capsys)
    assert f"{log}: its IMU messages have no AccY column (they have TimeUS, GyrX, GyrY, GyrZ, AccX, AccQ" in err
    assert "fieldcal reads AccX, AccY, AccZ (m/s²) from IMU messages, or ACC and GYR" in err
    assert "--map" in err
    recording, _ = import_log(log, imu=1)  # IMU2 kept its columns
    assert len(recording.t) == 45


def test_real_log_without_imu_messages_names_the_file_and_what_it_has(real_log, tmp_path, capsys):
    log = _edited(_edited(real_log, tmp_path, b"IMU\0", b"IMU\0", b"IMX\0"), tmp_path, b"IMU2", b"IMU2", b"IMY2")
    err = one_line_error(["calibrate", str(log), "--out", str(tmp_path / "s")], capsys)
    assert f"{log}: no IMU messages (nor ACC and GYR) in the log: set LOG_BITMASK to log IMU" in err
    assert "IMX" in err and "IMY2" in err  # what it has instead
