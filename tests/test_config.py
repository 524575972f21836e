"""Station configs: the shipped examples load; bad ones give one line naming the field."""
from pathlib import Path

import pytest

from fieldcal.config import CONFIGS_DIR, ConfigError, load_config


@pytest.mark.parametrize("name", sorted(p.stem for p in CONFIGS_DIR.glob("*.yaml")))
def test_shipped_configs_load(name):
    config = load_config(name)
    assert config.device.triads and config.station.gravity > 9.7
    if config.device.protocol != "sim":
        assert config.device.port.url and config.table.port.url


def mutated(tmp_path, old, new, name="sim.yaml"):
    text = (CONFIGS_DIR / name).read_text()
    assert old in text
    path = tmp_path / "station.yaml"
    path.write_text(text.replace(old, new, 1))
    return path


@pytest.mark.parametrize("name, old, new, message", [
    ("sim.yaml", "rate_hz: 250", "rate_hz: fast", "device.rate_hz: expected a number >= 0.001, got 'fast'"),
    ("sim.yaml", "imu_protocol: xsens", "imu_protocol: nmea",
     "device.sim.imu_protocol: expected 'xsens' or 'vectornav' or 'delimited', got 'nmea'"),
    ("sim.yaml", "kind: angular_rate", "kind: rate",
     "device.triads.gyroscope.kind: expected 'specific_force' or 'angular_rate', got 'rate'"),
    ("sim.yaml", "latitude_deg: 40.0", "latitude_deg: 140.0",
     "station.latitude_deg: expected a latitude from -90 to 90, got 140.0"),
    ("vn100.yaml", "port0, baudrate: 115200}", "port0, baudrate: 115200.5}",
     "device.port.baudrate: expected a whole number, got 115200.5"),
    ("vn100.yaml", "  port: {url: /dev/serial", "  prot: {url: /dev/serial",
     "device.prot: unknown key 'prot'; did you mean 'port'? (line 8)"),
    ("csv-example.yaml", "columns: [1, 2, 3]", "columns: [1, 2]",
     "device.channels.triads.accelerometer.columns: expected 3 column numbers, got [1, 2]"),
    ("vn100.yaml", "noise: {white: 1.37e-3,", "noise: {white: -1.37e-3,",
     "device.triads.accelerometer.noise.white: expected a number >= 1e-12, got -0.00137"),
    ("vn100.yaml", "bias_instability: 4.8e-5}", "bias_instabilty: 4.8e-5}",
     "device.triads.gyroscope.noise.bias_instabilty: unknown key 'bias_instabilty'; did you mean 'bias_instability'?"),
    ("vn100.yaml", "unit: rad/s, noise:", "unit: rad/s, zero: [1, 2], noise:",
     "device.triads.gyroscope.zero: expected a number or a list of three numbers, got a list of 2 items"),
    ("vn100.yaml", "  rate_hz: 200\n", "  rate_hz: 200\n  serial: [1]\n",
     "device.serial: expected the unit's serial number (text), got"),
    ("mti.yaml", "  protocol: ascii", "  protocol: stepper",
     "table.protocol: expected 'ascii' or 'grbl', got 'stepper'"),
    ("vn100.yaml", "unit: rad/s, noise:", "unit: rad/s, scale_tempco_ppm_per_k: -50, noise:",
     "device.triads.gyroscope.scale_tempco_ppm_per_k: expected a number >= 0, got -50"),
])
def test_bad_config_is_one_line_naming_the_field(tmp_path, name, old, new, message):
    path = mutated(tmp_path, old, new, name)
    with pytest.raises(ConfigError) as exc_info:
        load_config(path)
    text = str(exc_info.value)
    assert "\n" not in text and text.startswith(f"{path}: ") and message in text


def test_scale_temperature_coefficient_is_read_per_triad(tmp_path):
    config = load_config(mutated(tmp_path, "unit: rad/s, noise:", "unit: rad/s, scale_tempco_ppm_per_k: 80, noise:",
                                 "vn100.yaml"))
    tempco = {t.name: t.scale_tempco_ppm_per_k for t in config.device.triads}
    assert tempco == {"accelerometer": None, "gyroscope": 80.0}


def test_real_device_needs_a_port(tmp_path):
    path = mutated(tmp_path, "  port: {url: /dev/ttyUSB0, baudrate: 921600}\n", "", "mti.yaml")
    with pytest.raises(ConfigError, match=r"device\.port: expected a mapping with url"):
        load_config(path)


def test_missing_and_broken_files(tmp_path):
    with pytest.raises(ConfigError, match="cannot read config"):
        load_config(tmp_path / "nope.yaml")
    broken = tmp_path / "broken.yaml"
    broken.write_text("device: [\n")
    with pytest.raises(ConfigError, match=r"broken\.yaml: not valid YAML \(line"):
        load_config(broken)
    assert Path(load_config("sim").path).name == "sim.yaml"
