"""A triad's noise model measured from the recording itself, for a recording with no device
config: the white noise, and the bias instability (flicker) that moves every pose's mean.

Why: a real MEMS unit's pose mean is not off by white noise alone. Flicker (1/f) bias
instability moves the means too, and its slow part moves all of them alike, which the fit takes
for the bias and which no scatter between poses shows: with white noise alone the biases' σ
come out about half what they are (real-world Monte Carlo RMS z 1.75–2.8). What the poses do
show is the flicker's faster part: their means scatter about the fit more than white noise
says. Read through the flicker model (``drivers.noise``: white W plus the Gauss-Markov bank of
B, whose Allan deviation is flat at 0.664·B), that excess scatter at the poses' own times and
lengths tells B (the residuals' weighted sum of squares has a mean and variance known for
every B; see bias_instability), and B gives the slow, shared part the bias carries. The result
is a ``TriadNoise`` as a device config gives one, so the recording is weighted as with
``--config``.

Within a pose (3-6 s) the Allan deviation cannot tell B: measured on the real-world Monte Carlo's
recordings, its estimate ranged from 0 to 3.5 times the truth for the accelerometer, and a
warm-up's drift made the gyroscope's 5-13 times the truth. The scatter between poses is read at
the time scale that matters (the recording's), and the drift the fit models is not counted.

numpy and scipy.special; no I/O.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import gammaln

from drivers.noise import DEFAULT_FLICKER_TAU_MAX_S, TriadNoise
from fieldcal.recording import median_step
from fieldcal.recording.detect import interval_means

# The prior on B: density ∝ B^(PRIOR_POWER − 1), i.e. ∝ B^PRIOR_POWER per decade. Chosen on the
# real-world Monte Carlo (200 recordings, no --config): per decade even (0) leaves a consumer
# gyro's bias RMS z at 1.5, whose flicker the scatter often under-shows; even in B (1) puts a
# good gyro's at 0.4, whose flicker no scatter shows; 0.5 gives 0.84-0.96 for every bias.
PRIOR_POWER = 0.5
ESTIMATED = ("no device config (--config): estimated from the recording, the white noise from its still "
             "windows, the bias instability from how far the pose means scatter beyond it (with too few poses "
             "for that, each pose's parts; a note says which) (flicker model, whose slow part the biases' σ "
             "include)")


@dataclass(frozen=True)
class MeasuredNoise(TriadNoise):
    """A noise model measured from the recording, not given: its white noise is the samples'
    own scatter, the converter's quantisation already in it."""


# The last few window sets' flicker covariance of B = 1: the stages of one calibration (the norm
# solve's weights, the noise estimates, the gyro's prior and its up vectors' covariance) each ask
# for the same poses' (m, m) matrix, whose bank of exponentials costs O(m²) each time (on imu_tk's
# recording joined 16×, 633 poses, five times 30-90 ms).
_FLICKER_MEMO: dict[tuple[bytes, bytes, float], np.ndarray] = {}
_FLICKER_MEMO_SIZE = 4


def flicker_covariance(starts: np.ndarray, durations: np.ndarray,
                       tau_max_s: float = DEFAULT_FLICKER_TAU_MAX_S) -> np.ndarray:
    """(m, m) covariance of the means over m windows [start, start + duration) (s) of the bias
    instability of B = 1 (the device model's bank; scale by B²). Shared, so read-only."""
    starts, durations = (np.ascontiguousarray(x, dtype=float) for x in (starts, durations))
    key = (starts.tobytes(), durations.tobytes(), float(tau_max_s))
    flicker = _FLICKER_MEMO.pop(key, None)
    if flicker is None:
        flicker = TriadNoise(white=0.0, bias_instability=1.0, flicker_tau_max_s=tau_max_s).window_covariance(
            starts, durations)
        flicker.flags.writeable = False
        if len(_FLICKER_MEMO) >= _FLICKER_MEMO_SIZE:
            del _FLICKER_MEMO[next(iter(_FLICKER_MEMO))]
    _FLICKER_MEMO[key] = flicker  # the most recent last
    return flicker


def window_covariance(noise: TriadNoise, starts: np.ndarray, durations: np.ndarray) -> np.ndarray:
    """``noise.window_covariance`` from the shared flicker of B = 1: diag(white²/T) + B²·F (the
    bank's variances are proportional to B²), a new array the caller may change."""
    if noise.rate_random_walk or not noise.bias_instability:
        return noise.window_covariance(starts, durations)
    out = noise.bias_instability**2 * flicker_covariance(starts, durations, noise.flicker_tau_max_s)
    diagonal = np.arange(len(out))
    out[diagonal, diagonal] += noise.white**2 / np.asarray(durations, dtype=float)
    return out


def bias_instability(residuals: np.ndarray, design: np.ndarray, white: np.ndarray, flicker: np.ndarray,
                     weights: np.ndarray | None = None) -> float:
    """B (the residuals' unit) whose flicker, added to the known variance ``white`` (m,) of each
    of m values, explains the scatter of a fit's ``residuals`` (m, d): d columns of independent
    noise with the same model, the fit linear in ``design`` (m, p) (its Jacobian), weighted by
    ``weights`` (m,) (None: unweighted). ``flicker`` (m, m): the values' covariance for B = 1
    (``flicker_covariance``, times uᵢ·uⱼ for a norm residual that sees each pose's noise along
    its up).

    The scatter is a quadratic form whose mean and variance are known for every B (Gaussian
    noise: tr(QΣ) and 2 tr((QΣ)²) per column), taken as a scaled χ² of that mean and variance.
    On a dozen poses it pins B down only when the flicker is well above the white noise, so B²
    is its posterior mean over a grid of B (see PRIOR_POWER): close to the scatter's own
    estimate when that is clear; when it is not, neither zero (a scatter that happens to be
    small would leave the bias's σ at the white noise's) nor the largest B the scatter cannot
    rule out.
    """
    white = np.asarray(white, dtype=float)
    residuals = np.asarray(residuals, dtype=float).reshape(len(white), -1)
    m, d = residuals.shape
    w = np.ones(m) if weights is None else np.asarray(weights, dtype=float)
    X = np.asarray(design, dtype=float).reshape(m, -1)
    # The fit's residual maker R = I − H, H = X (XᵀWX)⁻¹ XᵀW, and Q = Rᵀ W R: the scatter
    # rᵀWr has mean tr(QΣ) for noise of covariance Σ, linear in the white and flicker parts.
    # Q = W − U P Uᵀ with U = WX and P = (XᵀWX)⁺ (P·XᵀWX·P = P): rank p off a diagonal, so Q·F
    # costs O(m²p), not the O(m³) of a dense product.
    U = w[:, None] * X
    P = np.linalg.pinv(X.T @ U)
    Q = np.diag(w) - U @ P @ U.T
    observed = float(np.sum(w[:, None] * residuals**2))
    QW, QF = Q * white[None, :], w[:, None] * flicker - U @ (P @ (U.T @ flicker))
    mean_white, mean_flicker = d * float(np.trace(QW)), d * float(np.trace(QF))
    if mean_flicker <= 0:
        return 0.0
    var_terms = 2 * d * np.array([np.sum(QW * QW.T), 2 * np.sum(QW * QF.T), np.sum(QF * QF.T)])
    # B from a thousandth to a thousand times the white noise of a pose's mean: far below, the
    # flicker changes nothing; far above, the scatter would show it.
    typical = math.sqrt(float(np.mean(white)))
    b = typical * np.geomspace(1e-3, 1e3, 241)
    b2 = b * b
    mean = mean_white + b2 * mean_flicker
    variance = var_terms[0] + b2 * var_terms[1] + b2 * b2 * var_terms[2]
    # The scatter as a scaled χ² of matching mean and variance (Satterthwaite): its tail, unlike
    # a normal's, rules out a B far above what the scatter shows.
    scale, dof = variance / (2 * mean), 2 * mean**2 / variance
    log_like = (0.5 * dof - 1) * math.log(max(observed, 1e-300)) - observed / (2 * scale) \
        - 0.5 * dof * np.log(2 * scale) - gammaln(0.5 * dof)
    log_like = log_like + PRIOR_POWER * np.log(b)
    weight = np.exp(log_like - log_like.max())
    return float(np.sqrt(np.sum(weight * b2) / np.sum(weight)))


@dataclass(frozen=True)
class PoseNoise:
    """What each pose's own samples say of the noise on its mean (output units): ``variance``
    (m, 3) each pose's per-axis sample variance, and ``bias_instability`` B measured within the
    poses (see ``within_pose_noise``)."""

    variance: np.ndarray
    bias_instability: float

    def flicker(self, intervals: np.ndarray, t: np.ndarray, period: float) -> np.ndarray:
        """(m, m): the covariance of the pose means (``intervals`` of ``t``, whose median step is
        ``period``) that the flicker of B makes, every axis alike (output units²)."""
        return self.bias_instability**2 * flicker_covariance(t[intervals[:, 0]], _spans(t, intervals, period))


WITHIN_POSE_PARTS = 2  # each pose cut in halves at least: their difference is noise alone, white and flicker
WITHIN_POSE_ALL_PARTS = 8  # and in more when the poses are few (a single rest: 8 parts), so that the
# parts' scatter rules out a B far above the truth: in halves, a single rest's σ were 1.5 times too wide.
WITHIN_POSE = ("σ from each pose's own samples (their white noise and the bias instability their parts show), "
               "not from the fit's residuals (dof {dof}: too few to measure the noise by)")


def within_pose_noise(values: np.ndarray, intervals: np.ndarray, t: np.ndarray,
                      parts: int | None = None, *, period: float | None = None) -> PoseNoise:
    """The noise of a triad's pose means read from each pose's own samples, for a fit with too
    few degrees of freedom to measure it by its residuals (at none, they are zero whatever the
    noise). Each pose ``intervals`` (m, 2) [start, stop) of ``values`` (n, 3) gives its samples'
    variance, and its ``parts`` equal parts' means, whose scatter about the pose's mean is the
    noise alone (the pose, the bias and the scale are the same in every part; default: halves, more
    when the poses are few): the white noise, and the faster part of the flicker, which through
    the flicker model tells B (bias_instability), and B the slow part that every pose shares and
    that no scatter shows. A drift within a pose
    (a warm-up) counts as flicker: the σ err on the wide side. ``period``: the median step of
    ``t`` (a Recording's ``period_s``), found again when not given."""
    intervals = np.asarray(intervals, dtype=int).reshape(-1, 2)
    m, values = len(intervals), np.asarray(values, dtype=float)
    counts = np.diff(intervals, axis=1)
    mean = interval_means(values, intervals)
    variance = np.maximum(interval_means(values**2, intervals) - mean**2, 0.0) * counts / np.maximum(counts - 1, 1)
    # A pose read as one value throughout (a quantised rest) has a variance floored far below
    # anything a converter resolves, so that no weight is infinite.
    variance = np.maximum(variance, (1e-9 * np.maximum(np.abs(mean), 1.0)) ** 2)
    parts = min(parts or max(WITHIN_POSE_PARTS, math.ceil(WITHIN_POSE_ALL_PARTS / m)), int(counts.min()))
    if parts < 2:  # a pose of one sample: nothing to tell the flicker by
        return PoseNoise(variance=variance, bias_instability=0.0)
    edges = intervals[:, :1] + (np.diff(intervals, axis=1) * np.arange(parts + 1)[None, :]) // parts
    windows = np.column_stack([edges[:, :-1].ravel(), edges[:, 1:].ravel()])
    means = interval_means(values, windows)
    design = np.repeat(np.eye(m), parts, axis=0)  # which pose each part is of
    part_counts = np.diff(windows, axis=1)[:, 0]
    white = np.repeat(np.mean(variance, axis=1), parts) / part_counts
    fitted = design @ (np.add.reduceat(means / white[:, None], np.arange(0, m * parts, parts), axis=0)
                       / np.add.reduceat(1.0 / white, np.arange(0, m * parts, parts))[:, None])
    period = (median_step(t) if len(t) > 1 else 1.0) if period is None else period
    flicker = flicker_covariance(t[windows[:, 0]], _spans(t, windows, period))
    b = bias_instability(means - fitted, design, white, flicker, weights=1.0 / white)
    return PoseNoise(variance=variance, bias_instability=b)


def _spans(t: np.ndarray, windows: np.ndarray, period: float) -> np.ndarray:
    """Each window's duration (s) from its first sample to its last, so that jittered timestamps
    cannot make neighbours overlap; one sample's ``period`` at least."""
    return np.maximum(t[windows[:, 1] - 1] - t[windows[:, 0]], period)
