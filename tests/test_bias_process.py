"""The simulator's bias instability as a stated model: the flicker bank's longest correlation time
is a config value, and the truth exposes the bias process, so that "the bias at the end of
calibration" (DESIGN 12) can be measured."""
import math

import numpy as np
import pytest

from drivers.noise import DEFAULT_FLICKER_TAU_MAX_S, TriadNoise, flicker_bank
from drivers.sim.noise import InnovationNoise, NoiseGenerator

RATE = 250.0
# IEEE Std 952: a flicker floor's Allan deviation is sqrt(2 ln 2 / π)·B = 0.664·B.
FLICKER_FLOOR = math.sqrt(2 * math.log(2) / math.pi)


def test_the_default_bank_is_the_one_every_earlier_result_used():
    """Nine processes, two per decade from 0.5 s to 5000 s, s² = (ln 10 / 2)·B²/π: bit for bit,
    so that sessions and figures from before the cut-off was configurable stand."""
    taus, sigmas = flicker_bank(2e-4)
    assert DEFAULT_FLICKER_TAU_MAX_S == 5000.0
    assert np.array_equal(taus, np.geomspace(0.5, 5000.0, 9))
    assert np.array_equal(sigmas, np.full(9, np.sqrt(np.log(10.0) / 2 / np.pi) * 2e-4))


@pytest.mark.parametrize("tau_max", [5e3, 1e5, 1e6])
def test_the_allan_floor_reaches_the_cut_off_and_falls_after_it(tau_max):
    """Flat at 0.664·B (IEEE Std 952) up to a few tenths of the longest correlation time, well
    below it a decade past it: the cut-off is where the bias stops wandering."""
    noise = TriadNoise(white=1e-9, bias_instability=1.0, flicker_tau_max_s=tau_max)
    taus = flicker_bank(1.0, tau_max)[0]
    assert taus[-1] == pytest.approx(tau_max) and taus[0] == 0.5
    flat = noise.allan_deviation(np.geomspace(10.0, tau_max / 3, 8))
    np.testing.assert_allclose(flat, FLICKER_FLOOR, rtol=0.05)
    assert noise.allan_deviation(np.array([30 * tau_max]))[0] < 0.6 * FLICKER_FLOOR


@pytest.mark.parametrize("tau_max", [1.0, 0.0, 1e9, float("nan")])
def test_a_cut_off_out_of_range_is_refused(tau_max):
    with pytest.raises(ValueError, match="flicker_tau_max_s: expected 5 to 1e\\+08 s"):
        flicker_bank(1.0, tau_max)


def test_the_innovations_form_refuses_triads_of_different_cut_offs():
    noises = [TriadNoise(1e-3, 1e-4), TriadNoise(1e-3, 1e-4, flicker_tau_max_s=1e5)]
    with pytest.raises(ValueError, match="same flicker_tau_max_s"):
        InnovationNoise(noises, RATE, np.random.default_rng(0))


def _generator(model, noise, seed):
    rng = np.random.default_rng(seed)
    if model == "bank":
        gen = NoiseGenerator(noise, RATE, rng)
        return lambda n: gen.draw(n), gen.bias_now
    gen = InnovationNoise([noise], RATE, rng)
    return lambda n: gen.draw(n)[0], lambda: gen.bias_now()[0]


@pytest.mark.parametrize("model", ["bank", "innovations"])
@pytest.mark.parametrize("tau_max", [5e3, 1e6])
def test_with_almost_no_white_noise_the_bias_is_the_last_sample(model, tau_max):
    """White noise of 1e-3 of the bank's spread: the sample is the bias process to within it, so
    bias_now must be the last sample drawn, across chunk sizes and the innovations' blocks."""
    noise = TriadNoise(white=1e-7, bias_instability=4e-4, flicker_tau_max_s=tau_max)
    draw, bias_now = _generator(model, noise, 3)
    white = noise.white * math.sqrt(RATE)
    spread = np.sqrt(np.sum(flicker_bank(4e-4, tau_max)[1] ** 2))
    for n in (1, 100, 2399, 2500, 1, 2501, 7000):
        last = draw(n)[-1]
        # bank: the last sample's white noise; innovations: that and the filtered law's spread
        np.testing.assert_allclose(bias_now(), last, rtol=0, atol=6 * math.sqrt(2) * white)
        assert 6 * math.sqrt(2) * white < 0.02 * spread  # so the check means something


@pytest.mark.parametrize("model", ["bank", "innovations"])
def test_asking_for_the_bias_does_not_change_the_samples(model):
    noise = TriadNoise(white=2e-3, bias_instability=4e-4)
    draw, bias_now = _generator(model, noise, 9)
    quiet_draw, _ = _generator(model, noise, 9)
    for n in (7, 3000, 250):
        bias_now()
        assert np.array_equal(draw(n), quiet_draw(n))


@pytest.mark.parametrize("model", ["bank", "innovations"])
def test_the_bias_and_the_samples_have_their_joint_law(model):
    """Over 200 seeds (600 axes): Var of the bias at the last sample is the bank's Σ s², and its
    covariance with the mean of the last 10 s of samples is Σ s²·(1 − pᴸ)/((1 − p)·L), from the
    bank's own recursion; the paper-like case where the white noise is as large as the flicker
    over the window. Bounds: 4.5 standard errors of each statistic."""
    noise = TriadNoise(white=2e-3, bias_instability=4e-4)
    taus, sigmas = flicker_bank(noise.bias_instability)
    poles, window = np.exp(-1 / RATE / taus), 2500
    variance = np.sum(sigmas**2)
    covariance = np.sum(sigmas**2 * (1 - poles**window) / (1 - poles) / window)
    biases, means = [], []
    for seed in range(200):
        draw, bias_now = _generator(model, noise, seed)
        means.append(draw(window)[-window:].mean(axis=0))
        biases.append(bias_now())
    b, m = np.ravel(biases), np.ravel(means)
    mean_variance = covariance + noise.white**2 / (window / RATE)  # Var of the window mean
    assert abs(np.mean(b * b) - variance) < 4.5 * variance * math.sqrt(2 / b.size)
    se = math.sqrt((variance * mean_variance + covariance**2) / b.size)
    assert abs(np.mean(b * m) - covariance) < 4.5 * se


def test_the_simulators_bias_now_is_k_times_the_process_plus_the_constant_bias():
    """At rest with almost no white noise, a triad's output is K·(true input + bias process) + b,
    so bias_now must be the last output less K times the true input (known: earth rate, gravity)."""
    from dataclasses import replace

    from drivers.sim import MimuSimulator
    from drivers.sim.device import paper_mimu

    device = {name: replace(t, noise=replace(t.noise, white=1e-9 * t.noise.bias_instability))
              for name, t in paper_mimu(flicker_tau_max_s=1e5).items()}
    sim = MimuSimulator(device, gravity=9.8, latitude_rad=math.radians(40.0), seed=4, noise_model="bank")
    chunk = sim.advance(1000, np.eye(3), 0.0, 1.0)
    force, omega = sim.true_inputs(np.eye(3), np.array([sim.table_angle]), np.zeros(1), np.zeros(1))
    for name, bias in sim.bias_now().items():
        t = device[name]
        true = force[-1] if t.kind == "specific_force" else omega[-1]
        expected = chunk.triads[name][-1] - t.K @ true
        np.testing.assert_allclose(bias, expected, rtol=0, atol=1e-3 * t.noise.bias_instability)
        # and it is not just the constant bias: the process is there, at its size
        assert np.max(np.abs(bias - t.bias)) > 0.05 * t.noise.bias_instability


def test_the_config_states_the_simulated_units_cut_off(tmp_path):
    from fieldcal.config import CONFIGS_DIR, ConfigError, load_config

    assert load_config("sim").device.sim.flicker_tau_max_s == DEFAULT_FLICKER_TAU_MAX_S
    text = (CONFIGS_DIR / "sim.yaml").read_text()
    path = tmp_path / "station.yaml"
    path.write_text(text.replace("    seed: 1\n", "    seed: 1\n    flicker_tau_max_s: 1.0e+5\n", 1))
    assert load_config(path).device.sim.flicker_tau_max_s == 1e5
    for bad, said in (("1.0e+9", "got 1000000000.0"), ("fast", "'fast'"), ("true", "got true")):
        path.write_text(text.replace("    seed: 1\n", f"    seed: 1\n    flicker_tau_max_s: {bad}\n", 1))
        with pytest.raises(ConfigError) as exc_info:
            load_config(path)
        message = str(exc_info.value)
        assert "\n" not in message and message.startswith(f"{path}: device.sim.flicker_tau_max_s: expected")
        assert said in message


def test_a_real_units_noise_may_state_its_cut_off(tmp_path):
    from fieldcal.config import CONFIGS_DIR, ConfigError, load_config

    text = (CONFIGS_DIR / "vn100.yaml").read_text()
    old = "bias_instability: 4.8e-5}"
    assert old in text
    path = tmp_path / "station.yaml"
    path.write_text(text.replace(old, "bias_instability: 4.8e-5, flicker_tau_max_s: 2.0e+4}", 1))
    noise = {t.name: t.noise for t in load_config(path).device.triads}
    assert noise["gyroscope"].flicker_tau_max_s == 2e4
    assert noise["accelerometer"].flicker_tau_max_s == DEFAULT_FLICKER_TAU_MAX_S
    path.write_text(text.replace(old, "bias_instability: 4.8e-5, flicker_tau_max_s: 1}", 1))
    with pytest.raises(ConfigError, match=r"device\.triads\.gyroscope\.noise\.flicker_tau_max_s: expected a number from 5"):
        load_config(path)


def test_a_headless_run_keeps_its_cut_off_and_reports_the_bias_at_its_end(tmp_path):
    """A short field-18 on a unit whose flicker wanders to 1e5 s: the session states the cut-off,
    so a replay solves with the same noise model (the σ depend on it) byte for byte; the outcome
    carries each triad's bias at the last sample, and a default run's session is as before."""
    from fieldcal.earth import Station
    from fieldcal.paramfile import dump
    from fieldcal.procedure.positions import load_procedure, parse_procedure
    from fieldcal.run.replay import recorded_parameters, replay
    from fieldcal.run.runner import RunSpec, open_run, run_headless

    text = (load_procedure("field-18").text.replace("dwell_s: 200", "dwell_s: 20")
            .replace("rate_deg_s: 10", "rate_deg_s: 30"))
    spec = RunSpec(parse_procedure(text, "field-18-short.yaml"), Station(40.0, 50.0), seed=3,
                   flicker_tau_max_s=1e5)
    result = run_headless(spec, tmp_path / "s")
    record = open_run(result.session)
    assert dump(replay(record).parameter_file).encode() == recorded_parameters(open_run(result.session))
    assert RunSpec.from_metadata(spec.to_metadata()).flicker_tau_max_s == 1e5
    default = RunSpec(spec.procedure, spec.station, seed=3)
    assert "flicker_tau_max_s" not in default.to_metadata()["device"]
    assert RunSpec.from_metadata(default.to_metadata()).flicker_tau_max_s == DEFAULT_FLICKER_TAU_MAX_S
    noises = {name: t.noise for name, t in spec.device().items()}
    assert set(result.bias_at_end) == set(result.truth) == set(noises)
    for name, bias in result.bias_at_end.items():
        assert noises[name].flicker_tau_max_s == 1e5
        wander = np.abs(bias - result.truth[name][:3])
        # the bias process is there, at the size of the flicker (σ about 1.3 B per axis)
        assert 1e-3 * noises[name].bias_instability < np.max(wander) < 8 * noises[name].bias_instability
