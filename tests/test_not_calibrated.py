"""Parameters the data did not determine (issue 27): marked not calibrated in the parameter file
(nominal value, no σ), and every reader of the file honours the mark."""
from __future__ import annotations

import copy
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
