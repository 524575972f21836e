"""What a real gyro does between poses, and what the recording path does about it.

* :func:`still_bias`: the gyro bias from every pose's still reading rather than the first one's.
  A real MEMS gyro's still reading moves from pose to pose (g-sensitivity, warm-up, temperature,
  bias random walk); the first pose's reading carries all of that at its worst (warm-up is
  largest at the start), the mean over the poses averages the orientation-dependent part out and
  the time-dependent part down. Its σ comes from the readings' own scatter, over an effective
  number of poses that shrinks when consecutive readings move together (a drift, not noise),
  and widened for a σ estimated from few readings (Student's t variance).
* :func:`saturated_spans`: the motions during which the gyro sat at the end of its range. A
  clipped rate integrates to the wrong rotation; such a motion is left out of the gyro solve.

Pure numpy: no I/O.
"""
from __future__ import annotations

import numpy as np

MIN_RAIL_RUN = 3  # consecutive samples at an axis's extreme value: the converter's rail, not a peak


def effective_count(residuals: np.ndarray) -> np.ndarray:
    """Per column of ``residuals`` (m, d), ordered in time: m·(1 − ρ)/(1 + ρ) with ρ ≥ 0 the lag-1
    autocorrelation, the number of independent readings the scatter is worth (at least 1)."""
    m = len(residuals)
    power = np.sum(residuals**2, axis=0)
    lag = np.sum(residuals[1:] * residuals[:-1], axis=0)
    rho = np.clip(np.divide(lag, power, out=np.zeros_like(power), where=power > 0), 0.0, 0.95)
    return np.maximum(m * (1 - rho) / (1 + rho), 1.0)


def still_bias(still: np.ndarray, floor_variance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(bias (3,), its 1σ (3,)) from the poses' still readings ``still`` (m, 3) in time order,
    the Earth rate's known part already taken off. ``floor_variance`` (3,): the variance the
    mean has whatever the scatter says (the white noise's and the unknown Earth rate's share).

    The σ² is the readings' variance over their effective count, times ν/(ν − 2) for ν = count − 1
    degrees of freedom when ν > 2 (a σ estimated from ν readings is itself uncertain: Student's
    t); with three readings or fewer the variance itself."""
    m = len(still)
    bias = still.mean(axis=0)
    residuals = still - bias
    variance = np.var(still, axis=0, ddof=1) if m > 1 else np.zeros(3)
    count = effective_count(residuals) if m > 2 else np.ones(3)
    nu = count - 1
    student = np.where(nu > 2, nu / np.maximum(nu - 2, 1e-9), 1.0)
    scatter = np.where(count > 3, variance / count * student, variance)
    return bias, np.sqrt(np.maximum(scatter, floor_variance))


def rail_samples(values: np.ndarray) -> np.ndarray:
    """(n,) bool: samples where some axis sits at its largest or smallest value of the whole
    recording for MIN_RAIL_RUN or more samples in a row (a clipped converter holds one code)."""
    values = np.asarray(values, dtype=float)
    out = np.zeros(len(values), dtype=bool)
    for extreme in (values.max(axis=0), values.min(axis=0)):
        at = values == extreme[None, :]
        for axis in range(values.shape[1]):  # three axes, not samples
            edges = np.flatnonzero(np.diff(np.r_[0, at[:, axis].astype(np.int8), 0]))
            for start, stop in edges.reshape(-1, 2):
                if stop - start >= MIN_RAIL_RUN:
                    out[start:stop] = True
    return out


def saturated_spans(values: np.ndarray, spans: np.ndarray) -> np.ndarray:
    """(k,) bool: the [start, stop) ``spans`` holding a rail sample (see rail_samples)."""
    rails = np.cumsum(np.r_[0, rail_samples(values).astype(int)])
    spans = np.asarray(spans, dtype=int).reshape(-1, 2)
    return rails[spans[:, 1]] - rails[spans[:, 0]] > 0
