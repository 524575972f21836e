"""The Ferraris protocol in a recording: six axis-aligned static poses and full turns.

Ferraris et al. (1995), the protocol of imucal and of many labs: the unit lies on each of its six
faces (x, y, z up and down), and turns once (or n times) through 360° about each axis while that
axis is vertical. Six directions cannot give the norm method its nine unknowns, but aligned
poses can: their true inputs are known, ±g along the axis that is up, so the accelerometer is
Ferraris's closed form (``fieldcal.solvers.classic.solve_six_position``, full K: it also holds
the unit's rotation relative to its faces), each axis's bias from the two faces where it is
vertical, where a placement's tilt does not reach it at first order.

The gyroscope comes from the turns: a turn about the vertical integrates to K·up·θ with θ = ±2πn,
up the vertical in the accelerometer's frame, once the still reading is taken off. That still
reading is the mean of the static intervals on either side of the turn, in the same pose: it
holds the bias, the vertical Earth rate and the g-sensitivity at that pose, all of which stay
constant through a turn about the vertical. Over all turns, K = W·C⁻¹ with W the integrals and
C the up vectors times their angles (least squares when there are more than three).

What a turn's 1σ holds: the white noise integrated over the turn, the still reading's own noise
times the turn's duration, the horizontal Earth rate (at an unknown heading: the still reading
taken off holds it for the whole turn, while the turning body sees it go round, earth_lever),
the accelerometer's error in the turn axis's direction, and the hand's error in bringing the
unit back to its heading, ``HEADING_SIGMA_DEG``, which nothing in the data can see. The
accelerometer's error in the turn axis is taken from its face means (turn_up_variance). The bias
is the mean of the six poses' gyro means, its σ their scatter (g-sensitivity and bias shifts)
over √6, never below the bias instability all faces share: a device config's, else measured
from the still intervals (estimated_turns_noise).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from fieldcal.earth import EARTH_RATE
from fieldcal.model import ANGULAR_RATE, SPECIFIC_FORCE
from fieldcal.recording.detect import TooFewPoses, interval_means
from fieldcal.recording.noise_estimate import MeasuredNoise, bias_instability, flicker_covariance
from fieldcal.calibration import Calibration, SolverDiagnostics
from fieldcal.model import FULL_PARAM_NAMES
from fieldcal.solvers.classic import SIX_FACES, _parameter_covariance, solve_six_position

ALIGNED_DEG = 15.0  # a pose this close to an axis, up or down, is that axis's aligned pose
SAME_POSE_DEG = 5.0  # a turn's start and end poses are this close
MIN_TURN_FRACTION = 0.75  # of a full turn, in a known rate unit
HALVES = 2  # windows per still interval in which the gyro's bias instability is measured
HEADING_SIGMA_DEG = 0.5  # 1σ of the hand's return to the same heading after a turn
# A scale factor drifts with the unit's temperature, and a Ferraris session sees each axis at one
# time only (x first, z last), so the scale is found as it was then, not as it is on average. 1σ
# of that drift: the triad's temperature coefficient (the device config's scale_tempco_ppm_per_k,
# else this typical MEMS one) times the temperature's move (the recording's temperature column,
# else this warming from the session's start to its end, linear in time).
ASSUMED_TEMPCO_PPM_PER_K = 100.0
ASSUMED_WARMING_K = 2.0
_AXES = SIX_FACES  # +x, +y, +z, −x, −y, −z


@dataclass(frozen=True)
class Turns:
    """Full turns found: ``spans`` (k, 2) [start, stop) samples, ``before``/``after`` (k,) the
    static intervals on either side, ``angles`` (k,) rad (±2πn), ``up`` (k, 3) the vertical."""

    spans: np.ndarray
    before: np.ndarray
    after: np.ndarray
    angles: np.ndarray
    up: np.ndarray


def aligned_axes(up: np.ndarray) -> np.ndarray | None:
    """(m,) index into ±x, ±y, ±z (0..5) of each pose's axis, or None unless every pose is within
    ALIGNED_DEG of one and all six are there."""
    cosines = up @ _AXES.T
    nearest = np.argmax(cosines, axis=1)
    close = cosines[np.arange(len(up)), nearest] >= math.cos(math.radians(ALIGNED_DEG))
    return nearest if close.all() and len(set(nearest.tolist())) == 6 else None


def face_poses(up: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """(mask of the poses within ALIGNED_DEG of an axis, their axes) when those poses hold all six
    faces and some other pose is tilted: the six faces alone fix bias and scale (Ferraris) where
    the norm method lacks poses; None otherwise (aligned_axes takes a session of faces only)."""
    cosines = up @ _AXES.T
    nearest = np.argmax(cosines, axis=1)
    close = cosines[np.arange(len(up)), nearest] >= math.cos(math.radians(ALIGNED_DEG))
    if close.all() or len(set(nearest[close].tolist())) != 6:
        return None
    return close, nearest[close]


FACE_NAMES = ("x up", "y up", "z up", "x down", "y down", "z down")  # _AXES order


def missing_faces(up: np.ndarray) -> list[str] | None:
    """The faces (FACE_NAMES) no pose lies on, when every pose lies within ALIGNED_DEG of one
    (a Ferraris session short of faces); None when some pose is tilted (hand-held poses)."""
    cosines = up @ _AXES.T
    nearest = np.argmax(cosines, axis=1)
    if not len(up) or np.any(cosines[np.arange(len(up)), nearest] < math.cos(math.radians(ALIGNED_DEG))):
        return None
    return [FACE_NAMES[a] for a in range(6) if a not in set(nearest.tolist())]


def session_times(t: np.ndarray, intervals: np.ndarray) -> np.ndarray:
    """(m,) each interval's middle relative to the session's middle, as a fraction of its length
    (−½ … ½): where a linear drift over the session stands at that interval."""
    span = max(float(t[-1] - t[0]), 1e-9)
    middle = 0.5 * (t[intervals[:, 0]] + t[intervals[:, 1] - 1])
    return (middle - 0.5 * (t[0] + t[-1])) / span


@dataclass(frozen=True)
class ScaleDrift:
    """What the scale factors' temperature drift can be: ``ppm_per_k`` (1σ, per triad name; a
    triad not named gets ASSUMED_TEMPCO_PPM_PER_K) and the recording's ``t`` and ``temperature``
    (per sample, K or °C; None: ASSUMED_WARMING_K, linear over the session)."""

    t: np.ndarray
    temperature: np.ndarray | None = None
    ppm_per_k: dict = field(default_factory=dict)

    def at(self, name: str, spans: np.ndarray) -> np.ndarray:
        """(k,) 1σ of the scale's relative change from the session's mean over each [start, stop)
        of ``spans`` (one drift for the whole session: they move together)."""
        tempco = float(self.ppm_per_k.get(name, ASSUMED_TEMPCO_PPM_PER_K))
        if self.temperature is None:
            moved = ASSUMED_WARMING_K * session_times(self.t, spans)
        else:
            temperature = np.asarray(self.temperature, dtype=float)
            cums = np.r_[0.0, np.cumsum(temperature)]
            moved = (cums[spans[:, 1]] - cums[spans[:, 0]]) / np.diff(spans, axis=1)[:, 0] - temperature.mean()
        return tempco * 1e-6 * moved

    def note(self, name: str) -> str:
        """What the σ of triad ``name``'s scale factors hold, and what was assumed, for the output."""
        if name in self.ppm_per_k:
            source = f"the device config's {float(self.ppm_per_k[name]):g} ppm/K"
        else:
            source = (f"an assumed {ASSUMED_TEMPCO_PPM_PER_K:g} ppm/K (the device config gives no "
                      "scale_tempco_ppm_per_k)")
        over = (f"an assumed {ASSUMED_WARMING_K:g} K warming (the recording has no temperature)"
                if self.temperature is None else f"the recorded {np.ptp(self.temperature):.2g} K")
        return (f"σ of the scale factors include their temperature drift, {source} over {over}: each axis is "
                "seen at one time only")


def scale_drift_covariance(values: np.ndarray, offset: np.ndarray, drift: np.ndarray) -> np.ndarray:
    """Covariance (flattened, position-major) of readings ``values`` (m, 3) that a drift of each
    axis's scale, independent per axis and 1σ ``drift`` (m,) relative at each (ScaleDrift.at),
    moves from the session's mean: each axis's output less its ``offset`` grows by the same
    fraction at all of them, in proportion to its drift."""
    shift = (np.asarray(values, dtype=float) - offset) * drift[:, None]  # (m, 3)
    cov = np.zeros((shift.size, shift.size))
    for j in range(3):  # per output axis: one drift for all positions
        v = np.zeros_like(shift)
        v[:, j] = shift[:, j]
        cov += np.outer(v.ravel(), v.ravel())
    return cov


def placement_runs(axes: np.ndarray) -> np.ndarray:
    """(m,) each interval's placement, numbered from 0: a run of consecutive intervals on one
    face (only a turn about the vertical between them, which keeps the tilt) is one placement;
    the face set down again later is another."""
    axes = np.asarray(axes)
    return np.cumsum(np.r_[True, axes[1:] != axes[:-1]]) - 1


def first_placements(axes: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """(6, m) weights that average each face's first placement: the first run of consecutive
    intervals on that face (a turn about the vertical between them keeps the placement), each
    interval by its samples. A face set down again later is another placement, another tilt
    and time: its mean differs by more than the noise (imucal's session: 8 mm/s² on +x), and
    averaging two placements matches neither, so the calibrated faces' norms miss g."""
    weights = np.zeros((6, len(axes)))
    run = placement_runs(axes)
    for a in range(6):  # a loop over faces
        on_face = np.flatnonzero(axes == a)
        chosen = on_face[run[on_face] == run[on_face[0]]]
        weights[a, chosen] = counts[chosen] / counts[chosen].sum()
    return weights


def solve_aligned_accelerometer(name: str, unit: str, means: np.ndarray, axes: np.ndarray,
                                gravity: float, covariance: np.ndarray, counts: np.ndarray,
                                drift: tuple[np.ndarray, str] | None = None) -> Calibration:
    """Ferraris's six-position solution (``fieldcal.solvers.classic.solve_six_position``: each
    axis's bias from its own up and down faces, the faces' norms fitted) on each face's first
    placement (first_placements). ``covariance``: of the flattened interval means (noise);
    the σ are scaled up by χ²/dof when the faces scatter more than that (placement errors),
    never down. ``counts``: each interval's samples. ``drift``: the scale's temperature drift at
    each interval and its note (ScaleDrift.at); None: no drift."""
    average = first_placements(axes, counts)
    faces = average @ means
    A = np.kron(average, np.eye(3))
    face_cov = A @ covariance @ A.T
    sol, ratio = solve_six_position(faces, gravity, name, SPECIFIC_FORCE, unit, face_cov)
    message = sol.diagnostics.message
    if drift is not None:  # the drift hides in the scale, not in the residuals: added after χ²
        # The offset is the faces' mean, where ±g cancels.
        face_cov = face_cov * max(ratio, 1.0) + A @ scale_drift_covariance(means, faces.mean(axis=0), drift[0]) @ A.T
        message = f"{message}; {drift[1]}"
    elif ratio > 1.0:
        face_cov = face_cov * ratio
    if drift is not None or ratio > 1.0:
        sol = replace(sol, **_six_position_sigma(sol, faces, gravity, face_cov),
                      diagnostics=replace(sol.diagnostics, message=message))
    return sol


def _six_position_sigma(sol: Calibration, faces: np.ndarray, gravity: float, face_cov: np.ndarray) -> dict:
    """The covariance and σ of ``sol``'s parameters for faces of covariance ``face_cov``."""
    widened = solve_six_position(faces, gravity, sol.name, sol.kind, sol.output_unit, face_cov)[0]
    return dict(covariance=widened.covariance, sigma=widened.sigma)


def up_vectors(acc: Calibration, means: np.ndarray) -> np.ndarray:
    a = acc.calibrate(means)
    return a / np.linalg.norm(a, axis=1, keepdims=True)


def sample_durations(n: int, rate_hz: float, t: np.ndarray | None) -> np.ndarray:
    """(n,) s each sample holds: until the next timestamp (the last one the median step), or
    1/rate_hz each without timestamps."""
    if t is None:
        return np.full(n, 1.0 / rate_hz)
    return np.diff(t, append=t[-1] + float(np.median(np.diff(t))))


def earth_lever(gyro: np.ndarray, rate_hz: float, spans: np.ndarray, reference: np.ndarray,
                angles: np.ndarray, t: np.ndarray | None = None) -> np.ndarray:
    """(k,) s: what multiplies the horizontal Earth rate in each turn's integral error. Still, the
    pose holds that rate fixed in the body, and the still reading taken off removes it for the
    whole turn, T; turning, the body sees it go round, which integrates to ∫e^{iφ(t)}dt, zero over
    a uniform turn but not where the turn starts and stops slowly near the pose's heading. So
    the error is |∫e^{iφ}dt − T| times the rate, in the horizontal direction of an unknown
    heading; φ from the gyro itself (the share of the turn's integral reached, times its angle)."""
    dt = sample_durations(len(gyro), rate_hz, t)
    lever = np.zeros(len(spans))
    for i, ((a, b), still, angle) in enumerate(zip(spans, reference, angles)):  # a loop over turns
        step = (np.asarray(gyro[a:b], dtype=float) - still) * dt[a:b, None]
        along = step @ (step.sum(axis=0) / np.linalg.norm(step.sum(axis=0)))
        phi = angle * (np.cumsum(along) - 0.5 * along) / along.sum()  # at each sample's middle
        lever[i] = abs(np.sum(dt[a:b] * np.exp(1j * phi)) - dt[a:b].sum())
    return lever


def integrals(gyro: np.ndarray, rate_hz: float, spans: np.ndarray, reference: np.ndarray,
              t: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """∫(gyro − reference) dt over each [start, stop) of ``spans`` (k, 3), and their durations
    (k,) in s. With timestamps ``t`` each sample holds until the next one, so a logger's dropped
    samples and jitter do not shorten a turn (at a nominal rate a 0.5 % drop is a 0.5 % scale
    error); without, every sample lasts 1/rate_hz."""
    dt = sample_durations(len(gyro), rate_hz, t)
    cums = np.cumsum(np.r_[np.zeros((1, 3)), (gyro - gyro[0]) * dt[:, None]], axis=0)
    times = np.r_[0.0, np.cumsum(dt)]
    duration = times[spans[:, 1]] - times[spans[:, 0]]
    return cums[spans[:, 1]] - cums[spans[:, 0]] - (reference - gyro[0]) * duration[:, None], duration


EDGE_SIGMAS = 8.0  # a pose's end whose 0.1 s gyro mean is this many σ from the pose's median: turning
# Of a pose: more is not a turn's slow start but a pose that is not still. A turntable's 2 s ramp
# before a 3 s pose is 40 % of it (0.4 left such a ramp in the still reading: a 21 % scale error).
MAX_TRIM = 0.6


def trim_turning_edges(gyro: np.ndarray, intervals: np.ndarray, variance: np.ndarray,
                       rate_hz: float) -> np.ndarray:
    """The static intervals without the ends where the gyro already turns. A turntable's slow
    start is invisible to the accelerometer, and in raw counts the turning detector cannot tell a
    slow turn's rate from a still shift; inside an aligned pose the still reading is one value,
    so a 0.1 s mean more than EDGE_SIGMAS σ of that mean from the pose's median, at either end,
    is the turn: it is cut off (at most MAX_TRIM of the pose)."""
    k = max(1, round(0.1 * rate_hz))
    sigma = np.sqrt(np.asarray(variance, dtype=float) / k)
    out = np.array(intervals, dtype=int).copy()
    for i, (a, b) in enumerate(intervals):  # a loop over poses, not samples
        values = np.asarray(gyro[a:b], dtype=float)
        if len(values) < 4 * k:
            continue
        cums = np.cumsum(np.r_[np.zeros((1, 3)), values], axis=0)
        means = (cums[k:] - cums[:-k]) / k  # the 0.1 s mean starting at each sample
        away = np.any(np.abs(means - np.median(values, axis=0)) > EDGE_SIGMAS * sigma, axis=1)
        still = np.flatnonzero(~away)
        if not len(still):
            continue
        start, stop = a + still[0], a + still[-1] + k
        if (start - a) + (b - stop) <= MAX_TRIM * (b - a):
            out[i] = (start, stop)
    return out


def find_turns(gyro: np.ndarray, rate_hz: float, intervals: np.ndarray, up: np.ndarray,
               units_per_rad_s: float | None, t: np.ndarray | None = None) -> Turns:
    """The motions that leave a pose and come back to it through a full turn (or several)."""
    still = interval_means(gyro, intervals)
    spans = np.column_stack([intervals[:-1, 1], intervals[1:, 0]])
    same = np.einsum("ij,ij->i", up[:-1], up[1:]) >= math.cos(math.radians(SAME_POSE_DEG))
    integral = integrals(gyro, rate_hz, spans, 0.5 * (still[:-1] + still[1:]), t)[0]
    size = np.linalg.norm(integral, axis=1)
    if units_per_rad_s is not None:
        turns = np.round(size / units_per_rad_s / (2 * math.pi))
        full = same & (turns >= 1) & (size / units_per_rad_s >= 2 * math.pi * (turns - 1 + MIN_TURN_FRACTION))
    else:  # raw counts: the same-pose motions that turn far more than the others
        turns = np.ones(len(size))
        full = same & (size >= 0.5 * size[same].max()) if same.any() else same
    k = np.flatnonzero(full)
    vertical = 0.5 * (up[k] + up[k + 1])
    vertical /= np.linalg.norm(vertical, axis=1, keepdims=True)
    sense = np.sign(np.einsum("ij,ij->i", vertical, integral[k]))
    return Turns(spans=spans[k], before=k, after=k + 1, angles=sense * 2 * math.pi * turns[k], up=vertical)


def solve_turns_gyro(name: str, unit: str, gyro: np.ndarray, rate_hz: float, intervals: np.ndarray,
                     axes: np.ndarray, turns: Turns, latitude_rad: float | None,
                     up_sigma: float = 0.0, t: np.ndarray | None = None, noise=None,
                     drift: ScaleDrift | None = None) -> Calibration:
    """K from the turns' integrals, the bias from the statics; see the module doc for the σ.
    ``axes``: each interval's aligned axis (see aligned_axes); ``up_sigma``: 1σ (rad) of the
    turn axes' directions, from the accelerometer's calibration, or (k, 3) the variance (rad²)
    of each turn's up along each axis (turn_up_variance); ``noise``: the device's noise
    model of this triad (a TriadNoise, in rad/s), if known, for its bias instability;
    ``drift``: the scale's temperature drift (None: assumed, over the times ``t``)."""
    axes_seen = np.abs(turns.up).argmax(axis=1)
    missing = [a for i, a in enumerate("xyz") if i not in set(axes_seen.tolist())]
    if missing:
        raise TooFewPoses(f"full turns about {', '.join(missing)} missing (found {len(turns.spans)} "
                          "turns): turn the unit once through 360° about each axis while it is vertical")
    counts = np.diff(intervals, axis=1)[:, 0]
    still = interval_means(gyro, intervals)
    n = np.diff(turns.spans, axis=1)[:, 0]
    w_before, w_after = counts[turns.before], counts[turns.after]
    # The still reading through the turn: the line from the pose before to the pose after, each
    # at its middle, taken at the turn's middle (a bias that drifts, warm-up or temperature,
    # moves during the turn as it does between the poses); its weight on each side, α.
    times = np.arange(len(gyro)) / rate_hz if t is None else t
    middle = 0.5 * (times[intervals[:, 0]] + times[intervals[:, 1] - 1])
    turn_middle = 0.5 * (times[turns.spans[:, 0]] + times[turns.spans[:, 1] - 1])
    alpha = np.clip((turn_middle - middle[turns.before]) / (middle[turns.after] - middle[turns.before]), 0.0, 1.0)
    reference = still[turns.before] * (1 - alpha)[:, None] + still[turns.after] * alpha[:, None]
    W, duration = integrals(gyro, rate_hz, turns.spans, reference, t)
    W = W.T
    C = (turns.up * turns.angles[:, None]).T  # W = K·C
    C_pinv = np.linalg.pinv(C)
    K = W @ C_pinv
    # Per turn and output axis, the variance of W's entry (output units · s)².
    white = np.array([np.var(gyro[a:b], axis=0, ddof=1) for a, b in intervals[[0]]])[0]
    reference_var = white[None, :] * ((1 - alpha) ** 2 / w_before + alpha**2 / w_after)[:, None]
    horizontal = EARTH_RATE if latitude_rad is None else EARTH_RATE * abs(math.cos(latitude_rad))
    k_scale = np.abs(np.diag(K))
    # The horizontal Earth rate, across the axis only, each horizontal axis half of it.
    lever = earth_lever(gyro, rate_hz, turns.spans, reference, turns.angles, t)
    earth = (k_scale[None, :] * horizontal * lever[:, None]) ** 2 / 2 * (1 - turns.up**2)
    heading = ((K @ turns.up.T).T * math.radians(HEADING_SIGMA_DEG)) ** 2
    # The axis's direction error moves the integral across it, not along it (turn_up_variance).
    if np.ndim(up_sigma) == 0:
        across = (k_scale[None, :] * turns.angles[:, None] * up_sigma) ** 2 * (1 - turns.up**2)
    else:
        across = (k_scale[None, :] * turns.angles[:, None]) ** 2 * np.asarray(up_sigma, dtype=float)
    var_W = (white[None, :] * n[:, None] / rate_hz**2 + reference_var * duration[:, None] ** 2 + earth + heading
             + across)
    # The six poses' gyro means: bias and the g-sensitivity, which cancels between up and down
    # (_AXES: face a and a + 3 are one axis up and down). Its σ: the scatter of the three axes'
    # up-and-down means, where the g-sensitivity is gone and the bias's moves between the poses
    # (warm-up, temperature, random walk) are not; never below what the white noise and the
    # horizontal Earth rate leave, nor, with the noise model, below its bias instability, which
    # all poses share and no scatter shows. Turning a face over about a horizontal axis f keeps
    # the Earth rate's component along f: each axis's up-and-down mean keeps (Ωh·f)f, f one of
    # the two other axes, so an output axis holds it from two of the three means, each ½ of the
    # time, with Ωh²/2 over the unknown heading: Ωh²/4 · 2 / 3² = Ωh²/18 in the mean of three.
    poses = np.array([still[axes == a].mean(axis=0) for a in range(6)])  # one mean per face
    pairs = 0.5 * (poses[:3] + poses[3:])
    bias = poses.mean(axis=0)
    weights = np.array([1.0 / (6 * np.count_nonzero(axes == a)) for a in axes])  # bias = weights @ still
    white_var = white * np.sum(weights**2 / counts)
    floor = white_var + (k_scale * horizontal) ** 2 / 18
    if noise is not None and getattr(noise, "bias_instability", 0.0):
        model = weights @ noise.window_covariance(times[intervals[:, 0]], counts / rate_hz) @ weights
        floor = floor + np.maximum(k_scale**2 * model - white_var, 0.0)
    bias_var = np.maximum(np.var(pairs, axis=0, ddof=1) / 3, floor)
    drift = drift or ScaleDrift(times)
    drift_note, drift = drift.note(name), drift.at(name, turns.spans)
    row_cov = np.zeros((3, 4, 4))
    for i in range(3):  # per output axis: K's row is W's row times C⁺, the columns independent
        row_cov[i, :3, :3] = C_pinv.T @ np.diag(var_W[:, i]) @ C_pinv
        # The scale's drift over the session (module doc): one per axis, in all turns at once.
        shift = (drift * W[i]) @ C_pinv
        row_cov[i, :3, :3] += np.outer(shift, shift)
        row_cov[i, 3, 3] = bias_var[i]
    residuals = (W - K @ C).T
    coef_cov = np.zeros((12, 12))  # the rows are independent: their blocks on the diagonal
    for i in range(3):
        coef_cov[4 * i:4 * i + 4, 4 * i:4 * i + 4] = row_cov[i]
    cov, sigma = _parameter_covariance(K, row_cov, coef_cov)
    return Calibration(name=name, kind=ANGULAR_RATE, output_unit=unit, method="classic", K=K, bias=bias,
                       covariance=cov, sigma=sigma, residuals=residuals / np.abs(np.diag(K)),
                       parameter_names=FULL_PARAM_NAMES, residual_unit="rad",
                       diagnostics=SolverDiagnostics(message=f"closed form (the turns' ±2π integrals); {drift_note}",
                                                     dof=residuals.size - 9))


def turn_up_variance(turns: Turns, intervals: np.ndarray, axes: np.ndarray, covariance: np.ndarray,
                     acc: Calibration, gravity: float) -> np.ndarray:
    """(k, 3) rad²: the variance of each turn's calibrated up vector along each body axis, given
    the covariance (flattened, position-major, output units) of the accelerometer's interval
    means it was solved from (solve_aligned_accelerometer), scaled up by its faces' χ²/dof.

    Why not the accelerometer's σ: on a face with axis j vertical, the up's component i is the
    reading there less the bias b_i and the cross term M_ij·g, and Ferraris's closed form takes
    both from the same kind of readings: b_i from the i faces, M_ij from the j faces' i readings.
    So the up's error is (the j faces' mean i reading − the i faces' mean i reading) / (k_i g): a
    bias instability that all faces share moves both alike and cancels. σ(b_i)² + σ(M_ij)² counts
    that shared part in full, once the biases' σ hold it (the estimated or the configured
    flicker): the gyro's cross terms then came out with σ ~25 % too wide (RMS z 0.75-0.81)."""
    counts = np.diff(intervals, axis=1)[:, 0]
    average = first_placements(axes, counts)  # (6, m): each face's mean as weights on the intervals
    chi2 = acc.diagnostics.reduced_chi2 or 1.0
    out = np.zeros((len(turns.spans), 3))
    for n, (before, after, up) in enumerate(zip(turns.before, turns.after, turns.up)):  # a loop over turns
        j = int(np.argmax(np.abs(up)))
        sense = float(np.sign(up[j]))
        at_turn = np.zeros(len(intervals))
        at_turn[[before, after]] += 0.5
        for i in set(range(3)) - {j}:
            w = (at_turn - 0.5 * (average[i] + average[i + 3])
                 - sense * 0.5 * (average[j] - average[j + 3]))
            cov_i = covariance[i::3, i::3]
            out[n, i] = max(chi2, 1.0) * float(w @ cov_i @ w) / (acc.K[i, i] * gravity) ** 2
    return out


def estimated_turns_noise(gyro: np.ndarray, intervals: np.ndarray, axes: np.ndarray, t: np.ndarray,
                          rate_hz: float, scale: float) -> MeasuredNoise:
    """A Ferraris gyro's noise model (rad/s; ``scale`` output units per rad/s) from the recording,
    when no config gives one: the white noise of its first pose, and the bias instability B
    (``noise_estimate.bias_instability``) from how the still readings on one placement of a face
    scatter. A full turn about the vertical brings the unit back to its attitude and heading, so
    the still readings before and after it hold the same bias, g-sensitivity and Earth rate: they
    differ by the noise alone, white and flicker, and by a drift (warm-up, temperature), fitted
    linear in time as the turns' still reading takes it. What that shows of B tells the
    flicker's slow part, which all faces share and the bias (their mean) carries, and which no
    scatter shows: without it the biases' σ were 1.4-1.7 times too small (RMS z over the
    real-world Monte Carlo's Ferraris sessions).

    Each interval is taken in HALVES. The faces seen again give two degrees of freedom per axis
    (three faces seen twice, less the drift), and in whole intervals drifts the model lacks (a
    warm-up's curve, a random walk) set B: 1.4 times the truth for a consumer gyro over the
    real-world Monte Carlo (4 times with a warm-up), RMS z 0.67-0.76. The halves add the scatter
    within each pose, which the white noise dominates: B then leans more on its prior, 0.9 times
    the truth there (RMS z 0.80-0.97), but 0.7 times on a session with no drift at all (RMS z
    1.25 over 30 clean consumer sessions, against 1.01 in whole intervals)."""
    white_var = np.var(gyro[intervals[0, 0]:intervals[0, 1]], axis=0, ddof=1)
    edges = intervals[:, :1] + (np.diff(intervals, axis=1) * np.arange(HALVES + 1)[None, :]) // HALVES
    windows = np.column_stack([edges[:, :-1].ravel(), edges[:, 1:].ravel()])
    counts = np.diff(windows, axis=1)[:, 0]
    still = interval_means(gyro, windows)
    # Which face each window is on, and a drift linear in time.
    design = np.column_stack([np.repeat(axes, HALVES)[:, None] == np.arange(6)[None, :],
                              session_times(t, windows)]).astype(float)
    white = float(np.mean(white_var)) / counts
    root = np.sqrt(1.0 / white)[:, None]
    fitted = design @ np.linalg.lstsq(design * root, still * root, rcond=None)[0]
    # Each window from its first sample to its last: jittered timestamps cannot make them overlap.
    flicker = flicker_covariance(t[windows[:, 0]], t[windows[:, 1] - 1] - t[windows[:, 0]])
    b = bias_instability(still - fitted, design, white, flicker, weights=1.0 / white)  # output units
    k = abs(float(scale))
    return MeasuredNoise(white=float(np.sqrt(np.mean(white_var) / rate_hz)) / k, bias_instability=b / k)
