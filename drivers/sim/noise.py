"""Drawing sensor noise for the simulator: the Gauss-Markov bank and random walks of a TriadNoise.

The model itself (``TriadNoise``, ``flicker_bank``) lives in ``drivers.noise``, which the station
imports without the simulator.
"""
from __future__ import annotations

import numpy as np

from drivers.noise import TriadNoise, flicker_bank

__all__ = ["NoiseGenerator", "TriadNoise", "flicker_bank"]


class NoiseGenerator:
    """Draws a triad's noise in consecutive blocks, carrying filter state between them."""

    def __init__(self, noise: TriadNoise, rate_hz: float, rng: np.random.Generator):
        self._noise = noise
        self._rng = rng
        dt = 1.0 / rate_hz
        self._white_sigma = noise.white * np.sqrt(rate_hz)
        taus, sigmas = flicker_bank(noise.bias_instability) if noise.bias_instability else ((), ())
        self._poles = np.exp(-dt / np.asarray(taus))
        self._gains = np.asarray(sigmas) * np.sqrt(1 - self._poles**2)
        # Start each process in its stationary distribution.
        self._state = np.array([rng.standard_normal(3) * s for s in sigmas]).reshape(-1, 3)
        # Samples per block of _gauss_markov: the slowest decay over a block stays below e².
        self._block = max(1, int(2.0 / -np.log(self._poles.min()))) if len(self._poles) else 1
        self._power_cache: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self._walk = np.zeros(3)
        self._walk_sigma = noise.rate_random_walk * np.sqrt(dt)

    def get_state(self) -> dict:
        return {"processes": self._state.tolist(), "walk": self._walk.tolist()}

    def set_state(self, state: dict) -> None:
        self._state = np.array(state["processes"], dtype=float).reshape(-1, 3)
        self._walk = np.array(state["walk"], dtype=float)

    def draw(self, n: int) -> np.ndarray:
        out = self._rng.standard_normal((n, 3)) * self._white_sigma
        if len(self._poles):
            # The same draws, in the same order, as one (n, 3) block per process.
            out += self._gauss_markov(self._rng.standard_normal((len(self._poles), n, 3)))
        if self._walk_sigma:
            walk = self._walk + np.cumsum(self._rng.standard_normal((n, 3)) * self._walk_sigma, axis=0)
            self._walk = walk[-1]
            out += walk
        return out

    def _powers(self, m: int) -> tuple[np.ndarray, np.ndarray]:
        """(P, m, 1) p^(k+1) and gain·p^(−k−1) for a block of m samples (chunks repeat sizes)."""
        if m not in self._power_cache:
            decay = (self._poles[:, None] ** np.arange(1, m + 1))[..., None]
            self._power_cache[m] = decay, self._gains[:, None, None] / decay
        return self._power_cache[m]

    def _gauss_markov(self, normal: np.ndarray) -> np.ndarray:
        """Σ over the bank of x[k] = p·x[k−1] + gain·normal[k], carrying the state; (P, n, 3) -> (n, 3).

        All processes at once, a block of samples at a time, by the closed form
        x[k] = p^(k+1)·(x[−1] + Σ_{j≤k} p^(−j−1)·drive[j]): one cumulative sum per block instead
        of a recursive filter per process. Blocks are short enough that p^(−k) stays below e², so
        the rounding is that of the recursion's.
        """
        n = normal.shape[1]
        total = np.empty((n, 3))
        for start in range(0, n, self._block):  # a few blocks per chunk
            d = normal[:, start:start + self._block]
            decay, weight = self._powers(d.shape[1])
            x = decay * (self._state[:, None, :] + np.cumsum(d * weight, axis=1))
            self._state = x[:, -1].copy()
            total[start:start + d.shape[1]] = x.sum(axis=0)
        return total
