"""Simulator physics against hand-worked kinematics."""
import dataclasses
import math

import numpy as np

from drivers.sim import MimuSimulator, Segment, TriadNoise, TriadTruth
from drivers.sim.device import paper_mimu

G, LAT, OMEGA_E = 9.8, math.radians(40.0), 7.292115e-5
IDEAL = {
    "accelerometer": TriadTruth("specific_force", np.eye(3), np.zeros(3), TriadNoise(0.0)),
    "gyroscope": TriadTruth("angular_rate", np.eye(3), np.zeros(3), TriadNoise(0.0)),
}
# Position 13 of paper Table 2: y east, z north-up, x south-up.
ATTITUDE = np.column_stack([[0, -1, 1], [math.sqrt(2), 0, 0], [0, 1, 1]]) / math.sqrt(2)


def collect(sim, segments):
    chunks = list(sim.run(segments, chunk_len=997))  # odd size: chunk edges mid-segment
    return np.concatenate([c.t for c in chunks]), {
        n: np.concatenate([c.triads[n] for c in chunks]) for n in chunks[0].triads}


def test_at_rest_reads_gravity_up_and_earth_rate():
    sim = MimuSimulator(IDEAL, gravity=G, latitude_rad=LAT, lever_arm=np.zeros(3))
    t, data = collect(sim, [Segment(10.0, ATTITUDE)])
    up_body = ATTITUDE.T @ [0, 0, 1]
    np.testing.assert_allclose(data["accelerometer"], np.tile(G * up_body, (len(t), 1)), atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(data["gyroscope"], axis=1), OMEGA_E, rtol=1e-12)
    np.testing.assert_allclose(data["gyroscope"] @ up_body, OMEGA_E * math.sin(LAT), rtol=1e-12)
    np.testing.assert_allclose(np.diff(t), 1 / 250.0)


def test_whole_turns_average_out_horizontal_earth_rate_and_show_centripetal_force():
    lever = np.array([0.05, -0.02, 0.03])
    sim = MimuSimulator(IDEAL, gravity=G, latitude_rad=LAT, lever_arm=lever)
    rate = math.radians(10.0)
    ramp, turn = 2.0, 36.0  # one turn at 10 °/s is 36 s = 9000 samples
    t, data = collect(sim, [Segment(ramp + turn, ATTITUDE, rate, ramp)])
    steady = t >= ramp
    up_body = ATTITUDE.T @ [0, 0, 1]
    np.testing.assert_allclose(data["gyroscope"][steady].mean(axis=0),
                               (rate + OMEGA_E * math.sin(LAT)) * up_body, atol=1e-12)
    # In body axes the centripetal acceleration is constant: -ω² times the lever arm's component
    # perpendicular to the table axis.
    radial = lever - (lever @ up_body) * up_body
    np.testing.assert_allclose(data["accelerometer"][steady],
                               np.tile(G * up_body - rate**2 * radial, (steady.sum(), 1)), atol=1e-12)
    # During the ramp the tangential acceleration α × r appears as well.
    alpha = rate / ramp
    in_ramp = (t > 0.1) & (t < ramp - 0.1)
    extra = data["accelerometer"][in_ramp] - G * up_body
    assert np.all(np.linalg.norm(extra, axis=1) > 0.9 * alpha * np.linalg.norm(radial))


def test_errors_noise_and_quantisation_are_applied():
    device = paper_mimu(raw_counts=True)
    quiet = {n: dataclasses.replace(t, noise=TriadNoise(0.0), lsb=0.0) for n, t in device.items()}
    noisy_t, noisy = collect(MimuSimulator(device, gravity=G, latitude_rad=LAT, seed=4),
                             [Segment(60.0, ATTITUDE)])
    _, clean = collect(MimuSimulator(quiet, gravity=G, latitude_rad=LAT, seed=4), [Segment(60.0, ATTITUDE)])
    acc = device["accelerometer"]
    np.testing.assert_allclose(clean["accelerometer"][0], acc.K @ (G * ATTITUDE.T @ [0, 0, 1]) + acc.bias)
    assert np.all(noisy["accelerometer"] == np.round(noisy["accelerometer"]))  # whole counts
    # White noise per sample: VRW·√fs through the scale factor, within sampling error.
    white = acc.noise.white * math.sqrt(250.0) * acc.K[0, 0]
    high_pass = np.diff(noisy["accelerometer"][:, 0] - clean["accelerometer"][:, 0]) / math.sqrt(2)
    assert abs(high_pass.std() / math.hypot(white, 1 / math.sqrt(12)) - 1) < 0.03


def test_same_seed_same_samples_other_seed_other_samples():
    device = paper_mimu()
    run = lambda seed: collect(MimuSimulator(device, gravity=G, latitude_rad=LAT, seed=seed),  # noqa: E731
                               [Segment(5.0, ATTITUDE)])[1]["gyroscope"]
    np.testing.assert_array_equal(run(1), run(1))
    assert not np.array_equal(run(1), run(2))


def test_noise_bank_is_the_recursion_on_the_same_draws_across_chunk_sizes():
    """The bank is drawn in closed form a block at a time; it must be the recursion
    x[k] = p·x[k−1] + drive[k] of every Gauss-Markov process on the same random numbers, whatever
    the chunk sizes (chunks carry the state), at 250 Hz and with a chunk longer than a block."""
    from scipy.signal import lfilter

    from drivers.noise import TriadNoise, flicker_bank
    from drivers.sim.noise import NoiseGenerator

    noise, rate = TriadNoise(white=2e-3, bias_instability=4e-4), 250.0
    sizes = [1, 300, 7, 1000, 2]
    chunked = NoiseGenerator(noise, rate, np.random.default_rng(5))
    chunked_out = np.concatenate([chunked.draw(n) for n in sizes])

    rng = np.random.default_rng(5)
    taus, sigmas = flicker_bank(noise.bias_instability)
    poles = np.exp(-1 / rate / taus)
    state = [rng.standard_normal(3) * s for s in sigmas]
    expected = []
    for n in sizes:
        out = rng.standard_normal((n, 3)) * noise.white * np.sqrt(rate)
        for i, (p, s) in enumerate(zip(poles, sigmas)):
            drive = rng.standard_normal((n, 3)) * s * np.sqrt(1 - p**2)
            x, _ = lfilter([1.0], [1.0, -p], drive, axis=0, zi=(p * state[i])[None, :])
            state[i] = x[-1]
            out += x
        expected.append(out)
    expected = np.concatenate(expected)
    scale = np.std(expected)
    np.testing.assert_allclose(chunked_out, expected, rtol=0, atol=1e-12 * scale)


def test_innovation_noise_is_its_recursion_on_the_same_draws_across_chunk_sizes():
    """ŝ[k+1] = p·ŝ[k] + K·e[k], y[k] = Σ ŝ[k] + e[k], sample by sample, against the sub-block
    products the generator uses, whatever the chunk sizes (a partial sub-block, several groups)."""
    from drivers.sim.noise import InnovationNoise

    noises = [TriadNoise(white=2e-3, bias_instability=4e-4), TriadNoise(white=1e-3),
              TriadNoise(white=5e-4, bias_instability=1e-4, rate_random_walk=1e-5)]
    sizes = [1, 300, 7, 1000, 2, 25, 2400, 24, 5000]
    gen = InnovationNoise(noises, 250.0, np.random.default_rng(5))
    state = gen._state.copy()
    drawn = np.concatenate([gen.draw(n) for n in sizes], axis=1)

    rng = np.random.default_rng(5)
    rng.standard_normal((3, len(gen._poles), 3))  # the initial states' draws
    expected, walk = [], np.zeros((3, 3))
    for _ in range(-(-sum(sizes) // gen.BLOCK)):  # drawn a block ahead, (triads, BLOCK, 3)
        e = rng.standard_normal((3, gen.BLOCK, 3)) * gen._sigma_e[:, :, None]
        steps = np.cumsum(rng.standard_normal((3, gen.BLOCK, 3)) * gen._walk_sigma[:, :, None], axis=1)
        for k in range(gen.BLOCK):
            expected.append(state.sum(axis=1) + e[:, k] + walk + steps[:, k])
            state = gen._poles[None, :, None] * state + gen._gain[:, :, None] * e[:, k][:, None, :]
        walk = walk + steps[:, -1]
    expected = np.array(expected).transpose(1, 0, 2)[:, :drawn.shape[1]]
    np.testing.assert_allclose(drawn, expected, rtol=0, atol=1e-12 * np.std(expected))
    assert not np.any(gen._gain[1])  # white noise alone: no bank to drive


def test_innovation_noise_continues_bit_for_bit_from_its_state():
    """A crashed run resumes from get_state: the block drawn ahead is drawn again."""
    from drivers.sim.device import PAPER_NOISE
    from drivers.sim.noise import InnovationNoise

    rng = np.random.default_rng(7)
    gen = InnovationNoise(list(PAPER_NOISE.values()), 250.0, rng)
    gen.draw(3100)
    state, rng_state = gen.get_state(), rng.bit_generator.state
    rng.standard_normal(5)  # the simulator draws the operator's hand from the same generator
    ahead = np.concatenate([gen.draw(n) for n in (250, 2000, 900)], axis=1)

    rng2 = np.random.default_rng(0)
    again = InnovationNoise(list(PAPER_NOISE.values()), 250.0, rng2)
    again.set_state(state)
    rng2.bit_generator.state = rng_state
    rng2.standard_normal(5)
    assert np.array_equal(np.concatenate([again.draw(n) for n in (250, 2000, 900)], axis=1), ahead)


def test_innovation_noise_has_the_law_of_white_noise_plus_the_gauss_markov_bank():
    """Same spectrum as white + bank (so the same stationary Gaussian process), and its states
    start in their stationary law; the paper's noise, where the bank is 1e-3 of the white noise."""
    from drivers.noise import flicker_bank
    from drivers.sim.device import PAPER_NOISE
    from drivers.sim.noise import InnovationNoise

    rate = 250.0
    gen = InnovationNoise(list(PAPER_NOISE.values()), rate, np.random.default_rng(1))
    omega = np.concatenate([[0.0], np.geomspace(1e-9, np.pi, 400)])
    back = np.exp(-1j * omega)[:, None]  # z⁻¹ on the unit circle
    poles = gen._poles
    for t, noise in enumerate(PAPER_NOISE.values()):
        taus, sigmas = flicker_bank(noise.bias_instability)
        np.testing.assert_allclose(poles, np.exp(-1 / rate / taus))
        gains = sigmas**2 * (1 - poles**2)
        bank = noise.white**2 * rate + np.sum(gains / np.abs(1 - poles * back) ** 2, axis=1)
        transfer = 1 + np.sum(gen._gain[t] * back / (1 - poles * back), axis=1)
        innovations = gen._sigma_e[t, 0] ** 2 * np.abs(transfer) ** 2
        np.testing.assert_allclose(innovations, bank, rtol=1e-9)
        start = gen._start_factor[t] @ gen._start_factor[t].T
        after = (poles[:, None] * start * poles[None, :]
                 + np.outer(gen._gain[t], gen._gain[t]) * gen._sigma_e[t, 0] ** 2)
        np.testing.assert_allclose(after, start, rtol=0, atol=1e-9 * np.abs(start).max())


def test_rotations_agree_with_scipy_at_every_angle():
    """The simulator's numpy rotations against scipy's Rotation, from 1e-9 rad to a half turn
    (the hand carries the cube upside down between positions)."""
    from scipy.spatial.transform import Rotation

    from drivers.sim.rotations import matrix_rotvec, rotvec_matrix, z_rotation

    rng = np.random.default_rng(0)
    axes = rng.standard_normal((40, 3))
    axes /= np.linalg.norm(axes, axis=1)[:, None]
    for angle in (1e-9, 1e-5, 1e-3, 0.1, 1.0, 3.0, math.pi - 1e-7):
        rotvecs = axes * angle
        matrices = rotvec_matrix(rotvecs)
        np.testing.assert_allclose(matrices, Rotation.from_rotvec(rotvecs).as_matrix(), rtol=0, atol=1e-15)
        for m, v in zip(matrices, rotvecs):
            np.testing.assert_allclose(matrix_rotvec(m), v, rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.abs(matrix_rotvec(np.diag([1.0, -1.0, -1.0]))), [math.pi, 0, 0], atol=1e-15)
    np.testing.assert_allclose(z_rotation(0.7), Rotation.from_euler("z", 0.7).as_matrix(), rtol=0, atol=1e-15)


def test_window_means_take_samples_from_the_start_inclusive_to_the_end_exclusive():
    """The simulated runs' averaging windows are [start, end) in sample time, worked by hand: at
    1 Hz with values equal to t, [2, 5) averages t = 2, 3, 4 and [5, 8) t = 5, 6, 7, so a sample on
    a shared edge counts once, in the later window. (The other convention, (start, end], gives
    4 and 7.) The chunk edge at t = 5 falls on the window edge too."""
    from drivers.chunk import SampleChunk
    from fieldcal.procedure.averaging import WindowAverager

    t = np.arange(10.0)
    values = np.column_stack([t, 10 * t, -t])
    averager = WindowAverager([5.0, 2.0], [8.0, 5.0])  # given out of order: means in this order
    for part in (slice(0, 5), slice(5, 10)):
        averager.feed(SampleChunk(t=t[part], triads={"accelerometer": values[part]}))
    np.testing.assert_array_equal(averager.counts, [3, 3])
    np.testing.assert_array_equal(averager.means("accelerometer"), [[6.0, 60.0, -6.0], [3.0, 30.0, -3.0]])


def test_window_means_refuse_overlapping_windows_and_a_window_without_samples():
    """What a mutation run of averaging.py found untested (issue 26): windows that overlap or end
    before they start are refused, and means of a window no sample fell in are an error naming
    how many, not a NaN."""
    import pytest

    from drivers.chunk import SampleChunk
    from fieldcal.procedure.averaging import WindowAverager

    for starts, ends in (([0.0, 2.0], [3.0, 5.0]), ([4.0], [3.0])):
        with pytest.raises(ValueError, match="^averaging windows overlap or end before they start$"):
            WindowAverager(starts, ends)
    WindowAverager([0.0, 3.0], [3.0, 5.0])  # touching is not overlapping
    averager = WindowAverager([0.0, 2.0, 4.0, 20.0], [1.0, 3.0, 5.0, 21.0])
    averager.feed(SampleChunk(t=np.arange(10.0), triads={"accelerometer": np.ones((10, 3))}))
    np.testing.assert_array_equal(averager.counts, [1, 1, 1, 0])
    assert averager.counts.dtype.kind == "i"
    with pytest.raises(ValueError, match="^1 averaging windows received no samples$"):
        averager.means("accelerometer")
    single = WindowAverager([0.0], [1.0])  # one sample is a mean
    single.feed(SampleChunk(t=np.arange(10.0), triads={"accelerometer": np.full((10, 3), 2.0)}))
    np.testing.assert_array_equal(single.means("accelerometer"), [[2.0, 2.0, 2.0]])
