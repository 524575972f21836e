"""The terminal UI against a real device: here the simulator served on pseudo-terminals in the
Xsens protocol with an ASCII rate table, read through pyserial and the parser exactly as
hardware would be. The test's hands carry the fixture; the UI reads, commands the table,
captures the session, and the capture replays to the same result."""
from __future__ import annotations

import math
import threading
import types
from pathlib import Path

import numpy as np
import pytest

from drivers.sim.device import PAPER_NOISE, paper_mimu
from drivers.sim.serve import SimulatedDevices
from fieldcal.procedure import events as ev
from fieldcal.config import ConfigError, load_config
from fieldcal.earth import Station
from fieldcal.run.replay import replay
from fieldcal.run.runner import RunSpec, open_run
from fieldcal.session.capture import SessionReader
from fieldcal.tui import FieldcalApp
from fieldcal.cli.tui import live_spec
from tests.test_tui import TWO_POSITIONS, TWO_WITH_TURNS, on_results, run_async, two_positions, until, waiting_at
from tests.tui_pilot import ask, log_settled, placed_and_still, press_and_go_on, what_it_shows

STATION = Station(40.0, 50.0)
QUICK_RATE_DEG_S = 60.0  # QUICK_TURNS' table rate
OPTIONS = types.SimpleNamespace(method="auto", on_motion="restart", thermal=None)


def live_config(tmp_path, devices: SimulatedDevices, noise: bool = True):
    acc, gyro = PAPER_NOISE["accelerometer"], PAPER_NOISE["gyroscope"]
    noise_acc = f", noise: {{white: {acc.white!r}, bias_instability: {acc.bias_instability!r}}}" if noise else ""
    noise_gyro = f", noise: {{white: {gyro.white!r}, bias_instability: {gyro.bias_instability!r}}}"
    path = tmp_path / "bench.yaml"
    path.write_text(f"""\
device:
  name: bench MTi
  serial: SN-42
  protocol: xsens
  rate_hz: 250
  port: {{url: {devices.imu_url}}}
  triads:
    accelerometer: {{kind: specific_force, unit: m/s^2{noise_acc}}}
    gyroscope: {{kind: angular_rate, unit: rad/s{noise_gyro}}}
table:
  protocol: ascii
  port: {{url: {devices.table_url}}}
  max_rate_deg_s: {QUICK_RATE_DEG_S}
station: {{latitude_deg: 40.0, height_m: 50.0}}
""")
    return load_config(path)


@pytest.fixture
def devices():
    served = SimulatedDevices(paper_mimu(), STATION.gravity, STATION.latitude_rad, imu_protocol="xsens",
                              table_protocol="ascii", speed=30, seed=3, rate_hz=250, waits_for_reader=True)
    served.start()
    yield served
    served.stop()


# TWO_WITH_TURNS with 2 s dwells and 60 °/s turns (live_config's table.max_rate_deg_s): the same
# steps in a fraction of the samples (each one read from the pty, parsed and fed; a loaded machine
# took 36 s over TWO_WITH_TURNS' 200 s). The second position is upside down, not the first turned about the
# vertical: "placed and still" must tell the carry's samples from the last step's, and a turn about
# gravity leaves the tilt as it was (then "ready" could be pressed before the station had read the
# carry, which it then saw as motion: 1 run in 6, 2026-11-27).
QUICK_TURNS = (TWO_POSITIONS.replace("20 s dwells", "2 s dwells").replace("dwell_s: 20", "dwell_s: 2")
               .replace('{id: 2, description: "z-upward, x-north, y-west", axes: {x: north, y: west, z: up}}',
                        '{id: 2, description: "z-downward, x-north, y-east", axes: {x: north, y: east, z: down}}')
               + f"rate_step: {{rate_deg_s: {QUICK_RATE_DEG_S}, turns: 1, ramp_s: 2, settle_s: 1}}\n")
assert "z: down" in QUICK_TURNS


@run_async
async def test_a_live_device_is_read_the_table_turns_and_the_session_replays(tmp_path, devices):
    config = live_config(tmp_path, devices)
    procedure = two_positions(tmp_path, QUICK_TURNS)
    spec = live_spec(config, procedure, OPTIONS)
    app = FieldcalApp(spec, 0, tmp_path / "session", config=config)
    async with app.run_test(size=(80, 24)) as pilot:
        for step, position in enumerate(procedure.positions):
            await until(pilot, lambda step=step: waiting_at(app, step))
            carried_until = devices.carry(position.attitude, 2.0).result(timeout=60)  # the operator's hands
            await until(pilot, lambda: placed_and_still(app, carried_until))  # and what the station shows
            # "b", a simulator key: refused on a real device
            await press_and_go_on(pilot, "b", "r")
        await until(pilot, lambda: on_results(app))
        outcome = app.outcome
    assert outcome.status == "completed" and outcome.completed == 2
    assert outcome.truth == {}  # a real device: no truth to compare with
    kinds = [e.kind for e in app.events]
    assert kinds.count("step_complete") == 2 and "motion_detected" not in kinds
    commands = [e.rate_deg_s for e in app.events if isinstance(e, ev.CommandTable)]
    assert sorted(commands[:2]) == [-QUICK_RATE_DEG_S, QUICK_RATE_DEG_S] and commands[2] == 0.0
    # The table really turned: half the difference of the two directions' gyro means (free of
    # the gyro bias) has the table's rate as its norm.
    reader = SessionReader(tmp_path / "session")
    for step in reader.steps():
        turns = {w["rate_deg_s"]: np.array(w["means"]["gyroscope"]) for w in step["windows"]
                 if w["rate_deg_s"]}
        assert sorted(turns) == [-QUICK_RATE_DEG_S, QUICK_RATE_DEG_S]
        measured = math.degrees(float(np.linalg.norm(turns[QUICK_RATE_DEG_S] - turns[-QUICK_RATE_DEG_S]) / 2))
        assert measured == pytest.approx(QUICK_RATE_DEG_S, rel=1e-3)
    assert reader.start["device"]["serial"] == "SN-42" and "simulation_truth" not in reader.start
    assert sum(1 for _ in reader.raw("imu")) > 0  # the bytes, as read
    # Replayed without the device or its config: the same events, the same verdicts.
    replayed = []
    again = replay(open_run(tmp_path / "session"), report=replayed.append)
    unit, samples = again.unit, again.samples
    assert [e.kind for e in replayed] == kinds[:len(replayed)] and len(replayed) >= len(kinds) - 1
    assert unit.failures == outcome.unit.failures and samples > 0
    # `fieldcal solve` re-solves it from the log with the device's own noise models (a real
    # device has no simulation truth to take them from).
    from fieldcal.run.compare import compare_methods
    solved = compare_methods(open_run(tmp_path / "session", log_only=True), ["powell", "classic"])
    assert "2 completed steps" in solved and solved.count("not calibrated") == 2 * len(outcome.unit.failures)


def test_a_live_run_needs_the_noise_and_a_table(tmp_path, devices):
    with pytest.raises(ConfigError, match=r"device\.triads\.accelerometer\.noise"):
        live_spec(live_config(tmp_path, devices, noise=False), two_positions(tmp_path), OPTIONS)
    config = live_config(tmp_path, devices)
    no_table = type(config)(config.path, config.device, config.station, None)
    with pytest.raises(ValueError, match="no table, and procedure two has rate steps"):
        live_spec(no_table, two_positions(tmp_path, TWO_WITH_TURNS), OPTIONS)
    assert live_spec(no_table, two_positions(tmp_path, TWO_POSITIONS), OPTIONS).live.serial == "SN-42"
    spec = live_spec(config, two_positions(tmp_path), OPTIONS)
    again = RunSpec.from_metadata(spec.to_metadata())  # what a replay rebuilds the run from
    assert again.to_metadata() == spec.to_metadata() and again.engine_settings() == spec.engine_settings()
    assert again.models()["gyroscope"].noise == PAPER_NOISE["gyroscope"]


@run_async
async def test_a_lost_device_is_said_at_once_the_dwell_waits_and_quitting_is_clean(tmp_path, devices):
    """Issue 15 item 3: the serving end goes away mid-dwell."""
    from fieldcal.tui.widgets.live import rows

    config = live_config(tmp_path, devices)
    procedure = two_positions(tmp_path, TWO_WITH_TURNS)
    app = FieldcalApp(live_spec(config, procedure, OPTIONS), 0, tmp_path / "session", config=config)
    async with app.run_test(size=(80, 24)) as pilot:
        await until(pilot, lambda: waiting_at(app, 0))
        devices.carry(procedure.positions[0].attitude, 2.0).result(timeout=60)
        await press_and_go_on(pilot, "r")
        await until(pilot, lambda: app.telemetry.phase != "place" or app.telemetry.step > 0)
        devices.stop()  # the device is gone (a fast simulator may be past the dwell by now)
        await until(pilot, lambda: app.telemetry.silent_s is not None)
        view = app.screen.view
        t = app.telemetry.t
        text, style = view.banner(sim=False)
        assert text.startswith("NO SAMPLES from the device") and style == "bad"
        assert ("dwell is paused" in text) == (app.telemetry.phase in ("dwell", "rate_wait", "rate_average"))
        shown = rows(view)
        assert "no samples" in shown["still"].plain and "σ" not in shown["still"].plain
        assert "s left" not in shown["dwell"].plain  # the dwell waits
        # Nothing moves: a later telemetry (its silence counted further) is still at the same
        # sample time and phase. (Waited for by what it says, not for a fixed time.)
        phase, silent = app.telemetry.phase, app.telemetry.silent_s
        await until(pilot, lambda: app.telemetry.silent_s > silent)
        assert app.telemetry.t == t and app.telemetry.phase == phase
        await pilot.press("q", "y")
    assert app.source.done.wait(60.0), "the run's thread never ended"
    assert app.source.outcome.status == "stopped"  # not an error: the ports were closed cleanly


@run_async
async def test_a_table_whose_port_goes_away_is_said_and_the_run_waits_for_the_operator(tmp_path, devices):
    """The table's cable is pulled (its port fails with EIO) while the unit sends on: the station
    says so and waits for the operator to skip or abort, as for any table that refuses a
    command; the run does not end in an error. (Under load the old code hit this when the device
    and table stopped while a backlog of samples was still being fed: the test above.)"""
    from drivers.sim.ports import PtyLink

    table = PtyLink()  # a table port nobody answers on; closed below, as a pulled cable
    try:
        config = live_config(tmp_path, devices)
        path = Path(config.path)
        path.write_text(path.read_text().replace(devices.table_url, table.url))
        config = load_config(path)
        procedure = two_positions(tmp_path, QUICK_TURNS)
        app = FieldcalApp(live_spec(config, procedure, OPTIONS), 0, tmp_path / "session", config=config)
        async with app.run_test(size=(80, 24)) as pilot:
            await until(pilot, lambda: waiting_at(app, 0))
            table.close()  # the station holds the port open; its far end is gone
            devices.carry(procedure.positions[0].attitude, 2.0).result(timeout=60)
            await press_and_go_on(pilot, "r")
            await until(pilot, lambda: log_settled(app, "ERROR: table: its port"))
            assert app.outcome is None and not app.source.done.is_set()
            log = " ".join(" ".join(line.text.split()) for line in app.procedure_screen.query_one("#log").lines)
            assert f"its port {table.url} failed" in log and "skip this step (s) or abort (a)" in log
            # (the unit sends on: Pilot.press would wait 2 s a key for an idle that never comes)
            assert "abort" in await ask(pilot, "a")
            await press_and_go_on(pilot, "y")
            await until(pilot, lambda: app.outcome is not None)
        assert app.source.done.wait(60.0), "the run's thread never ended"
    finally:
        table.close()
    assert app.source.outcome.status == "aborted"


@run_async
async def test_devices_lost_as_the_table_command_goes_out_are_said_and_the_run_waits(tmp_path, devices):
    """The unit's and the table's cables pulled just as the table is commanded: between the
    command's write and pyserial's flush of it, whose tcdrain then raises termios.error, not an
    OSError. The run must not end in an error (it did: the first test's CI failure of 2026-11-28,
    on the results screen at the rate step's first command); the station says the table's port
    failed and that no samples come, and waits for the operator."""
    config = live_config(tmp_path, devices)
    procedure = two_positions(tmp_path, QUICK_TURNS)
    app = FieldcalApp(live_spec(config, procedure, OPTIONS), 0, tmp_path / "session", config=config)
    pulled = threading.Event()
    async with app.run_test(size=(80, 24)) as pilot:
        await until(pilot, lambda: waiting_at(app, 0))
        port = app.source.bench.table._io.port  # the table's pyserial port, as the station opened it
        written, real_write, real_flush = [], port.write, port.flush

        def write(data):
            written.append(bytes(data))
            return real_write(data)

        def flush():
            if written[-1].startswith(b"RATE") and not pulled.is_set():
                pulled.set()
                devices.stop()  # both cables, after the command's bytes went out and before the flush
            return real_flush()

        port.write, port.flush = write, flush
        devices.carry(procedure.positions[0].attitude, 2.0).result(timeout=60)
        await press_and_go_on(pilot, "r")
        await until(pilot, lambda: app.outcome is not None or log_settled(app, "ERROR: table: its port"))
        assert app.outcome is None, what_it_shows(app)
        assert pulled.is_set() and app.telemetry.step == 0 and app.telemetry.phase in ("rate_wait", "rate_average")
        await until(pilot, lambda: app.telemetry.silent_s is not None)
        text, style = app.screen.view.banner(sim=False)
        assert text.startswith("NO SAMPLES from the device") and style == "bad"
        await pilot.press("q", "y")
    assert app.source.done.wait(60.0), "the run's thread never ended"
    assert app.source.outcome.status == "stopped"  # the session can be resumed
