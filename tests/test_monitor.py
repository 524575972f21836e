"""fieldcal monitor on a pty fed by a separate process: it prints the values that were sent."""
import io
import subprocess
import sys
import textwrap

import numpy as np
import pytest

WRITER = textwrap.dedent("""
    import sys, time
    import numpy as np
    from drivers.chunk import SampleChunk
    from drivers.sim.ports import PtyLink
    from drivers.sim.serve import make_encoder, _as_device_sends
    protocol = sys.argv[1]
    rng = np.random.default_rng(7)
    n = 40
    chunk = _as_device_sends(SampleChunk(
        t=np.arange(n) / 100.0,
        triads={"accelerometer": rng.normal(0, 1, (n, 3)).round(3) + [0, 0, 9.8],
                "gyroscope": rng.normal(0, 0.01, (n, 3)).round(6)}))
    data = make_encoder(protocol).encode(chunk)
    link = PtyLink()
    print(link.url, flush=True)
    sys.stdin.readline()              # the monitor has the port open
    link.write(b"\\x00garbage\\xff\\r\\n" + data)
    sys.stdin.readline()              # keep the pty until told to go
    link.close()
""")


def sent_values():
    rng = np.random.default_rng(7)
    acc = rng.normal(0, 1, (40, 3)).round(3) + [0, 0, 9.8]
    gyro = rng.normal(0, 0.01, (40, 3)).round(6)
    return acc, gyro


@pytest.mark.parametrize("protocol", ["xsens", "vectornav", "delimited"])
def test_monitor_prints_what_a_separate_process_sent(protocol, tmp_path):
    writer = subprocess.Popen([sys.executable, "-c", WRITER, protocol], stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, text=True)
    try:
        url = writer.stdout.readline().strip()
        config = tmp_path / "device.yaml"
        channels = ""
        if protocol == "delimited":
            channels = """
  channels:
    delimiter: ","
    time_column: 0
    triads:
      accelerometer: {columns: [1, 2, 3], unit: m/s^2}
      gyroscope: {columns: [4, 5, 6], unit: rad/s}
    temperature_column: 7"""
        config.write_text(f"""device:
  name: unit under test
  protocol: {protocol}
  rate_hz: 100
  port: {{url: {url}}}{channels}
  triads:
    accelerometer: {{kind: specific_force, unit: m/s^2}}
    gyroscope: {{kind: angular_rate, unit: rad/s}}
station: {{latitude_deg: 40.0}}
""")
        monitor = subprocess.Popen([sys.executable, "-m", "fieldcal.cli.main", "monitor", "--config", str(config),
                                    "--samples", "40", "--seconds", "20"],
                                   stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        for line in monitor.stderr:
            if line.startswith("port opened"):
                break
        writer.stdin.write("go\n")
        writer.stdin.flush()
        out, err = monitor.communicate(timeout=30)
    finally:
        writer.stdin.write("done\n")
        writer.stdin.close()
        writer.wait(timeout=60)
    assert monitor.returncode == 0, err
    table = np.genfromtxt(io.StringIO(out), delimiter=",", names=True)
    acc, gyro = sent_values()
    got_acc = np.column_stack([table[f"accelerometer_{a}"] for a in "xyz"])
    got_gyro = np.column_stack([table[f"gyroscope_{a}"] for a in "xyz"])
    np.testing.assert_allclose(got_acc, acc, atol=1e-6, rtol=1e-6)
    np.testing.assert_allclose(got_gyro, gyro, atol=1e-6, rtol=1e-6)
    assert "40 samples; frames 40" in err
    assert "discarded 11 B" in err  # the garbage line before the frames, counted
