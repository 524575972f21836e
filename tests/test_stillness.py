"""Stillness and orientation checks against the simulator and hand-built signals."""
from __future__ import annotations

import math
from itertools import pairwise

import numpy as np
import pytest
from hypothesis import given
from hypothesis import settings as hyp_settings
from hypothesis import strategies as st
from numpy.lib.stride_tricks import sliding_window_view
from scipy.spatial.transform import Rotation

from drivers.chunk import SampleChunk
from drivers.sim import MimuSimulator, Segment
from drivers.sim.device import paper_mimu
from fieldcal.procedure import sliding
from fieldcal.procedure.positions import load_procedure
from fieldcal.run.simrun import plan_procedure
from fieldcal.procedure.stillness import (
    StillnessDetector,
    StillnessSettings,
    angle_between,
    check_orientation,
    closest_positions,
    gravity_direction,
    sliding_std,
)

RATE = 250.0
N = 250  # samples in the default 1 s window at 250 Hz
G, LAT = 9.80, math.radians(40.0)
POSITIONS = load_procedure("field-18").positions
BY_ID = {p.id: p for p in POSITIONS}
DEG = math.pi / 180

# Up direction in body axes for each field-18 position, read off the paper's Table 2 wording
# (an axis "upward" has +1, "north-upward with 45° pitch" +1/√2, ...), not from positions.py.
S = 1 / math.sqrt(2)
PAPER_UP = {1: (0, 0, 1), 2: (0, 0, 1), 3: (0, 0, -1), 4: (0, 0, -1), 5: (0, 1, 0), 6: (0, 1, 0),
            7: (0, -1, 0), 8: (0, -1, 0), 9: (1, 0, 0), 10: (1, 0, 0), 11: (-1, 0, 0),
            12: (-1, 0, 0), 13: (S, 0, S), 14: (-S, 0, -S), 15: (0, S, S), 16: (0, -S, -S),
            17: (S, S, 0), 18: (-S, -S, 0)}
SAME_UP = {i: [j for j in PAPER_UP if PAPER_UP[j] == PAPER_UP[i]] for i in PAPER_UP}


def device(raw_counts=False):
    return {k: v for k, v in paper_mimu(raw_counts=raw_counts).items() if k != "inclinometer"}


def settings_for(dev, **kw):
    a, g = dev["accelerometer"], dev["gyroscope"]
    return StillnessSettings.from_noise(a.noise.white, g.noise.white, RATE, k_sf=a.K, k_rate=g.K,
                                        lsb_sf=a.lsb, lsb_rate=g.lsb, **kw)


def simulate(segments, seed=0, dev=None, chunk_len=25_000):
    sim = MimuSimulator(dev or device(), gravity=G, latitude_rad=LAT, rate_hz=RATE, seed=seed)
    return join(list(sim.run(segments, chunk_len)))


def join(chunks):
    return SampleChunk(t=np.concatenate([c.t for c in chunks]),
                       triads={n: np.concatenate([c.triads[n] for c in chunks]) for n in chunks[0].triads})


def split(chunk, sizes):
    edges = np.cumsum([0] + list(sizes))
    return [SampleChunk(t=chunk.t[a:b], triads={n: v[a:b] for n, v in chunk.triads.items()})
            for a, b in pairwise(edges) if b > a]


def detect(chunk, settings, **kw):
    return StillnessDetector(settings, RATE, **kw).feed(chunk)


def made(accel, gyro, t=None):
    t = np.arange(len(accel)) / RATE if t is None else t
    return SampleChunk(t=t, triads={"accelerometer": accel, "gyroscope": gyro})


# --------------------------------------------------------------------------------- settings


def test_from_noise_gives_the_simulated_per_sample_sigma():
    # Hand value: VRW 0.06 m/s/√h = 0.001 m/s²·√s; at 250 Hz, 0.001·√250 = 0.0158 m/s².
    plain = StillnessSettings.from_noise(0.001, 0.15 * DEG / 60, 250.0)
    np.testing.assert_allclose(plain.specific_force_sigma, [0.001 * math.sqrt(250)] * 3)
    np.testing.assert_allclose(plain.rate_sigma, [0.0025 * DEG * math.sqrt(250)] * 3)
    for raw in (False, True):
        dev = device(raw)
        s = settings_for(dev)
        data = simulate([Segment(40.0, POSITIONS[12].attitude)], seed=3, dev=dev)
        for name, sigma in (("accelerometer", s.specific_force_sigma), ("gyroscope", s.rate_sigma)):
            measured = np.diff(data.triads[name], axis=0).std(axis=0) / math.sqrt(2)
            np.testing.assert_allclose(measured, sigma, rtol=0.03)
    # Quantisation: 1 count on a 6.6-count σ adds 1/12 count² to the variance.
    q = StillnessSettings.from_noise(0.001, 0.001, 250.0, k_sf=415.0, lsb_sf=1.0)
    np.testing.assert_allclose(q.specific_force_sigma, math.sqrt((415 * 0.001 * math.sqrt(250)) ** 2 + 1 / 12))


@pytest.mark.parametrize("kw", [{"enter_factor": 3.0, "leave_factor": 2.0}, {"window_s": 0.0},
                                {"specific_force_sigma": 0.0}, {"rate_sigma": (1.0, -1.0, 1.0)}])
def test_bad_settings_are_refused(kw):
    with pytest.raises(ValueError):
        StillnessSettings(**{"specific_force_sigma": 0.01, "rate_sigma": 0.001, **kw})


# ------------------------------------------------------------------------------ sliding std


@pytest.mark.parametrize("pieces", [False, True])
@pytest.mark.parametrize("n", [2, 7, 250, 999])
def test_sliding_std_is_exact_despite_a_large_offset(n, pieces, monkeypatch):
    if pieces:  # long inputs are worked in pieces; make this one long
        monkeypatch.setattr(sliding, "_PIECE_ROWS", 1000)
    rng = np.random.default_rng(n)
    m = 3001
    x = 1e6 + 0.01 * rng.standard_normal((m, 3))
    x[1500:] += 0.3  # a step inside some windows
    x[:, 1] = 32768.0 + np.round(6.6 * rng.standard_normal(m))  # raw counts around mid-scale
    truth = sliding_window_view(x, n, axis=0).std(axis=-1, ddof=1)
    np.testing.assert_allclose(sliding_std(x, n), truth, rtol=1e-7)
    assert sliding_std(x[: n - 1], n).shape == (0, 3)


# ---------------------------------------------------------------------------------- at rest


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_rest_is_still_after_the_first_window_however_chunked(seed):
    rng = np.random.default_rng(100 + seed)
    dev = device()
    data = simulate([Segment(20.0, POSITIONS[seed * 5].attitude)], seed=seed, dev=dev)
    settings = settings_for(dev)
    whole = detect(data, settings)
    expected = np.arange(len(data)) >= N - 1
    np.testing.assert_array_equal(whole, expected)

    # 1-sample chunks across the first window, then sizes drawn from 1, 7, 250, 5000.
    sizes = [1] * 300
    while sum(sizes) < len(data):
        sizes.append(int(rng.choice([1, 7, 250, 5000])))
    det = StillnessDetector(settings, RATE)
    pieces = [det.feed(c) for c in split(data, sizes)]
    assert all(len(p) == len(c) for p, c in zip(pieces, split(data, sizes)))
    np.testing.assert_array_equal(np.concatenate(pieces), whole)
    assert det.still
    ratios = det.last_ratios
    assert set(ratios) == {"accelerometer", "gyroscope"}
    assert all(np.all((r > 0.7) & (r < 1.4)) for r in ratios.values())


def _eventful_signal():
    """Rest, bumps, a stretch between the factors, a bad sample and a time gap; 0.2 s window."""
    rng = np.random.default_rng(77)
    m = 1600
    x = rng.standard_normal((m, 6)) * np.repeat([0.02, 0.001], 3)
    x[300:304, 0] += 0.5
    x[500:700, 4] += 2.5 * 0.001 * (-1) ** np.arange(200)
    x[800:820, 5] += 0.05
    x[1000, 2] = np.nan
    t = np.arange(m) / RATE + np.where(np.arange(m) >= 1200, 3.0, 0.0)
    settings = StillnessSettings(specific_force_sigma=0.02, rate_sigma=0.001, window_s=0.2)
    return made(x[:, :3], x[:, 3:], t), settings


@hyp_settings(max_examples=40, deadline=None)
@given(st.lists(st.integers(1, 400), min_size=1, max_size=60))
def test_chunking_never_changes_the_answer(sizes):
    chunk, settings = _eventful_signal()
    whole = detect(chunk, settings)
    assert whole[:49].sum() == 0 and whole.any() and not whole.all()
    sizes = sizes + [len(chunk)]  # the rest in one piece
    det = StillnessDetector(settings, RATE)
    np.testing.assert_array_equal(np.concatenate([det.feed(c) for c in split(chunk, sizes)]), whole)


@pytest.mark.parametrize("raw_counts", [False, True])
def test_ten_minutes_of_rest_raise_no_false_alarm(raw_counts):
    dev = device(raw_counts)
    data = simulate([Segment(600.0, POSITIONS[8].attitude)], seed=11, dev=dev)
    out = detect(data, settings_for(dev))
    assert not out[: N - 1].any()
    assert out[N - 1:].all()  # zero transitions to moving in 150 000 samples


def test_first_chunk_shorter_than_the_window_is_not_still():
    dev = device()
    data = simulate([Segment(2.0, POSITIONS[0].attitude)], dev=dev)
    det = StillnessDetector(settings_for(dev), RATE)
    first = det.feed(split(data, [100])[0])
    assert not first.any() and not det.still
    assert np.all(np.isnan(det.last_ratios["accelerometer"]))
    assert det.feed(split(data, [100, 150])[1]).tolist() == [False] * 149 + [True]


# ------------------------------------------------------------------------------------ bumps


def bumped(seed, start, length, force=0.0, rate=0.0):
    dev = device()
    data = simulate([Segment(8.0, POSITIONS[4].attitude)], seed=seed, dev=dev)
    accel, gyro = data.triads["accelerometer"].copy(), data.triads["gyroscope"].copy()
    accel[start:start + length, 0] += force
    gyro[start:start + length, 2] += rate
    return made(accel, gyro), settings_for(dev)


@pytest.mark.parametrize("seed", [0, 1])
def test_a_bump_is_moving_while_in_the_window(seed):
    start, length = 1000, 5
    chunk, settings = bumped(seed, start, length, force=0.5, rate=20 * DEG)
    k = np.arange(len(chunk))
    # Still exactly when the trailing window is complete and holds no bump sample.
    expected = (k >= N - 1) & ((k < start) | (k - N + 1 > start + length - 1))
    np.testing.assert_array_equal(detect(chunk, settings), expected)
    sizes = [600, 401, 1, 3, 700, 7, 10_000]
    det = StillnessDetector(settings, RATE)
    np.testing.assert_array_equal(np.concatenate([det.feed(c) for c in split(chunk, sizes)]), expected)


def test_a_specific_force_bump_alone_is_seen():
    start, length = 1000, 5
    chunk, settings = bumped(4, start, length, force=0.5)
    out = detect(chunk, settings)
    moving = np.flatnonzero(~out[N - 1:]) + N - 1
    # Two 0.5 m/s² samples in 250 of 0.0158 m/s² noise already give a ratio of 3.
    assert start <= moving[0] <= start + 2
    assert moving[-1] == start + length - 1 + N - 1  # still again one full window after it
    assert len(moving) == moving[-1] - moving[0] + 1


@pytest.mark.parametrize("channel", range(6))
def test_any_axis_of_either_triad_breaks_stillness(channel):
    rng = np.random.default_rng(channel)
    settings = StillnessSettings(specific_force_sigma=0.02, rate_sigma=0.001)
    sig = np.array([0.02] * 3 + [0.001] * 3)
    x = rng.standard_normal((2000, 6)) * sig
    x[1000:1500, channel] += 5 * sig[channel] * (-1) ** np.arange(500)
    out = detect(made(x[:, :3], x[:, 3:]), settings)
    assert out[N - 1:1000].all() and not out[1000 + N // 2:1500].any() and out[1500 + N:].all()


def test_hysteresis_keeps_the_state_between_the_factors():
    rng = np.random.default_rng(5)
    sig_f, sig_w = 0.02, 0.001
    settings = StillnessSettings(specific_force_sigma=sig_f, rate_sigma=sig_w)
    seg = 3 * N
    alternate = (-1.0) ** np.arange(seg)
    # Window-std / σ: about 1, 2.5, 4, 2.5, 1 (the alternating parts are exact).
    accel_x = np.concatenate([rng.standard_normal(seg), 2.5 * alternate, 4 * alternate,
                              2.5 * alternate, rng.standard_normal(seg)]) * sig_f
    accel = np.column_stack([accel_x, rng.standard_normal((5 * seg, 2)) * sig_f])
    gyro = rng.standard_normal((5 * seg, 3)) * sig_w
    out = detect(made(accel, gyro), settings)
    assert not out[: N - 1].any()
    assert out[N - 1:2 * seg].all()  # quiet, then 2.5: stays still
    assert not out[2 * seg + N // 2:4 * seg].any()  # 4: moving; then 2.5 again: stays moving
    # Back to noise: still once the 2.5 part falls under ~57 % of the window (ratio < 2).
    assert not out[4 * seg:4 * seg + N // 3].any()
    assert out[4 * seg + 2 * N // 3:].all()


def test_a_gap_in_sample_time_or_a_bad_sample_restarts_the_window():
    dev = device()
    data = simulate([Segment(8.0, POSITIONS[2].attitude)], seed=9, dev=dev)
    settings = settings_for(dev)
    at = 1000
    k = np.arange(len(data))
    expected = (k >= N - 1) & ((k < at) | (k >= at + N - 1))
    gap_t = data.t + np.where(k >= at, 2.0, 0.0)  # 2 s with no samples
    back_t = data.t - np.where(k >= at, 0.5, 0.0)  # time steps backwards
    for t in (gap_t, back_t):
        chunk = made(data.triads["accelerometer"], data.triads["gyroscope"], t)
        np.testing.assert_array_equal(detect(chunk, settings), expected)
        det = StillnessDetector(settings, RATE)  # the gap on a chunk boundary
        np.testing.assert_array_equal(np.concatenate([det.feed(c) for c in split(chunk, [at, 5000])]),
                                      expected)
    gyro = data.triads["gyroscope"].copy()
    gyro[at - 1, 1] = np.nan  # a bad sample: not still there, nor for a window after it
    out = detect(made(data.triads["accelerometer"], gyro), settings)
    np.testing.assert_array_equal(out, (k >= N - 1) & ((k < at - 1) | (k >= at + N - 1)))


def test_missing_triad_is_named_and_the_gyro_can_be_left_out():
    dev = device()
    data = simulate([Segment(3.0, POSITIONS[0].attitude)], dev=dev)
    accel_only = SampleChunk(t=data.t, triads={"accelerometer": data.triads["accelerometer"]})
    with pytest.raises(ValueError, match="gyroscope"):
        detect(accel_only, settings_for(dev))
    out = detect(accel_only, settings_for(dev), angular_rate=None)
    assert out[N - 1:].all() and not out[: N - 1].any()


# ---------------------------------------------------------------------------- rate table


@pytest.mark.parametrize("seed", [0, 1])
def test_a_steady_table_rate_is_still_and_the_ramp_is_not(seed):
    dev = device()
    attitude = POSITIONS[6].attitude
    rest, ramp = 5.0, 2.0
    data = simulate([Segment(rest, attitude), Segment(12.0, attitude, 10 * DEG, ramp)], seed=seed,
                    dev=dev, chunk_len=333)
    out = detect(data, settings_for(dev))
    r0, r1 = int(rest * RATE), int((rest + ramp) * RATE)
    assert out[N - 1:r0].all()
    # The gyro ramp (10 °/s in 2 s) exceeds the leave factor within a fraction of a second, and
    # keeps the window loud until most of it has left the window.
    assert not out[r0 + N // 4:r1 + N // 2].any()
    assert out[r1 + N:].all()
    # The engine tells the settled rate from rest by the mean: about 10 °/s about local up.
    up = attitude.T @ [0, 0, 1]
    steady = data.triads["gyroscope"][r1 + N:] @ up
    assert abs(np.degrees(steady.mean()) - 10.0) < 0.1


# ------------------------------------------------------------------------------- orientation


def position_means(raw_counts, seed=21):
    """Mean accelerometer output over 1 s at each field-18 position placed with 3° errors."""
    plan = plan_procedure(load_procedure("field-18"), RATE, np.random.default_rng(seed),
                          placement_sigma_deg=3.0, with_rate_steps=False)
    dev = device(raw_counts)
    sim = MimuSimulator(dev, gravity=G, latitude_rad=LAT, rate_hz=RATE, seed=seed)
    means = [next(sim.run_segment(Segment(1.0, att))).triads["accelerometer"].mean(axis=0)
             for att in plan.attitudes]
    true_up = plan.attitudes[:, 2, :]
    return np.array(means), true_up, plan.attitudes


def test_angle_between_is_accurate_at_the_extremes():
    assert angle_between([1, 0, 0], [0, 2, 0]) == pytest.approx(90.0)
    assert angle_between([1, 0, 0], [1, 1e-9, 0]) == pytest.approx(math.degrees(1e-9), rel=1e-6)
    assert angle_between([1, 0, 0], [-1, 1e-9, 0]) == pytest.approx(180 - math.degrees(1e-9), rel=1e-12)
    np.testing.assert_allclose(angle_between(np.eye(3), [0, 0, 1]), [90, 90, 0], atol=1e-12)


def test_closest_positions_reports_every_position_sharing_the_up_direction():
    found = closest_positions([0.01, -0.02, 1.0], POSITIONS)
    assert [p.id for p, _ in found] == [1, 2]
    assert found[0][1] == pytest.approx(math.degrees(math.atan(math.hypot(0.01, 0.02))), rel=1e-9)
    wide = closest_positions([0, 0, 1], POSITIONS, tolerance_deg=50)
    assert [p.id for p, _ in wide] == [1, 2, 13, 15]
    assert [round(a) for _, a in wide] == [0, 0, 45, 45]
    assert closest_positions([1, 1, 1], POSITIONS) == []


@pytest.mark.parametrize("raw_counts", [False, True])
def test_every_position_passes_for_itself_and_fails_for_one_90_degrees_away(raw_counts):
    means, true_up, attitudes = position_means(raw_counts)
    if raw_counts:
        directions = gravity_direction(means, zero=32768, sensitivity=415)
        assert all(not check_orientation(gravity_direction(m), p, POSITIONS).ok
                   for m, p in zip(means, POSITIONS) if p.id in (3, 4, 7, 8, 11, 12))
    else:
        directions = gravity_direction(means)
    for d, up, attitude, position in zip(directions, true_up, attitudes, POSITIONS):
        assert angle_between(d, up) < 1.0  # output axes ≈ body axes: mg biases, 1e-4 scale errors
        own = check_orientation(d, position, POSITIONS)
        assert own.ok, own.message
        assert own.angle_deg == pytest.approx(angle_between(d, PAPER_UP[position.id]))
        assert own.angle_deg < 15
        assert position.id in [p.id for p, _ in own.looks_like]
        assert "orientation ok" in own.message

        ninety = [i for i in PAPER_UP if abs(np.dot(PAPER_UP[i], PAPER_UP[position.id])) < 1e-9]
        other = BY_ID[ninety[position.id % len(ninety)]]
        wrong = check_orientation(d, other, POSITIONS)
        assert not wrong.ok
        assert abs(wrong.angle_deg - 90) < 15
        assert [p.id for p, _ in wrong.looks_like] == SAME_UP[position.id]
        names = " or ".join(str(i) for i in SAME_UP[position.id])
        assert f"position {other.id} expects {other.description}" in wrong.message
        assert f"looks like position {names} (" in wrong.message
        assert "\n" not in wrong.message
        # Tilting the body as advised (right-hand rule about a body axis) reaches the expected up:
        # the new attitude is attitude · R, so the new up in body axes is Rᵀ · up.
        turn = Rotation.from_rotvec(math.radians(wrong.angle_deg) * np.array(wrong.tilt_axis))
        assert angle_between((attitude @ turn.as_matrix())[2], PAPER_UP[other.id]) < 1.0


def test_the_message_says_which_way_to_tilt():
    check = check_orientation([0.0, 0.02, 1.0], BY_ID[7], POSITIONS)
    assert not check.ok
    assert check.message.startswith("position 7 expects y-downward, x-east, z-north, but the unit "
                                    "looks like position 1 or 2 (z-upward), 91° away; ")
    assert "tilt it 91° about the body -x axis (right-hand rule) until -y points up" in check.message
    flipped = check_orientation([0.0, 0.0, -1.0], BY_ID[1], POSITIONS)
    assert flipped.angle_deg == pytest.approx(180.0)
    assert "looks like position 3 or 4 (z-downward)" in flipped.message
    assert abs(np.dot(flipped.tilt_axis, [0, 0, 1])) < 1e-12  # any horizontal axis turns it over
    lost = check_orientation([1.0, 0.0, 0.35], BY_ID[1], POSITIONS)
    assert lost.looks_like == () and "like no position" in lost.message
    assert "about the body y axis" in lost.message


def test_the_steady_path_windows_agree_with_sliding_std():
    """The detector's steady path (one reference per piece of new samples) against sliding_std,
    on quiet samples around a large offset and on a turn of the unit, for any number of rows."""
    from fieldcal.procedure.stillness import _trailing_std

    rng = np.random.default_rng(2)
    for rows in (250, 251, 499, 500, 749, 1300):
        quiet = rng.standard_normal((rows, 6)) * 0.01 + 600.0
        turn = quiet + np.linspace(0.0, 400.0, rows)[:, None]
        for x in (quiet, turn):
            expected = sliding_std(x, 250)
            np.testing.assert_allclose(_trailing_std(x, 250), expected, rtol=1e-9, atol=1e-12 * expected.max())


def _window_var_by_definition(x: np.ndarray, n: int, ddof: int) -> np.ndarray:
    """Each window's variance by numpy's own np.var over a view of its n rows (one column at a
    time, to keep the view's temporary small): the definition, independent of the block sums."""
    from numpy.lib.stride_tricks import sliding_window_view

    return np.column_stack([sliding_window_view(x[:, j], n).var(axis=-1, ddof=ddof) for j in range(x.shape[1])])


@pytest.mark.parametrize("m, n, ddof", [(2, 2, 1), (5, 3, 0), (101, 101, 0), (102, 101, 1), (1000, 101, 0),
                                        (999, 7, 1), (40_000, 100, 1)])
def test_window_var_gives_each_windows_variance_by_definition(m, n, ddof):
    rng = np.random.default_rng(m + n)
    x = 32768.0 + rng.normal(0.0, 3.0, (m, 3)).round()  # raw counts: ties and exact zeros too
    x[m // 3: m // 2] += 9.81 * 415.0  # a step inside
    got, expected = sliding._window_var(x, n, ddof), _window_var_by_definition(x, n, ddof)
    assert got.shape == expected.shape == (m - n + 1, 3)
    # the block sums round differently from np.var's two passes: equal to ~1e-9 of the largest
    # variance (a window across the step), exactly 0 where a window holds one value
    np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-9 * expected.max())
    assert np.array_equal(got == 0.0, expected == 0.0)


def test_a_chunk_whose_squares_overflow_is_judged_as_when_fed_whole():
    """Finite samples so large that their squares overflow (the window ratios come out NaN) right
    after a bump: the steady path, which tells a chunk still throughout by its largest ratio, must
    keep the state (moving) as the detector fed everything at once does, not call them still."""
    rng = np.random.default_rng(5)
    x = rng.standard_normal((4 * N, 6)) * np.repeat([0.02, 0.001], 3)
    x[3 * N - 10:3 * N, 0] += 1.0  # a bump at the end of the third chunk: moving
    x[3 * N:] = 1e200 * rng.standard_normal((N, 6))
    chunk = made(x[:, :3], x[:, 3:])
    settings = StillnessSettings(specific_force_sigma=0.02, rate_sigma=0.001)
    with np.errstate(over="ignore", invalid="ignore"):
        assert np.isfinite(x[3 * N:].sum()) and not np.isfinite((x[3 * N:] ** 2).sum())
        whole = detect(chunk, settings)
        det = StillnessDetector(settings, RATE)
        pieces = [det.feed(c) for c in split(chunk, [N] * 4)]
    assert pieces[1].all() and not pieces[2][-1]  # still, then the bump, on the steady path
    assert not pieces[3].any()  # NaN ratios decide nothing: still moving
    np.testing.assert_array_equal(np.concatenate(pieces), whole)
