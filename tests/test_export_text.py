"""The exported text itself: the json document's layout and characters, the C identifiers made from
triad names, and the c-header's refusals asserted whole. Asked for by mutation testing of
fieldcal/export (issue 26): each survived a mutant before."""
import json

import pytest

from fieldcal.calibration import with_not_calibrated
from fieldcal.export import export
from fieldcal.paramfile import ParameterFile, to_document
from test_export import STATION, parameter_file, triad

ZERO = [0.0] * 6


def accelerometer(name="accelerometer", kind="specific_force", unit="m/s^2"):
    return triad(name, kind, unit, [0.1, 0.0, 0.0], [1.0, 1.0, 1.0], ZERO)


def test_json_is_the_parameter_document_indented_by_two_with_its_characters_unescaped():
    pf = parameter_file(accelerometer(), triad("gyroscope", "angular_rate", "°/s", [0.0] * 3, [57.3] * 3, ZERO))
    text = export(pf, "json")
    assert json.loads(text) == to_document(pf) and text.endswith("}\n")
    lines = text.splitlines()
    assert lines[0] == "{" and lines[1].startswith('  "') and not lines[1].startswith('   ')
    assert '"°/s"' in text and "\\u00b0" not in text  # the unit as written, not escaped


@pytest.mark.parametrize("name, ident", [
    ("accel-2 x", "ACCEL_2_X"),  # every character C does not take is an underscore
    ("imu2", "IMU2"),
    ("2nd", "T_2ND"),  # an identifier cannot start with a digit
    ("a2", "A2"),  # nor is a letter then a digit refused
    ("gyroé", "GYRO_"),  # ASCII only: é is not a C identifier character
])
def test_a_triad_name_becomes_a_c_identifier(name, ident):
    text = export(parameter_file(accelerometer(name)), "c-header")
    assert f"static const double FIELDCAL_{ident}_BIAS[3] = {{0.1, 0.0, 0.0}};" in text


def test_c_header_refuses_a_named_triad_of_the_wrong_kind_in_one_line():
    with pytest.raises(ValueError) as info:
        export(parameter_file(accelerometer(kind="angular_rate", unit="rad/s")), "c-header")
    assert str(info.value) == ("export c-header: --accelerometer accelerometer: that triad is angular_rate in rad/s, "
                               "not specific_force: name the specific_force triad with --accelerometer")


def test_c_header_refuses_a_triad_not_calibrated_saying_what_firmware_would_do():
    pf = parameter_file(with_not_calibrated(accelerometer(), ["bias_z"], "poses too alike"))
    with pytest.raises(ValueError) as info:
        export(pf, "c-header")
    assert str(info.value) == ("export c-header: accelerometer: bias_z not calibrated (poses too alike); firmware "
                               "would take every term of BIAS and KINV, a nominal among them, as calibrated: export "
                               "px4, ardupilot (only what is calibrated) or json (the marks kept) instead")


def test_the_c_header_of_an_identity_triad_whole():
    """K = I, bias (0.1, 0, 0): K⁻¹ is the identity, every line as firmware reads it."""
    pf = parameter_file(accelerometer())
    assert export(pf, "c-header") == f"""\
/* fieldcal calibration parameters, generated: do not edit.
 * fieldcal {pf.provenance.software_version}, procedure classic-12, method classic,
 * device sim S7, inputs sha256 {"a" * 64}.
 * Per triad: calibrated[i] = sum_j KINV[i][j] * (raw[j] - BIAS[j]). */
#ifndef FIELDCAL_CALIBRATION_H
#define FIELDCAL_CALIBRATION_H

/* accelerometer (specific_force): raw in m/s^2, calibrated in m/s^2 */
static const double FIELDCAL_ACCELEROMETER_BIAS[3] = {{0.1, 0.0, 0.0}};
static const double FIELDCAL_ACCELEROMETER_KINV[3][3] = {{{{1.0, 0.0, 0.0}}, {{0.0, 1.0, 0.0}}, {{0.0, 0.0, 1.0}}}};

#endif /* FIELDCAL_CALIBRATION_H */
"""


def test_the_c_header_of_an_unnamed_device_says_so():
    pf = ParameterFile.build([accelerometer()], station=STATION, procedure="classic-12", method="classic",
                             input_sha256="a" * 64)
    assert f" * device ? , inputs sha256 {'a' * 64}." in export(pf, "c-header").splitlines()
