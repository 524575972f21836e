"""ArduPilot's IMU temperature calibration export (INS_TCAL1_*, issue 28) applied as ArduPilot's
firmware applies it (libraries/AP_InertialSensor/AP_InertialSensor_tempcal.cpp correct_sensor:
v −= p(T − 35) − p(T_cal − 35), p(x) = (c₁x + c₂x² + c₃x³)·10⁻⁶, T and T_cal held within
TMIN..TMAX; then AP_InertialSensor_Backend: v −= offsets, v *= scales) gives back the true input."""
from __future__ import annotations

import numpy as np
import pytest

from fieldcal.calibration import Calibration
from fieldcal.earth import Station
from fieldcal.export import export
from fieldcal.model import PARAM_NAMES
from fieldcal.paramfile import ParameterFile
from fieldcal.thermal import ThermalModel
from test_thermal_export import without_thermal

REF, LOW, HIGH = 25.0, 15.0, 40.0
ACC_TERMS = np.array([[3e-3, -5e-3, 8e-3], [1e-4, 0.0, -2e-4], [1e-6, 2e-6, 0.0]])  # m/s² per Kᵏ
GYRO_TERMS = np.array([[3.5e-4, -8.7e-4, 1.4e-3]])  # rad/s per K


def _cal(name, kind, theta, terms, drift=None, range_c=(LOW, HIGH), not_calibrated=()):
    model = ThermalModel(reference_c=REF, range_c=range_c, bias_terms=terms, bias_terms_sigma=terms * 0,
                         scale_drift=drift, scale_drift_sigma=None if drift is None else np.zeros(3))
    return Calibration(name=name, kind=kind, output_unit="m/s^2" if kind == "specific_force" else "rad/s",
                       method="powell", theta=theta, sigma=np.zeros(9), residual_rms=0.0, thermal=model,
                       not_calibrated=not_calibrated)


def _file(drift=None, gyro_range=(LOW, HIGH)):
    acc = _cal("accelerometer", "specific_force", [0.01, -0.02, 0.03, 1.001, 0.999, 1.002, 0, 0, 0], ACC_TERMS, drift)
    gyro = _cal("gyroscope", "angular_rate", [1e-3, -2e-3, 3e-3, 1.0, 1.0, 1.0, 0, 0, 0], GYRO_TERMS,
                range_c=gyro_range)
    return ParameterFile.build((acc, gyro), station=Station(48.0, 500.0), procedure="field-18",
                               method="powell", input_sha256="0" * 64)


def _params(text: str) -> dict[str, float]:
    return {name: float(value) for name, value in
            (line.split(",") for line in text.splitlines() if line and not line.startswith("#"))}


def _ardupilot_correct(p: dict, sensor: str, raw, temperature, caltemp: float | None = None, scale: bool = True):
    """ArduPilot's firmware, written out: the temperature correction, then offsets and scales."""
    tmin, tmax = p["INS_TCAL1_TMIN"], p["INS_TCAL1_TMAX"]
    c = np.array([[p[f"INS_TCAL1_{sensor}{k}_{a}"] for a in "XYZ"] for k in (1, 2, 3)])

    def poly(tdiff):
        tdiff = np.asarray(tdiff, dtype=float)[..., None]
        return (c[0] + (c[1] + c[2] * tdiff) * tdiff) * tdiff * 1e-6

    cal = p[f"INS_{sensor}1_CALTEMP"] if caltemp is None else caltemp
    v = raw - poly(np.clip(temperature, tmin, tmax) - 35.0) + poly(np.clip(cal, tmin, tmax) - 35.0)
    name = {"ACC": "ACC", "GYR": "GYR"}[sensor]
    v = v - np.array([p[f"INS_{name}OFFS_{a}"] for a in "XYZ"])
    return v * np.array([p[f"INS_ACCSCAL_{a}"] for a in "XYZ"]) if scale else v


def test_ardupilot_applies_the_exported_thermal_model_as_fieldcal_does():
    pf = _file()
    p = _params(export(pf, "ardupilot"))
    assert p["INS_TCAL1_ENABLE"] == 1 and (p["INS_TCAL1_TMIN"], p["INS_TCAL1_TMAX"]) == (LOW, HIGH)
    assert p["INS_ACC1_CALTEMP"] == REF and p["INS_GYR1_CALTEMP"] == REF
    rng = np.random.default_rng(5)
    true = rng.normal(scale=9.8, size=(200, 3))
    temperature = rng.uniform(LOW, HIGH, size=200)
    for cal, sensor, scale in ((pf["accelerometer"], "ACC", True), (pf["gyroscope"], "GYR", False)):
        dt = temperature[:, None] - REF
        terms = cal.thermal.bias_terms
        raw = true @ cal.K.T + cal.bias + sum(terms[k] * dt ** (k + 1) for k in range(len(terms)))
        # K is diagonal here: all of it is what ArduPilot holds (the gyro's scale is 1)
        np.testing.assert_allclose(_ardupilot_correct(p, sensor, raw, temperature, scale=scale), true,
                                   rtol=0, atol=1e-9)
        np.testing.assert_allclose(cal.calibrate(raw, temperature), true, rtol=0, atol=1e-9)


def test_a_thermal_only_file_leaves_the_vehicles_offsets_and_their_temperature_to_it():
    """A PX4 thermal log's file: nothing but the thermal terms is calibrated. The vehicle keeps
    its offsets and the temperature they were calibrated at; the correction moves the bias by its
    change from there."""
    nominal = [0, 0, 0, 1, 1, 1, 0, 0, 0]
    acc = _cal("accelerometer", "specific_force", nominal, ACC_TERMS, not_calibrated=PARAM_NAMES)
    gyro = _cal("gyroscope", "angular_rate", nominal, GYRO_TERMS, not_calibrated=PARAM_NAMES)
    pf = ParameterFile.build((acc, gyro), station=Station(0.0, 0.0), procedure="px4-thermal-log", method="lsq",
                             input_sha256="0" * 64)
    text = export(pf, "ardupilot")
    p = _params(text)
    assert not any(n.startswith(("INS_ACCOFFS", "INS_GYROFFS", "INS_ACCSCAL")) or n.endswith("CALTEMP") for n in p)
    vehicle = {"INS_ACCOFFS_X": 0.1, "INS_ACCOFFS_Y": -0.2, "INS_ACCOFFS_Z": 0.3,
               "INS_ACCSCAL_X": 1.0, "INS_ACCSCAL_Y": 1.0, "INS_ACCSCAL_Z": 1.0}
    caltemp = 30.0  # the vehicle's offsets were calibrated at 30 °C
    temperature = np.linspace(LOW, HIGH, 25)
    dt = temperature[:, None] - REF
    bias = np.array([0.1, -0.2, 0.3]) + sum(ACC_TERMS[k] * (dt ** (k + 1) - (caltemp - REF) ** (k + 1))
                                            for k in range(3))
    corrected = _ardupilot_correct({**p, **vehicle}, "ACC", bias, temperature, caltemp=caltemp)
    np.testing.assert_allclose(corrected, 0.0, atol=1e-9)


def test_the_common_range_of_both_triads_is_written_and_what_it_cannot_hold_is_said():
    text = export(_file(drift=np.array([5e-5, -3e-5, 4e-5]), gyro_range=(18.0, 45.0)), "ardupilot")
    p = _params(text)
    assert (p["INS_TCAL1_TMIN"], p["INS_TCAL1_TMAX"]) == (18.0, HIGH)
    assert "no scale drift, one range per IMU (TCAL_* is the barometer's)" in text
    line = next(t for t in text.splitlines() if "dropped: scale drift" in t)
    assert "+50, -30, +40 ppm/K" in line and "worst error 0.75 mg at 1 g" in line
    with pytest.raises(ValueError, match="share no temperature"):
        export(_file(gyro_range=(41.0, 50.0)), "ardupilot")


def test_files_without_a_thermal_model_export_to_ardupilot_as_before():
    text = export(without_thermal(_file()), "ardupilot")
    assert "TCAL" not in text and "CALTEMP" not in text
    assert list(_params(text))[:2] == ["INS_ACCOFFS_X", "INS_ACCSCAL_X"]
