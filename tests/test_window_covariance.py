"""TriadNoise.window_covariance: the covariance of window means under white noise plus the flicker
bank, built from one outer product per term and block of windows (not an exponential per pair):
against the double integral of the Gauss-Markov autocovariance, and against every pair's own
exponential on long, unordered, touching and epoch-timed windows."""
import math

import numpy as np
import pytest

from drivers.noise import TriadNoise


def pairwise(noise: TriadNoise, a: np.ndarray, T: np.ndarray) -> np.ndarray:
    """The model term by term and pair by pair: e^(-gap/τ) for every pair (a different method)."""
    m = len(a)
    cov = np.zeros((m, m))
    taus, sigmas = noise.bank()
    for i in range(m):
        for j in range(m):
            if i == j:
                cov[i, i] = noise.white**2 / T[i] + sum(
                    2 * s**2 * c / T[i] * (1 - c * (1 - math.exp(-T[i] / c)) / T[i]) for c, s in zip(taus, sigmas))
                continue
            early, late = (i, j) if a[i] < a[j] else (j, i)
            gap = max(a[late] - a[early] - T[early], 0.0)
            cov[i, j] = sum(s**2 * c * (1 - math.exp(-T[i] / c)) / T[i] * c * (1 - math.exp(-T[j] / c)) / T[j]
                            * math.exp(-gap / c) for c, s in zip(taus, sigmas))
    return cov


def test_two_windows_covary_as_the_double_integral_of_the_banks_autocovariance():
    noise = TriadNoise(white=0.0, bias_instability=1.0, flicker_tau_max_s=50.0)
    a, T = np.array([3.0, 10.0]), np.array([2.0, 4.0])
    # The mean of s²·e^(-|t-u|/τ) over t in one window and u in the other, as a single integral
    # over the lag (the pairs at lag x make a trapezoid's length L(x)), by the midpoint rule.
    def mean_over(first, second, T1, T2, lags):
        x = first + (np.arange(lags) + 0.5) / lags * (second - first)
        if T1 is None:  # a window with itself: L(x) = T - |x|
            L, norm = T2 - np.abs(x), T2 * T2
        else:
            g = first
            L, norm = np.clip(np.minimum.reduce([x - g, np.full_like(x, T1), np.full_like(x, T2),
                                                  g + T1 + T2 - x]), 0, None), T1 * T2
        return sum(s**2 * np.sum(L * np.exp(-np.abs(x) / c)) * (second - first) / lags / norm
                   for c, s in zip(*noise.bank()))
    gap = a[1] - a[0] - T[0]
    cross = mean_over(gap, gap + T[0] + T[1], T[0], T[1], 200_000)
    own = mean_over(-T[0], T[0], None, T[0], 200_000)
    cov = noise.window_covariance(a, T)
    assert cov[0, 1] == cov[1, 0] == pytest.approx(cross, rel=1e-8)
    assert cov[0, 0] == pytest.approx(own, rel=1e-8)


@pytest.mark.parametrize("t0, tau_max", [(0.0, 5000.0), (1.7e9, 5000.0), (250.0, 1e8), (0.0, 5.0)])
def test_many_windows_match_every_pairs_own_exponential(t0, tau_max):
    rng = np.random.default_rng(7)
    m = 150
    T = rng.uniform(2.0, 30.0, m)
    gaps = rng.uniform(0.5, 60.0, m)
    gaps[[10, 11, 40]] = [-5e-10, 0.0, 1e-12]  # touching windows (a timestamp's rounding apart)
    a = t0 + np.cumsum(T + gaps) - T  # some 5,000 s: the short terms need blocks, the long ones not
    order = rng.permutation(m)  # not in time order
    noise = TriadNoise(white=0.2, bias_instability=0.9, flicker_tau_max_s=tau_max)
    got = noise.window_covariance(a[order], T[order])
    want = pairwise(noise, a[order], T[order])
    off = ~np.eye(m, dtype=bool)
    # Either way a gap is known to the times' last bit (2.4e-7 s at epoch seconds), each term to
    # that over its τ (0.5 s the shortest); and ρ = τ(1 − e^(−T/τ))/T to its last bit times τ/T.
    taus = noise.bank()[0]
    timing = 4 * np.spacing(a.max()) / taus.min() + 4e-16 * taus.max() / T.min()
    np.testing.assert_allclose(got[off], want[off], rtol=1e-11 + timing, atol=1e-12 * np.abs(want).max())
    # The diagonal (unchanged by the blocks) has 1 - e^(-T/τ) and then 1 - ρ ≈ T/2τ cancel for the
    # long terms: numpy's exp and math's differ in their last bit, magnified (τ/T)² times.
    cancel = 1e-15 * (noise.bank()[0].max() / T.min()) ** 2
    np.testing.assert_allclose(np.diag(got), np.diag(want), rtol=1e-11 + cancel)
    assert np.array_equal(got, got.T)


def test_overlapping_windows_are_still_refused():
    noise = TriadNoise(white=0.1, bias_instability=0.5)
    with pytest.raises(ValueError, match="overlap"):
        noise.window_covariance([0.0, 5.0, 1.0], [2.0, 2.0, 2.0])
