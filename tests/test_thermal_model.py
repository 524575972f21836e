"""The thermal model (issue 28): bias(T) and scale(T) applied by Calibration.calibrate, refused
outside its range, and kept in the parameter file's versioned ``thermal`` section; files without
the section load and apply exactly as before."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from fieldcal.calibration import Calibration
from fieldcal.earth import Station
from fieldcal.model import k_from_params
from fieldcal.paramfile import ParameterFile, ParameterFileError, dump, load, loads
from fieldcal.thermal import TemperatureOutOfRange, ThermalModel

OLD_FILE = Path(__file__).parent / "data" / "golden" / "headless-resumed" / "parameters.yaml"
STATION = Station(latitude_deg=48.15, height_m=520.0)
THETA = np.array([0.05, -0.03, 0.02, 1.001, 0.998, 1.002, 1e-3, -2e-3, 5e-4])
# b1 (m/s² per K), b2 (per K²), b3 (per K³) per axis; s1 per axis (1/K)
TERMS = np.array([[1e-3, -2e-3, 5e-3], [1e-5, 0.0, -2e-5], [1e-7, 3e-7, 0.0]])
DRIFT = np.array([1e-4, -5e-5, 2e-5])


def _thermal(order: int = 3, drift: bool = True) -> ThermalModel:
    return ThermalModel(reference_c=25.0, range_c=(15.0, 40.0), bias_terms=TERMS[:order],
                        bias_terms_sigma=np.abs(TERMS[:order]) * 0.1 + 1e-9,
                        scale_drift=DRIFT if drift else None, scale_drift_sigma=DRIFT * 0 + 1e-6 if drift else None)


def _calibration(thermal: ThermalModel | None, name: str = "accelerometer") -> Calibration:
    return Calibration(name=name, kind="specific_force", output_unit="m/s^2", method="powell",
                       theta=THETA, sigma=np.full(9, 1e-4), residual_rms=1e-3, thermal=thermal)


def _true_raw(true: np.ndarray, temperature: np.ndarray) -> np.ndarray:
    """The forward model written out independently: raw = diag(1 + s1 ΔT) K true + b0 + Σ bk ΔTᵏ."""
    K = k_from_params(THETA)
    dt = temperature - 25.0
    bias = THETA[:3] + sum(TERMS[k] * dt[:, None] ** (k + 1) for k in range(3))
    return (1 + DRIFT * dt[:, None]) * (true @ K.T) + bias


def test_calibrate_inverts_the_thermal_forward_model_per_sample():
    rng = np.random.default_rng(3)
    true = rng.normal(scale=9.8, size=(50, 3))
    temperature = rng.uniform(15.0, 40.0, size=50)
    out = _calibration(_thermal()).calibrate(_true_raw(true, temperature), temperature)
    np.testing.assert_allclose(out, true, rtol=0, atol=1e-12)


def test_calibrate_hand_worked_value():
    # K = I, b0 = 0, b1 = 0.01, b2 = 0.001, s1 = 1e-3 at ΔT = 2 K:
    # offset 0.01·2 + 0.001·4 = 0.024, ratio 1.002, so (1.024 − 0.024) / 1.002 = 0.998003992...
    model = ThermalModel(reference_c=20.0, range_c=(20.0, 30.0), bias_terms=[[0.01] * 3, [0.001] * 3],
                         bias_terms_sigma=np.zeros((2, 3)), scale_drift=[1e-3] * 3, scale_drift_sigma=[0.0] * 3)
    cal = Calibration(name="acc", kind="specific_force", output_unit="m/s^2", method="powell",
                      theta=[0, 0, 0, 1, 1, 1, 0, 0, 0], sigma=np.zeros(9), residual_rms=0.0, thermal=model)
    np.testing.assert_allclose(cal.calibrate([1.024, 2.024, -0.976], 22.0),
                               [1.0 / 1.002, 2.0 / 1.002, -1.0 / 1.002], rtol=1e-14)


def test_outside_the_range_is_refused_in_one_line_unless_asked_to_extrapolate():
    cal = _calibration(_thermal())
    raw = np.zeros((4, 3))
    with pytest.raises(TemperatureOutOfRange) as exc:
        cal.calibrate(raw, [20.0, 41.5, 10.0, 30.0])
    message = str(exc.value)
    assert "\n" not in message and "accelerometer" in message and "2 of 4" in message
    assert "10.00 to 41.50" in message and "15.00 to 40.00" in message
    with pytest.raises(TemperatureOutOfRange, match="NaN"):
        cal.calibrate(raw, [20.0, np.nan, 25.0, 30.0])
    true = np.ones((1, 3))
    out = cal.calibrate(_true_raw(true, np.array([45.0])), 45.0, extrapolate=True)
    np.testing.assert_allclose(out, true, atol=1e-12)
    np.testing.assert_array_equal(cal.thermal.outside([14.9, 15.0, 40.0, 40.1]), [True, False, False, True])


def test_a_thermal_model_needs_the_temperature():
    with pytest.raises(ValueError, match="give the temperature"):
        _calibration(_thermal()).calibrate(np.zeros(3))
    with pytest.raises(ValueError, match="one temperature per sample"):
        _calibration(_thermal()).calibrate(np.zeros((3, 3)), [25.0, 25.0])


def test_without_a_thermal_model_the_temperature_changes_nothing():
    cal = _calibration(None)
    raw = np.random.default_rng(1).normal(size=(20, 3))
    expected = np.linalg.solve(k_from_params(THETA), (raw - THETA[:3]).T).T
    np.testing.assert_array_equal(cal.calibrate(raw), expected)
    np.testing.assert_array_equal(cal.calibrate(raw, np.full(20, 80.0)), expected)


def test_order_zero_with_scale_drift_only():
    model = ThermalModel(reference_c=25.0, range_c=(20.0, 30.0), bias_terms=np.zeros((0, 3)),
                         bias_terms_sigma=np.zeros((0, 3)), scale_drift=[1e-3, 0, 0], scale_drift_sigma=[0, 0, 0])
    assert model.order == 0
    np.testing.assert_array_equal(model.bias_offset([21.0, 29.0]), np.zeros((2, 3)))
    np.testing.assert_allclose(model.scale_ratio([30.0])[0], [1.005, 1.0, 1.0])


@pytest.mark.parametrize("bad, message", [
    (dict(bias_terms=np.zeros((4, 3)), bias_terms_sigma=np.zeros((4, 3))), "order 0 to 3"),
    (dict(range_c=(30.0, 20.0)), "low <= high"),
    (dict(reference_c=-300.0), "temperature in °C"),
    (dict(bias_terms_sigma=-np.ones((3, 3))), ">= 0"),
    (dict(scale_drift_sigma=None), "or neither"),
])
def test_invalid_models_are_refused(bad, message):
    kw = dict(reference_c=25.0, range_c=(15.0, 40.0), bias_terms=TERMS, bias_terms_sigma=np.ones((3, 3)),
              scale_drift=DRIFT, scale_drift_sigma=np.ones(3))
    with pytest.raises(ValueError, match=message):
        ThermalModel(**{**kw, **bad})


# The parameter file -------------------------------------------------------------------------

def _file(*triads: Calibration) -> ParameterFile:
    return ParameterFile.build(triads, station=STATION, procedure="field-18", method="powell",
                               input_sha256="0" * 64)


@pytest.mark.parametrize("order, drift", [(0, True), (1, False), (3, True)])
def test_thermal_section_round_trips_exactly(order, drift):
    pf = _file(_calibration(_thermal(order, drift)), _calibration(None, "inclinometer"))
    text = dump(pf)
    back = loads(text)
    assert back == pf and dump(back) == text
    model = back["accelerometer"].thermal
    np.testing.assert_array_equal(model.bias_terms, TERMS[:order])
    assert (model.scale_drift is None) == (not drift) and back["inclinometer"].thermal is None
    section = yaml.safe_load(text)["triads"]["accelerometer"]["thermal"]
    assert section["version"] == 1 and section["bias"]["order"] == order
    assert "thermal" not in yaml.safe_load(text)["triads"]["inclinometer"]


def test_a_different_thermal_model_makes_a_different_calibration():
    other = ThermalModel(reference_c=25.0, range_c=(15.0, 40.1), bias_terms=TERMS,
                         bias_terms_sigma=np.abs(TERMS) * 0.1 + 1e-9, scale_drift=DRIFT,
                         scale_drift_sigma=DRIFT * 0 + 1e-6)
    assert _calibration(_thermal()) != _calibration(other) and _calibration(_thermal()) != _calibration(None)


def test_old_files_load_and_apply_exactly_as_before():
    text = OLD_FILE.read_text()
    pf = load(OLD_FILE)
    assert all(t.thermal is None for t in pf.triads)
    assert dump(pf) == text  # written back byte for byte: no thermal section appears
    raw = np.random.default_rng(2).normal(scale=9.8, size=(10, 3))
    for t in pf.triads:
        expected = np.linalg.solve(t.K, (raw - t.bias).T).T
        np.testing.assert_array_equal(t.calibrate(raw), expected)
        np.testing.assert_array_equal(t.calibrate(raw, np.full(10, 60.0)), expected)


def _edited(mutate) -> str:
    doc = yaml.safe_load(dump(_file(_calibration(_thermal()))))
    mutate(doc["triads"]["accelerometer"]["thermal"])
    return yaml.safe_dump(doc, sort_keys=False)


@pytest.mark.parametrize("mutate, message", [
    (lambda m: m.update(refrence_temperature_c=25.0), "unknown key 'refrence_temperature_c'; did you mean "
                                                      "'reference_temperature_c'?"),
    (lambda m: m["bias"].update(sigmas={}), "unknown key 'sigmas'; did you mean 'sigma'?"),
    (lambda m: m.update(version=2), "thermal.version: expected 1 (fieldcal"),
    (lambda m: m["bias"].update(x=[1e-3, 2e-3]), "thermal.bias.x: expected a list of 3 numbers"),
    (lambda m: m["bias"].update(order=4), "thermal.bias.order: expected a whole number from 0 to 3"),
    (lambda m: m["bias"]["sigma"].update(y=[1e-3, -1.0, 0.0]), "thermal.bias.sigma.y[1]: expected a number >= 0"),
    (lambda m: m["range_c"].update(high=10.0), "thermal.range_c.high: expected a number from 15"),
    (lambda m: m["bias"].update(unit="mg per K"), "thermal.bias.unit: expected 'm/s^2 per K^k'"),
    (lambda m: m["scale_factor"].update(unit="ppm/K"), "thermal.scale_factor.unit: expected '1/K'"),
    (lambda m: m.pop("range_c"), "thermal.range_c: missing"),
])
def test_bad_thermal_sections_are_refused_in_one_line(mutate, message):
    with pytest.raises(ParameterFileError) as exc:
        loads(_edited(mutate), "params.yaml")
    assert message in str(exc.value)
    assert str(exc.value).startswith("params.yaml: triads.accelerometer.thermal") and "\n" not in str(exc.value)
