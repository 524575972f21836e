"""fieldcal apply --config: a live device, calibrated as it streams. The simulator is served on a
pty or a TCP socket (socket://) and read through pyserial and the protocol's parser exactly as
hardware would be, or started by the config itself (protocol sim); the parameter file holds the
simulator's own true errors, so the calibrated output must be the simulator's true specific
force and rate at rest, within its noise. Ctrl-C ends the stream between lines."""
from __future__ import annotations

import io
import signal
import subprocess
import sys

import numpy as np
import pytest

from drivers.sim.device import PAPER_NOISE, paper_mimu
from drivers.sim.physics import MimuSimulator
from drivers.sim.serve import SimulatedDevices
from fieldcal.calibration import Calibration
from fieldcal.earth import Station
from fieldcal.paramfile import ParameterFile, save

STATION = Station(40.0, 50.0)
RATE_HZ = 250
HEADER = ("t_s,accelerometer_x_m/s^2,accelerometer_y_m/s^2,accelerometer_z_m/s^2,"
          "gyroscope_x_rad/s,gyroscope_y_rad/s,gyroscope_z_rad/s")
TRIADS = """  triads:
    accelerometer: {kind: specific_force, unit: m/s^2}
    gyroscope: {kind: angular_rate, unit: rad/s}
station: {latitude_deg: 40.0, height_m: 50.0}
"""
DELIMITED_CHANNELS = """  channels:
    delimiter: ","
    time_column: 0
    triads:
      accelerometer: {columns: [1, 2, 3], unit: m/s^2}
      gyroscope: {columns: [4, 5, 6], unit: rad/s}
    temperature_column: 7
"""


def true_parameters(tmp_path):
    """The simulator's true K and bias of both triads, as a parameter file."""
    truth = paper_mimu()
    cals = [Calibration(name=name, kind=truth[name].kind, output_unit=truth[name].output_unit,
                        method="classic", K=truth[name].K, bias=truth[name].bias, sigma=np.zeros(9),
                        residual_rms=0.0) for name in ("accelerometer", "gyroscope")]
    pf = ParameterFile.build(cals, station=STATION, procedure="simulator truth", method="classic",
                             input_sha256="0" * 64)
    return save(pf, tmp_path / "truth.yaml")


def true_inputs_at_rest() -> tuple[np.ndarray, np.ndarray]:
    """Specific force (m/s²) and rate (rad/s) of a unit level and still at the station: gravity
    and the earth's rotation in body axes, as the simulator computes them."""
    sim = MimuSimulator(paper_mimu(), gravity=STATION.gravity, latitude_rad=STATION.latitude_rad,
                        rate_hz=RATE_HZ, seed=1)
    zero = np.zeros(1)
    force, rate = sim.true_inputs(np.eye(3), zero, zero, zero)
    return force[0], rate[0]


def device_config(tmp_path, protocol: str, url: str | None) -> str:
    path = tmp_path / "device.yaml"
    if url is None:  # the simulated device, started by the command itself
        path.write_text(f"device:\n  name: simulated MIMU\n  protocol: sim\n  rate_hz: {RATE_HZ}\n"
                        f"  sim: {{imu_protocol: {protocol}, seed: 5, speed: 0}}\n" + TRIADS)
    else:
        channels = DELIMITED_CHANNELS if protocol == "delimited" else ""
        path.write_text(f"device:\n  name: unit under test\n  protocol: {protocol}\n  rate_hz: {RATE_HZ}\n"
                        f"  port: {{url: {url}}}\n" + channels + TRIADS)
    return str(path)


def served(protocol: str, transport: str, on_chunk=None) -> SimulatedDevices:
    """The simulator at rest, level, as fast as it is read (the link's buffer paces it)."""
    return SimulatedDevices(paper_mimu(), STATION.gravity, STATION.latitude_rad, imu_protocol=protocol,
                            table_protocol=None, transport=transport, speed=0, seed=3, rate_hz=RATE_HZ,
                            on_chunk=on_chunk)


def apply_command(params, config, *extra) -> list[str]:
    return [sys.executable, "-m", "fieldcal.cli.main", "apply", str(params), "--config", config, *extra]


def assert_true_inputs_within_noise(table: np.ndarray) -> None:
    """Each axis's mean within 4 standard errors of white noise (plus twice the bias
    instability) of the truth: tighter than the simulator's smallest bias (1 mg, 0.01 °/s) and
    scale errors, so the raw output would fail it; the scatter is the white noise's."""
    force, rate = true_inputs_at_rest()
    n = len(table)
    for columns, truth, noise in ((slice(1, 4), force, PAPER_NOISE["accelerometer"]),
                                  (slice(4, 7), rate, PAPER_NOISE["gyroscope"])):
        sigma = noise.white * np.sqrt(RATE_HZ)  # per sample
        values = table[:, columns]
        np.testing.assert_allclose(values.mean(axis=0), truth, rtol=0,
                                   atol=4 * sigma / np.sqrt(n) + 2 * noise.bias_instability)
        assert np.all((values.std(axis=0) > 0.8 * sigma) & (values.std(axis=0) < 1.2 * sigma))


@pytest.mark.parametrize("protocol, transport", [("xsens", "pty"), ("vectornav", "tcp"), ("delimited", "sim")],
                         ids=["xsens on a pty", "vectornav on socket://", "config's simulated device"])
def test_a_live_device_calibrated_is_the_true_input(tmp_path, protocol, transport):
    params = true_parameters(tmp_path)
    out = tmp_path / "live.csv"
    devices = None if transport == "sim" else served(protocol, transport).start()
    try:
        config = device_config(tmp_path, protocol, devices and devices.imu_url)
        proc = subprocess.run(apply_command(params, config, "--samples", "2500", "--out", str(out)),
                              capture_output=True, text=True, timeout=300)
    finally:
        if devices is not None:
            devices.stop()
    assert proc.returncode == 0, proc.stderr
    assert "2500 samples calibrated into" in proc.stderr and "Traceback" not in proc.stderr
    text = out.read_text()
    assert text.splitlines()[0] == HEADER and text.endswith("\n")
    table = np.loadtxt(io.StringIO(text), delimiter=",", skiprows=1)
    assert table.shape == (2500, 7)
    np.testing.assert_allclose(np.diff(table[:, 0]), 1 / RATE_HZ, rtol=0, atol=1e-5)  # none lost
    assert_true_inputs_within_noise(table)


def test_ctrl_c_ends_the_stream_with_whole_lines(tmp_path):
    """Stopped by SIGINT mid-stream (no --samples): exit 0, every line whole and a sample, and
    the count on stderr is the lines written."""
    params = true_parameters(tmp_path)
    with served("xsens", "tcp") as devices:
        config = device_config(tmp_path, "xsens", devices.imu_url)
        proc = subprocess.Popen(apply_command(params, config), stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        try:
            head = [proc.stdout.readline() for _ in range(301)]  # the header and 300 samples
            proc.send_signal(signal.SIGINT)
            rest = proc.stdout.read()  # through readline's buffer (communicate would skip it)
            err = proc.stderr.read()  # a few lines: never fills its pipe meanwhile
            proc.wait(timeout=120)
        finally:
            proc.kill()
            proc.wait()
    text = b"".join(head).decode() + rest.decode()
    assert proc.returncode == 0, err.decode()
    assert text.endswith("\n") and text.splitlines()[0] == HEADER, (err.decode(), text[-300:])
    table = np.loadtxt(io.StringIO(text), delimiter=",", skiprows=1)
    assert table.ndim == 2 and table.shape[1] == 7 and len(table) >= 300
    assert f"{len(table)} samples calibrated;" in err.decode()
    assert_true_inputs_within_noise(table)


def test_ctrl_c_leaves_a_whole_out_file(tmp_path):
    """--out: SIGINT once samples flow (the command says so on stderr after its first block is
    in the file): the file is whole lines, as many as counted, each the true input within six
    standard deviations of the simulator's white noise."""
    params = true_parameters(tmp_path)
    out = tmp_path / "live.csv"
    with served("xsens", "pty") as devices:
        config = device_config(tmp_path, "xsens", devices.imu_url)
        proc = subprocess.Popen(apply_command(params, config, "--out", str(out)), stderr=subprocess.PIPE, text=True)
        try:
            said = []
            for line in proc.stderr:
                said.append(line)
                if line.startswith("samples flowing"):
                    break
            proc.send_signal(signal.SIGINT)
            err = "".join(said) + proc.stderr.read()
            proc.wait(timeout=120)
        finally:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, err
    text = out.read_text()
    assert text.endswith("\n") and text.splitlines()[0] == HEADER
    table = np.loadtxt(io.StringIO(text), delimiter=",", skiprows=1, ndmin=2)
    assert table.shape[1] == 7 and len(table) >= 1
    assert f"{len(table)} samples calibrated into {out}" in err
    force, rate = true_inputs_at_rest()
    for columns, truth, noise in ((slice(1, 4), force, PAPER_NOISE["accelerometer"]),
                                  (slice(4, 7), rate, PAPER_NOISE["gyroscope"])):
        assert np.all(np.abs(table[:, columns] - truth) < 6 * noise.white * np.sqrt(RATE_HZ))


def test_wrong_combinations_are_refused_in_one_line(tmp_path, capsys):
    from fieldcal.cli.main import main

    params = true_parameters(tmp_path)
    config = device_config(tmp_path, "xsens", "socket://127.0.0.1:9")
    cases = [([], "give the recording's INPUT files or a live device (--config), one of the two"),
             (["log.csv", "--config", config], "give the recording's INPUT files"),
             (["--config", config, "--map", "imu_tk"], "--map is for text INPUT files, not a live device"),
             (["log.csv", "--map", "imu_tk", "--samples", "5"], "--samples is for a live device (--config), not text"),
             (["run.ulg", "--rate", "5"], "--rate is for text INPUT files, not a log INPUT"),
             (["--config", config, "--topic", "/imu"], "--topic is for a log INPUT (.ulg, .bag, .bin), not a live"),
             (["log.csv"], "text INPUT files need their import map: give --map MAP")]
    for argv, message in cases:
        assert main(["apply", str(params), *argv]) == 2
        err = capsys.readouterr().err
        assert message in err and err.count("\n") == 1
    counts = tmp_path / "counts.yaml"
    counts.write_text(open(config).read().replace("unit: m/s^2", "unit: count"))
    assert main(["apply", str(params), "--config", str(counts)]) == 2
    assert "triad 'accelerometer' is read in 'count' but was calibrated in 'm/s^2'" in capsys.readouterr().err


def test_sample_numbers_leave_lost_frames_out():
    """Hand-worked: Xsens' 16-bit packet counter 65533, 65534, (65535 lost), 0 (wrapped), 1;
    then the next read 3 (2 lost), 3 again (re-sent: counted as the next), 4."""
    from fieldcal.apply.live import sample_numbers

    first, restarts = sample_numbers(np.array([65533.0, 65534.0, 0.0, 1.0]), 65536, None)
    np.testing.assert_array_equal(first, [0, 1, 3, 4])
    assert restarts == 0
    np.testing.assert_array_equal(sample_numbers(np.array([3.0, 3.0, 4.0]), 65536, (4, 1))[0], [6, 7, 8])
    np.testing.assert_array_equal(sample_numbers(np.array([10.0, 12.0, 5.0]), None, None)[0], [0, 2, 3])


def test_a_counter_stepping_back_is_no_wrap():
    """Hand-worked: 100, 101, then 99 (a frame re-sent or the device restarted), 100: the step
    back is one sample, not 65534 (655 s at Xsens' 100 Hz), and said; a read without counters
    (previous counter None) goes on from the last number."""
    from fieldcal.apply.live import sample_numbers

    numbers, restarts = sample_numbers(np.array([100.0, 101.0, 99.0, 100.0]), 65536, None)
    np.testing.assert_array_equal(numbers, [0, 1, 2, 3])
    assert restarts == 1
    numbers, restarts = sample_numbers(np.array([7.0, 0.0, 1.0]), 65536, (3, 5))  # restart at 0
    np.testing.assert_array_equal(numbers, [5, 6, 7])
    assert restarts == 1
    numbers, restarts = sample_numbers(np.array([40.0, 41.0]), 65536, (9, None))
    np.testing.assert_array_equal(numbers, [10, 11])
    assert restarts == 0


def test_a_failed_start_leaves_the_old_out_file(tmp_path, capsys):
    """--out FILE --force with no device answering: no samples, exit 1, and the file that
    --force would have replaced is as it was (no partial file left beside it)."""
    from fieldcal.cli.main import main

    params = true_parameters(tmp_path)
    config = device_config(tmp_path, "xsens", "socket://127.0.0.1:9")  # nothing listens there
    out = tmp_path / "live.csv"
    out.write_text("yesterday's calibrated samples\n")
    assert main(["apply", str(params), "--config", config, "--out", str(out), "--force", "--seconds", "0.2"]) == 1
    assert out.read_text() == "yesterday's calibrated samples\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["device.yaml", "live.csv", "truth.yaml"]
    for own in (params, config):  # never over the command's own files, --force or not
        assert main(["apply", str(params), "--config", config, "--out", str(own), "--force"]) == 2
        assert f"--out {own} is the input" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["device.yaml", "live.csv", "truth.yaml"]
