"""The noise model a recording with no device config is weighted with (issue 11): the white
noise and the bias instability measured from the recording itself, so that the biases' σ hold
the flicker all poses share. Against the simulator's known noise and parameters."""
from __future__ import annotations

import numpy as np
import pytest

from drivers.noise import TriadNoise
from drivers.sim.handheld import CONSUMER_NOISE, handheld_truth, simulate_handheld
from fieldcal.earth import Station
from fieldcal.model import params_from_k
from fieldcal.recording import Recording
from fieldcal.recording.calibrate import RecordingSettings, calibrate_recording
from fieldcal.recording.noise_estimate import bias_instability, flicker_covariance


def _bias_z(seed: int, settings: RecordingSettings = RecordingSettings()):
    """(solved − true)/σ of both triads' biases, a consumer unit held in 20 poses, no config."""
    sim = simulate_handheld(seed, n_poses=20, raw_counts=False, initial_rest_s=5.0,
                            truth=handheld_truth(False, CONSUMER_NOISE))
    cal = calibrate_recording(Recording(sim.t, sim.triads, sim.kinds, sim.units),
                              Station(sim.latitude_deg, 0.0, sim.gravity), settings)
    acc, truth = cal.specific_force["accelerometer"], sim.truth["accelerometer"]
    z_acc = ((acc.theta - params_from_k(truth.K, truth.bias)) / acc.sigma)[:3]
    gyro = cal.angular_rate["gyroscope"]
    z_gyro = (gyro.theta[:3] - sim.truth["gyroscope"].bias) / gyro.sigma[:3]
    return cal, np.r_[z_acc, z_gyro]


def test_without_a_config_the_biases_sigma_hold_the_bias_instability():
    """A consumer unit's flicker (0.1 mg, 10 °/h) moves all pose means alike: with white noise
    alone the biases' errors were 2-3σ in RMS. Measured from the recording, the RMS is near 1."""
    z = np.array([_bias_z(seed)[1] for seed in range(1, 11)])
    rms = float(np.sqrt(np.mean(z**2)))
    assert 0.65 < rms < 1.4, np.round(z, 1)
    white_only = np.array([_bias_z(seed, RecordingSettings(estimate_noise=False))[1] for seed in range(1, 4)])
    assert np.sqrt(np.mean(white_only**2)) > 1.6  # what the estimate is for


def test_the_estimated_noise_is_the_units_own_within_its_uncertainty():
    cal, _ = _bias_z(3)
    for name, noise in cal.estimated_noise.items():
        true = CONSUMER_NOISE[name]
        assert noise.white == pytest.approx(true.white, rel=0.1)
        assert 0.3 < noise.bias_instability / true.bias_instability < 3.0, name


@pytest.mark.parametrize("true_b", [0.0, 0.5, 2.0])
def test_bias_instability_from_the_scatter_of_a_fits_residuals(true_b):
    """Residuals of a line fitted to 300 pose means (white 1 each, flicker B): B back within its
    uncertainty; with no flicker, well below the white noise (the prior keeps it off zero)."""
    rng = np.random.default_rng(5)
    m = 300
    starts, durations = np.arange(m) * 8.0, np.full(m, 4.0)
    flicker = flicker_covariance(starts, durations)
    white = np.ones(m)
    covariance = np.diag(white) + true_b**2 * flicker
    values = np.linalg.cholesky(covariance) @ rng.standard_normal((m, 3))
    X = np.column_stack([np.ones(m), starts])
    residuals = values - X @ np.linalg.lstsq(X, values, rcond=None)[0]
    b = bias_instability(residuals, X, white, flicker)
    if true_b:
        assert b == pytest.approx(true_b, rel=0.25)
    else:
        assert b < 0.3


def test_the_summary_says_how_the_sigma_were_obtained():
    from fieldcal.recording.results import noise_lines

    cal, _ = _bias_z(2)
    lines = noise_lines(cal, configured=False)
    assert "estimated from the recording" in lines[0] and "no device config (--config)" in lines[0]
    assert any(line.startswith("  accelerometer: white") and "m/s²" in line for line in lines)
    assert any(line.startswith("  gyroscope: white") and "rad/s" in line for line in lines)
    with_config = calibrate_recording(
        *(lambda s: (Recording(s.t, s.triads, s.kinds, s.units), Station(s.latitude_deg, 0.0, s.gravity)))(
            simulate_handheld(2)), RecordingSettings(noise={n: TriadNoise(1e-3, 1e-4) for n in
                                                            ("accelerometer", "gyroscope")}))
    assert not with_config.estimated_noise
    assert noise_lines(with_config, configured=True) == ["noise: the config's noise model (bias instability included)"]


FACES = np.vstack([np.eye(3), -np.eye(3)])


def _ferraris_acc_bias_z(seed: int, settings: RecordingSettings = RecordingSettings()) -> np.ndarray:
    """(solved − true)/σ of the accelerometer's biases, a consumer unit's Ferraris session (six
    faces, a full table turn on three of them, each face seen again after its turn), no config."""
    sim = simulate_handheld(seed, n_poses=6, directions=FACES, initial_rest_s=5.0, raw_counts=False,
                            truth=handheld_truth(False, CONSUMER_NOISE),
                            table_turns=((0, 30.0, 10.0), (2, -40.0, 7.0), (4, 45.0, 6.0)))
    cal = calibrate_recording(Recording(sim.t, sim.triads, sim.kinds, sim.units),
                              Station(sim.latitude_deg, 0.0, sim.gravity), settings)
    acc, truth = cal.specific_force["accelerometer"], sim.truth["accelerometer"]
    return ((acc.file_theta - params_from_k(truth.K, truth.bias, full=True)) / acc.file_sigma)[:3]


def test_a_ferraris_accelerometers_bias_sigma_holds_the_flicker_its_faces_share():
    z = np.array([_ferraris_acc_bias_z(seed) for seed in range(1, 9)])
    assert 0.6 < np.sqrt(np.mean(z**2)) < 1.45, np.round(z, 1)
    white_only = np.array([_ferraris_acc_bias_z(seed, RecordingSettings(estimate_noise=False))
                           for seed in range(1, 9)])
    # White noise alone leaves these σ about 1.3× too small (RMS z 1.33 over these 24; it was 2.0
    # before the biases came from each axis's own two faces, Ferraris's estimator).
    assert np.sqrt(np.mean(white_only**2)) > 1.2, np.round(white_only, 1)


def _replaced_faces_session(seed: int):
    """A consumer unit's Ferraris session, no config, in which +x and +y are set down again at the
    end, each 0.5° off its first placement (g·sin 0.5° = 86 mm/s² across it): the calibration,
    the simulation and the accelerometer's true bias instability."""
    from scipy.spatial.transform import Rotation

    again = Rotation.from_rotvec(np.radians(0.5) * np.array([[0.0, 0.6, 0.8], [0.8, 0.0, 0.6]])).apply(FACES[:2])
    sim = simulate_handheld(seed, n_poses=8, directions=np.vstack([FACES, again]), initial_rest_s=5.0,
                            raw_counts=False, truth=handheld_truth(False, CONSUMER_NOISE),
                            table_turns=((0, 30.0, 10.0), (2, -40.0, 7.0), (4, 45.0, 6.0), (6, 30.0, 10.0)))
    cal = calibrate_recording(Recording(sim.t, sim.triads, sim.kinds, sim.units),
                              Station(sim.latitude_deg, 0.0, sim.gravity))
    return cal, sim


def test_a_face_set_down_again_with_another_tilt_is_not_counted_as_flicker():
    """B comes from the scatter within a placement (the intervals either side of a table turn),
    not across a face's placements, whose tilts differ: grouped by face, B came out 26-28 times
    the truth here and the biases' σ 20 times too wide (RMS z 0.05). Measured within placements,
    B is the unit's within its estimation scatter (0.3-3×, as above) and the biases' σ hold."""
    ratios, z = [], []
    for seed in range(1, 9):
        cal, sim = _replaced_faces_session(seed)
        ratios.append(cal.estimated_noise["accelerometer"].bias_instability
                      / CONSUMER_NOISE["accelerometer"].bias_instability)
        acc, truth = cal.specific_force["accelerometer"], sim.truth["accelerometer"]
        z.append(((acc.file_theta - params_from_k(truth.K, truth.bias, full=True)) / acc.file_sigma)[:3])
    assert all(0.3 < r < 3.0 for r in ratios), np.round(ratios, 2)
    assert 0.5 < np.sqrt(np.mean(np.square(z))) < 1.45, np.round(z, 2)


def _ferraris_gyro(seed: int, settings: RecordingSettings = RecordingSettings()):
    """A consumer unit's Ferraris session with a warming bias (no config): its calibration, and
    (solved − true)/σ of the gyro's biases."""
    from drivers.sim.handheld import RealWorld

    still = RealWorld(g_sensitivity_deg_s_per_g=0.05, warm_up_deg_s=0.0, temperature_ramp_k=0.0,
                      bias_tempco_deg_s_per_k=0.0, jitter_s=0.0, drop_fraction=0.0)
    sim = simulate_handheld(seed, n_poses=6, directions=FACES, initial_rest_s=5.0, raw_counts=False,
                            truth=handheld_truth(False, CONSUMER_NOISE), real_world=still,
                            table_turns=((0, 30.0, 10.0), (2, -40.0, 7.0), (4, 45.0, 6.0)))
    cal = calibrate_recording(Recording(sim.t, sim.triads, sim.kinds, sim.units),
                              Station(sim.latitude_deg, 0.0, sim.gravity), settings)
    gyro, truth = cal.angular_rate["gyroscope"], sim.truth["gyroscope"]
    return cal, ((gyro.file_theta - params_from_k(truth.K, truth.bias, full=True)) / gyro.file_sigma)[:3]


def test_a_ferraris_gyros_bias_sigma_holds_the_flicker_its_faces_share():
    """A consumer gyro's flicker moves all six faces' still readings alike, and the bias, their
    mean, with them: no scatter shows it. Its B measured from the still intervals (halves, faces
    seen again after their turns) widens the biases' σ by that shared part, and the summary says
    what was measured. White noise alone left the σ 3 times too small here (RMS z 3.0; the
    estimate gives 1.28 on these 12 sessions, 1.25 on 30: see ferraris.estimated_turns_noise)."""
    from fieldcal.recording.results import noise_lines

    runs = [_ferraris_gyro(seed) for seed in range(1, 13)]
    z = np.array([zs for _, zs in runs])
    assert 0.7 < np.sqrt(np.mean(z**2)) < 1.45, np.round(z, 1)
    true_b = CONSUMER_NOISE["gyroscope"].bias_instability
    measured = np.array([cal.estimated_noise["gyroscope"].bias_instability for cal, _ in runs])
    assert 0.3 * true_b < np.median(measured) < 3 * true_b, measured / true_b
    assert any(line.startswith("  gyroscope: white") and "rad/s" in line for line in noise_lines(runs[0][0], False))
    white_only = np.array([_ferraris_gyro(seed, RecordingSettings(estimate_noise=False))[1] for seed in range(1, 13)])
    assert np.sqrt(np.mean(white_only**2)) > 2.0, np.round(white_only, 1)


def test_the_scatters_moments_from_the_low_rank_residual_maker_are_the_dense_ones():
    """Q = RᵀWR is W less a rank-p term: B from it is B from the dense residual maker (the
    oracle, O(m³)), weighted or not, with a rank-deficient design too."""
    import math

    from scipy.special import gammaln

    from fieldcal.recording.noise_estimate import PRIOR_POWER

    def dense(residuals, design, white, flicker, weights=None):
        m = len(white)
        residuals = residuals.reshape(m, -1)
        d = residuals.shape[1]
        w = np.ones(m) if weights is None else weights
        X = design.reshape(m, -1)
        H = X @ np.linalg.pinv(X.T @ (w[:, None] * X)) @ (X.T * w[None, :])
        R = np.eye(m) - H
        Q = R.T @ (w[:, None] * R)
        observed = float(np.sum(w[:, None] * residuals**2))
        QW, QF = Q * white[None, :], Q @ flicker
        mean_white, mean_flicker = d * np.trace(QW), d * np.trace(QF)
        terms = 2 * d * np.array([np.sum(QW * QW.T), 2 * np.sum(QW * QF.T), np.sum(QF * QF.T)])
        b = math.sqrt(float(np.mean(white))) * np.geomspace(1e-3, 1e3, 241)
        mean = mean_white + b**2 * mean_flicker
        variance = terms[0] + b**2 * terms[1] + b**4 * terms[2]
        scale, dof = variance / (2 * mean), 2 * mean**2 / variance
        log_like = (0.5 * dof - 1) * math.log(observed) - observed / (2 * scale) - 0.5 * dof * np.log(
            2 * scale) - gammaln(0.5 * dof) + PRIOR_POWER * np.log(b)
        weight = np.exp(log_like - log_like.max())
        return float(np.sqrt(np.sum(weight * b**2) / np.sum(weight)))

    rng = np.random.default_rng(12)
    m = 40
    starts = np.cumsum(rng.uniform(5, 9, m))
    flicker = flicker_covariance(starts, rng.uniform(2, 4, m))
    white = rng.uniform(0.5, 2, m) * 1e-4
    for design, weights in ((rng.normal(size=(m, 9)), None), (rng.normal(size=(m, 9)), 1 / white),
                            (np.repeat(rng.normal(size=(m, 3)), 2, axis=1), 1 / white)):
        residuals = rng.normal(size=(m, 3)) * 3e-2
        ours = bias_instability(residuals, design, white, flicker, weights=weights)
        assert ours == pytest.approx(dense(residuals, design, white, flicker, weights), rel=1e-9)


def test_the_window_covariance_is_each_terms_masked_sum():
    """The window covariance sets its diagonal once instead of masking every Gauss-Markov term,
    and makes each term's e^(-gap/τ) as an outer product of two exponentials about a pivot (not
    one per pair): the masked form (the oracle) to rounding, its diagonal bit for bit."""
    from drivers.noise import flicker_bank

    rng = np.random.default_rng(21)
    starts, durations = np.cumsum(rng.uniform(5, 9, 60)), rng.uniform(2, 4, 60)
    noise = TriadNoise(white=1e-3, bias_instability=2e-4)
    a, T = starts, durations
    expected = np.diag(noise.white**2 / T)
    later = a[None, :] >= a[:, None]
    gap = np.where(later, a[None, :] - (a[:, None] + T[:, None]), a[:, None] - (a[None, :] + T[None, :]))
    off_diag = ~np.eye(len(a), dtype=bool)
    for c, s in zip(*flicker_bank(noise.bias_instability)):
        ramp = c * (1 - np.exp(-T / c)) / T
        cross = s**2 * np.outer(ramp, ramp) * np.exp(-np.maximum(gap, 0) / c)
        expected += np.where(off_diag, cross, np.diag(2 * s**2 * c / T * (1 - ramp)))
    got = noise.window_covariance(starts, durations)
    np.testing.assert_allclose(got, expected, rtol=1e-13, atol=1e-15 * np.abs(expected).max())
    np.testing.assert_array_equal(np.diag(got), np.diag(expected))
    with pytest.raises(ValueError, match="windows overlap"):
        noise.window_covariance(np.array([0.0, 1.0]), np.array([2.0, 2.0]))


def test_a_noise_models_window_covariance_from_the_shared_flicker_is_its_own():
    """The stages of one calibration share the poses' flicker covariance of B = 1 (made once):
    each noise model's is diag(white²/T) + B²·F, the device model's own to rounding, for any
    bank length; the shared matrix cannot be changed by a caller, and one with rate random walk
    is refused as the model refuses it."""
    from fieldcal.recording.noise_estimate import window_covariance

    rng = np.random.default_rng(27)
    starts, durations = np.cumsum(rng.uniform(5, 9, 40)), rng.uniform(2, 4, 40)
    for noise in (TriadNoise(white=1e-3, bias_instability=2e-4), TriadNoise(white=3e-5, bias_instability=4e-6,
                                                                             flicker_tau_max_s=1e5),
                  TriadNoise(white=1e-3)):
        ours = window_covariance(noise, starts, durations)
        np.testing.assert_allclose(ours, noise.window_covariance(starts, durations), rtol=1e-13, atol=0)
        ours[0, 0] = -1.0  # the caller's own copy
        np.testing.assert_allclose(window_covariance(noise, starts, durations),
                                   noise.window_covariance(starts, durations), rtol=1e-13, atol=0)
    shared = flicker_covariance(starts, durations)
    with pytest.raises(ValueError):
        shared[0, 0] = 0.0
    with pytest.raises(ValueError, match="rate random walk"):
        window_covariance(TriadNoise(white=1e-3, bias_instability=2e-4, rate_random_walk=1e-5), starts, durations)
