"""Drawing sensor noise for the simulator: the Gauss-Markov bank and random walks of a TriadNoise.

``InnovationNoise`` (the simulator's default) draws it from one normal number per sample and
axis; ``NoiseGenerator`` draws one per process, as the simulator did before (sessions recorded
then resume with it, and the simulated hand-held recordings, drivers.sim.handheld, use it).

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
        taus, sigmas = noise.bank()
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

    def bias_now(self) -> np.ndarray:
        """The bias process (bank + rate random walk, no white noise) at the last sample drawn,
        per axis: the bank's own states, so exact."""
        return self._state.sum(axis=0) + self._walk

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
    solution). Ten times fewer normal numbers are drawn this way, and drawing them was most of
    a simulated run's cost. The states are carried across draws of any size; the result is the
    recursion on the same draws whatever the sizes, which the tests check.

    Samples are drawn BLOCK at a time; ``draw(n)`` gives the next n, (triads, n, 3).
    """

    SUB_BLOCK = 25  # samples per small Toeplitz product: 25 multiply-adds per sample and axis
    BLOCK = 2500  # samples drawn ahead (a multiple of SUB_BLOCK)

    def __init__(self, noises, rate_hz: float, rng: np.random.Generator):
        self._rng = rng
        dt = 1.0 / rate_hz
        noises = list(noises)
        flickering = [n for n in noises if n.bias_instability]
        if len({n.flicker_tau_max_s for n in flickering}) > 1:
            raise ValueError("the innovations form shares one flicker bank: give every triad the same "
                             "flicker_tau_max_s (or draw with the bank)")
        taus = flickering[0].bank()[0] if flickering else np.zeros(0)
        self._poles = np.exp(-dt / taus) if len(taus) else np.zeros(0)
        count = len(self._poles)
        gains, sigma_e, starts, filtered = [], [], [], []
        for noise in noises:
            r = (noise.white**2) * rate_hz
            if not count or not noise.bias_instability:
                gains.append(np.zeros(count))
                sigma_e.append(np.sqrt(r))
                starts.append(np.zeros((count, count)))
                filtered.append(0.0)
                continue
            if r <= 0:
                raise ValueError("bias instability without white noise has no innovations form")
            sigmas = noise.bank()[1]
            q = sigmas**2 * (1 - self._poles**2)
            p = _filter_riccati(self._poles, q, r)
            s = float(np.sum(p)) + r  # 1ᵀ P 1 + r
            gains.append(self._poles * p.sum(axis=1) / s)
            sigma_e.append(np.sqrt(s))
            # Var of the bank's sum given every sample up to now: 1ᵀ(P − P1 1ᵀP / S)1.
            filtered.append(max(float(np.sum(p)) - float(np.sum(p)) ** 2 / s, 0.0))
            # Stationary law of ŝ: Σ − P, factored by its eigenvectors (it is only semi-definite
            # to rounding for the fast processes that the filter tracks closely).
            vals, vecs = np.linalg.eigh(np.diag(sigmas**2) - p)
            starts.append(vecs * np.sqrt(np.maximum(vals, 0.0)))
        self._gain = np.array(gains).reshape(len(noises), count)  # K (T, P)
        self._filtered_sigma = np.sqrt(np.array(filtered))[:, None]  # (T, 1)
        self._sigma_e = np.array(sigma_e)[:, None]  # (T, 1)
        # Start each state in its stationary distribution, as the bank does.
        self._start_factor = np.array(starts).reshape(len(noises), count, count)  # (T, P, P)
        self._state = np.einsum("tij,tjc->tic", self._start_factor, rng.standard_normal((len(noises), count, 3)))
        self._walk = np.zeros((len(noises), 3))
        self._walk_sigma = np.array([n.rate_random_walk for n in noises])[:, None] * np.sqrt(dt)
        self._matrices: tuple | None = None
        self._walking = bool(np.any(self._walk_sigma))
        self._block: np.ndarray | None = None  # (T, BLOCK, 3), drawn ahead
        self._innovations: np.ndarray | None = None  # its e, and the walk's path (for bias_now)
        self._walk_path: np.ndarray | None = None
        self._offset = 0
        self._block_start = (self._state.copy(), self._walk.copy(), None)

    def get_state(self) -> dict:
        """JSON-able: the states and the generator's state before the current block was drawn,
        and how much of the block is used (the block is drawn again on ``set_state``)."""
        return {"innovations": self._block_start[0].tolist(), "walk": self._block_start[1].tolist(),
                "rng": self._block_start[2], "offset": self._offset}

    def set_state(self, state: dict) -> None:
        self._state = np.array(state["innovations"], dtype=float).reshape(self._state.shape)
        self._walk = np.array(state["walk"], dtype=float).reshape(self._walk.shape)
        self._block, self._offset = None, 0
        self._block_start = (self._state.copy(), self._walk.copy(), None)
        if state.get("rng") is not None:
            rng = np.random.Generator(type(self._rng.bit_generator)())
            rng.bit_generator.state = state["rng"]
            self._next_block(rng)
            self._offset = int(state["offset"])

    def draw(self, n: int) -> np.ndarray:
        """The next n samples, (triads, n, 3): often a view of the block drawn ahead, so do not
        write to it."""
        parts = []
        while n > 0:
            if self._block is None or self._offset == self.BLOCK:
                self._next_block(self._rng)
            take = min(n, self.BLOCK - self._offset)
            parts.append(self._block[:, self._offset:self._offset + take])
            self._offset += take
            n -= take
        if len(parts) == 1:
            return parts[0]
        return np.concatenate(parts, axis=1) if parts else np.zeros((len(self._sigma_e), 0, 3))

    def _next_block(self, rng: np.random.Generator) -> None:
        """Draw BLOCK samples ahead, (T, BLOCK, 3): a chunk then costs a slice, not the dozen
        numpy calls of the bank's products."""
        self._block_start = (self._state.copy(), self._walk.copy(), rng.bit_generator.state)
        shape = (len(self._sigma_e), self.BLOCK, 3)
        e = rng.standard_normal(shape)
        e *= self._sigma_e[:, :, None]
        out = self._bank(e) if len(self._poles) else e.copy()
        out += e
        if self._walking:
            walk = self._walk[:, None] + np.cumsum(rng.standard_normal(shape) * self._walk_sigma[:, :, None], axis=1)
            self._walk = walk[:, -1]
            out += walk
        self._block = out
        self._innovations, self._walk_path = e, (walk if self._walking else None)
        self._offset = 0

    def bias_now(self) -> np.ndarray:
        """The bias process (bank + rate random walk, no white noise) at the last sample drawn,
        (triads, 3): a draw from its exact law given every sample drawn so far.

        The innovations form does not carry the bank's own states, only their prediction ŝ; the
        bank's sum at sample k given y[0..k] is normal with mean 1ᵀA⁻¹ŝ[k+1] (the filtered state,
        as K = A·P1/S) and variance 1ᵀ(P − P1 1ᵀP/S)1. One draw from that law together with the
        samples is a draw of (samples, bias) from their joint law, which is all a benchmark of
        "error against the bias at the end of calibration" needs. It is drawn from a jumped copy
        of the generator, so asking does not change the samples that follow.
        """
        state, walk = self._state, self._walk
        if self._block is not None:
            # ŝ after the block's first `offset` samples: A^o·ŝ0 + Σ_{q<o} A^(o−1−q)·K·e[q].
            start, walk_start, _ = self._block_start
            o = self._offset
            powers = self._poles[:, None] ** np.arange(o - 1, -1, -1)[None, :]  # (P, o)
            driven = np.einsum("pq,tqc->tpc", powers, self._innovations[:, :o])
            state = (self._poles**o)[None, :, None] * start + self._gain[:, :, None] * driven
            if self._walk_path is not None:
                walk = self._walk_path[:, o - 1] if o else walk_start
        filtered = (state / self._poles[None, :, None]).sum(axis=1) if len(self._poles) else np.zeros_like(walk)
        jumped = np.random.Generator(self._rng.bit_generator.jumped())
        return filtered + self._filtered_sigma * jumped.standard_normal(walk.shape) + walk

    def _bank(self, e: np.ndarray) -> np.ndarray:
        """1ᵀŝ[k] for a block of innovations e (T, BLOCK, 3), by sub-blocks of L samples; carries ŝ.

        In a sub-block from state ŝ: 1ᵀŝ[r] = Σ_i p_i^r ŝ_i + Σ_{q<r} h[r−1−q] e[q] with
        h[l] = Σ_i K_i p_i^l (a small Toeplitz product), and ŝ after it is p^L ŝ + Σ_q p^(L−1−q) K e[q].
        The states at the sub-block starts follow the same first-order recursion with poles
        a = p^L: ŝ at sub-block b of a group = a^b·(ŝ + Σ_{γ<b} a^(−γ−1)·drive[γ]), an exclusive
        cumulative sum, over groups short enough that a^(−group) stays below e⁶ (rounding grows
        by at most 400× on the fastest process, far below the white noise's last digit).
        """
        toeplitz, decay, weight, before, after, a_l, group = self._constants()
        triads, length = e.shape[0], self.SUB_BLOCK
        blocks = self.BLOCK // length
        # (T, L, blocks·3): samples of a sub-block down the rows, sub-blocks and axes across.
        e_t = e.reshape(triads, blocks, length, 3).transpose(0, 2, 1, 3).reshape(triads, length, blocks * 3)
        drive = (weight @ e_t).reshape(triads, -1, blocks, 3)  # (T, P, blocks, 3)
        starts = np.empty_like(drive)
        state = self._state
        for first in range(0, blocks, group):
            d = drive[:, :, first:first + group]
            g = d.shape[2]
            summed = np.cumsum(d * before[:, :g], axis=2)
            starts[:, :, first] = state
            starts[:, :, first + 1:first + g] = after[:, 1:g] * (state[:, :, None] + summed[:, :, :-1])
            state = after[:, g - 1] * a_l * (state + summed[:, :, -1])
        self._state = state
        bank = toeplitz @ e_t + decay @ starts.reshape(triads, len(self._poles), blocks * 3)
        return bank.reshape(triads, length, blocks, 3).transpose(0, 2, 1, 3).reshape(e.shape)

    def _constants(self) -> tuple:
        """The sub-block products' matrices, computed once: (T, L, L) strictly lower Toeplitz of
        h, (L, P) p^r, (T, P, L) K·p^(L−1−q); and for the recursion between sub-blocks
        (P, group, 1) a^(−γ−1) and a^b, (P, 1) a, and the group length."""
        if self._matrices is None:
            length = self.SUB_BLOCK
            powers = self._poles[None, :] ** np.arange(length)[:, None]  # (L, P): p^r
            h = self._gain @ powers.T  # (T, L): h[l]
            lag = np.arange(length)[:, None] - np.arange(length)[None, :] - 1
            toeplitz = np.where(lag >= 0, h[:, np.maximum(lag, 0)], 0.0)
            weight = self._gain[:, :, None] * powers[::-1].T[None]
            a = self._poles[:, None] ** length
            group = max(1, int(6.0 / -np.log(a.min())))
            steps = np.arange(group)
            self._matrices = (toeplitz, powers, weight, (a ** -(steps + 1.0))[..., None],
                              (a ** steps)[..., None], a, group)
        return self._matrices
