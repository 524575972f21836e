"""The simulator's temperature (issue 28): profiles, thermal truth per triad applied to the raw
output, the config that declares them (strictly read), the frames that serve the temperature,
and the run spec that carries them into a session."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from drivers.protocols import make_encoder, make_parser
from drivers.sim.device import MG, paper_mimu
from drivers.sim.physics import MimuSimulator, Segment
from drivers.sim.serve import _as_device_sends
from drivers.sim.thermal import SimThermal, TemperatureProfile, ThermalTruth
from fieldcal.config import ConfigError, load_config

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
WARMUP = TemperatureProfile("warmup", start_c=20.0, rise_k=13.0, time_constant_s=3600.0)
ACC = ThermalTruth(25.0, np.array([[3e-3, -5e-3, 8e-3], [1e-4, 0.0, -2e-4]]), np.array([5e-5, -3e-5, 4e-5]))
GYRO = ThermalTruth(25.0, np.array([[3.5e-4, -8.7e-4, 1.4e-3]]), np.array([2e-5, 3e-5, -2e-5]))


def test_profiles_hand_worked():
    assert WARMUP.at([0.0])[0] == 20.0
    assert WARMUP.at([3600.0])[0] == pytest.approx(20.0 + 13.0 * (1 - math.exp(-1)), abs=1e-12)
    ramp = TemperatureProfile("ramp", start_c=-10.0, rise_k=30.0, rate_k_per_s=0.01, soak_s=600.0)
    np.testing.assert_allclose(ramp.at([0.0, 600.0, 1600.0, 3600.0, 9000.0]), [-10.0, -10.0, 0.0, 20.0, 20.0])
    cooling = TemperatureProfile("ramp", start_c=40.0, rise_k=-20.0, rate_k_per_s=0.1)
    np.testing.assert_allclose(cooling.at([0.0, 100.0, 1000.0]), [40.0, 30.0, 20.0])
    np.testing.assert_array_equal(TemperatureProfile("constant", 25.0).at(np.arange(3.0)), [25.0] * 3)


def _chunks(thermal, noise_model):
    sim = MimuSimulator(paper_mimu(), 9.80, 0.7, rate_hz=50.0, seed=4, noise_model=noise_model, thermal=thermal)
    attitude = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    chunks = list(sim.run([Segment(100.0, np.eye(3)), Segment(60.0, attitude, table_rate=0.2, ramp_s=2.0)],
                          chunk_len=1000))
    sim.advance(500, np.eye(3), 0.0, 1.0)  # the at-rest path of a live bench too
    return chunks + [sim.advance(500, attitude, 0.0, 1.0)]


@pytest.mark.parametrize("noise_model", ["innovations", "bank"])
def test_thermal_truth_moves_raw_as_the_model_says(noise_model):
    # Same seed, same noise: the warm unit's output is the cold one's with K's rows scaled by
    # 1 + s1·ΔT and the bias terms added, at the temperature of the profile.
    profile = TemperatureProfile("ramp", start_c=15.0, rise_k=20.0, rate_k_per_s=0.1, soak_s=20.0)
    thermal = SimThermal(profile, {"accelerometer": ACC, "gyroscope": GYRO})
    warm, cold = _chunks(thermal, noise_model), _chunks(None, noise_model)
    truth = paper_mimu()
    for w, c in zip(warm, cold, strict=True):
        assert c.temperature is None
        np.testing.assert_array_equal(w.temperature, profile.at(w.t))
        dt = w.temperature[:, None] - 25.0
        for name, model in (("accelerometer", ACC), ("gyroscope", GYRO)):
            b = truth[name].bias
            offset = sum(model.bias_terms[k] * dt ** (k + 1) for k in range(len(model.bias_terms)))
            expected = (c.triads[name] - b) * (1 + model.scale_drift * dt) + b + offset
            np.testing.assert_allclose(w.triads[name], expected, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(w.triads["inclinometer"], c.triads["inclinometer"])


def test_a_unit_at_its_reference_temperature_is_the_unit_without_thermal_terms():
    thermal = SimThermal(TemperatureProfile("constant", 25.0), {"accelerometer": ACC, "gyroscope": GYRO})
    for w, c in zip(_chunks(thermal, "innovations"), _chunks(None, "innovations"), strict=True):
        for name in c.triads:
            np.testing.assert_array_equal(w.triads[name], c.triads[name])


def test_thermal_truth_for_a_triad_the_unit_lacks_is_refused():
    with pytest.raises(ValueError, match="no triad named magnetometer"):
        MimuSimulator(paper_mimu(), 9.8, 0.7, thermal=SimThermal(WARMUP, {"magnetometer": ACC}))


@pytest.mark.parametrize("protocol, resolution", [("xsens", 1e-5), ("vectornav", 0.05)])
def test_served_frames_carry_the_temperature(protocol, resolution):
    sim = MimuSimulator(paper_mimu(), 9.80, 0.7, rate_hz=100.0, seed=2,
                        thermal=SimThermal(WARMUP, {"accelerometer": ACC}))
    chunk = next(sim.run_segment(Segment(3000.0, np.eye(3)), chunk_len=300_000))
    sent = _as_device_sends(chunk)
    sample = slice(-200, None)  # the end of the warm-up, well above the constant 25 °C it used to send
    sent = type(sent)(t=sent.t[sample], triads={k: v[sample] for k, v in sent.triads.items()},
                      temperature=sent.temperature[sample], extras={k: v[sample] for k, v in sent.extras.items()})
    parsed = make_parser(protocol).feed(make_encoder(protocol).encode(sent), 0.0)
    assert parsed is not None and len(parsed) == 200
    np.testing.assert_allclose(parsed.temperature, WARMUP.at(chunk.t[sample]), atol=resolution)
    assert parsed.temperature.min() > 27.0


def test_sim_warmup_config_is_the_issues_unit():
    config = load_config(CONFIGS / "sim-warmup.yaml")
    thermal = config.device.sim.thermal
    profile = thermal.profile
    # field-18 on the simulator lasts 5093 s (headless, seed 1): the unit warms about 10 K
    assert 9.5 <= profile.at([5093.0])[0] - profile.at([0.0])[0] <= 10.5
    acc_mg_per_k = np.abs(thermal.triads["accelerometer"].bias_terms[0]) / MG
    gyro_deg_s_per_k = np.degrees(np.abs(thermal.triads["gyroscope"].bias_terms[0]))
    assert np.all((acc_mg_per_k >= 0.1) & (acc_mg_per_k <= 1.0))
    assert np.all((gyro_deg_s_per_k >= 0.01) & (gyro_deg_s_per_k <= 0.1))


def _config(tmp_path, sim_block: str) -> Path:
    text = (CONFIGS / "sim.yaml").read_text().replace("    speed: 1.0 ", sim_block + "\n    speed: 1.0 ")
    path = tmp_path / "station.yaml"
    path.write_text(text)
    return path


@pytest.mark.parametrize("block, message", [
    ("    temperature: {profile: warmup, start_c: 20, rise_k: 10, time_constant: 3600}",
     "device.sim.temperature.time_constant: unknown key 'time_constant'; did you mean 'time_constant_s'?"),
    ("    temperature: {profile: warmpu, start_c: 20}", "device.sim.temperature.profile: expected 'constant' or"),
    ("    temperature: {profile: warmup, start_c: 20, rise_k: 10}", "device.sim.temperature.time_constant_s: missing"),
    ("    temperature: {profile: ramp, start_c: 20, rise_k: 10, rate_k_per_s: 0.01, time_constant_s: 5}",
     "unknown key 'time_constant_s'"),
    ("    temperature: {profile: constant, start_c: 400}", "device.sim.temperature.start_c: expected a number from -60"),
    ("    thermal: {accelerometer: {reference_c: 25}}", "device.sim.temperature: missing"),
    ("    temperature: {profile: constant, start_c: 20}\n    thermal: {accelerometr: {reference_c: 25}}",
     "device.sim.thermal.accelerometr: unknown key 'accelerometr'; did you mean 'accelerometer'?"),
    ("    temperature: {profile: constant, start_c: 20}\n"
     "    thermal: {gyroscope: {reference_c: 25, bias_coefficients: [[1, 2, 3]], scale_drfit: 1.0e-5}}",
     "did you mean 'scale_drift'?"),
    ("    temperature: {profile: constant, start_c: 20}\n"
     "    thermal: {gyroscope: {reference_c: 25, bias_coefficients: [[1, 2]]}}",
     "device.sim.thermal.gyroscope.bias_coefficients[0]: expected a list of 3 numbers"),
    ("    temperature: {profile: constant, start_c: 20}\n"
     "    thermal: {gyroscope: {reference_c: 25, bias_coefficients: [[1, 2, 3], [1, 2, 3], [1, 2, 3], [1, 2, 3]]}}",
     "expected a list of up to 3 rows"),
])
def test_bad_thermal_configs_are_refused_in_one_line(tmp_path, block, message):
    with pytest.raises(ConfigError) as exc:
        load_config(_config(tmp_path, block))
    assert message in str(exc.value) and "\n" not in str(exc.value)


def test_configs_without_temperature_are_as_before(tmp_path):
    assert load_config(CONFIGS / "sim.yaml").device.sim.thermal is None


def test_the_run_spec_carries_the_thermal_truth_into_the_session_and_back():
    from fieldcal.procedure.positions import load_procedure
    from fieldcal.run.runner import RunSpec

    config = load_config(CONFIGS / "sim-warmup.yaml")
    spec = RunSpec(load_procedure("field-18"), config.station, sim_thermal=config.device.sim.thermal)
    meta = spec.to_metadata()
    back = RunSpec.from_metadata(meta)
    assert back.sim_thermal.to_dict() == config.device.sim.thermal.to_dict()
    plain = RunSpec(load_procedure("field-18"), config.station).to_metadata()
    assert "sim_thermal" not in plain and RunSpec.from_metadata(plain).sim_thermal is None
