"""The thermal model fitted jointly with the norm calibration (issue 28): each average tagged with
the unit's mean temperature by the engine, the bias polynomial's order chosen from the data, and
every parameter (thermal ones included) against the truth in its own σ."""
from __future__ import annotations

import numpy as np
import pytest

from drivers.sim.thermal import SimThermal, TemperatureProfile, ThermalTruth
from fieldcal.earth import Station
from fieldcal.model import distort_with
from fieldcal.procedure.positions import load_procedure, parse_procedure
from fieldcal.procedure.windows import WindowKind, WindowRecord
from fieldcal.solvers import CalibrationError, StaticNormProblem, solve_norm
from fieldcal.solvers.thermal import solve_thermal_norm

G = 9.80154
MG = 9.80665e-3
UP = np.array([p.up_body for p in load_procedure("field-18").positions])
THETA = np.r_[np.array([1.0, 2.0, 3.0]) * MG, 1.0001, 1.0002, 1.0003, 2e-4, -3e-4, 4e-4]
B1 = np.array([0.3, -0.5, 0.8]) * MG  # per K
B2 = np.array([0.01, 0.0, -0.02]) * MG  # per K²
TRUTH_REF_C = 25.0
SIGMA = 7e-5  # m/s², a 200 s average of the paper's accelerometer
# the unit warming up over field-18: one dwell every 283 s, 20 °C + 13 K (1 − exp(−t/1 h))
TEMPERATURES = 20.0 + 13.0 * -np.expm1(-(100.0 + 283.0 * np.arange(18)) / 3600.0)


def _averages(seed: int, b2=B2) -> np.ndarray:
    rng = np.random.default_rng(seed)
    dt = TEMPERATURES[:, None] - TRUTH_REF_C
    return distort_with(THETA, G * UP) + B1 * dt + b2 * dt**2 + rng.normal(scale=SIGMA, size=(18, 3))


def _truth_at(ref_c: float, b2=B2) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The true b₀, b₁, b₂ about the fit's reference (the polynomial re-centred by hand)."""
    d = ref_c - TRUTH_REF_C
    return THETA[:3] + B1 * d + b2 * d**2, B1 + 2 * b2 * d, b2


def _z(fit, b2=B2) -> np.ndarray:
    cal, model = fit.calibration, fit.calibration.thermal
    b0, b1, b2 = _truth_at(model.reference_c, b2)
    truth = np.r_[b0, THETA[3:], b1, b2][:9 + 3 * model.order]
    sigma = np.r_[cal.sigma, model.bias_terms_sigma.ravel()]
    return (np.r_[cal.theta, model.bias_terms.ravel()] - truth) / sigma


def test_joint_fit_recovers_the_truth_with_the_order_it_has():
    fit = solve_thermal_norm(StaticNormProblem(_averages(1), G), TEMPERATURES, np.full((18, 3), SIGMA))
    model = fit.calibration.thermal
    assert model.order == 2 and list(fit.chi2_by_order) == [0, 1, 2]
    assert model.reference_c == pytest.approx(TEMPERATURES.mean())
    assert model.range_c == (TEMPERATURES.min(), TEMPERATURES.max())
    assert np.all(np.abs(_z(fit)) < 4.0)
    # without the thermal terms the same averages miss the biases by hundreds of σ
    plain = solve_norm(StaticNormProblem(_averages(1), G), np.full((18, 3), SIGMA), method="lsq")
    assert plain.diagnostics.chi2 > 1e4 * plain.diagnostics.dof


def test_the_joint_covariance_holds_every_sigma_and_its_condition_is_the_jacobians():
    """The fit's joint covariance (JᵀJ)⁻¹ (times χ²/dof when Birge-scaled): the nine's block is the
    calibration's, its diagonal the thermal terms' σ², and its condition number the square of the
    Jacobian's, which the diagnostics state (scaling leaves a condition number as it is)."""
    fit = solve_thermal_norm(StaticNormProblem(_averages(1), G), TEMPERATURES, np.full((18, 3), SIGMA))
    cal, model = fit.calibration, fit.calibration.thermal
    count = 9 + 3 * model.order + (3 if model.scale_drift is not None else 0)
    assert fit.covariance.shape == (count, count)
    np.testing.assert_allclose(fit.covariance[:9, :9], cal.covariance, rtol=1e-12)
    sigma = np.sqrt(np.diag(fit.covariance))
    np.testing.assert_allclose(sigma[9:9 + 3 * model.order], model.bias_terms_sigma.ravel(), rtol=1e-12)
    assert cal.diagnostics.condition_number ** 2 == pytest.approx(np.linalg.cond(fit.covariance), rel=1e-6)


def test_a_linear_unit_and_a_cold_one_get_terms_found_near_zero():
    linear = solve_thermal_norm(StaticNormProblem(_averages(2, b2=0 * B2), G), TEMPERATURES, np.full((18, 3), SIGMA))
    # 18 norms cannot tell a quadratic term from the drift and the linear one well enough to drop
    # it harmlessly (it would move them by more than half their σ): kept, and found ~0
    assert linear.calibration.thermal.order >= 1
    assert np.all(np.abs(_z(linear, 0 * B2)) < 4.0)
    rng = np.random.default_rng(3)
    still = distort_with(THETA, G * UP) + rng.normal(scale=SIGMA, size=(18, 3))
    fit = solve_thermal_norm(StaticNormProblem(still, G), TEMPERATURES, np.full((18, 3), SIGMA))
    model = fit.calibration.thermal
    # room for the drift: fitted, and found ~0, as are the bias terms 18 norms cannot rule out
    assert model.scale_drift is not None
    assert np.all(np.abs(model.scale_drift / model.scale_drift_sigma) < 4.0)
    assert np.all(np.abs(model.bias_terms / model.bias_terms_sigma) < 4.0)
    assert np.all(np.abs(fit.calibration.errors_in_sigma(THETA)) < 4.0)
    without = solve_thermal_norm(StaticNormProblem(still, G), TEMPERATURES, np.full((18, 3), SIGMA),
                                 scale=False, max_order=0)
    plain = solve_norm(StaticNormProblem(still, G), np.full((18, 3), SIGMA), method="lsq")
    np.testing.assert_allclose(without.calibration.theta, plain.theta, rtol=0, atol=1e-3 * SIGMA)


def test_sigma_is_honest_over_seeds():
    # 40 seeded fits (about a second): each parameter's RMS z, thermal terms included, near 1
    z = np.array([_z(solve_thermal_norm(StaticNormProblem(_averages(100 + s), G), TEMPERATURES,
                                        np.full((18, 3), SIGMA))) for s in range(40)])
    assert z.shape == (40, 15)  # every fit chose the true order
    rms = np.sqrt(np.mean(z**2, axis=0))
    assert np.all((rms > 0.7) & (rms < 1.35)), rms.round(2)


S1 = np.array([50.0, -30.0, 40.0]) * 1e-6  # scale drift per K, configs/sim-warmup.yaml's accelerometer


def _drifting_averages(seed: int) -> np.ndarray:
    """``_averages`` of a unit whose scale factors also drift: diag(1 + s₁ΔT)·K·a + b(T)."""
    rng = np.random.default_rng(seed)
    dt = TEMPERATURES[:, None] - TRUTH_REF_C
    clean = distort_with(THETA, G * UP) - THETA[:3]
    return clean * (1 + S1 * dt) + THETA[:3] + B1 * dt + B2 * dt**2 + rng.normal(scale=SIGMA, size=(18, 3))


def test_a_drifting_accelerometer_is_honest_over_seeds():
    # The drift was fitted only where the 18 norms left room beside the chosen order, so never
    # beside a quadratic bias: unmodelled, it pulled the biases and scale factors (RMS z 2.9 here,
    # 2.06 on configs/sim-warmup.yaml). 30 seeds, about a second.
    from fieldcal.thermal import truth_about

    z = []
    for s in range(30):
        fit = solve_thermal_norm(StaticNormProblem(_drifting_averages(200 + s), G), TEMPERATURES,
                                 np.full((18, 3), SIGMA))
        model = fit.calibration.thermal
        theta, terms = truth_about(THETA, TRUTH_REF_C, np.vstack([B1, B2]), S1, model.reference_c)
        assert model.order == 2 and model.scale_drift is not None
        z.append(np.r_[fit.calibration.errors_in_sigma(theta), (model.bias_terms - terms).ravel() / model.bias_terms_sigma.ravel(),
                       (model.scale_drift - S1) / model.scale_drift_sigma])
    z = np.array(z)
    # Σz² over 30 independent fits is χ² with 30 degrees of freedom per parameter; for all 18 of
    # them together (correlated within a fit) the 0.1 % and 99.9 % points of χ²₃₀ still bound each.
    per_parameter = np.sum(z**2, axis=0)
    assert np.all((per_parameter > 11.6) & (per_parameter < 59.7)), np.sqrt(per_parameter / 30).round(2)


def test_one_temperature_per_average_is_required():
    with pytest.raises(ValueError, match="one finite temperature per average"):
        solve_thermal_norm(StaticNormProblem(_averages(1), G), TEMPERATURES[:-1], np.full((18, 3), SIGMA))
    with pytest.raises(ValueError, match=r"^max_order: expected 0 to 3, got 4$"):
        solve_thermal_norm(StaticNormProblem(_averages(1), G), TEMPERATURES, np.full((18, 3), SIGMA), max_order=4)


# The engine tags each window with the unit's mean temperature -------------------------------

def test_window_temperature_round_trips_and_old_windows_have_none():
    w = WindowRecord(WindowKind("static"), 1.0, 2.0, 0.0, {"accelerometer": [0.0, 0.0, 9.8]}, 23.5)
    assert WindowRecord.from_dict(w.to_dict()) == w
    old = w.to_dict()
    del old["temperature_c"]
    assert WindowRecord.from_dict(old).temperature_c is None
    assert "temperature_c" not in WindowRecord.from_dict(old).to_dict()


PROFILE = TemperatureProfile("ramp", start_c=10.0, rise_k=30.0, rate_k_per_s=0.05)


@pytest.fixture(scope="module")
def warm_run(tmp_path_factory):
    """A short field-18 (3 s dwells at 20 Hz) through the conductor, the unit warming 0.05 K/s."""
    from fieldcal.run.runner import RunSpec, run_headless

    text = load_procedure("field-18").text.replace("name: field-18", "name: mini").replace("dwell_s: 200", "dwell_s: 3") \
        .replace("rate_step: {rate_deg_s: 10, turns: 1, ramp_s: 2, settle_s: 1}",
                 "rate_step: {rate_deg_s: 60, turns: 1, ramp_s: 3, settle_s: 1}")
    thermal = SimThermal(PROFILE, {"accelerometer": ThermalTruth(25.0, np.array([B1 * 10]), np.zeros(3)),
                                   "gyroscope": ThermalTruth(25.0, np.radians([[0.02, -0.05, 0.08]]), np.zeros(3))})
    spec = RunSpec(parse_procedure(text, "mini.yaml"), Station(40.0, 50.0), seed=3, rate_hz=20.0,
                   sim_thermal=thermal)
    directory = tmp_path_factory.mktemp("warm") / "run"
    return directory, run_headless(spec, directory)


def test_each_window_carries_the_mean_temperature_of_its_samples(warm_run):
    from fieldcal.run.runner import open_run

    windows = [w for step in open_run(warm_run[0]).completed for w in step.windows]
    assert len(windows) == 54
    for w in windows:
        # the window's samples are at start, start + 1/rate, ... (duration · rate of them)
        t = w.start + np.arange(round(w.duration * 20.0)) / 20.0
        assert w.temperature_c == pytest.approx(PROFILE.at(t).mean(), abs=1e-9)
    assert windows[-1].temperature_c - windows[0].temperature_c > 5.0


def test_the_run_prints_the_thermal_model_beside_the_truth(warm_run):
    import io

    from fieldcal.cli.sessions import _print_result

    outcome = warm_run[1]
    acc = outcome.unit.solutions["accelerometer"]
    assert acc.thermal is not None and acc.thermal.order >= 1
    out = io.StringIO()
    _print_result(outcome, out)
    text = out.getvalue()
    section = text[text.index("accelerometer ("):text.index("gyroscope (")]
    assert "thermal model about" in section and "b1 x" in section and "mg/K" in section
    # the true b1 (ten times B1: 3, -5, 8 mg/K) is printed beside the solved one, with error/σ
    rows = {line.split()[0] + line.split()[1]: line.split() for line in section.splitlines()
            if line.strip().startswith("b1 ")}
    assert [rows[f"b1{a}"][6] for a in "xyz"] == ["3", "-5", "8"]
    assert all(abs(float(rows[f"b1{a}"][8])) < 4.0 for a in "xyz")


def test_the_largest_error_printed_counts_the_thermal_terms(warm_run):
    # It was taken over the nine parameters alone, so a thermal term 3σ off went unreported.
    import io

    from fieldcal.cli.sessions import _print_result
    from fieldcal.report import _thermal_errors, thermal_truths

    outcome = warm_run[1]
    truths = thermal_truths(outcome.unit.solutions, outcome.truth, outcome.thermal_truth)
    worst_term = max(float(np.max(np.abs(_thermal_errors(cal.thermal, truths[n][1]))))
                     for n, cal in outcome.unit.solutions.items() if cal.thermal.order)
    worst_nine = max(float(np.nanmax(np.abs(cal.errors_in_sigma(truths[n][0]))))
                     for n, cal in outcome.unit.solutions.items())
    out = io.StringIO()
    _print_result(outcome, out)
    printed = float(out.getvalue().split("largest error against the simulation truth: ")[1].split("σ")[0])
    assert printed == pytest.approx(max(worst_term, worst_nine), abs=0.006)


def test_truth_re_centred_by_hand():
    from fieldcal.thermal import truth_about

    theta = np.array([1.0, 1.0, 1.0, 2.0, 2.0, 2.0, 1e-3, 0.0, 0.0])
    terms = np.array([[0.1] * 3, [0.01] * 3])
    moved, moved_terms = truth_about(theta, 20.0, terms, [1e-3, 0.0, 0.0], 22.0)
    # b0' = 1 + 0.1·2 + 0.01·4 = 1.24; b1' = 0.1 + 2·0.01·2 = 0.14; b2' = 0.01; kx' = 2·1.002
    np.testing.assert_allclose(moved[:3], 1.24)
    np.testing.assert_allclose(moved_terms, [[0.14] * 3, [0.01] * 3])
    np.testing.assert_allclose(moved[3:6], [2.004, 2.0, 2.0])
    np.testing.assert_array_equal(moved[6:], theta[6:])


def test_a_warm_gyro_is_solved_within_its_sigma(warm_run):
    # Its bias moves 0.05-0.08 °/s/K over 20 K: far beyond the Earth rate its static norms weigh,
    # so weights taken at a solution that ignores the warming would be wrong.
    from fieldcal.report import thermal_truths, worst_error

    outcome = warm_run[1]
    gyro = outcome.unit.solutions["gyroscope"]
    assert gyro.thermal is not None and gyro.thermal.order >= 1
    truths = thermal_truths(outcome.unit.solutions, outcome.truth, outcome.thermal_truth)
    assert worst_error({"gyroscope": gyro}, truths) < 4.0


# Whether the thermal model is fitted: a stated setting, said in one line ----------------------

def test_the_thermal_setting_decides_and_the_solve_says_so(warm_run):
    from dataclasses import replace

    from fieldcal.run.replay import resolve_session
    from fieldcal.run.runner import open_run

    record = open_run(warm_run[0], log_only=True)
    assert record.spec.thermal == "auto"  # what the run was given (and every older session did)
    temperatures = [w.temperature_c for step in record.completed for w in step.windows]
    span = f"span {max(temperatures) - min(temperatures):.2f} K"
    auto = warm_run[1].unit
    assert all(cal.thermal is not None for cal in auto.solutions.values())
    assert auto.thermal_note.startswith("thermal model fitted (thermal: auto; window temperatures ")
    assert span in auto.thermal_note
    for name, cal in auto.solutions.items():
        assert f"{name} order {cal.thermal.order} + scale drift" in auto.thermal_note
    off, pf = resolve_session(record, thermal="off")
    assert all(cal.thermal is None for cal in off.solutions.values())
    assert off.thermal_note == f"thermal model not fitted (thermal: off; window temperatures " \
        f"{min(temperatures):.2f} to {max(temperatures):.2f} °C, {span})"
    assert all(t.thermal is None for t in pf.triads)
    # the setting is stored with the run, so its resume and replay solve as it did
    from fieldcal.run.runner import RunSpec
    stored = RunSpec.from_metadata(replace(record.spec, thermal="off").to_metadata())
    assert stored.thermal == "off"
    assert "thermal" not in record.spec.to_metadata()  # auto: the session reads as before


def test_auto_needs_the_span_and_on_does_not():
    from types import SimpleNamespace

    from fieldcal.solvers.solve import THERMAL_MIN_SPAN_K, _temperatures, thermal_statement

    windows = [SimpleNamespace(temperature_c=t) for t in (25.0, 25.1, 25.3)]
    assert _temperatures(windows, "auto") is None and _temperatures(windows, "off") is None
    np.testing.assert_array_equal(_temperatures(windows, "on"), [25.0, 25.1, 25.3])
    assert thermal_statement(windows, {}, "auto") == (
        "thermal model not fitted (thermal: auto; window temperatures 25.00 to 25.30 °C, span 0.30 K, "
        f"below the {THERMAL_MIN_SPAN_K} K auto needs)")
    cold = [SimpleNamespace(temperature_c=None)] * 3  # a device that reports none
    assert thermal_statement(cold, {}, "auto") is None  # nothing was decided: nothing to say
    assert thermal_statement(cold, {}, "on") == \
        "thermal model not fitted (thermal: on), the windows do not all carry a temperature"


def test_solve_takes_thermal_off_and_says_so(warm_run, capsys):
    from fieldcal.cli.main import main

    assert main(["solve", str(warm_run[0]), "--method", "lsq", "--thermal", "off"]) == 0
    out = capsys.readouterr().out
    assert "thermal model not fitted (thermal: off; window temperatures" in out
    assert "thermal model about" not in out


@pytest.mark.parametrize("written, means", [("off", "off"), ("on", "on"), ("auto", "auto"), (None, "auto")])
def test_the_config_says_auto_on_or_off(tmp_path, written, means):
    from fieldcal.config import load_config

    path = tmp_path / "station.yaml"
    text = open("configs/sim-warmup.yaml").read().replace("\nthermal: auto\n", "\n")
    assert "\nthermal:" not in text  # the shipped setting taken out: absent means absent
    path.write_text(text + (f"thermal: {written}\n" if written else ""))
    assert load_config(path).thermal == means


def test_the_config_offers_the_settings_the_solver_takes():
    from fieldcal.config import THERMAL_SETTINGS
    from fieldcal.solvers.methods import THERMAL_MODES

    assert THERMAL_SETTINGS == THERMAL_MODES


def test_a_misspelt_thermal_setting_is_one_line_with_the_nearest(tmp_path, capsys):
    from fieldcal.cli.main import main

    path = tmp_path / "station.yaml"
    path.write_text(open("configs/sim-warmup.yaml").read().replace("\nthermal: auto\n", "\n") + "thermal: of\n")
    assert main(["run", "--config", str(path), "--headless", "--out", str(tmp_path / "s")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "thermal: expected auto or on or off (did you mean 'off'?), got 'of'" in err
    assert str(path) in err and not (tmp_path / "s").exists()


def test_sim_warmup_field18_is_honest_per_triad():
    # configs/sim-warmup.yaml's unit warming 10 K through field-18, ten seeds through the conductor
    # with no session recorded (a quarter less CPU than recording ten): every parameter, thermal terms included, against the truth re-centred on
    # the fit's reference. The accelerometer's RMS z was 2.06 while its drift went unfitted.
    # The bench hands the engine 5 s of samples at a time, so the scripted operator answers it
    # within 5 s rather than 1 s (4 % more samples a run, the same windows, noise and warm-up):
    # the conductor's and engine's per-chunk work was most of a run's CPU (1.43 → 1.06 s). Ten
    # runs and the same statistic: the same power; the draws are new (the nearest of the 48
    # per-parameter sums to its bound is 1.86× inside it, with 1 s chunks 1.55×).
    from scipy.stats import chi2

    from fieldcal.report import _thermal_errors

    z: dict[str, dict[str, list]] = {}  # triad -> parameter -> z of each run that fitted it
    for seed in range(1, 11):
        outcome, truths = _sim_warmup_run(seed, chunk_s=5)  # (no session: these checks read none)
        for name, cal in outcome.unit.solutions.items():
            theta, terms = truths[name]
            values = np.r_[cal.errors_in_sigma(theta), _thermal_errors(cal.thermal, terms).ravel()]
            for j, value in enumerate(values):
                z.setdefault(name, {}).setdefault(f"{j}", []).append(value)
    assert set(z) == {"accelerometer", "gyroscope", "inclinometer"}
    # The runs are the independent draws, not the parameters: an exact fit (the inclinometer's
    # and accelerometer's order 2 with the drift, 18 unknowns on 18 norms) has one weakly
    # determined direction that all its z share, and its σ, the information at the estimate,
    # moves with where the estimate lands on it (0.1-7000× the bound at the truth over the
    # thermal benchmark's runs, while the errors stay near the bound). So 10 runs' pooled RMS z
    # scatters far more than χ² of 10×18 draws says (the inclinometer's 1.24 on these seeds, 1.15
    # with 1 s chunks, 1.00 over seeds 1-24): the pooled bound this test had was near its edge by chance. Per parameter,
    # Σz² over the runs that fitted it is χ² with that many degrees of freedom if σ is honest;
    # its 0.1 % and 99.9 % points, shared out over the parameters of all three triads, bound each.
    count = sum(len(by) for by in z.values())
    for name, by in z.items():
        for j, values in by.items():
            low, high = chi2.ppf([0.001 / count, 1 - 0.001 / count], len(values))
            assert low < np.sum(np.square(values)) < high, (name, j, np.sqrt(np.mean(np.square(values))).round(3))


def test_a_thermal_soak_recovers_the_truth_within_its_sigma():
    # procedures/thermal-soak.yaml (nine faces, three passes) in configs/sim-chamber.yaml's ramp
    # (18 to 32 °C): every parameter, thermal terms and scale drift included, within 4σ of the
    # truth, and the accelerometer's biases far better determined than a 10 K warm-up leaves them.
    from fieldcal.config import load_config
    from fieldcal.report import thermal_truths, worst_error
    from fieldcal.run.runner import RunSpec

    config = load_config("configs/sim-chamber.yaml")
    spec = RunSpec(load_procedure("procedures/thermal-soak.yaml"), config.station, seed=4,
                   rate_hz=config.device.rate_hz, sim_thermal=config.device.sim.thermal)
    outcome = _unrecorded_run(spec)  # (no session: these checks read none)
    assert set(outcome.unit.solutions) == {"accelerometer", "gyroscope", "inclinometer"}
    truths = thermal_truths(outcome.unit.solutions, outcome.truth, outcome.thermal_truth)
    assert worst_error(outcome.unit.solutions, truths) < 4.0
    for name, truth in config.device.sim.thermal.triads.items():
        model = outcome.unit.solutions[name].thermal
        assert model.order >= 1 and model.range_c[1] - model.range_c[0] > 13.0
        assert np.all(np.abs(model.scale_drift - truth.scale_drift) < 4.0 * model.scale_drift_sigma)
    acc = outcome.unit.solutions["accelerometer"]
    assert np.all(acc.sigma[:3] < 0.1 * MG)  # field-18 warming 10 K: 0.1-0.4 mg


def _sim_warmup_run(seed: int, windows: list | None = None, chunk_s: int = 1):
    """A headless field-18 run on configs/sim-warmup.yaml with no session recorded
    (``_unrecorded_run``): (outcome, the thermal truths re-centred). ``windows``: a list to
    receive the engine's windows, in the order the solve read them."""
    from fieldcal.config import load_config
    from fieldcal.report import thermal_truths
    from fieldcal.run.runner import RunSpec

    config = load_config("configs/sim-warmup.yaml")
    spec = RunSpec(load_procedure("field-18"), config.station, seed=seed, rate_hz=config.device.rate_hz,
                   sim_thermal=config.device.sim.thermal)
    outcome = _unrecorded_run(spec, windows, chunk_s)
    return outcome, thermal_truths(outcome.unit.solutions, outcome.truth, outcome.thermal_truth)


def _unrecorded_run(spec, windows: list | None = None, chunk_s: int = 1):
    """``run_headless(spec, ...)``'s outcome, to the bit, through the same conductor, bench and
    scripted operator with no session recorded: for checks that read none (writing one is a third
    of a warm-up run's CPU). ``windows``: a list to receive the engine's windows (what the solve
    read, as a recorded session's completed steps hold them). ``chunk_s``: seconds of samples the
    bench hands over at a time (1 as run_headless; more: another run, its operator slower to act)."""
    from fieldcal.run.conductor import Conductor
    from fieldcal.run.operators import ScriptedOperator
    from fieldcal.run.runner import SimulatedBench

    bench = SimulatedBench(spec)
    bench.chunk_n *= chunk_s
    conductor = Conductor(spec, bench, ScriptedOperator(spec.script, spec.procedure))
    outcome = conductor.run()
    if windows is not None:
        windows.extend(conductor.engine.windows_and_averages()[0])
    return outcome


def _least_squares_failing_at(monkeypatch, sizes: set[int]) -> None:
    """scipy's least_squares as the thermal fit calls it, but out of evaluations (as MINPACK says
    it) for every fit of that many unknowns: 12 + 3k for order k with the scale drift."""
    from scipy import optimize

    monkeypatch.undo()  # (one pattern of failures at a time: the real least_squares below)
    real = optimize.least_squares

    def least_squares(fun, x0, **kwargs):
        res = real(fun, x0, **kwargs)
        if len(x0) in sizes:
            res.success, res.message = False, "The maximum number of function evaluations is exceeded."
        return res

    monkeypatch.setattr(optimize, "least_squares", least_squares)


def test_an_order_whose_fit_does_not_converge_is_no_candidate(monkeypatch):
    # configs/sim-warmup.yaml seeds 34 and 51: a warm gyro's order-0 fit (its bias moving ~250
    # Earth rates over the run) ran out of evaluations in the second weighting pass, and that
    # failed the whole triad (2 of the thermal benchmark's first 56 runs). Such a fit rests on how
    # the least squares crawl along a misfit of χ² ~ 10⁷: seed 34's stopped after 1200
    # evaluations, and since the Jacobian is taken in one evaluation of a stack it converges in
    # 785. So the failure is made here, order by order, on a drifting accelerometer (truth: order 2).
    from fieldcal.thermal import truth_about

    def fit():
        return solve_thermal_norm(StaticNormProblem(_drifting_averages(200), G), TEMPERATURES, np.full((18, 3), SIGMA))

    plain = fit()
    assert plain.calibration.thermal.order == 2 and set(plain.chi2_by_order) == {0, 1, 2}
    # order 0 unconverged: no candidate, and the orders that converge are judged as before
    _least_squares_failing_at(monkeypatch, {12})
    without_0 = fit()
    model = without_0.calibration.thermal
    assert model.order == 2 and set(without_0.chi2_by_order) == {1, 2}
    np.testing.assert_array_equal(without_0.calibration.theta, plain.calibration.theta)
    theta, terms = truth_about(THETA, TRUTH_REF_C, np.vstack([B1, B2]), S1, model.reference_c)
    z = np.r_[without_0.calibration.errors_in_sigma(theta), ((model.bias_terms - terms) / model.bias_terms_sigma).ravel(),
              (model.scale_drift - S1) / model.scale_drift_sigma]
    assert np.all(np.abs(z) < 4.0), z.round(2)
    # order 2 unconverged after order 1 was chosen: the search ends with order 1
    _least_squares_failing_at(monkeypatch, {18})
    without_2 = fit()
    assert without_2.calibration.thermal.order == 1 and set(without_2.chi2_by_order) == {0, 1}
    # none converges: the triad fails in one line saying why
    _least_squares_failing_at(monkeypatch, {12, 15, 18})
    with pytest.raises(CalibrationError) as failed:
        fit()
    assert str(failed.value) == ("accelerometer: the thermal fit did not converge "
                                 "(The maximum number of function evaluations is exceeded.)")


@pytest.fixture(scope="module")
def seed380():
    """configs/sim-warmup.yaml seed 380 through the conductor: (outcome, truths, the engine's windows)."""
    windows: list = []
    return (*_sim_warmup_run(380, windows), windows)


def test_an_undetermined_exact_fit_gives_way_to_the_lower_order(seed380):
    # configs/sim-warmup.yaml seed 380: the inclinometer's order 2 with the scale drift is an exact
    # fit of its 18 norms, and at that run's placements and temperatures its Jacobian is singular
    # (condition number 5e10), which lost the whole triad (1 of the thermal benchmark's 400 runs).
    # An order the windows cannot determine is now no candidate: the order below it is kept.
    from fieldcal.report import worst_error

    outcome, truths, _ = seed380
    assert outcome.unit.failures == {}
    inclinometer = outcome.unit.solutions["inclinometer"]
    assert inclinometer.thermal.order < 2 and inclinometer.diagnostics.condition_number < 1e10
    assert worst_error({"inclinometer": inclinometer}, truths) < 4.0


def _inclinometer_inputs(seed380, name="inclinometer"):
    """Seed 380's inclinometer (or ``name``) problem, its static windows' temperatures, covariance
    and solution."""
    from fieldcal.procedure.windows import STATIC
    from fieldcal.solvers.assemble import window_indices

    outcome, _, windows = seed380
    temperatures = np.array([windows[i].temperature_c for i in window_indices(windows, STATIC)])
    return (outcome.unit.problems[name], temperatures, outcome.unit.covariances[name], outcome.unit.solutions[name])


def test_the_windows_read_back_give_the_runs_own_inclinometer_solution(seed380):
    # the last-bits tests below perturb these inputs (the engine's windows, as a recorded session
    # holds them): they must be exactly the ones the run solved
    problem, temperatures, covariance, solved = _inclinometer_inputs(seed380)
    np.testing.assert_array_equal(solve_thermal_norm(problem, temperatures, covariance).calibration.theta,
                                  solved.theta)


def test_the_order_chosen_does_not_hinge_on_the_last_bits(seed380):
    # The same run's temperatures times 1 ± 1e-13 made the inclinometer take order 2 in 5 of 5
    # cases: its condition number fell to 1.5e7-2.4e8, under the 1e10 limit, with bias σ 10⁵
    # times order 1's (issue 26). That order 2 is an exact fit (18 unknowns on 18 norms) that
    # leaves χ² 1.0: it stops on a fold of the model, where JᵀJ is singular and its computed
    # condition number is rounding. A fold is now known by the χ² it leaves (smooth in the data),
    # its σ come from the observed information, and it is kept on Akaike's criterion alone.
    problem, temperatures, covariance, solved = _inclinometer_inputs(seed380)  # (checked above)
    for factor in (1 + 1e-13, 1 - 1e-13, 1 + 3e-13, 1 - 3e-13, 1 + 1e-12):
        perturbed = solve_thermal_norm(problem, temperatures * factor, covariance).calibration
        assert perturbed.thermal.order == solved.thermal.order, factor
        np.testing.assert_allclose(perturbed.sigma, solved.sigma, rtol=1e-4)  # (ill-posed: ×10⁵)


def test_an_accelerometers_fold_is_kept_with_sigma_the_last_bits_do_not_move(seed380):
    # Seed 380's accelerometer: its order 2 (the truth's: b₂ 0.01 and -0.02 mg/K²) is an exact fit
    # that stops on a fold too (χ² 0.16 left), but order 1 leaves 8 more (Akaike keeps the fold).
    # Its σ were JᵀJ's at the fold, 50-890 m/s² on the biases as the temperatures' last bits moved
    # (issue 26); from the observed information they are 2-25 mm/s², the truth lies within 4σ of
    # the estimates, and the last bits move them by under 1e-4 (second differences' rounding).
    from fieldcal.report import _thermal_errors

    problem, temperatures, covariance, solved = _inclinometer_inputs(seed380, "accelerometer")
    theta, terms = seed380[1]["accelerometer"]
    assert solved.thermal.order == 2 and solved.diagnostics.chi2 > 0.1
    z = np.r_[solved.errors_in_sigma(theta), _thermal_errors(solved.thermal, terms).ravel()]
    assert np.all(np.abs(z) < 4.0), z.round(2)
    for factor in (1 + 1e-13, 1 - 1e-13, 1 + 3e-13, 1 - 3e-13, 1 + 1e-12):
        perturbed = solve_thermal_norm(problem, temperatures * factor, covariance).calibration
        assert perturbed.thermal.order == 2, factor
        np.testing.assert_allclose(perturbed.sigma, solved.sigma, rtol=1e-3)


def test_the_observed_information_of_a_hand_worked_fold():
    # r(x) = (x₀² + c, x₁ − 2): the data (−c, 2) lie outside what x₀² can reach, so least squares
    # stops at x = (0, 2), where J = [[0, 0], [0, 1]] is singular. The Hessian of ½|r|² there is
    # JᵀJ + Σ rᵢ∇²rᵢ = [[2c, 0], [0, 1]]: x₀ is determined by the curvature alone.
    from fieldcal.solvers.thermal import _observed_information

    c = 0.3
    x = np.array([0.0, 2.0])
    J = np.array([[0.0, 0.0], [0.0, 1.0]])
    information = _observed_information(lambda z: np.stack([z[..., 0] ** 2 + c, z[..., 1] - 2.0], axis=-1), x, J,
                                        np.array([1e-4, 1e-4]))  # (r of a stack of points: one call)
    np.testing.assert_allclose(information, [[2 * c, 0.0], [0.0, 1.0]], rtol=0, atol=1e-8)


def test_the_averages_brought_back_to_the_reference_temperature_by_hand():
    """(u − b₀ − b₁ΔT − b₂ΔT²)/(1 + s₁ΔT) + b₀: a unit 2 K warm, its scale 1 % and 2 % up per kelvin on x and y."""
    from fieldcal.solvers.thermal import _corrected

    u = np.array([[1.1, 2.2, 3.3], [0.5, 0.5, 0.5]])
    theta = np.r_[0.1, 0.2, 0.3, np.ones(3), np.zeros(3)]
    terms = np.array([[0.01, 0.0, 0.0], [0.0, 0.001, 0.0]])  # b₁ on x, b₂ on y
    drift = np.array([0.01, 0.02, 0.0])
    got = _corrected(u, np.array([2.0, 0.0]), theta, terms, drift).reshape(2, 3)
    np.testing.assert_allclose(got[0], [(1.1 - 0.1 - 0.02) / 1.02 + 0.1, (2.2 - 0.2 - 0.004) / 1.04 + 0.2, 3.3],
                               rtol=1e-14)
    np.testing.assert_allclose(got[1], u[1], rtol=1e-14)  # at the reference: unchanged


def _candidate(J=None, information=None, fold=False):
    """The fields ``_undetermined`` reads of a candidate fit: J (4), the information (6), fold (7)."""
    return (None, None, None, None, J, None, information, fold)


def test_an_undetermined_candidate_says_its_condition_number_and_whether_at_a_fold():
    from fieldcal.solvers.thermal import _undetermined

    # A solution: J's singular values 2 and 2e-12, condition number 1e12 (beyond 1/UNDETERMINED).
    assert _undetermined(_candidate(J=np.diag([2.0, 2e-12]))) == "condition number 1e+12"
    assert _undetermined(_candidate(J=np.diag([2.0, 2e-9]))) is None
    # A fold: the observed information's eigenvalues 4 and 4e-24 are J's squared, so the same
    # condition number √(4/4e-24) = 1e12; a negative eigenvalue (a saddle) has none finite.
    assert _undetermined(_candidate(information=np.diag([4.0, 4e-24]), fold=True)) == "condition number 1e+12, at a fold"
    assert _undetermined(_candidate(information=np.diag([4.0, -1.0]), fold=True)) == "condition number inf, at a fold"
    assert _undetermined(_candidate(information=np.diag([4.0, 4e-18]), fold=True)) is None


def test_the_thermal_fit_without_a_covariance_is_refused_by_name():
    u = G * UP / np.linalg.norm(UP, axis=1, keepdims=True)
    with pytest.raises(ValueError, match="^accelerometer: the thermal fit needs the covariance of the averages$"):
        solve_thermal_norm(StaticNormProblem(u, G, name="accelerometer"), TEMPERATURES, None)


def test_a_covariance_given_by_its_parts_is_the_dense_one():
    # Any covariance with .dense() (the windows' Markov parts, a block-semiseparable one) is taken
    # as its dense matrix: the residuals' covariance the same as from that matrix given itself.
    from fieldcal.solvers.thermal import _residual_covariance_at

    class ByParts:
        def __init__(self, dense):
            self._dense = dense

        def dense(self):
            return self._dense

    rng = np.random.default_rng(2)
    root = rng.normal(size=(54, 54)) * SIGMA
    cov = root @ root.T
    u = G * UP / np.linalg.norm(UP, axis=1, keepdims=True)
    problem = StaticNormProblem(u, G)
    expected = _residual_covariance_at(problem, THETA, u.ravel(), cov)
    np.testing.assert_array_equal(_residual_covariance_at(problem, THETA, u.ravel(), ByParts(cov)), expected)
    assert expected.shape == (18, 18) and np.all(np.linalg.eigvalsh(expected) > 0)


def test_at_one_temperature_no_thermal_term_is_determined():
    # Every average at 30 °C: a bias term or a scale drift times Δt = 0 moves nothing, so order 1
    # is undetermined and the order-0 fit stands, the plain solve's calibration; with the drift in
    # every candidate, none is determined and the fit refuses, naming the last one's infinite
    # condition (order 2 and the drift: 18 unknowns for 18 norms, an exact fit, so a fold).
    u = _averages(1)
    same = np.full(18, 30.0)
    fit = solve_thermal_norm(StaticNormProblem(u, G), same, np.full((18, 3), SIGMA), scale=False)
    plain = solve_norm(StaticNormProblem(u, G), np.full((18, 3), SIGMA), method="lsq")
    assert fit.calibration.thermal.order == 0 and fit.calibration.thermal.scale_drift is None
    assert list(fit.chi2_by_order) == [0]
    assert np.all(np.abs(fit.calibration.theta - plain.theta) < 0.1 * plain.sigma)
    assert fit.calibration.diagnostics.evaluations == fit.calibration.diagnostics.iterations > 0
    from fieldcal.solvers import CalibrationError

    with pytest.raises(CalibrationError, match=r"^accelerometer: the thermal terms are not determined by these "
                       r"positions and temperatures \(condition number inf, at a fold\)$"):
        solve_thermal_norm(StaticNormProblem(u, G, name="accelerometer"), same, np.full((18, 3), SIGMA))
