"""PX4's thermal compensation export (issue 28): TC_A0_*/TC_G0_* applied as PX4's firmware applies
them (src/modules/temperature_compensation: offset = x0 + x1·dT + x2·dT² + x3·dT³ per axis, dT
held within TMIN..TMAX; src/lib/sensor_calibration: (data − thermal offset − CAL offset)·scale)
give back the true input of a unit whose whole model PX4 can hold."""
from __future__ import annotations

import numpy as np

from fieldcal.calibration import Calibration
from fieldcal.earth import Station
from fieldcal.export import export
from fieldcal.paramfile import ParameterFile
from fieldcal.thermal import ThermalModel

REF, LOW, HIGH = 25.0, 15.0, 40.0
ACC_TERMS = np.array([[3e-3, -5e-3, 8e-3], [1e-4, 0.0, -2e-4], [1e-6, 2e-6, 0.0]])  # m/s² per Kᵏ
GYRO_TERMS = np.array([[3.5e-4, -8.7e-4, 1.4e-3]])  # rad/s per K


def _cal(name, kind, theta, terms, drift=None):
    model = ThermalModel(reference_c=REF, range_c=(LOW, HIGH), bias_terms=terms, bias_terms_sigma=terms * 0,
                         scale_drift=drift, scale_drift_sigma=None if drift is None else np.zeros(3))
    return Calibration(name=name, kind=kind, output_unit="m/s^2" if kind == "specific_force" else "rad/s",
                       method="powell", theta=theta, sigma=np.zeros(9), residual_rms=0.0, thermal=model)


def _file(drift=None):
    # diagonal K: all of it is what PX4 holds (accelerometer scale; the gyro's is 1)
    acc = _cal("accelerometer", "specific_force", [0.01, -0.02, 0.03, 1.001, 0.999, 1.002, 0, 0, 0], ACC_TERMS, drift)
    gyro = _cal("gyroscope", "angular_rate", [1e-3, -2e-3, 3e-3, 1.0, 1.0, 1.0, 0, 0, 0], GYRO_TERMS)
    return ParameterFile.build((acc, gyro), station=Station(48.0, 500.0), procedure="field-18",
                               method="powell", input_sha256="0" * 64)


def _params(text: str) -> dict[str, float]:
    rows = [line.split("\t") for line in text.splitlines() if not line.startswith("#")]
    return {name: float(value) for _, _, name, value, _ in rows}


def _px4_correct(p: dict, sensor: str, cal: str, raw: np.ndarray, temperature: np.ndarray, scale: bool):
    """PX4's firmware, written out: the thermal offset, then CAL offset and scale."""
    dt = np.clip(temperature, p[f"TC_{sensor}0_TMIN"], p[f"TC_{sensor}0_TMAX"]) - p[f"TC_{sensor}0_TREF"]
    x = np.array([[p[f"TC_{sensor}0_X{k}_{i}"] for i in range(3)] for k in range(4)])
    offset = x[0] + dt[:, None] * x[1] + dt[:, None] ** 2 * x[2] + dt[:, None] ** 3 * x[3]
    corrected = raw - offset - np.array([p[f"CAL_{cal}0_{a}OFF"] for a in "XYZ"])
    return corrected * np.array([p[f"CAL_{cal}0_{a}SCALE"] for a in "XYZ"]) if scale else corrected


def test_px4_applies_the_exported_thermal_model_as_fieldcal_does():
    pf = _file()
    p = _params(export(pf, "px4"))
    assert p["TC_A_ENABLE"] == 1 and p["TC_G_ENABLE"] == 1
    assert (p["TC_A0_TREF"], p["TC_A0_TMIN"], p["TC_A0_TMAX"]) == (REF, LOW, HIGH)
    assert p["TC_G0_X2_0"] == 0.0 and p["TC_A0_X0_1"] == 0.0
    rng = np.random.default_rng(5)
    true = rng.normal(scale=9.8, size=(200, 3))
    temperature = rng.uniform(LOW, HIGH, size=200)
    for cal, sensor, name, scale in ((pf["accelerometer"], "A", "ACC", True), (pf["gyroscope"], "G", "GYRO", False)):
        dt = temperature[:, None] - REF
        terms = cal.thermal.bias_terms
        raw = true @ cal.K.T + cal.bias + sum(terms[k] * dt ** (k + 1) for k in range(len(terms)))
        np.testing.assert_allclose(_px4_correct(p, sensor, name, raw, temperature, scale), true, rtol=0, atol=1e-9)
        np.testing.assert_allclose(cal.calibrate(raw, temperature), true, rtol=0, atol=1e-9)


def test_outside_its_range_px4_holds_the_end_offset_and_says_so_in_the_file():
    pf = _file()
    text = export(pf, "px4")
    assert "holds the offset of the nearer end" in text and "set TC_A0_ID" in text
    p = _params(text)
    raw = np.zeros((2, 3))
    at_ends = _px4_correct(p, "G", "GYRO", raw, np.array([HIGH, LOW]), False)
    beyond = _px4_correct(p, "G", "GYRO", raw, np.array([HIGH + 10, LOW - 10]), False)
    np.testing.assert_array_equal(beyond, at_ends)


def test_the_scale_drift_px4_cannot_hold_is_named_with_its_cost():
    text = export(_file(drift=np.array([5e-5, -3e-5, 4e-5])), "px4")
    line = next(t for t in text.splitlines() if "dropped: scale drift" in t)
    # 50 ppm/K over 15 K from TREF at 1 g: 7.5e-4 g = 0.75 mg
    assert "+50, -30, +40 ppm/K" in line and "worst error 0.75 mg at 1 g" in line


def without_thermal(pf: ParameterFile) -> ParameterFile:
    """``pf``'s calibrations as a file without a thermal model writes them."""
    return ParameterFile(triads=tuple(Calibration(name=t.name, kind=t.kind, output_unit=t.output_unit,
                                                  method=t.method, theta=t.theta, sigma=t.sigma,
                                                  residual_rms=0.0) for t in pf.triads),
                         provenance=pf.provenance)


def test_files_without_a_thermal_model_export_as_before():
    plain = without_thermal(_file())
    assert "TC_" not in export(plain, "px4")
