"""fieldcal apply: a recording's text in, calibrated CSV out, block by block, equal to the true
inputs the raw text was made from; a malformed line stops it with the line's number."""
import io
import re
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fieldcal.apply import apply_file, calibrated_blocks, plan
from fieldcal.apply.text import TextError, squeeze_blanks
from fieldcal.calibration import Calibration
from fieldcal.cli.main import main
from fieldcal.earth import Station
from fieldcal.model import k_from_terms
from fieldcal.paramfile import ParameterFile, save
from fieldcal.recording.import_map import load_import_map
from fieldcal.units import STANDARD_GRAVITY

# single-csv: t in ms, accelerometer in mg read as g, gyro in deg/s read as rad/s
ACC = Calibration(name="accelerometer", kind="specific_force", output_unit="g", method="classic",
                  K=k_from_terms([1.002 / STANDARD_GRAVITY, 0.997 / STANDARD_GRAVITY, 1.0 / STANDARD_GRAVITY],
                                 [1e-3, -2e-3, 5e-4, 0.0, 3e-3, -1e-3]),
                  bias=[0.012, -0.004, 0.02], sigma=np.full(9, 1e-6), residual_rms=0.0)
GYR = Calibration(name="gyroscope", kind="angular_rate", output_unit="rad/s", method="classic",
                  K=k_from_terms([1.01, 0.99, 1.0], [0.0, 2e-4, 0.0, 0.0, 0.0, -1e-4]),
                  bias=[1e-3, -2e-3, 5e-4], sigma=np.full(9, 1e-6), residual_rms=0.0)


def parameter_file(*triads):
    return ParameterFile.build(triads, station=Station(40.0, 50.0), procedure="classic-12",
                               method="classic", input_sha256="b" * 64)


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    """A CSV of 3000 samples whose raw values are made from known true inputs."""
    rng = np.random.default_rng(3)
    n = 3000
    true_acc = rng.normal(size=(n, 3)) * 5.0  # m/s²
    true_gyr = rng.normal(size=(n, 3))  # rad/s
    raw_mg = (true_acc @ ACC.K.T + ACC.bias) * 1e3
    raw_dps = np.rad2deg(true_gyr @ GYR.K.T + GYR.bias)
    t_ms = 1000.0 + 4.0 * np.arange(n)
    path = tmp_path_factory.mktemp("rec") / "log.csv"
    rows = np.c_[t_ms, raw_mg, raw_dps, np.full(n, 25.0)]
    np.savetxt(path, rows, delimiter=",", fmt="%.12g",
               header="t_ms,ax_mg,ay_mg,az_mg,gx_dps,gy_dps,gz_dps,temp_C", comments="")
    written = np.loadtxt(path, delimiter=",", skiprows=1)  # the raw values as the text holds them
    return path, t_ms / 1e3, true_acc, true_gyr, written[:, 1:4] * 1e-3, np.deg2rad(written[:, 4:7])


def test_calibrated_output_is_the_true_input(tmp_path, capsys, recording):
    path, t, true_acc, true_gyr, _, _ = recording
    params = save(parameter_file(ACC, GYR), tmp_path / "p.yaml")
    out = tmp_path / "cal.csv"
    assert main(["apply", str(params), str(path), "--map", "single-csv", "--out", str(out)]) == 0
    assert "3000 samples calibrated" in capsys.readouterr().err
    header = out.read_text().splitlines()[0]
    assert header == ("t_s,accelerometer_x_m/s^2,accelerometer_y_m/s^2,accelerometer_z_m/s^2,"
                      "gyroscope_x_rad/s,gyroscope_y_rad/s,gyroscope_z_rad/s")
    data = np.loadtxt(out, delimiter=",", skiprows=1)
    np.testing.assert_array_equal(data[:, 0], t)  # 1004 ms is written 1.004, the double nearest
    # the text had 12 significant digits (the raw values' rounding is all the difference)
    np.testing.assert_allclose(data[:, 1:4], true_acc, atol=1e-9)
    np.testing.assert_allclose(data[:, 4:7], true_gyr, atol=1e-9)
    # every number is written in full: the text reads back to the very doubles calibrated
    [p] = plan(parameter_file(ACC, GYR), load_import_map("single-csv"), [path])
    np.testing.assert_array_equal(data[:, 1:], np.vstack([v for _, v in calibrated_blocks(p)]))


def test_small_blocks_split_lines_and_give_the_same_samples(recording):
    path, t, _, _, raw_acc, raw_gyr = recording
    [p] = plan(parameter_file(ACC, GYR), load_import_map("single-csv"), [path])
    blocks = list(calibrated_blocks(p, block_bytes=1000))  # ~12 lines a block, cut mid-line
    assert len(blocks) > 100
    t_all = np.concatenate([b[0] for b in blocks])
    values = np.vstack([b[1] for b in blocks])
    np.testing.assert_allclose(t_all, t, atol=1e-12)
    np.testing.assert_allclose(values, np.hstack([ACC.calibrate(raw_acc), GYR.calibrate(raw_gyr)]),
                               rtol=1e-12, atol=1e-12)


def test_a_triad_missing_from_the_parameters_is_skipped_and_a_wrong_unit_refused(tmp_path, capsys,
                                                                                 recording):
    path = recording[0]
    params = save(parameter_file(GYR), tmp_path / "p.yaml")
    assert main(["apply", str(params), str(path), "--map", "single-csv"]) == 0
    captured = capsys.readouterr()
    assert captured.out.splitlines()[0] == "t_s,gyroscope_x_rad/s,gyroscope_y_rad/s,gyroscope_z_rad/s"
    assert len(captured.out.splitlines()) == 3001
    assert "triad 'accelerometer' is not in" in captured.err
    in_si = Calibration(name="accelerometer", kind="specific_force", output_unit="m/s^2", method="powell",
                        K=np.eye(3), bias=np.zeros(3), sigma=np.zeros(9), residual_rms=0.0)
    params = save(parameter_file(in_si, GYR), tmp_path / "q.yaml")
    assert main(["apply", str(params), str(path), "--map", "single-csv"]) == 2
    err = capsys.readouterr().err
    assert "read in 'g' but was calibrated in 'm/s^2'" in err and err.count("\n") == 1


def test_two_file_map_writes_one_csv_per_input_into_a_directory(tmp_path, capsys):
    """imu_tk: accelerometer and gyro in separate files, in counts; each file calibrated alone."""
    acc = Calibration(name="accelerometer", kind="specific_force", output_unit="count", method="powell",
                      K=np.diag([400.0, 410.0, 420.0]), bias=[32768.0, 32700.0, 32800.0],
                      sigma=np.zeros(9), residual_rms=0.0)
    gyr = Calibration(name="gyroscope", kind="angular_rate", output_unit="count", method="powell",
                      K=np.diag([4700.0, 4650.0, 4720.0]), bias=[32768.0, 32760.0, 32790.0],
                      sigma=np.zeros(9), residual_rms=0.0)
    params = save(parameter_file(acc, gyr), tmp_path / "p.yaml")
    rng = np.random.default_rng(4)
    truth = {}
    for name, cal in (("acc", acc), ("gyro", gyr)):
        true = rng.normal(size=(50, 3))
        raw = np.rint(true @ cal.K.T + cal.bias)  # whole counts, as the device gives them
        np.savetxt(tmp_path / f"{name}.txt", np.c_[0.01 * np.arange(50), raw], fmt="%.10g")
        truth[name] = cal.calibrate(raw)
    argv = ["apply", str(params), str(tmp_path / "acc.txt"), str(tmp_path / "gyro.txt"), "--map", "imu_tk"]
    assert main(argv) == 2 and "give --out DIR" in capsys.readouterr().err
    (tmp_path / "out").mkdir()
    assert main([*argv, "--out", str(tmp_path / "out")]) == 0
    for name in ("acc", "gyro"):
        data = np.loadtxt(tmp_path / "out" / f"{name}-calibrated.csv", delimiter=",", skiprows=1)
        np.testing.assert_allclose(data[:, 1:], truth[name], atol=1e-9)
    assert main([*argv, "--out", str(tmp_path / "out")]) == 2  # never over a file without --force
    assert "--force" in capsys.readouterr().err


def test_a_hand_worked_sample(tmp_path):
    """K = diag(2, 4, 0.5), b = (1, 0, -1): raw (3, 8, -0.5) is K⁻¹(2, 8, 0.5) = (1, 2, 1) rad/s."""
    gyro = Calibration(name="gyroscope", kind="angular_rate", output_unit="rad/s", method="classic",
                       K=np.diag([2.0, 4.0, 0.5]), bias=[1.0, 0.0, -1.0], sigma=np.zeros(9), residual_rms=0.0)
    layout = tmp_path / "map.yaml"
    layout.write_text("files:\n  - time: {column: 0, unit: ms}\n    triads:\n"
                      "      gyroscope: {columns: [1, 2, 3], kind: angular_rate, unit: rad/s}\n")
    (tmp_path / "in.csv").write_text("time,x,y,z\n1500,3,8,-0.5\n1504,1,0,-1\n")
    [p] = plan(parameter_file(gyro), load_import_map(layout), [tmp_path / "in.csv"])
    out = io.BytesIO()
    assert apply_file(p, out) == 2
    assert out.getvalue().decode().splitlines() == [
        "t_s,gyroscope_x_rad/s,gyroscope_y_rad/s,gyroscope_z_rad/s", "1.5,1.0,2.0,1.0", "1.504,0.0,0.0,0.0"]


def _applied(p, block_bytes) -> bytes:
    out = io.BytesIO()
    apply_file(p, out, block_bytes)
    return out.getvalue()


def test_one_block_or_many_give_the_same_csv(recording):
    """The 3000-line file (~250 kB) read in one block, and in blocks of 64 kB and of 1000 bytes
    (~10 lines each, cut mid-line), writes the same bytes."""
    path = recording[0]
    [p] = plan(parameter_file(ACC, GYR), load_import_map("single-csv"), [path])
    assert path.stat().st_size < 1 << 20
    assert len(list(calibrated_blocks(p, 1 << 20))) == 1
    shortest = min(len(line) for line in path.read_bytes().splitlines()[1:])
    assert max(len(t) for t, _ in calibrated_blocks(p, 1000)) <= 2 * 1000 // shortest  # memory: a block
    whole = _applied(p, 1 << 20)
    assert whole.count(b"\n") == 3001
    assert _applied(p, 1 << 16) == whole
    assert _applied(p, 1000) == whole


def test_blank_separated_text_with_ragged_blanks(tmp_path):
    """imu_tk's blank-separated layout: runs of spaces and tabs, blanks at the line ends, CRLF,
    comments and blank lines; read in small blocks and whole, both equal to the truth."""
    acc = Calibration(name="accelerometer", kind="specific_force", output_unit="count", method="powell",
                      K=np.diag([400.0, 410.0, 420.0]), bias=[32768.0, 32700.0, 32800.0],
                      sigma=np.zeros(9), residual_rms=0.0)
    rng = np.random.default_rng(5)
    raw = np.rint(rng.normal(size=(500, 3)) @ acc.K.T + acc.bias)
    blanks = [" ", "  ", "\t", " \t "]
    lines = [f"{blanks[i % 4]}{0.01 * i:.2f}{blanks[(i + 1) % 4]}{r[0]:.0f}{blanks[(i + 2) % 4]}{r[1]:.0f}"
             f"{blanks[(i + 3) % 4]}{r[2]:.0f}{blanks[i % 3]}" for i, r in enumerate(raw)]
    lines[100:100] = ["# paused", "", "   "]
    (tmp_path / "acc.txt").write_bytes(("\r\n".join(lines) + "\r\n").encode())
    np.savetxt(tmp_path / "gyro.txt", np.zeros((1, 4)))  # the map's second file
    gyro_counts = Calibration(name="gyroscope", kind="angular_rate", output_unit="count", method="powell",
                              K=np.eye(3), bias=np.zeros(3), sigma=np.zeros(9), residual_rms=0.0)
    params = parameter_file(acc, gyro_counts)
    plans = plan(params, load_import_map("imu_tk"), [tmp_path / "acc.txt", tmp_path / "gyro.txt"])
    whole = _applied(plans[0], 1 << 20)
    assert _applied(plans[0], 300) == whole
    data = np.loadtxt(io.BytesIO(whole), delimiter=",", skiprows=1)
    np.testing.assert_array_equal(data[:, 0], np.round(0.01 * np.arange(500), 2))
    np.testing.assert_allclose(data[:, 1:], acc.calibrate(raw), rtol=1e-14, atol=1e-14)


def test_squeezing_blanks():
    assert squeeze_blanks(b"  1 \t 2\t3  \r\n\t4  5\n \n") == b"1 2 3\r\n4 5\n\n"
    assert squeeze_blanks(b"1,2\n") == b"1,2\n"
    assert squeeze_blanks(b"1 2\t3\n") == b"1 2 3\n"
    assert squeeze_blanks(b"\t\ta\t\tb\t\t") == b"a b"  # the end of the block ends a line
    assert squeeze_blanks(b"") == b""


def test_named_columns_without_time_are_timed_by_the_rate(tmp_path, capsys):
    """imucal's CSV: columns found by their header names (in any order), no time column."""
    acc = Calibration(name="accelerometer", kind="specific_force", output_unit="m/s^2", method="powell",
                      K=np.diag([1.01, 0.99, 1.0]), bias=[0.1, -0.2, 0.05], sigma=np.zeros(9), residual_rms=0.0)
    rng = np.random.default_rng(6)
    raw = np.round(rng.normal(size=(40, 3)) * 9.8, 6)
    path = tmp_path / "imucal.csv"
    np.savetxt(path, np.c_[np.zeros((40, 3)), raw[:, ::-1]], delimiter=",", fmt="%.6f",
               header="gyr_x,gyr_y,gyr_z,acc_z,acc_y,acc_x", comments="")
    params = save(parameter_file(acc), tmp_path / "p.yaml")
    argv = ["apply", str(params), str(path), "--map", "imucal"]
    assert main(argv) == 2
    assert "no time column: give its sample rate (--rate HZ" in capsys.readouterr().err
    assert main([*argv, "--rate", "0"]) == 2
    assert "--rate: expected a sample rate above 0 Hz, got 0" in capsys.readouterr().err
    assert main([*argv, "--rate", "100"]) == 0
    data = np.loadtxt(io.StringIO(capsys.readouterr().out), delimiter=",", skiprows=1)
    np.testing.assert_allclose(data[:, 0], np.arange(40) / 100, rtol=0, atol=1e-15)
    np.testing.assert_allclose(data[:, 1:], acc.calibrate(raw), rtol=1e-14, atol=1e-14)


GOOD = [f"{1000 + 4 * i},{i % 7}.5,{2 * i},-{i % 5},0.1,0.2,0.3,25" for i in range(2000)]


@pytest.mark.parametrize("lines, where, what", [
    (GOOD[:1400] + ["6600,1,x,3,0.1,0.2,0.3,25"] + GOOD[1400:], 1402, "accelerometer.y (column 3) is 'x'"),
    (GOOD[:1400] + ["6600,1,2"] + GOOD[1400:], 1402, "3 fields where the first sample has 8"),
    (GOOD[:1400] + ["6600,1,2,3,0.1,0.2,0.3"] + GOOD[1400:], 1402, "7 fields where the first sample has 8"),
    (GOOD[:1400] + ["6600,1,,3,0.1,0.2,0.3,25"] + GOOD[1400:], 1402, "accelerometer.y (column 3) is empty"),
    (GOOD[:1400] + ["6600,1,2,3,0.1,0.2,0.3,25,7"] + GOOD[1400:], 1402, "9 fields where the first sample has 8"),
    (GOOD[:30] + ["1120,1,2,3,nan,0.2,0.3,25"] + GOOD[30:], 32, "gyroscope.x (column 5) is 'nan'"),
    (GOOD[:30] + ["1120,1,2,3,0.1,1e999,0.3,25"] + GOOD[30:], 32, "gyroscope.y (column 6) is '1e999'"),
], ids=["text in the middle", "short line", "missing column", "empty field", "long line", "nan", "overflow"])
@pytest.mark.parametrize("block_bytes", [1 << 20, 4096])
def test_a_malformed_line_stops_apply_with_its_number(tmp_path, capsys, lines, where, what, block_bytes):
    """Never a sample dropped or guessed: one line naming the file and the line, nothing written."""
    path = tmp_path / "log.csv"
    path.write_text("t_ms,ax,ay,az,gx,gy,gz,T\n" + "\n".join(lines) + "\n")
    [p] = plan(parameter_file(ACC, GYR), load_import_map("single-csv"), [path])
    with pytest.raises(TextError, match=f"^apply: {path}: line {where}: {re.escape(what)}") as caught:
        _applied(p, block_bytes)
    assert caught.value.line == where and "\n" not in str(caught.value)
    params = save(parameter_file(ACC, GYR), tmp_path / "p.yaml")
    out = tmp_path / "cal.csv"
    assert main(["apply", str(params), str(path), "--map", "single-csv", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"line {where}:" in err and "Traceback" not in err
    assert sorted(tmp_path.iterdir()) == sorted([path, params])  # no CSV, no partial file left


def test_an_empty_field_not_read_is_no_fault(tmp_path):
    """The temperature (not calibrated) empty on some lines, last on the line: the samples are
    read, an empty last field being no missing one."""
    lines = [line.rsplit(",", 1)[0] + "," if i % 3 == 0 else line for i, line in enumerate(GOOD)]
    path = tmp_path / "log.csv"
    path.write_text("t_ms,ax,ay,az,gx,gy,gz,T\n" + "\n".join(lines) + "\n")
    [p] = plan(parameter_file(ACC, GYR), load_import_map("single-csv"), [path])
    data = np.loadtxt(io.BytesIO(_applied(p, 4096)), delimiter=",", skiprows=1)
    raw = np.array([[float(v) for v in line.split(",")[1:7]] for line in GOOD])
    np.testing.assert_array_equal(data[:, 0], (1000 + 4 * np.arange(2000)) / 1000)
    np.testing.assert_allclose(data[:, 1:], np.hstack([ACC.calibrate(raw[:, :3] * 1e-3),
                                                       GYR.calibrate(np.deg2rad(raw[:, 3:]))]), rtol=1e-13, atol=1e-13)


def test_a_last_line_cut_off_mid_write_is_refused(tmp_path, capsys):
    path = tmp_path / "log.csv"
    path.write_text("t_ms,ax,ay,az,gx,gy,gz,T\n" + "\n".join(GOOD) + "\n1000,1,2,3,0.1,0.")
    params = save(parameter_file(ACC, GYR), tmp_path / "p.yaml")
    assert main(["apply", str(params), str(path), "--map", "single-csv"]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""  # refused before anything is written
    assert captured.err.count("\n") == 1
    assert f"{path}: line 2002: the last line has no line end" in captured.err
    path.write_text("t_ms,ax,ay,az,gx,gy,gz,T\n" + "\n".join(GOOD) + "\n# end of log")  # a comment: whole
    assert main(["apply", str(params), str(path), "--map", "single-csv"]) == 0
    assert capsys.readouterr().out.count("\n") == 2001


def test_header_comments_and_blank_lines_are_skipped(tmp_path, capsys):
    path = tmp_path / "log.csv"
    path.write_text("# logger v2\nFs,250\nt_ms,ax,ay,az,gx,gy,gz,T\n" + "\n".join(GOOD[:10])
                    + "\n\n# paused\n   \n" + "\n".join(GOOD[10:20]) + "\n")
    params = save(parameter_file(ACC, GYR), tmp_path / "p.yaml")
    assert main(["apply", str(params), str(path), "--map", "single-csv"]) == 0
    data = np.loadtxt(io.StringIO(capsys.readouterr().out), delimiter=",", skiprows=1)
    np.testing.assert_array_equal(data[:, 0], (1000 + 4 * np.arange(20)) / 1000)
    (tmp_path / "empty.csv").write_text("t_ms,ax,ay,az,gx,gy,gz,T\n")
    assert main(["apply", str(params), str(tmp_path / "empty.csv"), "--map", "single-csv"]) == 2
    assert "no sample of CSV log in its first 200 lines" in capsys.readouterr().err


def test_a_blank_too_many_is_not_hidden_by_a_short_line(tmp_path):
    """A blank too many is no fault in a blank-separated file; the short line after it is."""
    acc = Calibration(name="accelerometer", kind="specific_force", output_unit="count", method="powell",
                      K=np.eye(3), bias=np.zeros(3), sigma=np.zeros(9), residual_rms=0.0)
    (tmp_path / "acc.txt").write_text("0 1 2 3\n0.01 1  2 3\n0.02 1 2\n0.03 1 2 3\n")
    np.savetxt(tmp_path / "gyro.txt", np.zeros((1, 4)))
    gyro = Calibration(name="gyroscope", kind="angular_rate", output_unit="count", method="powell",
                       K=np.eye(3), bias=np.zeros(3), sigma=np.zeros(9), residual_rms=0.0)
    plans = plan(parameter_file(acc, gyro), load_import_map("imu_tk"), [tmp_path / "acc.txt", tmp_path / "gyro.txt"])
    with pytest.raises(TextError, match="line 3: 3 fields where the first sample has 4"):
        _applied(plans[0], 1 << 20)


def test_output_piped_into_head_ends_quietly(tmp_path):
    """`fieldcal apply ... | head`: the reader leaving is not an error (exit 0, nothing on stderr)."""
    path = tmp_path / "log.csv"
    path.write_text("t_ms,ax,ay,az,gx,gy,gz,T\n" + "\n".join(GOOD * 20) + "\n")  # ~3 MB out, beyond a pipe
    params = save(parameter_file(ACC, GYR), tmp_path / "p.yaml")
    code = (f"from fieldcal.cli.main import main; raise SystemExit(main(['apply', {str(params)!r}, "
            f"{str(path)!r}, '--map', 'single-csv']))")
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert proc.stdout.readline().startswith(b"t_s,accelerometer_x")
    proc.stdout.close()
    assert proc.wait(timeout=120) == 0
    assert proc.stderr.read() == b""


@pytest.mark.parametrize("files, map_name, units", [
    (["imu_tk_xsens_acc.mat.gz", "imu_tk_xsens_gyro.mat.gz"], "imu_tk", ("count", "count")),
    (["imucal_ferraris_session.csv.gz"], "imucal", ("m/s^2", "deg/s")),
], ids=["imu_tk Xsens logs", "imucal Ferraris CSV"])
def test_real_device_files_give_what_fieldcal_import_reads(tmp_path, files, map_name, units):
    """Real bytes (tests/data/real): imu_tk's Xsens logs (runs of blanks, counts, two files) and
    imucal's Ferraris CSV (columns by name, no time column). What apply calibrates is what the
    importer's own parser (a separate reader) reads, calibrated."""
    from test_real_recordings import unpacked

    from fieldcal.recording.importer import import_recording
    paths = unpacked(tmp_path, *files)
    rate = 102.4 if map_name == "imucal" else None
    recording = import_recording(paths, map_name, rate_hz=rate)
    cals = [Calibration(name=name, kind=kind, output_unit=unit, method="classic",
                        K=k_from_terms([k] * 3, [1e-3, -2e-3, 5e-4, 1e-3, 3e-3, -1e-3]), bias=[b, -b, 2 * b],
                        sigma=np.zeros(9), residual_rms=0.0)
            for name, kind, unit, k, b in zip(("accelerometer", "gyroscope"), ("specific_force", "angular_rate"),
                                              units, (1.2, 0.9), (0.3, 0.7) if map_name == "imucal" else (32768, 32000))]
    plans = plan(parameter_file(*cals), load_import_map(map_name), paths, rate_hz=rate)
    first = np.loadtxt(io.BytesIO(_applied(plans[0], 1 << 16)), delimiter=",", skiprows=1)
    # the importer keeps the first file's samples where all files overlap, bit for bit
    keep = np.isin(first[:, 0], recording.t)
    assert keep.sum() == len(recording.t) > 5000
    triad = plans[0].calibrations[0]
    np.testing.assert_allclose(first[keep, 1:4], triad.calibrate(recording.triads[triad.name]), rtol=1e-13, atol=1e-12)
    if map_name == "imucal":  # both triads in one file
        np.testing.assert_allclose(first[:, 4:7], cals[1].calibrate(recording.triads["gyroscope"]), rtol=1e-13, atol=1e-12)


@settings(deadline=None)  # a loaded machine must not fail it: no time limit per example
@given(st.lists(st.text(alphabet=" \t1a-.", max_size=12), max_size=8), st.sampled_from(["\n", "\r\n"]),
       st.booleans())
def test_squeezing_blanks_is_splitting_each_line_on_blanks(lines, end, ended):
    """The vectorised squeeze against Python's own bytes.split, line by line."""
    text = end.join(lines) + (end if ended else "")
    want = "\n".join(" ".join(line.split()) for line in text.split("\n"))
    assert squeeze_blanks(text.encode()).decode().replace("\r", "") == want.replace("\r", "")


def _ulog_combined(path):
    """sensor_combined's timestamp (s), accelerometer and gyro, as pyulog reads them."""
    from pyulog import ULog
    [data] = [d.data for d in ULog(str(path), ["sensor_combined"]).data_list]
    return (data["timestamp"] * 1e-6, np.column_stack([data[f"accelerometer_m_s2[{i}]"] for i in range(3)]),
            np.column_stack([data[f"gyro_rad[{i}]"] for i in range(3)]))


def _dataflash_imu(path):
    from test_logs_dataflash import decoded
    rows = decoded(path, "IMU")
    return rows[:, 0] * 1e-6, rows[:, 1:4], rows[:, 4:7]


def _ros_imu(path):
    from test_logs_bags import deserialized
    t, rate, accel = deserialized(path, "/imu/data")
    return t, accel, rate


@pytest.mark.parametrize("name, as_name, truth, extra", [
    ("px4_sample_log_small.ulg.gz", "log.ulg", _ulog_combined, []),
    ("pymavlink_test.BIN.gz", "test.BIN", _dataflash_imu, ["--imu", "0"]),
    ("robot_localization_test2.bag.gz", "jackal.bag", _ros_imu, ["--topic", "/imu/data"]),
], ids=["PX4 ULog", "ArduPilot DataFlash", "ROS 1 bag"])
def test_real_logs_are_calibrated_as_their_own_readers_decode_them(tmp_path, capsys, name, as_name, truth, extra):
    """Real logs (tests/data/real), read whole by the importer: the CSV is each sample as the
    format's own library decodes it (pyulog, pymavlink's DFReader, rosbags' deserializer, one
    message at a time), calibrated by K⁻¹ worked out here."""
    pytest.importorskip({"log.ulg": "pyulog", "test.BIN": "pymavlink", "jackal.bag": "rosbags"}[as_name])
    from xsens_logs import unpacked

    path = unpacked(tmp_path, name, as_name)
    acc = Calibration(name="accelerometer", kind="specific_force", output_unit="m/s^2", method="classic",
                      K=k_from_terms([1.01, 0.98, 1.02], [1e-3, -2e-3, 5e-4, 1e-3, 3e-3, -1e-3]),
                      bias=[0.1, -0.2, 0.3], sigma=np.zeros(9), residual_rms=0.0)
    gyr = Calibration(name="gyroscope", kind="angular_rate", output_unit="rad/s", method="classic",
                      K=np.diag([1.01, 0.99, 1.0]), bias=[1e-3, -2e-3, 5e-4], sigma=np.zeros(9), residual_rms=0.0)
    params = save(parameter_file(acc, gyr), tmp_path / "p.yaml")
    out = tmp_path / "cal.csv"
    assert main(["apply", str(params), str(path), *extra, "--out", str(out)]) == 0
    t, raw_acc, raw_gyr = truth(path)
    assert f"{len(t)} samples calibrated into {out}" in capsys.readouterr().err
    data = np.loadtxt(out, delimiter=",", skiprows=1)
    np.testing.assert_allclose(data[:, 0], t - (t[0] if as_name == "jackal.bag" else 0), rtol=0, atol=1e-9)
    np.testing.assert_allclose(data[:, 1:4], (raw_acc - acc.bias) @ np.linalg.inv(acc.K).T, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(data[:, 4:7], (raw_gyr - gyr.bias) / np.diag(gyr.K), rtol=1e-12, atol=1e-12)
    in_counts = Calibration(name="gyroscope", kind="angular_rate", output_unit="count", method="powell",
                            K=np.eye(3), bias=np.zeros(3), sigma=np.zeros(9), residual_rms=0.0)
    assert main(["apply", str(save(parameter_file(in_counts), tmp_path / "q.yaml")), str(path), *extra]) == 2
    err = capsys.readouterr().err
    assert "triad 'gyroscope' is read in 'rad/s' but was calibrated in 'count'" in err and err.count("\n") == 1


def test_a_quote_in_a_column_not_read_loses_no_sample(tmp_path, capsys):
    """A ``"`` in the temperature (not read) is text, as fieldcal import reads it: polars must
    not take the lines up to the next ``"`` as one quoted field (the samples would vanish)."""
    path = tmp_path / "q.csv"
    path.write_text('t_ms,ax,ay,az,gx,gy,gz,T\n1000,1,2,1000,0.1,0.2,0.3,"x\n1004,1,2,1000,0.1,0.2,0.3,25\n'
                    '1008,1,2,1000,0.1,0.2,0.3,y"\n1012,1,2,1000,0.1,0.2,0.3,25\n')
    params = save(parameter_file(ACC, GYR), tmp_path / "p.yaml")
    for block_bytes in (1 << 20, 40):
        [p] = plan(parameter_file(ACC, GYR), load_import_map("single-csv"), [path])
        data = np.loadtxt(io.BytesIO(_applied(p, block_bytes)), delimiter=",", skiprows=1)
        np.testing.assert_array_equal(data[:, 0], [1.0, 1.004, 1.008, 1.012])
        np.testing.assert_allclose(data[:, 1:4], np.tile(ACC.calibrate(np.array([[1e-3, 2e-3, 1.0]])), (4, 1)),
                                   rtol=1e-14)
    assert main(["apply", str(params), str(path), "--map", "single-csv"]) == 0
    assert capsys.readouterr().out.count("\n") == 5
    path.write_text('t_ms,ax,ay,az,gx,gy,gz,T\n1000,1,2,1000,0.1,0.2,0.3,25\n1004,"1",2,1000,0.1,0.2,0.3,25\n')
    assert main(["apply", str(params), str(path), "--map", "single-csv"]) == 2  # a quoted number: refused
    assert "line 3: accelerometer.x (column 2) is '\"1\"'" in capsys.readouterr().err


def test_outputs_that_would_overwrite_each_other_or_an_input_are_refused(tmp_path, capsys):
    """a/x.txt and b/x.txt both give x-calibrated.csv: refused up front (nothing written), one
    line naming both; an output that is an input or the parameter file: refused even with --force."""
    acc = Calibration(name="accelerometer", kind="specific_force", output_unit="count", method="powell",
                      K=np.eye(3), bias=np.zeros(3), sigma=np.zeros(9), residual_rms=0.0)
    gyro = Calibration(name="gyroscope", kind="angular_rate", output_unit="count", method="powell",
                       K=np.eye(3), bias=np.zeros(3), sigma=np.zeros(9), residual_rms=0.0)
    params = save(parameter_file(acc, gyro), tmp_path / "p.yaml")
    for folder in ("a", "b"):
        (tmp_path / folder).mkdir()
        np.savetxt(tmp_path / folder / "x.txt", np.c_[0.01 * np.arange(5), np.ones((5, 3))], fmt="%.10g")
    (tmp_path / "out").mkdir()
    inputs = [str(tmp_path / "a" / "x.txt"), str(tmp_path / "b" / "x.txt")]
    assert main(["apply", str(params), *inputs, "--map", "imu_tk", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and inputs[0] in err and inputs[1] in err
    assert list((tmp_path / "out").iterdir()) == []
    single = tmp_path / "one.csv"
    single.write_text("t_ms,ax,ay,az,gx,gy,gz,T\n" + "\n".join(GOOD[:5]) + "\n")
    before = single.read_bytes()
    params = save(parameter_file(ACC, GYR), tmp_path / "p2.yaml")
    for out in (single, params):
        argv = ["apply", str(params), str(single), "--map", "single-csv", "--out", str(out), "--force"]
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and f"--out {out} is the input" in err
    assert single.read_bytes() == before


def test_padded_fields_and_other_bytes_in_a_column_not_read_are_read_as_fieldcal_import_reads_them(tmp_path):
    """``1004, 1 ,2,...`` (blanks around fields) and ``25\\xb0C`` (Latin-1 in the temperature, not
    read): the same samples as fieldcal import reads; ``1 2`` (a blank inside a field) is refused."""
    from fieldcal.apply.text import strip_padding
    from fieldcal.recording.importer import import_recording

    lines = [line.replace(",", " , ", 2).replace(",25", ",  25\xb0C\t") if i % 2 else " " + line + " "
             for i, line in enumerate(GOOD[:300])]
    path = tmp_path / "log.csv"
    path.write_bytes(("t_ms,ax,ay,az,gx,gy,gz,T\n" + "\n".join(lines) + "\n").encode("latin-1"))
    truth = import_recording([path], "single-csv")
    [p] = plan(parameter_file(ACC, GYR), load_import_map("single-csv"), [path])
    for block_bytes in (1 << 20, 500):
        data = np.loadtxt(io.BytesIO(_applied(p, block_bytes)), delimiter=",", skiprows=1)
        np.testing.assert_allclose(data[:, 0], truth.t, rtol=1e-15)  # import takes ms × 0.001
        np.testing.assert_allclose(data[:, 1:4], ACC.calibrate(truth.triads["accelerometer"]), rtol=1e-13, atol=1e-13)
    assert strip_padding(b" 1 ,\t2 2 , \r\n\t,3\n", ",") == b"1,2 2,\r\n,3\n"
    assert strip_padding(b"1\t \t2\n", "\t") == b"1\t\t2\n"  # a tab delimiter is no padding
    path.write_text("t_ms,ax,ay,az,gx,gy,gz,T\n" + "\n".join(GOOD[:5]) + "\n1020,1 2,3,4,0.1,0.2,0.3,25\n")
    with pytest.raises(TextError, match=r"line 7: accelerometer.x \(column 2\) is '1 2'"):
        _applied(p, 1 << 20)


def test_a_line_only_the_csv_reader_refuses_is_named(tmp_path, monkeypatch):
    """Whatever polars refuses that the line check lets pass is still named by its line number
    (found by halving the block), never 'after sample N'."""
    import fieldcal.apply.text as text

    path = tmp_path / "log.csv"
    path.write_text("t_ms,ax,ay,az,gx,gy,gz,T\n" + "\n".join(GOOD[:40]) + "\n1160,1_0,2,3,0.1,0.2,0.3,25\n"
                    + "\n".join(GOOD[40:60]) + "\n")
    monkeypatch.setattr(text, "_PLAIN_NUMBER", re.compile(rb"[0-9_.+-]+"))  # a check blind to '1_0'
    [p] = plan(parameter_file(ACC, GYR), load_import_map("single-csv"), [path])
    for block_bytes in (1 << 20, 300):
        with pytest.raises(TextError, match="line 42: not read as a sample by the CSV reader") as caught:
            _applied(p, block_bytes)
        assert caught.value.line == 42


def test_a_closed_standard_output_is_one_line(tmp_path):
    """``fieldcal apply p.yaml log.csv --map single-csv >&-``: no traceback, a line saying what to do."""
    import os

    path = tmp_path / "log.csv"
    path.write_text("t_ms,ax,ay,az,gx,gy,gz,T\n" + "\n".join(GOOD[:5]) + "\n")
    params = save(parameter_file(ACC, GYR), tmp_path / "p.yaml")
    proc = subprocess.run([sys.executable, "-m", "fieldcal.cli.main", "apply", str(params), str(path), "--map",
                           "single-csv"], stderr=subprocess.PIPE, text=True, preexec_fn=lambda: os.close(1),
                          timeout=120)
    assert proc.returncode == 2
    assert proc.stderr == "fieldcal: apply: standard output is closed: give --out FILE\n"


def test_a_pipe_as_input_is_refused_in_one_line_naming_it(tmp_path):
    """``cat log.csv | fieldcal apply p.yaml /dev/stdin``: one line naming the input; /dev/stdin
    redirected from a regular file is read."""
    path = tmp_path / "log.csv"
    path.write_text("t_ms,ax,ay,az,gx,gy,gz,T\n" + "\n".join(GOOD[:5]) + "\n")
    params = save(parameter_file(ACC, GYR), tmp_path / "p.yaml")
    argv = [sys.executable, "-m", "fieldcal.cli.main", "apply", str(params), "/dev/stdin", "--map", "single-csv"]
    piped = subprocess.run(argv, input=path.read_bytes(), capture_output=True, timeout=120)
    assert piped.returncode == 2 and piped.stdout == b""
    assert piped.stderr.decode() == ("fieldcal: apply: /dev/stdin: not a regular file (a pipe or a device): apply "
                                     "reads a file more than once; save the text to a file and give that\n")
    with open(path, "rb") as stdin:
        redirected = subprocess.run(argv, stdin=stdin, capture_output=True, timeout=120)
    assert redirected.returncode == 0 and redirected.stdout.count(b"\n") == 6


def test_rate_with_a_time_column_is_refused_and_times_not_forward_are_counted(tmp_path, capsys):
    """--rate where the file has its own times: refused in one line. Times that repeat (1004
    twice) or go back (1000 after 1008) across a block's edge: said once with their count (2),
    and every sample is written, in the file's order."""
    params = save(parameter_file(ACC, GYR), tmp_path / "p.yaml")
    path = tmp_path / "log.csv"
    lines = GOOD[:3] + [GOOD[1]] + [GOOD[0]] + GOOD[3:8]  # t: 1000 1004 1008 1004 1000 1012 ...
    path.write_text("t_ms,ax,ay,az,gx,gy,gz,T\n" + "\n".join(lines) + "\n")
    assert main(["apply", str(params), str(path), "--map", "single-csv", "--rate", "100"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--rate" in err and "time column" in err
    assert main(["apply", str(params), str(path), "--map", "single-csv"]) == 0
    captured = capsys.readouterr()
    data = np.loadtxt(io.StringIO(captured.out), delimiter=",", skiprows=1)
    np.testing.assert_array_equal(data[:, 0], [float(line.split(",")[0]) / 1000 for line in lines])
    assert captured.err == (f"fieldcal apply: {path}: 2 sample times repeat or go back (t_s not increasing); "
                            "every sample is written, in the file's order\n")
    [p] = plan(parameter_file(ACC, GYR), load_import_map("single-csv"), [path])
    said = []
    apply_file(p, io.BytesIO(), block_bytes=100, warn=said.append)  # the step back across blocks
    assert len(said) == 1 and ": 2 sample times" in said[0]
