"""The bound of the bias at the end of the calibration (DESIGN 12: the value the unit is used
with): the bias process's covariance with window means, and the best linear unbiased predictor's
error beside the turn-on constant's."""
import numpy as np
import pytest

from drivers.noise import TriadNoise


def test_a_point_is_the_limit_of_a_vanishing_window():
    """point_covariance against window_covariance with a window of 1 µs at t (an independent
    path through the exact bank formulas)."""
    noise = TriadNoise(white=1e-3, bias_instability=2e-4, flicker_tau_max_s=1e5)
    starts, durations, t = np.array([0.0, 50.0, 400.0]), np.array([20.0, 100.0, 30.0]), 1000.0
    windows = noise.window_covariance(np.r_[starts, t], np.r_[durations, 1e-6])
    np.testing.assert_allclose(noise.point_covariance(starts, durations, t), windows[-1, :3], rtol=1e-5)
    flicker_only = TriadNoise(white=0.0, bias_instability=2e-4, flicker_tau_max_s=1e5)
    # (10 ms: shorter windows lose the variance to rounding in 1 − ramp; 10 ms costs 0.2 %)
    point = flicker_only.window_covariance([t], [1e-2])[0, 0]
    assert noise.bias_variance() == pytest.approx(point, rel=5e-3)
    with pytest.raises(ValueError, match="ends after"):
        noise.point_covariance(starts, durations, 100.0)


def test_the_predictor_is_the_flat_prior_limit_of_gaussian_conditioning():
    """For a linear model y = A·x + n, the BLUP error of E·x + f (f correlated with n) is the
    posterior covariance of E·x + f given y as x's prior widens: computed here by plain Gaussian
    conditioning, against crb's Goldberger formula."""
    from fieldcal.solvers.crb import EndBias, _bound

    rng = np.random.default_rng(2)
    m, p = 30, 12  # 9 parameters and 3 nuisances
    A = rng.standard_normal((m, p))
    root = rng.standard_normal((m + 3, m + 3))
    joint = root @ root.T / (m + 3) + 0.1 * np.eye(m + 3)  # (n, f) jointly
    C, G, V = joint[:m, :m], joint[:m, m:], joint[m:, m:]
    steps = np.full(p, 1e-3)
    bound, end = _bound(lambda x: x @ A.T, np.zeros(p), steps, C, EndBias(G, V))
    prior = 1e6
    E = np.zeros((3, p))
    E[:, :3] = np.eye(3)
    s_yy = prior * A @ A.T + C
    s_by = prior * E @ A.T + G.T
    posterior = prior * E @ E.T + V - s_by @ np.linalg.solve(s_yy, s_by.T)
    np.testing.assert_allclose(end.predicted, posterior, rtol=1e-4, atol=1e-9)
    # the constant's own estimate (GLS) used as the end value: its error, by the estimator itself
    L = np.linalg.solve(A.T @ np.linalg.solve(C, A), A.T @ np.linalg.inv(C))[:3]
    np.testing.assert_allclose(end.constant, L @ C @ L.T - L @ G - G.T @ L.T + V, rtol=1e-6)
    np.testing.assert_allclose(bound, (np.linalg.inv(A.T @ np.linalg.solve(C, A)))[:9, :9], rtol=1e-6)


def _field18(models):
    from fieldcal.planning.design import Design, OperatorModel, timeline
    from fieldcal.procedure.positions import load_procedure

    reference = load_procedure("field-18")
    step = reference.rate_step
    design = Design(tuple(p.attitude for p in reference.positions), reference.dwell_s, step.rate_deg_s, step.turns)
    windows, _ = timeline(design, OperatorModel())
    return windows, np.array(design.attitudes), step.rate_deg_s


def test_with_white_noise_alone_the_end_is_the_turn_on_bias():
    """No bias process: the bias at the end is the constant, and both σ are the bound's."""
    from dataclasses import replace

    from drivers.sim.device import paper_mimu
    from fieldcal.earth import Station
    from fieldcal.planning.design import end_bias_sigmas, window_sigmas
    from fieldcal.solvers.solve import models_from_truth

    device = {n: replace(t, noise=replace(t.noise, bias_instability=0.0)) for n, t in paper_mimu().items()}
    models = {n: m for n, m in models_from_truth(device).items() if n != "inclinometer"}
    windows, attitudes, rate = _field18(models)
    station = Station(40.0, 50.0)
    turn_on = window_sigmas(windows, attitudes, rate, models, station, 250.0)
    for name, (predicted, constant) in end_bias_sigmas(windows, attitudes, rate, models, station, 250.0).items():
        np.testing.assert_allclose(predicted, turn_on[name][:3], rtol=1e-9)
        np.testing.assert_allclose(constant, turn_on[name][:3], rtol=1e-9)


def test_field_18_based_targets_judge_biases_at_the_end_and_take_overrides():
    """--target field-18[,TRIAD.GROUP=σ]: field-18's σ with the biases' those against the bias at
    the end of the run (of the solver's bias_at_end, the best linear unbiased predictor); a group
    given after it replaces it
    (in operator units: °/h for a gyro bias); TRIAD.GROUP=σ alone is what it always was."""
    from drivers.sim.device import paper_mimu
    from fieldcal.earth import Station
    from fieldcal.planning.command import judged_at_end, parse_targets, resolve_targets
    from fieldcal.planning.design import Design, OperatorModel, bound_sigmas, end_bias_sigmas, timeline
    from fieldcal.procedure.positions import load_procedure
    from fieldcal.solvers.solve import models_from_truth
    from fieldcal.units import display_scale

    models = models_from_truth(paper_mimu())
    station = Station(40.0, 50.0)
    reference = load_procedure("field-18")
    step = reference.rate_step
    design = Design(tuple(p.attitude for p in reference.positions), reference.dwell_s, step.rate_deg_s, step.turns)
    at_end = bound_sigmas(design, OperatorModel(), models, station, 250.0, bias_at_end=True)
    turn_on = bound_sigmas(design, OperatorModel(), models, station, 250.0)
    windows, seconds = timeline(design, OperatorModel())
    ends = end_bias_sigmas(windows, np.array(design.attitudes), step.rate_deg_s, models, station, 250.0, seconds)
    for name in models:
        np.testing.assert_allclose(at_end[name][:3], ends[name][0], rtol=1e-12)
        np.testing.assert_allclose(at_end[name][3:], turn_on[name][3:], rtol=1e-12)
        # the bias at the end carries the process's wander the constant does not
        assert np.all(at_end[name][:3] > turn_on[name][:3])

    assert judged_at_end("field-18") and judged_at_end("field-18, gyroscope.bias=2")
    assert not judged_at_end("gyroscope.bias=2")
    assert {n: list(t) for n, t in resolve_targets("field-18", models, at_end).items()} == \
        {n: list(t) for n, t in at_end.items()}
    tightened = resolve_targets("field-18,gyroscope.bias=0.5", models, at_end)
    gyro = models["gyroscope"]
    np.testing.assert_allclose(tightened["gyroscope"][:3] * display_scale(gyro.kind, gyro.output_unit, 0), 0.5)
    np.testing.assert_array_equal(tightened["gyroscope"][3:], at_end["gyroscope"][3:])
    np.testing.assert_array_equal(tightened["accelerometer"], at_end["accelerometer"])
    alone = resolve_targets("gyroscope.bias=0.5", models, at_end)
    assert np.all(np.isinf(alone["accelerometer"]))
    np.testing.assert_array_equal(alone["gyroscope"], parse_targets("gyroscope.bias=0.5", models)["gyroscope"])


def test_a_bad_group_after_field_18_is_a_one_line_error(tmp_path, capsys):
    from fieldcal.cli.main import main

    out = tmp_path / "p.yaml"
    assert main(["plan", "--config", "sim", "--target", "field-18,magnetometer.bias=1", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert "TRIAD.GROUP" in err and len(err.splitlines()) == 1 and not out.exists()


def test_a_planned_procedure_carries_no_bias_target_the_tui_cannot_measure():
    """The TUI's tracker shows the turn-on constant's σ; a bias judged at the end of the
    calibration is another quantity, so its target is not written for it to look met."""
    from drivers.sim.device import paper_mimu
    from fieldcal.planning.command import operator_targets
    from fieldcal.solvers.solve import models_from_truth

    models = models_from_truth(paper_mimu())
    limits = {name: np.full(9, 1e-4) for name in models}
    both = operator_targets(models, limits)
    at_end = operator_targets(models, limits, at_end=True)
    for name in models:
        assert {"bias_x", "bias_y", "bias_z"} <= set(both[name])
        assert set(at_end[name]) == set(both[name]) - {"bias_x", "bias_y", "bias_z"}
