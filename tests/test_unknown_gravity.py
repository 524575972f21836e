"""g comes from where it belongs (--gravity, else the place's normal gravity, else a stated
default with its worldwide spread in the scale factors' σ), never from the uncalibrated sensor's
own norm: a unit reading 2 % low or 4 % high at rest is that much off in scale, which the
calibration must find, not fold into g."""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from drivers.sim.device import PAPER_NOISE
from drivers.sim.handheld import simulate_handheld, to_text
from fieldcal.cli.main import main
from fieldcal.earth import Station, normal_gravity
from fieldcal.recording import Recording
from fieldcal.recording.calibrate import calibrate_recording
from fieldcal.recording.outcome import RecordingSettings
from fieldcal.recording.place import GRAVITY_SPREAD, UnknownPlace

NOISE = RecordingSettings(noise=dict(PAPER_NOISE))
LATITUDE = 52.0  # the simulated place; its normal gravity is 0.11 % above the default's (45°)
G = normal_gravity(LATITUDE)


def scaled_recording(seed: int, factor: float):
    """A hand-held recording in m/s² whose accelerometer reads ``factor`` times the truth, and
    that accelerometer's true scale factors (output per m/s²)."""
    sim = simulate_handheld(seed, raw_counts=False, latitude_deg=LATITUDE, gravity=G)
    triads = dict(sim.triads, accelerometer=sim.triads["accelerometer"] * factor)
    truth = np.diag(sim.truth["accelerometer"].K) * factor
    return Recording(sim.t, triads, sim.kinds, sim.units), truth


@pytest.mark.parametrize("factor", [0.98, 1.04])
def test_a_mis_scaled_accelerometer_is_found_without_a_place(factor):
    recording, truth = scaled_recording(4, factor)
    cal = calibrate_recording(recording, UnknownPlace(), NOISE)
    acc = cal.specific_force["accelerometer"]
    scale, sigma = acc.theta[3:6], acc.sigma[3:6]
    # The sensor's own norm would put g 2 % low (4 % high) and leave the scale near 1.
    assert np.all(np.abs(scale / truth - 1) < GRAVITY_SPREAD)
    assert np.all(np.abs(scale - truth) < 3 * sigma)
    # The σ says where it comes from: the worldwide spread of g, not the fit.
    assert np.all(sigma / np.abs(scale) >= 0.9 * GRAVITY_SPREAD / math.sqrt(3))
    assert any("unknown g" in note and "--latitude" in note for note in cal.notes)
    assert cal.place.gravity == pytest.approx(normal_gravity(45.0))
    assert "45°" in cal.place.gravity_source and "--latitude" in cal.place.gravity_source


@pytest.mark.parametrize("factor", [0.98, 1.04])
def test_with_the_latitude_the_scale_is_within_its_usual_sigma(factor):
    recording, truth = scaled_recording(4, factor)
    cal = calibrate_recording(recording, Station(LATITUDE), NOISE)
    acc = cal.specific_force["accelerometer"]
    relative_sigma = acc.sigma[3:6] / np.abs(acc.theta[3:6])
    assert np.all(np.abs(acc.theta[3:6] - truth) < 3 * acc.sigma[3:6])
    assert np.all(relative_sigma < 0.1 * GRAVITY_SPREAD)  # the place known: g no longer dominates
    assert not any("unknown g" in note for note in cal.notes)


def test_a_given_gravity_adds_no_spread():
    recording, truth = scaled_recording(4, 0.98)
    cal = calibrate_recording(recording, UnknownPlace(gravity=G), NOISE)
    acc = cal.specific_force["accelerometer"]
    assert np.all(np.abs(acc.theta[3:6] - truth) < 3 * acc.sigma[3:6])
    assert np.all(acc.sigma[3:6] / np.abs(acc.theta[3:6]) < 0.1 * GRAVITY_SPREAD)


def _si_text(tmp_path, factor):
    sim = simulate_handheld(4, raw_counts=False, latitude_deg=LATITUDE, gravity=G)
    acc, gyro = to_text(replace(sim, accelerometer=sim.accelerometer * factor), tmp_path / "text")
    mapping = tmp_path / "si.yaml"
    mapping.write_text(
        "files:\n"
        "  - {name: acc, delimiter: null, time: {column: 0, unit: s}, triads: {accelerometer: "
        "{columns: [1, 2, 3], kind: specific_force, unit: m/s^2}}}\n"
        "  - {name: gyro, delimiter: null, time: {column: 0, unit: s}, triads: {gyroscope: "
        "{columns: [1, 2, 3], kind: angular_rate, unit: rad/s}}}\n")
    return acc, gyro, mapping


def test_fieldcal_calibrate_of_a_unit_reading_4_percent_high_is_no_refusal(tmp_path, capsys):
    """Before: g from the sensor's norm (10.2 m/s²) died with 'gravity_m_s2: expected 9.7..9.9'."""
    acc, gyro, mapping = _si_text(tmp_path, 1.04)
    code = main(["calibrate", str(acc), str(gyro), "--map", str(mapping), "--out", str(tmp_path / "s")])
    captured = capsys.readouterr()
    assert code == 0, captured.out + captured.err
    assert "gravity_m_s2" not in captured.out + captured.err
    assert "WGS84 normal gravity at 45°" in captured.out and "--latitude" in captured.out
    assert "unknown g" in captured.out


@pytest.mark.parametrize("options, named", [(["--latitude", "52", "--gravity", "9.5"], "--gravity"),
                                            (["--latitude", "95"], "--latitude"),
                                            (["--latitude", "52", "--height", "20000"], "--height"),
                                            (["--height", "300"], "--height: needs --latitude")])
def test_a_place_option_out_of_range_is_named(tmp_path, capsys, options, named):
    acc, gyro, mapping = _si_text(tmp_path, 1.0)
    code = main(["calibrate", str(acc), str(gyro), "--map", str(mapping), "--out", str(tmp_path / "s"), *options])
    err = capsys.readouterr().err
    assert code != 0
    assert named in err and "gravity_m_s2" not in err and "latitude_deg" not in err and "height_m" not in err
