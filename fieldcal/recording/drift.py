"""What a real gyro does between poses, and what the recording path does about it.

* :func:`still_bias`: the gyro bias from every pose's still reading rather than the first one's.
  A real MEMS gyro's still reading moves from pose to pose (g-sensitivity, warm-up, temperature,
  bias random walk); the first pose's reading carries all of that at its worst (warm-up is
  largest at the start). Fitted over all poses as bias + g-sensitivity·up + a linear drift, the
  orientation's share comes out and the drift is centred on the recording's mean time. Its σ
  comes from the fit's own residuals, over an effective number of poses that shrinks when
  consecutive residuals move together (a drift the line does not follow), and widened for a σ
  estimated from few readings (Student's t variance).
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


MIN_POSES_FOR_MODEL = 10  # poses needed to fit the g-sensitivity and a drift beside the bias


def still_bias(still: np.ndarray, floor_variance: np.ndarray, up: np.ndarray | None = None,
               times: np.ndarray | None = None, centre: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(bias (3,), its 1σ (3,)) from the poses' still readings ``still`` (m, 3) in time order,
    the Earth rate's known part already taken off. ``floor_variance`` (3,): the variance the
    bias has whatever the scatter says (the white noise's and the unknown Earth rate's share).

    With ``up`` (m, 3, each pose's up vector) and ``times`` (m,, s) and enough poses, each axis's
    readings are fitted as bias + g-sensitivity·up + drift·(t − ``centre``): the bias is the
    reading at the recording's middle (default: the poses' mean time), the bias it had on
    average, with the orientation's share taken out; else it is the readings' mean. Its σ² is the fit's residual variance times the bias's
    row of (XᵀX)⁻¹, over an effective count that shrinks when neighbouring residuals move
    together (a drift the line does not follow), times ν/(ν − 2) for a variance estimated from
    ν degrees of freedom (Student's t); with too few readings the residual variance itself."""
    m = len(still)
    X, coef, residuals = still_fit(still, up, times, centre)
    p = X.shape[1]
    if m <= p:
        return coef[0], np.sqrt(np.maximum(np.var(still, axis=0), floor_variance))
    variance = np.sum(residuals**2, axis=0) / (m - p)
    leverage = float(np.linalg.inv(X.T @ X)[0, 0])  # 1/m for the plain mean
    count = effective_count(residuals) if m > 2 else np.ones(3)
    nu = count * (m - p) / m
    student = np.where(nu > 2, nu / np.maximum(nu - 2, 1e-9), 3.0)
    scatter = variance * leverage * (m / count) * student
    return coef[0], np.sqrt(np.maximum(scatter, floor_variance))


def still_fit(still: np.ndarray, up: np.ndarray | None = None, times: np.ndarray | None = None,
              centre: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The model of :func:`still_bias` (design X, coefficients, residuals (m, 3)): the bias alone,
    or with enough poses and their ``up`` and ``times`` also the g-sensitivity and a drift."""
    m = len(still)
    if up is not None and times is not None and m >= MIN_POSES_FOR_MODEL:
        span = max(float(np.ptp(times)), 1e-9)
        middle = times.mean() if centre is None else centre
        X = np.column_stack([np.ones(m), up, (times - middle) / span])
    else:
        X = np.ones((m, 1))
    coef, *_ = np.linalg.lstsq(X, still, rcond=None)
    return X, coef, still - X @ coef


def rail_samples(values: np.ndarray) -> np.ndarray:
    """(n,) bool: samples where some axis sits at its largest or smallest value of the whole
    recording for MIN_RAIL_RUN or more samples in a row (a clipped converter holds one code),
    that value far from the axis's median (a quarter of its range or more: a still reading that
    happens to be the lowest is not a rail)."""
    # Read where they are, in their own type: no float copy of the samples (a 16× joined imu_tk
    # recording's gyro: 20 MiB). An axis reaches its extreme at a few samples, usually apart:
    # their runs are found from where they are, and the median (a copy of that axis) is taken
    # only for an axis with a run long enough to be a rail.
    values = np.asarray(values)
    out = np.zeros(len(values), dtype=bool)
    if not len(values):
        return out
    # Column by column: down the rows of an (n, 3) array numpy reduces three numbers at a time,
    # some 7 times slower than along one strided column.
    columns = [values[:, axis] for axis in range(values.shape[1])]
    high, low = np.array([c.max() for c in columns]), np.array([c.min() for c in columns])
    spread = high.astype(float) - low
    median = {}  # of the axes with a run at an extreme, each once
    for extreme in (high, low):
        for axis in np.flatnonzero(spread != 0):  # (a constant axis is not clipped)
            at = np.flatnonzero(values[:, axis] == extreme[axis])
            if len(at) < MIN_RAIL_RUN:
                continue
            breaks = np.flatnonzero(np.diff(at) != 1) + 1  # where consecutive samples stop
            starts, stops = at[np.r_[0, breaks]], at[np.r_[breaks - 1, len(at) - 1]] + 1
            rails = stops - starts >= MIN_RAIL_RUN
            if not rails.any():
                continue
            if axis not in median:
                median[axis] = float(np.median(values[:, axis]))
            if abs(extreme[axis] - median[axis]) < 0.25 * spread[axis]:
                continue
            for start, stop in zip(starts[rails].tolist(), stops[rails].tolist()):  # a few runs
                out[start:stop] = True
    return out


def saturated_spans(values: np.ndarray, spans: np.ndarray) -> np.ndarray:
    """(k,) bool: the [start, stop) ``spans`` holding a rail sample (see rail_samples)."""
    rails = np.flatnonzero(rail_samples(values))  # few: counted per span by where they fall
    spans = np.asarray(spans, dtype=int).reshape(-1, 2)
    return np.searchsorted(rails, spans[:, 1]) > np.searchsorted(rails, spans[:, 0])


def regular_times(t: np.ndarray, rate_hz: float) -> np.ndarray:
    """Timestamps with a logger's jitter taken out: each sample put on the nearest point of a
    regular grid (a line through the timestamps, so a clock's own rate error stays), dropped
    samples leaving their gaps. A converter samples on its own clock; the jitter is when the
    logger wrote the time down, and integrating a rate over it (2 ms at 100 Hz is a fifth of a
    step) adds rotation errors the gyro never made. Timestamps whose residual from the grid
    exceeds a quarter step are not jitter of a regular grid: the timestamps are kept as they are."""
    t = np.asarray(t, dtype=float)
    if len(t) < 3:
        return t
    step = 1.0 / rate_hz
    index = np.round((t - t[0]) / step)
    t_mean = t.mean()
    t_centred = t - t_mean  # the same in both fits: made once (each pass over n numbers counts at 16×)
    scratch = np.empty_like(t)
    for _ in range(2):  # the grid's line, refitted once the indices are known
        index_mean = index.mean()
        centred = np.subtract(index, index_mean, out=scratch)  # least squares in closed form (np.polyfit's SVD costs ~10×)
        slope = float(centred @ t_centred / (centred @ centred))
        offset = float(t_mean - slope * index_mean)
        index = np.round(np.divide(np.subtract(t, offset, out=index), slope, out=index), out=index)
    if np.any(np.diff(index) <= 0):
        return t  # two samples on one point of the grid: not a jittered grid (kept to the last bit)
    grid = offset + slope * index
    off_grid = np.max(np.abs(t - grid))
    if off_grid > 0.25 * slope or off_grid < 1e-3 * slope:
        return t  # not a jittered grid, or already a regular one (kept to the last bit)
    return grid
