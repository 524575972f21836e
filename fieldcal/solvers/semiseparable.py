"""Whitening in O(n) of residuals whose covariance comes from a sum of Gauss–Markov processes.

Why: the flicker (bias instability) model of ``drivers.noise`` is a bank of first-order
Gauss–Markov processes, so the means of one axis over time-ordered windows have a covariance
that couples every window with every other: dense, and its Cholesky factor O(n³) (on imu_tk's
recording joined 16×, 1266 gyro residuals: 65 ms and two 13 MiB matrices a solve, growing with
the cube). Between two windows the covariance is a product of a factor of the later one, a decay
e^(−Δt/τ) and a factor of the earlier one, term by term: the matrix is *semiseparable*, and its
Cholesky factor too, which a recursion along time makes and applies with a state of a few numbers
per term (the Kalman filter's innovations are the same whitening). celerite2 does this for point
observations of sums of exponentials; here the observations are window means seen through a 2×3
map per end of each motion, plus low-rank and neighbour terms, which it cannot express.

``MarkovWindows``: one axis's window-mean covariance (white plus bank), kept by its parts.
``BlockSemiseparable``: a symmetric matrix of b×b blocks, S_ij for i > j being
  left_i · diag(Π_{l=j+2}^{i−1} decay_l) · right_j   (i ≥ j + 2, the generator part)
  + sub_j                                              (i = j + 1, any neighbour block)
  + low_i · low_jᵀ                                     (every pair: a low-rank part)
with the diagonal blocks given whole, and optionally a last block (``tail``) tied to the rest by
the low-rank part alone. ``factor()`` gives its Cholesky factor L (S = L·Lᵀ) as a
``SemiseparableWhitener``, whose ``@`` applies L⁻¹: the same numbers as the dense factor's
(the block order is the Cholesky order), in O(n·r²) with r = 2·g + b + c (g generators, c
low-rank columns), memory O(n·r·b). The loop is over blocks (one per motion), never over samples.

numpy only; no I/O.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

_OVERLAP_TOLERANCE_S = 1e-9  # windows ending this much after the next one starts still count as ordered


@dataclass(frozen=True)
class MarkovWindows:
    """Covariance of one axis's means over m windows [start, start + duration) in time order,
    not overlapping, of white noise (``white``, unit·√s) plus Gauss–Markov processes of
    correlation times ``taus`` (s) and standard deviations ``sigmas`` (``drivers.noise``'s
    bank): W_pp = white²/T_p + Σ 2σ²τ(1 − ρ_p)/T_p and, for p later than q,
    W_pq = Σ σ²·ρ_p·ρ_q·e^(−(a_p − e_q)/τ), ρ = τ(1 − e^(−T/τ))/T (``TriadNoise.window_covariance``)."""

    starts: np.ndarray
    durations: np.ndarray
    white: float
    taus: np.ndarray
    sigmas: np.ndarray

    @classmethod
    def of(cls, noise, starts, durations) -> "MarkovWindows | None":
        """From a ``TriadNoise``; None when the windows are not in time order without overlap or
        the noise has a rate random walk (no stationary covariance): callers then use the dense
        matrix."""
        a, T = (np.asarray(x, dtype=float).ravel() for x in (starts, durations))
        if noise.rate_random_walk or np.any(a[1:] - (a[:-1] + T[:-1]) < -_OVERLAP_TOLERANCE_S):
            return None
        taus, sigmas = noise.bank()
        return cls(a, T, float(noise.white), np.asarray(taus, dtype=float), np.asarray(sigmas, dtype=float))

    def __len__(self) -> int:
        return len(self.starts)

    def ramps(self) -> np.ndarray:
        """(m, k): ρ of every window for every term (as ``TriadNoise.window_covariance`` has it)."""
        T, c = self.durations[:, None], self.taus[None, :]
        return c * (1 - np.exp(-T / c)) / T

    def diagonal(self) -> np.ndarray:
        """(m,): each window's own variance."""
        T = self.durations
        own = self.white**2 / T
        if len(self.taus):
            own = own + np.sum(2 * self.sigmas**2 * self.taus * (1 - self.ramps()) / T[:, None], axis=1)
        return own

    def between(self, later: np.ndarray, earlier: np.ndarray) -> np.ndarray:
        """W between windows ``later`` and ``earlier`` (index arrays, later > earlier)."""
        if not len(self.taus):
            return np.zeros(np.shape(later))
        rho = self.ramps()
        gap = np.maximum(self.starts[later] - self.starts[earlier] - self.durations[earlier], 0.0)
        return np.sum(self.sigmas**2 * rho[later] * rho[earlier] * np.exp(-gap[..., None] / self.taus), axis=-1)

    def dense(self) -> np.ndarray:
        """The (m, m) matrix, for a check or a small problem."""
        m = len(self)
        later, earlier = np.tril_indices(m, -1)
        out = np.zeros((m, m))
        out[later, earlier] = out[earlier, later] = self.between(later, earlier)
        out[np.arange(m), np.arange(m)] = self.diagonal()
        return out


@dataclass(frozen=True)
class ChainedPoses:
    """The covariance of k chained motions' 2-vector residuals from their k + 1 poses' errors
    (``recording.up_covariance.UpCovariance.chained_parts``): motion i moves by
    start_i·δa_i + end_i·δa_{i+1} + shared_i·δθ, the δa of the three axes alike of covariance
    ``windows`` (W_pq·I; ``MarkovWindows``, a dense (k+1, k+1) or None) plus each pose's own
    (``own_diagonal`` (k, 2, 2): within a motion, ``own_sub`` (k−1, 2, 2): block (i+1, i)), and
    δθ of covariance ``theta_covariance``."""

    start: np.ndarray
    end: np.ndarray
    shared: np.ndarray
    theta_covariance: np.ndarray
    own_diagonal: np.ndarray
    own_sub: np.ndarray
    windows: "MarkovWindows | np.ndarray | None"

    def blocks(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(diagonal (k, 2, 2), sub (k−1, 2, 2), left (k, 2, g), right (k, g, 2), decay (k, g), low
        (k, 2, c)) of a ``BlockSemiseparable`` equal to this covariance (the diagonal with the
        low-rank part in it, ``sub`` without). ValueError for dense windows: use ``chained``."""
        k = len(self.start)
        Y = (self.start, self.end)
        low = self.shared @ _root(self.theta_covariance)
        diagonal = self.own_diagonal + low @ np.swapaxes(low, 1, 2)
        sub = self.own_sub.copy()
        W = self.windows
        if W is None:
            return diagonal, sub, np.zeros((k, 2, 0)), np.zeros((k, 0, 2)), np.ones((k, 0)), low
        if not isinstance(W, MarkovWindows):
            raise ValueError("dense windows have no generators")
        i = np.arange(k)
        own = W.diagonal()

        def outer(s, t, rows=slice(None), cols=slice(None)):
            return Y[s][rows] @ np.swapaxes(Y[t][cols], 1, 2)

        cross = W.between(i + 1, i)[:, None, None]  # the two poses of one motion
        diagonal += own[:-1, None, None] * outer(0, 0) + own[1:, None, None] * outer(1, 1) \
            + cross * (outer(1, 0) + outer(0, 1))
        later, earlier = slice(1, None), slice(None, -1)  # block (i+1, i): motion i+1's poses against motion i's
        sub += (cross[:-1] * outer(0, 0, later, earlier) + own[1:-1, None, None] * outer(0, 1, later, earlier)
                + W.between(i[:-1] + 2, i[:-1])[:, None, None] * outer(1, 0, later, earlier)
                + W.between(i[:-1] + 2, i[:-1] + 1)[:, None, None] * outer(1, 1, later, earlier))
        # The generators, term by term: a later motion's poses seen from the end of the pose before
        # its first, an earlier one's from the end of its last; every exponent ≤ 0.
        taus, sigmas, rho = W.taus, W.sigmas, W.ramps()
        ends = W.starts + W.durations
        before = np.r_[W.starts[0], ends[:-2]]  # e_{i−1} (for motion 0, never used: its start)
        left = sum(((sigmas * rho[i + s] * np.exp(-np.maximum(W.starts[i + s] - before, 0.0)[:, None] / taus))
                    [:, None, :, None] * Y[s][:, :, None, :]) for s in (0, 1))  # (k, 2, terms, 3)
        right = sum(((sigmas * rho[i + t] * np.exp(-np.maximum(ends[i + 1] - ends[i + t], 0.0)[:, None] / taus))
                     [:, :, None, None] * np.swapaxes(Y[t], 1, 2)[:, None, :, :]) for t in (0, 1))  # (k, terms, 3, 2)
        steps = np.maximum(np.diff(ends[:-1], prepend=ends[0]), 0.0)  # e_l − e_{l−1}
        decay = np.repeat(np.exp(-steps[:, None] / taus), 3, axis=1)
        g = 3 * len(taus)
        return diagonal, sub, left.reshape(k, 2, g), right.reshape(k, g, 2), decay, low


def _root(covariance: np.ndarray) -> np.ndarray:
    """R with R·Rᵀ = covariance (symmetric, positive semidefinite, maybe singular)."""
    values, vectors = np.linalg.eigh(np.asarray(covariance, dtype=float))
    return vectors * np.sqrt(np.maximum(values, 0.0))


class SemiseparableWhitener:
    """r ↦ L⁻¹r (``whitener @ r``, r of shape (N,) or (N, c)) for the factor L of a
    ``BlockSemiseparable`` (see there), by forward substitution along the blocks."""

    def __init__(self, matrix: "BlockSemiseparable", inverse_diagonal, gains, tail_inverse):
        self.matrix, self.inverse_diagonal, self.gains, self.tail_inverse = matrix, inverse_diagonal, gains, tail_inverse
        n, b = matrix.diagonal.shape[:2]
        self.shape = (n * b + matrix.tail_size,) * 2
        # L_i⁻¹ times the state's left generator, every block's at once: the substitution's
        # loop then makes one product with the state a block (x_i = L_i⁻¹r_i − (L_i⁻¹p_i)·f).
        self.inverse_left = np.matmul(inverse_diagonal, matrix.state_left)  # (n, b, r)

    def __matmul__(self, r: np.ndarray) -> np.ndarray:
        S = self.matrix
        r = np.asarray(r, dtype=float)
        vector = r.ndim == 1
        R = r.reshape(len(r), -1)
        n, b = S.diagonal.shape[:2]
        x = np.empty_like(R)
        blocks = x[:n * b].reshape(n, b, -1)
        np.matmul(self.inverse_diagonal, R[:n * b].reshape(n, b, -1), out=blocks)  # L_i⁻¹r_i, all at once
        f = np.zeros((S.state_size, R.shape[1]))
        inverse_left, gains = self.inverse_left, self.gains
        # S.transition done in place on the one state, written out: the loop runs once a block
        # (hundreds, several passes a solve), where a call and two arrays a block cost more than
        # its few flops. The same operations on the same numbers: the low rank, kept, is not copied.
        g, b, _ = S.sizes
        carried, waiting, neighbour = f[:g], f[g:2 * g], f[g:2 * g + b]
        decay = S.decay[:, :, None]
        for i in range(n):
            xi = blocks[i]
            xi -= inverse_left[i] @ f
            carried *= decay[i]  # f = a_i·f + gains_i·x_i
            carried += waiting
            neighbour.fill(0.0)
            f += gains[i] @ xi
        if S.tail_size:
            tail = slice(n * b, None)
            x[tail] = self.tail_inverse @ (R[tail] - S._tail_low() @ f[S.low_slots])
        return x[:, 0] if vector else x

    def matrix_dense(self) -> np.ndarray:
        """L⁻¹ itself, for a check."""
        return self @ np.eye(self.shape[0])


@dataclass(frozen=True)
class BlockSemiseparable:
    """See the module docstring. ``diagonal`` (n, b, b): S_ii whole; ``sub`` (n−1, b, b): the
    part of S_{i+1,i} beyond the low-rank one; ``left`` (n, b, g), ``right`` (n, g, b),
    ``decay`` (n, g) in (0, 1]: the generator part (decay_l applies from block l−1 to l);
    ``low`` (n, b, c); ``tail_diagonal`` (t, t) and ``tail_low`` (t, c): a last block of t rows
    (none by default)."""

    diagonal: np.ndarray
    sub: np.ndarray
    left: np.ndarray
    right: np.ndarray
    decay: np.ndarray
    low: np.ndarray
    tail_diagonal: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    tail_low: np.ndarray | None = None  # None: (t, c) zeros
    sizes: tuple[int, int, int] = field(init=False)
    state_left: np.ndarray = field(init=False)
    state_right: np.ndarray = field(init=False)

    def __post_init__(self):
        n, b = self.diagonal.shape[:2]
        g, c = self.left.shape[2], self.low.shape[2]
        # The state: the generators carried from two blocks back and more (g, decaying), the last
        # block's right generator waiting a block (g), its neighbour block (b), the low rank (c).
        object.__setattr__(self, "sizes", (g, b, c))
        if self.tail_low is None:
            object.__setattr__(self, "tail_low", np.zeros((len(self.tail_diagonal), c)))
        zeros = np.zeros((n, b, g))
        state_left = np.concatenate([self.left, zeros, np.broadcast_to(np.eye(b), (n, b, b)), self.low], axis=2)
        object.__setattr__(self, "state_left", state_left)
        sub = np.concatenate([self.sub, np.zeros((1, b, b))]) if n else self.sub
        state_right = np.concatenate([np.zeros((n, g, b)), self.right, sub,
                                      np.swapaxes(self.low, 1, 2)], axis=1)
        object.__setattr__(self, "state_right", state_right)

    def _tail_low(self) -> np.ndarray:
        assert self.tail_low is not None  # made in __post_init__
        return self.tail_low

    @property
    def tail_size(self) -> int:
        return len(self.tail_diagonal)

    @property
    def state_size(self) -> int:
        g, b, c = self.sizes
        return 2 * g + b + c

    @property
    def low_slots(self) -> slice:
        g, b, c = self.sizes
        return slice(2 * g + b, 2 * g + b + c)

    def transition(self, f: np.ndarray, i: int, out: np.ndarray | None = None) -> np.ndarray:
        """a_i·f for a state f (r, …): the carried generators decay from block i−1 to i and take
        in the waiting one; the waiting slot and the neighbour slot empty; the low rank stays.
        ``out``: where to put it (not f itself), for a loop that keeps two states."""
        g, b, c = self.sizes
        out = np.empty_like(f) if out is None else out
        np.multiply(self.decay[i].reshape((g,) + (1,) * (f.ndim - 1)), f[:g], out=out[:g])
        out[:g] += f[g:2 * g]
        out[g:2 * g + b] = 0.0
        out[2 * g + b:] = f[2 * g + b:]
        return out

    def dense(self) -> np.ndarray:
        """The whole matrix, for a check or a small problem."""
        n, b = self.diagonal.shape[:2]
        N = n * b + self.tail_size
        out = np.zeros((N, N))
        for i in range(n):
            out[i * b:(i + 1) * b, i * b:(i + 1) * b] = self.diagonal[i]
            for j in range(i):
                block = self.low[i] @ self.low[j].T + (self.sub[j] if j == i - 1 else self.left[i] @ _decayed(self, i, j))
                out[i * b:(i + 1) * b, j * b:(j + 1) * b] = block
                out[j * b:(j + 1) * b, i * b:(i + 1) * b] = block.T
        if self.tail_size:
            out[n * b:, n * b:] = self.tail_diagonal
            cross = self._tail_low() @ self.low.reshape(n * b, -1).T
            out[n * b:, :n * b] = cross
            out[:n * b, n * b:] = cross.T
        return out

    def factor(self) -> SemiseparableWhitener:
        """The Cholesky factor, as its whitener; ValueError when S is not positive definite."""
        n, b = self.diagonal.shape[:2]
        r = self.state_size
        M = np.zeros((r, r))  # Σ over earlier blocks of their gains carried to this block
        inverse = np.empty((n, b, b))
        gains = np.empty((n, r, b))
        aM, aMp = np.empty((r, r)), np.empty((r, b))  # a·M and a·M·pᵀ, made in place each block
        for j in range(n):
            p, q = self.state_left[j], self.state_right[j]
            pM = p @ M
            inverse[j] = _inverse_cholesky(self.diagonal[j] - pM @ p.T, j)
            self.transition(pM.T, j, out=aMp)  # a_j·M·pᵀ (M symmetric)
            h = (q - aMp) @ inverse[j].T
            gains[j] = h
            self.transition(M, j, out=aM)
            self.transition(aM.T, j, out=M.T)  # a·M·aᵀ, into M: (a·(a·M)ᵀ)ᵀ
            M += h @ h.T
        tail_inverse = np.zeros((0, 0))
        if self.tail_size:
            p = self._tail_low()
            low = self.low_slots
            tail_inverse = _inverse_cholesky(self.tail_diagonal - p @ M[low, low] @ p.T, n)
        return SemiseparableWhitener(self, inverse, gains, tail_inverse)


def _decayed(S: BlockSemiseparable, i: int, j: int) -> np.ndarray:
    """diag(Π_{l=j+2}^{i−1} decay_l)·right_j, for ``dense``."""
    factor = np.prod(S.decay[j + 2:i], axis=0) if i > j + 2 else np.ones(S.decay.shape[1])
    return factor[:, None] * S.right[j]


def _inverse_cholesky(block: np.ndarray, index: int) -> np.ndarray:
    """L⁻¹ for the lower Cholesky factor L of ``block``; ValueError when it is not positive
    definite. A 2×2 block (a rotation residual's two components, one a block on a chain of
    hundreds) in closed form: numpy's cholesky and inv cost some 20 µs a call, most of the
    factor's time, for a few flops."""
    if block.shape == (2, 2):
        (a, _), (c, d) = block.tolist()
        if not a > 0.0:
            raise ValueError(f"not positive definite at block {index}")
        l11 = math.sqrt(a)
        l21 = c / l11
        rest = d - l21 * l21
        if not rest > 0.0:
            raise ValueError(f"not positive definite at block {index}")
        l22 = math.sqrt(rest)
        return np.array([[1.0 / l11, 0.0], [-l21 / (l11 * l22), 1.0 / l22]])
    try:
        return np.linalg.inv(np.linalg.cholesky(block))
    except np.linalg.LinAlgError:
        raise ValueError(f"not positive definite at block {index}") from None
