"""Issue 15 item 2: the setup screen offers the unfinished sessions; a quit live run resumed in
the terminal UI, with the device (the simulator serving Xsens frames on a pty) running on, or
power-cycled in between; and the device-clock judgement itself, on hand-worked cases and on real
frame bytes."""
from __future__ import annotations

import os
import re
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from drivers.chunk import SampleChunk
from drivers.protocols import make_parser
from drivers.sim.device import paper_mimu
from drivers.sim.serve import SimulatedDevices
from fieldcal.cli.tui import live_spec
from fieldcal.config import load_config
from fieldcal.run.deviceclock import XSENS_TIME_PERIOD_S, DeviceClock, clock_of, judge_restart, went_back
from fieldcal.run.replay import replay
from fieldcal.session.capture import SessionReader
from fieldcal.tui import FieldcalApp
from fieldcal.run.runner import open_run
from tests.test_tui_live import OPTIONS, STATION, live_config
from tests.tui_pilot import ask, press_and_go_on, run_async, until, waiting_at
from tests.test_tui import on_results, two_positions

SHORT = """\
name: two-short
title: two positions, 1 s dwells
dwell_s: 1
positions:
  - {id: 1, description: "z-upward, x-south, y-east", axes: {x: south, y: east, z: up}}
  - {id: 2, description: "z-upward, x-north, y-west", axes: {x: north, y: west, z: up}}
"""
# The served device's sample time per wall time. It waits for the station's reads
# (``serve``): the world's clock (``WorldClock``, its sample time) then runs at most a pty's
# buffer (0.3 s) ahead of what the station has read, however loaded the host, well within the
# clock judgement's 2 s slack; and the carries' motion is never lost.
SPEED = 10.0
# The operator's hands: a carry is seen as motion, then the unit still.
CARRY_S = 0.5


# --- the judgement, by hand ------------------------------------------------------------------

def test_a_clock_that_ran_on_is_not_a_restart_one_that_is_behind_is():
    last = DeviceClock(host_utc=1000.0, time_s=500.0, time_period_s=XSENS_TIME_PERIOD_S, counter=7,
                       counter_modulus=65536)
    ran_on = judge_restart(last, DeviceClock(1100.0, 600.5), rate_hz=100)
    assert ran_on.power_cycled is False
    # Restarted 30 s before: 30 s where 600 s was due.
    restarted = judge_restart(last, DeviceClock(1100.0, 30.0), rate_hz=100)
    assert restarted.power_cycled is True and "600.0 s" in restarted.reason
    # A restart long ago that has run past the old reading is still behind what was due.
    assert judge_restart(last, DeviceClock(5000.0, 3000.0), rate_hz=100).power_cycled is True
    # SampleTimeFine wraps after 119 h: 10 s before the wrap, then 100 s later 90 s after it.
    near_wrap = DeviceClock(0.0, XSENS_TIME_PERIOD_S - 10.0, XSENS_TIME_PERIOD_S)
    assert judge_restart(near_wrap, DeviceClock(100.0, 90.0), rate_hz=100).power_cycled is False


def test_a_packet_counter_is_judged_modulo_its_wrap_and_nothing_is_cannot_tell():
    wide = DeviceClock(0.0, counter=2**32 - 500, counter_modulus=2**32)
    # 10 s at 100 Hz: 1000 frames on, past the wrap: 500.
    assert judge_restart(wide, DeviceClock(10.0, counter=505), rate_hz=100).power_cycled is False
    assert judge_restart(wide, DeviceClock(10.0, counter=12), rate_hz=100).power_cycled is True
    # A 16-bit counter at 100 Hz wraps every 655 s: a restarted unit's counter would land within
    # the ±2 s slack by chance 0.6 % of the time, so even a count that fits cannot tell.
    last = DeviceClock(0.0, counter=65000, counter_modulus=65536)
    check = judge_restart(last, DeviceClock(10.0, counter=470), rate_hz=100)
    assert check.power_cycled is None and "too often to tell" in check.reason
    # A 32-bit counter at 1 kHz still tells after a day away (±88 s of slack in 49 days' wrap).
    assert judge_restart(wide, DeviceClock(86400.0, counter=12), rate_hz=1000).power_cycled is True
    assert judge_restart(DeviceClock(0.0), DeviceClock(10.0), rate_hz=100).power_cycled is None
    assert judge_restart(None, DeviceClock(10.0, 5.0), rate_hz=100).power_cycled is None
    assert DeviceClock.from_dict(last.to_dict()) == last
    assert DeviceClock.from_dict(None) is None  # a step recorded before clocks were


def test_with_the_port_open_only_a_clock_gone_back_is_a_restart():
    """Between two reads (``went_back``): frames read late or faster than the host run ahead of
    or lag the host's time but never go back; a restarted clock does."""
    last = DeviceClock(1000.0, 600.0)
    assert went_back(last, DeviceClock(1000.1, 640.0), rate_hz=100) is None  # ran ahead (as fast as read)
    assert went_back(last, DeviceClock(1010.0, 600.5), rate_hz=100) is None  # lagging (a backlog)
    assert went_back(last, DeviceClock(1000.1, 599.0), rate_hz=100) is None  # within the slack
    assert went_back(last, DeviceClock(1000.5, 0.3), rate_hz=100).power_cycled is True
    near_wrap = DeviceClock(0.0, XSENS_TIME_PERIOD_S - 0.5, XSENS_TIME_PERIOD_S)
    assert went_back(near_wrap, DeviceClock(1.0, 0.5, XSENS_TIME_PERIOD_S), rate_hz=100) is None  # wrapped
    assert went_back(DeviceClock(0.0, counter=5000), DeviceClock(0.2, counter=20), rate_hz=100).power_cycled
    assert went_back(DeviceClock(0.0), DeviceClock(0.2), rate_hz=100) is None  # no clock: cannot tell


def test_the_clock_is_read_from_real_frames():
    from drivers.protocols import make_encoder

    n = 5
    chunk = SampleChunk(t=123.0 + np.arange(n) / 100, triads={"accelerometer": np.zeros((n, 3)),
                                                              "gyroscope": np.zeros((n, 3))},
                        temperature=np.full(n, 25.0))
    xsens = make_parser("xsens")
    parsed = xsens.feed(make_encoder("xsens").encode(chunk), t_host=9.0)
    clock = clock_of(parsed, xsens, host_utc=1e9)
    assert clock.time_s == pytest.approx(123.04) and clock.counter == n - 1  # the encoder counts from 0
    assert clock.time_period_s == XSENS_TIME_PERIOD_S and clock.counter_modulus == 65536
    vectornav = make_parser("vectornav")
    sent = SampleChunk(t=chunk.t, triads={**chunk.triads, "magnetometer": np.zeros((n, 3))},
                       temperature=chunk.temperature, extras={"pressure": np.full(n, 101.3)})
    parsed = vectornav.feed(make_encoder("vectornav").encode(sent), t_host=9.0)
    assert len(parsed) == n and clock_of(parsed, vectornav, 1e9) == DeviceClock(1e9)  # the host's alone


# --- in the terminal UI, on a device served on a pty ----------------------------------------

class WorldClock:
    """The simulated world's time as the host's wall clock: the served device's sample time
    (plus what passed before it was switched on), so the host and the device agree exactly on
    how long the run was away, whatever the load on the machine running the test."""

    def __init__(self, devices: SimulatedDevices):
        self.devices, self.offset = devices, 0.0

    def switch(self, devices: SimulatedDevices) -> None:
        """A power cycle: the new device's clock starts at zero, the world's runs on."""
        self.offset += self.devices.simulator.time
        self.devices = devices

    def __call__(self) -> float:
        return self.offset + self.devices.simulator.time


def serve(seed: int, protocol: str = "xsens", speed: float = SPEED, waits_for_reader: bool = True) -> SimulatedDevices:
    return SimulatedDevices(paper_mimu(), STATION.gravity, STATION.latitude_rad, imu_protocol=protocol,
                            table_protocol="ascii", speed=speed, seed=seed, rate_hz=250,
                            waits_for_reader=waits_for_reader).start()


@pytest.fixture
def served():
    devices = [serve(3)]
    yield devices
    for d in devices:
        d.stop()


def vectornav_config(tmp_path, devices):
    """``live_config`` for a device sending VectorNav ASCII sentences (no counter, no time)."""
    path = Path(live_config(tmp_path, devices).path)
    path.write_text(path.read_text().replace("protocol: xsens", "protocol: vectornav"))
    return load_config(path)


def _live_app(tmp_path, config, procedure, world, silence_clock=None) -> FieldcalApp:
    """``silence_clock``: what the device's silence is measured in (default: the host's time)."""
    return FieldcalApp(live_spec(config, procedure, OPTIONS), 0, tmp_path / "session", config=config,
                       wall_clock=world, silence_clock=silence_clock)


async def _first_step(app, pilot, devices, procedure) -> None:
    """The operator places the unit for the first step; the run then waits at the second."""
    await until(pilot, lambda: waiting_at(app, 0))
    devices.carry(procedure.positions[0].attitude, CARRY_S).result(timeout=60)
    await press_and_go_on(pilot, "r")  # (a device read all the time: Pilot.press would wait 2 s)
    await until(pilot, lambda: waiting_at(app, 1))


async def _first_step_then_quit(tmp_path, devices, world, procedure, make_config=live_config):
    config = make_config(tmp_path, devices)
    app = _live_app(tmp_path, config, procedure, world)
    async with app.run_test(size=(80, 24)) as pilot:
        await _first_step(app, pilot, devices, procedure)
        await ask(pilot, "q")
        await pilot.press("y")
    assert app.source.done.wait(60.0), "the run's thread never ended"
    assert app.source.outcome.status == "stopped"
    assert f"fieldcal tui --resume {tmp_path / 'session'} --config" in app.source.outcome.message
    return config


async def _resume(tmp_path, config, world, first_step, carry, silence_clock=None):
    app = FieldcalApp(speed=0, resume=open_run(tmp_path / "session"), config=config, wall_clock=world,
                      silence_clock=silence_clock)
    async with app.run_test(size=(80, 24)) as pilot:
        await until(pilot, lambda: waiting_at(app, first_step))
        # A loaded machine may keep the device's first samples more than 2 s (wall) away: the
        # banner says NO SAMPLES until they come. What the resume says is read once they have.
        await until(pilot, lambda: app.telemetry.silent_s is None)
        banner = str(app.screen.query_one("#banner").render())
        for step in range(first_step, 2):
            await until(pilot, lambda step=step: waiting_at(app, step))
            carry(app.spec.procedure.positions[step].attitude)
            await press_and_go_on(pilot, "r")
        await until(pilot, lambda: app.outcome is not None and on_results(app))
        log = log_text(app)
    return app, banner, log


def _the_config_must_be_the_sessions_device(tmp_path, config):
    """`tui --resume` of a live session: which config gives the ports, in one line if none fits."""
    from fieldcal.cli.tui import resume_config
    session = open_run(tmp_path / "session")
    live = session.spec.live
    assert live.name == "bench MTi" and live.serial == "SN-42"
    with pytest.raises(ValueError, match="give its station config \\(the ports\\) with --config"):
        resume_config(session, None)  # (XDG_CONFIG_HOME is empty: no remembered setup)
    with pytest.raises(ValueError, match="was recorded from bench MTi \\(serial SN-42, xsens\\); .*sim.yaml is"):
        resume_config(session, "sim")
    assert resume_config(session, str(config.path)).device.port.url == config.device.port.url


def _the_command_line_resumes_it_on_the_configs_ports(tmp_path, config, monkeypatch):
    from fieldcal.cli.main import main
    from fieldcal.tui import app

    asked = []
    monkeypatch.setattr(app, "run_tui", lambda *a, **kw: asked.append((a, kw)) or 0)
    assert main(["tui", "--resume", str(tmp_path / "session"), "--config", str(config.path)]) == 0
    (args, kw), = asked
    assert args[1] == 0.0 and kw["resume"].directory == tmp_path / "session"  # a device's pace, not a speed
    assert kw["config"].device.port.url == config.device.port.url


@run_async
async def test_a_live_run_resumed_on_a_device_that_ran_on_continues_after_its_last_step(tmp_path, served,
                                                                                       monkeypatch):
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "xdg"))
    devices = served[0]
    world = WorldClock(devices)
    procedure = two_positions(tmp_path, SHORT)
    config = await _first_step_then_quit(tmp_path, devices, world, procedure)
    (first,) = SessionReader(tmp_path / "session").steps()
    clock = first["bench"]["device_clock"]
    assert clock["time_s"] > 0 and 0 <= clock["counter"] < 65536 and clock["host_utc"] > 0
    _the_config_must_be_the_sessions_device(tmp_path, config)
    _the_command_line_resumes_it_on_the_configs_ports(tmp_path, config, monkeypatch)

    app, banner, log = await _resume(tmp_path, config, world, 1,
                                     lambda attitude: devices.carry(attitude, CARRY_S).result(timeout=60))
    assert banner.startswith("RESUMED after 1 completed step: place the unit again")
    assert "its clock ran on" in log and "power-cycled" not in log
    assert app.outcome.status == "completed" and app.outcome.completed == 2
    reader = SessionReader(tmp_path / "session")
    (resume,) = [d["data"] for d in reader.documents("resume")]
    assert resume == {"completed_steps": [0], "skipped": []}
    assert reader.steps()[0] == first  # appended to, never rewritten
    assert [r.step for r in open_run(reader.directory).completed] == [0, 1]
    # Every sample fed came from bytes in the raw capture, also those read to judge the clock
    # before the session could be written.
    parser = make_parser("xsens")
    parsed = sum(len(c) for _, data in reader.raw("imu") if (c := parser.feed(data, 0.0)) is not None)
    assert parsed >= reader.n_samples > 0


@run_async
async def test_a_live_run_resumed_after_a_power_cycle_measures_the_completed_steps_again(tmp_path, served):
    devices = served[0]
    world = WorldClock(devices)
    procedure = two_positions(tmp_path, SHORT)
    await _first_step_then_quit(tmp_path, devices, world, procedure)
    (first,) = SessionReader(tmp_path / "session").steps()
    devices.stop()  # switched off; switched on again, plugged into another port
    restarted = serve(4)
    served.append(restarted)
    world.switch(restarted)
    config = live_config(tmp_path, restarted)

    app, banner, log = await _resume(tmp_path, config, world, 0,
                                     lambda attitude: restarted.carry(attitude, CARRY_S).result(timeout=60))
    reader, why = _first_step_measured_again(
        tmp_path, app, banner, log, "POWER-CYCLED since the last step",
        "WARNING: the unit was power-cycled since the last completed step (its clock reads")
    assert "power-cycled" in why
    steps = reader.steps()
    assert len(steps) == 3 and steps[0] == first  # the first measurement is kept in the session,
    kept = open_run(reader.directory).steps  # but no longer counted
    assert [s.record.step for s in kept] == [0, 1] and kept[0].record.to_dict() != \
        {k: v for k, v in first.items() if k not in ("skipped", "bench")}
    assert [r.step for r in open_run(reader.directory).completed] == [0, 1]
    # Replayed without the devices: the recorded resume restarts the engine from no step.
    replayed = []
    again = replay(open_run(tmp_path / "session"), report=replayed.append)
    unit, samples = again.unit, again.samples
    assert [e.kind for e in replayed].count("step_complete") == 3 and samples > 0
    assert unit.failures == app.outcome.unit.failures


@run_async
async def test_a_session_another_station_holds_is_not_resumed_and_the_ports_are_closed_again(
        tmp_path, served, monkeypatch):
    """The ports open (the device's clock is read) before the session can be reopened; when it
    cannot be (here another fieldcal holds it), the device is let go, not held open behind an
    ERROR for a retry to open a second time. The session is unchanged."""
    from fieldcal.run.livebench import LiveBench
    from fieldcal.session.capture import SessionWriter

    devices = served[0]
    world = WorldClock(devices)
    config = await _first_step_then_quit(tmp_path, devices, world, two_positions(tmp_path, SHORT))
    closed = []
    close = LiveBench.close
    monkeypatch.setattr(LiveBench, "close", lambda self: (closed.append(self), close(self))[1])
    before = (tmp_path / "session" / "log.jsonl").read_bytes()
    holder = SessionWriter.append_to(tmp_path / "session")  # another station writing it
    try:
        app = FieldcalApp(speed=0, resume=open_run(tmp_path / "session"), config=config, wall_clock=world)
        async with app.run_test(size=(80, 24)) as pilot:
            await until(pilot, lambda: app.source.done.is_set())
            await pilot.press("q")
    finally:
        holder.close()
    assert app.source.outcome.status == "error" and closed == [app.source.bench]
    assert (tmp_path / "session" / "log.jsonl").read_bytes() == before


# A device whose frames carry no clock (VectorNav ASCII), quit after a step and resumed: its
# completed step is measured again, in test_clockless_resume.py's quit-question test (the same
# real-time run, asserted once).


def _first_step_measured_again(tmp_path, app, banner: str, log: str, said: str, logged: str):
    """The banner ``said`` so and the log ``logged`` why, the first step was measured again and
    the run completed: the session's reader and its resume document's why."""
    assert banner.startswith(f"{said}: its gyro turn-on bias may have changed; the 1 completed step is "
                             "measured again")
    assert logged in log
    assert app.outcome.status == "completed" and app.outcome.completed == 2
    reader = SessionReader(tmp_path / "session")
    (resume,) = [d["data"] for d in reader.documents("resume")]
    assert resume["completed_steps"] == [] and resume["dropped"] == [0]
    return reader, resume["why"]


CANNOT_TELL = "CANNOT TELL whether the unit was power-cycled"
NO_CLOCK = "its frames carry no packet counter or time"


# --- the setup screen's offer ------------------------------------------------------------------

@run_async
async def test_the_setup_screen_offers_an_unfinished_session_and_resumes_it(tmp_path, monkeypatch):
    import types

    from fieldcal.cli.tui import resume_maker
    from fieldcal.run.runner import RunSpec, run_headless
    from fieldcal.tui.screens.setup import SetupScreen
    from fieldcal.tui.view import ACTIVE, DONE

    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "xdg"))
    sessions = tmp_path / "sessions"
    spec = RunSpec(two_positions(tmp_path), STATION, seed=5)
    quit_run = FieldcalApp(spec, speed=0, session_dir=sessions / "quit-after-one")
    async with quit_run.run_test(size=(80, 24)) as pilot:
        await until(pilot, lambda: waiting_at(quit_run, 0))
        await pilot.press("r")
        await until(pilot, lambda: waiting_at(quit_run, 1))
        await pilot.press("q", "y")
    assert quit_run.source.done.wait(60.0), "the run's thread never ended"
    run_headless(spec, sessions / "completed")  # ended: not offered
    (sessions / "not-a-session").mkdir()

    def make_run(config, procedure, choice=None):  # pragma: no cover - the test resumes, it never starts
        raise AssertionError("not started")

    args = types.SimpleNamespace(speed=0.0, config=None)
    app = FieldcalApp(setup=(None, make_run, sessions, resume_maker(args)))
    async with app.run_test(size=(80, 24)) as pilot:
        await until(pilot, lambda: isinstance(app.screen, SetupScreen) and bool(app.screen.query("#unfinished")))
        offered = app.screen.unfinished
        assert [(u.path.name, u.done, u.total, u.device) for u in offered] == [("quit-after-one", 1, 2, None)]
        assert app.screen.query_one("#unfinished").value == str(sessions / "quit-after-one")
        await pilot.press("ctrl+r")
        await until(pilot, lambda: waiting_at(app, 1))
        assert app.screen.view.tiles == [DONE, ACTIVE]
        assert str(app.screen.query_one("#banner").render()).startswith("RESUMED after 1 completed step")
        await pilot.press("r")
        await until(pilot, lambda: app.outcome is not None and on_results(app))
    assert app.outcome.status == "completed" and app.outcome.completed == 2
    assert SessionReader(sessions / "quit-after-one").stop_reason == "completed"


# --- the port lost and regained mid-run ---------------------------------------------------------

def without_table(tmp_path, devices, make_config=live_config):
    """``make_config`` without the table: a power cycle of the unit alone (static steps)."""
    path = Path(make_config(tmp_path, devices).path)
    path.write_text(re.sub(r"table:\n(  .*\n)+", "", path.read_text()))
    return load_config(path)


def power_cycle(devices: SimulatedDevices, seed: int) -> SimulatedDevices:
    """The unit switched off and on again on the same port (its by-id link): a new simulated unit,
    its clock from zero and its own turn-on bias, served behind the old one's path."""
    path = Path(devices.imu_url)
    devices.stop()  # its pty closes: the station's port fails
    restarted = serve(seed)
    path.parent.mkdir(exist_ok=True)
    path.symlink_to(os.readlink(restarted.imu_url))
    return restarted


def log_text(app) -> str:
    return " ".join(" ".join(line.text.split()) for line in app.procedure_screen.query_one("#log").lines)


async def _step_one_then(tmp_path, devices, world, procedure, meanwhile, then_step, make_config=live_config,
                         said="regained"):
    """A live run: the first step, ``meanwhile()`` (the port goes and comes back; it returns the
    device serving now), the banner shown once the log has ``said`` it and the run waits for the
    operator at ``then_step``."""
    app = _live_app(tmp_path, without_table(tmp_path, devices, make_config), procedure, world)
    async with app.run_test(size=(80, 24)) as pilot:
        await _first_step(app, pilot, devices, procedure)
        devices = await meanwhile(app, pilot)
        await until(pilot, lambda: said in log_text(app) and waiting_at(app, then_step)
                    and app.telemetry.silent_s is None)  # (not the outage's NO SAMPLES banner)
        banner = str(app.screen.query_one("#banner").render())
        for step in range(then_step, len(procedure.positions)):
            await until(pilot, lambda step=step: waiting_at(app, step))
            devices.carry(procedure.positions[step].attitude, CARRY_S).result(timeout=60)
            await press_and_go_on(pilot, "r")
            await until(pilot, lambda step=step: app.telemetry.step > step or app.outcome is not None)
        await until(pilot, lambda: app.outcome is not None and on_results(app))
        log = log_text(app)
    return app, banner, log


@run_async
async def test_a_unit_power_cycled_mid_run_has_its_completed_steps_measured_again(tmp_path, served):
    """The port is lost and comes back with the unit's clock restarted: the station says so and
    the run starts over, keeping the old step documents but no longer counting them."""
    devices = served[0]
    world = WorldClock(devices)
    procedure = two_positions(tmp_path, SHORT)
    link = Path(devices.imu_url)

    async def switched_off_and_on(app, pilot):
        restarted = power_cycle(devices, 4)
        served.append(restarted)
        world.switch(restarted)
        return restarted

    try:
        app, banner, log = await _step_one_then(tmp_path, devices, world, procedure, switched_off_and_on, 0)
    finally:
        link.unlink(missing_ok=True)
        link.parent.rmdir()
    reader, why = _first_step_measured_again(
        tmp_path, app, banner, log, "POWER-CYCLED while the port was lost",
        "WARNING: the unit was power-cycled while its port was lost (its clock reads")
    assert "power-cycled while its port was lost" in why
    steps = reader.steps()
    assert [s["step"] for s in steps] == [0, 0, 1]  # the first measurement kept in the session,
    assert [s.record.step for s in open_run(reader.directory).steps] == [0, 1]  # but no longer counted
    assert open_run(reader.directory).steps[0].record.to_dict() != \
        {k: v for k, v in steps[0].items() if k not in ("skipped", "bench")}
    replayed = []
    again = replay(open_run(tmp_path / "session"), report=replayed.append)
    unit, samples = again.unit, again.samples
    assert [e.kind for e in replayed].count("step_complete") == 3 and samples > 0
    assert unit.failures == app.outcome.unit.failures


@run_async
async def test_a_unit_power_cycled_with_its_port_open_has_its_completed_steps_measured_again(tmp_path, served):
    """A unit behind a powered adapter (or on its own supply) restarts without its port noticing:
    its clock going back mid-stream tells, and the run starts over as after a regained port."""
    devices = served[0]
    procedure = two_positions(tmp_path, SHORT)

    async def switched_off_and_on(app, pilot):
        devices.power_cycle(4).result(timeout=60)
        return devices

    app, banner, log = await _step_one_then(tmp_path, devices, lambda: devices.world_time, procedure,
                                            switched_off_and_on, 0, said="stayed open")
    reader, why = _first_step_measured_again(
        tmp_path, app, banner, log, "POWER-CYCLED while the port stayed open",
        "WARNING: the unit was power-cycled while its port stayed open (its clock reads")
    assert ": lost" not in log and "regained" not in log  # the port never noticed
    assert [s["step"] for s in reader.steps()] == [0, 0, 1]
    assert [s.record.step for s in open_run(reader.directory).steps] == [0, 1]


def _cable_pulled(devices):
    """``meanwhile`` for ``_step_one_then``: the cable pulled and plugged back, the unit running on."""
    async def cable_pulled_and_plugged_back(app, pilot):
        devices.imu_link.unplug()
        await until(pilot, lambda: ": lost" in log_text(app))
        devices.imu_link.replug()
        return devices
    return cable_pulled_and_plugged_back


@run_async
async def test_a_unit_whose_frames_carry_no_clock_has_its_steps_measured_again_after_a_pulled_cable(
        tmp_path, monkeypatch):
    """VectorNav ASCII: nothing tells whether the unit was cycled while its port was lost. (Its
    reads' arrivals are stamped in the unit's time, as test_clockless_resume's: the rate check
    and the stream's continuity then hold on a loaded machine whose starved simulator falls
    behind the host's clock.)"""
    from tests.test_clockless_resume import CLOCKLESS_SPEED, on_world_time

    # The unit goes on only once the station has read what it sent (waits_for_reader): stamped in
    # the unit's time but served from a starved thread that runs ahead of the reads, the arrivals
    # measured 246.5 Hz (-1.4 %) under two `yes` (CI rehearsal, 2026-11-28 02:20 UTC) and the run
    # was held before its first dwell. So stamped, it runs at CLOCKLESS_SPEED as the other
    # VectorNav runs (in real time it waited 10 s of its 13 s).
    devices = serve(5, "vectornav", CLOCKLESS_SPEED, waits_for_reader=True)
    on_world_time(monkeypatch, devices.arrival_time)
    try:
        app, banner, log = await _step_one_then(tmp_path, devices, WorldClock(devices), two_positions(tmp_path, SHORT),
                                                _cable_pulled(devices), 0, vectornav_config)
    finally:
        devices.stop()
    _, why = _first_step_measured_again(tmp_path, app, banner, log, CANNOT_TELL, NO_CLOCK)
    assert "may have been power-cycled while its port was lost" in why


@run_async
async def test_a_unit_whose_cable_was_pulled_keeps_its_completed_steps(tmp_path, served):
    """The port is lost and comes back with the unit's clock run on: nothing is measured again."""
    devices = served[0]
    world = WorldClock(devices)
    procedure = two_positions(tmp_path, SHORT)

    app, banner, log = await _step_one_then(tmp_path, devices, world, procedure, _cable_pulled(devices), 1)
    assert "POWER-CYCLED" not in banner and "power-cycled" not in log
    assert f"port {devices.imu_url} regained: its clock ran on" in log and "the 1 completed step is kept" in log
    assert app.outcome.status == "completed" and app.outcome.completed == 2
    reader = SessionReader(tmp_path / "session")
    assert list(reader.documents("resume")) == []
    assert [s["step"] for s in reader.steps()] == [0, 1]


# --- resumed at the console (`fieldcal resume SESSION --config`) -------------------------------

class Lines:
    """A stdout the test can wait on: what was written, and an event per awaited text."""

    def __init__(self):
        self.text = ""
        self.changed = threading.Condition()

    def write(self, data: str) -> int:
        with self.changed:
            self.text += data
            self.changed.notify_all()
        return len(data)

    def flush(self) -> None:
        pass

    def wait_for(self, text: str, timeout_s: float = 60.0) -> None:
        with self.changed:
            assert self.changed.wait_for(lambda: text in self.text, timeout_s), f"{text!r} never came"


def test_a_live_session_resumed_at_the_console_after_a_power_cycle_measures_its_steps_again(
        tmp_path, served, monkeypatch, capsys):
    """`fieldcal resume` of a quit live run: the same device-clock check as the terminal UI's
    resume; the operator places the unit and presses Enter."""
    import asyncio
    from concurrent.futures import ThreadPoolExecutor

    from fieldcal.cli.main import main

    devices = served[0]
    procedure = two_positions(tmp_path, SHORT)
    # The host's own clock, as the command uses: a power cycle puts the device's far behind it.
    asyncio.run(_first_step_then_quit(tmp_path, devices, time.time, procedure))
    (first,) = SessionReader(tmp_path / "session").steps()
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "xdg"))  # no remembered setup: --config needed
    assert main(["resume", str(tmp_path / "session")]) == 2
    assert "give its station config (the ports) with --config" in capsys.readouterr().err
    devices.stop()  # switched off; switched on again, plugged into another port
    restarted = serve(4)
    served.append(restarted)
    config = live_config(tmp_path, restarted)

    read, write = os.pipe()
    keys = os.fdopen(write, "w")
    out = Lines()
    monkeypatch.setattr(sys, "stdin", os.fdopen(read, "r"))
    monkeypatch.setattr(sys, "stdout", out)
    with ThreadPoolExecutor(1) as pool:
        status = pool.submit(main, ["resume", str(tmp_path / "session"), "--config", str(config.path),
                                    "--registry", str(tmp_path / "r.sqlite")])
        for position in procedure.positions:
            out.wait_for(f"place the unit in position {position.id}")
            restarted.carry(position.attitude, CARRY_S).result(timeout=60)
            keys.write("\n")
            keys.flush()
        assert status.result(timeout=120) == 1  # two static positions calibrate nothing
    keys.close()
    assert "WARNING: the unit was power-cycled since the last completed step (its clock reads" in out.text
    assert "procedure complete: 2 positions done" in out.text and "solved: nothing" in out.text
    reader = SessionReader(tmp_path / "session")
    assert reader.stop_reason == "completed"
    (resume,) = [d["data"] for d in reader.documents("resume")]
    assert resume["completed_steps"] == [] and resume["dropped"] == [0] and "power-cycled" in resume["why"]
    steps = reader.steps()
    assert [s["step"] for s in steps] == [0, 0, 1] and steps[0] == first


def test_frames_held_at_resume_past_a_regained_port_are_judged_against_those_before_it(tmp_path, served):
    """``first_clock`` holds what it read, a lost and regained port among it: the frames after the
    regain are judged against those before (here the unit restarted: its time went from 100 s
    to 0.5 s in 2 s) and handed out only after the judgement is taken."""
    from types import SimpleNamespace

    from drivers.transport import PORT_REGAINED, PortEvent
    from fieldcal.run.livebench import LiveBench

    def chunk(t):
        return SampleChunk(t=np.array([t - 0.01, t]), triads={"accelerometer": np.zeros((2, 3))})

    class Port:
        """The device's port as read once: stamped chunks (arrival, chunk) and the port's events."""
        parser = SimpleNamespace(device_time=True)  # frames carry the device's time
        counters = SimpleNamespace(discarded_bytes=0, checksum_failures=0, missing_frames=0)
        batches = [([(1.0, chunk(100.0)), (3.0, chunk(0.5))], [PortEvent(PORT_REGAINED, 2.0, gap_s=0.5)])]

        def read_stamped(self):
            return self.batches.pop(0) if self.batches else ([], [])

        def arrival_clock(self):
            return 3.0

    ticks = iter(range(100))
    bench = LiveBench(without_table(tmp_path, served[0]), clock=lambda: float(next(ticks)),
                      wall_clock=lambda: 1000.0)
    bench.connection = Port()
    assert bench.first_clock(timeout_s=10.0, fresh_s=0.5).time_s == 0.5
    first = bench.next_chunks()
    assert [float(c.t[-1]) for c in first] == [100.0]  # the frame before the loss only
    check = bench.take_regain_check()
    assert check.power_cycled is True and bench.judged_port == "was lost"
    assert [float(c.t[-1]) for c in bench.next_chunks()] == [0.5]  # then the one after
