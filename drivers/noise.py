"""A triad's noise model: white noise, flicker bias instability, rate random walk.

Bias instability is flicker (1/f) noise, whose Allan deviation is flat at 0.664·B (IEEE Std 952).
It is modelled as a bank of first-order Gauss-Markov processes with log-spaced correlation
times and equal variances, which sums to a 1/f spectrum between the shortest and longest
correlation time. A bank rather than true 1/f keeps generation causal and chunkable (the
simulator, ``drivers.sim.noise``, draws the bank as AR(1) filters with carried state, or as
their Kalman innovations form from one random number per sample) and
keeps the covariance of window averages exact, which the Cramér-Rao bound needs.

numpy only: the station reads this model from its config and weights its solves with it, so it
must not pull in the simulator or scipy.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

# About two processes per decade from 0.5 s to the longest correlation time. With the default
# 5000 s the Allan deviation is flat (ripple < 3 %) from about 5 s to 2000 s, which covers the
# 200 s dwells and field-18's length; past the longest time the bias stops wandering. Where a
# real unit's flicker ends is a modelling choice no Allan plot of a few hours pins down, so it is
# a config value (``flicker_tau_max_s``, README "Bias instability model"), not a constant.
_BANK_PER_DECADE = 2
_BANK_TAU_MIN_S = 0.5
DEFAULT_FLICKER_TAU_MAX_S = 5000.0
# The range a config may give: at least a decade above the shortest process, at most 1e8 s (three
# years; 25 processes).
FLICKER_TAU_MAX_RANGE_S = (10 * _BANK_TAU_MIN_S, 1e8)


def flicker_bank(bias_instability: float, tau_max_s: float = DEFAULT_FLICKER_TAU_MAX_S
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Correlation times (s) and standard deviations of the Gauss-Markov bank for a given B,
    whose slowest process has correlation time ``tau_max_s``.

    A sum of Lorentzians 2 s² τ / (1 + (2π f τ)²) with ln τ spaced by h approximates s²/(2 f h);
    the IEEE Std 952 flicker spectrum is B² / (2π f), hence s² = h B² / π.
    """
    low, high = FLICKER_TAU_MAX_RANGE_S
    if not low <= tau_max_s <= high:
        raise ValueError(f"flicker_tau_max_s: expected {low:g} to {high:g} s, got {tau_max_s!r}")
    n = int(round(np.log10(tau_max_s / _BANK_TAU_MIN_S) * _BANK_PER_DECADE)) + 1
    taus = np.geomspace(_BANK_TAU_MIN_S, tau_max_s, n)
    h = np.log(tau_max_s / _BANK_TAU_MIN_S) / (n - 1)  # ln 10 / 2 when the span is whole half-decades
    sigmas = np.full(n, np.sqrt(h / np.pi) * bias_instability)
    return taus, sigmas


@dataclass(frozen=True)
class TriadNoise:
    """Noise of one triad, per axis, in SI input units (m/s² or rad/s).

    white: random-walk coefficient (VRW or ARW) in unit/√Hz, i.e. unit·√s;
    bias_instability: IEEE Std 952 B in unit; rate_random_walk: unit/√s;
    flicker_tau_max_s: the longest correlation time of the flicker bank (where 1/f stops).
    """

    white: float
    bias_instability: float = 0.0
    rate_random_walk: float = 0.0
    flicker_tau_max_s: float = DEFAULT_FLICKER_TAU_MAX_S

    def bank(self) -> tuple[np.ndarray, np.ndarray]:
        """This triad's flicker bank: correlation times and standard deviations (empty if B = 0)."""
        if not self.bias_instability:
            return np.zeros(0), np.zeros(0)
        return flicker_bank(self.bias_instability, self.flicker_tau_max_s)

    def allan_deviation(self, tau: np.ndarray) -> np.ndarray:
        """Exact Allan deviation of this noise model (white + bank + rate random walk)."""
        tau = np.asarray(tau, dtype=float)
        var = self.white**2 / tau + self.rate_random_walk**2 * tau / 3.0
        if self.bias_instability > 0:
            for c, s in zip(*self.bank()):
                x = tau / c
                var = var + (s**2 * c**2 / tau**2) * (2 * x - 3 + 4 * np.exp(-x) - np.exp(-2 * x))
        return np.sqrt(var)

    def bias_variance(self) -> float:
        """Variance of the bias process (the bank's sum) at any one time, per axis."""
        return float(np.sum(self.bank()[1] ** 2))

    def point_covariance(self, starts: npt.ArrayLike, durations: npt.ArrayLike, t: float) -> np.ndarray:
        """Covariance between the means of one axis over windows [start, start+T) that end by
        ``t`` and the bias process at time ``t``: Σ s² · τ(1 − e^(−T/τ))/T · e^(−(t − start − T)/τ)
        over the bank (white noise is independent of it). The bias at the end of a calibration
        is predicted from its windows with this (DESIGN 12)."""
        if self.rate_random_walk:
            raise ValueError("point covariance is undefined with rate random walk")
        a = np.asarray(starts, dtype=float)
        T = np.asarray(durations, dtype=float)
        gap = t - (a + T)
        if np.any(gap < -1e-9):
            raise ValueError("a window ends after the time the bias is wanted at")
        gap = np.maximum(gap, 0.0)
        out = np.zeros(len(a))
        for c, s in zip(*self.bank()):
            out += s**2 * c * (1 - np.exp(-T / c)) / T * np.exp(-gap / c)
        return out

    def window_covariance(self, starts: npt.ArrayLike, durations: npt.ArrayLike) -> np.ndarray:
        """Covariance between the means of one axis over non-overlapping windows [start, start+T).

        Exact for the continuous-time model (white + Gauss-Markov bank). Rate random walk has no
        stationary covariance and is not supported here.
        """
        if self.rate_random_walk:
            raise ValueError("window covariance is undefined with rate random walk")
        a = np.asarray(starts, dtype=float)
        T = np.asarray(durations, dtype=float)
        cov = np.diag(self.white**2 / T)
        if self.bias_instability > 0:
            diagonal = np.arange(len(a))
            variance = cov[diagonal, diagonal].copy()
            cov += _bank_cross_terms(a, T, *self.bank())
            for c, s in zip(*self.bank()):
                ramp = c * (1 - np.exp(-T / c)) / T
                variance += 2 * s**2 * c / T * (1 - ramp)
            cov[diagonal, diagonal] = variance
        return cov


# Two windows whose bank term has fallen below e^(-_FAR) of its value at no gap share nothing
# (e^-200 ~ 1e-87 of the bias variance: far under any rounding of the sums it enters).
_FAR = 200.0


def _bank_cross_terms(a: np.ndarray, T: np.ndarray, taus: np.ndarray, sigmas: np.ndarray) -> np.ndarray:
    """(m, m) Σ s²·ρᵢ·ρⱼ·e^(−gap/τ) between the means over windows [a, a + T) (diagonal left 0),
    ρ = τ(1 − e^(−T/τ))/T, gap from the earlier window's end to the later one's start (0 where
    they touch within 1e-9 s). Why not e^(−gap/τ) for every pair: m² exponentials per term, ten
    terms (on imu_tk's recording joined 16×, 633 poses: two thirds of a noise estimate). For the
    later window j and the earlier i, e^(−(aⱼ − eᵢ)/τ) = e^(−(aⱼ − P)/τ)·e^((eᵢ − P)/τ) is one
    outer product of m-vectors, its exponents about a pivot P kept within ±_FAR by taking the
    later windows in blocks of _FAR·τ seconds, each with its own pivot (older rows beyond _FAR
    left out), so that nothing overflows and no exponent loses digits to a large time."""
    m = len(a)
    order = np.argsort(a, kind="stable")
    a_s, T_s = a[order], T[order]
    e_s = a_s + T_s
    gaps = a_s[1:] - e_s[:-1]
    if np.any(gaps < -1e-9):
        raise ValueError("windows overlap")
    upper = np.zeros((m, m))
    whole_left, whole_right = [], []  # terms whose one block is every window: one product for all of them
    for c, s in zip(taus, sigmas):
        ramp = c * (1 - np.exp(-T_s / c)) / T_s
        row_scale, column_scale = s**2 * ramp, ramp
        span = _FAR * c
        block = np.floor((a_s - a_s[0]) / span).astype(np.intp)
        cuts = np.flatnonzero(np.diff(block)) + 1
        for lo, hi in zip(np.r_[0, cuts], np.r_[cuts, m]):  # a loop over blocks of windows, not samples
            pivot = a_s[lo]
            first = int(np.searchsorted(e_s, pivot - span))  # rows whose term can still matter
            rows = slice(first, hi - 1)  # the last window of a block has no later one in it
            # Rows up to hi - 2 end by a later window's start (+1e-9): e^((e - P)/τ) ≤ e^_FAR.
            left = row_scale[rows] * np.exp(np.minimum(e_s[rows] - pivot, span) / c)
            right = column_scale[lo:hi] * np.exp(-(a_s[lo:hi] - pivot) / c)
            if not len(cuts):
                whole_left.append(np.r_[left, 0.0])
                whole_right.append(right)
            else:
                upper[rows, lo:hi] += np.multiply.outer(left, right)
    if whole_left:
        upper += np.column_stack(whole_left) @ np.vstack(whole_right)
    # Windows that touch (a gap within 1e-9 s below 0) count as touching, not as overlapping.
    touching = np.flatnonzero(gaps < 0)
    if len(touching):
        i, j = touching, touching + 1
        rho = taus * (1 - np.exp(-T_s[:, None] / taus)) / T_s[:, None]
        upper[i, j] = np.sum(sigmas**2 * rho[i] * rho[j], axis=1)
    out = np.triu(upper, 1)  # below the diagonal: the pairs the other way round, not terms
    out += out.T
    if np.any(order != np.arange(m)):
        back = np.empty(m, dtype=np.intp)
        back[order] = np.arange(m)
        out = out[np.ix_(back, back)]
    return out
