"""fieldcal apply: a recording's text in, calibrated CSV out, block by block, equal to the true
inputs the raw text was made from."""
import numpy as np
import pytest

from fieldcal.apply import apply_file, calibrated_blocks, plan
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
    np.testing.assert_allclose(data[:, 0], t, atol=1e-6)
    # the text had 12 significant digits; the output 9 decimals
    np.testing.assert_allclose(data[:, 1:4], true_acc, atol=1e-8)
    np.testing.assert_allclose(data[:, 4:7], true_gyr, atol=1e-8)


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
