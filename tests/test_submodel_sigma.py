"""A sub-model's σ without a device config are honest (issue 27): over seeded simulated
recordings calibrated with no noise model, the calibrated parameters' errors against the
simulator's truth scatter as their σ say, at every number of degrees of freedom the fit has.

At dof 0 (as many distinct poses as the parameters they determine) the fit's residuals are zero
whatever the noise, and its σ were the white noise's alone: RMS z 1.71 (a consumer gyro's bias
from a single rest: 1.74). At dof 2-3 the noise
measured from the scatter of so few residuals leaned on its prior: RMS z 0.11. Now, below
submodel.SCATTER_DOF, the σ come from each pose's own samples (noise_estimate.within_pose_noise).
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np
import pytest
from scipy.stats import chi2

from drivers.sim.handheld import CONSUMER_NOISE, handheld_truth, simulate_handheld
from fieldcal.earth import Station
from fieldcal.model import PARAM_NAMES, params_from_k
from fieldcal.recording import Recording
from fieldcal.recording.calibrate import calibrate_recording
from fieldcal.recording.noise_estimate import WITHIN_POSE
from fieldcal.recording.outcome import SUBMODEL_PROTOCOL, RecordingSettings
from fieldcal.recording.submodel import SCATTER_DOF

FACES = np.vstack([np.eye(3), -np.eye(3)])
NO_Z_DOWN = (2, 0, 1, 3, 4)  # z up, x up, y up, x down, y down: the unit never turned over


def five_faces_tilted(seed: int, n: int, tilt_deg: float = 20.0) -> np.ndarray:
    """``n`` up vectors on the five faces other than z down (each at least once, then at random),
    each tilted by ``tilt_deg`` about a random horizontal axis. With no pose near z down the norm
    method refuses them ("none with z down"), and the sub-model solves what they determine: all
    nine parameters or nearly, on n - 9 degrees of freedom or one more."""
    rng = np.random.default_rng([seed, 5])
    order = np.r_[NO_Z_DOWN, rng.choice(NO_Z_DOWN, n - len(NO_Z_DOWN))]
    across = np.cross(FACES[order], rng.normal(size=(n, 3)))
    across /= np.linalg.norm(across, axis=1, keepdims=True)
    return np.cos(np.radians(tilt_deg)) * FACES[order] + np.sin(np.radians(tilt_deg)) * across


@lru_cache(maxsize=None)
def accelerometer_z(seed: int, n: int) -> tuple[int, np.ndarray, str]:
    """(the fit's dof, z of each calibrated parameter against the truth, where its σ came from)
    for one recording with the paper's noise, calibrated with no config."""
    sim = simulate_handheld(seed, n_poses=n, directions=five_faces_tilted(seed, n), raw_counts=False)
    cal = calibrate_recording(Recording(sim.t, sim.triads, sim.kinds, sim.units),
                              Station(sim.latitude_deg, 0.0, sim.gravity), RecordingSettings())
    assert cal.protocol == SUBMODEL_PROTOCOL
    acc, truth = cal.specific_force["accelerometer"], sim.truth["accelerometer"]
    calibrated = np.isin(PARAM_NAMES, acc.calibrated)
    z = (acc.theta - params_from_k(truth.K, truth.bias, full=True)) / acc.sigma
    return acc.diagnostics.dof, z[calibrated], acc.diagnostics.message


# (poses, seeds): 9 poses give dof 0 (or 1), 10-12 give 1-3, 24 give 15.
CASES = {"dof 0": (9, range(30)), "dof 1-3": ((10, 11, 12), range(10)), "large dof": (24, range(12))}


def draws(case: str) -> list[tuple[int, np.ndarray, str]]:
    poses, seeds = CASES[case]
    return [accelerometer_z(seed, n) for n in np.atleast_1d(poses) for seed in seeds]


def rms_bounds(draw_count: int, p: float = 1e-3) -> tuple[float, float]:
    """Two-sided bounds on RMS z for ``draw_count`` draws: a draw's z are correlated (the biases
    share the flicker), so a draw counts as one degree of freedom, not as many as its parameters
    (the bounds are then wider than for independent z: a true σ never fails them by chance)."""
    low, high = chi2.ppf([p / 2, 1 - p / 2], draw_count)
    return float(np.sqrt(low / draw_count)), float(np.sqrt(high / draw_count))


# The draws (accelerometer_z's cache) are per process: the tests that read the same ones run on one
# xdist worker (--dist loadgroup), which simulates and calibrates them once (42 recordings, 2.8 s).
SHARES_THE_DRAWS = pytest.mark.xdist_group("test_submodel_sigma.py:draws")


@SHARES_THE_DRAWS
@pytest.mark.parametrize("case, dofs", [("dof 0", range(0, 1)), ("dof 1-3", range(1, 4)),
                                        ("large dof", range(10, 100))])
def test_sub_model_sigma_without_a_config_match_the_errors(case, dofs):
    """RMS z of the calibrated parameters within the χ² bounds for the number of draws, both
    sides, among the draws whose fit has that many degrees of freedom and determines some
    parameter (the dof 0 case's few draws at dof 1 are left to their own case)."""
    kept = [(dof, z, why) for dof, z, why in draws(case) if dof in dofs and z.size]
    assert len(kept) >= 10, [dof for dof, _, _ in draws(case)]
    rms = float(np.sqrt(np.mean(np.concatenate([z for _, z, _ in kept]) ** 2)))
    low, high = rms_bounds(len(kept))
    assert low < rms < high, (case, rms, (low, high))


@SHARES_THE_DRAWS
def test_the_output_says_where_the_sigma_came_from():
    """Below SCATTER_DOF the σ come from the poses' own samples, and the solution says so with
    its dof; from SCATTER_DOF on, from the scatter about the fit."""
    for dof, z, why in draws("dof 0") + draws("large dof"):
        if not z.size:
            assert why == "nothing determined"
        elif dof < SCATTER_DOF:
            assert why == WITHIN_POSE.format(dof=dof)
        else:
            assert why.startswith("σ from the noise measured by the poses' scatter about the fit")


def test_a_single_rests_gyro_bias_sigma_match_the_errors():
    """Rests alone (one pose, no scatter at all), a consumer gyro (10 °/h bias instability, about
    the horizontal Earth rate the σ also carry): the bias's σ hold the flicker the rest's own
    samples show, where they held the white noise and the Earth rate alone (RMS z 1.74)."""
    z = []
    for seed in range(30):
        sim = simulate_handheld(seed, n_poses=1, directions=np.array([[0.0, 0.0, 1.0]]), raw_counts=False,
                                initial_rest_s=60.0, truth=handheld_truth(False, CONSUMER_NOISE))
        cal = calibrate_recording(Recording(sim.t, sim.triads, sim.kinds, sim.units),
                                  Station(sim.latitude_deg, 0.0, sim.gravity), RecordingSettings())
        gyro, truth = cal.angular_rate["gyroscope"], sim.truth["gyroscope"]
        assert gyro.calibrated == ("bias_x", "bias_y", "bias_z")
        assert gyro.diagnostics.message == WITHIN_POSE.format(dof=0)
        z.append((gyro.theta[:3] - truth.bias) / gyro.sigma[:3])
    rms = float(np.sqrt(np.mean(np.square(z))))
    low, high = rms_bounds(len(z))
    assert low < rms < high, (rms, (low, high))


def test_a_real_sub_model_agrees_with_the_full_solve_on_the_same_file(tmp_path):
    """Real data (imucal's Ferraris session, tests/data/real): cut before its z-down face, five
    faces are left, too few for the Ferraris protocol and the norm method; the sub-model's
    accelerometer biases (x and y: both their faces are there) and gyro biases, with their σ from
    the poses' own samples, agree with the six faces' full solve of the whole file within the
    combined σ."""
    import gzip
    import json
    from pathlib import Path

    from fieldcal.recording.importer import import_recording
    from fieldcal.recording.outcome import ALIGNED_PROTOCOL
    from fieldcal.recording.place import UnknownPlace

    real = Path(__file__).parent / "data" / "real"
    path = tmp_path / "session.csv"
    path.write_bytes(gzip.decompress((real / "imucal_ferraris_session.csv.gz").read_bytes()))
    recording = import_recording([path], "imucal", rate_hz=102.4)
    full = calibrate_recording(recording, UnknownPlace(gravity=9.81))
    assert full.protocol == ALIGNED_PROTOCOL
    before = recording.t < recording.t[json.loads((real / "imucal_ferraris_session_list.json").read_text())
                                       ["z_a"]["start"]]
    cut = Recording(recording.t[before], {n: v[before] for n, v in recording.triads.items()}, recording.kinds,
                    recording.units)
    sub = calibrate_recording(cut, UnknownPlace(gravity=9.81))
    assert sub.protocol == SUBMODEL_PROTOCOL
    pairs = [(full.specific_force["accelerometer"], sub.specific_force["accelerometer"]),
             (full.angular_rate["gyroscope"], sub.angular_rate["gyroscope"])]
    assert {"bias_x", "bias_y"} <= set(pairs[0][1].calibrated)
    for whole, part in pairs:
        assert part.diagnostics.message.startswith("σ from each pose's own samples"), part.diagnostics.message
        bias = [PARAM_NAMES.index(n) for n in part.calibrated if n.startswith("bias")]
        combined = np.hypot(whole.sigma[bias], part.sigma[bias])
        assert np.all(np.abs(part.theta[bias] - whole.theta[bias]) < combined), (part.theta[bias], whole.theta[bias],
                                                                                 combined)


def test_within_pose_noise_of_poses_too_short_to_cut_is_white_alone():
    """Poses of one and two samples (a --min-still far below the rate): a pose of one sample has
    no parts to tell the flicker by (B = 0, its variance floored, never a division by zero); of
    two, halves of one sample each."""
    from fieldcal.recording.noise_estimate import within_pose_noise

    values = np.random.default_rng(1).normal(9.8, 0.01, (10, 3))
    t = np.arange(10) / 100.0
    single = within_pose_noise(values, np.array([[0, 1], [3, 5]]), t)
    assert single.bias_instability == 0.0 and np.all(single.variance > 0)
    pair = within_pose_noise(values, np.array([[0, 2], [3, 5]]), t)
    assert np.isfinite(pair.bias_instability) and np.all(np.isfinite(pair.flicker(np.array([[0, 2], [3, 5]]), t, 0.01)))


def test_a_consumer_gyros_bias_from_many_still_poses_has_honest_sigma():
    """Nine still poses (dof 8: the scatter path), a consumer gyro: its bias's σ hold the
    flicker (the larger of what the poses' scatter and their own samples show): RMS z 0.92, where
    the scatter alone, its Earth-rate share that of a horizontal axis, gave 1.33."""
    z = []
    for seed in range(30):
        sim = simulate_handheld(seed, n_poses=9, directions=five_faces_tilted(seed, 9), raw_counts=False,
                                truth=handheld_truth(False, CONSUMER_NOISE))
        cal = calibrate_recording(Recording(sim.t, sim.triads, sim.kinds, sim.units),
                                  Station(sim.latitude_deg, 0.0, sim.gravity), RecordingSettings())
        gyro = cal.angular_rate["gyroscope"]
        assert gyro.diagnostics.message.startswith("σ from the noise measured by the poses' scatter")
        z.append((gyro.theta[:3] - sim.truth["gyroscope"].bias) / gyro.sigma[:3])
    rms = float(np.sqrt(np.mean(np.square(z))))
    low, high = rms_bounds(len(z))
    assert low < rms < high, (rms, (low, high))
