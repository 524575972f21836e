"""The exported text itself: the json document's layout and characters, the C identifiers made from
triad names, and the c-header's refusals asserted whole. Asked for by mutation testing of
fieldcal/export (issue 26): each survived a mutant before."""
import json

import numpy as np
import pytest

from fieldcal.calibration import with_not_calibrated
from fieldcal.export import export
from fieldcal.model import PARAM_NAMES, k_from_terms
from fieldcal.paramfile import ParameterFile, to_document
from test_export import ACC_TERMS, GYR_TERMS, STATION, parameter_file, triad

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


def test_imucal_takes_the_exported_json_back_to_the_true_input(tmp_path):
    """The quick peer check (the simulated one is slow): imucal itself reads the file and turns
    raw counts made from a known input by a known K and bias back into that input."""
    from imucal.management import load_calibration_info

    acc = triad("accelerometer", "specific_force", "count", [30.0, -20.0, 10.0], [400.0, 410.0, 390.0], ACC_TERMS)
    gyr = triad("gyroscope", "angular_rate", "count", [5.0, -3.0, 2.0], [1000.0, 990.0, 1010.0], GYR_TERMS)
    path = tmp_path / "imu.json"
    pf = parameter_file(acc, gyr)
    path.write_text(export(pf, "imucal-json"))
    rng = np.random.default_rng(3)
    true_acc, true_gyr = rng.normal(scale=9.8, size=(50, 3)), rng.normal(size=(50, 3))  # m/s², rad/s
    raw_acc = true_acc @ k_from_terms([400.0, 410.0, 390.0], ACC_TERMS).T + [30.0, -20.0, 10.0]
    raw_gyr = true_gyr @ k_from_terms([1000.0, 990.0, 1010.0], GYR_TERMS).T + [5.0, -3.0, 2.0]
    got_acc, got_gyr = load_calibration_info(path).calibrate(raw_acc, raw_gyr, acc_unit="count", gyr_unit="count")
    np.testing.assert_allclose(got_acc, true_acc, rtol=0, atol=1e-9)
    np.testing.assert_allclose(got_gyr, np.rad2deg(true_gyr), rtol=0, atol=1e-9)  # imucal's gyro is in °/s
    doc = json.loads(path.read_text())
    assert (doc["from_acc_unit"], doc["from_gyr_unit"], doc["cal_type"]) == ("count", "count", "Ferraris")
    assert doc["comment"] == f"fieldcal {pf.provenance.software_version}: classic-12, classic, device sim S7"


GYRO = triad("gyroscope", "angular_rate", "rad/s", [0.0] * 3, [1.0] * 3, GYR_TERMS)


@pytest.mark.parametrize("triads, line", [
    ((accelerometer(kind="angular_rate", unit="rad/s"), GYRO),
     "export imucal-json: --accelerometer accelerometer: that triad is angular_rate in rad/s, not specific_force: "
     "name the specific_force triad with --accelerometer"),
    ((accelerometer(), triad("gyroscope", "specific_force", "m/s^2", [0.0] * 3, [1.0] * 3, ZERO)),
     "export imucal-json: --gyroscope gyroscope: that triad is specific_force in m/s^2, not angular_rate: "
     "name the angular_rate triad with --gyroscope"),
    ((accelerometer(), with_not_calibrated(GYRO, ["bias_x"], "rests only")),
     "export imucal-json: gyroscope: bias_x not calibrated (rests only); imucal's calibration holds every term and "
     "has no mark for a nominal one: export px4, ardupilot (only what is calibrated) or json (the marks kept) "
     "instead"),
])
def test_imucal_json_refusals_are_one_whole_line(triads, line):
    with pytest.raises(ValueError) as info:
        export(parameter_file(*triads), "imucal-json")
    assert str(info.value) == line


def test_what_a_diagonal_format_drops_is_named_term_by_term_with_its_worst_error():
    """ACC_TERMS and GYR_TERMS by hand: every non-zero term in mrad, the gyro's scale factors other
    than 1 (its scale is not kept), and the worst error ‖A⁻¹K − I‖₂ at 1 g and at 100 °/s."""
    from fieldcal.export.autopilot import diagonal_parameters

    acc = triad("accelerometer", "specific_force", "m/s^2", [0.0] * 3, [1.002, 0.998, 1.001], ACC_TERMS)
    gyr = triad("gyroscope", "angular_rate", "rad/s", [0.0] * 3, [1.01, 0.99, 1.0], GYR_TERMS)
    _, (acc_loss, gyr_loss) = diagonal_parameters(parameter_file(acc, gyr), "px4", "accelerometer", "gyroscope",
                                                  gyro_scale=False)
    assert acc_loss.what == ("m_xy = 1 mrad", "m_xz = -2 mrad", "m_yx = 0.5 mrad", "m_zx = 3 mrad", "m_zy = -1 mrad")
    assert gyr_loss.what == ("m_xz = 0.2 mrad", "m_zy = -0.1 mrad", "scale_x = 1.0100000", "scale_y = 0.9900000")
    M = np.zeros((3, 3))
    M[[0, 0, 1, 1, 2, 2], [1, 2, 0, 2, 0, 1]] = ACC_TERMS
    assert acc_loss.error == pytest.approx(np.linalg.svd(M, compute_uv=False)[0] * 1000.0, rel=1e-9)  # mg at 1 g
    assert (acc_loss.unit, acc_loss.reference, gyr_loss.unit, gyr_loss.reference) == ("mg", "at 1 g", "°/h",
                                                                                      "at 100 °/s")
    assert acc_loss.line() == ("accelerometer: dropped m_xy = 1 mrad, m_xz = -2 mrad, m_yx = 0.5 mrad, "
                               f"m_zx = 3 mrad, m_zy = -1 mrad; worst error {acc_loss.error:.3g} mg at 1 g")


def test_a_triad_name_the_file_lacks_is_refused_naming_those_it_has():
    with pytest.raises(ValueError) as info:
        export(parameter_file(accelerometer(), GYRO), "px4", accelerometer="acc")
    assert str(info.value) == ("export: no triad named 'acc' in the parameter file (it has accelerometer, gyroscope); "
                               "name it with --accelerometer")


FIRMWARE = ("firmware would take every term of BIAS and KINV, a nominal among them, as calibrated: export px4, "
            "ardupilot (only what is calibrated) or json (the marks kept) instead")


@pytest.mark.parametrize("triads, fmt, options, line", [
    ((accelerometer("acc1"), accelerometer("acc2"), GYRO), "px4", {"accelerometer": "gyroscope"},
     "export px4: --accelerometer gyroscope: that triad is angular_rate in rad/s, not specific_force: name the "
     "specific_force triad with --accelerometer (the file's specific_force triads: acc1, acc2)"),
    ((accelerometer("acc1"), GYRO), "px4", {"accelerometer": "gyroscope"},
     "export px4: --accelerometer gyroscope: that triad is angular_rate in rad/s, not specific_force: name the "
     "specific_force triad with --accelerometer (the file's specific_force triad: acc1)"),
    ((accelerometer(unit="count"), GYRO), "px4", {},
     "export px4: triad 'accelerometer' reports in 'count'; px4 takes readings in m/s^2 (calibrate a device "
     "reporting physical units)"),
    ((with_not_calibrated(accelerometer(), ["bias_z", "delta_zx"]), GYRO), "c-header", {},
     f"export c-header: accelerometer: bias_z, delta_zx not calibrated; {FIRMWARE}"),
    ((with_not_calibrated(accelerometer(), PARAM_NAMES[:6], "a"), with_not_calibrated(GYRO, PARAM_NAMES[:3], "b")),
     "px4", {}, "export px4: none of what px4 holds is calibrated in this file (accelerometer: a; gyroscope: b)"),
    ((with_not_calibrated(accelerometer(), PARAM_NAMES[:6], "a"), with_not_calibrated(GYRO, PARAM_NAMES[:3], "b")),
     "ardupilot", {},
     "export ardupilot: none of what ardupilot holds is calibrated in this file (accelerometer: a; gyroscope: b)"),
    ((accelerometer(unit="count"), GYRO), "ardupilot", {},
     "export ardupilot: triad 'accelerometer' reports in 'count'; ardupilot takes readings in m/s^2 (calibrate a "
     "device reporting physical units)"),
])
def test_export_refusals_are_one_whole_line(triads, fmt, options, line):
    with pytest.raises(ValueError) as info:
        export(parameter_file(*triads), fmt, **options)
    assert str(info.value) == line


def test_a_kind_check_without_a_format_names_the_command_alone():
    from fieldcal.export.autopilot import check_kind

    with pytest.raises(ValueError, match=r"^export: --accelerometer gyroscope: that triad is angular_rate"):
        check_kind(parameter_file(accelerometer(), GYRO), "gyroscope", "--accelerometer", "")


def test_the_autopilot_files_first_line_names_the_device_or_says_it_is_unnamed():
    unnamed = ParameterFile.build([accelerometer(), GYRO], station=STATION, procedure="classic-12",
                                  method="classic", input_sha256="a" * 64)
    version = unnamed.provenance.software_version
    assert export(unnamed, "px4").splitlines()[0] == (f"# px4 calibration of unnamed device by fieldcal {version} "
                                                      "(classic-12, classic)")
    assert export(parameter_file(accelerometer(), GYRO), "ardupilot").splitlines()[0] == (
        f"# ardupilot calibration of sim S7 by fieldcal {version} (classic-12, classic)")


def test_ardupilot_writes_each_axis_offset_then_scale_and_the_gyro_offsets_last():
    gyr = triad("gyroscope", "angular_rate", "rad/s", [0.25, 0.5, 0.75], [1.0] * 3, ZERO)
    text = export(parameter_file(triad("accelerometer", "specific_force", "m/s^2", [0.1, 0.2, 0.3], [2.0, 4.0, 0.5],
                                       ZERO), gyr), "ardupilot")
    assert [line for line in text.splitlines() if not line.startswith("#")] == [
        "INS_ACCOFFS_X,0.1", "INS_ACCSCAL_X,0.5", "INS_ACCOFFS_Y,0.2", "INS_ACCSCAL_Y,0.25",
        "INS_ACCOFFS_Z,0.3", "INS_ACCSCAL_Z,2.0", "INS_GYROFFS_X,0.25", "INS_GYROFFS_Y,0.5", "INS_GYROFFS_Z,0.75"]


def test_the_px4_file_of_a_diagonal_unit_whole():
    """Nothing to drop (no terms, the gyro's scale 1): offsets and 1/k as QGroundControl reads them, type 9."""
    gyr = triad("gyroscope", "angular_rate", "rad/s", [0.25, 0.5, 0.75], [1.0] * 3, ZERO)
    pf = parameter_file(triad("accelerometer", "specific_force", "m/s^2", [0.1, 0.2, 0.3], [2.0, 4.0, 0.5], ZERO), gyr)
    rows = [("CAL_ACC0_XOFF", 0.1), ("CAL_ACC0_YOFF", 0.2), ("CAL_ACC0_ZOFF", 0.3), ("CAL_ACC0_XSCALE", 0.5),
            ("CAL_ACC0_YSCALE", 0.25), ("CAL_ACC0_ZSCALE", 2.0), ("CAL_GYRO0_XOFF", 0.25), ("CAL_GYRO0_YOFF", 0.5),
            ("CAL_GYRO0_ZOFF", 0.75)]
    assert export(pf, "px4").splitlines() == [
        f"# px4 calibration of sim S7 by fieldcal {pf.provenance.software_version} (classic-12, classic)",
        "# px4 keeps an offset and a diagonal scale per triad; the rest is dropped:",
        "#   accelerometer: nothing dropped", "#   gyroscope: nothing dropped",
        "# Vehicle-Id\tComponent-Id\tName\tValue\tType", *(f"1\t1\t{name}\t{value}\t9" for name, value in rows)]


def test_a_dropped_m_yz_and_a_gyro_scale_of_two_are_named():
    from fieldcal.export.autopilot import diagonal_parameters

    gyr = triad("gyroscope", "angular_rate", "rad/s", [0.0] * 3, [2.0, 1.0, 1.0], [0.0, 0.0, 0.0, 4e-3, 0.0, 0.0])
    _, (_, loss) = diagonal_parameters(parameter_file(accelerometer(), gyr), "px4", "accelerometer", "gyroscope",
                                       gyro_scale=False)
    assert loss.what == ("m_yz = 4 mrad", "scale_x = 2.0000000")


def test_the_imucal_json_of_an_unnamed_device_its_units_and_layout():
    pf = ParameterFile.build([accelerometer(), GYRO], station=STATION, procedure="classic-12", method="classic",
                             input_sha256="a" * 64)
    text = export(pf, "imucal-json")
    doc = json.loads(text)
    assert doc["comment"] == f"fieldcal {pf.provenance.software_version}: classic-12, classic, device ?"
    assert (doc["acc_unit"], doc["gyr_unit"], doc["from_acc_unit"], doc["from_gyr_unit"]) == (
        "m/s^2", "deg/s", "m/s^2", "rad/s")
    assert text.splitlines()[1] == '  "acc_unit": "m/s^2",' and text.endswith("}\n")
