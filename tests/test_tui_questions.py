"""Issue 23: every key that ends or discards work asks first, in words that say what would be
lost, and "no" keeps the run going (Textual's Pilot). Enter on the setup screen moves to the
next field; only the start key (or button) starts."""
from __future__ import annotations

from tui_pilot import ask, press_and_go_on, question_asked, run_async, until, waiting_at
from fieldcal.procedure import events as ev
from fieldcal.run.runner import RunSpec, open_run
from fieldcal.tui import FieldcalApp
from fieldcal.tui.readings import Telemetry
from fieldcal.tui.screens.help import HelpScreen
from fieldcal.tui.screens.procedure import ProcedureScreen
from fieldcal.tui.view import RunView, clock_text, duration_words
from tests.test_tui_keys import STATION, confirm_text, three_positions


def sim_app(tmp_path, capture: bool = True) -> FieldcalApp:
    return FieldcalApp(RunSpec(three_positions(), STATION, seed=4), speed=0,
                       session_dir=tmp_path / "s" if capture else None)


async def no_keeps_the_run_going(pilot, app, step: int) -> None:
    """"n" answers the question no: the bar goes, the run waits where it was, and r still works."""
    await pilot.press("n")
    assert confirm_text(app) == ""
    assert app.is_running and app.outcome is None and waiting_at(app, step)
    await pilot.press("r")
    await until(pilot, lambda: waiting_at(app, step + 1))


def recorded_actions(tmp_path) -> list[str]:
    from fieldcal.session.capture import SessionReader

    return [a["action"] for a in SessionReader(tmp_path / "s").actions()]


async def first_position_done(pilot, app) -> None:
    """The operator places the first position and the run waits at the second."""
    await until(pilot, lambda: waiting_at(app, 0))
    await pilot.press("r")
    await until(pilot, lambda: waiting_at(app, 1))


@run_async
async def test_ctrl_q_asks_says_what_is_done_and_that_a_resume_continues_and_no_keeps_going(tmp_path):
    app = sim_app(tmp_path)
    async with app.run_test(size=(80, 24)) as pilot:
        await first_position_done(pilot, app)
        await pilot.press("ctrl+q")
        question = confirm_text(app)
        assert question.startswith("Quit mid-run? 1 of 3 positions done in ")
        assert "a resume continues after the last completed step" in question
        await no_keeps_the_run_going(pilot, app, 1)
        await pilot.press("ctrl+q", "ctrl+q")  # its own key again: yes
        await until(pilot, lambda: not app.is_running)
    assert app.source.done.wait(60.0) and app.source.outcome.status == "stopped"
    assert recorded_actions(tmp_path) == ["ready", "ready"]


@run_async
async def test_ctrl_c_asks_the_same_question_instead_of_telling_to_press_ctrl_q(tmp_path):
    app = sim_app(tmp_path, capture=False)
    async with app.run_test(size=(80, 24)) as pilot:
        await until(pilot, lambda: waiting_at(app, 0))
        await pilot.press("ctrl+c")
        question = confirm_text(app)
        assert question.startswith("Quit mid-run? 0 of 3 positions done")
        assert "Nothing is captured (no session directory): all of it is lost." in question
        await no_keeps_the_run_going(pilot, app, 0)
        await pilot.press("ctrl+c", "y")
        await until(pilot, lambda: not app.is_running)
    assert app.source.done.wait(60.0) and app.source.outcome.status == "stopped"


@run_async
async def test_ctrl_q_and_ctrl_c_over_the_help_come_back_to_the_run_and_ask(tmp_path):
    app = sim_app(tmp_path, capture=False)
    async with app.run_test(size=(80, 24)) as pilot:
        await until(pilot, lambda: waiting_at(app, 0))
        for key in ("ctrl+q", "ctrl+c"):
            await pilot.press("question_mark")
            await until(pilot, lambda: isinstance(app.screen, HelpScreen))
            await pilot.press(key)
            await until(pilot, lambda: isinstance(app.screen, ProcedureScreen))
            assert confirm_text(app).startswith("Quit mid-run?"), key
            await pilot.press("n")
            assert confirm_text(app) == "" and waiting_at(app, 0)
        await no_keeps_the_run_going(pilot, app, 0)


@run_async
async def test_q_asks_and_no_keeps_the_run_going(tmp_path):
    app = sim_app(tmp_path)
    async with app.run_test(size=(80, 24)) as pilot:
        await until(pilot, lambda: waiting_at(app, 0))
        await pilot.press("q")
        assert confirm_text(app).startswith("Quit mid-run? 0 of 3 positions done")
        await no_keeps_the_run_going(pilot, app, 0)


@run_async
async def test_abort_says_the_work_done_and_that_there_is_no_resume_and_no_keeps_going(tmp_path):
    app = sim_app(tmp_path)
    async with app.run_test(size=(80, 24)) as pilot:
        await first_position_done(pilot, app)
        await pilot.press("a")
        question = confirm_text(app)
        assert question.startswith("ABORT the run? 1 of 3 positions done in ") and "no resume" in question
        await no_keeps_the_run_going(pilot, app, 1)
    assert "abort" not in recorded_actions(tmp_path)


@run_async
async def test_skip_asks_and_no_keeps_the_position(tmp_path):
    app = sim_app(tmp_path)
    async with app.run_test(size=(80, 24)) as pilot:
        await until(pilot, lambda: waiting_at(app, 0))
        await pilot.press("s")
        assert confirm_text(app).startswith("Skip position 1?")
        await no_keeps_the_run_going(pilot, app, 0)
    assert recorded_actions(tmp_path) == ["ready"]
    assert app.view.tiles[0] == "done"


@run_async
async def test_redo_is_on_o_away_from_s_and_a_asks_and_no_keeps_the_step(tmp_path):
    app = sim_app(tmp_path)
    async with app.run_test(size=(80, 24)) as pilot:
        await until(pilot, lambda: waiting_at(app, 0))
        await pilot.press("d")  # no longer redo: nothing happens
        assert confirm_text(app) == "" and waiting_at(app, 0)
        await pilot.press("o")
        assert confirm_text(app) == ("Redo position 1 from the placement? Nothing of it is measured yet.  "
                                     "o or y: redo · other key: no")
        await no_keeps_the_run_going(pilot, app, 0)
        await pilot.press("o", "y")
        await until(pilot, lambda: "redo" in recorded_actions(tmp_path))
        assert waiting_at(app, 1)  # (step 2 had not begun: redone from its placement)
    assert recorded_actions(tmp_path) == ["ready", "redo"]


def folded_view(*events, t: float) -> RunView:
    """A view of three positions with 20 s dwells, fed these events, at sample time ``t``."""
    view = RunView(three_positions())
    for e in events:
        view.apply(e)
    view.set_telemetry(Telemetry(t=t, phase="dwell", step=view.step, waiting=False, samples=0))
    return view


def test_redo_skip_and_back_say_how_much_of_the_step_they_drop():
    view = folded_view(ev.StepStarted(0.0, 0, 1, "", 3), ev.StepComplete(50.0, 0, 1),
                       ev.StepStarted(50.0, 1, 2, "", 3), ev.Still(80.0, 1.0), t=92.4)
    assert view.dwell.total == 20  # the procedure's dwell
    assert view.confirmation("redo") == "Redo position 2 from the placement? 12 s of its 20 s dwell would be lost."
    assert view.confirmation("skip") == "Skip position 2? 12 s of its 20 s dwell would be dropped. (u goes back to it)"
    assert view.work_words() == "1 of 3 positions done in 2 min"  # 92 s, rounded to minutes


def live_app(tmp_path, protocol: str, monkeypatch):
    """The UI on a simulated device served on a pty in ``protocol``, with no table."""
    import pytest

    from drivers.sim.device import PAPER_NOISE, paper_mimu
    from drivers.sim.serve import SimulatedDevices
    from fieldcal.cli.tui import live_spec
    from fieldcal.config import load_config
    from tests.test_clockless_resume import CLOCKLESS_SPEED, on_world_time
    from tests.test_tui_live import OPTIONS

    # VectorNav ASCII carries no device time: its rate is measured from its reads' arrivals (as
    # fast as read, the run would be held: issue 23's rate check), stamped here in the unit's own
    # time, which waits for the station's reads (as test_clockless_resume's units). An Xsens
    # served as fast as read floods a run that waits for the operator: each key took the Pilot seconds.
    devices = SimulatedDevices(paper_mimu(), STATION.gravity, STATION.latitude_rad, imu_protocol=protocol,
                               table_protocol=None, speed=CLOCKLESS_SPEED, seed=3, rate_hz=200,
                               waits_for_reader=True)
    on_world_time(monkeypatch, devices.arrival_time)
    devices.start()
    tmp_path.mkdir()
    acc, gyro = PAPER_NOISE["accelerometer"], PAPER_NOISE["gyroscope"]
    path = tmp_path / "bench.yaml"
    path.write_text(f"""\
device:
  name: bench unit
  protocol: {protocol}
  rate_hz: 200
  port: {{url: {devices.imu_url}}}
  triads:
    accelerometer: {{kind: specific_force, unit: m/s^2, noise: {{white: {acc.white!r}, bias_instability: {acc.bias_instability!r}}}}}
    gyroscope: {{kind: angular_rate, unit: rad/s, noise: {{white: {gyro.white!r}, bias_instability: {gyro.bias_instability!r}}}}}
station: {{latitude_deg: 40.0, height_m: 50.0}}
""")
    config = load_config(path)
    if config.device.protocol != protocol:  # pragma: no cover
        pytest.fail(f"the config is not {protocol}")
    app = FieldcalApp(live_spec(config, three_positions(), OPTIONS), 0, tmp_path / "session", config=config)
    return app, devices


@run_async
async def test_the_quit_question_says_when_a_resume_measures_everything_again(tmp_path, monkeypatch):
    """A VectorNav's ASCII frames carry no clock: a resume cannot show the unit stayed powered and
    measures every completed position again (here none is: it starts from the first); an Xsens's
    carry one: a resume can continue."""
    for protocol, words in (("vectornav", "this device's frames carry no clock, so a resume cannot show "
                                          "the unit stayed powered: it starts from the first step."),
                            ("xsens", "a resume continues after the last completed step if the unit "
                                      "stays powered")):
        app, devices = live_app(tmp_path / protocol, protocol, monkeypatch)
        try:
            async with app.run_test(size=(80, 24)) as pilot:
                await until(pilot, lambda: waiting_at(app, 0) and app.source.bench.device_clock is not None)
                # (keys and their effect waited for: a device read all the time never lets
                # Pilot.press see the process idle, 2 s a key)
                assert words in await ask(pilot, "ctrl+q"), protocol
                await press_and_go_on(pilot, "n")
                await until(pilot, lambda: question_asked(app) == "")
                assert app.is_running and waiting_at(app, 0)
                await ask(pilot, "q")
                await press_and_go_on(pilot, "q")
                await until(pilot, lambda: not app.is_running)
        finally:
            devices.stop()
        assert app.source.done.wait(60.0) and app.source.outcome.status == "stopped"


@run_async
async def test_elapsed_does_not_go_back_after_a_resume(tmp_path):
    """A resume continues from the last completed step's sample time; the run had gone on past
    it (the unit carried towards the next position) before it was quit: "elapsed" keeps that."""
    app = sim_app(tmp_path)
    async with app.run_test(size=(80, 24)) as pilot:
        await first_position_done(pilot, app)
        quit_at = app.view.elapsed
        assert quit_at > app.view.placing_s[0]  # (the run has sample time behind it)
        await pilot.press("q", "y")
    assert app.source.done.wait(60.0)
    resumed = FieldcalApp(speed=0, resume=open_run(tmp_path / "s"))
    async with resumed.run_test(size=(80, 24)) as pilot:
        await until(pilot, lambda: waiting_at(resumed, 1))
        assert resumed.view.t < quit_at  # the engine's clock restarts at the last completed step
        assert resumed.view.elapsed >= quit_at
        assert resumed.view.job_text().endswith(f"{clock_text(resumed.view.elapsed)} elapsed, "
                                                f"≈{duration_words(resumed.view.remaining_s())} to go")


def test_elapsed_keeps_counting_when_the_sample_clock_goes_back():
    view = RunView(three_positions())
    for t in (0.0, 30.0, 5.0, 12.0):  # a clock that restarted at 5 s after 30 s
        view.set_telemetry(Telemetry(t=t, step=0, phase="place", waiting=False, samples=0))
    assert view.elapsed == 30.0 + 7.0


@run_async
async def test_the_bell_rings_when_a_step_ends_and_the_banner_says_what_next(tmp_path):
    """Issue 22: the operator, across the bench during a dwell, hears that it is their turn."""
    app = sim_app(tmp_path)
    rings = []
    app.bell = lambda: rings.append(app.view.step)
    async with app.run_test(size=(80, 24)) as pilot:
        await until(pilot, lambda: waiting_at(app, 0))
        assert rings == []  # nothing has ended yet
        await pilot.press("r")
        await until(pilot, lambda: waiting_at(app, 1))
        assert len(rings) == 1
        await pilot.pause()
        assert str(app.screen.query_one("#banner").render()).startswith("Position 2: ")
        await pilot.press("s", "s")  # a skip ends the step too
        await until(pilot, lambda: waiting_at(app, 2))
        assert len(rings) == 2
        await pilot.press("q", "y")
    assert app.source.done.wait(60.0)
    replay = FieldcalApp(None, speed=0, replay=open_run(tmp_path / "s"))  # nobody to call: it stays quiet
    replay.bell = lambda: rings.append("replay")
    async with replay.run_test(size=(80, 24)) as pilot:
        await until(pilot, lambda: replay.outcome is not None)
    assert [e.kind for e in replay.events].count("step_complete") == 1 and "replay" not in rings
