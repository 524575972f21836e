"""PX4's and ArduPilot's thermal compensation lines at their edges (issue 26's mutation survivors
in fieldcal/export): one triad with a thermal model and the other without, a device reporting in
mg and °/s, the parameter types QGroundControl's file declares, two ranges that share one
temperature, and the comments that name each model. Truth: hand-worked unit conversions,
MAVLink's MAV_PARAM_TYPE numbering (6 = INT32, 9 = REAL32) and ArduPilot's INS_TCAL1 scaling
(SI units × 10⁶, AP_InertialSensor_tempcal.cpp SCALE_FACTOR)."""
from __future__ import annotations

import numpy as np
import pytest

from fieldcal.calibration import Calibration
from fieldcal.earth import Station
from fieldcal.export import FORMATS, export, exporter
from fieldcal.paramfile import ParameterFile
from fieldcal.thermal import ThermalModel

REF, LOW, HIGH = 25.0, 15.0, 40.0
MAV_PARAM_TYPE_INT32, MAV_PARAM_TYPE_REAL32 = 6, 9


def _cal(name, kind, unit, theta, terms=None, drift=None, range_c=(LOW, HIGH)):
    model = None if terms is None else ThermalModel(
        reference_c=REF, range_c=range_c, bias_terms=np.asarray(terms, dtype=float),
        bias_terms_sigma=np.zeros_like(np.asarray(terms, dtype=float)),
        scale_drift=None if drift is None else np.asarray(drift, dtype=float),
        scale_drift_sigma=None if drift is None else np.zeros(3))
    return Calibration(name=name, kind=kind, output_unit=unit, method="powell", theta=theta,
                       sigma=np.zeros(9), residual_rms=0.0, thermal=model)


def _file(acc_terms, gyro_terms, acc_unit="m/s^2", gyro_unit="rad/s", gyro_drift=None,
          acc_range=(LOW, HIGH), gyro_range=(LOW, HIGH)):
    acc = _cal("accelerometer", "specific_force", acc_unit, [0.01, -0.02, 0.03, 1.001, 0.999, 1.002, 0, 0, 0],
               acc_terms, range_c=acc_range)
    gyro = _cal("gyroscope", "angular_rate", gyro_unit, [1e-3, -2e-3, 3e-3, 1.0, 1.0, 1.0, 0, 0, 0], gyro_terms,
                gyro_drift, gyro_range)
    return ParameterFile.build((acc, gyro), station=Station(48.0, 500.0), procedure="field-18",
                               method="powell", input_sha256="0" * 64)


def _rows(text: str) -> dict[str, tuple[float, int]]:
    rows = [line.split("\t") for line in text.splitlines() if not line.startswith("#")]
    return {name: (float(value), int(kind)) for _, _, name, value, kind in rows}


def test_a_gyro_model_after_an_accelerometer_without_one_is_written():
    rows = _rows(export(_file(None, [[2e-4, -3e-4, 5e-4]]), "px4"))
    assert "TC_A_ENABLE" not in rows and not any(n.startswith("TC_A0_") for n in rows)
    assert rows["TC_G_ENABLE"] == (1.0, MAV_PARAM_TYPE_INT32)
    assert [rows[f"TC_G0_X1_{i}"][0] for i in range(3)] == [2e-4, -3e-4, 5e-4]
    assert (rows["TC_G0_TREF"][0], rows["TC_G0_TMIN"][0], rows["TC_G0_TMAX"][0]) == (REF, LOW, HIGH)


def test_every_value_but_the_enable_flags_is_a_float():
    rows = _rows(export(_file([[1e-3, 0.0, 2e-3]], [[2e-4, -3e-4, 5e-4]]), "px4"))
    assert {n for n, (_, kind) in rows.items() if kind == MAV_PARAM_TYPE_INT32} == {"TC_A_ENABLE", "TC_G_ENABLE"}
    assert all(kind == MAV_PARAM_TYPE_REAL32 for n, (_, kind) in rows.items() if not n.endswith("_ENABLE"))


def test_a_device_in_mg_and_degrees_per_second_gets_its_thermal_terms_in_si_units():
    # 2 mg/K = 2 · 9.80665e-3 m/s²/K; 0.01 °/s per K = 0.01 · π/180 rad/s per K; second order 3 mg/K².
    text = export(_file([[2.0, 0.0, -1.0], [3.0, 0.0, 0.0]], [[0.01, 0.0, 0.0]], "mg", "deg/s"), "px4")
    rows = _rows(text)
    assert rows["TC_A0_X1_0"][0] == pytest.approx(2 * 9.80665e-3, rel=1e-12)
    assert rows["TC_A0_X1_2"][0] == pytest.approx(-9.80665e-3, rel=1e-12)
    assert rows["TC_A0_X2_0"][0] == pytest.approx(3 * 9.80665e-3, rel=1e-12)
    assert rows["TC_A0_X3_0"][0] == 0.0 and rows["TC_A0_X0_0"][0] == 0.0
    assert rows["TC_G0_X1_0"][0] == pytest.approx(0.01 * np.pi / 180, rel=1e-12)


def test_each_model_is_named_in_a_comment_with_the_id_to_set():
    text = export(_file([[1e-3, 0.0, 2e-3], [1e-5, 0.0, 0.0]], [[2e-4, -3e-4, 5e-4]]), "px4")
    comments = [line for line in text.splitlines() if line.startswith("# TC_")]
    assert comments == [
        "# TC_A0: accelerometer's thermal model, order 2, about 25.00 °C over 15.00 to 40.00 °C "
        "(PX4 holds the offset of the nearer end outside it); set TC_A0_ID to the sensor's device id "
        "(CAL_ACC0_ID)",
        "# TC_G0: gyroscope's thermal model, order 1, about 25.00 °C over 15.00 to 40.00 °C "
        "(PX4 holds the offset of the nearer end outside it); set TC_G0_ID to the sensor's device id "
        "(CAL_GYRO0_ID)"]


def test_a_gyros_scale_drift_is_costed_at_100_degrees_per_second_in_ppm_to_three_digits():
    # The largest, 12.34999 ppm/K, over the 15 K from TREF to TMAX at 100 °/s:
    # 1.852e-4 · 100 °/s · 3600 s/h = 66.69 °/h; 12.34999 ppm/K is 12.3 at three digits, not 12.4.
    for fmt in ("px4", "ardupilot"):
        text = export(_file(None, [[2e-4, -3e-4, 5e-4]], gyro_drift=[1e-5, -1.234999e-5, 0.0]), fmt)
        line = next(t for t in text.splitlines() if "dropped: scale drift" in t)
        assert line == "#   dropped: scale drift +10, -12.3, +0 ppm/K; worst error 66.7 °/h at 100 °/s over the range"


@pytest.mark.parametrize("fmt", FORMATS)
def test_each_writer_called_alone_takes_the_triads_export_names_by_default(fmt):
    pf = _file([[1e-3, 0.0, 2e-3]], [[2e-4, -3e-4, 5e-4]])
    assert exporter(fmt)(pf) == export(pf, fmt)


def _ardupilot_rows(text: str) -> dict[str, float]:
    return {name: float(value) for name, value in
            (line.split(",") for line in text.splitlines() if line and not line.startswith("#"))}


def test_ardupilot_gets_the_thermal_terms_of_a_device_in_mg_and_degrees_per_second_in_si_units_times_a_million():
    # First order: re-centring on ArduPilot's 35 °C leaves the slope. 2 mg/K = 2 · 9.80665e-3 m/s²/K,
    # ×10⁶ = 19613.3; 0.01 °/s per K = 1.745329e-4 rad/s per K, ×10⁶ = 174.5329.
    rows = _ardupilot_rows(export(_file([[2.0, 0.0, -1.0]], [[0.01, 0.0, 0.0]], "mg", "deg/s"), "ardupilot"))
    assert rows["INS_TCAL1_ACC1_X"] == pytest.approx(19613.3, rel=1e-12)
    assert rows["INS_TCAL1_ACC1_Z"] == pytest.approx(-9806.65, rel=1e-12)
    assert rows["INS_TCAL1_ACC2_X"] == 0.0 and rows["INS_TCAL1_ACC3_X"] == 0.0
    assert rows["INS_TCAL1_GYR1_X"] == pytest.approx(0.01 * np.pi / 180 * 1e6, rel=1e-12)


def test_ardupilot_takes_two_ranges_that_share_one_temperature():
    rows = _ardupilot_rows(export(_file([[1e-3, 0.0, 2e-3]], [[2e-4, -3e-4, 5e-4]], acc_range=(LOW, REF),
                                        gyro_range=(REF, HIGH)), "ardupilot"))
    assert rows["INS_TCAL1_TMIN"] == rows["INS_TCAL1_TMAX"] == REF


@pytest.mark.parametrize("with_model, without", [("gyroscope", "ACC"), ("accelerometer", "GYR")])
def test_ardupilot_names_the_triad_without_a_thermal_model_it_leaves_to_the_vehicle(with_model, without):
    terms = [[1e-3, 0.0, 2e-3]]
    text = export(_file(terms if with_model == "accelerometer" else None,
                        terms if with_model == "gyroscope" else None), "ardupilot")
    comments = [line for line in text.splitlines() if line.startswith("# INS_TCAL1") or "no thermal model" in line]
    written = "ACC" if without == "GYR" else "GYR"
    assert comments == [
        "# INS_TCAL1: ArduPilot's polynomial about 35 °C, valid 15.00 to 40.00 °C (held at the nearer end "
        "outside it); no scale drift, one range per IMU (TCAL_* is the barometer's)",
        f"# INS_TCAL1_{written}k: {with_model}'s thermal model, order 1, about 25.00 °C",
        f"# not written, no thermal model (the vehicle keeps its own values): INS_TCAL1_{without}1..3_*"]
    rows = _ardupilot_rows(text)
    assert f"INS_TCAL1_{written}1_X" in rows and not any(n.startswith(f"INS_TCAL1_{without}") for n in rows)


@pytest.mark.parametrize("misnamed", ["accelerometer", "gyroscope"])
def test_the_c_header_alone_refuses_a_triad_named_for_the_other_kind(misnamed):
    """c_header writes every triad but checks that the ones named accelerometer and gyroscope
    are of those kinds (firmware takes FIELDCAL_<NAME>_* by the name): called without names, it
    checks those two, as export does."""
    from fieldcal.export.c_header import c_header

    # the misnamed triad, and one of the other kind under a neutral name
    rate = _cal("accelerometer" if misnamed == "accelerometer" else "rate", "angular_rate", "rad/s",
                [1e-3, -2e-3, 3e-3, 1.0, 1.0, 1.0, 0, 0, 0])
    force = _cal("gyroscope" if misnamed == "gyroscope" else "force", "specific_force", "m/s^2",
                 [0.01, -0.02, 0.03, 1.001, 0.999, 1.002, 0, 0, 0])
    pf = ParameterFile.build((force, rate), station=Station(48.0, 500.0), procedure="field-18",
                             method="powell", input_sha256="0" * 64)
    with pytest.raises(ValueError, match=f"--{misnamed} {misnamed}: that triad is"):
        c_header(pf)


def test_px4_writes_the_thermal_model_of_a_file_with_nothing_else_calibrated():
    """A PX4 thermal log's file: no offset or scale calibrated, only the thermal terms. The
    export writes those (and says which CAL_* it leaves to the vehicle) rather than refusing a
    file with nothing to write."""
    from fieldcal.model import PARAM_NAMES

    nominal = [0, 0, 0, 1, 1, 1, 0, 0, 0]
    triads = []
    for name, kind, unit, terms in (("accelerometer", "specific_force", "m/s^2", [[1e-3, 0.0, 2e-3]]),
                                    ("gyroscope", "angular_rate", "rad/s", [[2e-4, -3e-4, 5e-4]])):
        cal = _cal(name, kind, unit, nominal, terms)
        triads.append(Calibration(name=name, kind=kind, output_unit=unit, method="lsq", theta=nominal,
                                  sigma=np.zeros(9), residual_rms=0.0, thermal=cal.thermal,
                                  not_calibrated=PARAM_NAMES))
    pf = ParameterFile.build(triads, station=Station(0.0, 0.0), procedure="px4-thermal-log", method="lsq",
                             input_sha256="0" * 64)
    text = export(pf, "px4")
    rows = _rows(text)
    assert rows["TC_A_ENABLE"] == (1.0, MAV_PARAM_TYPE_INT32) and rows["TC_G0_X1_2"][0] == 5e-4
    assert not any(n.startswith("CAL_") for n in rows)
    assert "# not written, not calibrated (the vehicle keeps its own values): CAL_ACC0_XOFF" in text


def test_only_calibrated_alone_refuses_values_none_of_which_is_calibrated():
    """Called without ``more`` (nothing else written besides), a file whose every value is a
    nominal is refused in one line: a flight stack would take them for calibrated ones."""
    from fieldcal.export.autopilot import only_calibrated
    from fieldcal.model import PARAM_NAMES

    cal = Calibration(name="accelerometer", kind="specific_force", output_unit="m/s^2", method="lsq",
                      theta=[0, 0, 0, 1, 1, 1, 0, 0, 0], sigma=np.zeros(9), residual_rms=0.0,
                      not_calibrated=PARAM_NAMES, not_calibrated_why="a thermal log holds no offset")
    with pytest.raises(ValueError, match="^export px4: none of what px4 holds is calibrated in this file "
                                         r"\(accelerometer: a thermal log holds no offset\)$"):
        only_calibrated("px4", [("CAL_ACC0_XOFF", 0.0, cal, "bias_x")])
