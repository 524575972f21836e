"""Exports: what ArduPilot and PX4 keep is applied as they apply it, and what they drop costs
the error reported; imucal itself loads the imucal JSON and calibrates as fieldcal does."""
import json
from pathlib import Path

import numpy as np
import pytest

from fieldcal.calibration import Calibration
from fieldcal.cli.main import main
from fieldcal.earth import Station
from fieldcal.model import k_from_terms
from fieldcal.paramfile import ParameterFile, save
from fieldcal.units import STANDARD_GRAVITY

STATION = Station(40.0, 50.0)
QUICK = str(Path(__file__).parent / "faults" / "quick.yaml")


def triad(name, kind, unit, bias, scale, terms, si_per_unit=1.0):
    K = k_from_terms(np.array(scale) / si_per_unit, terms)
    return Calibration(name=name, kind=kind, output_unit=unit, method="classic", K=K,
                       bias=np.array(bias) / si_per_unit, sigma=np.full(9, 1e-6), residual_rms=0.0)


def parameter_file(*triads):
    return ParameterFile.build(triads, station=STATION, procedure="classic-12", method="classic",
                               input_sha256="a" * 64, device_name="sim", device_serial="S7")


ACC_TERMS = [1e-3, -2e-3, 0.5e-3, 0.0, 3e-3, -1e-3]
GYR_TERMS = [0.0, 2e-4, 0.0, 0.0, 0.0, -1e-4]


@pytest.fixture(scope="module")
def diagonal_case():
    """An accelerometer reporting in g, a gyro in deg/s: both formats work in SI."""
    acc = triad("accelerometer", "specific_force", "g", [0.02, -0.01, 0.05], [1.002, 0.998, 1.001],
                ACC_TERMS, si_per_unit=STANDARD_GRAVITY)
    gyr = triad("gyroscope", "angular_rate", "deg/s", np.deg2rad([0.1, -0.2, 0.3]), [1.01, 0.99, 1.0],
                GYR_TERMS, si_per_unit=np.pi / 180)
    return parameter_file(acc, gyr), acc, gyr


def _run(argv, capsys):
    status = main(argv)
    captured = capsys.readouterr()
    return status, captured.out, captured.err


def _parameters(text, fmt):
    rows = [line for line in text.splitlines() if line and not line.startswith("#")]
    if fmt == "ardupilot":
        return {n: float(v) for n, v in (r.split(",") for r in rows)}
    return {f[2]: float(f[3]) for f in (r.split("\t") for r in rows)}


def _directions(n=20000, seed=0):
    u = np.random.default_rng(seed).normal(size=(n, 3))
    return u / np.linalg.norm(u, axis=1, keepdims=True)


def _worst(text, pf, fmt, triad):
    """The worst error written in the file (3 digits), and as computed."""
    from fieldcal.export.autopilot import diagonal_parameters

    line = next(x for x in text.splitlines() if x.startswith(f"#   {triad}: dropped"))
    loss = {d.triad: d for d in diagonal_parameters(pf, fmt, "accelerometer", "gyroscope", False)[1]}[triad]
    assert float(line.split("worst error ")[1].split()[0]) == pytest.approx(loss.error, rel=5e-3)
    return loss.error


@pytest.mark.parametrize("fmt, acc_names, gyr_names", [
    ("ardupilot", ("INS_ACCOFFS_{}", "INS_ACCSCAL_{}"), ("INS_GYROFFS_{}", None)),
    ("px4", ("CAL_ACC0_{}OFF", "CAL_ACC0_{}SCALE"), ("CAL_GYRO0_{}OFF", None)),
])
def test_autopilot_parameters_applied_as_the_autopilot_does(tmp_path, capsys, diagonal_case, fmt,
                                                            acc_names, gyr_names):
    pf, acc, gyr = diagonal_case
    params = save(pf, tmp_path / "p.yaml")
    status, text, err = _run(["export", str(params), "--format", fmt], capsys)
    assert status == 0 and "dropped m_xy = 1 mrad" in err
    values = _parameters(text, fmt)
    u = _directions()
    # accelerometer, 1 g inputs: raw (in g) as the device reports it, converted to m/s² as the
    # autopilot's driver does, then (raw - offset) * scale
    raw = (u * STANDARD_GRAVITY) @ acc.K.T + acc.bias
    off = np.array([values[acc_names[0].format(a)] for a in "XYZ"])
    scale = np.array([values[acc_names[1].format(a)] for a in "XYZ"])
    corrected = (raw * STANDARD_GRAVITY - off) * scale
    error_mg = np.linalg.norm(corrected - u * STANDARD_GRAVITY, axis=1) / STANDARD_GRAVITY * 1e3
    worst = _worst(text, pf, fmt, "accelerometer")
    # the misalignment alone: the worst error over directions is sigma_max(M) at 1 g
    assert worst == pytest.approx(np.linalg.norm(k_from_terms(np.ones(3), ACC_TERMS) - np.eye(3), 2) * 1e3,
                                  rel=1e-3)
    assert error_mg.max() <= worst * (1 + 1e-3) and error_mg.max() > 0.98 * worst
    # gyro, 100 °/s: offsets only, so its scale factors are dropped too
    rate = np.deg2rad(100.0)
    raw = (u * rate) @ gyr.K.T + gyr.bias  # deg/s, as the device reports
    g_off = np.array([values[gyr_names[0].format(a)] for a in "XYZ"])
    corrected = np.deg2rad(raw) - g_off
    error_deg_h = np.rad2deg(np.linalg.norm(corrected - u * rate, axis=1)) * 3600
    worst = _worst(text, pf, fmt, "gyroscope")
    assert error_deg_h.max() <= worst * (1 + 1e-3) and error_deg_h.max() > 0.98 * worst
    assert "scale_x = 1.0100000" in err
    # neither format has a gyro scale parameter to fill
    assert not any(k.startswith(("CAL_GYRO0_XSCALE", "INS_GYROSCAL")) for k in values)


def test_a_device_unit_triad_cannot_go_to_an_autopilot(tmp_path, capsys):
    acc = triad("accelerometer", "specific_force", "count", [100, 0, 0], [1, 1, 1], ACC_TERMS, 1e-3)
    gyr = triad("gyroscope", "angular_rate", "rad/s", [0, 0, 0], [1, 1, 1], GYR_TERMS)
    params = save(parameter_file(acc, gyr), tmp_path / "p.yaml")
    status, _, err = _run(["export", str(params), "--format", "px4"], capsys)
    assert status == 2 and "'accelerometer' reports in 'count'" in err and "\n" not in err.strip()
    status, _, err = _run(["export", str(params), "--format", "px4", "--accelerometer", "acc"], capsys)
    assert status == 2 and "no triad named 'acc'" in err and "--accelerometer" in err


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    """A calibration of the simulated MIMU (quick procedure) and its truth."""
    from drivers.sim.device import paper_mimu
    from fieldcal.paramfile import hash_inputs
    from fieldcal.run.simcal import run_simulated_calibration

    cal = run_simulated_calibration(5, QUICK, paper_mimu(raw_counts=True))
    pf = ParameterFile.build(tuple(cal.solutions.values()), station=cal.station, procedure="quick",
                             method="powell", input_sha256=hash_inputs(*(p.data for p in cal.problems.values())),
                             device_name="sim", device_serial="42", simulation=True)
    return pf, paper_mimu(raw_counts=True)


def test_imucal_loads_the_json_and_calibrates_as_fieldcal(tmp_path, capsys, simulated):
    from imucal.management import load_calibration_info

    pf, truth = simulated
    params = save(pf, tmp_path / "p.yaml")
    out = tmp_path / "imu.json"
    assert _run(["export", str(params), "--format", "imucal-json", "--out", str(out)], capsys)[0] == 0
    info = load_calibration_info(out)
    assert type(info).__name__ == "FerrarisCalibrationInfo"
    rng = np.random.default_rng(1)
    true_acc = _directions(500, 2) * STANDARD_GRAVITY
    true_gyr = rng.normal(size=(500, 3))  # rad/s
    acc_t, gyr_t = truth["accelerometer"], truth["gyroscope"]
    raw_acc = true_acc @ acc_t.K.T + acc_t.bias  # counts, as the simulated unit reports
    raw_gyr = true_gyr @ gyr_t.K.T + gyr_t.bias
    acc, gyr = info.calibrate(raw_acc, raw_gyr, acc_unit="count", gyr_unit="count")
    ours_acc = pf["accelerometer"].calibrate(raw_acc)
    ours_gyr = np.rad2deg(pf["gyroscope"].calibrate(raw_gyr))
    np.testing.assert_allclose(acc, ours_acc, rtol=0, atol=1e-9 * STANDARD_GRAVITY)
    np.testing.assert_allclose(gyr, ours_gyr, rtol=0, atol=1e-9)
    # and both are the truth, to the calibration's accuracy (a few mg, a few 0.01 °/s)
    assert np.abs(acc - true_acc).max() < 5e-3 * STANDARD_GRAVITY
    assert np.abs(gyr - np.rad2deg(true_gyr)).max() < 0.05
    with pytest.raises(ValueError, match="unit"):  # imucal checks the unit it was made for
        info.calibrate(raw_acc, raw_gyr, acc_unit="m/s^2", gyr_unit="count")


def test_c_header_and_json(tmp_path, capsys, simulated):
    pf, _ = simulated
    params = save(pf, tmp_path / "p.yaml")
    status, text, _ = _run(["export", str(params), "--format", "c-header"], capsys)
    assert status == 0
    for cal in pf.triads:  # the arrays hold the bias and K⁻¹ to the last bit
        name = cal.name.upper()
        bias = text.split(f"FIELDCAL_{name}_BIAS[3] = {{")[1].split("}")[0]
        assert [float(x) for x in bias.split(",")] == cal.bias.tolist()
        kinv = text.split(f"FIELDCAL_{name}_KINV[3][3] = {{")[1].split("};")[0]
        rows = [[float(x) for x in r.strip(" {},").split(",")] for r in kinv.split("}, {")]
        np.testing.assert_array_equal(rows, np.linalg.inv(cal.K))
    status, text, _ = _run(["export", str(params), "--format", "json"], capsys)
    doc = json.loads(text)
    assert doc["triads"]["gyroscope"]["K"] == pf["gyroscope"].K.tolist()
    out = tmp_path / "x.h"
    out.write_text("keep")
    status, _, err = _run(["export", str(params), "--format", "c-header", "--out", str(out)], capsys)
    assert status == 2 and out.read_text() == "keep" and "--force" in err


@pytest.mark.parametrize("fmt", ["px4", "ardupilot", "c-header", "imucal-json"])
def test_a_triad_of_the_wrong_kind_is_refused(tmp_path, capsys, diagonal_case, fmt):
    """Issue 25 item 5: `--gyroscope accelerometer` wrote the accelerometer's m/s² offsets as
    CAL_GYRO0_*OFF (exit 0); every format now checks the kind of the triads it is told to use."""
    pf, _, _ = diagonal_case
    params = save(pf, tmp_path / "p.yaml")
    out = tmp_path / "out"
    status, text, err = _run(["export", str(params), "--format", fmt, "--gyroscope", "accelerometer",
                              "--out", str(out)], capsys)
    assert status == 2 and not out.exists()
    assert "--gyroscope accelerometer" in err and "is specific_force" in err and "not angular_rate" in err
    assert "gyroscope" in err.split("triad: ")[-1] and len(err.strip().splitlines()) == 1
    status, _, err = _run(["export", str(params), "--format", fmt, "--accelerometer", "gyroscope"], capsys)
    assert status == 2 and "--accelerometer gyroscope" in err and "is angular_rate" in err


def test_c_header_refuses_a_gyroscope_named_triad_that_measures_force(tmp_path, capsys):
    """A file whose triad called 'gyroscope' is an accelerometer: its arrays would be taken by the
    firmware's gyro code by their name."""
    acc = triad("gyroscope", "specific_force", "m/s^2", [0.1, 0, 0], [1, 1, 1], ACC_TERMS)
    params = save(parameter_file(acc), tmp_path / "p.yaml")
    status, text, err = _run(["export", str(params), "--format", "c-header"], capsys)
    assert status == 2 and text == "" and "--gyroscope gyroscope" in err
    status, text, _ = _run(["export", str(params), "--format", "c-header", "--accelerometer", "gyroscope",
                            "--gyroscope", "none"], capsys)
    assert status == 0 and "gyroscope (specific_force): raw in m/s^2, calibrated in m/s^2" in text
