"""Static poses of a hand-held recording, from the accelerometer alone (imu_tk's detector).

Tedaldi et al. (ICRA 2014): a sample is static when the norm of the per-axis variance of the
accelerometer over a centred window is below ``multiple`` times its level over the initial rest.
The threshold multiple is not known in advance; :func:`pose_candidates` gives the poses for each
of ``settings.multiples`` and the caller keeps the one whose accelerometer calibration fits best,
as imu_tk does. Pure numpy: no I/O, no clock; sample index / rate is the time.

API (``acc``: (n, 3) accelerometer samples in any unit, ``rate_hz``: sample rate):

* :class:`DetectorSettings`, :class:`DetectionError` (a ValueError, one line: what and what to do).
* ``noise_level(acc, rate_hz, settings, gyro=None) -> NoiseLevel``: per-axis variance and imu_tk's
  base level. With ``settings.init_rest_s`` (the ``--rest`` option) over that initial rest, which
  must be still (refused if bumped or drifting) and followed by data; without it (real logs start
  with 2-8 s of rest, or none) over the quietest windows of the whole recording: the windows
  within twice the 10th percentile of the window statistic, i.e. every still window and no
  moving one, whose mean variance is the white noise (each window's own mean removed, so a
  bias that shifts between poses does not count as noise).
* the static intervals (inside ``pose_candidates``): [start, stop) sample indices, the initial
  rest first. The long window finds the static runs; each edge is then placed
  by a short window (``edge_window_s``) on the deviation from the run's own mean, which sees the
  start of a motion far sooner than the long window's variance does, and backed off by ``guard_s``
  so that no moving sample is kept: a few still samples lost cost little, a turn cut short spoils
  the gyro calibration that integrates between poses.
* ``pose_candidates(acc, rate_hz, settings, zero=None, sensitivity=None, gyro=None, noise=None)
  -> list[Poses]``: the poses at each of ``settings.multiples``.
* ``up_directions(means, zero=None, sensitivity=None)``: gravity direction per pose in body axes.
  With ``zero`` (output at zero input, e.g. 32768 counts) it is (mean - zero) / sensitivity; without
  it, the centre of the sphere fitted to the pose means (|m - c| = r, linear least squares) is the
  zero, so raw counts need no nominal values; when the means cannot fix a sphere (fewer than four,
  or all in a plane) the midpoint of each axis's range is used, which is right only for an axis
  seen both up and down (a refused recording then, in any case).
* ``check_spread(up, min_poses, cover_deg=60) -> SpreadReport`` and ``require_poses(poses,
  settings)`` (raises with the report's message when not ok).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from fieldcal.procedure.sliding import sliding_std, sliding_variance_by_column


class DetectionError(ValueError):
    """A recording the detector cannot use; the message says what and what to do."""


class TooFewPoses(DetectionError):
    """A recording read and searched whole that holds too few usable poses (or turns) to calibrate
    from: "not calibrated" (exit status 1 in the README's table), not bad input (2)."""

    exit_status = 1


@dataclass(frozen=True)
class DetectorSettings:
    """``init_rest_s``: the still start that sets the noise level (``--rest``); None: the quietest
    windows set it and no rest is assumed. ``window_s``: the
    variance window. ``min_static_s``: shorter static stretches are not poses. ``multiples``:
    thresholds tried by :func:`pose_candidates`. ``min_separation_deg``: a pose this close to an
    earlier distinct one is a duplicate. ``min_poses``: distinct poses needed (9 unknowns per
    triad). ``cover_deg``: every axis must be seen within this of up and of down.
    ``edge_window_s``, ``edge_sigmas``, ``guard_s``: edge placement (see module doc).
    ``rest_spike_ratio`` / ``rest_drift_ratio``: the initial rest is refused when a window's
    variance exceeds the median window's that many times (a bump), or so does the variance over
    the whole rest (a slow tilt, settling).
    ``min_design``: smallest singular value per √pose of the norm method's regressors."""

    init_rest_s: float | None = None
    window_s: float = 1.0
    min_static_s: float = 2.0
    multiples: tuple[float, ...] = (2, 3, 4, 5, 6, 8, 10, 13, 16, 20)
    min_separation_deg: float = 10.0
    min_poses: int = 9
    cover_deg: float = 60.0
    edge_window_s: float = 0.1
    edge_sigmas: float = 6.0
    guard_s: float = 0.05
    rest_spike_ratio: float = 10.0
    rest_drift_ratio: float = 3.0
    min_design: float = 0.02


@dataclass(frozen=True)
class NoiseLevel:
    """Accelerometer per-axis white-noise variance (input units²), ``base`` = its norm (imu_tk),
    and the gyroscope's per-axis variance when one was given. ``rest_samples``: the initial rest
    that is a pose whatever the threshold (0 without ``--rest``); ``source``: where the level was
    measured, for the summary. ``quiet``: over the non-overlapping windows, the quietest ones it
    was measured in (see quiet_windows; None: measured over the initial rest); ``quiet_gyro_means``
    the gyroscope's means over those windows, made with its variances (the turns' still level)."""

    variance: np.ndarray
    base: float
    gyro_variance: np.ndarray | None = None
    rest_samples: int = 0
    source: str = "the initial rest"
    quiet: np.ndarray | None = field(default=None, compare=False, repr=False)
    quiet_gyro_means: np.ndarray | None = field(default=None, compare=False, repr=False)


@dataclass(frozen=True)
class Poses:
    """Static intervals (m, 2) [start, stop), mean accelerometer (m, 3), unit up (m, 3) in body
    axes, ``distinct`` (m,) (False: a duplicate, still a rotation endpoint), and the multiple."""

    intervals: np.ndarray
    means: np.ndarray
    up: np.ndarray
    distinct: np.ndarray
    multiple: float
    # Durations (s) of the still stretches too short to be poses, for a refusal to name.
    short_s: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def count(self) -> int:
        return int(self.distinct.sum())


@dataclass(frozen=True)
class SpreadReport:
    """Whether the detected poses point in enough directions for a norm solve."""
    count: int
    ok: bool
    missing: list[str]
    design: float
    message: str


def _samples(seconds: float, rate_hz: float) -> int:
    return max(1, round(seconds * rate_hz))


def _half_window(rate_hz: float, settings: DetectorSettings) -> int:
    return max(1, _samples(settings.window_s, rate_hz) // 2)


def window_statistic(acc: np.ndarray, rate_hz: float, settings: DetectorSettings) -> np.ndarray:
    """(n,) norm of the per-axis variance over the centred window of 2·half + 1 samples; near the
    ends, the nearest full window's value."""
    half = _half_window(rate_hz, settings)
    var = sliding_variance_by_column(acc, 2 * half + 1, ddof=0)  # (axes, windows): each axis contiguous
    stat = np.empty(len(acc))
    if not var.shape[1]:  # shorter than one window: no value to extend (as np.pad refused)
        raise ValueError(f"window_statistic: {len(acc)} samples, fewer than a window of {2 * half + 1}")
    # The norm over axes made in place in the statistic's middle, the ends then filled with the
    # nearest full window's value: no copy of it, nor an n-long temporary per step.
    body = stat[half:half + var.shape[1]]
    np.square(var[0], out=body)
    for axis in var[1:]:  # three axes
        body += np.square(axis, out=axis)
    np.sqrt(body, out=body)
    stat[:half], stat[half + var.shape[1]:] = body[0], body[-1]
    return stat


def row_sums(values: np.ndarray) -> np.ndarray:
    """(n,) sums of the rows of ``values`` (n, d), column by column: the additions, in their
    order, of ``values.sum(axis=1)`` (which numpy runs d numbers at a time: ~5× slower at d = 3)."""
    total = values[:, 0].copy()
    for column in range(1, values.shape[1]):  # d columns: three for a triad
        total += values[:, column]
    return total


QUIET_PERCENTILE = 10.0  # the quietest windows: within QUIET_SPAN times this percentile
QUIET_SPAN = 2.0


def noise_level(acc: np.ndarray, rate_hz: float, settings: DetectorSettings,
                gyro: np.ndarray | None = None) -> NoiseLevel:
    acc = np.asarray(acc, dtype=float)
    if settings.init_rest_s is None:
        return quiet_noise_level(acc, rate_hz, settings, gyro)
    rest_n = _samples(settings.init_rest_s, rate_hz)
    window = 2 * _half_window(rate_hz, settings) + 1
    if rest_n < 3 * window:  # the noise level is the median over windows: it needs several
        raise DetectionError(
            f"an initial rest of {settings.init_rest_s:g} s is too short to measure the noise: it must "
            f"hold at least 3 stillness windows of {window / rate_hz:.3g} s; give a rest of "
            f"{3 * window / rate_hz:.3g} s or more (--rest), and record the unit still that long first")
    if len(acc) < rest_n + window:
        raise DetectionError(
            f"recording is {len(acc) / rate_hz:.1f} s long, but it must start with {settings.init_rest_s:g} s "
            f"of rest followed by the poses: give a shorter --rest, or none (the noise then comes from "
            f"the quietest windows)")
    rest = acc[:rest_n]
    variance = rest.var(axis=0)
    base = float(np.linalg.norm(variance))
    if not (math.isfinite(base) and base > 0):
        raise DetectionError("accelerometer shows no noise at all over the initial rest: check that "
                             "the file holds live samples")
    # The median window is the noise level whatever happened: a bump raises a few windows far
    # above it, a slow tilt or settling raises the variance over the whole rest.
    windows = np.linalg.norm(sliding_std(rest, window, ddof=0) ** 2, axis=1)
    typical = float(np.median(windows))
    peak = int(np.argmax(windows))
    if windows[peak] > settings.rest_spike_ratio * typical:
        raise DetectionError(
            f"the initial {settings.init_rest_s:g} s rest is not still (at {(peak + window / 2) / rate_hz:.1f} s "
            f"the accelerometer variance is {windows[peak] / typical:.0f}x its typical level): keep the unit "
            f"still at the start, or give a shorter --rest, or none")
    if base > settings.rest_drift_ratio * typical:
        raise DetectionError(
            f"the initial {settings.init_rest_s:g} s rest drifts (accelerometer variance over it is "
            f"{base / typical:.1f}x that of {settings.window_s:g} s windows): set the unit down firmly and "
            f"let it settle before recording, or give a shorter --rest, or none")
    gyro_variance = None
    if gyro is not None:
        gyro_variance = np.asarray(gyro[:rest_n], dtype=float).var(axis=0)
        if not np.all(gyro_variance > 0):
            raise DetectionError("gyroscope shows no noise on some axis over the initial rest: check "
                                 "that the file holds live samples")
    return NoiseLevel(variance=variance, base=base, gyro_variance=gyro_variance, rest_samples=rest_n,
                      source=f"the initial {settings.init_rest_s:g} s rest")


def window_variances(values: np.ndarray, window: int) -> tuple[np.ndarray, np.ndarray]:
    """Per-axis variance (k, d) and mean (k, d) of the k whole non-overlapping windows."""
    k = len(values) // window
    blocks = np.asarray(values[:k * window], dtype=float).reshape(k, window, -1)
    # np.var's own steps (the mean, then the mean square about it, each summed along the window),
    # without its generic machinery: the same numbers at under half the cost. The deviations are
    # made some windows at a time (never a copy of all the samples: 20 MiB at 16× imu_tk).
    means = window_sums(blocks) / window
    variances = np.empty(means.shape)
    chunk = max(1, _DEVIATION_SAMPLES // window)
    for lo in range(0, k, chunk):
        deviations = blocks[lo:lo + chunk] - means[lo:lo + chunk, None, :]
        np.einsum("kwd,kwd->kd", deviations, deviations, out=variances[lo:lo + chunk])
    return variances / window, means


def window_sums(blocks: np.ndarray) -> np.ndarray:
    """(k, d) sums of ``blocks`` (k, w, d) over its windows' w rows: ``blocks.sum(axis=1)``'s
    additions in its order (the first row, then each next one added), made as w additions over
    every window at once, where numpy's reduction adds d numbers at a time (at d = 3 on imu_tk's
    recording joined 16×: 6.7 ms instead of 14). A few long windows: numpy's own, the same bits."""
    k, w = blocks.shape[:2]
    if w > k:  # w additions of few numbers each: no faster
        return blocks.sum(axis=1)
    total = blocks[:, 0, :].copy()
    for row in range(1, w):  # the rows of a window (a second's samples), each over every window
        total += blocks[:, row, :]
    return total


_DEVIATION_SAMPLES = 1 << 16  # samples whose deviations window_variances makes at once (~1.5 MiB for 3 axes)


def _quietest(variance: np.ndarray, among: np.ndarray) -> np.ndarray:
    """Of the windows ``among``, those whose variance norm is within QUIET_SPAN times the
    QUIET_PERCENTILE-th percentile."""
    stat = np.linalg.norm(variance, axis=1)
    if not among.any():
        return among
    return among & (stat <= QUIET_SPAN * np.percentile(stat[among], QUIET_PERCENTILE))


def quiet_windows(acc: np.ndarray, rate_hz: float, settings: DetectorSettings) -> np.ndarray:
    """(k,) bool over the non-overlapping ``window_s`` windows: the quietest, i.e. still ones."""
    variance, _ = window_variances(acc, 2 * _half_window(rate_hz, settings) + 1)
    return _quietest(variance, np.ones(len(variance), dtype=bool))


def quiet_noise_level(acc: np.ndarray, rate_hz: float, settings: DetectorSettings,
                      gyro: np.ndarray | None = None) -> NoiseLevel:
    """The white noise of the still windows, when the recording has no known initial rest."""
    window = 2 * _half_window(rate_hz, settings) + 1
    min_windows = max(3, math.ceil(settings.min_static_s * rate_hz / window))
    if len(acc) < 10 * min_windows * window:
        raise DetectionError(
            f"recording is {len(acc) / rate_hz:.1f} s long: too short to find its noise level from "
            f"its quietest {settings.window_s:g} s windows; record the poses for longer, or give "
            f"--rest S if it starts with S seconds still")
    windows = window_variances(acc, window)[0]
    quiet = _quietest(windows, np.ones(len(windows), dtype=bool))  # as quiet_windows, computed once
    variance = windows[quiet].mean(axis=0) * window / (window - 1)
    base = float(np.linalg.norm(variance))
    if not (math.isfinite(base) and base > 0):
        raise DetectionError("accelerometer shows no noise at all in its quietest windows: check that "
                             "the file holds live samples")
    gyro_variance = gyro_means = None
    if gyro is not None:
        # A turntable turns with the accelerometer still: of its quiet windows, the gyro's quietest.
        windows, gyro_means = window_variances(gyro, window)
        gyro_means = gyro_means[quiet]
        gyro_variance = windows[_quietest(windows, quiet)].mean(axis=0) * window / (window - 1)
        if not np.all(gyro_variance > 0):
            raise DetectionError("gyroscope shows no noise on some axis in the quietest windows: check "
                                 "that the file holds live samples")
    return NoiseLevel(variance=variance, base=base, gyro_variance=gyro_variance, rest_samples=0,
                      source=f"the quietest {settings.window_s:g} s windows ({int(quiet.sum())} of {len(quiet)})",
                      quiet=quiet, quiet_gyro_means=gyro_means)


def true_runs(mask: np.ndarray) -> np.ndarray:
    """(k, 2) [start, stop) of the runs of True."""
    padded = np.zeros(len(mask) + 2, dtype=bool)
    padded[1:-1] = mask
    return np.flatnonzero(padded[1:] != padded[:-1]).reshape(-1, 2)


_RUNS_AT_ONCE = 64  # runs whose edges _first_loud searches together (under 1 MiB of temporaries at 100 Hz)


def _first_loud(columns: tuple[np.ndarray, ...], inv_var: np.ndarray, means: np.ndarray, first: np.ndarray,
                length: np.ndarray, step: int, k: int, threshold: float) -> np.ndarray:
    """Per run r, how many samples from ``first[r]`` (going by ``step``, ±1, over ``length[r]``
    samples) the first k-sample window starts whose mean z² = Σ (x − mean_r)²/σ² exceeds
    threshold (length - k + 1 if none); x the columns side by side. All runs at once: only the
    samples near each edge are read, in batches of runs that bound the temporaries (every
    threshold's runs are searched together)."""
    if len(first) > _RUNS_AT_ONCE:
        return np.concatenate([_first_loud(columns, inv_var, means[i:i + _RUNS_AT_ONCE], first[i:i + _RUNS_AT_ONCE],
                                           length[i:i + _RUNS_AT_ONCE], step, k, threshold)
                               for i in range(0, len(first), _RUNS_AT_ONCE)])
    width = int(max(length.max(initial=0), k))
    j = np.arange(width)
    idx = first[:, None] + step * j  # clipped to the samples by the gathers
    near = np.empty((len(first), width, means.shape[1]))  # (runs, width, columns): the triads side by side
    at = 0
    for c in columns:
        # Gathered into a fresh (contiguous) array, then copied into its columns: np.take into the
        # strided columns of ``near`` runs its slow element-by-element path, some 9× the cost
        # (two thirds of the edge search at imu_tk's recording joined 16×).
        near[..., at:at + c.shape[1]] = np.take(c, idx, axis=0, mode="clip")
        at += c.shape[1]
    near -= means[:, None, :]
    z2 = np.square(near, out=near) @ inv_var  # (runs, width)
    c = np.zeros((len(first), width + 1))
    np.cumsum(z2, axis=1, out=c[:, 1:])
    loud = ((c[:, k:] - c[:, :-k]) / k > threshold) & (j[None, :width - k + 1] <= (length - k)[:, None])
    return np.where(loud.any(axis=1), np.argmax(loud, axis=1), length - k + 1)


@dataclass(frozen=True)
class _EdgeSignals:
    """What every threshold's interval search reads, made once for all of them: the window
    statistic (n,), the triads whose deviation places the edges (accelerometer, and gyroscope
    when given; not copied side by side), their means over any rows, and their inverse noise
    variances."""

    stat: np.ndarray
    columns: tuple[np.ndarray, ...]
    means: tuple[PrefixMeans, ...]
    inv_var: np.ndarray

    @classmethod
    def of(cls, acc, rate_hz, noise: NoiseLevel, settings: DetectorSettings, gyro=None) -> "_EdgeSignals":
        acc = np.asarray(acc, dtype=float)
        # Edges watch the gyroscope too when given: a turn about the vertical, or the cubic onset of a
        # tilt, shows in the rate long before it shows in the accelerometer.
        columns, variance = (acc,), noise.variance
        if gyro is not None:
            if noise.gyro_variance is None:
                raise ValueError("static_intervals: gyro given but noise_level was measured without it")
            columns = (acc, np.asarray(gyro, dtype=float))
            variance = np.r_[noise.variance, noise.gyro_variance]
        return cls(window_statistic(acc, rate_hz, settings), columns, tuple(PrefixMeans(c) for c in columns),
                   1.0 / np.maximum(variance, 1e-300))

    def means_over(self, intervals: np.ndarray) -> np.ndarray:
        return np.hstack([m(intervals) for m in self.means])


def _level_edges(stat: np.ndarray, levels: np.ndarray, still_head: int) -> tuple[np.ndarray, np.ndarray]:
    """(owner, edges): the runs of stat < level for every level, each run's start then stop
    (sample indices, stop exclusive), level by level in the order given, each level's in time
    order; the first ``still_head`` samples below every level. Each sample's rank among the
    sorted levels (how many are at or below it) is read once; a level's runs start or stop only
    where the rank moves across it, so the levels are looked at there alone, not at every
    sample (ten thresholds: ten n-long comparisons and their edges)."""
    n = len(stat)
    order = np.argsort(levels, kind="stable")
    rank = np.full(n + 2, len(levels), dtype=np.intp)  # a sample beyond either end: below none
    rank[1:-1] = np.searchsorted(levels[order], stat, side="right")  # NaN: at the end, below none
    rank[1:min(still_head, n) + 1] = 0
    at = np.flatnonzero(rank[1:] != rank[:-1])  # between samples at - 1 and at
    low, high = np.minimum(rank[at], rank[at + 1]), np.maximum(rank[at], rank[at + 1])
    crossed = high - low  # the sorted levels low..high - 1 start or stop a run there
    first = np.cumsum(crossed) - crossed
    level = np.repeat(low - first, crossed) + np.arange(int(crossed.sum()))
    owner, edges = order[level], np.repeat(at, crossed)
    by_level = np.lexsort((edges, owner))
    return owner[by_level], edges[by_level]


def _static_intervals(signals: _EdgeSignals, rate_hz: float, noise: NoiseLevel, multiples,
                      settings: DetectorSettings) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per threshold multiple: the static intervals, and the durations (s) of the still stretches
    too short to be poses (a quiet run's length plus the window that found it still, or an
    interval cut below ``min_static_s`` by its edges), for a refusal to say that poses were held
    too briefly. Every multiple's runs are found, and their edges placed, at once."""
    columns, inv_var = signals.columns, signals.inv_var
    n = len(columns[0])
    half = _half_window(rate_hz, settings)
    rest_n = noise.rest_samples
    levels = np.asarray(multiples, dtype=float) * noise.base
    # noise_level has checked the initial rest: always a pose
    owner, edges = _level_edges(signals.stat, levels, max(rest_n - half, 0))
    runs, owner = edges.reshape(-1, 2), owner[::2]
    min_n = _samples(settings.min_static_s, rate_hz)
    long_enough = ((runs[:, 0] == 0) & (rest_n > 0)) | (runs[:, 1] - runs[:, 0] + 2 * half >= min_n)
    short = (runs[~long_enough, 1] - runs[~long_enough, 0] + 2 * half) / rate_hz
    short_owner = owner[~long_enough]
    runs, owner = runs[long_enough], owner[long_enough]

    k = _samples(settings.edge_window_s, rate_hz)
    guard = round(settings.guard_s * rate_hz)
    dof = len(inv_var)
    threshold = dof + settings.edge_sigmas * math.sqrt(2.0 * dof / k)  # mean of dof·k χ²(1) / k
    a, b = runs[:, 0], runs[:, 1]
    # Every centre in [a, b) has a quiet window: the run itself is still. Its middle gives the
    # pose's mean; the edges are searched from half a window inside it outward.
    q = np.minimum(half // 2, (b - a) // 4)
    means = signals.means_over(np.column_stack([a + q, b - q]))
    lo, hi = np.maximum(0, a - half - k), np.minimum(n, b + half + k)
    inner_stop, inner_start = np.maximum(a, b - half), np.minimum(b, a + half)
    stop = np.where(b < n, inner_stop + _first_loud(columns, inv_var, means, inner_stop, hi - inner_stop, 1, k,
                                                    threshold) - guard, n)
    start = np.where(a > 0, inner_start - _first_loud(columns, inv_var, means, inner_start - 1, inner_start - lo, -1,
                                                      k, threshold) + guard, 0)
    out = np.column_stack([start, np.minimum(stop, n)])
    same = owner[1:] == owner[:-1]  # neighbours (of one multiple) never share samples
    out[1:, 0] = np.where(same, np.maximum(out[1:, 0], out[:-1, 1]), out[1:, 0])
    keep = (out[:, 1] - out[:, 0] >= min_n) | ((out[:, 0] == 0) & (rest_n > 0))
    short = np.r_[short, np.maximum(out[~keep, 1] - out[~keep, 0], 0) / rate_hz]
    short_owner = np.r_[short_owner, owner[~keep]]
    out, owner = out[keep], owner[keep]
    return [(out[owner == j], np.sort(short[short_owner == j])) for j in range(len(levels))]


def up_directions(means: np.ndarray, zero=None, sensitivity=None) -> np.ndarray:
    """(m, 3) unit gravity direction (up) in body axes from pose means; see module doc."""
    means = np.asarray(means, dtype=float)
    scale = np.ones(3) if sensitivity is None else np.broadcast_to(np.asarray(sensitivity, float), (3,))
    if zero is not None:
        v = (means - zero) / scale
    else:
        v = means / scale
        centre = 0.5 * (v.max(axis=0) + v.min(axis=0)) if len(v) else np.zeros(3)
        if len(v) >= 4:
            # |v - c|² = r²  <=>  |v|² = 2 v·c + (r² - |c|²): linear in (c, r² - |c|²).
            ref = v.mean(axis=0)
            spread = np.sqrt(((v - ref) ** 2).sum(axis=1).mean()) or 1.0
            u = (v - ref) / spread
            design = np.column_stack([2 * u, np.ones(len(u))])
            if np.linalg.cond(design) < 1e6:
                sol = np.linalg.lstsq(design, (u * u).sum(axis=1), rcond=None)[0]
                if sol[3] + sol[:3] @ sol[:3] > 0:
                    centre = ref + spread * sol[:3]
        v = v - centre
    norm = np.linalg.norm(v, axis=1, keepdims=True)
    return v / np.where(norm > 0, norm, 1.0)


def distinct_poses(up: np.ndarray, min_separation_deg: float) -> np.ndarray:
    """(m,) bool: False for a pose within ``min_separation_deg`` of an earlier distinct one."""
    cos_min = math.cos(math.radians(min_separation_deg))
    close = up @ up.T > cos_min  # every pair at once; the choice below is in order
    distinct = np.ones(len(up), dtype=bool)
    i = 0
    # A loop over the distinct poses alone (a long recording repeats a few dozen poses hundreds of
    # times): each rules out the later close ones, and the next one left is distinct.
    while i < len(up):
        distinct[i + 1:] &= ~close[i + 1:, i]  # row k, column i: as the order written
        later = distinct[i + 1:]
        i = i + 1 + int(np.argmax(later)) if later.any() else len(up)
    return distinct


class PrefixMeans:
    """Means of ``values`` (n, d) over any [start, stop) rows (first row taken off: raw counts keep
    their precision). Each call sums the samples once between consecutive interval ends
    (np.add.reduceat, no copy of them) and cumulates only those few sums: no n-long cumulative
    sum is made or kept (on imu_tk's recording joined 16×, 40 MiB at detection's peak for the
    accelerometer and gyro). On integer-valued samples (raw counts) every sum is exact, so the
    means are bit for bit those of one cumulative sum over all samples."""

    def __init__(self, values: np.ndarray):
        self.values = np.asarray(values, dtype=float)
        self.offset = self.values[0]

    def __call__(self, intervals: np.ndarray) -> np.ndarray:
        intervals = np.asarray(intervals, dtype=int).reshape(-1, 2)
        n, d = self.values.shape
        if not len(intervals):
            return np.zeros((0, d))
        cuts, where = np.unique(intervals, return_inverse=True)
        where = where.reshape(-1, 2)
        # reduceat sums [cuts[i], cuts[i + 1]), the last index to the end: a last cut at n is
        # no index (the one before it then runs to n); a last cut below n sums a tail unused.
        inside = cuts[:-1] if cuts[-1] == n else cuts
        sums = np.add.reduceat(self.values, inside, axis=0)[:len(cuts) - 1]
        sums -= np.diff(cuts)[:, None] * self.offset  # about the first row, as the means are taken
        cums = np.zeros((len(cuts), d))
        np.cumsum(sums, axis=0, out=cums[1:])
        return self.offset + (cums[where[:, 1]] - cums[where[:, 0]]) / np.diff(intervals, axis=1)


def interval_means(values: np.ndarray, intervals: np.ndarray) -> np.ndarray:
    """Mean of ``values`` (n, 3) over each [start, stop) of ``intervals`` (m, 2), vectorised.

    Intervals in order and apart (poses, turns) are summed where they lie, by one reduction
    over the samples that makes no copy of them; PrefixMeans' cumulative sum, which pays for
    itself over many queries, would copy and sum all n samples for this one (on imu_tk's
    recording joined 16×, a third of a second and 40 MiB for the gyro's poses)."""
    intervals = np.asarray(intervals, dtype=int).reshape(-1, 2)
    values = np.asarray(values)
    n = len(values)
    starts, stops = intervals[:, 0], intervals[:, 1]
    if not len(intervals) or np.any(stops <= starts) or np.any(starts[1:] < stops[:-1]) or starts[0] < 0 \
            or stops[-1] > n:
        return PrefixMeans(values)(intervals)
    # reduceat sums [index_k, index_k+1): at the starts the intervals, at the stops the gaps between
    # them (a gap of none gives one sample, unused); the last interval runs to its stop or the end.
    edges = intervals.ravel()
    sums = np.add.reduceat(values, edges[:-1] if stops[-1] == n else edges, axis=0, dtype=float)[0::2]
    return sums / (stops - starts)[:, None]


def _poses(settings, multiple, zero, sensitivity, intervals, means, short) -> Poses:
    up = up_directions(means, zero, sensitivity)
    return Poses(intervals=intervals, means=means, up=up,
                 distinct=distinct_poses(up, settings.min_separation_deg), multiple=float(multiple), short_s=short)


def pose_candidates(acc: np.ndarray, rate_hz: float, settings: DetectorSettings,
                    zero=None, sensitivity=None, gyro: np.ndarray | None = None,
                    noise: NoiseLevel | None = None) -> list[Poses]:
    """The poses for each of ``settings.multiples``, the noise level and the window statistic
    measured once (the noise level may be given), every multiple's intervals found in one pass."""
    acc = np.asarray(acc, dtype=float)
    noise = noise_level(acc, rate_hz, settings, gyro) if noise is None else noise
    signals = _EdgeSignals.of(acc, rate_hz, noise, settings, gyro)
    found = _static_intervals(signals, rate_hz, noise, settings.multiples, settings)
    # Every multiple's pose means in one pass over the samples, then split per multiple.
    counts = np.cumsum([len(intervals) for intervals, _ in found])[:-1]
    means = np.split(signals.means[0](np.vstack([intervals for intervals, _ in found])), counts)
    return [_poses(settings, m, zero, sensitivity, intervals, pose_means, short)
            for m, (intervals, short), pose_means in zip(settings.multiples, found, means)]


_AXES = np.vstack([np.eye(3), -np.eye(3)])
_AXIS_NAMES = ["x up", "y up", "z up", "x down", "y down", "z down"]


def norm_design(up: np.ndarray) -> float:
    """Smallest singular value per √pose of the norm method's regressors at these directions.

    (Kᵀ⁻¹-weighted) |m - b|² = g² is linear in [x², y², z², xy, xz, yz, x, y, z, 1]; on unit
    vectors x² + y² + z² = 1, so z² is dropped and the nine left must be independent."""
    if len(up) < 9:
        return 0.0
    x, y, z = up.T
    regressors = np.column_stack([x * x, y * y, x * y, x * z, y * z, x, y, z, np.ones(len(up))])
    return float(np.linalg.svd(regressors, compute_uv=False)[-1] / math.sqrt(len(up)))


def check_spread(up: np.ndarray, min_poses: int, cover_deg: float = 60.0,
                 min_design: float = DetectorSettings.min_design) -> SpreadReport:
    """Is this set of distinct up vectors enough for the accelerometer's norm calibration?"""
    up = np.asarray(up, dtype=float).reshape(-1, 3)
    count = len(up)
    covered = (up @ _AXES.T).max(axis=0) >= math.cos(math.radians(cover_deg)) if count else np.zeros(6, bool)
    missing = [name for name, c in zip(_AXIS_NAMES, covered) if not c]
    design = norm_design(up)
    where = f"add poses with {', '.join(missing)} (within {cover_deg:g}° of vertical)"
    if count < min_poses:
        hint = where if missing else "add poses tilted between the axes (a cube corner up)"
        message = f"only {count} distinct poses (need at least {min_poses}): {hint}"
    elif missing:
        message = f"{count} distinct poses, but none with {', '.join(missing)}: {where}"
    elif design < min_design:
        message = (f"{count} distinct poses, but too alike for the norm method (design {design:.2g} < "
                   f"{min_design:g}): add poses with two or three axes tilted (a cube corner up)")
    else:
        message = f"{count} distinct poses, well spread"
    ok = count >= min_poses and not missing and design >= min_design
    return SpreadReport(count=count, ok=ok, missing=missing, design=design, message=message)


def too_short(poses: Poses, settings: DetectorSettings) -> str:
    """What a refusal adds when still stretches were seen that were held too briefly to be poses
    ("" when none were)."""
    short = poses.short_s[poses.short_s > 0]
    if not len(short):
        return ""
    lo, hi = f"{short.min():.1f}", f"{short.max():.1f}"
    span = f"{lo}-{hi} s" if lo != hi else f"{lo} s"
    were = "were" if len(short) != 1 else "was"
    return (f"; {len(short)} more still stretch{'es' * (len(short) != 1)} of {span} {were} seen, held under the "
            f"{settings.min_static_s:g} s a pose must last: hold each pose {settings.min_static_s:g} s or more, or "
            f"give --min-still S to take shorter ones (their means are noisier)")


def require_poses(poses: Poses, settings: DetectorSettings) -> SpreadReport:
    """The spread report of the distinct poses; DetectionError with its message when not ok."""
    report = check_spread(poses.up[poses.distinct], settings.min_poses, settings.cover_deg,
                          settings.min_design)
    if not report.ok:
        raise TooFewPoses(report.message)
    return report
