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
