"""Gyro calibration from the rotations between static poses, against an analytic hand-held motion.

The generator is independent of the solver: between rest poses the attitude is
A_i · exp(s1(τ) v1) · exp(s2(τ) v2) with overlapping septic smoothstep profiles, so the axis
of rotation swings during the motion (non-commuting), and its body rate is analytic:
for R = A·B1·B2, ω_body = B2ᵀ·ṡ1·v1 + ṡ2·v2.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fieldcal.solvers import CalibrationError
from fieldcal.model import k_from_terms
from fieldcal.solvers.rotation import _Steps, integrate, scan_scale, solve_gyro_rotations

FS = 100.0
DEG = math.pi / 180
UP = np.array([0.0, 0.0, 1.0])


def smoothstep(x):
    """Septic 0 → 1 and its derivative: rate, acceleration and jerk start and end at zero, as a
    hand's do (a quintic's jerk jumps, which limits any integrator to third order)."""
    x = np.clip(x, 0.0, 1.0)
    return x**4 * (35 - 84 * x + 70 * x * x - 20 * x**3), 140 * x**3 * (1 - x) ** 3


@dataclass(frozen=True)
class Turn:
    """One motion: from pose A, exp(s1 v1)·exp(s2 v2) over [start, start + T] seconds."""
    start: float
    T: float
    v1: np.ndarray
    v2: np.ndarray

    def profiles(self, t):
        tau = np.asarray(t, dtype=float) - self.start
        s1, d1 = smoothstep(tau / (0.65 * self.T))
        s2, d2 = smoothstep((tau - 0.35 * self.T) / (0.65 * self.T))
        return s1, d1 / (0.65 * self.T), s2, d2 / (0.65 * self.T)

    def rate(self, t):
        s1, d1, s2, d2 = self.profiles(t)
        return Rotation.from_rotvec(s2[:, None] * self.v2).inv().apply(d1[:, None] * self.v1) \
            + d2[:, None] * self.v2

    def relative(self, t):
        s1, _, s2, _ = self.profiles(np.atleast_1d(t))
        return Rotation.from_rotvec(s1[0] * self.v1) * Rotation.from_rotvec(s2[0] * self.v2)


@dataclass(frozen=True)
class Recording:
    t: np.ndarray
    omega: np.ndarray  # (n, 3) true body rate, rad/s
    spans: np.ndarray  # (m, 2) inclusive motion spans: last rest sample .. first rest sample
    poses: Rotation  # m + 1 rest attitudes, body to world
    turns: tuple

    def attitude(self, i):
        """Attitude at sample i, which lies in (or at the ends of) some motion's span."""
        k = int(np.searchsorted(self.spans[:, 1], i))
        return self.poses[k] * self.turns[k].relative(self.t[i])

    def up(self):
        """Gravity-up in the body frame at each pose."""
        return self.poses.inv().apply(UP)


@lru_cache(maxsize=None)
def hand_recording(seed, n_poses=20, rest=1.0, axis=None, jitter=0.0):
    """Rest poses joined by two-axis turns of 1.5-2.5 rad each in 2-3.5 s (peaks near 200 °/s).

    ``axis`` forces every turn about one body axis (a degenerate recording); ``jitter`` (s)
    moves each timestamp uniformly within ±jitter, as host receive times do."""
    rng = np.random.default_rng(seed)
    poses = [Rotation.random(random_state=rng) if axis is None else Rotation.identity()]
    rest_n = int(rest * FS)
    spans, turns = [], []
    start = rest_n - 1  # index of the last rest sample before the motion
    for _ in range(n_poses - 1):
        n_move = int(rng.uniform(2.0, 3.5) * FS)
        vs = []
        for _ in range(2):
            direction = rng.normal(size=3) if axis is None else np.eye(3)[axis]
            angle = rng.uniform(1.5, 2.5) * rng.choice([-1, 1])
            vs.append(direction / np.linalg.norm(direction) * angle)
        turns.append(Turn(start / FS, n_move / FS, *vs))
        spans.append((start, start + n_move))
        poses.append(poses[-1] * Rotation.from_rotvec(vs[0]) * Rotation.from_rotvec(vs[1]))
        start += n_move + rest_n - 1
    n = start + rest_n
    t = np.arange(n) / FS + rng.uniform(-jitter, jitter, n)
    omega = np.zeros((n, 3))
    for (i0, i1), turn in zip(spans, turns, strict=True):
        omega[i0:i1 + 1] = turn.rate(t[i0:i1 + 1])
    return Recording(t, omega, np.array(spans), Rotation.concatenate(poses), tuple(turns))


def test_generator_is_what_it_claims():
    rec = hand_recording(1)
    peak = np.max(np.linalg.norm(rec.omega, axis=1)) / DEG
    assert 150 < peak < 300
    up = rec.up()
    # Poses spread over the sphere: the mean up vector is short, every octant-ish direction seen.
    assert np.linalg.norm(up.mean(axis=0)) < 0.5
    # Spans run from rest to rest.
    assert np.abs(rec.omega[rec.spans.ravel()]).max() < 1e-12


def product(rotvecs):
    """exp(r_1)·exp(r_2)·…, one step at a time."""
    r = Rotation.identity()
    for step in Rotation.from_rotvec(rotvecs):
        r = r * step
    return r


def naive_product(omega, t, span):
    """First order: the product of exp(ω_j·h) over the steps."""
    i0, i1 = span
    return product(np.diff(t[i0:i1 + 1])[:, None] * omega[i0:i1])


def trapezoid_product(omega, t, span):
    """Second order without coning: the product of exp(h·(ω_j + ω_j+1)/2) over the steps."""
    i0, i1 = span
    return product(np.diff(t[i0:i1 + 1])[:, None] * (omega[i0:i1] + omega[i0 + 1:i1 + 1]) / 2)


@pytest.mark.parametrize("jitter", [0.0, 2e-3], ids=["uniform", "jittered-2ms"])
def test_integrator_matches_the_analytic_attitude_far_better_than_simpler_rules(jitter):
    rec = hand_recording(2, jitter=jitter)
    mid = [(i0, (i0 + i1) // 2 + 7) for i0, i1 in rec.spans[:6]]  # ends mid-motion, full rate
    spans = np.r_[rec.spans, mid]
    q = Rotation.from_quat(integrate(rec.omega, rec.t, spans))
    truths = [rec.attitude(i0).inv() * rec.attitude(i1) for i0, i1 in spans]
    errors = np.array([(q[k].inv() * truth).magnitude() for k, truth in enumerate(truths)])
    assert errors.max() < 1e-6, errors.max()  # peaks near 200 °/s sampled at 100 Hz
    # The threshold means something: first order (exp(ω_j·h) products) misses by millirad when
    # a span ends in motion, and the trapezoid without the coning term by 10⁻⁵ rest to rest.
    m = len(rec.spans)
    for k in (m, m + 1):
        first = (naive_product(rec.omega, rec.t, spans[k]).inv() * truths[k]).magnitude()
        assert first > 1e-3 > 1000 * errors[k]
    for k in (0, 1, 2):
        second = (trapezoid_product(rec.omega, rec.t, spans[k]).inv() * truths[k]).magnitude()
        assert second > 30 * errors[k], (second, errors[k])
    # A span that is the whole array, starting and ending in motion: one-sided rate slopes.
    i0, i1 = rec.spans[4]
    cut = slice(i0 + 50, i1 - 30)
    q = integrate(rec.omega[cut], rec.t[cut], [(0, i1 - 31 - i0 - 50)])
    truth = rec.attitude(i0 + 50).inv() * rec.attitude(i1 - 31)
    assert (Rotation.from_quat(q[0]).inv() * truth).magnitude() < 1e-6


# Consumer grade (0.01 °/s/√Hz) in SI; tactical (0.15 °/√h) in 16-bit counts, quantised.
GRADES = {"si": dict(counts=False, arw=0.01 * DEG),
          "counts": dict(counts=True, arw=0.15 * DEG / 60)}
UP_SIGMA = 1e-4  # rad per tangent component: a few seconds of accelerometer average
REST_S = 10.0  # the initial rest whose mean is the fixed bias


def true_gyro(rng, counts):
    """K = diag(k)(I + M) and b of a gyro, and the nominal K0 a datasheet would give."""
    nominal = 1877.0 if counts else 1.0
    k = nominal * (1 + rng.uniform(-0.02, 0.02, 3))
    M = rng.uniform(-0.015, 0.015, 6)
    b = (32768.0 + rng.uniform(-60, 60, 3)) if counts else rng.uniform(-0.02, 0.02, 3)
    return k, M, b, nominal


def observe(rec, rng, counts, arw, noise=True):
    """Raw gyro output, the measured up directions, the initial-rest bias and the σ of each."""
    k, M, b, nominal = true_gyro(rng, counts)
    K = k_from_terms(k, M)
    omega = rec.omega + (rng.normal(0, arw * math.sqrt(FS), rec.omega.shape) if noise else 0)
    raw = omega @ K.T + b
    rate_noise = arw
    if counts and noise:
        raw = np.round(raw)
        rate_noise = math.sqrt(arw**2 + 1 / 12 / nominal**2 / FS)  # quantisation, white
    up = rec.up()
    if noise:
        up = Rotation.from_rotvec(rng.normal(0, UP_SIGMA, up.shape)).apply(up)
    b0 = b + K @ rng.normal(0, rate_noise / math.sqrt(REST_S), 3) if noise else b
    sigmas = dict(up_sigma=UP_SIGMA, rate_noise=rate_noise,
                  bias_sigma=nominal * rate_noise / math.sqrt(REST_S))
    return dict(raw=raw, up=up, b0=b0, nominal=nominal, sigmas=sigmas, k=k, M=M, b=b)


def solve(rec, obs, sigmas=True, **kw):
    kw = {"b0": obs["b0"], **(obs["sigmas"] if sigmas else {}), **kw}
    return solve_gyro_rotations(rec.t, obs["raw"], rec.spans, obs["up"][:-1], obs["up"][1:],
                                K0=obs["nominal"], **kw)


@pytest.mark.parametrize("grade", GRADES)
@pytest.mark.parametrize("estimate_bias", [False, True], ids=["bias-fixed", "bias-free"])
def test_noise_free_recovery_is_exact(grade, estimate_bias):
    rec = hand_recording(3)
    obs = observe(rec, np.random.default_rng(30), GRADES[grade]["counts"], 0.0, noise=False)
    b0 = obs["b"] + (0.01 * obs["nominal"] if estimate_bias else 0)  # a wrong start when free
    sol = solve(rec, obs, sigmas=False, b0=b0, estimate_bias=estimate_bias)
    assert sol.diagnostics.scaled_by_residuals and (not sol.diagnostics.held) == estimate_bias
    assert sol.method == "rotation" and sol.parameter_names[6:] == ("m_xy", "m_xz", "m_yx", "m_yz", "m_zx", "m_zy")
    assert np.max(np.abs(sol.scale_factor / obs["k"] - 1)) < 1e-7
    assert np.max(np.abs(sol.misalignment - obs["M"])) < 1e-7
    assert np.max(np.abs(sol.bias - obs["b"])) / obs["nominal"] < 1e-7
    assert np.sqrt(np.mean(sol.residuals**2)) < 1e-7
    # The K0 start is 2 % and 0.9° off: the solver moved, far.
    assert np.max(np.abs(np.diag(sol.K) / obs["nominal"] - 1)) > 1e-3
    iterations = sol.diagnostics.iterations
    assert 0 < iterations < 100 and sol.diagnostics.converged
    assert sol.diagnostics.message == f"Gauss-Newton (Broyden): steps below 0.01 sigma after {iterations} iterations"


@pytest.mark.parametrize("grade", GRADES)
def test_errors_match_the_reported_sigma_over_seeds(grade):
    """With the bias fixed at a noisy initial-rest mean (its σ propagated) and with it free."""
    normalised = {False: [], True: []}
    for seed in range(5):
        rec = hand_recording(10 + seed)
        obs = observe(rec, np.random.default_rng(100 + seed), **GRADES[grade])
        truth = np.r_[obs["b"], obs["k"], obs["M"]]
        for free in (False, True):
            sol = solve(rec, obs, estimate_bias=free)
            # The bias prior (free) adds three equations as it adds three unknowns.
            fit = sol.diagnostics
            assert fit.dof == 2 * len(rec.spans) - 9 and not fit.scaled_by_residuals
            # All twelve: a bias held at the rest mean has that mean's σ.
            z = (sol.theta - truth) / sol.sigma
            assert np.all(np.abs(z) < 3), (seed, free, dict(zip(sol.parameter_names, z.round(2),
                                                                strict=True)))
            normalised[free].append(z)
    for free, zs in normalised.items():
        rms = np.sqrt(np.mean(np.square(zs)))
        assert 0.5 < rms < 1.6, (free, rms)


def test_bias_free_solution_is_consistent():
    rec = hand_recording(3)
    obs = observe(rec, np.random.default_rng(7), **GRADES["counts"])
    sol = solve(rec, obs, estimate_bias=True)  # the rest mean b0 ± bias_sigma is a prior
    assert sol.parameter_names[:3] == ("bias_x", "bias_y", "bias_z") and not sol.diagnostics.held
    assert np.array_equal(sol.bias, sol.theta[:3])
    assert np.all(np.abs(sol.bias - obs["b"]) < 3 * sol.sigma[:3])
    # From the rotations alone, started at mid-scale rather than the rest mean: wider, still right.
    loose = solve(rec, obs, estimate_bias=True, bias_sigma=None, b0=32768.0)
    assert np.all(loose.sigma[:3] > 1.2 * sol.sigma[:3])
    assert np.all(np.abs(loose.bias - obs["b"]) < 3 * loose.sigma[:3])
    # Calibrated rates: the motion's truth back from the raw output.
    i0, i1 = rec.spans[0]
    assert np.abs(sol.calibrate(obs["raw"][i0:i1]) - rec.omega[i0:i1]).max() < 0.01


def test_labels_number_the_poses():
    rec = hand_recording(3)
    obs = observe(rec, np.random.default_rng(7), **GRADES["si"])
    sol = solve(rec, obs)
    assert sol.residual_labels[:3] == ("motion 1→2 a", "motion 1→2 b", "motion 2→3 a")
    assert len(sol.residuals) == len(sol.residual_labels) == 2 * len(rec.spans)
    # Drop motion 5 (a pose rejected): the chain breaks and the poses after it renumber.
    keep = np.r_[0:4, 5:len(rec.spans)]
    up = obs["up"]
    sol = solve_gyro_rotations(rec.t, obs["raw"], rec.spans[keep], up[:-1][keep], up[1:][keep],
                               K0=1.0, b0=obs["b0"], **obs["sigmas"])
    assert sol.residual_labels[6:10] == ("motion 4→5 a", "motion 4→5 b", "motion 6→7 a",
                                         "motion 6→7 b")


def test_too_few_motions_is_refused():
    rec = hand_recording(4, n_poses=6)
    obs = observe(rec, np.random.default_rng(1), **GRADES["si"])
    with pytest.raises(CalibrationError,
                       match=r"5 motions between poses, need at least 7: add more poses"):
        solve(rec, obs)
    with pytest.raises(CalibrationError, match=r"need at least 8"):
        solve(rec, obs, estimate_bias=True, bias_sigma=None)
    with pytest.raises(CalibrationError, match=r"0 motions between poses"):
        solve_gyro_rotations(rec.t, obs["raw"], np.zeros((0, 2)), np.zeros((0, 3)),
                             np.zeros((0, 3)), K0=1.0, b0=0.0)


@pytest.mark.parametrize("noise", [False, True], ids=["noise-free", "noisy"])
def test_turns_about_one_axis_are_refused(noise):
    rec = hand_recording(5, axis=0)
    obs = observe(rec, np.random.default_rng(2), **GRADES["si"], noise=noise)
    with pytest.raises(CalibrationError, match=r"do not span enough rotation axes: .*scale_y"):
        solve(rec, obs, sigmas=noise)


def test_extra_residuals_are_applied():
    rec = hand_recording(3)
    obs = observe(rec, np.random.default_rng(8), **GRADES["si"])
    plain = solve(rec, obs)
    target = obs["k"] * (1 + np.array([2e-3, -1e-3, 1.5e-3]))  # some 100σ from the rotations'
    calls = []

    def prior(K_inv, bias):
        calls.append(bias)
        return (np.diag(np.linalg.inv(K_inv)) - target) / 1e-7

    sol = solve(rec, obs, extra_residuals=prior)
    assert np.all(np.abs(plain.scale_factor - obs["k"]) < 3 * plain.sigma[3:6])
    assert np.all(np.abs(sol.scale_factor - target) < 1e-6)
    fit, plain_fit = sol.diagnostics, plain.diagnostics
    assert np.all(sol.sigma[3:6] < 1e-6) and len(fit.extra_residuals) == 3
    assert fit.dof == plain_fit.dof + 3 and fit.chi2 > plain_fit.chi2 + 100
    assert np.array_equal(calls[-1], obs["b0"])  # the fixed bias is what the callable sees
    # With the bias estimated under its rest prior as well: the prior's three equations pay for
    # the bias's three unknowns and the extra three add theirs (the side block is all six).
    both = solve(rec, obs, extra_residuals=prior, estimate_bias=True)
    assert both.diagnostics.dof == plain_fit.dof + 3 and len(both.diagnostics.extra_residuals) == 6
    assert np.all(np.abs(both.scale_factor - target) < 1e-6)


def test_powell_agrees_with_least_squares():
    rec = hand_recording(3)
    obs = observe(rec, np.random.default_rng(9), **GRADES["counts"])
    lsq, powell = solve(rec, obs), solve(rec, obs, method="powell")
    assert powell.diagnostics.search == "powell" and lsq.diagnostics.search == "lsq"
    assert np.all(np.abs(powell.theta - lsq.theta) <= 0.02 * lsq.sigma)
    assert powell.diagnostics.chi2 == pytest.approx(lsq.diagnostics.chi2, rel=1e-6)


def test_bad_inputs_say_what_is_wrong():
    rec = hand_recording(3)
    obs = observe(rec, np.random.default_rng(9), **GRADES["si"])
    unweighted = "bias_sigma and extra_residuals need up_sigma or rate_noise"
    with pytest.raises(ValueError, match=unweighted):
        solve(rec, obs, sigmas=False, bias_sigma=1e-3)
    with pytest.raises(ValueError, match=unweighted):
        solve(rec, obs, sigmas=False, extra_residuals=lambda K_inv, b: np.zeros(1))
    with pytest.raises(ValueError, match="method"):
        solve(rec, obs, method="newton")
    m = len(rec.spans)  # the chained poses' covariance is (3m + 3)², m motions
    with pytest.raises(ValueError, match=rf"^up_covariance: expected a \({3 * m + 3}, {3 * m + 3}\) matrix for {m} "
                       r"chained motions, and no up_sigma with it$"):
        solve(rec, obs, sigmas=False, up_covariance=np.eye(3 * m))
    with pytest.raises(ValueError, match="dominant diagonal"):
        solve_gyro_rotations(rec.t, obs["raw"], rec.spans, obs["up"][:-1], obs["up"][1:],
                             K0=np.eye(3)[[1, 0, 2]], b0=0.0)


def test_the_parameter_file_holds_the_rotation_calibration():
    """The file's named angles are the lower-triangle terms (Δyz = −m_yx, Δzy = m_zx, Δzx = −m_zy)
    with their σ; the held bias carries the prior's σ; K (upper triangle included) is kept."""
    from fieldcal.earth import Station
    from fieldcal.paramfile import ParameterFile, dump, hash_inputs, loads

    rec = hand_recording(3)
    obs = observe(rec, np.random.default_rng(7), **GRADES["si"])
    sol = solve(rec, obs, output_unit="rad/s")
    assert sol.diagnostics.held == ("bias_x", "bias_y", "bias_z")
    np.testing.assert_array_equal(sol.sigma[:3], np.full(3, obs["sigmas"]["bias_sigma"]))
    pf = ParameterFile.build([sol], station=Station(48.0), procedure="recording", method="rotation",
                             input_sha256=hash_inputs(np.zeros(3)))
    back = loads(dump(pf))["gyro"]
    assert back == sol and back.method == "rotation" and back.residual_unit == "rad"
    np.testing.assert_array_equal(back.K, sol.K)
    m = sol.named()
    np.testing.assert_allclose(back.misalignment, [-m["m_yx"][0], m["m_zx"][0], -m["m_zy"][0]], rtol=1e-12)
    np.testing.assert_array_equal(back.sigma[6:], [m[n][1] for n in ("m_yx", "m_zx", "m_zy")])
    # And against the simulated truth: the file's angles are the true M's, within 4σ.
    true_terms = np.array([-obs["M"][2], obs["M"][4], -obs["M"][5]])
    assert np.all(np.abs(back.misalignment - true_terms) < 4 * back.sigma[6:])


def test_the_exact_jacobian_is_a_hand_worked_turns_derivative():
    """A constant rate ω about a fixed axis n for T seconds, raw = k·ω + b: the turn is exactly
    exp(θ·n), θ = |ω|·T (no slope, no coning), and its derivatives are known in closed form:
    scaling k by dk turns it back by θ/k·dk about n; a bias change δ along n by T/k·δ; one
    perpendicular to n, e, by J_r(θn)·(−T/k)e = −T/k·(sin θ/θ·e − (1 − cos θ)/θ·n × e)."""
    n = np.array([1.0, 2.0, 2.0]) / 3.0
    e = np.array([2.0, -1.0, 0.0]) / math.sqrt(5.0)  # ⟂ n
    rate, T, k, b = 1.3, 2.0, 1877.0, np.array([32768.0, 32700.0, 32800.0])
    t = np.arange(int(T * FS) + 1) / FS
    raw = np.tile(k * rate * n + b, (len(t), 1))
    dK = np.array([np.eye(3), np.zeros((3, 3)), np.zeros((3, 3))])  # d(k·I), then two bias moves
    d_bias = np.array([np.zeros(3), n, e])
    q, D = _Steps(raw, t, [(0, len(t) - 1)], offset=b).jacobian(np.eye(3) / k, np.zeros(3), dK, d_bias)
    theta = rate * T
    np.testing.assert_allclose(Rotation.from_quat(q[0]).as_rotvec(), theta * n, rtol=1e-13, atol=1e-13)
    perpendicular = math.sin(theta) / theta * e - (1 - math.cos(theta)) / theta * np.cross(n, e)
    expected = np.column_stack([-theta / k * n, -T / k * n, -T / k * perpendicular])
    np.testing.assert_allclose(D[0], expected, rtol=1e-11, atol=1e-16)


def test_the_exact_jacobian_is_the_finite_difference_one_on_a_hand_recording():
    """Every element of K and of the bias, on two-axis turns in raw counts: the exact Jacobian and
    central differences agree to their truncation and rounding errors (1e-7 relative here;
    a wrong term would be off by its own size)."""
    rec = hand_recording(3)
    obs = observe(rec, np.random.default_rng(7), **GRADES["counts"])
    steps = _Steps(obs["raw"], rec.t, rec.spans, offset=obs["b0"])
    K = k_from_terms(obs["k"], obs["M"])
    delta_b = obs["b"] - obs["b0"]

    def turned(dK, d_bias):
        return Rotation.from_quat(steps.quaternions(np.linalg.inv(K + dK), delta_b + d_bias))

    dK = np.zeros((12, 3, 3))
    dK[:9].reshape(9, 9)[:, :] = np.eye(9) * obs["nominal"]  # each element of K, 1 count per rad/s
    d_bias = np.zeros((12, 3))
    d_bias[9:] = np.eye(3)  # 1 count
    q, D = steps.jacobian(np.linalg.inv(K), delta_b, dK, d_bias)
    np.testing.assert_array_equal(q, steps.quaternions(np.linalg.inv(K), delta_b))
    h = 1e-5
    for p in range(12):
        # δψ with C(x + h) = C(x)·exp(δψ·h), by central differences of the rotation vector
        ahead = (turned(0 * dK[p], 0 * d_bias[p]).inv() * turned(h * dK[p], h * d_bias[p])).as_rotvec()
        behind = (turned(0 * dK[p], 0 * d_bias[p]).inv() * turned(-h * dK[p], -h * d_bias[p])).as_rotvec()
        np.testing.assert_allclose(D[:, :, p], (ahead - behind) / (2 * h), rtol=0, atol=1e-7 * np.abs(D[:, :, p]).max())


@pytest.mark.parametrize("seed,n_poses", [(3, 20), (4, 6), (11, 20)])
def test_the_scale_scan_finds_the_grid_scale_an_exhaustive_exact_scan_finds(seed, n_poses):
    """The scan integrates most scales over a few motions only (a lower bound of their misfit);
    its choice is every grid scale's exact misfit's least, computed here with ``integrate``, and
    the grid scale nearest the gyro's true sensitivity. Six poses: one motion bounds them all."""
    rec = hand_recording(seed, n_poses=n_poses)
    obs = observe(rec, np.random.default_rng(seed), **GRADES["counts"])
    scales = np.geomspace(1e-3, 1e6, 73)  # fieldcal.recording.calibrate's grid
    up = obs["up"]

    def misfit(k):
        q = Rotation.from_quat(integrate((obs["raw"] - obs["b0"]) / k, rec.t, rec.spans))
        return np.sum((q.inv().apply(up[:-1]) - up[1:]) ** 2)

    found = scan_scale(rec.t, obs["raw"], rec.spans, up[:-1], up[1:], obs["b0"], scales)
    assert found == scales[np.argmin([misfit(k) for k in scales])]
    assert found == scales[np.argmin(np.abs(np.log(scales / np.mean(obs["k"]))))]


def test_motions_replaced_or_not_the_scans_own_make_their_own_steps():
    """The integration steps a Motions keeps are its own: dataclasses.replace starts a new cache,
    and scan_scale uses a Motions only when it holds the very t and raw it was given."""
    from dataclasses import replace

    from fieldcal.solvers.rotation import Motions

    t = np.arange(200) * 0.01
    raw = np.zeros((200, 3))
    raw[50:150, 2] = 0.5  # rad/s about z for 1 s
    spans = np.array([[40, 160]])
    up = np.array([[1.0, 0.0, 0.0]])
    motions = Motions.of(t, raw, spans, up, up)
    first = motions.steps(np.zeros(3))
    assert motions.steps(np.zeros(3)) is first
    doubled = replace(motions, raw=2 * raw)
    assert doubled.steps(np.zeros(3)) is not first
    angle = lambda m: 2 * np.degrees(np.arccos(m.steps(np.zeros(3)).quaternions(np.eye(3), np.zeros(3))[0, 3]))
    assert angle(motions) == pytest.approx(np.degrees(0.5), abs=1e-6)  # 0.5 rad in 1 s
    assert angle(doubled) == pytest.approx(np.degrees(1.0), abs=1e-6)
    # scan_scale given another recording's Motions integrates its own raw: a turn of 90° read in
    # counts of 1/1000 rad/s scans to 1000, whatever the Motions at hand holds.
    from fieldcal.solvers.rotation import scan_scale

    turned = np.zeros((200, 3))
    turned[50:150, 2] = 1000.0 * (np.pi / 2)  # counts: 90° about z in 1 s
    start, end = np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, -1.0, 0.0]])
    scales = np.geomspace(10.0, 1e5, 41)  # 1000 among them
    own = scan_scale(t, turned, spans, start, end, np.zeros(3), scales)
    other = scan_scale(t, turned, spans, start, end, np.zeros(3), scales, motions=doubled)
    assert own == other == pytest.approx(1000.0)


def test_the_chained_up_covariance_is_the_dense_product():
    """Motion i moves by E_iᵀ·C_iᵀ·δup_i − E_iᵀ·δup_{i+1}: the block-bidiagonal map applied block
    by block (O(m²)) gives the dense A·U·Aᵀ (the oracle, O(m³)); so does the up covariance kept by
    its parts, whose dense form is the means' covariance (W ⊗ K·Kᵀ plus each pose's own, in
    output units) carried through K⁻¹ and ∂u/∂a, plus the calibration's shared error."""
    from fieldcal.recording.up_covariance import UpCovariance
    from fieldcal.solvers.rotation import _chained_up_covariance

    rng = np.random.default_rng(8)
    m = 7
    E, C = rng.normal(size=(m, 3, 2)), Rotation.random(m, random_state=3).as_matrix()
    root = rng.normal(size=(3 * m + 3, 3 * m + 3))
    U = root @ root.T
    A = np.zeros((2 * m, 3 * m + 3))
    for i in range(m):
        A[2 * i:2 * i + 2, 3 * i:3 * i + 3] = E[i].T @ C[i].T
        A[2 * i:2 * i + 2, 3 * i + 3:3 * i + 6] = -E[i].T
    np.testing.assert_allclose(_chained_up_covariance(E, C, U), A @ U @ A.T, rtol=1e-12, atol=1e-12 * np.abs(U).max())

    K = np.diag([400.0, 410.0, 395.0]) + rng.normal(size=(3, 3))
    K_inv = np.linalg.inv(K)
    root = rng.normal(size=(m + 1, m + 1))
    W = root @ root.T
    own_counts = rng.uniform(0.5, 2.0, (m + 1, 3))  # each pose's own variance per output axis
    D, shared = rng.normal(size=(m + 1, 3, 3)), rng.normal(size=(m + 1, 3, 9))
    theta_cov = np.cov(rng.normal(size=(9, 30)))
    parts = UpCovariance(D, W, (K_inv[None] * own_counts[:, None, :]) @ K_inv.T, shared, theta_cov)
    means_cov = np.kron(W, K @ K.T) + np.diag(own_counts.ravel())  # output units
    L = np.zeros((3 * m + 3, 3 * m + 3))
    for i in range(m + 1):
        L[3 * i:3 * i + 3, 3 * i:3 * i + 3] = D[i] @ K_inv
    S = shared.reshape(3 * m + 3, 9)
    dense = L @ means_cov @ L.T + S @ theta_cov @ S.T
    np.testing.assert_allclose(parts.dense(), dense, rtol=1e-10, atol=1e-12 * np.abs(dense).max())
    expected = A @ dense @ A.T
    np.testing.assert_allclose(parts.chained(E, C), expected, rtol=1e-10, atol=1e-12 * np.abs(expected).max())
    white = UpCovariance(D, None, parts.own, shared, theta_cov)  # white noise alone: no windows
    expected = A @ (L @ np.diag(own_counts.ravel()) @ L.T + S @ theta_cov @ S.T) @ A.T
    np.testing.assert_allclose(white.chained(E, C), expected, rtol=1e-10, atol=1e-12 * np.abs(expected).max())


def test_a_long_recordings_steps_take_little_more_memory_than_their_terms():
    """The integration terms are made a group of spans at a time: the steps of 300,000 samples of
    motion (600 spans) peak at well under twice the terms' own memory (tracemalloc counts numpy's
    buffers: no clock). Made for all spans at once, their temporaries peaked at 4.7 times. The
    terms are the same as for each span alone (grouping changes nothing but when they are made)."""
    import tracemalloc

    rng = np.random.default_rng(27)
    n = 320_000
    t = np.cumsum(rng.uniform(0.009, 0.011, n))
    raw = rng.normal(32768.0, 50.0, size=(n, 3))
    starts = np.arange(600) * 530 + 10
    spans = np.column_stack([starts, starts + 500])
    tracemalloc.start()
    try:
        steps = _Steps(raw, t, spans, offset=raw[0])
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 2.0 * steps.terms.nbytes, (peak / steps.terms.nbytes)
    for span in (0, 299, 599):  # each span's terms as its own _Steps makes them
        alone = _Steps(raw, t, spans[span:span + 1], offset=raw[0])
        blocks = alone.terms.shape[1] // 64
        mine = steps.terms.reshape(10, 64, -1)[:, :, steps.first_block[span]:steps.first_block[span] + blocks]
        np.testing.assert_array_equal(mine, alone.terms.reshape(10, 64, blocks))


def test_the_rotations_and_their_jacobian_of_many_spans_are_made_a_group_at_a_time(monkeypatch):
    """The quaternions and the exact Jacobian of 600 spans (300,000 steps), made a group of spans
    at a time, are bit for bit those made with all spans in one group, and their temporaries stay
    well under the terms' own memory (tracemalloc counts numpy's buffers: no clock). Made for all
    spans at once, the compositions alone took 1.4 times the terms and were kept."""
    import tracemalloc

    import fieldcal.solvers.rotation as rotation

    rng = np.random.default_rng(28)
    n = 320_000
    t = np.cumsum(rng.uniform(0.009, 0.011, n))
    raw = rng.normal(32768.0, 50.0, size=(n, 3))
    raw[:, 2] += 3000.0 * np.sin(t)  # a real turn to compose, not noise alone
    starts = np.arange(600) * 530 + 10
    spans = np.column_stack([starts, starts + 500])
    K_inv, delta_b = np.eye(3) / 80.0 + 1e-4, np.array([1.0, -2.0, 0.5])
    dK, d_bias = rng.normal(size=(4, 3, 3)) * 1e-3, rng.normal(size=(4, 3))
    steps = _Steps(raw, t, spans, offset=raw[0])
    assert len(steps.span_groups) >= 8
    tracemalloc.start()
    try:
        q, D = steps.jacobian(K_inv, delta_b, dK, d_bias)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 0.5 * steps.terms.nbytes, (peak / steps.terms.nbytes)
    monkeypatch.setattr(rotation, "_SPAN_GROUP_BLOCKS", 1 << 30)
    whole = _Steps(raw, t, spans, offset=raw[0])
    assert len(whole.span_groups) == 1
    q_whole, D_whole = whole.jacobian(K_inv, delta_b, dK, d_bias)
    np.testing.assert_array_equal(q, q_whole)
    np.testing.assert_array_equal(D, D_whole)
    np.testing.assert_array_equal(steps.quaternions(K_inv, delta_b), q_whole)


def test_a_start_holds_the_bias_unless_asked_to_estimate_it():
    from fieldcal.solvers.rotation import RotationStart

    held = RotationStart.of(1.0, [1e-3, 0.0, -2e-3])
    assert held.estimate_bias is False
    np.testing.assert_array_equal(held.b0, [1e-3, 0.0, -2e-3])
    assert RotationStart.of(1.0, 0.0, estimate_bias=True).estimate_bias is True


def test_the_residual_covariance_is_the_hand_placed_direction_noise():
    """Motions sharing a pose correlate by −σ_end,i·σ_start,i+1·E_iᵀ·C_{i+1}·E_{i+1} (the block
    above the diagonal, its transpose below), each motion's own residuals by σ_start² + σ_end²;
    the same whether made afresh or into given zeros."""
    from fieldcal.solvers.rotation import _residual_covariance

    rng = np.random.default_rng(3)
    m = 3
    E = rng.normal(size=(m, 3, 2))
    C = Rotation.random(m, random_state=4).as_matrix()
    shared = np.array([True, False])  # motions 0 and 1 share a pose; 1 and 2 do not
    sigma = np.array([[1e-3, 2e-3], [3e-3, 4e-3], [5e-3, 6e-3]])  # (start, end) per motion
    expected = np.diag(np.repeat(sigma[:, 0] ** 2 + sigma[:, 1] ** 2, 2))
    expected[0:2, 2:4] = -sigma[0, 1] * sigma[1, 0] * (E[0].T @ C[1] @ E[1])
    expected[2:4, 0:2] = expected[0:2, 2:4].T
    made = _residual_covariance(E, C, shared, sigma, None, np.ones(m))
    into = _residual_covariance(E, C, shared, sigma, None, np.ones(m), out=np.zeros((2 * m, 2 * m)))
    np.testing.assert_allclose(made, expected, rtol=1e-12, atol=1e-20)
    np.testing.assert_allclose(into, expected, rtol=1e-12, atol=1e-20)


def test_the_residuals_are_the_rotations_misfit_in_radians():
    """Each residual takes the direction noise of its two poses, σ² + σ² per tangent component
    (the angle random walk adds little here): the reported residuals are radians of that size,
    not the whitened ones (about 1). Each iteration evaluates the model at least once more."""
    rec = hand_recording(3)
    obs = observe(rec, np.random.default_rng(7), **GRADES["counts"])
    sol = solve(rec, obs, estimate_bias=True)
    assert len(sol.residuals) == 2 * len(rec.spans)
    rms = np.sqrt(np.mean(sol.residuals**2))
    assert 0.5 * math.sqrt(2) * UP_SIGMA < rms < 2 * math.sqrt(2) * UP_SIGMA
    fit = sol.diagnostics
    assert fit.evaluations > fit.iterations > 0


def test_a_weak_geometry_names_its_parameter_and_condition_number():
    """A hand-made Jacobian whose third column moves the rotations 1e-9 as much as the others:
    refused, naming that parameter and the condition number σ_max/σ_min = 1e9."""
    from types import SimpleNamespace

    from fieldcal.solvers.rotation import _check_geometry

    model = SimpleNamespace(nb=3, names=("bias_x", "scale_y", "m_xz"))
    J = np.vstack([np.diag([1.0, 1.0, 1e-9]), np.zeros((1, 3))])
    with pytest.raises(CalibrationError) as refused:
        _check_geometry(model, J, np.ones(3), "gyro")
    assert str(refused.value) == ("gyro: the motions do not span enough rotation axes: m_xz barely change the "
                                  "rotations (condition number 1e+09); turn the unit about other axes")
    sound = np.vstack([np.diag([1.0, 2.0, 3.0]), np.zeros((1, 3))])  # condition number 3: taken
    np.testing.assert_array_equal(_check_geometry(model, sound, np.full(3, 2.0), "gyro"), 2.0 * sound)
