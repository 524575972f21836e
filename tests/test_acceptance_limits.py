"""Acceptance limits at their edges, in the device's own unit where every value is exact: a limit
is met when the value equals it, a parameter with no limit or not calibrated is shown as it is,
and drift is compared only between two calibrations of one unit. Asked for by mutation testing
(issue 26): each of these survived a mutant of fieldcal/acceptance.py before."""
import numpy as np
import pytest

from fieldcal.acceptance import Check, Limit, SpecError, TriadSpec, evaluate, spec_from_document
from fieldcal.calibration import Calibration, with_not_calibrated
from test_acceptance import parameter_file, spec

SCALE = 400.0  # counts per m/s²: every bias below is a whole number of counts, exact in binary


def counts(bias, sigma=0.5, scale=SCALE, name="accelerometer", kind="specific_force"):
    theta = np.r_[bias, [scale] * 3, [0.0] * 3]
    return Calibration(name=name, kind=kind, output_unit="count", method="powell",
                       theta=theta, sigma=np.r_[[sigma] * 3, [0.25] * 3, [0.0] * 3], residual_rms=1.0,
                       residual_unit="count")


BIAS_LIMITS = {"unit": "count", "min": 32760, "max": 32780, "max_sigma": 0.5, "max_drift": 2}


def test_a_value_equal_to_its_limit_meets_it():
    """At the minimum, at the maximum, σ at its maximum and drifts of ±2 counts against 2: PASS."""
    today = parameter_file(counts([32760.0, 32780.0, 32770.0]))
    previous = parameter_file(counts([32758.0, 32782.0, 32770.0]))
    verdict = evaluate(spec(bias=BIAS_LIMITS), today, previous)
    biases = [c for c in verdict.checks if c.parameter.startswith("bias")]
    assert [c.reasons for c in biases] == [(), (), ()] and verdict.passed
    assert [c.drift for c in biases] == [2.0, -2.0, 0.0] and [c.sigma for c in biases] == [0.5] * 3
    assert biases[0].drift_sigma == pytest.approx(2.0 / np.hypot(0.5, 0.5))
    assert verdict.notes == ()  # the same unit, a previous calibration: the drift was checked


def test_one_count_past_each_limit_fails_it():
    today = parameter_file(counts([32759.0, 32781.0, 32770.0], sigma=0.75))
    previous = parameter_file(counts([32759.0, 32781.0, 32767.0]))
    checks = evaluate(spec(bias=BIAS_LIMITS), today, previous).checks
    assert [c.reasons for c in checks[:3]] == [
        ("32759 count below the minimum 32760 count", "σ 0.75 count above the maximum 0.5 count"),
        ("32781 count above the maximum 32780 count", "σ 0.75 count above the maximum 0.5 count"),
        ("σ 0.75 count above the maximum 0.5 count",
         "drifted 3 count since the previous calibration, more than 2 count")]


def test_a_parameter_with_no_limit_is_shown_with_its_value_and_sigma():
    verdict = evaluate(spec(bias=BIAS_LIMITS), parameter_file(counts([32770.0] * 3)))
    scale_x = next(c for c in verdict.checks if c.parameter == "scale_x")
    # a scale factor in counts is shown per g (9.80665 m/s²)
    assert (scale_x.value, scale_x.sigma) == (pytest.approx(SCALE * 9.80665), pytest.approx(0.25 * 9.80665))
    assert scale_x.reasons == () and scale_x.calibrated


@pytest.mark.parametrize("why, reason", [
    ("", "not calibrated: the data did not determine it"),
    ("still poses only: add poses with z up", "not calibrated: still poses only: add poses with z up"),
])
def test_a_parameter_not_calibrated_fails_its_limit_and_keeps_its_nominal_value(why, reason):
    cal = with_not_calibrated(counts([32770.0] * 3), ["bias_z", "delta_zx"], why)
    checks = {c.parameter: c for c in evaluate(spec(bias=BIAS_LIMITS), parameter_file(cal)).checks}
    bias_z, angle = checks["bias_z"], checks["delta_zx"]
    assert (bias_z.value, bias_z.sigma, bias_z.reasons, bias_z.calibrated) == (0.0, None, (reason,), False)
    assert (angle.value, angle.reasons, angle.calibrated) == (0.0, (), False)  # no limit: no failure


def test_no_drift_sigma_when_neither_calibration_has_one():
    today = parameter_file(counts([32772.0] * 3, sigma=0.0))
    previous = parameter_file(counts([32770.0] * 3, sigma=0.0))
    bias_x = evaluate(spec(bias=BIAS_LIMITS), today, previous).checks[0]
    assert (bias_x.drift, bias_x.drift_sigma) == (2.0, None)


def test_a_parameters_own_entry_in_another_unit_is_named_with_the_triad():
    limits = spec(bias=BIAS_LIMITS, bias_x={"unit": "mg", "max": 4})
    with pytest.raises(SpecError) as info:
        evaluate(limits, parameter_file(counts([32770.0] * 3)))
    assert str(info.value) == ("spec.yaml: triads.accelerometer.bias_x.unit: expected 'count' (the unit triad "
                               "'accelerometer' is shown in), got 'mg'")
    assert info.value.field == "triads.accelerometer.bias_x"


def test_an_entry_in_another_unit_than_its_group_takes_none_of_the_groups_limits():
    triad = TriadSpec("accelerometer", {"bias": Limit("mg", min=-4.0, max=4.0),
                                        "bias_x": Limit("count", max_sigma=0.5)})
    assert triad.limit_for("bias_x") == Limit("count", max_sigma=0.5)
    assert triad.limit_for("bias_y") == Limit("mg", min=-4.0, max=4.0)


def test_a_triad_the_file_lacks_is_one_failed_check_naming_what_the_file_has():
    doc = {"schema": "fieldcal-spec/1", "product": "p", "triads": {"gyroscope": {"bias": {"unit": "°/h"}}}}
    verdict = evaluate(spec_from_document(doc), parameter_file(counts([32770.0] * 3)))
    assert verdict.checks == (Check("gyroscope", "triad", None, None, "",
                                    ("not in the parameter file (it has accelerometer)",)),)


def test_the_spec_checks_every_triad_it_names_and_notes_the_others():
    """A spec naming a magnetometer first: its check fails, the accelerometer's are still made."""
    pf = parameter_file(counts([32770.0] * 3), counts([0.0] * 3, name="gyro1", kind="angular_rate"),
                        counts([0.0] * 3, name="gyro2", kind="angular_rate"))
    doc = {"schema": "fieldcal-spec/1", "product": "p",
           "triads": {"magnetometer": {"bias": {"unit": "count"}}, "accelerometer": {"bias": BIAS_LIMITS}}}
    verdict = evaluate(spec_from_document(doc), pf)
    assert verdict.checks[0].reasons == ("not in the parameter file (it has accelerometer, gyro1, gyro2)",)
    assert [c.triad for c in verdict.checks[1:]] == ["accelerometer"] * 9
    assert verdict.notes == ("drift not checked: no previous calibration of this unit",
                             "not in the spec, not checked: gyro1, gyro2")


def test_a_residual_equal_to_its_limit_meets_it():
    verdict = evaluate(spec(max_residual={"unit": "count", "value": 1}), parameter_file(counts([32770.0] * 3)))
    assert verdict.checks[-1] == Check("accelerometer", "residual", 1.0, None, "count", ())


def test_a_residual_limit_in_another_unit_names_the_entry_and_the_triad():
    with pytest.raises(SpecError) as info:
        evaluate(spec(max_residual={"unit": "mg", "value": 1}), parameter_file(counts([32770.0] * 3)))
    assert str(info.value) == ("spec.yaml: triads.accelerometer.max_residual.unit: expected 'count' (the unit "
                               "triad 'accelerometer' is shown in), got 'mg'")
    assert (info.value.path, info.value.field) == ("spec.yaml", "triads.accelerometer.max_residual")


def test_a_unit_that_is_not_a_string_is_named_with_its_entry():
    with pytest.raises(SpecError) as info:
        spec(bias={"unit": 5})
    assert str(info.value) == ("spec.yaml: triads.accelerometer.bias.unit: expected a non-empty string (quote it), "
                               "got 5")


def test_a_residual_limit_below_one_is_kept():
    assert spec(max_residual={"unit": "mg", "value": 0.5}).triads[0].max_residual == (0.5, "mg")


def test_a_limit_may_be_negative_or_a_single_value():
    assert spec(bias={"unit": "mg", "min": -20, "max": -10}).triads[0].limits == {
        "bias": Limit("mg", min=-20.0, max=-10.0)}
    assert spec(bias={"unit": "mg", "min": 4, "max": 4}).triads[0].limits == {"bias": Limit("mg", min=4.0, max=4.0)}


SCHEMA = {"schema": "fieldcal-spec/1", "product": "p"}


@pytest.mark.parametrize("doc, line, field", [
    ({**SCHEMA, "triads": {"accelerometer": {"bias": 5}}},
     "triads.accelerometer.bias: expected a mapping, got 5", "triads.accelerometer.bias"),
    (["x"], "expected a mapping, got a list of 1 item", ""),
    ({**SCHEMA, "triads": {"accelerometer": {"bias": {"unit": "mg", "maxx": 1}}}},
     "triads.accelerometer.bias.maxx: expected one of unit, min, max, max_sigma, max_drift, got the unknown key "
     "'maxx' (nearest: 'max')", "triads.accelerometer.bias.maxx"),
    (SCHEMA, "triads: expected a value, got nothing (the key is missing)", "triads"),
    ({**SCHEMA, "triads": {"a": {"max_residual": {"value": 1}}}},
     "triads.a.max_residual.unit: expected a value, got nothing (the key is missing)", "triads.a.max_residual.unit"),
    ({**SCHEMA, "triads": {"accelerometer": {"bias": {"unit": "mg", "min": 4, "max": 1}}}},
     "triads.accelerometer.bias.max: expected a number >= min (4), got 1", "triads.accelerometer.bias.max"),
    ({"schema": "fieldcal-spec/2", "product": "p", "triads": {"a": {}}},
     "schema: expected 'fieldcal-spec/1', got 'fieldcal-spec/2'", "schema"),
    ({"schema": "fieldcal-spec/1", "product": 5, "triads": {"a": {}}},
     "product: expected a non-empty string (quote it), got 5", "product"),
    ({**SCHEMA, "triads": {}}, "triads: expected a mapping of triad name to limits, got an empty mapping", "triads"),
    ({**SCHEMA, "triads": ["a"]}, "triads: expected a mapping of triad name to limits, got a list of 1 item", "triads"),
    ({**SCHEMA, "triads": {5: {}}}, "triads: expected triad names that are non-empty strings, got 5", "triads"),
    ({**SCHEMA, "triads": {"": {}}}, "triads: expected triad names that are non-empty strings, got ''", "triads"),
    ({**SCHEMA, "triads": {"a": {"max_residual": 3}}}, "triads.a.max_residual: expected a mapping, got 3",
     "triads.a.max_residual"),
    ({**SCHEMA, "triads": {"a": {"max_residual": {"unit": "mg", "value": -1}}}},
     "triads.a.max_residual.value: expected a number >= 0, got -1", "triads.a.max_residual.value"),
    ({**SCHEMA, "triads": {"a": {"max_residual": {"unit": 5, "value": 1}}}},
     "triads.a.max_residual.unit: expected a non-empty string (quote it), got 5", "triads.a.max_residual.unit"),
])
def test_a_bad_spec_document_is_one_line_naming_the_field(doc, line, field):
    """The line names the file, the field, what it must be and what it is."""
    with pytest.raises(SpecError) as info:
        spec_from_document(doc, "spec.yaml")
    assert (str(info.value), info.value.path, info.value.field) == (f"spec.yaml: {line}", "spec.yaml", field)


def test_a_spec_built_from_a_document_alone_is_named_as_such():
    assert spec_from_document({**SCHEMA, "triads": {"a": {}}}).path == "<spec>"
