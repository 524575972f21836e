"""The engine as a state machine, on the simulator through the conductor: discard mode, redo,
abort, rate direction."""
import numpy as np
import pytest

from fieldcal.procedure import events as ev
from fieldcal.earth import Station
from fieldcal.procedure.positions import parse_procedure
from fieldcal.run.conductor import Conductor, Operator, Place, Subscriber
from fieldcal.run.runner import RunSpec, SimulatedBench

SHORT = """name: short
dwell_s: 20
rate_step: {rate_deg_s: 10, turns: 1, ramp_s: 2, settle_s: 1}
positions:
  - {id: 1, description: "z-upward", axes: {x: south, y: east, z: up}}
  - {id: 2, description: "y-upward", axes: {x: east, y: up, z: south}}
"""


class EventLog(Subscriber):
    def __init__(self):
        self.events = []

    def event(self, e, run):
        self.events.append(e)


class Harness:
    """A conductor on the simulated bench, its moves made by the test one at a time."""

    def __init__(self, seed=1, on_motion="restart"):
        self.spec = RunSpec(parse_procedure(SHORT, "short.yaml"), Station(40.0, 50.0), seed=seed,
                            on_motion=on_motion)
        self.bench = SimulatedBench(self.spec)
        self.log = EventLog()
        self.conductor = Conductor(self.spec, self.bench, Operator(), [self.log])
        self.conductor.start()

    @property
    def engine(self):
        return self.conductor.engine

    @property
    def events(self):
        return self.log.events

    def feed(self, chunks):
        for chunk in chunks:
            self.conductor.feed(chunk)

    def act(self, name):
        self.conductor.act(ev.Action(name))

    def place(self):
        self.conductor.do(Place(self.engine.position.attitude))
        self.act(ev.READY)

    def run_until(self, kind, limit_s=400):
        start = len(self.events)
        for _ in range(int(limit_s)):
            if any(e.kind == kind for e in self.events[start:]):
                return next(e for e in self.events[start:] if e.kind == kind)
            self.feed([self.bench.next_chunk()])
        raise AssertionError(f"no {kind} within {limit_s} s")


def test_discard_mode_keeps_the_undisturbed_part_of_the_dwell():
    durations = {}
    for mode in ("restart", "discard"):
        h = Harness(on_motion=mode)
        h.place()
        still = h.run_until("still")
        while h.engine._average.n < 10 * 250:  # halfway through the 20 s dwell
            h.feed([h.bench.next_chunk()])
        before = len(h.events)
        h.feed(h.bench.bump())
        motion = next(e for e in h.events[before:] if e.kind == "motion_detected")
        assert motion.restarted is (mode == "restart")
        durations[mode] = h.run_until("dwell_complete").t - still.t
    # Restarting needs a fresh 20 s after the bump; discarding keeps the ~9 s before it.
    assert durations["restart"] - durations["discard"] == pytest.approx(9.0, abs=1.5)


def test_redo_throws_away_the_step_and_asks_again():
    h = Harness()
    h.place()
    h.run_until("still")
    h.act(ev.REDO)
    assert [e.kind for e in h.events[-2:]] == ["step_started", "place_unit"]
    assert h.engine.step == 0 and not h.engine.records
    h.place()
    h.run_until("step_complete")
    assert 0 in h.engine.records


def test_abort_stops_the_table_and_the_engine():
    h = Harness()
    h.place()
    h.run_until("command_table")  # dwell done, table told to turn
    h.act(ev.ABORT)
    assert [e.kind for e in h.events[-2:]] == ["command_table", "aborted"]
    assert h.events[-2].rate_deg_s == 0.0
    assert h.engine.feed(h.bench.next_chunk()) == [] and h.engine.act(ev.Action(ev.READY)) == []


def test_a_steady_turn_the_wrong_way_never_counts_as_settled():
    h = Harness()
    h.place()
    h.run_until("rate_step_complete")  # +10 °/s done; the engine now commands -10 °/s
    assert h.events[-1].kind == "command_table" and h.events[-1].rate_deg_s == -10.0
    h.bench.command_table(+10.0)  # a miswired table keeps turning +10 °/s
    for _ in range(60):
        h.feed([h.bench.next_chunk()])
        h.bench.command_table(+10.0)
    assert not any(e.kind == "rate_settled" and e.rate_deg_s < 0 for e in h.events)


def test_a_whole_short_procedure_gives_one_record_per_step_with_the_windows():
    h = Harness()
    for _ in range(2):
        h.place()
        h.run_until("step_complete")
    assert [e.kind for e in h.events[-2:]] == ["procedure_complete", "solved"]  # concluded once
    windows, averages = h.engine.windows_and_averages()
    assert [w.kind for w in windows] == ["static", "plus", "minus"] * 2
    assert [w.duration for w in windows] == [20.0, 36.0, 36.0] * 2
    # The static averages point along local up in body axes: z, then y.
    acc = averages["accelerometer"][[0, 3]]
    assert np.argmax(np.abs(acc[0])) == 2 and np.argmax(np.abs(acc[1])) == 1


def test_no_static_dwell_on_a_turning_table():
    h = Harness()
    h.bench.command_table(10.0)  # a table nobody stopped, at the procedure's rate
    h.act(ev.READY)
    for _ in range(30):
        h.feed([h.bench.next_chunk()])
    turning = [e for e in h.events if e.kind == "table_turning"]
    assert len(turning) == 1 and turning[0].rate_deg_s == pytest.approx(10.0, abs=0.1)
    assert not any(e.kind in ("still", "dwell_complete") for e in h.events)
    h.bench.command_table(0.0)  # stopped: the dwell can start
    h.run_until("still")


def test_a_run_that_cannot_progress_is_aborted_not_endless(tmp_path):
    import dataclasses

    from fieldcal.run.runner import run_headless
    from fieldcal.procedure.stillness import StillnessSettings

    class NeverStill(RunSpec):
        def engine_settings(self):
            settings = super().engine_settings()
            s = settings.stillness
            strict = StillnessSettings(specific_force_sigma=s.specific_force_sigma, rate_sigma=s.rate_sigma,
                                       enter_factor=0.01, leave_factor=0.02)
            return dataclasses.replace(settings, stillness=strict)

    spec = NeverStill(parse_procedure(SHORT, "short.yaml"), Station(40.0, 50.0))
    reasons = []
    result = run_headless(spec, tmp_path / "s", lambda e: reasons.append(getattr(e, "reason", "")))
    assert result.aborted
    assert any("cannot make progress" in r for r in reasons)


def test_too_low_a_sample_rate_is_refused_before_any_file(tmp_path):
    from fieldcal.run.runner import run_headless

    spec = RunSpec(parse_procedure(SHORT, "short.yaml"), Station(40.0, 50.0), rate_hz=2.0)
    with pytest.raises(ValueError, match="rate_hz: 2 Hz gives 2 samples"):
        run_headless(spec, tmp_path / "s")
    assert not (tmp_path / "s").exists()


def test_the_stillness_window_needs_ten_samples_and_ten_are_enough():
    from fieldcal.procedure.engine import EngineSettings
    from fieldcal.procedure.stillness import StillnessSettings

    one_second = StillnessSettings(specific_force_sigma=2e-3, rate_sigma=1e-4, window_s=1.0)
    assert EngineSettings(rate_hz=10.0, stillness=one_second).rate_hz == 10.0  # 10 samples: enough
    with pytest.raises(ValueError, match=r"rate_hz: 9 Hz gives 9 samples per 1 s stillness window; "
                                         r"at least 10 are needed"):
        EngineSettings(rate_hz=9.0, stillness=one_second)
    with pytest.raises(ValueError, match=r"on_motion: expected 'restart' or 'discard', got 'ignore'"):
        EngineSettings(rate_hz=10.0, stillness=one_second, on_motion="ignore")
