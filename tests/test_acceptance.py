"""Acceptance limits: a product spec loaded strictly, and PASS/FAIL per parameter against
hand-worked calibrations and against a simulated unit's known truth."""

import numpy as np
import pytest

from fieldcal.acceptance import SpecError, evaluate, load_spec, spec_from_document
from fieldcal.calibration import Calibration
from fieldcal.cli.main import main
from fieldcal.earth import Station
from fieldcal.model import k_from_params
from fieldcal.paramfile import ParameterFile, save
from fieldcal.units import STANDARD_GRAVITY
from brisk_quick import brisk_quick

MG = STANDARD_GRAVITY * 1e-3  # m/s² per mg
STATION = Station(40.0, 50.0)


def accelerometer(bias_mg, scale=(1.0, 1.0, 1.0), angles_mrad=(0.0, 0.0, 0.0), sigma_mg=0.01,
                  residual_mg=0.5, unit="m/s^2", per_unit=1.0):
    theta = np.r_[np.array(bias_mg) * MG * per_unit, np.array(scale) * per_unit, np.array(angles_mrad) * 1e-3]
    sigma = np.r_[[sigma_mg * MG * per_unit] * 3, [1e-5 * per_unit] * 3, [1e-5] * 3]
    return Calibration(name="accelerometer", kind="specific_force", output_unit=unit, method="powell",
                       K=k_from_params(theta), bias=theta[:3], sigma=sigma,
                       residual_rms=residual_mg * MG * per_unit)


def parameter_file(*triads, serial="A1"):
    return ParameterFile.build(triads, station=STATION, procedure="field-18", method="powell",
                               input_sha256="0" * 64, device_name="sim", device_serial=serial)


def spec(**triad):
    return spec_from_document({"schema": "fieldcal-spec/1", "product": "test unit",
                               "triads": {"accelerometer": triad}}, "spec.yaml")


def by_name(verdict):
    return {(c.triad, c.parameter): c for c in verdict.checks}


def test_each_limit_fails_the_parameter_it_names_with_the_reason():
    pf = parameter_file(accelerometer([5.0, 3.0, -1.0], scale=(1.002, 1.0, 1.0), residual_mg=1.5))
    verdict = evaluate(spec(bias={"unit": "mg", "min": -4, "max": 4},
                            scale={"unit": "1", "min": 0.999, "max": 1.001},
                            max_residual={"unit": "mg", "value": 1.0}), pf)
    checks = by_name(verdict)
    assert not verdict.passed
    assert checks["accelerometer", "bias_x"].reasons == ("5 mg above the maximum 4 mg",)
    assert checks["accelerometer", "bias_x"].value == pytest.approx(5.0)
    assert checks["accelerometer", "bias_y"].passed and checks["accelerometer", "bias_z"].passed
    assert checks["accelerometer", "scale_x"].reasons == ("1.002 1 above the maximum 1.001 1",)
    assert checks["accelerometer", "scale_y"].passed
    assert checks["accelerometer", "residual"].reasons == ("RMS 1.5 mg above the maximum 1 mg",)
    assert {c.parameter for c in verdict.failures} == {"bias_x", "scale_x", "residual"}


def test_a_parameter_entry_overrides_its_group_and_sigma_is_limited():
    pf = parameter_file(accelerometer([5.0, 3.0, -1.0], angles_mrad=(0.5, -2.0, 0.0), sigma_mg=0.2))
    verdict = evaluate(spec(bias={"unit": "mg", "min": -4, "max": 4, "max_sigma": 0.1},
                            bias_x={"unit": "mg", "max": 6},
                            misalignment={"unit": "mrad", "min": -1, "max": 1}), pf)
    checks = by_name(verdict)
    # bias_x: its own max (6 mg) passes the value; the group's max_sigma still applies
    assert checks["accelerometer", "bias_x"].reasons == ("σ 0.2 mg above the maximum 0.1 mg",)
    assert checks["accelerometer", "delta_zy"].reasons == ("-2 mrad below the minimum -1 mrad",)
    assert checks["accelerometer", "delta_yz"].passed


def test_drift_since_the_previous_calibration_in_operator_units_and_sigma():
    previous = parameter_file(accelerometer([2.0, 3.0, -1.0], sigma_mg=0.03))
    today = parameter_file(accelerometer([5.0, 3.5, -1.0], sigma_mg=0.04))
    verdict = evaluate(spec(bias={"unit": "mg", "max_drift": 1.0}), today, previous)
    x, y = by_name(verdict)["accelerometer", "bias_x"], by_name(verdict)["accelerometer", "bias_y"]
    assert x.drift == pytest.approx(3.0) and x.drift_sigma == pytest.approx(3.0 / 0.05)
    assert x.reasons == ("drifted 3 mg since the previous calibration, more than 1 mg",)
    assert y.passed and y.drift == pytest.approx(0.5)
    # without a previous calibration the drift is not checked, and the verdict says so
    alone = evaluate(spec(bias={"unit": "mg", "max_drift": 1.0}), today)
    assert alone.passed and any("drift not checked" in n for n in alone.notes)


def test_a_triad_the_spec_names_and_the_file_lacks_fails():
    doc = {"schema": "fieldcal-spec/1", "product": "p",
           "triads": {"gyroscope": {"bias": {"unit": "°/h", "max": 100}}}}
    verdict = evaluate(spec_from_document(doc), parameter_file(accelerometer([0, 0, 0])))
    assert not verdict.passed and "not in the parameter file" in verdict.failures[0].reasons[0]
    assert any("not checked: accelerometer" in n for n in verdict.notes)


def test_a_spec_in_another_unit_than_the_file_is_refused_naming_both():
    counts = parameter_file(accelerometer([1, 1, 1], unit="count", per_unit=1000.0))
    with pytest.raises(SpecError, match=r"triads\.accelerometer\.bias\.unit: expected 'count'.*got 'mg'"):
        evaluate(spec(bias={"unit": "mg", "max": 4}), counts)


@pytest.mark.parametrize("text, message", [
    ("schema: fieldcal-spec/1\nproduct: p\ntriads: {accelerometer: {bais: {unit: mg}}}\n",
     r"triads\.accelerometer\.bais: .*nearest: 'bias'"),
    ("schema: fieldcal-spec/1\nproduct: p\ntriads: {accelerometer: {bias: {unit: mg, max_sigmaa: 1}}}\n",
     r"bias\.max_sigmaa: .*nearest: 'max_sigma'"),
    ("schema: fieldcal-spec/1\nproduct: p\ntriads: {accelerometer: {bias: {max: 1}}}\n",
     r"triads\.accelerometer\.bias\.unit: expected a value, got nothing"),
    ("schema: fieldcal-spec/1\nproduct: p\ntriads: {accelerometer: {bias: {unit: mg, max: '4'}}}\n",
     r"bias\.max: expected a number"),
    ("schema: fieldcal-spec/1\nproduct: p\ntriads: {accelerometer: {bias: {unit: mg, min: 4, max: 1}}}\n",
     r"bias\.max: expected a number >= min"),
    ("schema: fieldcal-spec/1\nproduct: p\ntriads: {accelerometer: {bias: {unit: mg, max_sigma: -1}}}\n",
     r"bias\.max_sigma: expected a number >= 0"),
    ("schema: fieldcal-spec/1\nproduct: !!python/object:os.system x\ntriads: {}\n", r"not valid YAML"),
    ("schema: fieldcal-spec/2\nproduct: p\ntriads: {a: {}}\n", r"schema: expected 'fieldcal-spec/1'"),
])
def test_a_bad_spec_is_one_line_naming_the_file_and_field(tmp_path, text, message):
    path = tmp_path / "spec.yaml"
    path.write_text(text)
    with pytest.raises(SpecError, match=message) as info:
        load_spec(path)
    assert str(info.value).startswith(str(path)) and "\n" not in str(info.value)


SPEC_TEXT = """\
schema: fieldcal-spec/1
product: paper MIMU
triads:
  accelerometer:
    bias: {unit: mg, min: -10, max: %s}
    scale: {unit: "1", min: 0.999, max: 1.001}
    misalignment: {unit: mrad, min: -2, max: 2}
"""


def test_check_exit_status_says_pass_or_fail(tmp_path, capsys):
    params = save(parameter_file(accelerometer([1.0, 2.0, 3.0])), tmp_path / "p.yaml")
    (tmp_path / "ok.yaml").write_text(SPEC_TEXT % "10")
    (tmp_path / "tight.yaml").write_text(SPEC_TEXT % "2.5")
    assert main(["check", str(params), "--spec", str(tmp_path / "ok.yaml")]) == 0
    assert "paper MIMU: PASS" in capsys.readouterr().out
    assert main(["check", str(params), "--spec", str(tmp_path / "tight.yaml")]) == 3
    out = capsys.readouterr().out
    assert "FAIL: 3 mg above the maximum 2.5 mg" in out and "paper MIMU: FAIL (1 of" in out
    (tmp_path / "bad.yaml").write_text("schema: fieldcal-spec/1\nproduct: p\ntriads: {a: {sacle: {unit: '1'}}}\n")
    assert main(["check", str(params), "--spec", str(tmp_path / "bad.yaml")]) == 2
    assert "nearest: 'scale'" in capsys.readouterr().err


def test_headless_run_with_a_spec_against_the_simulated_truth(tmp_path, capsys):
    """paper_mimu's accelerometer has biases 1, 2, 3 mg and scale factors 1.0001..1.0003: a spec
    allowing ±10 mg passes, one capping the bias at 2.5 mg fails bias_z only."""
    quick = str(brisk_quick(tmp_path))  # quick.yaml with brisk rate steps: none of this checks their speed
    (tmp_path / "ok.yaml").write_text(SPEC_TEXT % "10")
    (tmp_path / "tight.yaml").write_text(SPEC_TEXT % "2.5")
    argv = ["run", "--headless", "--quiet", "--procedure", quick, "--out", str(tmp_path / "s"),
            "--unit-serial", "PAPER-1", "--seed"]  # one unit: its drift is taken (issue 23)
    assert main([*argv, "3", "--spec", str(tmp_path / "ok.yaml")]) == 0
    assert "paper MIMU: PASS" in capsys.readouterr().out
    assert main([*argv, "4", "--spec", str(tmp_path / "tight.yaml")]) == 3
    out = capsys.readouterr().out
    failed = [line for line in out.splitlines() if "FAIL:" in line]
    assert len(failed) == 1 and "bias z" in failed[0] and "above the maximum 2.5 mg" in failed[0]
    assert "drift since" in out  # the first run's session is this unit's previous calibration
    # a spec in another unit than the unit's is refused after the run, which is still recorded
    from fieldcal.registry import Registry
    (tmp_path / "counts.yaml").write_text(SPEC_TEXT.replace("unit: mg", "unit: count") % "10")
    registry = tmp_path / "r.sqlite"
    assert main([*argv, "5", "--spec", str(tmp_path / "counts.yaml"), "--registry", str(registry)]) == 2
    assert "expected 'mg'" in capsys.readouterr().err
    with Registry(registry) as r:
        assert r.db.execute("SELECT COUNT(*), MAX(passed) FROM calibrations").fetchone() == (1, None)


def test_calibrate_with_a_spec_in_the_device_unit(tmp_path, capsys):
    """The hand-held simulation's accelerometer biases are 32778, 32762 and 32784 counts: a spec
    capping them at 32772 count fails x and z, and a wrong unit in the spec is refused first."""
    from drivers.sim.handheld import simulate_handheld, to_text

    acc, gyro = to_text(simulate_handheld(3), tmp_path)
    spec = tmp_path / "spec.yaml"
    spec.write_text("schema: fieldcal-spec/1\nproduct: handheld\ntriads:\n"
                    "  accelerometer: {bias: {unit: count, min: 32700, max: 32772}}\n")
    argv = ["calibrate", str(acc), str(gyro), "--map", "imu_tk", "--latitude", "40", "--gravity", "9.80",
            "--out", str(tmp_path / "s"), "--registry", str(tmp_path / "r.sqlite"), "--spec", str(spec)]
    assert main(argv) == 3
    out = capsys.readouterr().out
    failed = sorted(line.split()[2] for line in out.splitlines() if "FAIL:" in line)
    assert failed == ["x", "z"] and "above the maximum 32772 count" in out
    (tmp_path / "bad.yaml").write_text("schema: fieldcal-spec/1\nproduct: p\ntriads: {a: {bias: {unit: mg, maxx: 1}}}\n")
    argv[-1] = str(tmp_path / "bad.yaml")
    assert main(argv) == 2  # refused before anything is imported
    assert "nearest: 'max'" in capsys.readouterr().err and len(list((tmp_path / "s").iterdir())) == 1
