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


# ---------------------------------------------------------------------------------------------
# The same noise from one random number per sample and axis


def _filter_riccati(poles: np.ndarray, q: np.ndarray, r: float) -> np.ndarray:
    """P of the steady-state one-step predictor of y[k] = Σ_i s_i[k] + v[k] (Var v = r), where
    s_i[k+1] = poles_i·s_i[k] + w_i (Var w_i = q_i): the filter DARE
    P = A P A − A P 1 (1ᵀ P 1 + r)⁻¹ 1ᵀ P A + Q, solved by the structure-preserving doubling
    algorithm (quadratic convergence; poles within 1e-6 of 1 take some 25 doublings)."""
    m = len(poles)
    eye = np.eye(m)
    a = np.diag(poles)
    g = np.full((m, m), 1.0 / r)  # Cᵀ R⁻¹ C with C = 1ᵀ
    h = np.diag(q)
    for _ in range(200):
        w = np.linalg.solve(eye + g @ h, eye)  # (I + G H)⁻¹
        a_w = a @ w
        h = h + a.T @ h @ w @ a
        g = g + a_w @ g @ a.T
        a = a_w @ a
        if np.max(np.abs(a)) < 1e-18:  # A^(2^k): what is left to add is below rounding
            return (h + h.T) / 2
    raise ArithmeticError("the noise bank's Riccati equation did not converge")


class InnovationNoise:
    """The noise of several triads, white + Gauss-Markov bank (+ rate random walk), drawn from
    one normal number per sample and axis instead of one per process.

    White noise plus a bank of first-order Gauss-Markov processes is a Gaussian process with a
    rational spectrum; its innovations (Kalman) form ŝ[k+1] = A ŝ[k] + K e[k], y[k] = 1ᵀŝ[k] + e[k]
    with white e of variance S has exactly the same autocovariance, hence the same distribution,
    when ŝ starts in its stationary law N(0, Σ − P) (Σ: the bank's covariance, P: the Riccati
    solution). The bank has ten times fewer normal numbers to draw this way, which is most of a
    simulated run's cost. The states are carried across draws of any size; the result is the
    recursion on the same draws whatever the sizes, which the tests check.

    ``draw(n)`` gives (n, triads, 3).
    """

    SUB_BLOCK = 25  # samples per small Toeplitz product: 25 multiply-adds per sample and axis

    def __init__(self, noises, rate_hz: float, rng: np.random.Generator):
        self._rng = rng
        dt = 1.0 / rate_hz
        noises = list(noises)
        taus = flicker_bank(1.0)[0] if any(n.bias_instability for n in noises) else np.zeros(0)
        self._poles = np.exp(-dt / taus) if len(taus) else np.zeros(0)
        count = len(self._poles)
        gains, sigma_e, starts = [], [], []
        for noise in noises:
            r = (noise.white**2) * rate_hz
            if not count or not noise.bias_instability:
                gains.append(np.zeros(count))
                sigma_e.append(np.sqrt(r))
                starts.append(np.zeros((count, count)))
                continue
            if r <= 0:
                raise ValueError("bias instability without white noise has no innovations form")
            sigmas = flicker_bank(noise.bias_instability)[1]
            q = sigmas**2 * (1 - self._poles**2)
            p = _filter_riccati(self._poles, q, r)
            s = float(np.sum(p)) + r  # 1ᵀ P 1 + r
            gains.append(self._poles * p.sum(axis=1) / s)
            sigma_e.append(np.sqrt(s))
            # Stationary law of ŝ: Σ − P, factored by its eigenvectors (it is only semi-definite
            # to rounding for the fast processes that the filter tracks closely).
            vals, vecs = np.linalg.eigh(np.diag(sigmas**2) - p)
            starts.append(vecs * np.sqrt(np.maximum(vals, 0.0)))
        self._gain = np.array(gains).reshape(len(noises), count)  # K (T, P)
        self._sigma_e = np.array(sigma_e)[:, None]  # (T, 1)
        # Start each state in its stationary distribution, as the bank does.
        self._start_factor = np.array(starts).reshape(len(noises), count, count)  # (T, P, P)
        self._state = np.einsum("tij,tjc->tic", self._start_factor, rng.standard_normal((len(noises), count, 3)))
        self._walk = np.zeros((len(noises), 3))
        self._walk_sigma = np.array([n.rate_random_walk for n in noises])[:, None] * np.sqrt(dt)
        self._matrices: dict[int, tuple[np.ndarray, ...]] = {}
        self._powers: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}
        self._walking = bool(np.any(self._walk_sigma))

    def get_state(self) -> dict:
        return {"innovations": self._state.tolist(), "walk": self._walk.tolist()}

    def set_state(self, state: dict) -> None:
        self._state = np.array(state["innovations"], dtype=float).reshape(self._state.shape)
        self._walk = np.array(state["walk"], dtype=float).reshape(self._walk.shape)

    def draw(self, n: int) -> np.ndarray:
        e = self._rng.standard_normal((n, len(self._sigma_e), 3)) * self._sigma_e
        out = e.copy()
        if len(self._poles) and n:
            full = n - n % self.SUB_BLOCK
            if full:
                out[:full] += self._bank(e[:full], self.SUB_BLOCK)
            if full < n:
                out[full:] += self._bank(e[full:], n - full)
        if self._walking:
            walk = self._walk + np.cumsum(self._rng.standard_normal(e.shape) * self._walk_sigma, axis=0)
            self._walk = walk[-1]
            out += walk
        return out

    def _bank(self, e: np.ndarray, length: int) -> np.ndarray:
        """1ᵀŝ[k] over sub-blocks of ``length`` samples (len(e) a multiple of it); carries ŝ.

        In a sub-block from state ŝ: 1ᵀŝ[r] = Σ_i p_i^r ŝ_i + Σ_{q<r} h[r−1−q] e[q] with
        h[l] = Σ_i K_i p_i^l (a small Toeplitz product), and ŝ after it is p^L ŝ + Σ_q p^(L−1−q) K e[q].
        The states at the sub-block starts follow the same first-order recursion with poles p^L.
        """
        toeplitz, decay, weight = self._sub_block_matrices(length)
        blocks = len(e) // length
        triads = e.shape[1]
        # (T, L, blocks·3): samples of a sub-block down the rows, sub-blocks and axes across.
        e_t = e.reshape(blocks, length, triads, 3).transpose(2, 1, 0, 3).reshape(triads, length, blocks * 3)
        drive = (weight @ e_t).reshape(triads, -1, blocks, 3)  # (T, P, blocks, 3)
        starts = np.empty_like(drive)
        group = self._group(length)
        for first in range(0, blocks, group):  # one group per chunk of a second or so
            d = drive[:, :, first:first + group]
            before, after = self._group_powers(length, d.shape[2])
            # ŝ at sub-block b (from this group's first) = a^b·(ŝ + Σ_{γ<b} a^(−γ−1)·drive[γ]),
            # a = p^L, by an exclusive cumulative sum; a^(−group) stays below e².
            summed = np.cumsum(d * before, axis=2)
            starts[:, :, first] = self._state
            starts[:, :, first + 1:first + d.shape[2]] = (after[:, 1:] * (self._state[:, :, None] + summed[:, :, :-1]))
            self._state = after[:, -1] * self._pole_power(length) * (self._state + summed[:, :, -1])
        bank = toeplitz @ e_t + decay @ starts.reshape(triads, len(self._poles), blocks * 3)
        return bank.reshape(triads, length, blocks, 3).transpose(2, 1, 0, 3).reshape(len(e), triads, 3)

    def _pole_power(self, length: int) -> np.ndarray:
        return (self._poles ** length)[:, None]

    def _group(self, length: int) -> int:
        """Sub-blocks per closed-form group: the fastest decay over a group stays below e²."""
        return max(1, int(2.0 / (length * -np.log(self._poles.min()))))

    def _group_powers(self, length: int, blocks: int) -> tuple[np.ndarray, np.ndarray]:
        """(P, blocks, 1) a^(−γ−1) and a^b for a = p^length."""
        key = (length, blocks)
        if key not in self._powers:
            a = self._poles[:, None] ** length
            self._powers[key] = (a ** -(np.arange(blocks) + 1.0))[..., None], (a ** np.arange(blocks))[..., None]
        return self._powers[key]

    def _sub_block_matrices(self, length: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(T, L, L) strictly lower Toeplitz of h, (L, P) p^r and (T, P, L) K·p^(L−1−q)."""
        if length not in self._matrices:
            powers = self._poles[None, :] ** np.arange(length)[:, None]  # (L, P): p^r
            h = self._gain @ powers.T  # (T, L): h[l]
            lag = np.arange(length)[:, None] - np.arange(length)[None, :] - 1
            toeplitz = np.where(lag >= 0, h[:, np.maximum(lag, 0)], 0.0)
            weight = self._gain[:, :, None] * powers[::-1].T[None]
            self._matrices[length] = toeplitz, powers, weight
        return self._matrices[length]
