"""The covariance of the poses' up vectors, kept by its parts, so that the rotation solve's
residual covariance (2 per motion) is whitened in O(m) (``chained_parts``, with the windows'
covariance by its parts: ``solvers.semiseparable``), or made in O(m²) (``chained``), without the
dense (3m, 3m) matrix, whose products with the chain of motions cost O(m³) and hundreds of MiB
on a long recording.

An up vector u_i = a_i/|a_i| moves by D_i·δa_i (D_i = ∂u/∂a at pose i), and a_i = K⁻¹(mean_i − b)
by K⁻¹·δmean_i (each mean's noise) and by ∂a_i/∂θ·δθ (the accelerometer calibration's error, which
every pose shares). With the device's noise model the means' covariance is W ⊗ K·Kᵀ (W the
window covariance, bias instability included; ``static_solve.means_covariance``), so in a it is W_ij·I, plus
each mean's own part (white noise alone, or one count's quantisation).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fieldcal.recording.noise_estimate import window_covariance
from fieldcal.solvers.semiseparable import ChainedPoses, MarkovWindows


@dataclass(frozen=True)
class UpCovariance:
    """``D`` (m, 3, 3): ∂u/∂a per pose; ``windows`` (m, m), its parts (``MarkovWindows``: the
    rotation solve then whitens in O(m), see ``chained_parts``) or None: the covariance shared by
    the three axes of a (W_ij·I); ``own`` (m, 3, 3): each pose's own covariance in a; ``shared``
    (m, 3, p) with ``theta_covariance`` (p, p): ∂u_i/∂θ and the calibration's covariance."""

    D: np.ndarray
    windows: np.ndarray | MarkovWindows | None
    own: np.ndarray
    shared: np.ndarray
    theta_covariance: np.ndarray

    @property
    def shape(self) -> tuple[int, int]:
        return (3 * len(self.D),) * 2

    def dense(self) -> np.ndarray:
        """The (3m, 3m) matrix, for a check or a small problem."""
        m = len(self.D)
        S = self.shared.reshape(3 * m, -1)
        out = S @ self.theta_covariance @ S.T
        blocks = np.zeros((m, 3, m, 3))
        if self.windows is not None:
            blocks += self._dense_windows()[:, None, :, None] * np.einsum("iac,jbc->iajb", self.D, self.D)
        idx = np.arange(m)
        blocks[idx, :, idx, :] += self.D @ self.own @ np.swapaxes(self.D, 1, 2)
        return out + blocks.reshape(3 * m, 3 * m)

    def chained(self, E: np.ndarray, C: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """(2m', 2m') covariance of the rotation residuals of the m' = m − 1 motions, motion i
        joining pose i to pose i+1: r_i moves by E_iᵀ·C_iᵀ·δu_i − E_iᵀ·δu_{i+1}
        (solvers.rotation._chained_up_covariance, there from the dense matrix). ``out``: a
        (2m', 2m') matrix (C order) to add it to, returned: no second dense matrix."""
        k = len(E)
        Et = np.swapaxes(E, 1, 2)
        ends = (Et @ np.swapaxes(C, 1, 2), -Et)  # the motion's map of its start's and its end's δu
        poses = (slice(0, k), slice(1, k + 1))
        Y = [end @ self.D[p] for end, p in zip(ends, poses)]  # (k, 2, 3): of δa at either end
        Z = sum(end @ self.shared[p] for end, p in zip(ends, poses)).reshape(2 * k, -1)
        shared = Z @ self.theta_covariance @ Z.T
        if out is None:
            out = shared
        else:
            out += shared
        del shared
        blocks = out.reshape(k, 2, k, 2)  # a view: each motion's 2×2 block
        if self.windows is not None:
            windows = self._dense_windows()
            for s in (0, 1):
                for t in (0, 1):
                    product = (Y[s].reshape(2 * k, 3) @ Y[t].reshape(2 * k, 3).T).reshape(k, 2, k, 2)
                    product *= windows[poses[s], poses[t]][:, None, :, None]
                    blocks += product
                    del product
        # Each pose's own part reaches the motions that touch it: block-tridiagonal.
        idx = np.arange(k)
        own = (self.own[:-1], self.own[1:])
        for s in (0, 1):
            blocks[idx, :, idx, :] += Y[s] @ own[s] @ np.swapaxes(Y[s], 1, 2)
        between = Y[1][:-1] @ self.own[1:-1] @ np.swapaxes(Y[0][1:], 1, 2)  # pose i+1: end of i, start of i+1
        blocks[idx[:-1], :, idx[1:], :] += between
        blocks[idx[1:], :, idx[:-1], :] += np.swapaxes(between, 1, 2)
        return out

    def chained_parts(self, E: np.ndarray, C: np.ndarray) -> ChainedPoses:
        """What ``chained`` sums, by its parts (the rotation solve's structured whitening): each
        motion's maps of δa at its start and end pose, of the calibration's error, and each pose's
        own part where it reaches the motions that touch it."""
        k = len(E)
        Et = np.swapaxes(E, 1, 2)
        ends = (Et @ np.swapaxes(C, 1, 2), -Et)
        start, end = ends[0] @ self.D[:-1], ends[1] @ self.D[1:]
        shared = ends[0] @ self.shared[:-1] + ends[1] @ self.shared[1:]
        own_diagonal = start @ self.own[:-1] @ np.swapaxes(start, 1, 2) + end @ self.own[1:] @ np.swapaxes(end, 1, 2)
        own_sub = start[1:] @ self.own[1:-1] @ np.swapaxes(end[:-1], 1, 2)  # pose i+1: start of i+1, end of i
        return ChainedPoses(start, end, shared.reshape(k, 2, -1), self.theta_covariance, own_diagonal, own_sub,
                            self.windows)

    def _dense_windows(self) -> np.ndarray:
        return self.windows.dense() if isinstance(self.windows, MarkovWindows) else np.asarray(self.windows)


@dataclass(frozen=True)
class MeansCovariance:
    """The pose means' covariance (output units) W ⊗ K·Kᵀ + each mean's own ``own`` (m, 3) per
    axis, kept by its parts: a norm solve weighs residual i by its gradient g_i in mean i alone
    (solvers.norm), so the residuals' covariance g_i·(W_ij·K·Kᵀ)·g_jᵀ + δ_ij·g_i·own_i·g_iᵀ is
    made in O(m²) without the dense (3m, 3m) matrix."""

    windows: np.ndarray
    K: np.ndarray
    own: np.ndarray

    def residual_covariance(self, gradients: np.ndarray) -> np.ndarray:
        along = gradients @ self.K  # (m, 3): g_i·K
        return self.windows * (along @ along.T) + np.diag(np.einsum("ia,ia->i", gradients**2, self.own))

    def dense(self) -> np.ndarray:
        return np.kron(self.windows, self.K @ self.K.T) + np.diag(self.own.ravel())


def means_parts(intervals: np.ndarray, t: np.ndarray, variance: np.ndarray, noise, K: np.ndarray,
                quantised: bool, *, period: float) -> tuple[np.ndarray | MarkovWindows | None, np.ndarray]:
    """(windows, own) of the pose means' covariance in a = K⁻¹·mean, as ``static_solve.means_covariance``
    makes it in output units: white noise per axis alone (no noise model), else the model's
    window covariance on every axis alike (by its parts where the windows are in time order)
    plus, for ``quantised`` raw counts, one count's. ``period``: the median step of ``t`` (s)."""
    counts = np.diff(intervals, axis=1)[:, 0]
    K_inv = np.linalg.inv(K)
    if noise is None:
        own = (K_inv[None] * (variance[None, None, :] / counts[:, None, None])) @ K_inv.T
        return None, own
    durations = counts * period
    windows = MarkovWindows.of(noise, t[intervals[:, 0]], durations)
    if windows is None:
        windows = window_covariance(noise, t[intervals[:, 0]], durations)
    scale = (1.0 / 12.0 / counts) if quantised else np.zeros(len(counts))
    return windows, scale[:, None, None] * (K_inv @ K_inv.T)[None]
