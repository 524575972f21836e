"""imu_tk's real Xsens recording (tests/data/real) in physical units, for the log-format tests
that write it as a ROS bag or a DataFlash log, and the checks they share: the log calibrates as
the text files do, through the known unit map; bad input gives one line."""
from __future__ import annotations

import gzip
from pathlib import Path

import numpy as np

from fieldcal.cli.main import main
from fieldcal.model import params_from
from fieldcal.paramfile import load
from fieldcal.recording.importer import import_recording

REAL = Path(__file__).parent / "data" / "real"
ZERO_COUNT, GYRO_SCALE = 32768.0, 1.0 / 6258.0  # imu_tk's example: counts -> rad/s
IMU_TK_GRAVITY = 9.81744  # m/s^2, what imu_tk's example uses for this recording
PLACE = ["--latitude", "45", "--gravity", f"{IMU_TK_GRAVITY}"]  # not published: any latitude
_TEXT_RESULT: list = []  # (output, parameter file) of calibrating the text files


def unpacked(tmp: Path, name: str, as_name: str | None = None) -> Path:
    """The gzipped real file ``name`` of tests/data/real, decompressed into ``tmp``."""
    path = tmp / (as_name or name.removesuffix(".gz"))
    path.write_bytes(gzip.decompress((REAL / name).read_bytes()))
    return path


def xsens_in_units(tmp: Path):
    """(the two text files, their Recording in counts, the accelerometer's m/s² per count, the
    accelerometer in m/s², the gyro in rad/s): raw_unit = scale·(count − 32768), the
    accelerometer's scale nominal (the first 10 s at about g), the gyro's imu_tk's 1/6258."""
    paths = [unpacked(tmp, name) for name in ("imu_tk_xsens_acc.mat.gz", "imu_tk_xsens_gyro.mat.gz")]
    text = import_recording(paths, "imu_tk")
    counts = text.triads["accelerometer"] - ZERO_COUNT
    acc_scale = IMU_TK_GRAVITY / np.linalg.norm(counts[:1000].mean(axis=0))
    return paths, text, acc_scale, counts * acc_scale, (text.triads["gyroscope"] - ZERO_COUNT) * GYRO_SCALE


def assert_calibrates_as_text(log: Path, paths, acc_scale: float, acc_within_sigma: float, tmp_path: Path,
                              capsys) -> str:
    """``fieldcal calibrate`` on the log finds the text's poses, and its parameters are the
    text's through the unit map (K_log = s·K, bias_log = s·(bias − 32768)): the accelerometer
    within ``acc_within_sigma`` σ, the gyro within 1 σ (in counts fieldcal scans for the scale
    that makes the rotations fit and weights one count of quantisation, in rad/s it carries the
    Earth rate as an error term: the weights differ). Returns the log's output."""
    if not _TEXT_RESULT:  # the text's calibration, once per test process
        assert main(["calibrate", *map(str, paths), "--map", "imu_tk", *PLACE, "--params",
                     str(tmp_path / "text.yaml"), "--out", str(tmp_path / "t")]) == 0
        _TEXT_RESULT.append((capsys.readouterr().out, load(tmp_path / "text.yaml")))
    text_out, by_text = _TEXT_RESULT[0]
    assert main(["calibrate", str(log), *PLACE, "--params", str(tmp_path / "log.yaml"),
                 "--out", str(tmp_path / "l")]) == 0
    log_out = capsys.readouterr().out
    poses = [line for line in text_out.splitlines() if "poses" in line][:1]
    assert poses and poses[0] in log_out and "51175 samples" in log_out
    by_log = load(tmp_path / "log.yaml")
    for name, scale, within in (("accelerometer", acc_scale, acc_within_sigma), ("gyroscope", GYRO_SCALE, 1.0)):
        got = by_log[name]
        expected = params_from(scale * by_text[name].K, scale * (by_text[name].bias - ZERO_COUNT),
                               got.parameter_names)
        assert np.all(np.abs(got.theta - expected) < within * got.sigma), (name, (got.theta - expected) / got.sigma)
    return log_out


def one_line_error(argv, capsys) -> str:
    """The command fails with exit 2 and one line on stderr, no traceback; that line."""
    code = main(argv)
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    return err
