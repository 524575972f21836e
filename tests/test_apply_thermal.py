"""fieldcal apply with a thermal model (issue 28): each sample corrected at its own temperature,
read from the map's temperature column, against the simulator's thermal truth; samples outside
the calibrated range refused (or held at its edge when asked), in one line with their count; no
temperature column: the model at its reference temperature, said; old parameter files apply
byte for byte as before, whatever the map says of temperature."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from drivers.sim.thermal import TemperatureProfile, ThermalTruth
from fieldcal.apply import apply_file, plan
from fieldcal.apply.thermal import TemperatureOutside
from fieldcal.calibration import Calibration
from fieldcal.cli.main import main
from fieldcal.earth import Station
from fieldcal.model import k_from_terms
from fieldcal.paramfile import ParameterFile, load, save
from fieldcal.recording.import_map import ImportMapError, load_import_map
from fieldcal.thermal import ThermalModel

OLD_FILE = Path(__file__).parent / "data" / "golden" / "headless-resumed" / "parameters.yaml"
REFERENCE_C, RANGE_C = 25.0, (19.5, 31.0)
# configs/sim-warmup.yaml's thermal truth: 0.3, -0.5, 0.8 mg/K and 0.01, 0, -0.02 mg/K²; 50, -30,
# 40 ppm/K. The gyroscope: 0.02, -0.05, 0.08 °/s/K; 20, 30, -20 ppm/K.
ACC_TRUTH = ThermalTruth(REFERENCE_C, [[0.002941995, -0.004903325, 0.00784532], [9.8067e-05, 0.0, -0.000196133]],
                         [5.0e-05, -3.0e-05, 4.0e-05])
GYR_TRUTH = ThermalTruth(REFERENCE_C, [[0.000349066, -0.000872665, 0.001396263]], [2.0e-05, 3.0e-05, -2.0e-05])
ACC_K = k_from_terms([1.002, 0.997, 1.001], [1e-3, -2e-3, 5e-4, 0.0, 3e-3, -1e-3])
GYR_K = k_from_terms([1.01, 0.99, 1.0], [0.0, 2e-4, 0.0, 0.0, 0.0, -1e-4])
ACC_BIAS, GYR_BIAS = np.array([0.05, -0.03, 0.02]), np.array([1e-3, -2e-3, 5e-4])

MAP = """files:
  - time: {{column: t_ms, unit: ms}}
{temperature}    triads:
      accelerometer: {{columns: [ax, ay, az], kind: specific_force, unit: m/s^2}}
      gyroscope: {{columns: [gx, gy, gz], kind: angular_rate, unit: rad/s}}
"""
WITH_TEMPERATURE = "    temperature: {column: temp_cC, scale: 0.01}\n"  # centidegrees, as some loggers write


def _model(truth: ThermalTruth) -> ThermalModel:
    return ThermalModel(reference_c=truth.reference_c, range_c=RANGE_C, bias_terms=truth.bias_terms,
                        bias_terms_sigma=np.abs(truth.bias_terms) * 0.05, scale_drift=truth.scale_drift,
                        scale_drift_sigma=np.full(3, 1e-6))


def _calibrations(thermal: bool = True) -> tuple[Calibration, Calibration]:
    acc = Calibration(name="accelerometer", kind="specific_force", output_unit="m/s^2", method="classic", K=ACC_K,
                      bias=ACC_BIAS, sigma=np.full(9, 1e-5), residual_rms=0.0,
                      thermal=_model(ACC_TRUTH) if thermal else None)
    gyr = Calibration(name="gyroscope", kind="angular_rate", output_unit="rad/s", method="classic", K=GYR_K,
                      bias=GYR_BIAS, sigma=np.full(9, 1e-6), residual_rms=0.0,
                      thermal=_model(GYR_TRUTH) if thermal else None)
    return acc, gyr


def _params(path: Path, thermal: bool = True) -> Path:
    pf = ParameterFile.build(_calibrations(thermal), station=Station(40.0, 50.0), procedure="field-18",
                             method="classic", input_sha256="c" * 64)
    return save(pf, path)


def _raw(true: np.ndarray, K, bias, truth: ThermalTruth, temperature_c: np.ndarray) -> np.ndarray:
    """The simulator's forward model: raw = diag(1 + s₁ΔT)·K·true + bias + Σₖ bₖΔTᵏ."""
    offset, ratio = truth.offset_and_ratio(temperature_c)
    return ratio * (true @ K.T) + bias + offset


def _recording(tmp_path: Path, temperature_c: np.ndarray, seed: int = 5):
    """A CSV of raw samples made from known true inputs at the given temperatures (°C, written
    in centidegrees); the true inputs and the raw values as the text holds them."""
    rng = np.random.default_rng(seed)
    n = len(temperature_c)
    true_acc, true_gyr = rng.normal(size=(n, 3)) * 5.0, rng.normal(size=(n, 3))
    raw_acc = _raw(true_acc, ACC_K, ACC_BIAS, ACC_TRUTH, temperature_c)
    raw_gyr = _raw(true_gyr, GYR_K, GYR_BIAS, GYR_TRUTH, temperature_c)
    path = tmp_path / "log.csv"
    rows = np.c_[4.0 * np.arange(n), raw_acc, raw_gyr, np.round(temperature_c * 100)]
    np.savetxt(path, rows, delimiter=",", fmt="%.17g", header="t_ms,ax,ay,az,gx,gy,gz,temp_cC", comments="")
    return path, true_acc, true_gyr, raw_acc, raw_gyr


def _map(tmp_path: Path, temperature: str = WITH_TEMPERATURE) -> Path:
    path = tmp_path / "map.yaml"
    path.write_text(MAP.format(temperature=temperature))
    return path


def _warmup(n: int) -> np.ndarray:
    """A warm-up as configs/sim-warmup.yaml's, 20 °C + 13 K towards τ = 1 h, over 85 minutes
    (10 K), at centidegree resolution as the text holds it."""
    profile = TemperatureProfile("warmup", start_c=20.0, rise_k=13.0, time_constant_s=3600.0)
    return np.round(profile.at(np.linspace(0.0, 85 * 60.0, n)) * 100) / 100


def test_each_sample_is_corrected_at_its_own_temperature(tmp_path, capsys):
    temperature = _warmup(4000)
    assert np.ptp(temperature) > 9.5  # the unit warms by about 10 K
    path, true_acc, true_gyr, raw_acc, _ = _recording(tmp_path, temperature)
    out = tmp_path / "cal.csv"
    assert main(["apply", str(_params(tmp_path / "p.yaml")), str(path), "--map", str(_map(tmp_path)),
                 "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "4000 samples calibrated" in err and "thermal" not in err  # all within range: nothing to say
    data = np.loadtxt(out, delimiter=",", skiprows=1)
    np.testing.assert_allclose(data[:, 1:4], true_acc, rtol=0, atol=1e-11)
    np.testing.assert_allclose(data[:, 4:7], true_gyr, rtol=0, atol=1e-11)
    # and the model mattered: the static calibration alone misses by the thermal drift
    static = np.linalg.solve(ACC_K, (raw_acc - ACC_BIAS).T).T
    assert np.abs(static - true_acc).max() > 0.02  # > 2 mg


def test_blocks_give_what_calibrate_gives_sample_by_sample(tmp_path):
    temperature = _warmup(600)
    path, *_, raw_acc, raw_gyr = _recording(tmp_path, temperature, seed=8)
    params = load(_params(tmp_path / "p.yaml"))
    [p] = plan(params, load_import_map(_map(tmp_path)), [path])
    out = tmp_path / "cal.csv"
    with open(out, "wb") as fh:
        apply_file(p, fh, block_bytes=512)  # many blocks, each split mid-recording
    data = np.loadtxt(out, delimiter=",", skiprows=1)
    text = np.loadtxt(path, delimiter=",", skiprows=1)
    t_c = text[:, 7] * 0.01
    np.testing.assert_allclose(data[:, 1:4], params.triad("accelerometer").calibrate(text[:, 1:4], t_c),
                               rtol=0, atol=1e-12)
    np.testing.assert_allclose(data[:, 4:7], params.triad("gyroscope").calibrate(text[:, 4:7], t_c),
                               rtol=0, atol=1e-12)


def _too_warm(n: int = 500, over: int = 37) -> np.ndarray:
    """Within the range but for ``over`` samples near the end, at 31.5 to 33 °C."""
    temperature = np.linspace(20.0, 30.0, n)
    temperature[n - over - 10:n - 10] = np.linspace(31.5, 33.0, over)
    return temperature


def test_samples_outside_the_range_are_refused_in_one_line_with_their_count(tmp_path, capsys):
    path, *_ = _recording(tmp_path, _too_warm())
    out = tmp_path / "cal.csv"
    params = _params(tmp_path / "p.yaml")
    assert main(["apply", str(params), str(path), "--map", str(_map(tmp_path)), "--out", str(out)]) != 0
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert ("37 of 500 samples at 31.50 to 33.00 °C are outside accelerometer's calibrated range 19.50 to "
            "31.00 °C") in err and "gyroscope's" in err and "--hold-temperature-edge" in err
    assert not out.exists()  # nothing written, not even a part
    # the count is of the whole file, though the first block out of range stops the output
    [p] = plan(load(params), load_import_map(_map(tmp_path)), [path])
    with pytest.raises(TemperatureOutside, match="37 of 500 samples"):
        apply_file(p, open(tmp_path / "part.csv", "wb"), block_bytes=256)


def test_held_at_the_edge_when_asked_and_said(tmp_path, capsys):
    temperature = _too_warm()
    path, *_ = _recording(tmp_path, temperature)
    out = tmp_path / "cal.csv"
    params = _params(tmp_path / "p.yaml")
    assert main(["apply", str(params), str(path), "--map", str(_map(tmp_path)), "--out", str(out),
                 "--hold-temperature-edge"]) == 0
    err = capsys.readouterr().err
    assert "37 of 500 samples at 31.50 to 33.00 °C are outside accelerometer's" in err
    assert "corrected at the nearest edge of the range" in err
    data = np.loadtxt(out, delimiter=",", skiprows=1)
    text = np.loadtxt(path, delimiter=",", skiprows=1)
    acc = load(params).triad("accelerometer")
    held = np.minimum(text[:, 7] * 0.01, RANGE_C[1])
    np.testing.assert_allclose(data[:, 1:4], acc.calibrate(text[:, 1:4], held), rtol=0, atol=1e-12)
    hot = temperature > RANGE_C[1]
    assert np.count_nonzero(hot) == 37
    np.testing.assert_allclose(data[hot, 1:4], acc.calibrate(text[hot, 1:4], RANGE_C[1]), rtol=0, atol=1e-12)


def test_without_a_temperature_column_the_model_applies_at_its_reference_and_says_so(tmp_path, capsys):
    path, *_ = _recording(tmp_path, _warmup(300))
    out = tmp_path / "cal.csv"
    params = _params(tmp_path / "p.yaml")
    assert main(["apply", str(params), str(path), "--map", str(_map(tmp_path, "")), "--out", str(out)]) == 0
    lines = [line for line in capsys.readouterr().err.splitlines() if "thermal" in line]
    assert len(lines) == 1 and "applied at its reference temperature" in lines[0]
    assert "accelerometer at 25.00 °C (calibrated over 19.50 to 31.00 °C)" in lines[0]
    assert lines[0].endswith("name the temperature column in the map to correct each sample at its own")
    data = np.loadtxt(out, delimiter=",", skiprows=1)
    text = np.loadtxt(path, delimiter=",", skiprows=1)
    acc, gyr = load(params).triads
    np.testing.assert_allclose(data[:, 1:4], acc.calibrate(text[:, 1:4], REFERENCE_C), rtol=0, atol=1e-12)
    np.testing.assert_allclose(data[:, 4:7], gyr.calibrate(text[:, 4:7], REFERENCE_C), rtol=0, atol=1e-12)


def test_old_parameter_files_apply_byte_for_byte_as_before_whatever_the_temperature_column(tmp_path, capsys):
    """The golden parameter file (schema 1, before thermal models): its samples take the very
    arithmetic they took before, so the output with a map naming a temperature column is
    byte-identical to that without, and the column is not even read (it may hold text)."""
    old = load(OLD_FILE)
    assert all(t.thermal is None for t in old.triads)
    rng = np.random.default_rng(4)
    raw = rng.normal(size=(700, 6)) * [9.8, 9.8, 9.8, 1.0, 1.0, 1.0]
    path = tmp_path / "log.csv"
    with open(path, "w") as fh:
        fh.write("t_ms,ax,ay,az,gx,gy,gz,temp_cC\n")
        for i, row in enumerate(raw):
            fh.write(f"{4 * i}," + ",".join(repr(float(x)) for x in row) + (",n/a\n" if i % 7 else ",2500\n"))
    outputs = []
    for name, temperature in (("without", ""), ("with", WITH_TEMPERATURE)):
        out = tmp_path / f"{name}.csv"
        assert main(["apply", str(OLD_FILE), str(path), "--map", str(_map(tmp_path, temperature)),
                     "--out", str(out)]) == 0
        assert "temperature" not in capsys.readouterr().err
        outputs.append(out.read_bytes())
    assert outputs[0] == outputs[1]
    data = np.loadtxt(tmp_path / "with.csv", delimiter=",", skiprows=1)
    for j, t in enumerate(old.triads[:2]):
        np.testing.assert_allclose(data[:, 1 + 3 * j:4 + 3 * j], np.linalg.solve(t.K, (raw[:, 3 * j:3 * j + 3] - t.bias).T).T,
                                   rtol=0, atol=1e-12)


@pytest.mark.parametrize("temperature, message", [
    ("{column: temp_cC, scael: 0.01}", "files[0].temperature.scael: unknown key 'scael'; did you mean 'scale'?"),
    ("{column: temp_cC, scale: -1}", "files[0].temperature.scale: expected a number > 0"),
    ("{column: -2}", "files[0].temperature.column: expected a column number"),
])
def test_a_wrong_temperature_entry_in_a_map_is_one_line(tmp_path, temperature, message):
    with pytest.raises(ImportMapError) as caught:
        load_import_map(_map(tmp_path, f"    temperature: {temperature}\n"))
    assert message in str(caught.value) and "\n" not in str(caught.value)


# A config's simulated unit warming on a chamber's ramp, 1 K/s from 20 °C for 10 K (the Xsens
# frames carry its temperature), with configs/sim-warmup.yaml's thermal truth about 20 °C.
WARMING_DEVICE = """device:
  name: simulated MIMU, warming
  protocol: sim
  rate_hz: 250
  sim:
    imu_protocol: xsens
    seed: 5
    speed: 0
    temperature: {profile: ramp, start_c: 20.0, rise_k: 10.0, rate_k_per_s: 1.0}
    thermal:
      accelerometer:
        reference_c: 20.0
        bias_coefficients: [[0.002941995, -0.004903325, 0.00784532], [9.8067e-05, 0.0, -0.000196133]]
        scale_drift: [5.0e-05, -3.0e-05, 4.0e-05]
      gyroscope:
        reference_c: 20.0
        bias_coefficients: [[0.000349066, -0.000872665, 0.001396263]]
        scale_drift: [2.0e-05, 3.0e-05, -2.0e-05]
  triads:
    accelerometer: {kind: specific_force, unit: m/s^2}
    gyroscope: {kind: angular_rate, unit: rad/s}
station: {latitude_deg: 40.0, height_m: 50.0}
"""


def _device_truth(tmp_path: Path, high_c: float) -> tuple[Path, Path]:
    """The warming device's config, and its truth as a parameter file whose thermal model was
    calibrated over 19.5 °C to ``high_c``."""
    from drivers.sim.device import paper_mimu
    from fieldcal.config import load_config

    config = tmp_path / "warming.yaml"
    config.write_text(WARMING_DEVICE)
    thermal = load_config(config).device.sim.thermal.triads
    truth = paper_mimu()
    cals = [Calibration(name=name, kind=truth[name].kind, output_unit=truth[name].output_unit, method="classic",
                        K=truth[name].K, bias=truth[name].bias, sigma=np.zeros(9), residual_rms=0.0,
                        thermal=ThermalModel(reference_c=20.0, range_c=(19.5, high_c),
                                             bias_terms=thermal[name].bias_terms,
                                             bias_terms_sigma=np.zeros_like(thermal[name].bias_terms),
                                             scale_drift=thermal[name].scale_drift, scale_drift_sigma=np.zeros(3)))
            for name in ("accelerometer", "gyroscope")]
    pf = ParameterFile.build(cals, station=Station(40.0, 50.0), procedure="simulator truth", method="classic",
                             input_sha256="0" * 64)
    return config, save(pf, tmp_path / "truth.yaml")


def test_a_warming_live_device_is_corrected_at_the_temperature_its_frames_carry(tmp_path, capsys):
    """At rest while it warms 10 K: the output is the true specific force and rate within the
    noise, where the static calibration alone is off by the drift (1.5 mg on average)."""
    from test_apply_live import assert_true_inputs_within_noise

    config, params = _device_truth(tmp_path, 31.0)
    out = tmp_path / "live.csv"
    assert main(["apply", str(params), "--config", str(config), "--samples", "2500", "--out", str(out)]) == 0
    assert "2500 samples calibrated into" in capsys.readouterr().err
    table = np.loadtxt(out, delimiter=",", skiprows=1)
    assert_true_inputs_within_noise(table)
    # the test can fail: what the thermal terms took off, on average over the samples' temperatures
    profile = TemperatureProfile("ramp", start_c=20.0, rise_k=10.0, rate_k_per_s=1.0)
    drift = ThermalTruth(20.0, ACC_TRUTH.bias_terms, ACC_TRUTH.scale_drift).offset_and_ratio(profile.at(table[:, 0]))[0]
    assert np.abs(drift.mean(axis=0)).max() > 0.01  # m/s², against a tolerance of about 0.002


def test_a_live_device_warmer_than_the_range_stops_and_keeps_what_it_wrote(tmp_path, capsys):
    config, params = _device_truth(tmp_path, 24.0)
    out = tmp_path / "live.csv"
    assert main(["apply", str(params), "--config", str(config), "--samples", "2500", "--out", str(out)]) != 0
    err = capsys.readouterr().err
    [line] = [line for line in err.splitlines() if "outside" in line]
    assert "outside accelerometer's calibrated range 19.50 to 24.00 °C" in line and line.startswith("fieldcal")
    assert "refused, the thermal model does not extrapolate" in line
    # what was streamed before is kept, every sample of it within the range (the ramp passes
    # 24 °C at t = 4 s); a first read already too warm leaves no file
    if out.exists():
        table = np.loadtxt(out, delimiter=",", skiprows=1, ndmin=2)
        assert f"{len(table)} samples calibrated into" in err and table[:, 0].max() <= 4.0
    else:
        assert "\n0 samples calibrated;" in err


def _log_recording(temperature_c):
    """What a log's reader gives (as fieldcal import reads a ULog): SI samples, with or without
    the unit's temperature, made from known true inputs by the simulator's thermal model."""
    from fieldcal.recording import Recording

    rng = np.random.default_rng(11)
    n = 400
    t_c = _warmup(n)
    true_acc, true_gyr = rng.normal(size=(n, 3)) * 5.0, rng.normal(size=(n, 3))
    triads = {"accelerometer": _raw(true_acc, ACC_K, ACC_BIAS, ACC_TRUTH, t_c),
              "gyroscope": _raw(true_gyr, GYR_K, GYR_BIAS, GYR_TRUTH, t_c)}
    recording = Recording(t=np.arange(n) * 0.004, triads=triads,
                          kinds={"accelerometer": "specific_force", "gyroscope": "angular_rate"},
                          units={"accelerometer": "m/s^2", "gyroscope": "rad/s"},
                          temperature=None if temperature_c is None else temperature_c(t_c))
    return recording, true_acc, true_gyr


@pytest.mark.parametrize("seen", ["its own", "none", "too warm"])
def test_a_log_is_corrected_at_its_temperature(tmp_path, capsys, monkeypatch, seen):
    from fieldcal.recording import importer, logs

    temperature = {"its own": lambda t: t, "none": None, "too warm": lambda t: t + 3.0}[seen]
    recording, true_acc, true_gyr = _log_recording(temperature)
    report = importer.ImportReport(map_path="", map_text="", files=(), alignment=(), warnings=())
    monkeypatch.setattr(logs, "import_log", lambda *_: (recording, report))
    out = tmp_path / "cal.csv"
    code = main(["apply", str(_params(tmp_path / "p.yaml")), str(tmp_path / "flight.ulg"), "--out", str(out)])
    err = capsys.readouterr().err
    if seen == "too warm":  # refused before a sample is written
        assert code != 0 and not out.exists()
        hot = np.count_nonzero(recording.temperature > RANGE_C[1])
        assert f"{hot} of 400 samples at" in err and "refused" in err and err.count("\n") == 1
        return
    assert code == 0
    data = np.loadtxt(out, delimiter=",", skiprows=1)
    if seen == "none":
        assert "no temperature read, so the thermal model is applied at its reference temperature" in err
        assert "map" not in err  # a log has no map to name a column in
        acc = load(tmp_path / "p.yaml").triad("accelerometer")
        np.testing.assert_allclose(data[:, 1:4], acc.calibrate(recording.triads["accelerometer"], REFERENCE_C),
                                   rtol=0, atol=1e-12)
        assert np.abs(data[:, 1:4] - true_acc).max() > 0.01  # the drift it could not take off
    else:
        assert "temperature" not in err
        np.testing.assert_allclose(data[:, 1:4], true_acc, rtol=0, atol=1e-11)
        np.testing.assert_allclose(data[:, 4:7], true_gyr, rtol=0, atol=1e-11)
