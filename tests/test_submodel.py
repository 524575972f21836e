"""Calibrate what the data determine (issue 27, DESIGN principle 13): a recording whose poses are
too few or too alike for the norm method, and not the six faces, gives what they do determine
(by the rank of the norm equations' Jacobian, not by a rule), the rest marked not calibrated;
rests alone give the gyro's bias."""
from __future__ import annotations

import numpy as np
import pytest
import yaml

from drivers.sim.handheld import CONSUMER_NOISE, handheld_truth, simulate_handheld, to_text
from fieldcal.cli.main import main
from fieldcal.earth import Station
from fieldcal.model import PARAM_NAMES, params_from_k
from fieldcal.paramfile import load
from fieldcal.recording import Recording
from fieldcal.recording.calibrate import calibrate_recording
from fieldcal.recording.detect import DetectionError
from fieldcal.recording.outcome import SUBMODEL_PROTOCOL, RecordingSettings
from fieldcal.recording.place import UnknownPlace
from fieldcal.recording.results import summary_lines

FACES = np.vstack([np.eye(3), -np.eye(3)])


def recording_of(sim) -> Recording:
    return Recording(sim.t, sim.triads, sim.kinds, sim.units)


def station_of(sim) -> Station:
    return Station(sim.latitude_deg, 0.0, sim.gravity)


def truth_of(sim, name) -> np.ndarray:
    """The nine PARAM_NAMES values of the simulated triad (its K's lower triangle named)."""
    truth = sim.truth[name]
    return params_from_k(truth.K, truth.bias, full=True)


def faces_tilted(seed: int, tilt_deg: float = 20.0) -> np.ndarray:
    """z up first (the rest), then the other five faces and three faces again, each tilted by
    ``tilt_deg`` about a random horizontal axis: beyond the Ferraris protocol's 15°, and too
    alike for the norm method."""
    rng = np.random.default_rng(seed)
    ups = []
    for face in np.r_[2, 0, 1, 3, 4, 5, rng.integers(0, 6, 3)]:
        across = np.cross(FACES[face], rng.normal(size=3))
        across /= np.linalg.norm(across)
        ups.append(np.cos(np.radians(tilt_deg)) * FACES[face] + np.sin(np.radians(tilt_deg)) * across)
    return np.array(ups)


def rests_only(seed: int):
    return simulate_handheld(seed, n_poses=1, directions=np.array([[0.0, 0.0, 1.0]]), raw_counts=False,
                             initial_rest_s=60.0)


def assert_solved_within_sigma(solution, truth, limit=3.0):
    """Every calibrated parameter within ``limit`` σ of the truth; every other one nominal, no σ."""
    z = (solution.theta - truth) / solution.sigma
    calibrated = np.isin(PARAM_NAMES, solution.calibrated)
    assert np.all(np.abs(z[calibrated]) < limit), dict(zip(PARAM_NAMES, z))
    assert np.all(np.isnan(solution.sigma[~calibrated]))


@pytest.mark.parametrize("seed", [4, 6])
def test_rests_only_give_the_gyro_bias_and_mark_the_rest(seed):
    """One still pose: the accelerometer's norm gives one equation for nine unknowns (nothing is
    determined: every parameter marked, saying which poses to add); the gyro's bias is the rest's
    mean less the vertical Earth rate, within its σ of the truth; its scale and misalignment are
    marked, nominal."""
    sim = rests_only(seed)
    cal = calibrate_recording(recording_of(sim), station_of(sim), RecordingSettings())
    assert cal.protocol == SUBMODEL_PROTOCOL
    acc = cal.specific_force["accelerometer"]
    assert not cal.failures and acc.calibrated == () and "add poses with x up" in acc.not_calibrated_why
    np.testing.assert_array_equal(acc.K, np.eye(3))  # m/s^2: nominal
    assert np.all(np.isnan(acc.sigma))
    gyro = cal.angular_rate["gyroscope"]
    assert gyro.calibrated == ("bias_x", "bias_y", "bias_z") and gyro.method == "still"
    assert_solved_within_sigma(gyro, truth_of(sim, "gyroscope"))
    np.testing.assert_array_equal(gyro.theta[3:], [1.0, 1.0, 1.0, 0.0, 0.0, 0.0])  # rad/s: nominal
    line = summary_lines(cal)[-1]
    assert line.startswith("calibrated: gyroscope bias x/y/z. NOT calibrated (nominal, no σ): accelerometer (all); "
                           "gyroscope scale factor x/y/z, misalignment Δyz/Δzy/Δzx. To add them: accelerometer: add poses")
    assert "accelerometer (all)" in line and "rotations between 9 or more well-spread poses" in line


def test_rests_only_without_a_place_carry_the_earth_rate_and_say_so():
    """No latitude: the whole Earth rate (direction unknown) is an error in the bias's σ, wider
    than with the place known, and a note says so and names --latitude."""
    sim = rests_only(4)
    known = calibrate_recording(recording_of(sim), station_of(sim), RecordingSettings())
    unknown = calibrate_recording(recording_of(sim), UnknownPlace(gravity=sim.gravity), RecordingSettings())
    gyro = unknown.angular_rate["gyroscope"]
    assert np.all(gyro.sigma[:3] > known.angular_rate["gyroscope"].sigma[:3])
    assert_solved_within_sigma(gyro, truth_of(sim, "gyroscope"))
    assert any("Earth rate" in n and "--latitude" in n for n in unknown.notes)


@pytest.mark.parametrize("seed", [0, 11])
def test_poses_too_alike_give_what_the_jacobian_determines_within_sigma(seed):
    """Faces tilted by 20°, nine poses, a consumer unit: too alike for the norm method (refused
    whole before). What they determine is solved, within 3σ of the truth; the rest is marked:
    some of the misalignment needs poses between the axes, the x and y biases do not."""
    sim = simulate_handheld(8, n_poses=9, directions=faces_tilted(seed), raw_counts=False,
                            truth=handheld_truth(False, CONSUMER_NOISE))
    cal = calibrate_recording(recording_of(sim), station_of(sim), RecordingSettings())
    assert cal.protocol == SUBMODEL_PROTOCOL and "cube corner" in cal.spread.message  # too alike (or too few)
    acc = cal.specific_force["accelerometer"]
    assert {"bias_x", "bias_y"} <= set(acc.calibrated) and 0 < len(acc.not_calibrated) < 9
    assert set(acc.not_calibrated) & {"delta_yz", "delta_zy", "delta_zx"}  # between the axes: not seen
    assert_solved_within_sigma(acc, truth_of(sim, "accelerometer"))
    assert_solved_within_sigma(cal.angular_rate["gyroscope"], truth_of(sim, "gyroscope"))
    assert "a cube corner up" in acc.not_calibrated_why


def test_the_same_poses_on_a_quieter_unit_determine_more():
    """No rule by pose count or design figure decides: the Fisher information does. The poses of
    the consumer case above, on a unit with the paper's noise, determine all nine parameters
    (within 3σ of the truth), where the consumer unit's noise left some open."""
    directions = faces_tilted(11)
    quiet = simulate_handheld(8, n_poses=9, directions=directions, raw_counts=False)
    noisy = simulate_handheld(8, n_poses=9, directions=directions, raw_counts=False,
                              truth=handheld_truth(False, CONSUMER_NOISE))
    settings = RecordingSettings()
    acc = calibrate_recording(recording_of(quiet), station_of(quiet), settings).specific_force["accelerometer"]
    assert acc.calibrated == PARAM_NAMES
    assert_solved_within_sigma(acc, truth_of(quiet, "accelerometer"))
    fewer = calibrate_recording(recording_of(noisy), station_of(noisy), settings).specific_force["accelerometer"]
    assert len(fewer.calibrated) < 9


def test_poses_about_one_face_leave_the_biases_open():
    """A cone about z up: bias and scale along z trade against each other, and the tilt of the
    cone's rim against the x and y biases: the Jacobian leaves them open, so they are not
    calibrated, whatever a fit would give them."""
    d = np.column_stack([0.5 * np.cos(np.arange(12)), 0.5 * np.sin(np.arange(12)), np.ones(12)])
    sim = simulate_handheld(8, n_poses=12, directions=d / np.linalg.norm(d, axis=1, keepdims=True),
                            raw_counts=False)
    cal = calibrate_recording(recording_of(sim), station_of(sim), RecordingSettings())
    acc = cal.specific_force.get("accelerometer")
    if acc is not None:
        assert {"bias_x", "bias_y", "bias_z", "scale_z"} <= set(acc.not_calibrated)
        assert_solved_within_sigma(acc, truth_of(sim, "accelerometer"))
    assert_solved_within_sigma(cal.angular_rate["gyroscope"], truth_of(sim, "gyroscope"))


def test_raw_counts_have_no_nominal_and_are_still_refused():
    """In counts a scale has no nominal value to be left at: too few poses are refused, naming
    the poses to add, as before."""
    sim = simulate_handheld(8, n_poses=5, directions=FACES[[4, 0, 1, 5, 3]], raw_counts=True)
    with pytest.raises(DetectionError, match=r"only 5 distinct poses"):
        calibrate_recording(recording_of(sim), station_of(sim), RecordingSettings())


def _map(tmp_path, sim):
    """imu_tk's two-file layout in the simulation's physical units."""
    doc = yaml.safe_load(open("configs/recordings/imu_tk.yaml"))
    for spec, name in zip(doc["files"], ("accelerometer", "gyroscope")):
        spec["triads"][name]["unit"] = sim.units[name]
    path = tmp_path / "physical.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def test_fieldcal_calibrate_writes_the_marks_and_says_what_was_solved(tmp_path, capsys):
    """The command writes a parameter file holding the gyro's bias alone, every other parameter
    marked, says so in one line and exits 0 (the largest well-determined model was solved); the
    file's px4 export holds the gyro's offsets alone."""
    sim = rests_only(4)
    acc, gyro = to_text(sim, tmp_path)
    code = main(["calibrate", str(acc), str(gyro), "--map", str(_map(tmp_path, sim)), "--latitude", "40",
                 "--out", str(tmp_path / "s"), "--params", str(tmp_path / "p.yaml")])
    out = capsys.readouterr().out
    assert code == 0, out
    assert "calibrated: gyroscope bias x/y/z. NOT calibrated" in out
    pf = load(tmp_path / "p.yaml")
    assert pf.names == ("accelerometer", "gyroscope") and pf["accelerometer"].calibrated == ()
    assert pf["gyroscope"].not_calibrated == PARAM_NAMES[3:]
    assert_solved_within_sigma(pf["gyroscope"], truth_of(sim, "gyroscope"))
    from fieldcal.export import export
    written = [line.split("\t")[2] for line in export(pf, "px4").splitlines() if not line.startswith("#")]
    assert written == ["CAL_GYRO0_XOFF", "CAL_GYRO0_YOFF", "CAL_GYRO0_ZOFF"]


def test_imucals_session_without_its_turns_gives_its_gyro_bias_as_imucal_does(tmp_path):
    """A real file cut down: imucal's Ferraris session with its three turns taken out (six faces
    and nothing that rotates the gyro). The accelerometer is Ferraris's solution as before; the
    gyro's scale and misalignment are not calibrated, naming the turns, and its bias, the still
    faces' mean, is imucal's own b_g (the mean of its six annotated faces) within 3σ."""
    import gzip
    import json
    from pathlib import Path

    imucal = pytest.importorskip("imucal")
    pd = pytest.importorskip("pandas")
    from fieldcal.recording.importer import import_recording

    real = Path(__file__).parent / "data" / "real"
    path = tmp_path / "session.csv"
    path.write_bytes(gzip.decompress((real / "imucal_ferraris_session.csv.gz").read_bytes()))
    recording = import_recording([path], "imucal", rate_hz=102.4)
    sections = json.loads((real / "imucal_ferraris_session_list.json").read_text())
    keep = np.ones(len(recording.t), bool)
    for turn in ("x_rot", "y_rot", "z_rot"):
        keep[sections[turn]["start"]:sections[turn]["end"]] = False
    cut = Recording(recording.t[keep], {n: v[keep] for n, v in recording.triads.items()}, recording.kinds,
                    recording.units)
    cal = calibrate_recording(cut, UnknownPlace(gravity=9.81))
    assert not cal.failures and cal.specific_force["accelerometer"].calibrated == PARAM_NAMES
    gyro = cal.angular_rate["gyroscope"]
    assert gyro.not_calibrated == PARAM_NAMES[3:] and "turn the unit once through 360°" in gyro.not_calibrated_why
    info = imucal.FerrarisCalibration(grav=9.81).compute(
        imucal.ferraris_regions_from_section_list(pd.read_csv(path, header=0, index_col=0),
                                                  pd.read_json(real / "imucal_ferraris_session_list.json").T),
        sampling_rate_hz=102.4, from_acc_unit="m/s^2", from_gyr_unit="deg/s")
    assert np.all(np.abs((gyro.theta[:3] - info.b_g) / gyro.sigma[:3]) < 3.0), (gyro.theta[:3], info.b_g)


def test_a_norm_solve_its_measured_noise_leaves_degenerate_falls_to_the_sub_model():
    """These nine poses pass the norm method's screen on white noise, and its solve again with the
    noise measured from them found an angle known only to ±0.032 rad: the whole recording was
    refused ("positions are degenerate"); later, on other last bits of the pose means' sums, the
    norm method took them with σ from a scatter that nine poses of nine parameters do not have.
    Now an exact fit is not asked for its noise: the sub-model takes the poses, saying why."""
    sim = simulate_handheld(113, n_poses=9, directions=faces_tilted(113), raw_counts=False)
    cal = calibrate_recording(recording_of(sim), station_of(sim), RecordingSettings())
    assert cal.protocol == SUBMODEL_PROTOCOL
    assert "with its measured noise: accelerometer: 9 poses leave the norm fit no degree of freedom" in cal.tried[-1][2]
    assert_solved_within_sigma(cal.specific_force["accelerometer"], truth_of(sim, "accelerometer"))


def test_an_exact_norm_fit_is_not_asked_for_its_noise_and_says_why():
    """Nine poses leave the norm fit of nine parameters no degree of freedom: its residuals are
    zero whatever the noise, and measuring the noise from their scatter gave B = nan (a
    RuntimeWarning), whose solve was refused as "degenerate". The refusal now says why, with no
    nan on the way, and the sub-model takes the poses with σ from their own samples."""
    import warnings

    sim = simulate_handheld(118, n_poses=9, directions=faces_tilted(118), raw_counts=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        cal = calibrate_recording(recording_of(sim), station_of(sim), RecordingSettings())
    assert cal.protocol == SUBMODEL_PROTOCOL
    assert "9 poses leave the norm fit no degree of freedom: their scatter cannot measure the noise" in cal.tried[-1][2]
    assert_solved_within_sigma(cal.specific_force["accelerometer"], truth_of(sim, "accelerometer"))
