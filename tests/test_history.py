"""The previous calibration of a unit: found among sibling sessions, and checked against the
SHA-256 its session recorded, so a hand-edited file is not taken as the calibration (issue 16)."""
from __future__ import annotations

import os

import numpy as np

from fieldcal.earth import Station
from fieldcal.paramfile import ParameterFile, TriadParameters, dump, hash_inputs
from fieldcal.session.capture import SessionWriter
from fieldcal.session.history import EDITED, UNRECORDED, VERIFIED, previous_calibration

STATION = Station(latitude_deg=48.15, height_m=520.0)


def _parameters(bias_x: float, serial: str = "A1") -> ParameterFile:
    triad = TriadParameters(name="accelerometer", kind="specific_force", output_unit="m/s^2",
                            bias=np.array([bias_x, -0.02, 0.03]), K=np.eye(3) * 1.001,
                            sigma=np.full(9, 1e-4), residual_rms=1e-3, method="powell")
    return ParameterFile.build([triad], station=STATION, procedure="field-18", method="powell",
                               input_sha256=hash_inputs(np.zeros(3)), device_name="imu",
                               device_serial=serial)


def _session(directory, pf: ParameterFile, mtime_ns: int) -> None:
    w = SessionWriter.create(directory, {})
    w.write_parameters(pf)
    w.stop("completed")
    w.close()
    for written in directory.glob("parameters*.yaml"):
        os.utime(written, ns=(mtime_ns, mtime_ns))


def test_the_newest_file_of_the_same_unit_is_found_and_verified(tmp_path):
    _session(tmp_path / "old", _parameters(0.01), 1_000_000_000)
    _session(tmp_path / "new", _parameters(0.02), 2_000_000_000)
    _session(tmp_path / "other-unit", _parameters(0.03, serial="B2"), 3_000_000_000)
    (tmp_path / "damaged").mkdir()
    (tmp_path / "damaged" / "parameters.yaml").write_text("schema: nonsense\n")
    found, unreadable = previous_calibration(tmp_path, "imu", "A1")
    assert unreadable == 1
    assert found.path == tmp_path / "new" / "parameters.yaml"
    assert found.parameters["accelerometer"].bias[0] == 0.02
    assert found.check == VERIFIED and not found.edited
    assert "edited" not in found.describe() and "not verified" not in found.describe()


def test_an_old_session_re_solved_today_is_not_the_units_newest_calibration(tmp_path):
    """`fieldcal resolve` writes parameters-002.yaml and parameters.yaml into an old session
    now; the unit's previous calibration is still the session measured last."""
    _session(tmp_path / "old", _parameters(0.01), 1_000_000_000)
    _session(tmp_path / "new", _parameters(0.02), 2_000_000_000)
    w = SessionWriter.append_to(tmp_path / "old")
    w.write_parameters(_parameters(0.011))  # the re-solve, written with today's time
    w.close()
    found, _ = previous_calibration(tmp_path, "imu", "A1")
    assert found.path == tmp_path / "new" / "parameters.yaml"


def test_a_file_edited_after_calibration_is_said_to_be(tmp_path):
    _session(tmp_path / "s", _parameters(0.01), 1_000_000_000)
    path = tmp_path / "s" / "parameters.yaml"
    # A careful hand edit: still a valid, self-consistent file, but not the one calibrated.
    path.write_text(dump(_parameters(0.05)))
    found, _ = previous_calibration(tmp_path, "imu", "A1")
    assert found.parameters["accelerometer"].bias[0] == 0.05  # loaded, so the values can be shown
    assert found.check == EDITED and found.edited
    assert "EDITED AFTER CALIBRATION" in found.describe() and str(path) in found.describe()


def test_a_re_solved_sessions_genuine_file_is_verified_against_the_newest_calibration(tmp_path):
    """parameters.yaml is a copy of the newest numbered file: after a re-solve its SHA-256 is the
    one the log recorded last, not the first calibration's; the file the first wrote is still
    checked against its own record."""
    from fieldcal.session.history import recorded_check

    _session(tmp_path / "s", _parameters(0.01), 1_000_000_000)
    w = SessionWriter.append_to(tmp_path / "s")
    w.write_parameters(_parameters(0.011))  # the re-solve
    w.close()
    s = tmp_path / "s"
    assert (s / "parameters.yaml").read_bytes() == (s / "parameters-002.yaml").read_bytes() \
        != (s / "parameters-001.yaml").read_bytes()
    found, _ = previous_calibration(tmp_path, "imu", "A1")
    assert found.parameters["accelerometer"].bias[0] == 0.011
    assert found.check == VERIFIED and not found.edited
    assert recorded_check(s / "parameters-001.yaml") == VERIFIED
    assert recorded_check(s / "parameters-002.yaml") == VERIFIED
    # and the first calibration's values put back by hand are an edit of the current file
    (s / "parameters.yaml").write_bytes((s / "parameters-001.yaml").read_bytes())
    assert recorded_check(s / "parameters.yaml") == EDITED


def test_a_file_without_a_recorded_checksum_is_not_called_verified(tmp_path):
    (tmp_path / "copied").mkdir()
    (tmp_path / "copied" / "parameters.yaml").write_text(dump(_parameters(0.01)))
    found, _ = previous_calibration(tmp_path, "imu", "A1")
    assert found.check == UNRECORDED and "not verified" in found.describe()


def test_the_session_being_written_is_excluded(tmp_path):
    _session(tmp_path / "today", _parameters(0.01), 1_000_000_000)
    assert previous_calibration(tmp_path, "imu", "A1", exclude=tmp_path / "today") == (None, 0)
    assert previous_calibration(tmp_path, None, None) == (None, 0)
