"""Classic 12-position method (paper eqs. 4-8) on simulated Table 1 data, and agreement with the
norm method on the same device."""
import math
from functools import lru_cache

import numpy as np
import pytest

from drivers.sim.device import paper_mimu
from fieldcal.procedure.positions import load_procedure
from fieldcal.run.simcal import DEFAULT_STATION, run_simulated_calibration
from fieldcal.procedure.windows import MINUS, PLUS, STATIC
from fieldcal.run.simrun import plan_procedure, simulate_averages
from fieldcal.solvers.solve import average_covariance, models_from_truth
from fieldcal.solvers import CalibrationError, StaticNormProblem, solve_classic, solve_norm


@lru_cache(maxsize=None)  # one process builds each seed's run once, whichever fixture asks
def classic_run(seed):
    procedure = load_procedure("classic-12")
    device = paper_mimu()
    plan = plan_procedure(procedure, 250.0, np.random.default_rng(seed))
    means, _ = simulate_averages(plan, device, DEFAULT_STATION, 250.0, seed=seed)
    up = np.array([p.up_body for p in procedure.positions])
    kinds = np.array([w.kind for w in plan.windows])
    pos = np.array([w.position for w in plan.windows])
    g, rate = DEFAULT_STATION.gravity, math.radians(procedure.rate_step.rate_deg_s)
    vertical = DEFAULT_STATION.earth_rate_vertical
    static = kinds == STATIC
    spin = (kinds == PLUS) | (kinds == MINUS)
    sign = np.where(kinds == PLUS, 1.0, -1.0)
    windows = np.array(plan.windows, dtype=object)
    models = models_from_truth(device)
    accel = solve_classic(means["accelerometer"][static], g * up[pos[static]], "accelerometer",
                          "specific_force", covariance=average_covariance(
                              models["accelerometer"], list(windows[static]), 250.0))
    gyro_inputs = (sign[spin] * rate + vertical)[:, None] * up[pos[spin]]
    gyro = solve_classic(means["gyroscope"][spin], gyro_inputs, "gyroscope", "angular_rate",
                         covariance=average_covariance(models["gyroscope"], list(windows[spin]), 250.0))
    return device, means, static, accel, gyro


@pytest.fixture(scope="module")
def classic():
    return [classic_run(seed) for seed in (21, 22, 23)]


@pytest.fixture(scope="module")
def first_classic():
    """classic[0] alone, for the tests that read no other: the fast loop builds one run, not three."""
    return classic_run(21)


def test_classic_recovers_k_and_u0(classic):
    for device, _, _, accel, gyro in classic:
        for sol in (accel, gyro):
            truth = device[sol.name]
            named = sol.named()
            # σ of K_ij = k_i·m_ij from the terms' σ (K_ii: the scale factor's own).
            sigma_k = np.array([[named[f"scale_{a}" if a == b else f"m_{a}{b}"][1] * (1 if a == b else sol.K[i, i])
                                 for b in "xyz"] for i, a in enumerate("xyz")])
            sigma_b = sol.sigma[:3]
            # The table is aligned, so the full K is the true lower-triangular one: the upper
            # triangle must come out zero within noise too.
            assert np.all(np.abs(sol.K - truth.K) < 4.5 * sigma_k), (sol.name, (sol.K - truth.K) / sigma_k)
            assert np.all(np.abs(sol.bias - truth.bias) < 4.5 * sigma_b), sol.name


def test_norm_method_cannot_use_the_six_classic_directions(first_classic):
    _, means, static, _, _ = first_classic
    with pytest.raises(CalibrationError, match="degenerate"):
        solve_norm(StaticNormProblem(means["accelerometer"][static], DEFAULT_STATION.gravity))


def test_norm_method_on_field_18_agrees_with_classic(classic):
    z = []
    for k, (_, _, _, accel, gyro) in enumerate(classic):
        field = run_simulated_calibration(seed=40 + k)
        for sol in (accel, gyro):
            norm = field.solutions[sol.name]
            # The nine named parameters both give (the classic K's lower-triangle angles).
            z.append((norm.file_theta - sol.file_theta) / np.hypot(norm.file_sigma, sol.file_sigma))
    z = np.array(z)
    # Independent estimates of the same parameters: differences of order their combined 1σ.
    assert np.sqrt(np.mean(z**2)) < 1.5, z
    assert np.all(np.abs(z) < 4), z


def test_residual_scatter_alone_misses_common_mode_drift(first_classic):
    device, means, static, with_noise_model, _ = first_classic
    procedure = load_procedure("classic-12")
    up = np.array([p.up_body for p in procedure.positions])
    scatter_only = solve_classic(means["accelerometer"][static], DEFAULT_STATION.gravity * up,
                                 "accelerometer", "specific_force")
    np.testing.assert_allclose(scatter_only.bias, with_noise_model.bias)  # same estimate
    assert np.all(scatter_only.sigma[:3] < with_noise_model.sigma[:3])  # smaller, wrongly


def test_classic_rejects_inputs_that_do_not_span_the_axes():
    with pytest.raises(ValueError, match="span all three axes"):
        solve_classic(np.ones((6, 3)), np.tile([0.0, 0.0, 9.8], (6, 1)), "accelerometer", "specific_force")


def tilted_faces(K, bias, gravity, offsets):
    """The six faces' exact means (no noise) of raw = K·a + bias when each face's true up is
    tilted off its axis by the small offsets (rad) of its row of ``offsets`` (the up axis's
    entry ignored)."""
    from fieldcal.solvers.classic import SIX_FACES
    up = SIX_FACES + offsets * (1 - np.abs(SIX_FACES))
    up /= np.linalg.norm(up, axis=1, keepdims=True)
    return gravity * up @ K.T + bias


def test_six_position_bias_is_blind_to_the_tables_tilt_and_the_faces_norms_are_g():
    """Hand-worked: a unit turned over on a table that slopes 0.25°, each axis where it is
    horizontal reading the slope's g·sin ≈ 43 mm/s² on both faces of a pair (turned over about
    it), and each placement a little off besides. The least-squares bias (the mean of all six
    faces) takes that in; Ferraris's, from the two faces where the axis is vertical, sees it only
    at second order, and the calibrated faces' norms are g."""
    from fieldcal.solvers.classic import SIX_FACES, solve_six_position
    g = 9.81
    K = np.array([[1.01, 0.004, -0.003], [0.006, 0.99, 0.002], [-0.005, 0.007, 1.02]])
    bias = np.array([0.3, -0.2, 0.5])
    rng = np.random.default_rng(4)
    offsets = math.radians(0.25) + rng.normal(0.0, math.radians(0.05), (6, 3))
    faces = tilted_faces(K, bias, g, offsets)
    sol, _ = solve_six_position(faces, g, "accelerometer", "specific_force", "m/s^2", np.eye(18) * 1e-6)
    least_squares = solve_classic(faces, g * SIX_FACES, "accelerometer", "specific_force")
    assert np.min(np.abs(least_squares.bias - bias)) > 0.02  # what the old solution did
    assert np.max(np.abs(sol.bias - bias)) < 2e-4  # 0.1 % of the least-squares error
    np.testing.assert_allclose(np.linalg.norm(sol.calibrate(faces), axis=1), g, atol=1e-9)
    np.testing.assert_allclose(np.diag(sol.K), np.diag(K), rtol=3e-5)
