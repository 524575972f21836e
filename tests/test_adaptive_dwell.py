"""Adaptive dwell: the engine ends a dwell once it holds the planned information at the measured
noise level. The rule sees only time and noise: the values being estimated cannot move it."""
import numpy as np
import pytest

from drivers.chunk import SampleChunk
from fieldcal.procedure import events as ev
from fieldcal.procedure.engine import Engine, EngineSettings
from fieldcal.procedure.positions import ProcedureError, parse_procedure
from fieldcal.procedure.stillness import StillnessSettings

RATE_HZ = 100.0
SF_WHITE, RATE_WHITE = 2e-3, 1e-4  # per-sample σ, output units
PROCEDURE = """name: adaptive
dwell_s: 30
adaptive_dwell: {adaptive}
positions:
  - {{id: 1, description: "z-upward", axes: {{x: east, y: north, z: up}}}}
"""


def settings(on_motion="restart"):
    return EngineSettings(rate_hz=RATE_HZ, on_motion=on_motion,
                          stillness=StillnessSettings(specific_force_sigma=SF_WHITE, rate_sigma=RATE_WHITE))


def dwell_end(seed, bias=(0.0, 0.0, 0.0), noise_factor=1.0, adaptive=True, seconds=200,
              bump_at=None, on_motion="restart", chunk_s=1):
    """(sample seconds averaged, sample time the dwell ended), feeding a still unit (z up) in
    chunks of ``chunk_s`` seconds; ``bump_at``: a half-second knock in that second."""
    engine = Engine(parse_procedure(PROCEDURE.format(adaptive=str(adaptive).lower()), "p.yaml"),
                    settings(on_motion))
    engine.start()
    engine.act(ev.Action(ev.READY))
    rng = np.random.default_rng(seed)
    n = int(RATE_HZ * chunk_s)
    for k in range(seconds // chunk_s):
        t = (k * n + np.arange(n)) / RATE_HZ
        sf = np.array([0.0, 0.0, 9.8]) + np.array(bias) + noise_factor * SF_WHITE * rng.standard_normal((n, 3))
        rate = noise_factor * RATE_WHITE * rng.standard_normal((n, 3))
        if k == bump_at:
            sf[:n // 2] += 0.5 * np.sin(np.arange(n // 2))[:, None]
        for e in engine.feed(SampleChunk(t, {"accelerometer": sf, "gyroscope": rate})):
            if isinstance(e, ev.DwellComplete):
                return e.duration_s, e.t
    raise AssertionError("the dwell never ended")


def dwell_length(seed, **kw):
    return dwell_end(seed, **kw)[0]


def test_different_biases_give_identical_dwell_lengths():
    # The same noise draw on very different biases: the rule must not see the values.
    lengths = {dwell_length(7, bias=bias) for bias in ((0.0, 0.0, 0.0), (0.05, -0.08, 0.03), (-0.2, 0.1, 0.4))}
    assert len(lengths) == 1


def test_the_expected_noise_takes_about_the_planned_dwell():
    lengths = [dwell_length(seed) for seed in range(3)]
    assert all(28.0 <= length <= 32.0 for length in lengths), lengths


def test_a_noisier_unit_dwells_longer_in_proportion_to_its_variance():
    # Noise 1.5× the expected σ: 2.25× the planned samples for the same information.
    length = dwell_length(3, noise_factor=1.5)
    assert length == pytest.approx(30.0 * 2.25, rel=0.05)


def test_a_quieter_unit_stops_early_but_not_before_the_minimum():
    assert dwell_length(4, noise_factor=0.7) == pytest.approx(30.0 * 0.49, rel=0.05)
    assert dwell_length(5, noise_factor=0.1) == pytest.approx(settings().min_dwell_s, abs=0.02)


def test_without_the_option_the_dwell_is_the_planned_one_whatever_the_noise():
    assert dwell_length(6, noise_factor=1.5, adaptive=False) == 30.0


def test_the_option_must_be_a_boolean():
    with pytest.raises(ProcedureError, match="adaptive_dwell"):
        parse_procedure(PROCEDURE.format(adaptive="maybe"), "p.yaml")


@pytest.mark.parametrize("on_motion", ["restart", "discard"])
def test_a_bumped_dwell_ends_later_with_the_same_information(on_motion):
    quiet_s, quiet_end = dwell_end(9, on_motion=on_motion)
    bumped_s, bumped_end = dwell_end(9, on_motion=on_motion, bump_at=15)
    # The knock's samples never count, nor does their spread judge the noise level.
    assert bumped_end > quiet_end
    assert bumped_s == pytest.approx(quiet_s, rel=0.05)


def test_a_dwell_judges_the_noise_on_the_chunk_it_is_in():
    # Half the expected noise: a quarter of the variance, so a quarter of the planned 30 s, 7.5 s
    # (above the 5 s floor); the whole dwell lies in one 60-second chunk, whose own samples set it.
    duration, _ = dwell_end(3, noise_factor=0.5, seconds=60, chunk_s=60)
    assert duration == pytest.approx(7.5, abs=0.5)


@pytest.mark.parametrize("bump_at", [None, 8])
def test_a_planned_dwell_reports_progress_every_ten_seconds_of_samples_and_not_at_its_end(bump_at):
    engine = Engine(parse_procedure(PROCEDURE.format(adaptive="false"), "p.yaml"), settings())
    engine.start()
    engine.act(ev.Action(ev.READY))
    rng = np.random.default_rng(4)
    n = int(RATE_HZ)
    events = []
    for k in range(50):
        t = (k * n + np.arange(n)) / RATE_HZ
        sf = np.array([0.0, 0.0, 9.8]) + SF_WHITE * rng.standard_normal((n, 3))
        if k == bump_at:  # a knock in the first half of second 8: the dwell starts again after it
            sf[:n // 2] += 0.5 * np.sin(np.arange(n // 2))[:, None]
        events += engine.feed(SampleChunk(t, {"accelerometer": sf, "gyroscope": RATE_WHITE * rng.standard_normal((n, 3))}))
    motion = [e for e in events if isinstance(e, ev.MotionDetected)]
    if bump_at is not None:
        [knock] = motion
        assert (knock.phase, knock.restarted) == ("dwell", True) and 8.0 <= knock.t < 8.5
    else:
        assert motion == []
    start = [e.t for e in events if isinstance(e, ev.Still)][-1]
    [end] = [e.t for e in events if isinstance(e, ev.DwellComplete)]
    progress = [e for e in events if isinstance(e, ev.DwellProgress)]
    assert [(p.done_s, p.total_s) for p in progress] == [(10.0, 30.0), (20.0, 30.0)]
    # Each reported once its ten seconds of samples are in: in the chunk (1 s) where they were.
    for p in progress:
        assert start + p.done_s - 0.01 <= p.t < start + p.done_s + 1.0
    assert end == pytest.approx(start + 30.0, abs=0.02)
    [window] = engine.records[0].windows
    assert (window.kind, window.rate_deg_s, window.duration) == ("static", 0.0, 30.0)
