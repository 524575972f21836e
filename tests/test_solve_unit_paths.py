"""solve_unit's classic path (an aligned procedure, a device in raw counts) against the simulated
device's true parameters, and the thermal decision's words and edges by hand."""
from types import SimpleNamespace

import numpy as np
import pytest

from drivers.sim.device import paper_mimu
from fieldcal.procedure.positions import load_procedure
from fieldcal.procedure.windows import STATIC, Window
from fieldcal.run.simcal import DEFAULT_STATION
from fieldcal.run.simrun import plan_procedure, simulate_averages
from fieldcal.solvers.solve import _temperatures, models_from_truth, solve_unit, thermal_statement

RATE_HZ = 250.0


@pytest.fixture(scope="module")
def classic_counts():
    procedure = load_procedure("classic-12")
    device = {name: triad for name, triad in paper_mimu(raw_counts=True).items() if name != "inclinometer"}
    plan = plan_procedure(procedure, RATE_HZ, np.random.default_rng(5))
    means, _ = simulate_averages(plan, device, DEFAULT_STATION, RATE_HZ, seed=5)
    return procedure, device, plan, means


def test_an_aligned_run_solved_by_the_classic_method_finds_the_devices_k(classic_counts):
    procedure, device, plan, means = classic_counts
    result = solve_unit(procedure, plan.windows, means, models_from_truth(device), DEFAULT_STATION, RATE_HZ,
                        method="classic")
    assert result.failures == {} and set(result.solutions) == {"accelerometer", "gyroscope"}
    for name, truth in device.items():
        sol = result.solutions[name]
        assert (sol.kind, sol.output_unit, sol.method) == (truth.kind, "count", "classic")
        # the full K (the table-aligned rotation included) against the simulator's, within 5σ
        sigma_k = sol.sigma[3:6]
        assert np.all(np.abs(np.diag(sol.K) - np.diag(truth.K)) < 5 * sigma_k), (name, np.diag(sol.K), sigma_k)
        used = [i for i, w in enumerate(plan.windows) if (w.kind == STATIC) == (truth.kind == "specific_force")]
        assert result.inputs[name].shape == (3 * len(used),)
        np.testing.assert_array_equal(result.inputs[name], means[name][used].ravel())
        # one count's quantisation adds 1/12 count² over each window's samples to every axis
        C = truth.noise.window_covariance([plan.windows[i].start for i in used],
                                          [plan.windows[i].duration for i in used])
        quantisation = result.covariances[name] - np.kron(C, truth.K @ truth.K.T)
        samples = np.array([plan.windows[i].duration for i in used]) * RATE_HZ
        np.testing.assert_allclose(quantisation, np.kron(np.diag(1 / 12 / samples), np.eye(3)),
                                   rtol=1e-9, atol=1e-9 * np.abs(result.covariances[name]).max())


def test_the_classic_method_on_a_procedure_without_known_orientations_is_a_failure_named(classic_counts):
    _, device, _, _ = classic_counts
    field = load_procedure("field-18")
    plan = plan_procedure(field, RATE_HZ, np.random.default_rng(1), with_rate_steps=False)
    means = {name: np.zeros((len(plan.windows), 3)) for name in device}
    result = solve_unit(field, plan.windows, means, models_from_truth(device), DEFAULT_STATION, RATE_HZ,
                        method="classic")
    assert result.solutions == {}
    assert result.failures["accelerometer"] == ("accelerometer: the classic method needs an aligned procedure "
                                                "(known orientations); field-18 is not one")


def _windows(*temperatures):
    return [Window(STATIC, i, 10.0 * i, 5.0, temperature_c=t) for i, t in enumerate(temperatures)]


def test_temperatures_are_used_only_when_every_window_has_one_and_the_span_is_enough():
    assert _temperatures(_windows(20.0, None), "on") is None
    assert _temperatures(_windows(20.0, 20.25), "auto") is None
    np.testing.assert_array_equal(_temperatures(_windows(20.0, 20.5), "auto"), [20.0, 20.5])  # 0.5 K: enough
    np.testing.assert_array_equal(_temperatures(_windows(20.0, 20.25), "on"), [20.0, 20.25])
    assert _temperatures(_windows(20.0, 30.0), "off") is None


def _fitted(order, scale=None):
    return SimpleNamespace(thermal=SimpleNamespace(order=order, scale_drift=scale))


def test_the_thermal_statement_word_for_word():
    windows = _windows(20.0, 20.5)
    assert thermal_statement(windows, {}, "auto") == (
        "thermal model not fitted (thermal: auto; window temperatures 20.00 to 20.50 °C, span 0.50 K)")
    assert thermal_statement(_windows(20.0, 20.25), {}, "auto") == (
        "thermal model not fitted (thermal: auto; window temperatures 20.00 to 20.25 °C, span 0.25 K, "
        "below the 0.5 K auto needs)")
    solutions = {"accelerometer": _fitted(1, np.zeros(3)), "gyroscope": _fitted(2), "inclinometer": _fitted(None)}
    solutions["inclinometer"].thermal = None
    assert thermal_statement(windows, solutions, "on") == (
        "thermal model fitted (thermal: on; window temperatures 20.00 to 20.50 °C, span 0.50 K): "
        "accelerometer order 1 + scale drift, gyroscope order 2")
    assert thermal_statement(_windows(20.0, None), {}, "auto") is None
    assert thermal_statement(_windows(20.0, None), {}, "on") == (
        "thermal model not fitted (thermal: on), the windows do not all carry a temperature")


def test_a_field_run_is_solved_by_the_method_asked_for_with_its_bias_at_the_end():
    procedure = load_procedure("field-18")
    device = {"accelerometer": paper_mimu()["accelerometer"]}
    plan = plan_procedure(procedure, RATE_HZ, np.random.default_rng(3), with_rate_steps=False)
    means, _ = simulate_averages(plan, device, DEFAULT_STATION, RATE_HZ, seed=3)
    end_s = plan.windows[-1].start + plan.windows[-1].duration
    result = solve_unit(procedure, plan.windows, means, models_from_truth(device), DEFAULT_STATION, RATE_HZ,
                        method="lsq", end_s=end_s)
    sol = result.solutions["accelerometer"]
    assert sol.diagnostics.search == "lsq"  # not the procedure's default, Powell
    truth = device["accelerometer"]
    assert np.all(np.abs(sol.bias - truth.bias) < 5 * sol.sigma[:3])
    assert sol.bias_at_end is not None and sol.bias_at_end.time_s == end_s
    assert np.all(np.isfinite(sol.bias_at_end.sigma)) and np.all(sol.bias_at_end.sigma > 0)
    # without end_s: no bias at the end
    plain = solve_unit(procedure, plan.windows, means, models_from_truth(device), DEFAULT_STATION, RATE_HZ)
    assert plain.solutions["accelerometer"].bias_at_end is None
    assert plain.solutions["accelerometer"].diagnostics.search == "powell"


def test_a_misspelt_thermal_setting_is_refused_naming_the_three():
    procedure = load_procedure("field-18")
    with pytest.raises(ValueError, match=r"^thermal: expected one of auto, on, off, got 'warm'$"):
        solve_unit(procedure, [], {}, {}, DEFAULT_STATION, RATE_HZ, thermal="warm")


def test_without_static_dwells_the_across_axis_earth_rate_is_not_ruled_out():
    from fieldcal.solvers.solve import across_earth_rate_usable

    model = models_from_truth(paper_mimu())["gyroscope"]
    assert across_earth_rate_usable(model, [], DEFAULT_STATION) is True
