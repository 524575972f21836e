"""The largest well-determined sub-model (DESIGN principle 13, issue 27), for a recording whose
poses are too few or too alike for the norm method and are not the six faces either: what the
data determine is calibrated, the rest marked not calibrated (nominal value, no σ).

The accelerometer: which of its nine parameters the poses determine is read off the Jacobian of
its norm equations |K⁻¹(m − b)| = g at the nominal model, each row whitened by its pose mean's
noise along the up direction and each column in its parameter's natural unit (k·g for a bias, k
for a scale factor, 1 rad for an angle). Its singular directions with 1/s above
``RANK_FRACTION`` are the combinations the poses leave open; they are held at the nominal model,
and Gauss-Newton moves the rest (truncated SVD: the minimum-norm step). A parameter is then
calibrated when both hold:

* its σ, with every other parameter free (the Fisher information of the kept directions, scaled
  up by χ²/dof), is at most ``WELL_DETERMINED`` of its natural unit, and
* what the open directions could move it by, were the unit as far from nominal as a consumer
  MEMS datasheet allows (``PLAUSIBLE_OFFSET`` along each), is within that σ.

Poses near one face only: every direction seen is a cap of the sphere, the bias and scale
along its axis and the tilt of its rim trade against each other, and nothing may come out; poses
near the six faces, tilted at random: biases and scale factors, not the angles. No rule says
which: the Jacobian does.

The gyroscope's bias is the mean of every pose's still reading less the vertical Earth rate
(``gyro_solve.gyro_prior``, as the full solve's prior); its scale and misalignment need the
rotations between well-spread poses and are marked. A triad in a device's own units (counts) has
no nominal scale to leave a scale at: such a recording is not solved here.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from fieldcal.calibration import STILL_METHOD, Calibration, SolverDiagnostics, nominal_value, with_not_calibrated
from fieldcal.earth import Station
from fieldcal.model import ANGULAR_RATE, PARAM_NAMES, SPECIFIC_FORCE
from fieldcal.recording import Recording
from fieldcal.recording.candidates import Detection
from fieldcal.recording.detect import interval_means
from fieldcal.recording.noise_estimate import WITHIN_POSE, MeasuredNoise, PoseNoise, within_pose_noise
from fieldcal.recording.outcome import SUBMODEL_PROTOCOL, RecordingCalibration, RecordingSettings
from fieldcal.recording.place import UnknownPlace
from fieldcal.recording.up_covariance import MeansCovariance
from fieldcal.solvers.problems import StaticNormProblem

# A singular direction known no better than this (natural units) is left at the nominal model:
# the norm solver's own bound for a parameter the positions do not determine.
RANK_FRACTION = 0.01
# A parameter is calibrated when known to this fraction of its natural unit, per bias, scale
# factor and angle: about a tenth of what a consumer MEMS accelerometer's datasheet already
# promises of the nominal (zero-g offset ±50 mg, sensitivity ±2 %, cross-axis 1-2 %), so 5 mg,
# 0.2 % and 2 mrad: known less well, a calibration adds little to the nominal.
WELL_DETERMINED = np.repeat([5e-3, 2e-3, 2e-3], 3)
# How far from nominal a consumer unit may be along an open direction (natural units: 1 %).
PLAUSIBLE_OFFSET = 0.01
_ITERATIONS = 20
# Degrees of freedom from which the means' scatter about the fit measures their noise (as the
# full solve measures it); with fewer, each pose's own samples do (noise_estimate.within_pose_noise).
SCATTER_DOF = 6
SIGMA_FROM_SCATTER = ("σ from the noise measured by the poses' scatter about the fit ({dof} degrees of freedom), "
                      "scaled up by χ²/dof when above 1")
MIN_POSES_FOR_NOISE = 3  # still poses from which a gyro's bias instability is measured
_STEP_TOL = 1e-9  # natural units: a Gauss-Newton step this small has converged
GYRO_WHY = ("its scale factors and misalignment need the rotations between 9 or more well-spread poses "
            "(or the six faces and a full turn about each axis)")


def nominal_theta(kind: str, unit: str) -> np.ndarray | None:
    """The nine parameters of a triad nothing calibrated; None for a device's own unit."""
    values = [nominal_value(kind, unit, n) for n in PARAM_NAMES]
    return None if any(v is None for v in values) else np.array(values, dtype=float)


def submodel_protocol(recording: Recording, station: Station | UnknownPlace, detection: Detection,
                      tried, settings: RecordingSettings, faces: str = "") -> RecordingCalibration | None:
    """What the poses of the threshold that found the most determine; None when the recording's
    triads are not in physical units (no nominal) or nothing at all is determined. A triad of
    which nothing is determined is there, every parameter marked (``nothing_determined``).
    ``faces``: what a Ferraris session lacks (``aligned.faces_missing``), for what would add it."""
    candidate = max(detection.candidates, key=lambda c: (c.spread.count, len(c.poses.intervals)))
    poses, spread, reference = candidate.poses, candidate.spread, detection.reference
    if not len(poses.intervals) or any(nominal_theta(recording.kinds[n], recording.units[n]) is None
                                       for n in (*detection.forces, *detection.rates)):
        return None
    add = spread.message.split(": ", 1)[-1] if ": " in spread.message else "add poses"
    add += faces  # a Ferraris session short of a face: which
    specific_force, failures, notes, estimated = {}, {}, [], {}
    for name in detection.forces:
        values = recording.triads[name]
        means = interval_means(values, poses.intervals)
        variance = detection.noise.variance if name == reference else \
            np.var(values[poses.intervals[0, 0]:poses.intervals[0, 1]], axis=0, ddof=1)
        measure = settings.estimate_noise and name not in settings.noise
        solution, measured = solve_determined(
            name, recording.units[name], means, poses.intervals, recording.t, variance, station.gravity, add,
            settings.noise.get(name), recording.rate_hz if measure else None,
            within_pose_noise(values, poses.intervals, recording.t, period=recording.period_s) if measure else None,
            period=recording.period_s)
        if measured is not None:
            estimated[name] = measured
        if measured is not None and solution is not None:
            notes.append(f"{name}: {solution.diagnostics.message}")
        specific_force[name] = solution if solution is not None else nothing_determined(
            name, recording.units[name], means, station.gravity,
            f"the {len(poses.intervals)} poses determine none of its parameters: {add}")
    angular_rate, bias_sigma = {}, {}
    up = poses.means / np.linalg.norm(poses.means, axis=1, keepdims=True)  # physical units: zero known
    for name in detection.rates:
        angular_rate[name], measured = still_gyro(recording, name, poses, up, station, settings.noise.get(name),
                                                  estimate=settings.estimate_noise)
        bias_sigma[name] = angular_rate[name].sigma[:3]
        if measured is not None:
            estimated[name] = measured
            notes.append(f"{name}: {angular_rate[name].diagnostics.message}")
    if detection.rates and isinstance(station, UnknownPlace):
        notes.append("the gyro's bias holds the Earth rate (up to 15 °/h, its direction unknown) as an error "
                     "in its σ: give --latitude to take off its vertical part")
    if not any(sol.calibrated for sol in (*specific_force.values(), *angular_rate.values())):
        return None
    return RecordingCalibration(poses, spread, tuple(tried), specific_force, angular_rate, failures, reference,
                                bias_sigma, np.zeros((0, 2), int), False, detection.noise.source, station,
                                SUBMODEL_PROTOCOL, notes=tuple(notes), estimated_noise=estimated)


@dataclass(frozen=True)
class _Fit:
    """A truncated-SVD fit in natural units: the solution, its covariance (the kept directions
    only, scaled up by χ²/dof), χ² and dof, the condition number of what was kept, and each
    parameter's share (norm of its row) in the open directions."""

    theta: np.ndarray
    covariance: np.ndarray
    chi2: float
    dof: int
    condition: float
    open_share: np.ndarray
    scaled: bool = False  # the covariance scaled up by χ²/dof


def _truncated_fit(residuals_at, theta0: np.ndarray, natural: np.ndarray, whiten,
                   scale_by_residuals: bool = True) -> _Fit | None:
    """Gauss-Newton from the nominal ``theta0`` in the directions the whitened Jacobian keeps
    (1/s at most RANK_FRACTION of a natural unit), the others held; None when it keeps none.
    ``whiten``: residuals (m,) or (m, k) to whitened ones. ``scale_by_residuals``: the
    covariance scaled up by χ²/dof when that is above 1 (False: the noise's own, whatever the
    residuals say)."""
    def jacobian(theta):
        steps = 1e-6 * natural
        values = residuals_at(theta + np.concatenate([np.diag(steps), -np.diag(steps)]))  # (18, m)
        return whiten(((values[:9] - values[9:]) / (2 * steps)[:, None]).T) * natural

    _, s, _ = np.linalg.svd(jacobian(theta0))
    rank = int(np.count_nonzero(s * RANK_FRACTION > 1.0))
    if rank == 0:
        return None
    theta = theta0.copy()
    for _ in range(_ITERATIONS):
        U, s, Vt = np.linalg.svd(jacobian(theta), full_matrices=True)
        step = Vt[:rank].T @ ((U[:, :rank].T @ -whiten(residuals_at(theta))) / s[:rank])
        theta = theta + natural * step
        if np.max(np.abs(step)) < _STEP_TOL:
            break
    _, s, Vt = np.linalg.svd(jacobian(theta), full_matrices=True)
    r = whiten(residuals_at(theta))
    chi2, dof = float(r @ r), len(r) - rank
    kept = Vt[:rank].T
    ratio = chi2 / dof if dof > 0 and scale_by_residuals else 1.0
    covariance = (kept / s[:rank] ** 2) @ kept.T * max(ratio, 1.0)
    return _Fit(theta, covariance, chi2, dof, float(s[0] / s[rank - 1]), np.linalg.norm(Vt[rank:].T, axis=1),
                ratio > 1.0)


def _solution(name: str, unit: str, problem: StaticNormProblem, fit: _Fit, natural: np.ndarray,
              sigma_from: str = "") -> Calibration:
    return Calibration(name=name, kind=SPECIFIC_FORCE, output_unit=unit, method="lsq", theta=fit.theta,
                       covariance=fit.covariance * np.outer(natural, natural),
                       residuals=problem.residuals(fit.theta, problem.data), residual_labels=problem.residual_labels,
                       diagnostics=SolverDiagnostics(search="gauss-newton, the determined directions only",
                                                     message=sigma_from, chi2=fit.chi2, dof=fit.dof,
                                                     scaled_by_residuals=fit.scaled,
                                                     condition_number=fit.condition))


def solve_determined(name: str, unit: str, means: np.ndarray, intervals: np.ndarray, t: np.ndarray,
                     variance: np.ndarray, gravity: float, add: str, noise=None,
                     rate_hz: float | None = None, pose_noise: PoseNoise | None = None, *, period: float
                     ) -> tuple[Calibration | None, MeasuredNoise | None]:
    """The specific-force triad's parameters its pose means determine (module doc), the rest
    nominal and marked (None when none is determined), and the noise model measured for it
    (None: the device's ``noise`` was given, or none was measured). ``intervals``: the poses'
    [start, stop) in samples of ``t``, whose median step is ``period`` (s); ``variance``: per-axis white noise of one sample (output
    units²); ``add``: which poses would add the rest.

    The means are weighed by their white noise, then by their exact covariance, the bias
    instability all poses share included (white noise alone put the errors at 1.7 times the σ
    (RMS) on the paper's unit): with the device's ``noise`` model; else, given ``rate_hz``, with
    one measured from the recording: from the means' scatter about the fit when it has
    SCATTER_DOF degrees of freedom or more, as the full solve measures it, else from what each
    pose's own samples say (``pose_noise``, ``noise_estimate.within_pose_noise``), and then the
    σ are not scaled by χ²/dof either. A fit with as many poses as the parameters it determines
    leaves no residual at all, whatever the noise (its σ were the white noise's alone: RMS z 1.7);
    with a few more, the scatter barely constrains B, which its prior then sets (RMS z 0.45; issue
    27). The solution's ``diagnostics.message`` says where its σ came from."""
    from fieldcal.recording.static_solve import estimated_force_noise, means_covariance

    theta0 = nominal_theta(SPECIFIC_FORCE, unit)
    problem = StaticNormProblem(means, gravity, name=name, output_unit=unit,
                                labels=tuple(f"pose {i + 1}" for i in range(len(means))))
    residuals_at = problem.residual_function(problem.data)
    natural = np.r_[theta0[3:6] * gravity, theta0[3:6], np.ones(3)]
    counts = np.diff(intervals, axis=1)[:, 0]
    # Each mean's noise along its up; a noise measured as 0 (a quantised rest) floored far below
    # anything a converter resolves, so that no weight is infinite.
    own = pose_noise.variance if pose_noise is not None else np.broadcast_to(variance, means.shape)
    own = np.maximum(own, (1e-9 * natural[:3]) ** 2)
    up = means / np.linalg.norm(means, axis=1, keepdims=True)
    weight = 1.0 / np.sqrt(np.sum(up**2 * own, axis=1) / counts)
    fit = _truncated_fit(residuals_at, theta0, natural, lambda r: r * weight.reshape(-1, *([1] * (r.ndim - 1))))
    if fit is None:
        return None, None
    covariance, measured, sigma_from, scale = None, None, "", True
    white = _solution(name, unit, problem, fit, natural)  # on white-noise weights
    if noise is None and rate_hz is not None and fit.dof >= SCATTER_DOF:  # measured by the scatter, as in a full solve
        noise = measured = estimated_force_noise(white, means, intervals, t, variance, rate_hz, gravity)
        sigma_from = SIGMA_FROM_SCATTER.format(dof=fit.dof)
    if noise is not None:  # the device's model, or the one the scatter measured
        covariance = means_covariance(intervals, t, variance, noise, white.K, unit, parts=True, period=period)
    elif rate_hz is not None and pose_noise is not None:  # too few residuals: the poses' own samples
        covariance, scale = MeansCovariance(pose_noise.flicker(intervals, t, period), np.eye(3),
                                            pose_noise.variance / counts[:, None]), False
        k = float(theta0[3])  # output units per SI unit
        measured = MeasuredNoise(white=float(np.sqrt(np.mean(pose_noise.variance) / rate_hz)) / k,
                                 bias_instability=pose_noise.bias_instability / k)
        sigma_from = WITHIN_POSE.format(dof=fit.dof)
    if covariance is not None:
        # The residuals' covariance gᵢ·Σᵢⱼ·gⱼᵀ, each residual's gradient in its own mean.
        residual_covariance = covariance.residual_covariance(problem.point_gradients(fit.theta))
        root = np.linalg.cholesky(residual_covariance)
        fit = _truncated_fit(residuals_at, theta0, natural, lambda r: np.linalg.solve(root, r), scale)
    if fit is None:
        return None, measured
    sigma_natural = np.sqrt(np.diag(fit.covariance))
    determined = (sigma_natural <= WELL_DETERMINED) & (PLAUSIBLE_OFFSET * fit.open_share <= sigma_natural)
    if not determined.any():
        return None, measured
    unsolved = [n for n, ok in zip(PARAM_NAMES, determined) if not ok]
    solution = _solution(name, unit, problem, fit, natural, sigma_from)
    return (with_not_calibrated(solution, unsolved, f"{len(means)} poses too few or too alike to determine them: "
                                f"{add}") if unsolved else solution), measured


def nothing_determined(name: str, unit: str, means: np.ndarray, gravity: float, why: str) -> Calibration:
    """A specific-force triad of which the poses determine nothing: every parameter nominal and
    marked, so that the file still says so (and apply passes its readings through as read); its
    residuals the poses' norms at the nominal less g."""
    theta = nominal_theta(SPECIFIC_FORCE, unit)
    residuals = StaticNormProblem(means, gravity, name=name, output_unit=unit).residuals(theta, means.ravel())
    solution = Calibration(name=name, kind=SPECIFIC_FORCE, output_unit=unit, method="lsq", theta=theta,
                           covariance=np.zeros((9, 9)), residuals=residuals,
                           diagnostics=SolverDiagnostics(message="nothing determined", dof=0))
    return with_not_calibrated(solution, PARAM_NAMES, why)


def still_gyro(recording: Recording, name: str, poses, up: np.ndarray, station: Station | UnknownPlace,
               noise=None, why: str = GYRO_WHY, estimate: bool = True) -> tuple[Calibration, MeasuredNoise | None]:
    """A gyro's bias alone, and the noise model measured for it (None: the config's ``noise``
    given, or none measured): the mean of every pose's still reading less the vertical Earth rate
    (``drift.still_bias`` without the g-sensitivity and drift terms, which poses too alike cannot
    tell from the bias); its scale at the unit's own and no misalignment, both marked not
    calibrated (``why``: what would add them). ``up``: each pose's up vector.

    Its σ: the unknown Earth rate's share (at a known place the horizontal part, at an unknown
    heading: on an axis at angle α to the vertical, (Ω·cos φ·sin α)²/2), and with a config's
    ``noise`` its white noise and bias instability; else, with ``estimate``, a noise model
    measured: with SCATTER_DOF or more degrees of freedom from the poses' scatter about their
    mean as the full solve measures it (never below the white noise's share), with fewer from
    each pose's own samples (``noise_estimate.within_pose_noise``), never from a scatter of so
    few readings (a single rest has none: its σ were the white noise's alone, 1.7 times too
    small on a consumer gyro)."""
    from fieldcal.recording.drift import still_bias
    from fieldcal.recording.gyro_solve import _less_earth_rate

    gyro, unit, intervals = recording.triads[name], recording.units[name], poses.intervals
    scale = float(nominal_theta(ANGULAR_RATE, unit)[3])  # output units per rad/s
    m, counts = len(intervals), np.diff(intervals, axis=1)[:, 0]
    still, earth_variance = _less_earth_rate(interval_means(gyro, intervals), up, scale, station)
    # Each pose's share of the Earth rate left (rad²/s², per axis): at a known place the
    # horizontal part, which an axis along the vertical does not see.
    earth = np.full((m, 3), earth_variance) if isinstance(station, UnknownPlace) else \
        earth_variance * (1.0 - np.clip(up, -1.0, 1.0) ** 2)
    earth_mean = scale**2 * earth.sum(axis=0) / m**2
    dof = m - 1
    measured, sigma_from = None, ""
    if noise is None and estimate and dof < SCATTER_DOF:  # too few readings to scatter: their own samples
        pose_noise = within_pose_noise(gyro, intervals, recording.t, period=recording.period_s)
        bias = np.mean(still, axis=0)
        weights = np.full(m, 1.0 / m)
        own = weights**2 @ (pose_noise.variance / counts[:, None])
        bias_sigma = np.sqrt(earth_mean + own + weights @ pose_noise.flicker(intervals, recording.t, recording.period_s) @ weights)
        measured = MeasuredNoise(white=float(np.sqrt(np.mean(pose_noise.variance) / recording.rate_hz)) / abs(scale),
                                 bias_instability=pose_noise.bias_instability / abs(scale))
        sigma_from = WITHIN_POSE.format(dof=dof)
    else:
        rest_variance = np.var(gyro[intervals[0, 0]:intervals[0, 1]], axis=0, ddof=1)
        white = np.mean(rest_variance[None, :] / counts[:, None], axis=0) / m
        bias, bias_sigma = still_bias(still, earth_mean + white)
        if noise is None and estimate and m >= MIN_POSES_FOR_NOISE:  # measured, as the full solve does
            from fieldcal.recording.gyro_solve import estimated_rate_noise

            # The Earth rate's share of the scatter, on average over the axes: at a known place
            # (Ω·cos φ)²/3, not the /2 of a horizontal axis, which took flicker for Earth rate.
            scattered = estimated_rate_noise(still, up, intervals, recording.t, scale, rest_variance,
                                             scale**2 * float(earth.mean()), recording.rate_hz)
            # B as the poses' own samples show it too, the larger kept: a scatter of a few readings,
            # the Earth rate's share taken off, often under-shows a consumer gyro's flicker (RMS z
            # 1.21-1.41 on 9-14 poses; with the larger, 0.92-1.07).
            within = within_pose_noise(gyro, intervals, recording.t, period=recording.period_s).bias_instability \
                / abs(scale)
            noise = measured = replace(scattered, bias_instability=max(scattered.bias_instability, within))
            sigma_from = SIGMA_FROM_SCATTER.format(dof=dof)
        if noise is not None and noise.bias_instability:  # what every pose shares, which no scatter shows
            weights = np.full(m, 1.0 / m)
            times = recording.t[intervals[:, 0]]
            model = weights @ noise.window_covariance(times, counts / recording.rate_hz) @ weights
            bias_sigma = np.sqrt(bias_sigma**2 + np.maximum(scale**2 * model - white, 0.0))
    theta = np.r_[bias, np.full(3, scale), np.zeros(3)]
    residuals = still - bias
    solution = Calibration(name=name, kind=ANGULAR_RATE, output_unit=unit, method=STILL_METHOD, theta=theta,
                           sigma=np.r_[bias_sigma, np.zeros(6)], residuals=residuals, residual_unit=unit,
                           residual_rms=float(np.sqrt(np.mean(residuals**2))),
                           diagnostics=SolverDiagnostics(message=sigma_from or "the still poses' mean",
                                                         dof=max(residuals.size - 3, 0)))
    return with_not_calibrated(solution, PARAM_NAMES[3:], why), measured


def summary_line(cal: RecordingCalibration) -> str:
    """One line: what was calibrated, what was not, and what would add it; "" when every triad
    is calibrated whole."""
    from fieldcal.report import label

    solved, unsolved, adds = [], [], []
    for name, sol in (*cal.specific_force.items(), *cal.angular_rate.items()):
        if not sol.not_calibrated:
            continue
        solved += [f"{name} {_names(sol.calibrated, label)}"] if sol.calibrated else []
        unsolved.append(f"{name} {_names(sol.not_calibrated, label)}" if sol.calibrated else f"{name} (all)")
        adds.append(f"{name}: {sol.not_calibrated_why.split(': ', 1)[-1]}" if sol.not_calibrated_why else "")
    unsolved += [name for name in cal.failures]
    if not solved:
        return ""
    return (f"calibrated: {'; '.join(solved)}. NOT calibrated (nominal, no σ): {'; '.join(unsolved)}. "
            f"To add them: {'; '.join(a for a in adds if a)}")


def _names(names, label) -> str:
    """"bias x, y; scale factor z" from the parameter names, grouped."""
    groups: dict[str, list[str]] = {}
    for n in names:
        group, _, axis = n.rpartition("_") if n.startswith(("bias", "scale")) else ("misalignment", "", n)
        groups.setdefault(group, []).append(axis if group != "misalignment" else label(n))
    return ", ".join(f"{'scale factor' if g == 'scale' else g} {'/'.join(axes)}" for g, axes in groups.items())

