"""A PX4 thermal-calibration log in (fieldcal thermal), fitted by fieldcal's thermal fit, checked
against the simulator's thermal truth and against PX4's own process_sensor_caldata.py."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pyulog")

from fieldcal.cli.main import main  # noqa: E402
from fieldcal.recording.errors import RecordingImportError  # noqa: E402
from fieldcal.recording.thermal_log import fit_held_thermal, read_thermal_ulog  # noqa: E402
from fieldcal.thermal import truth_about  # noqa: E402
from px4_thermal_log import ACCEL_TRUTH, GYRO_TRUTH, imu_fields, thermal_log, write_ulog  # noqa: E402

ORACLE = Path(__file__).parent / "data" / "px4_thermal_oracle.json"


@pytest.fixture(scope="module")
def warmup(tmp_path_factory) -> Path:
    return thermal_log(tmp_path_factory.mktemp("px4") / "thermal.ulg", seed=1)


@pytest.fixture(scope="module")
def fits(warmup):
    return {t.name: (t, fit_held_thermal(t)) for t in read_thermal_ulog(warmup)}


def _true_terms(truth, reference_c):
    return truth_about(np.zeros(9), truth.reference_c, truth.bias_terms, truth.scale_drift, reference_c)[1]


@pytest.mark.parametrize("name, truth", [("accelerometer", ACCEL_TRUTH), ("gyroscope", GYRO_TRUTH)])
def test_the_fit_recovers_the_simulators_thermal_truth_within_its_sigma(fits, name, truth):
    triad, fit = fits[name]
    model = fit.calibration.thermal
    true = _true_terms(truth, model.reference_c)
    assert model.order >= len(truth.bias_terms)  # every true term is in the model
    padded = np.vstack([true, np.zeros((model.order - len(true), 3))])  # terms the truth has not: 0
    z = (model.bias_terms - padded) / model.bias_terms_sigma
    assert np.all(np.abs(z) < 4), z
    # the noise of a window mean, measured from the data, is the simulator's white noise averaged
    per_window = len(triad.t) // fit.windows
    noise = {"accelerometer": 0.02, "gyroscope": 0.002}[name] / np.sqrt(per_window)
    assert np.allclose(fit.window_sigma, noise, rtol=0.25)
    assert fit.dof == 3 * fit.windows - 3 - 3 * model.order  # the pins add nothing to χ²'s freedom
    assert fit.chi2 / fit.dof < 1.5 and not fit.inflated
    low, high = model.range_c
    assert (low, high) == (triad.temperature_c.min(), triad.temperature_c.max())
    assert model.reference_c == pytest.approx((low + high) / 2)  # PX4's TREF
    cal = fit.calibration
    assert set(cal.not_calibrated) == set(cal.parameter_names)  # one pose: no K, no bias


def test_the_gyros_cubic_is_found_and_an_order_of_truth_is_never_dropped(fits):
    assert fits["gyroscope"][1].calibration.thermal.order == 3
    chi2 = fits["accelerometer"][1].chi2_by_order
    assert chi2[1] - chi2[2] > 100  # the accelerometer's curvature is far beyond noise


@pytest.mark.parametrize("name, letter", [("accelerometer", "A"), ("gyroscope", "G")])
def test_the_fit_agrees_with_px4_process_sensor_caldata_within_its_sigma(fits, name, letter):
    """PX4's script (stored result, tests/data/px4_thermal_oracle.json) fits the same log with a
    fixed order 3 after a median filter and temperature bins; the same reference temperature."""
    params = json.loads(ORACLE.read_text())["parameters"]
    model = fits[name][1].calibration.thermal
    assert model.reference_c == pytest.approx(params[f"TC_{letter}0_TREF"], abs=1e-4)
    assert model.range_c == pytest.approx((params[f"TC_{letter}0_TMIN"], params[f"TC_{letter}0_TMAX"]), abs=1e-4)
    px4 = np.array([[params[f"TC_{letter}0_X{k}_{i}"] for i in range(3)] for k in (1, 2, 3)])
    z = (model.bias_terms - px4[:model.order]) / model.bias_terms_sigma
    assert np.all(np.abs(z) < 3), z


def test_fieldcal_thermal_writes_a_parameter_file_px4_export_makes_tc_parameters_of(warmup, fits, tmp_path, capsys):
    fits_sigma = {name: fit.calibration.thermal.bias_terms_sigma for name, (_, fit) in fits.items()}
    params = tmp_path / "thermal.yaml"
    assert main(["thermal", str(warmup), "--params", str(params)]) == 0
    out = capsys.readouterr().out
    assert "bias polynomial of order 3" in out and "not calibrated by one still pose" in out
    assert main(["export", str(params), "--format", "px4"]) == 0
    text = capsys.readouterr().out
    values = {f[2]: float(f[3]) for f in (line.split("\t") for line in text.splitlines()
                                          if line and not line.startswith("#"))}
    assert "CAL_ACC0_XOFF" not in values and "CAL_GYRO0_XOFF" not in values  # not calibrated: not written
    oracle = json.loads(ORACLE.read_text())["parameters"]
    # Applied as PX4 applies it (offset = Σ Xk·dT^k, dT = T − TREF within [TMIN, TMAX]; X0 is the
    # CAL offset's part), the exported correction's change over the range and PX4's own agree
    # within 3σ of each exported term (|Σ Δk dT^k| <= Σ 3σk |dT|^k).
    for letter, name in (("A", "accelerometer"), ("G", "gyroscope")):
        sigma = fits_sigma[name]
        dt = np.linspace(values[f"TC_{letter}0_TMIN"], values[f"TC_{letter}0_TMAX"], 50) - values[f"TC_{letter}0_TREF"]
        powers = dt[:, None] ** np.arange(1, 4)
        for i in range(3):
            ours = powers @ [values[f"TC_{letter}0_X{k}_{i}"] for k in (1, 2, 3)]
            theirs = powers @ [oracle[f"TC_{letter}0_X{k}_{i}"] for k in (1, 2, 3)]
            allowed = np.abs(powers[:, :len(sigma)]) @ (3 * sigma[:, i])
            assert np.all(np.abs(ours - theirs) <= allowed)
            assert np.ptp(theirs) > 10 * allowed.max()  # a test that can fail: the change is far beyond it


def _log_without(tmp_path, field=None, topic=None, temperature=None, z=None):
    t = np.arange(0, 600.0, 0.04)
    stamp = (t * 1e6).astype(np.uint64) + 1
    temp = np.linspace(-5, 30, len(t)) if temperature is None else temperature(t)
    noise = np.random.default_rng(3).normal(0, 0.01, (3, len(t)))
    columns = {"timestamp": stamp, "timestamp_sample": stamp, "device_id": np.zeros(len(t)),
               "x": noise[0], "y": noise[1], "z": noise[2] + (-9.8 if z is None else z(t)), "temperature": temp}
    fields = imu_fields()
    if field:
        fields = [f for f in fields if f[1] != field]
        columns.pop(field)
    gyro = {**columns, "z": noise[2] * 0.1}  # still: the gyro's z is no gravity axis
    topics = {name: (fields, cols) for name, cols in (("sensor_accel", columns), ("sensor_gyro", gyro))
              if name != topic}
    return write_ulog(tmp_path / "bad.ulg", topics)


@pytest.mark.parametrize("how, said", [
    ({"field": "temperature"}, "sensor_accel has no temperature field"),
    ({"topic": "sensor_gyro"}, "no sensor_gyro instance 0 in the log (it has sensor_accel instance 0)"),
    ({"temperature": lambda t: np.full(len(t), 21.0)}, "spans 0.00 K (21.00 to 21.00 °C): too little"),
])
def test_a_log_that_cannot_give_a_thermal_model_is_one_line_naming_why(tmp_path, capsys, how, said):
    log = _log_without(tmp_path, **how)
    assert main(["thermal", str(log)]) == 2
    err = capsys.readouterr().err
    assert said in err and err.count("\n") == 1 and "Traceback" not in err


def test_not_a_ulog_and_a_cut_log_are_one_line(warmup, tmp_path, capsys):
    junk = tmp_path / "junk.ulg"
    junk.write_bytes(b"not a ulog at all" * 100)
    assert main(["thermal", str(junk)]) == 2
    assert "not a readable ULog" in capsys.readouterr().err
    cut = tmp_path / "cut.ulg"
    cut.write_bytes(warmup.read_bytes()[:-7])
    with pytest.raises(RecordingImportError, match="damaged"):
        read_thermal_ulog(cut)
    assert main(["thermal", str(tmp_path / "log.csv")]) == 2
    assert "expected a PX4 log (.ulg)" in capsys.readouterr().err


def test_params_is_refused_before_the_log_is_read_when_it_exists(warmup, tmp_path, capsys):
    params = tmp_path / "thermal.yaml"
    params.write_text("mine\n")
    assert main(["thermal", str(warmup), "--params", str(params)]) == 2
    assert "--force" in capsys.readouterr().err
    assert params.read_text() == "mine\n"


def test_a_board_moved_during_the_warm_up_is_kept_with_a_warning_and_wider_sigma(tmp_path, capsys):
    """Tilted by a few degrees half-way: z reads 1 % less gravity from then on, a step no
    polynomial in temperature follows. The fit is kept (its σ inflated by the misfit), and said."""
    log = _log_without(tmp_path, z=lambda t: np.where(t < 300, -9.8, -9.8 * 0.99))
    assert main(["thermal", str(log)]) == 0
    out = capsys.readouterr().out
    assert "WARNING: accelerometer fits with χ²/dof" in out and "was the board moved" in out
    assert "σ are widened" in out
    assert "WARNING: gyroscope" not in out


def _field_calibration(path, gyro_unit="deg/s", thermal=None):
    """A field calibration of the unit (a diagonal K, so every term is one PX4 and ArduPilot hold)."""
    from fieldcal.calibration import Calibration
    from fieldcal.earth import Station
    from fieldcal.paramfile import ParameterFile, save

    acc = Calibration(name="accelerometer", kind="specific_force", output_unit="m/s^2", method="powell",
                      theta=[0.05, -0.08, 0.1, 1.001, 0.999, 1.002, 0, 0, 0], sigma=np.full(9, 1e-4),
                      residual_rms=0.0, thermal=thermal)
    gyro = Calibration(name="gyroscope", kind="angular_rate", output_unit=gyro_unit, method="powell",
                       theta=[0.2, -0.1, 0.05, 1.0, 1.0, 1.0, 0, 0, 0], sigma=np.full(9, 1e-3), residual_rms=0.0)
    pf = ParameterFile.build((acc, gyro), station=Station(48.0, 500.0), procedure="field-18", method="powell",
                             input_sha256="0" * 64)
    save(pf, path)
    return pf


def test_onto_a_field_calibration_keeps_it_and_adds_the_models_about_its_temperature(warmup, tmp_path, capsys):
    from fieldcal.paramfile import load

    base = _field_calibration(tmp_path / "field.yaml")
    full = tmp_path / "full.yaml"
    assert main(["thermal", str(warmup), "--onto", str(tmp_path / "field.yaml"), "--at", "20",
                 "--params", str(full)]) == 0
    pf = load(full)
    assert pf.provenance.procedure == "field-18 + px4-thermal-log"
    assert pf.provenance.input_sha256 != base.provenance.input_sha256  # the log is among its inputs now
    for name, truth, si in (("accelerometer", ACCEL_TRUTH, 1.0), ("gyroscope", GYRO_TRUTH, np.pi / 180)):
        np.testing.assert_array_equal(pf[name].theta, base[name].theta)  # the field calibration as it was
        model = pf[name].thermal
        assert model.reference_c == 20.0
        true = _true_terms(truth, 20.0) / si  # the truth about 20 °C, in the triad's unit (°/s for the gyro)
        padded = np.vstack([true, np.zeros((model.order - len(true), 3))])
        assert np.all(np.abs((model.bias_terms - padded) / model.bias_terms_sigma) < 4)
    capsys.readouterr()
    assert main(["export", str(full), "--format", "ardupilot"]) == 0
    text = capsys.readouterr().out
    assert "INS_ACCOFFS_X,0.05" in text and "INS_TCAL1_ENABLE,1" in text and "INS_ACC1_CALTEMP,20.0" in text


@pytest.mark.parametrize("argv, said", [
    (["--onto", "{field}"], "--onto: give --at, the temperature"),
    (["--onto", "{field}", "--at", "20"], "--onto: give --params"),
    (["--onto", "{field}", "--at", "60", "--params", "{out}"], "--at: 60 °C is outside the log's sensor_accel "
                                                               "temperatures -10.00 to 37.51 °C"),
    (["--onto", "{counts}", "--at", "20", "--params", "{out}"], "--onto: gyroscope reports in 'count'"),
    (["--onto", "{warm}", "--at", "20", "--params", "{out}"], "--onto: accelerometer has a thermal model already"),
])
def test_onto_refusals_are_one_line(warmup, tmp_path, capsys, argv, said):
    from fieldcal.thermal import ThermalModel

    _field_calibration(tmp_path / "field.yaml")
    _field_calibration(tmp_path / "counts.yaml", gyro_unit="count")
    _field_calibration(tmp_path / "warm.yaml", thermal=ThermalModel(
        reference_c=20.0, range_c=(10.0, 30.0), bias_terms=[[1e-3, 1e-3, 1e-3]], bias_terms_sigma=[[1e-5] * 3]))
    paths = {"field": tmp_path / "field.yaml", "counts": tmp_path / "counts.yaml", "warm": tmp_path / "warm.yaml",
             "out": tmp_path / "out.yaml"}
    assert main(["thermal", str(warmup), *(a.format(**paths) for a in argv)]) == 2
    err = capsys.readouterr().err
    assert said in err and err.count("\n") == 1
    assert not (tmp_path / "out.yaml").exists()


def test_a_real_px4_log_is_read_by_its_own_fields_and_too_short_a_one_is_one_line(tmp_path, capsys):
    """PX4's sample log (tests/data/real): sensor_accel and sensor_gyro with x, y, z,
    temperature and device_id as PX4 writes them, six samples each: read, and refused as too few."""
    from pyulog import ULog
    from xsens_logs import unpacked

    log = unpacked(tmp_path, "px4_sample_log_small.ulg.gz", "log.ulg")
    with pytest.raises(RecordingImportError, match="sensor_accel instance 0 has 6 samples with a finite reading "
                                                   "and temperature: too few for a thermal fit"):
        read_thermal_ulog(log)
    accel = next(d.data for d in ULog(str(log), ["sensor_accel"]).data_list if d.multi_id == 2)
    assert np.all(np.isfinite(accel["temperature"])) and len(accel["temperature"]) == 6
    assert main(["thermal", str(log), "--instance", "2"]) == 2
    err = capsys.readouterr().err
    assert "sensor_accel instance 2 has 6 samples" in err and err.count("\n") == 1
