"""Drawing sensor noise for the simulator: the Gauss-Markov bank and random walks of a TriadNoise.

The model itself (``TriadNoise``, ``flicker_bank``) lives in ``drivers.noise``, which the station
imports without the simulator.
"""
from __future__ import annotations

import numpy as np
from scipy.signal import lfilter

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
        self._state = [rng.standard_normal(3) * s for s in sigmas]
        self._walk = np.zeros(3)
        self._walk_sigma = noise.rate_random_walk * np.sqrt(dt)

    def get_state(self) -> dict:
        return {"processes": [x.tolist() for x in self._state], "walk": self._walk.tolist()}

    def set_state(self, state: dict) -> None:
        self._state = [np.array(x, dtype=float) for x in state["processes"]]
        self._walk = np.array(state["walk"], dtype=float)

    def draw(self, n: int) -> np.ndarray:
        out = self._rng.standard_normal((n, 3)) * self._white_sigma
        for i, (pole, gain) in enumerate(zip(self._poles, self._gains)):
            drive = self._rng.standard_normal((n, 3)) * gain
            # x[k] = pole·x[k-1] + drive[k]; zi holds pole·x[-1].
            x, _ = lfilter([1.0], [1.0, -pole], drive, axis=0, zi=(pole * self._state[i])[None, :])
            self._state[i] = x[-1]
            out += x
        if self._walk_sigma:
            walk = self._walk + np.cumsum(self._rng.standard_normal((n, 3)) * self._walk_sigma, axis=0)
            self._walk = walk[-1]
            out += walk
        return out
