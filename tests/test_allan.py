"""Allan deviation (paper eq. 3) and IEEE Std 952 noise terms against independent truth: a hand-worked
eq. 3, the simulator's exact theoretical ADEV, and the noise parameters the simulator was given."""
import numpy as np
import pytest

from drivers.sim.noise import NoiseGenerator, TriadNoise
from fieldcal.allan import NoiseTerms, allan_deviation, noise_terms, plot_allan

DEG = np.pi / 180.0
MG = 9.80665e-3
# Paper Table 4 noise, converted to SI by hand: VRW 0.06 m/s/sqrt(h) = 0.06/60 m/s^2*sqrt(s),
# ARW 0.15 deg/sqrt(h) = 0.15*pi/180/60 rad/s*sqrt(s), B in mg and deg/h.
ACC = TriadNoise(white=0.06 / 60.0, bias_instability=0.05 * MG)
GYRO = TriadNoise(white=0.15 * DEG / 60.0, bias_instability=0.5 * DEG / 3600.0)
SEEDS = (0, 1, 2, 3)


def record(noise, rate_hz, seconds, seed):
    return NoiseGenerator(noise, rate_hz, np.random.default_rng(seed)).draw(int(rate_hz * seconds))


@pytest.fixture(scope="module")
def acc_curves():
    # 6 h at 10 Hz: the accelerometer's flicker floor is reached from ~100 s (white and floor
    # cross at (N/0.664B)^2 = 9 s), and 6 h puts B's reading scatter at ~3.5 % (1 sigma).
    # 10 Hz is plenty: the white region still spans 0.1-3 s.
    return [allan_deviation(record(ACC, 10.0, 6 * 3600, seed), 10.0) for seed in SEEDS]


def test_eq3_by_hand():
    # y = [1, 3, 2, 5, 4, 0] at 2 Hz; theta_k = dt * sum of the first k samples, theta_0 = 0:
    # theta/dt = [0, 1, 4, 6, 11, 15, 15], N = 7.
    # m = 1 (tau 0.5 s): second differences/dt = y[k+1]-y[k] = 2, -1, 3, -1, -4 -> sum sq 31,
    #   sigma^2 = dt^2 * 31 / (2 * 0.5^2 * (7 - 2)) = 31/10.
    # m = 2 (tau 1 s): 11-8+0 = 3, 15-12+1 = 4, 15-22+4 = -3 -> sum sq 34,
    #   sigma^2 = dt^2 * 34 / (2 * 1^2 * (7 - 4)) = 17/12.
    y = np.array([1.0, 3.0, 2.0, 5.0, 4.0, 0.0])
    taus, adev, n = allan_deviation(y, 2.0, taus=[0.5, 1.0])
    np.testing.assert_allclose(taus, [0.5, 1.0])
    np.testing.assert_allclose(adev, np.sqrt([31 / 10, 17 / 12]), rtol=1e-12)
    np.testing.assert_array_equal(n, [6, 3])
    # Per axis, scale-equivariant, blind to a constant bias; tau = 1.5 s (2 clusters) is dropped.
    taus3, adev3, _ = allan_deviation(np.column_stack([y, 10 * y + 7.0]), 2.0, taus=[0.5, 1, 1.5])
    np.testing.assert_allclose(taus3, [0.5, 1.0])
    np.testing.assert_allclose(adev3, np.sqrt([31 / 10, 17 / 12])[:, None] * [1, 10], rtol=1e-12)


def test_default_taus_and_shapes():
    x = record(TriadNoise(white=1e-3), 100.0, 60, seed=5)
    taus, adev, n = allan_deviation(x, 100.0)
    assert adev.shape == (taus.size, 3)
    assert taus[0] == pytest.approx(0.01) and n.min() >= 9 and np.all(np.diff(taus) > 0)
    per_decade = taus.size / np.log10(taus[-1] / taus[0])
    assert 7 <= per_decade <= 11
    t1, a1, _ = allan_deviation(x[:, 1], 100.0)
    np.testing.assert_allclose(t1, taus)
    np.testing.assert_allclose(a1, adev[:, 1])


def test_adev_matches_theory_within_scatter():
    x = record(ACC, 10.0, 6 * 3600, seed=11)
    taus, adev, n = allan_deviation(x, 10.0, taus=[0.1, 1.0, 10.0, 100.0, 1000.0])
    np.testing.assert_allclose(taus, [0.1, 1.0, 10.0, 100.0, 1000.0])
    # Non-overlapping ADEV from n clusters has relative sd ~ 1/sqrt(2(n-2)) (chi-square with
    # n-2 dof); the overlapping one is no worse. 4 sd bounds 15 comparisons comfortably.
    bound = 4.0 / np.sqrt(2.0 * (n - 2))
    ratio = adev / ACC.allan_deviation(taus)[:, None]
    assert np.all(np.abs(ratio - 1) < bound[:, None]), (ratio, bound)


@pytest.mark.parametrize("seed_index", range(len(SEEDS)))
def test_accelerometer_white_and_bias_instability(acc_curves, seed_index):
    taus, adev, n = acc_curves[seed_index]
    for axis in range(3):
        nt = noise_terms(taus, adev[:, axis], unit="m/s^2", n_clusters=n)
        assert nt.white == pytest.approx(ACC.white, rel=0.10)
        assert nt.bias_instability == pytest.approx(ACC.bias_instability, rel=0.10)
        assert nt.rate_random_walk is None
        assert 100.0 <= nt.tau_at_minimum <= taus[-1]  # past the white/floor crossing at 9 s


def test_accelerometer_floor_is_read_not_bounded(acc_curves):
    """6 h against a white/floor crossing at 9 s: the floor is inside the record, so B is a reading."""
    for taus, adev, n in acc_curves:
        for axis in range(3):
            nt = noise_terms(taus, adev[:, axis], unit="m/s^2", n_clusters=n)
            assert nt.floor_reached
            assert not nt.describe("specific_force")["bias instability"].startswith("≤")


def test_a_dwell_too_short_for_the_gyro_floor_gives_an_upper_bound_only():
    """A 200 s dwell of the paper's gyro (white/floor crossing at (N/0.664B)² ≈ 740 s): the curve
    still falls along its -1/2 line where the record ends, so its lowest point, several times B,
    is stated as an upper bound, never as the bias instability."""
    for seed in SEEDS:
        taus, adev, n = allan_deviation(record(GYRO, 250.0, 200, seed), 250.0)
        for axis in range(3):
            nt = noise_terms(taus, adev[:, axis], unit="rad/s", n_clusters=n)
            assert not nt.floor_reached
            assert nt.bias_instability > 1.5 * GYRO.bias_instability  # what used to be stated as B
            text = nt.describe("angular_rate")["bias instability"]
            assert text.startswith("≤ ") and text.endswith("deg/h (the record is too short to show the floor)")


def test_gyro_angle_random_walk():
    # The paper's gyro hides its floor under white noise until ~700 s, so B is not read here (see
    # the accelerometer test); its ARW comes off the -1/2 line.
    for seed in (0, 1, 2):
        taus, adev, n = allan_deviation(record(GYRO, 10.0, 3 * 3600, seed), 10.0)
        for axis in range(3):
            nt = noise_terms(taus, adev[:, axis], unit="rad/s", n_clusters=n)
            assert nt.white == pytest.approx(GYRO.white, rel=0.10)


def test_white_noise_alone():
    noise = TriadNoise(white=2e-3)
    for seed in (0, 1, 2):
        taus, adev, n = allan_deviation(record(noise, 100.0, 1800, seed), 100.0)
        for axis in range(3):
            nt = noise_terms(taus, adev[:, axis], n_clusters=n)
            assert nt.white == pytest.approx(noise.white, rel=0.03)
            assert nt.rate_random_walk is None


def test_rate_random_walk_recovered():
    # White and random walk cross at sqrt(3)*N/K = 0.17 s, leaving two decades of +1/2 slope.
    noise = TriadNoise(white=1e-3, rate_random_walk=1e-2)
    for seed in (0, 1, 2):
        taus, adev, n = allan_deviation(record(noise, 100.0, 1800, seed), 100.0)
        for axis in range(3):
            nt = noise_terms(taus, adev[:, axis], n_clusters=n)
            assert nt.rate_random_walk is not None
            assert nt.rate_random_walk == pytest.approx(noise.rate_random_walk, rel=0.20)
            assert nt.white == pytest.approx(noise.white, rel=0.05)


def test_describe_in_operator_units():
    gyro = NoiseTerms(white=GYRO.white, bias_instability=GYRO.bias_instability,
                      tau_at_minimum=200.0, rate_random_walk=None, unit="rad/s").describe("angular_rate")
    assert gyro["ARW"] == "0.15 deg/sqrt(h)"
    assert gyro["bias instability"] == "0.5 deg/h"
    assert gyro["RRW"] == "none" and gyro["tau at minimum"] == "200 s"
    acc = NoiseTerms(white=ACC.white, bias_instability=ACC.bias_instability, tau_at_minimum=1e3,
                     rate_random_walk=1e-4, unit="m/s^2").describe("specific_force")
    assert acc["VRW"] == "0.06 m/s/sqrt(h)" and acc["bias instability"] == "0.05 mg"
    # 1e-4 m/s^2/sqrt(s) = 1e-4 / 9.80665e-3 mg/sqrt(s) = 0.0102 mg/sqrt(s) = 0.612 mg/sqrt(h).
    assert acc["acceleration RW"] == "0.612 mg/sqrt(h)"
    with pytest.raises(ValueError):
        NoiseTerms(1.0, 1.0, 1.0, None).describe("magnetic_field")


@pytest.mark.parametrize("samples, rate, taus", [
    (np.array([]), 100.0, None),
    (np.zeros((0, 3)), 100.0, None),
    (np.array([1.0, np.nan, 2.0] * 10), 100.0, None),
    (np.full((20, 3), np.inf), 100.0, None),
    (np.ones((5, 3)), 100.0, None),                 # default taus need 9 clusters
    (np.ones(100), 10.0, [4.0, 5.0]),               # 2 clusters per tau at most
    (np.ones(100), 10.0, [0.01]),                   # shorter than one sample
    (np.ones(100), 0.0, None),
    (np.ones((10, 3, 2)), 100.0, None),
])
def test_bad_input_raises(samples, rate, taus):
    with pytest.raises(ValueError) as err:
        allan_deviation(samples, rate, taus)
    assert "\n" not in str(err.value) and str(err.value)


def test_noise_terms_bad_input():
    with pytest.raises(ValueError):
        noise_terms(np.array([1.0, 2.0, 3.0]), np.array([1.0, 1.0]))
    with pytest.raises(ValueError):
        noise_terms(np.array([1.0, 2.0, 3.0]), np.array([1.0, 0.8, 0.7]))


def test_plot_writes_png(acc_curves, tmp_path):
    taus, adev, n = acc_curves[0]
    terms = [noise_terms(taus, adev[:, j], unit="m/s^2", n_clusters=n) for j in range(3)]
    path = tmp_path / "allan.png"
    plot_allan(taus, adev, terms, path, "accelerometer, simulated 6 h", kind="specific_force")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert path.stat().st_size > 10_000
