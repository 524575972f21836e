"""Allan deviation of a static record and the IEEE Std 952 noise terms read off it (paper eq. 3).

Inputs are rate-type signals in SI units (m/s² or rad/s); the deviation itself comes from
allantools' overlapping estimator, which integrates the rate to θ exactly as eq. 3 does.
"""
from __future__ import annotations

from dataclasses import dataclass

import allantools
import numpy as np
from scipy.optimize import nnls

MIN_CLUSTERS = 3        # below this an explicit tau says nothing; such taus are dropped
DEFAULT_CLUSTERS = 9    # default taus stop at N/9: the last points are noisy enough already
READ_CLUSTERS = 8       # noise_terms ignores taus with fewer independent clusters than this
FLICKER_FLOOR = 0.664   # ADEV of flicker noise is flat at 0.664·B (IEEE Std 952)
G0 = 9.80665            # m/s² per g, for mg
_DEG = 180.0 / np.pi
# The floor is shown where the white noise no longer dominates the deviation: at the curve's
# lowest point its share of the variance (N²/τ over σ²) is at most this. Past the white/floor
# crossing (share 1/2) the curve flattens (log slope -share/2); at 0.55 it lies at most
# 1/√0.45 = 1.49× above the floor, and a minimum turned up by a rate random walk (share 1/2)
# passes. Above it the curve is still falling along its -1/2 line and its lowest point is
# only an upper bound on the floor.
WHITE_SHARE_AT_FLOOR = 0.55
# ... and the part above the white line must stand out of the scatter of the deviation there
# (relative 1σ about 1/√clusters): on a short record the last, few-cluster points scatter up
# off the -1/2 line and bend the fit up like a floor would.
FLOOR_SIGMAS = 2.0
TOO_SHORT = "(the record is too short to show the floor)"


def _default_ms(n: int) -> np.ndarray:
    top = n // DEFAULT_CLUSTERS
    if top < 1:
        return np.empty(0, dtype=np.int64)
    k = int(np.ceil(10 * np.log10(top))) + 1
    return np.unique(np.round(np.geomspace(1, top, max(k, 1))).astype(np.int64))


def allan_deviation(samples, rate_hz: float, taus=None):
    """Overlapping Allan deviation per axis of a rate signal (n,) or (n, k) sampled at rate_hz.

    Returns (taus, adev, n_clusters): taus (s) snapped to whole samples, adev shaped (len(taus),)
    or (len(taus), k) in the input unit, and the number of independent clusters of length tau
    behind each point. Explicit taus with fewer than MIN_CLUSTERS clusters are dropped.
    """
    x = np.asarray(samples, dtype=float)
    if x.ndim not in (1, 2) or x.size == 0:
        raise ValueError(f"samples must be a non-empty (n,) or (n, k) array, got shape {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ValueError("samples contain NaN or infinite values; cut the record around the gap")
    if not (np.isfinite(rate_hz) and rate_hz > 0):
        raise ValueError(f"rate_hz must be positive, got {rate_hz}")
    n = x.shape[0]
    if taus is None:
        ms = _default_ms(n)
    else:
        t = np.atleast_1d(np.asarray(taus, dtype=float))
        if t.ndim != 1 or not np.all(np.isfinite(t) & (t > 0)):
            raise ValueError("taus must be a 1-D array of positive seconds")
        ms = np.unique(np.round(t * rate_hz).astype(np.int64))
        ms = ms[(ms >= 1) & (n // np.maximum(ms, 1) >= MIN_CLUSTERS)]
    if ms.size == 0:
        raise ValueError(f"{n} samples at {rate_hz:g} Hz are too few: no tau has "
                         f"{MIN_CLUSTERS} clusters (default taus need {DEFAULT_CLUSTERS})")
    cols = x.reshape(n, -1)
    adev = np.empty((ms.size, cols.shape[1]))
    for j in range(cols.shape[1]):
        # Pass taus that round back to exactly our m; allantools then computes eq. 3 for each.
        t_out, dev, _, _ = allantools.oadev(cols[:, j], rate=rate_hz, data_type="freq",
                                            taus=ms / rate_hz)
        if t_out.size != ms.size:  # would mean allantools dropped a tau behind our back
            raise RuntimeError("allantools returned an unexpected tau list")
        adev[:, j] = dev
    return ms / rate_hz, (adev[:, 0] if x.ndim == 1 else adev), n // ms


@dataclass(frozen=True)
class NoiseTerms:
    """IEEE Std 952 terms of one axis, in SI: white (N, unit·√s), bias_instability (B, unit),
    tau_at_minimum (s), rate_random_walk (K, unit/√s, None without a +1/2 region).

    ``floor_reached`` False: the curve was still falling (white noise still dominant) where the
    record ends, so ``bias_instability`` is only an upper bound (the flicker floor lies at or
    below the lowest deviation the record reached), not a reading."""

    white: float
    bias_instability: float
    tau_at_minimum: float
    rate_random_walk: float | None
    unit: str = ""
    floor_reached: bool = True

    def describe(self, kind: str) -> dict[str, str]:
        """Operator-unit strings, e.g. {"ARW": "0.15 deg/sqrt(h)", ...}, for kind
        "angular_rate" (rad/s in) or "specific_force" (m/s² in)."""
        if kind == "angular_rate":
            names = ("ARW", "bias instability", "RRW")
            scale = (_DEG * 60, _DEG * 3600, _DEG * 3600 * 60)
            units = ("deg/sqrt(h)", "deg/h", "deg/h/sqrt(h)")
        elif kind == "specific_force":
            # mg for B and K keeps the accelerometer numbers on the scale datasheets use.
            names = ("VRW", "bias instability", "acceleration RW")
            scale = (60.0, 1e3 / G0, 1e3 / G0 * 60)
            units = ("m/s/sqrt(h)", "mg", "mg/sqrt(h)")
        else:
            raise ValueError(f"kind must be 'angular_rate' or 'specific_force', got {kind!r}")
        values = (self.white, self.bias_instability, self.rate_random_walk)
        out = {name: ("none" if v is None else f"{v * s:.3g} {u}")
               for name, v, s, u in zip(names, values, scale, units)}
        if not self.floor_reached:
            out["bias instability"] = f"≤ {out['bias instability']} {TOO_SHORT}"
        out["tau at minimum"] = f"{self.tau_at_minimum:.4g} s"
        return out


def _longest_run(mask: np.ndarray) -> np.ndarray:
    """Indices of the longest run of True in mask (empty if none)."""
    edges = np.flatnonzero(np.diff(np.concatenate(([0], mask.astype(np.int8), [0]))))
    if edges.size == 0:
        return np.empty(0, dtype=np.int64)
    starts, stops = edges[::2], edges[1::2]
    i = np.argmax(stops - starts)
    return np.arange(starts[i], stops[i])


def _local_slope(lt: np.ndarray, la: np.ndarray, half: int = 2) -> np.ndarray:
    """Log-log slope from a straight-line fit over +-half neighbours: exact on a power law (also
    at the ends, where a running mean would bend it) and steadier than a two-point difference."""
    out = np.empty_like(lt)
    for i in range(lt.size):
        s = slice(max(i - half, 0), min(i + half + 1, lt.size))
        x = lt[s] - lt[s].mean()
        out[i] = np.dot(x, la[s]) / np.dot(x, x)
    return out


def _power_law_fit(t: np.ndarray, a: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Fitted ADEV of the IEEE Std 952 model var = sum C_n tau^n, n = -2..2 (quantisation, white,
    flicker floor, rate random walk, rate ramp), C_n >= 0, in relative error weighted by w."""
    design = t[:, None] ** np.arange(-2, 3)[None, :] / (a**2)[:, None]
    norm = np.linalg.norm(design, axis=0)  # tau^±2 columns span 1e12: scale for nnls
    c, _ = nnls(design * np.sqrt(w)[:, None] / norm, np.sqrt(w))
    return np.sqrt(design @ (c / norm)) * a


def noise_terms(taus, adev, *, unit: str = "", n_clusters=None) -> NoiseTerms:
    """Read N, B, the minimum and K off one axis' Allan deviation curve as IEEE Std 952 does.

    n_clusters (from allan_deviation) weights the reading; without it the curve is assumed to
    end at DEFAULT_CLUSTERS clusters, as the default taus do.
    """
    t = np.asarray(taus, dtype=float)
    a = np.asarray(adev, dtype=float)
    if t.ndim != 1 or a.shape != t.shape:
        raise ValueError(f"taus and adev must be equal-length 1-D arrays, got {t.shape}, {a.shape}")
    keep = np.isfinite(t) & np.isfinite(a) & (t > 0) & (a > 0)
    nc = None if n_clusters is None else np.broadcast_to(np.asarray(n_clusters, float), t.shape)[keep]
    order = np.argsort(t[keep])
    t, a = t[keep][order], a[keep][order]
    # Without counts, assume the curve ends where the default taus end.
    nc = DEFAULT_CLUSTERS * t[-1:] / t if nc is None else nc[order]
    t, a, nc = t[nc >= READ_CLUSTERS], a[nc >= READ_CLUSTERS], nc[nc >= READ_CLUSTERS]
    if t.size < 5:
        raise ValueError(f"need at least 5 usable points on the Allan curve, got {t.size}")
    # A point's relative scatter goes as 1/sqrt(clusters); the cap stops the thousands of
    # near-identical short-tau points from outvoting the model's fit of the bottom.
    w = np.minimum(nc, 1000.0)
    lt, la = np.log(t), np.log(a)
    slope = _local_slope(lt, la)
    # The raw minimum of a flat, noisy bottom sits 1-2 sigma low (20-40 % for a few-hour
    # record); the minimum of the weighted power-law fit uses the whole curve instead.
    fitted = _power_law_fit(t, a, w)
    i_min = int(np.argmin(fitted))

    def line(idx, gradient):
        # Fixed slope: only the intercept (log a - slope log t) is fitted, weighted.
        return float(np.exp(np.average(la[idx] - gradient * lt[idx], weights=w[idx])))

    head = np.arange(i_min + 1)
    white_run = head[_longest_run((slope[head] >= -0.6) & (slope[head] <= -0.4))]
    if white_run.size == 0:
        white_run = np.arange(min(3, t.size))
    white = line(white_run, -0.5)  # sigma = N/sqrt(tau): N is the line's value at tau = 1 s

    tail = np.arange(i_min, t.size)
    walk_run = tail[_longest_run((slope[tail] >= 0.4) & (slope[tail] <= 0.6))]
    # Two or three rising points in the noisy tail are no evidence of a random walk.
    rrw = line(walk_run, 0.5) * np.sqrt(3.0) if walk_run.size >= 4 else None  # value at 3 s

    white_share = white**2 / t[i_min] / fitted[i_min] ** 2
    above_white = 1.0 - np.sqrt(min(white_share, 1.0))  # relative height of the fit over the white line
    floor_reached = bool(white_share <= WHITE_SHARE_AT_FLOOR and above_white > FLOOR_SIGMAS / np.sqrt(nc[i_min]))
    return NoiseTerms(white=white, bias_instability=float(fitted[i_min]) / FLICKER_FLOOR,
                      tau_at_minimum=float(t[i_min]), rate_random_walk=rrw, unit=unit,
                      floor_reached=floor_reached)


def plot_allan(taus, adev, terms, path, title: str = "", kind: str | None = None,
               overwrite: bool = True) -> None:
    """Log-log PNG like paper Figs. 2-4: one line per axis, its fitted -1/2 (dashed) and +1/2
    (dotted) lines and its minimum (circle). terms: one NoiseTerms per column of adev; kind
    ("angular_rate"/"specific_force") puts the terms in operator units in the legend."""
    # Figure + Agg canvas rather than pyplot: no global backend switch in a process that may
    # also run the TUI, and nothing is imported until a plot is asked for.
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    t = np.asarray(taus, dtype=float)
    a = np.asarray(adev, dtype=float).reshape(t.size, -1)
    terms = [terms] if isinstance(terms, NoiseTerms) else list(terms)
    if len(terms) != a.shape[1]:
        raise ValueError(f"{a.shape[1]} axes but {len(terms)} NoiseTerms")
    names = "xyz" if a.shape[1] == 3 else [str(i) for i in range(a.shape[1])]
    fig = Figure(figsize=(8, 5), dpi=110)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    for j, (name, nt) in enumerate(zip(names, terms)):
        color, label = f"C{j}", name
        if kind is not None:
            label += ": " + ", ".join(f"{k} {v}" for k, v in nt.describe(kind).items())
        ax.loglog(t, a[:, j], color=color, lw=1.5, label=label)
        ax.loglog(t, nt.white / np.sqrt(t), color=color, ls="--", lw=0.8)
        if nt.rate_random_walk is not None:
            ax.loglog(t, nt.rate_random_walk * np.sqrt(t / 3.0), color=color, ls=":", lw=0.8)
        ax.plot(nt.tau_at_minimum, nt.bias_instability * FLICKER_FLOOR, "o", color=color, ms=8,
                mfc="none", mew=1.5)
    ax.set_ylim(a[a > 0].min() / 2, a.max() * 2)  # keep the fitted lines from stretching the axis
    ax.set_xlabel("averaging time τ (s)")
    unit = terms[0].unit
    ax.set_ylabel(f"Allan deviation σ(τ) ({unit})" if unit else "Allan deviation σ(τ)")
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    ax.plot([], [], "k--", lw=0.8, label="slope -1/2 fit: N at τ = 1 s")
    ax.plot([], [], "k:", lw=0.8, label="slope +1/2 fit: K at τ = 3 s")
    ax.plot([], [], "ko", mfc="none", label="fitted minimum = 0.664·B")
    # Below the axes: inside, it hides the bottom of the curve, which is what the plot is for.
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(0.0, -0.12))
    import io

    from fieldcal.atomic import write_atomically

    png = io.BytesIO()  # then written by the one rule: never through a link planted at ``path``
    fig.savefig(png, format="png", bbox_inches="tight")
    write_atomically(path, png.getvalue(), overwrite=overwrite, hint="give --force to replace it")


GAP_FACTOR = 3.0        # a step this many local sample intervals long: samples are missing
RATE_BLOCK = 100        # samples per block for the local sample interval (a block's median)
RATE_TOLERANCE = 0.10   # neighbouring blocks whose intervals differ by more are at another rate


@dataclass(frozen=True)
class Stretch:
    """Rows [start, stop) of a record sampled at one rate without a gap."""

    start: int
    stop: int
    rate_hz: float

    @property
    def seconds(self) -> float:
        return (self.stop - self.start) / self.rate_hz


def regular_stretches(t: np.ndarray) -> tuple[list[Stretch], list[str]]:
    """Split a strictly increasing time column at gaps and rate changes (eq. 3 assumes evenly
    spaced samples: a gap or another rate inside a cluster makes its Allan deviation wrong).

    The local sample interval is the median of each block of RATE_BLOCK intervals, so a gap does
    not hide in it and timestamp jitter does not split the record. Returns the stretches, and one
    phrase per break ("a 100 s gap after row 5000 (t = 50 s)", "the rate changes from 100 Hz to
    50 Hz at row 9001"), rows 1-based as in the file's data rows.
    """
    t = np.asarray(t, dtype=float)
    dt = np.diff(t)
    if dt.size == 0:
        return [Stretch(0, len(t), 0.0)], []
    n_blocks = -(-dt.size // RATE_BLOCK)
    padded = np.full(n_blocks * RATE_BLOCK, np.nan)
    padded[: dt.size] = dt
    local = np.nanmedian(padded.reshape(n_blocks, RATE_BLOCK), axis=1)
    gaps = np.flatnonzero(dt > GAP_FACTOR * np.repeat(local, RATE_BLOCK)[: dt.size])
    notes = [f"a {dt[i]:.4g} s gap after row {i + 1} (t = {t[i]:.6g} s)" for i in gaps]
    cuts = set((gaps + 1).tolist())
    for b in np.flatnonzero(np.abs(local[1:] / local[:-1] - 1) > RATE_TOLERANCE) + 1:
        # the new rate starts at the first interval of its size in the two blocks around the change
        window = dt[(b - 1) * RATE_BLOCK: (b + 1) * RATE_BLOCK]
        row = (b - 1) * RATE_BLOCK + int(np.argmax(np.abs(window / local[b] - 1) <= RATE_TOLERANCE))
        notes.append(f"the rate changes from {1 / local[b - 1]:.4g} Hz to {1 / local[b]:.4g} Hz "
                     f"at row {row + 1}")
        cuts.add(int(row))
    bounds = [0, *sorted(c for c in cuts if 0 < c < len(t)), len(t)]
    stretches = []
    for lo, hi in zip(bounds[:-1], bounds[1:]):
        # gap-free: the mean interval, which timestamp jitter does not bias as a median can
        stretches.append(Stretch(lo, hi, (hi - lo - 1) / (t[hi - 1] - t[lo]) if hi - lo > 1 else 0.0))
    return stretches, notes
