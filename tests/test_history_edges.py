"""The previous calibration's edges (issue 26's mutation survivors in session/history.py): a unit
known only by half its identity, exclusions and damaged files in any directory order, and the
checksum check of a session whose data files are gone."""
from __future__ import annotations

import numpy as np

from fieldcal.earth import Station
from fieldcal.paramfile import ParameterFile, TriadParameters, hash_inputs
from fieldcal.session.capture import SessionWriter
from fieldcal.session.history import VERIFIED, previous_calibration, recorded_check

STATION = Station(latitude_deg=48.15, height_m=520.0)


def _parameters(bias_x: float, name: str | None = "imu", serial: str | None = "A1") -> ParameterFile:
    triad = TriadParameters(name="accelerometer", kind="specific_force", output_unit="m/s^2",
                            bias=np.array([bias_x, -0.02, 0.03]), K=np.eye(3) * 1.001,
                            sigma=np.full(9, 1e-4), residual_rms=1e-3, method="powell")
    return ParameterFile.build([triad], station=STATION, procedure="field-18", method="powell",
                               input_sha256=hash_inputs(np.zeros(3)), device_name=name,
                               device_serial=serial)


def _session(directory, pf: ParameterFile, raw: bytes | None = None) -> None:
    w = SessionWriter.create(directory, {})
    if raw is not None:
        w.write_raw("imu", 0.0, raw)
    w.write_parameters(pf)
    w.stop("completed")
    w.close()


def test_a_unit_missing_its_serial_or_its_name_has_no_previous_calibration(tmp_path):
    """Half an identity matches nothing, not even a file with the same half missing: two units
    without serials must never be taken for one another."""
    _session(tmp_path / "no-serial", _parameters(0.01, serial=None))
    _session(tmp_path / "no-name", _parameters(0.02, name=None))
    assert previous_calibration(tmp_path, "imu", None) == (None, 0)
    assert previous_calibration(tmp_path, None, "A1") == (None, 0)


def test_any_excluded_session_leaves_the_newest_of_the_others(tmp_path):
    """Whatever place the excluded session takes in the directory's listing, every other one is
    still looked at: each of three, excluded in turn, leaves the newest of the other two."""
    biases = {"first": 0.01, "second": 0.02, "third": 0.03}
    for name, bias in biases.items():  # written in this order, so "third" is the newest
        _session(tmp_path / name, _parameters(bias))
    expected = {"first": 0.03, "second": 0.03, "third": 0.02}
    for excluded, bias in expected.items():
        found, unreadable = previous_calibration(tmp_path, "imu", "A1", exclude=tmp_path / excluded)
        assert (found.parameters["accelerometer"].bias[0], unreadable) == (bias, 0), excluded


def test_every_unreadable_file_is_counted_and_passed_over(tmp_path):
    """Two damaged files among good ones: both counted, and the good ones (wherever the listing
    puts them) still found."""
    _session(tmp_path / "good-a", _parameters(0.01))
    for name in ("damaged-1", "damaged-2"):
        (tmp_path / name).mkdir()
        (tmp_path / name / "parameters.yaml").write_text("schema: nonsense\n")
    _session(tmp_path / "good-b", _parameters(0.02))
    found, unreadable = previous_calibration(tmp_path, "imu", "A1")
    assert unreadable == 2
    assert found.path == tmp_path / "good-b" / "parameters.yaml"


def test_a_session_whose_data_files_are_gone_still_verifies_its_parameters(tmp_path):
    """The checksum is in the log: a session copied without its data files (samples, raw device bytes)
    still says whether its parameter file is the one calibrated."""
    _session(tmp_path / "s", _parameters(0.01), raw=b"$VNYMR,1,2,3*00\r\n")
    for data_file in ("raw-imu.bin", "samples.bin"):
        (tmp_path / "s" / data_file).unlink(missing_ok=True)
    assert recorded_check(tmp_path / "s" / "parameters.yaml") == VERIFIED
    found, _ = previous_calibration(tmp_path, "imu", "A1")
    assert found.check == VERIFIED


def test_the_callers_record_of_the_session_is_the_one_checked_against(tmp_path):
    """A certificate reads its session once and hands its record over: the check uses that
    record's checksum, not a second reading of the directory (here its log gone since)."""
    from fieldcal.session.record import RunRecord

    _session(tmp_path / "s", _parameters(0.01))
    record = RunRecord.open(tmp_path / "s", log_only=True)
    for log in (tmp_path / "s").glob("*.jsonl"):
        log.unlink()
    assert recorded_check(tmp_path / "s" / "parameters.yaml", record) == VERIFIED
    assert recorded_check(tmp_path / "s" / "parameters.yaml") != VERIFIED  # read again: no log
