"""The operator's line about a previous calibration, whole, for each check its file can get.
Asked for by mutation testing of fieldcal/session/history.py (issue 26): the lines were only
searched for a word."""
from pathlib import Path

import pytest

from fieldcal.session.history import EDITED, UNRECORDED, VERIFIED, PreviousCalibration
from test_acceptance import accelerometer, parameter_file

PATH = Path("sessions/unit7/parameters.yaml")


@pytest.mark.parametrize("check, tail", [
    (VERIFIED, ""),
    (EDITED, " (EDITED AFTER CALIBRATION: its SHA-256 differs from the one its session recorded)"),
    (UNRECORDED, " (not verified: its session recorded no checksum for it)"),
])
def test_the_previous_calibration_line_names_the_file_and_its_check(check, tail):
    found = PreviousCalibration(PATH, parameter_file(accelerometer([0.0] * 3)), check)
    assert found.describe() == f"the previous calibration of this unit, {PATH}{tail}"
