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
            later = a[None, :] >= a[:, None]
            gap = np.where(later, a[None, :] - (a[:, None] + T[:, None]),
                           a[:, None] - (a[None, :] + T[None, :]))
            diagonal = np.arange(len(a))
            gap[diagonal, diagonal] = 0.0  # a window with itself: its own term, below
            if np.any(gap < -1e-9):
                raise ValueError("windows overlap")
            np.maximum(gap, 0, out=gap)
            variance = cov[diagonal, diagonal].copy()
            # The cross terms everywhere, the diagonal then set to the windows' own variance: the
            # same sums as masking each term, without an n×n mask and diagonal matrix per term.
            for c, s in zip(*self.bank()):
                ramp = c * (1 - np.exp(-T / c)) / T
                cov += s**2 * np.outer(ramp, ramp) * np.exp(-gap / c)
                variance += 2 * s**2 * c / T * (1 - ramp)
            cov[diagonal, diagonal] = variance
        return cov
