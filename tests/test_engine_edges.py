"""The engine's edges, each against a hand-worked value: the dwell's white-noise sums, the stretch
a bump drops, the step "unskip" returns to, a resumed run's clock, the time a turning table is
seen, the counts' sensitivity in the orientation check, the tolerance's boundary in any order and
the gyro's part in stillness (the mutation sample of fieldcal/procedure/engine.py of 2026-11-28,
docs/benchmarks.md, found these unguarded). Fed noiseless synthetic samples whose every number
is known."""
import math

import numpy as np
import pytest

from drivers.chunk import SampleChunk
from fieldcal.procedure import events as ev
from fieldcal.procedure.engine import DWELL, PLACE, SETTLING, Engine, EngineSettings, _Average, skipped_to_return_to
from fieldcal.procedure.positions import parse_procedure
from fieldcal.procedure.stillness import StillnessSettings
from fieldcal.procedure.windows import STATIC, StepRecord, WindowRecord

RATE_HZ = 100.0
G = 9.8
Z_UP = """name: one
dwell_s: 5
{extra}
positions:
  - {{id: 1, axes: {{x: east, y: north, z: up}}}}
  - {{id: 2, axes: {{x: up, y: north, z: west}}}}
"""


def engine(extra: str = "", **settings) -> Engine:
    stillness = StillnessSettings(specific_force_sigma=settings.pop("sf_sigma", 2e-3), rate_sigma=1e-4)
    return Engine(parse_procedure(Z_UP.format(extra=extra), "one.yaml"),
                  EngineSettings(rate_hz=RATE_HZ, stillness=stillness, **settings))


def chunk(first: int, sf, rate, n: int = 100) -> SampleChunk:
    """n samples from sample `first` on, each triad the same row (or rows) throughout."""
    return SampleChunk(np.arange(first, first + n) / RATE_HZ,
                       {"accelerometer": np.broadcast_to(np.asarray(sf, float), (n, 3)).copy(),
                        "gyroscope": np.broadcast_to(np.asarray(rate, float), (n, 3)).copy()})


def feed(e: Engine, sf, rate, seconds: int, first: int = 0) -> list[ev.Event]:
    out = []
    for k in range(seconds):
        out += e.feed(chunk(first + k * int(RATE_HZ), sf, rate))
    return out


def test_the_white_noise_level_counts_the_differences_inside_each_stretch():
    # Samples alternating ±(1, 2, 3): every sample-to-sample difference is ±2·(1, 2, 3), so the
    # per-sample white variance Σd²/(2·count) is 2·(1, 4, 9), however the samples are split into
    # stretches; two stretches of 10 hold 9 + 9 differences (none across their boundary).
    sign = (-1.0) ** np.arange(20)
    values = sign[:, None] * np.array([1.0, 2.0, 3.0])
    samples = SampleChunk(np.arange(20) / RATE_HZ, {"accelerometer": values, "gyroscope": values})
    average = _Average(track_noise=True)
    average.add(samples, 0, 10)
    average.add(samples, 10, 20)
    np.testing.assert_allclose(average.white_variance("accelerometer"), [2.0, 8.0, 18.0], rtol=1e-15)


def test_a_stretch_reaching_the_disturbed_time_goes_with_it():
    # Two stretches of ten samples, the second ending at 0.19 s: the disturbed stretch from 0.19 s
    # on holds its last sample, so only the first stretch (mean of samples 0..9) is kept.
    values = np.arange(20.0)[:, None] * np.ones(3)
    samples = SampleChunk(np.arange(20) / RATE_HZ, {"accelerometer": values})
    average = _Average()
    average.add(samples, 0, 10)
    average.add(samples, 10, 20)
    average.drop_after(float(samples.t[19]))
    assert average.n == 10
    assert average.means() == {"accelerometer": [4.5, 4.5, 4.5]}


def test_unskip_from_a_skipped_step_goes_to_the_last_one_after_it():
    # "the nearest one before step, else the last one after it": the current step is not before itself
    assert skipped_to_return_to({2, 4}, 2) == 4


def test_a_resumed_run_with_nothing_done_starts_at_time_zero():
    e = engine()
    e.restore([])
    started = e.start()
    assert [(x.kind, x.t) for x in started] == [("step_started", 0.0), ("place_unit", 0.0)]


def test_a_turning_table_is_reported_at_the_sample_that_ends_the_check():
    # One sample a chunk: the check of 0.5 s ends at a sample of this very chunk, so the event
    # carries that chunk's one time (the gyro reads the full 10 °/s table rate: turning).
    e = engine("rate_step: {rate_deg_s: 10, turns: 1, ramp_s: 2, settle_s: 1}")
    e.start()
    e.act(ev.Action(ev.READY))
    turning = []
    for k in range(300):
        one = chunk(k, (0.0, 0.0, G), (0.0, 0.0, math.radians(10.0)), n=1)
        turning += [(x, float(one.t[0])) for x in e.feed(one) if isinstance(x, ev.TableTurning)]
    assert len(turning) == 1
    event, fed_at = turning[0]
    assert event.t == fed_at
    assert event.rate_deg_s == pytest.approx(10.0, rel=1e-12)


def test_raw_counts_are_divided_by_each_axis_sensitivity_before_the_orientation_check():
    # Tilted 5° about x from z up; y counts 400 per m/s², z 100: the counts alone would point
    # atan(4·tan 5°) = 19.3° from z, beyond the 15° tolerance; the sensitivities undo that.
    tilt = math.radians(5.0)
    counts = 32768.0 + np.array([100.0, 400.0, 100.0]) * G * np.array([0.0, math.sin(tilt), math.cos(tilt)])
    e = engine(sf_sigma=(0.5, 2.0, 0.5), sf_zero=(32768.0,) * 3, sf_sensitivity=(100.0, 400.0, 100.0))
    e.start()
    e.act(ev.Action(ev.READY))
    still = [x for x in feed(e, counts, (0.0, 0.0, 0.0), 3) if x.kind in ("still", "wrong_orientation")]
    assert [x.kind for x in still] == ["still"]
    assert still[0].angle_to_expected_deg == pytest.approx(5.0, abs=1e-9)


def resumed_any_order(tolerance_deg: float) -> Engine:
    """Any order, step 0 (z up) done: where it was measured is where the unit is taken to rest."""
    e = engine("any_order: true", tolerance_deg=tolerance_deg)
    e.restore([StepRecord(0, 1, (WindowRecord(STATIC, 0.0, 5.0, 0.0, {"accelerometer": [0.0, 0.0, G]}),))])
    e.start()
    return e


def test_a_unit_exactly_at_the_tolerance_from_where_the_last_step_rested_is_not_placed_yet():
    # Still at 45° between z (where step 0 rested) and x (position 2), never moved, tolerance 45°:
    # the boundary counts as "still where it was", as it counts as "in" a position.
    e = resumed_any_order(45.0)
    out = feed(e, (5.0, 0.0, 5.0), (0.0, 0.0, 0.0), 3, first=600)
    assert not any(isinstance(x, ev.PositionRecognised) for x in out)
    assert e.phase == PLACE and e._detector is not None  # judged, and waiting for a move
    e = resumed_any_order(45.0)  # the same unit, moved first and then still there: position 2
    e.feed(SampleChunk(np.arange(600, 700) / RATE_HZ,
                       {"accelerometer": G * np.sin(np.arange(100) / 5.0)[:, None] * np.ones(3),
                        "gyroscope": np.zeros((100, 3))}))
    out = feed(e, (5.0, 0.0, 5.0), (0.0, 0.0, 0.0), 3, first=700)
    assert [(x.step, x.position_id) for x in out if isinstance(x, ev.PositionRecognised)] == [(1, 2)]
    assert e.phase == DWELL


def test_stillness_watches_the_gyro_too():
    # The accelerometer reads a steady 1 g while the gyro swings ±0.01 rad/s, 100 times its
    # stated noise: not still. The same with a quiet gyro: still.
    swing = 1e-2 * np.sin(np.arange(100) / 3.0)[:, None] * np.array([1.0, 1.0, 1.0])
    e = engine()
    e.start()
    e.act(ev.Action(ev.READY))
    out = feed(e, (0.0, 0.0, G), swing, 5)
    assert not any(x.kind == "still" for x in out) and e.phase == SETTLING
    e = engine()
    e.start()
    e.act(ev.Action(ev.READY))
    assert [x.kind for x in feed(e, (0.0, 0.0, G), (0.0, 0.0, 0.0), 5) if x.kind == "still"] == ["still"]


QUARTER_TURN = math.radians(90.0)  # the table's 90 °/s in rad/s
RATE_STEP = "rate_step: {rate_deg_s: 90, turns: 1, ramp_s: 3, settle_s: 2}"  # one turn: 4 s, 400 samples


class Bench:
    """The unit z up on a table, fed one-second chunks from sample `k` on; every event kept."""

    def __init__(self, e: Engine):
        self.e, self.k, self.events = e, 0, []

    def second(self, gyro_z, sf=(0.0, 0.0, G)) -> list[ev.Event]:
        gyro = np.zeros((100, 3))
        gyro[:, 2] = gyro_z
        out = self.e.feed(chunk(self.k, sf, gyro))
        self.k += 100
        self.events += out
        return out

    def until(self, kind: str, gyro_z, limit_s: int = 20) -> ev.Event:
        for _ in range(limit_s):
            found = [x for x in self.second(gyro_z) if x.kind == kind]
            if found:
                return found[0]
        raise AssertionError(f"no {kind} within {limit_s} s")

    def after(self, event: ev.Event) -> list[ev.Event]:
        return self.events[next(i for i, x in enumerate(self.events) if x is event) + 1:]


def turned(rate_error: float = 0.02) -> tuple[Bench, ev.Event, ev.Event]:
    """Placed, dwelt, and the table turning at +90 °/s (its gyro reading `rate_error` high) until
    the +ω window is complete: (bench, rate_settled, rate_step_complete)."""
    b = Bench(engine(RATE_STEP))
    b.e.start()
    b.e.act(ev.Action(ev.READY))
    b.until("dwell_complete", 0.0)
    assert [x.rate_deg_s for x in b.events if x.kind == "command_table"] == [90.0]
    settled = b.until("rate_settled", (1 + rate_error) * QUARTER_TURN)
    return b, settled, b.until("rate_step_complete", (1 + rate_error) * QUARTER_TURN)


def test_a_rate_within_its_tolerance_settles_and_one_turn_is_averaged():
    # 2 % off the commanded 90 °/s is inside the 3 % tolerance; one turn at 90 °/s is 4 s: 400
    # samples, the first at the settled time, the last 3.99 s later, where −90 °/s is commanded.
    b, settled, complete = turned()
    assert (settled.rate_deg_s, settled.window_s) == (90.0, 4.0)
    assert complete.t - settled.t == pytest.approx(3.99, abs=1e-9)
    assert [(x.kind, x.t, x.rate_deg_s) for x in b.after(complete) if x.kind == "command_table"] \
        == [("command_table", complete.t, -90.0)]
    minus = b.until("rate_step_complete", -1.02 * QUARTER_TURN)
    stop = [x for x in b.after(minus) if x.kind in ("command_table", "step_complete")]
    assert [(x.kind, x.t) for x in stop] == [("command_table", minus.t), ("step_complete", minus.t)]
    plus_window = b.e.records[0].windows[1]
    assert (plus_window.start, plus_window.duration, plus_window.rate_deg_s) == (settled.t, 4.0, 90.0)


def test_a_rate_off_by_more_than_its_tolerance_never_settles():
    b = Bench(engine(RATE_STEP))
    b.e.start()
    b.e.act(ev.Action(ev.READY))
    b.until("dwell_complete", 0.0)
    for _ in range(10):
        b.second(1.04 * QUARTER_TURN)  # 4 % fast: outside the 3 %
    assert not any(x.kind == "rate_settled" for x in b.events)


def test_a_bump_while_the_turns_are_averaged_restarts_them():
    b = Bench(engine(RATE_STEP))
    b.e.start()
    b.e.act(ev.Action(ev.READY))
    b.until("dwell_complete", 0.0)
    b.until("rate_settled", QUARTER_TURN)
    b.second(QUARTER_TURN)
    bump_at = b.k + 50  # the second half of the next second is shaken
    sf = np.tile([0.0, 0.0, G], (100, 1))
    sf[50:] += np.sin(np.arange(1, 51) / 2.0)[:, None] * np.array([1.0, -1.0, 0.5])
    motion = [x for x in b.second(QUARTER_TURN, sf=sf) if x.kind == "motion_detected"]
    assert [(x.t, x.phase, x.restarted) for x in motion] == [(bump_at / RATE_HZ, "rate", True)]
    assert b.e.phase == "rate_wait"
    again = b.until("rate_settled", QUARTER_TURN)
    complete = b.until("rate_step_complete", QUARTER_TURN)
    assert again.t > bump_at / RATE_HZ and complete.t - again.t == pytest.approx(3.99, abs=1e-9)


def stopped_table_any_order(rate_step: str = RATE_STEP) -> Bench:
    """Any order, z up: the one step measured with its rate step, the table then slowing from
    −90 °/s to a stop in one second (RATE_STEP's ramp_s is 3, settle_s 2)."""
    b = Bench(engine(f"any_order: true\n{rate_step}"))
    b.e.start()
    b.until("dwell_complete", 0.0)
    b.until("rate_step_complete", QUARTER_TURN)
    b.until("step_complete", -QUARTER_TURN)
    b.second(np.linspace(-QUARTER_TURN, 0.0, 100))
    return b


def test_a_table_slowing_to_a_stop_is_not_the_operator_moving_the_unit():
    # Left where step 1 was measured (z up, no remaining position there): the gyro's swing while
    # the table stops is no move, so the engine waits to be placed and says nothing.
    b = stopped_table_any_order()
    for _ in range(4):
        b.second(0.0)
    assert b.e.phase == PLACE
    assert not any(x.kind == "wrong_orientation" for x in b.events)
    b = stopped_table_any_order()  # the same, then moved by hand once the table has stopped
    for _ in range(4):
        b.second(0.0)
    b.second(0.0, sf=np.tile([0.0, 0.0, G], (100, 1)) + np.sin(np.arange(100) / 2.0)[:, None])
    for _ in range(3):
        b.second(0.0)
    assert [x.looks_like for x in b.events if x.kind == "wrong_orientation"] == [(1,)]


def test_a_resumed_run_starts_at_the_first_step_neither_done_nor_skipped():
    three = Engine(parse_procedure(Z_UP.format(extra="") + "  - {id: 3, axes: {x: north, y: west, z: up}}\n",
                                   "three.yaml"),
                   EngineSettings(rate_hz=RATE_HZ, stillness=StillnessSettings(specific_force_sigma=2e-3,
                                                                              rate_sigma=1e-4)))
    done = StepRecord(0, 1, (WindowRecord(STATIC, 0.0, 5.0, 0.0, {"accelerometer": [0.0, 0.0, G]}),))
    three.restore([done])
    assert three.start()[0].step == 1
    three.restore([done], skipped=[1])
    assert three.start()[0].step == 2


def test_a_resumed_any_order_run_takes_the_unit_to_rest_where_the_last_measured_step_was():
    # Step 0 (z up) measured last, at 20 s; step 1 (x up) before it, at 10 s: the unit left z up
    # is still where it was measured, not placed anywhere new, whatever the steps' order.
    e = Engine(parse_procedure(Z_UP.format(extra="any_order: true") + "  - {id: 3, axes: {x: north, y: up, z: east}}\n",
                               "three.yaml"),
               EngineSettings(rate_hz=RATE_HZ, stillness=StillnessSettings(specific_force_sigma=2e-3, rate_sigma=1e-4)))
    e.restore([StepRecord(0, 1, (WindowRecord(STATIC, 15.0, 5.0, 0.0, {"accelerometer": [0.0, 0.0, G]}),)),
               StepRecord(1, 2, (WindowRecord(STATIC, 5.0, 5.0, 0.0, {"accelerometer": [G, 0.0, 0.0]}),))])
    e.start()
    out = feed(e, (0.0, 0.0, G), (0.0, 0.0, 0.0), 3, first=2000)
    assert e.phase == PLACE and not any(x.kind == "wrong_orientation" for x in out)


def test_a_table_found_turning_again_after_it_stopped_is_reported_again():
    # Turning at 90 °/s when first still: reported; stopped: still, the dwell starts; a bump, and
    # the table found turning at the next check: reported a second time.
    b = Bench(engine(RATE_STEP))
    b.e.start()
    b.e.act(ev.Action(ev.READY))
    for _ in range(3):
        b.second(QUARTER_TURN)
    b.until("still", 0.0)
    b.second(0.0, sf=np.tile([0.0, 0.0, G], (100, 1)) + np.sin(np.arange(1, 101) / 2.0)[:, None])
    for _ in range(3):
        b.second(QUARTER_TURN)
    assert [x.kind for x in b.events if x.kind in ("table_turning", "still", "motion_detected")] \
        == ["table_turning", "still", "motion_detected", "table_turning"]


def test_a_step_starts_by_naming_its_position_in_the_files_words():
    # Position 1 has no description: its attitude in the procedure files' words.
    e = engine()
    assert [(x.kind, x.description) for x in e.start()] == [("step_started", "z-upward, x-east, y-north"),
                                                            ("place_unit", "z-upward, x-east, y-north")]


def in_small_chunks(e: Engine, sf: np.ndarray, first: int) -> list[ev.Event]:
    """sf (n, 3) fed ten samples a chunk (a quiet gyro), from sample `first` on."""
    out = []
    for k in range(0, len(sf), 10):
        out += e.feed(SampleChunk(np.arange(first + k, first + k + 10) / RATE_HZ,
                                  {"accelerometer": sf[k:k + 10], "gyroscope": np.zeros((10, 3))}))
    return out


def test_a_unit_lifted_during_the_check_and_put_back_counts_as_moved_however_small_the_chunks():
    # Any order, resumed where step 0 (z up) rested: still 1.2 s (the first second is the
    # detector's first window, then the check begins), lifted for 0.2 s, put back: moved, so the
    # position is judged, and z up is no remaining position.
    e = resumed_any_order(15.0)
    z_up = np.tile([0.0, 0.0, G], (120, 1))
    lifted = np.array([0.0, 0.0, G]) + np.sin(np.arange(1, 21) / 2.0)[:, None] * np.ones(3)
    out = in_small_chunks(e, np.vstack([z_up, lifted, np.tile([0.0, 0.0, G], (300, 1))]), first=600)
    assert [x.looks_like for x in out if x.kind == "wrong_orientation"] == [(1,)]


def test_the_rest_of_a_resumed_raw_count_step_is_taken_without_its_zero():
    # Counts: 400 a m/s² around 32768 on every axis. Step 0 rested z up (32768 + 400·g on z);
    # the unit still there is where it was measured: waiting to be placed, no complaint.
    e = engine("any_order: true", sf_sigma=0.8, sf_zero=(32768.0,) * 3, sf_sensitivity=(400.0,) * 3)
    counts = 32768.0 + 400.0 * np.array([0.0, 0.0, G])
    e.restore([StepRecord(0, 1, (WindowRecord(STATIC, 0.0, 5.0, 0.0, {"accelerometer": counts.tolist()}),))])
    e.start()
    out = feed(e, counts, (0.0, 0.0, 0.0), 3, first=600)
    assert e.phase == PLACE and not any(x.kind == "wrong_orientation" for x in out)


def test_still_and_the_dwell_are_stamped_with_their_last_samples():
    # Noiseless from sample 0: still from sample 99 (the first full 1 s window), the 0.5 s check
    # is samples 99..148, the 5 s dwell 149..648.
    e = engine()
    e.start()
    e.act(ev.Action(ev.READY))
    out = feed(e, (0.0, 0.0, G), (0.0, 0.0, 0.0), 8)
    assert [(x.kind, x.t) for x in out if x.kind in ("still", "dwell_complete")] == [("still", 1.48),
                                                                                    ("dwell_complete", 6.48)]
    assert e.records[0].windows[0].start == 1.49


def test_a_raw_count_gyro_at_its_zero_is_a_table_at_rest():
    # The gyro reads 32768 counts at rest, 1000 a rad/s: a table at rest, not one turning.
    e = engine(RATE_STEP, rate_zero=(32768.0,) * 3, rate_sensitivity=(1000.0,) * 3)
    e.start()
    e.act(ev.Action(ev.READY))
    out = feed(e, (0.0, 0.0, G), (32768.0,) * 3, 3)
    assert [x.kind for x in out if x.kind in ("still", "table_turning")] == ["still"]


def test_a_unit_moved_while_the_table_is_still_stopping_is_moved():
    # Recognised as left where step 0 was measured, then lifted from the last sample of a second
    # on, for 0.3 s, and put back, all (the detector's window after it included) well before the
    # table's stop time (ramp 3 s + settle 8 s) is over: the lift was the operator's, and z up,
    # once it is still again, is no remaining position.
    b = stopped_table_any_order("rate_step: {rate_deg_s: 90, turns: 1, ramp_s: 3, settle_s: 8}")
    stopped_at = next(x.t for x in b.events if x.kind == "step_complete")
    for _ in range(3):
        if b.e.phase == PLACE and b.e._detector is not None:  # judged: still where it was measured
            break
        b.second(0.0)
    assert b.e.phase == PLACE and b.e._detector is not None
    lifted_from = (b.k + 99) / RATE_HZ
    lift = np.tile([0.0, 0.0, G], (200, 1))
    lift[99:129] += np.sin(np.arange(1, 31) / 2.0)[:, None]
    b.second(0.0, sf=lift[:100])
    b.second(0.0, sf=lift[100:])
    assert b.k / RATE_HZ + 1.0 < stopped_at + 11.0  # (the point: the lift and its window before the stop time)
    for _ in range(3):
        b.second(0.0)
    wrong = [x for x in b.events if x.kind == "wrong_orientation"]
    assert [x.looks_like for x in wrong] == [(1,)] and wrong[0].t > lifted_from + 0.3
