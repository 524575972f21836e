"""Acceptance limits on the thermal model (issue 28): a spec's ``thermal`` entry limits each
triad's bias drift b₁ (the bias group's unit per K) and scale drift s₁ (ppm/K) per axis,
hand-worked; strict keys; a file without a thermal model fails "not calibrated for temperature"."""
from pathlib import Path

import numpy as np
import pytest

from fieldcal.acceptance import SpecError, evaluate, spec_from_document
from fieldcal.calibration import Calibration
from fieldcal.cli.main import main
from fieldcal.earth import Station
from fieldcal.paramfile import ParameterFile, load, save
from fieldcal.thermal import ThermalModel
from fieldcal.units import STANDARD_GRAVITY

MG = STANDARD_GRAVITY * 1e-3  # m/s² per mg
DEG_H = np.pi / 180 / 3600  # rad/s per °/h
OLD_FILE = Path(__file__).parent / "data" / "golden" / "headless-resumed" / "parameters.yaml"
THETA = [0.01, -0.02, 0.03, 1.0001, 0.9998, 1.0002, 1e-4, -2e-4, 3e-4]


def triad(name, kind, unit, b1, b1_sigma, s1=None, s1_sigma=None):
    """A calibration whose thermal model is b₁ (a second-order term too, which no limit reads)."""
    thermal = None if b1 is None else ThermalModel(
        reference_c=25.0, range_c=(20.0, 30.0), bias_terms=[b1, np.full(3, 1e-6)],
        bias_terms_sigma=[b1_sigma, np.full(3, 1e-7)], scale_drift=s1, scale_drift_sigma=s1_sigma)
    return Calibration(name=name, kind=kind, output_unit=unit, method="powell", theta=THETA,
                       sigma=np.full(9, 1e-5), residual_rms=1e-3, thermal=thermal)


def parameter_file(*triads):
    return ParameterFile.build(triads, station=Station(40.0, 50.0), procedure="field-18", method="powell",
                               input_sha256="0" * 64)


def spec(**triads):
    return spec_from_document({"schema": "fieldcal-spec/1", "product": "thermal unit", "triads": triads}, "spec.yaml")


def by_name(verdict):
    return {(c.triad, c.parameter): c for c in verdict.checks}


# accelerometer: b₁ = 0.3, -1.2, 0.8 mg/K (σ 0.02 mg/K), s₁ = 50, -30, 150 ppm/K (σ 5 ppm/K);
# gyroscope: b₁ = 72, -180, 10 °/h/K (0.02, -0.05, 0.0028 °/s/K), σ 4 °/h/K, no scale term
ACC = triad("accelerometer", "specific_force", "m/s^2", np.array([0.3, -1.2, 0.8]) * MG, [0.02 * MG] * 3,
            np.array([50.0, -30.0, 150.0]) * 1e-6, np.full(3, 5e-6))
GYR = triad("gyroscope", "angular_rate", "rad/s", np.array([72.0, -180.0, 10.0]) * DEG_H, [4 * DEG_H] * 3)
LIMITS = {"accelerometer": {"thermal": {"bias_drift": {"unit": "mg/K", "min": -1, "max": 1, "max_sigma": 0.05},
                                        "scale_drift": {"unit": "ppm/K", "min": -100, "max": 100}}},
          "gyroscope": {"thermal": {"bias_drift": {"unit": "°/h/K", "min": -100, "max": 100, "max_sigma": 3}}}}


def test_thermal_terms_against_their_limits_hand_worked():
    verdict = evaluate(spec(**LIMITS), parameter_file(ACC, GYR))
    checks = by_name(verdict)
    assert checks["accelerometer", "bias_drift_x"].passed
    assert checks["accelerometer", "bias_drift_x"].value == pytest.approx(0.3)
    assert checks["accelerometer", "bias_drift_x"].sigma == pytest.approx(0.02)
    assert checks["accelerometer", "bias_drift_x"].unit == "mg/K"
    assert checks["accelerometer", "bias_drift_y"].reasons == ("-1.2 mg/K below the minimum -1 mg/K",)
    assert checks["accelerometer", "scale_drift_y"].passed
    assert checks["accelerometer", "scale_drift_z"].reasons == ("150 ppm/K above the maximum 100 ppm/K",)
    assert checks["gyroscope", "bias_drift_x"].value == pytest.approx(72.0)
    assert checks["gyroscope", "bias_drift_y"].reasons == ("-180 °/h/K below the minimum -100 °/h/K",
                                                           "σ 4 °/h/K above the maximum 3 °/h/K")
    assert {(c.triad, c.parameter) for c in verdict.failures} == {
        ("accelerometer", "bias_drift_y"), ("accelerometer", "scale_drift_z"), ("gyroscope", "bias_drift_x"),
        ("gyroscope", "bias_drift_y"), ("gyroscope", "bias_drift_z")}  # the gyro's σ fails on every axis


def test_a_file_without_a_thermal_model_is_not_calibrated_for_temperature():
    no_model = triad("accelerometer", "specific_force", "m/s^2", None, None)
    verdict = evaluate(spec(accelerometer=LIMITS["accelerometer"]), parameter_file(no_model))
    assert not verdict.passed
    [bias, scale] = [c for c in verdict.checks if "drift" in c.parameter]
    assert (bias.parameter, scale.parameter) == ("bias_drift", "scale_drift")
    assert bias.reasons == ("not calibrated for temperature: the parameter file has no thermal model",)
    # a model without a scale term: its scale drift is not calibrated, its bias drift is checked
    verdict = evaluate(spec(gyroscope={"thermal": {"bias_drift": {"unit": "°/h/K", "max": 100},
                                                   "scale_drift": {"unit": "ppm/K", "max": 50}}}),
                       parameter_file(GYR))
    checks = by_name(verdict)
    assert checks["gyroscope", "scale_drift"].reasons == (
        "not calibrated for temperature: its thermal model has no scale term",)
    assert checks["gyroscope", "bias_drift_x"].passed


def test_an_old_file_checked_against_a_thermal_spec_fails_in_one_line_per_term(tmp_path, capsys):
    path = tmp_path / "spec.yaml"
    path.write_text("schema: fieldcal-spec/1\nproduct: thermal unit\ntriads:\n  accelerometer:\n"
                    "    bias: {unit: mg, min: -50, max: 50}\n    thermal:\n"
                    "      bias_drift: {unit: mg/K, min: -1, max: 1}\n")
    assert main(["check", str(OLD_FILE), "--spec", str(path)]) == 3
    out = capsys.readouterr().out
    assert "FAIL: not calibrated for temperature: the parameter file has no thermal model" in out
    assert "bias x" in out and "FAIL (1 of" in out


def test_an_order_zero_model_has_no_bias_drift_and_passes_its_range():
    flat = ThermalModel(reference_c=25.0, range_c=(20.0, 30.0), bias_terms=np.zeros((0, 3)),
                        bias_terms_sigma=np.zeros((0, 3)), scale_drift=[1e-5] * 3, scale_drift_sigma=[1e-6] * 3)
    cal = Calibration(name="accelerometer", kind="specific_force", output_unit="m/s^2", method="powell",
                      theta=THETA, sigma=np.full(9, 1e-5), residual_rms=1e-3, thermal=flat)
    checks = by_name(evaluate(spec(accelerometer=LIMITS["accelerometer"]), parameter_file(cal)))
    assert checks["accelerometer", "bias_drift_z"].passed and checks["accelerometer", "bias_drift_z"].value == 0.0
    assert checks["accelerometer", "scale_drift_x"].value == pytest.approx(10.0)


def test_a_thermal_file_round_trips_into_the_same_checks(tmp_path):
    back = load(save(parameter_file(ACC, GYR), tmp_path / "p.yaml"))
    assert [(c.parameter, c.reasons) for c in evaluate(spec(**LIMITS), back).checks] == \
        [(c.parameter, c.reasons) for c in evaluate(spec(**LIMITS), parameter_file(ACC, GYR)).checks]


@pytest.mark.parametrize("thermal, message", [
    ({"bias_drfit": {"unit": "mg/K", "max": 1}}, "triads.accelerometer.thermal.bias_drfit: expected one of "
     "bias_drift, scale_drift, got the unknown key 'bias_drfit' (nearest: 'bias_drift')"),
    ({"scale_drift": {"unit": "ppm/K", "max_drift": 1}}, "thermal.scale_drift.max_drift: expected one of unit, "
     "min, max, max_sigma"),
    ({"bias_drift": {"max": 1}}, "thermal.bias_drift.unit: expected a value"),
    ({}, "triads.accelerometer.thermal: expected limits on bias_drift or scale_drift"),
    ({"bias_drift": {"unit": "mg/K", "min": 2, "max": 1}}, "thermal.bias_drift.max: expected a number >= min"),
])
def test_a_bad_thermal_entry_is_one_line_naming_the_field(thermal, message):
    with pytest.raises(SpecError) as caught:
        spec(accelerometer={"thermal": thermal})
    assert message in str(caught.value) and "\n" not in str(caught.value)


def test_a_thermal_limit_in_another_unit_is_refused_naming_both():
    with pytest.raises(SpecError, match=r"thermal.bias_drift.unit: expected 'mg/K' .* got 'm/s\^2/K'"):
        evaluate(spec(accelerometer={"thermal": {"bias_drift": {"unit": "m/s^2/K", "max": 1}}}), parameter_file(ACC))
