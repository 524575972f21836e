"""Parameters the data did not determine (issue 27): marked not calibrated in the parameter file
(nominal value, no σ), and every reader of the file honours the mark."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from fieldcal.calibration import Calibration, with_not_calibrated
from fieldcal.earth import Station
from fieldcal.model import ANGULAR_RATE, PARAM_NAMES, SPECIFIC_FORCE
from fieldcal.paramfile import ParameterFile, ParameterFileError, dump, load, loads

DATA = Path(__file__).parent / "data"
STATION = Station(latitude_deg=48.15, height_m=520.0)
ACC_THETA = np.array([0.05, -0.03, 0.02, 1.001, 0.998, 1.002, 1e-3, -2e-3, 5e-4])
GYRO_THETA = np.array([0.3, -0.2, 0.1, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0])  # deg/s: nominal scale 180/π
GYRO_THETA[3:6] = 180 / np.pi


def _cal(name, kind, unit, theta, method="powell") -> Calibration:
    return Calibration(name=name, kind=kind, output_unit=unit, method=method, theta=theta,
                       sigma=np.full(9, 1e-4), residual_rms=1e-3)


def partial_file() -> ParameterFile:
    """The accelerometer's x and y biases alone calibrated (poses too alike); the gyro's bias alone
    (still poses)."""
    acc = with_not_calibrated(_cal("accelerometer", SPECIFIC_FORCE, "m/s^2", ACC_THETA),
                              [n for n in PARAM_NAMES if n not in ("bias_x", "bias_y")],
                              "the poses are too alike: add poses with x or y up")
    gyro = with_not_calibrated(_cal("gyroscope", ANGULAR_RATE, "deg/s", GYRO_THETA, "still"), PARAM_NAMES[3:],
                               "rests only: add rotations between poses")
    return ParameterFile.from_solutions([acc, gyro], station=STATION, procedure="recording",
                                        inputs=[np.zeros(3)])


def test_marked_parameters_are_nominal_with_no_sigma_and_the_rest_kept():
    pf = partial_file()
    acc, gyro = pf["accelerometer"], pf["gyroscope"]
    assert acc.calibrated == ("bias_x", "bias_y")
    np.testing.assert_array_equal(acc.theta[:2], ACC_THETA[:2])
    np.testing.assert_array_equal(acc.theta[2:], [0.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0])
    np.testing.assert_array_equal(acc.K, np.eye(3))
    assert np.all(np.isnan(acc.sigma[2:])) and np.all(acc.sigma[:2] == 1e-4)
    assert gyro.calibrated == PARAM_NAMES[:3]
    np.testing.assert_allclose(np.diag(gyro.K), np.full(3, 180 / np.pi), rtol=1e-15)


def test_marks_round_trip_exactly_and_say_why(tmp_path):
    pf = partial_file()
    text = dump(pf)
    doc = yaml.safe_load(text)
    acc = doc["triads"]["accelerometer"]
    assert acc["not_calibrated"] == {"version": 1, "parameters": list(PARAM_NAMES[2:]),
                                     "why": "the poses are too alike: add poses with x or y up"}
    assert acc["bias"]["sigma"] == {"x": 1e-4, "y": 1e-4, "z": None}
    assert acc["scale_factor"]["sigma"] == {"x": None, "y": None, "z": None}
    again = loads(text)
    assert again == pf and dump(again) == text
    assert again["accelerometer"].not_calibrated == PARAM_NAMES[2:]


def test_old_files_load_unmarked_and_are_written_back_byte_for_byte():
    """A file from before the marks (the golden session's, written by an earlier fieldcal) reads
    as every parameter calibrated, and writes back to the very same bytes."""
    path = DATA / "golden" / "headless-resumed" / "parameters.yaml"
    pf = load(path)
    assert all(t.not_calibrated == () and t.calibrated == PARAM_NAMES for t in pf.triads)
    assert all(np.all(np.isfinite(t.sigma)) for t in pf.triads)
    assert dump(pf) == path.read_text()


def _edited(mutate) -> str:
    doc = yaml.safe_load(dump(partial_file()))
    mutate(doc)
    return yaml.safe_dump(doc, sort_keys=False)


@pytest.mark.parametrize("mutate, field", [
    (lambda d: d["triads"]["accelerometer"]["bias"]["sigma"].update(z=1e-4), "bias.sigma.z"),
    (lambda d: d["triads"]["accelerometer"]["bias"].update(z=0.02), "bias.z"),
    (lambda d: d["triads"]["accelerometer"]["not_calibrated"].update(version=2), "not_calibrated.version"),
    (lambda d: d["triads"]["accelerometer"]["not_calibrated"].update(parameters=["scale_q"]),
     "not_calibrated.parameters"),
    (lambda d: d["triads"]["accelerometer"]["bias"]["sigma"].update(x=None), "bias.sigma.x"),
])
def test_a_hand_edited_mark_is_refused_in_one_line(mutate, field):
    """A σ given to a parameter marked not calibrated, a value moved off its nominal, a mark of a
    version or name not known, or a calibrated parameter's σ taken away: refused, field named."""
    with pytest.raises(ParameterFileError) as info:
        loads(_edited(mutate), "p.yaml")
    message = str(info.value)
    assert "\n" not in message and f"triads.accelerometer.{field}" in message


def test_a_scale_in_counts_cannot_be_left_at_a_nominal():
    counts = Calibration(name="accelerometer", kind=SPECIFIC_FORCE, output_unit="count", method="powell",
                         theta=[0, 0, 0, 1000.0, 1000.0, 1000.0, 0, 0, 0], sigma=np.ones(9), residual_rms=1.0)
    with pytest.raises(ValueError, match="no nominal value"):
        with_not_calibrated(counts, ["scale_z"])
    assert with_not_calibrated(counts, ["bias_z"]).calibrated == tuple(n for n in PARAM_NAMES if n != "bias_z")


# ---------------------------------------------------------------------------------------------
# apply, export, check and the certificate honour the marks


def test_apply_corrects_only_what_is_calibrated_and_says_so(tmp_path, capsys):
    """The gyro's bias alone calibrated (deg/s): apply takes the bias off and converts deg/s to
    rad/s, nothing else; the accelerometer's z axis passes through as read. stderr names what
    was not calibrated."""
    from fieldcal.cli.main import main

    pf = partial_file()
    from fieldcal.paramfile import save
    save(pf, tmp_path / "p.yaml")
    rows = np.array([[0.0, 1.0, 2.0, 9.8, 0.3, -0.2, 0.1], [0.01, 0.5, -0.5, 9.7, 1.3, 0.8, -0.9]])
    (tmp_path / "in.csv").write_text("t,ax,ay,az,gx,gy,gz\n" + "\n".join(",".join(repr(float(v)) for v in r) for r in rows) + "\n")
    (tmp_path / "map.yaml").write_text(yaml.safe_dump({"description": "one csv", "files": [{
        "name": "csv", "delimiter": ",", "time": {"column": 0, "unit": "s"},
        "triads": {"accelerometer": {"columns": [1, 2, 3], "kind": "specific_force", "unit": "m/s^2"},
                   "gyroscope": {"columns": [4, 5, 6], "kind": "angular_rate", "unit": "deg/s"}}}]}))
    code = main(["apply", str(tmp_path / "p.yaml"), str(tmp_path / "in.csv"), "--map",
                 str(tmp_path / "map.yaml"), "--out", str(tmp_path / "out.csv")])
    err = capsys.readouterr().err
    assert code == 0, err
    assert "apply: accelerometer: bias_z, scale_x" in err and "only bias_x, bias_y corrected" in err
    assert "apply: gyroscope: scale_x" in err and "not calibrated" in err
    out = np.loadtxt(tmp_path / "out.csv", delimiter=",", skiprows=1)
    np.testing.assert_allclose(out[:, 1:3], rows[:, 1:3] - ACC_THETA[:2], rtol=1e-15)
    np.testing.assert_array_equal(out[:, 3], rows[:, 3])  # z: as read
    np.testing.assert_allclose(out[:, 4:], np.radians(rows[:, 4:] - GYRO_THETA[:3]), rtol=1e-12)


def _export(pf, fmt):
    from fieldcal.export import export
    return export(pf, fmt)


def test_px4_and_ardupilot_get_only_calibrated_values_and_the_reason():
    """A flight stack keeps its own value of a parameter a file leaves out: the nominal scale
    and z offset are not written (a nominal would pass for a calibration), the reason is."""
    pf = partial_file()
    px4 = _export(pf, "px4")
    names = [line.split("\t")[2] for line in px4.splitlines() if not line.startswith("#")]
    assert names == ["CAL_ACC0_XOFF", "CAL_ACC0_YOFF", "CAL_GYRO0_XOFF", "CAL_GYRO0_YOFF", "CAL_GYRO0_ZOFF"]
    assert ("# not written, not calibrated (the vehicle keeps its own values): CAL_ACC0_ZOFF, CAL_ACC0_XSCALE, "
            "CAL_ACC0_YSCALE, CAL_ACC0_ZSCALE") in px4
    assert "the poses are too alike" in px4
    ardupilot = _export(pf, "ardupilot")
    assert [line.split(",")[0] for line in ardupilot.splitlines() if not line.startswith("#")] == [
        "INS_ACCOFFS_X", "INS_ACCOFFS_Y", "INS_GYROFFS_X", "INS_GYROFFS_Y", "INS_GYROFFS_Z"]
    assert float(ardupilot.split("INS_ACCOFFS_X,")[1].split()[0]) == ACC_THETA[0]


def test_a_diagonal_format_with_nothing_calibrated_to_hold_is_refused():
    acc = with_not_calibrated(_cal("accelerometer", SPECIFIC_FORCE, "m/s^2", ACC_THETA), PARAM_NAMES, "rests only")
    gyro = with_not_calibrated(_cal("gyroscope", ANGULAR_RATE, "deg/s", GYRO_THETA), PARAM_NAMES, "no turns")
    pf = ParameterFile.from_solutions([acc, gyro], station=STATION, procedure="recording", inputs=[np.zeros(3)])
    with pytest.raises(ValueError, match="export px4: none of what px4 holds is calibrated"):
        _export(pf, "px4")


@pytest.mark.parametrize("fmt", ["c-header", "imucal-json"])
def test_formats_that_hold_every_term_refuse_a_file_with_marks(fmt):
    with pytest.raises(ValueError) as info:
        _export(partial_file(), fmt)
    message = str(info.value)
    assert "\n" not in message and f"export {fmt}: accelerometer: bias_z" in message and "not calibrated" in message


def test_json_export_keeps_the_marks():
    import json
    doc = json.loads(_export(partial_file(), "json"))
    assert doc["triads"]["gyroscope"]["not_calibrated"]["parameters"] == list(PARAM_NAMES[3:])
    assert doc["triads"]["gyroscope"]["scale_factor"]["sigma"] == {"x": None, "y": None, "z": None}


def _spec():
    from fieldcal.acceptance import spec_from_document
    return spec_from_document({"schema": "fieldcal-spec/1", "product": "test unit", "triads": {
        "accelerometer": {"bias": {"unit": "mg", "min": -10, "max": 10}},
        "gyroscope": {"bias": {"unit": "°/h", "min": -2e5, "max": 2e5}}}})


def test_check_fails_a_limited_parameter_that_is_not_calibrated_and_never_passes_one():
    """bias_z is limited and not calibrated: FAIL "not calibrated" though its nominal 0 is within
    the limits; an unlimited one not calibrated reads "not calibrated", never PASS."""
    from fieldcal.acceptance import evaluate, verdict_lines

    verdict = evaluate(_spec(), partial_file())
    failed = {(c.triad, c.parameter) for c in verdict.failures}
    assert failed == {("accelerometer", "bias_z")}
    check = next(c for c in verdict.checks if c.parameter == "bias_z" and c.triad == "accelerometer")
    assert check.reasons[0].startswith("not calibrated: the poses are too alike") and check.sigma is None
    assert not verdict.passed
    table = "\n".join(verdict_lines(verdict))
    scale_rows = [line for line in table.splitlines() if "scale x" in line]
    assert scale_rows and all("not calibrated (no limit)" in line and "PASS" not in line for line in scale_rows)


def test_the_certificate_shows_not_calibrated_for_those_parameters():
    from fieldcal.acceptance import evaluate
    from fieldcal.certificate import _triad_section

    pf, spec = partial_file(), _spec()
    verdict = evaluate(spec, pf)
    checks = {(c.triad, c.parameter): c for c in verdict.checks}
    html = _triad_section(pf["accelerometer"], checks, True, None, spec)
    rows = html.split("<tr>")
    bias_z = next(r for r in rows if r.startswith("<td>bias z"))
    assert "not calibrated" in bias_z and "FAIL: not calibrated" in bias_z and "nan" not in html
    scale_x = next(r for r in rows if r.startswith("<td>scale x"))
    assert "not calibrated (no limit)" in scale_x and "PASS" not in scale_x
    bias_x = next(r for r in rows if r.startswith("<td>bias x"))
    assert "PASS" in bias_x


def test_the_registry_indexes_only_calibrated_parameters(tmp_path):
    """A nominal is nothing of the unit to track: its row is left out (the registry's σ column
    holds numbers), so a later calibration that does determine it shows no drift from it."""
    from dataclasses import replace

    from fieldcal.paramfile import save
    from fieldcal.registry import Registry

    pf = partial_file()
    pf = replace(pf, provenance=replace(pf.provenance, device_serial="U1"))
    registry = Registry(tmp_path / "registry.sqlite")
    assert registry.record(save(pf, tmp_path / "p.yaml"))
    [entry] = registry.history("U1")
    assert set(entry["parameters"]) == {("accelerometer", "bias_x"), ("accelerometer", "bias_y"),
                                        ("gyroscope", "bias_x"), ("gyroscope", "bias_y"), ("gyroscope", "bias_z")}
