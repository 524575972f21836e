"""Calibrate a unit from a plain recording: detect the poses, solve the accelerometer (and any
other specific-force triad) by the norm method, then the gyroscope from the rotations between
poses, with no procedure and no operator.

The threshold multiple of the pose detector is chosen as imu_tk chooses it: each multiple's
poses are calibrated and the best fit (smallest χ²/dof of the accelerometer's norm equations)
wins; each set is ranked by the least χ² it allows, and only the best is solved by Powell.
Every static interval's mean is an equation, a pose seen twice (a duplicate) as well: it
is more data, though only distinct poses count for the spread. The noise comes from the
device's noise model when one is given (exact covariance of the pose means, bias instability
included), else from a model of the same form measured from the recording (``noise_estimate``):
the white noise of the detector's noise level (the initial rest given by ``--rest``, or the
recording's quietest windows), the bias instability from how far the pose means scatter about
the fit beyond it; either way the σ are scaled up by χ²/dof when the fit says the model is not
all there is. The gyroscope's bias is the mean of
every pose's still reading less the vertical Earth rate, which the accelerometer's up direction
fixes; its σ comes from those readings' scatter (the horizontal Earth rate at an unknown heading,
g-sensitivity, warm-up and other drift), counted over fewer poses when neighbours move together
(``drift.still_bias``). The horizontal Earth rate also widens each motion's residual, and a
motion during which the gyro clipped at its range is left out. A gyro reporting raw counts needs no nominal sensitivity: a
scan over the scale finds the one that makes the motions' rotations fit.
"""
from __future__ import annotations

from functools import partial
from dataclasses import replace

import numpy as np

from fieldcal.earth import Station
from fieldcal.recording import Recording
from fieldcal.recording.candidates import RATE_UNITS, Detection, detect_candidates
from fieldcal.recording.detect import (DetectionError, Poses, SpreadReport, TooFewPoses,
                                      interval_means, too_short)
from fieldcal.recording.drift import regular_times
from fieldcal.recording.noise_estimate import MeasuredNoise, bias_instability, flicker_covariance
from fieldcal.solvers import CalibrationError
from fieldcal.calibration import Calibration
from fieldcal.recording.place import UnknownPlace, place_gravity, with_gravity_uncertainty
from fieldcal.recording.outcome import ALIGNED_FORCE_ONLY_PROTOCOL, ALIGNED_PROTOCOL, FORCE_ONLY_PROTOCOL, NORM_PROTOCOL, RecordingCalibration, RecordingSettings
from fieldcal.recording.static_solve import estimated_force_noise, means_covariance, solve_static
from fieldcal.recording.pose_choice import PoseChoice, choose_poses, with_estimated_noise
from fieldcal.recording.gyro_solve import solve_gyro


def calibrate_recording(recording: Recording, station: Station | UnknownPlace,
                        settings: RecordingSettings = RecordingSettings()) -> RecordingCalibration:
    """The pipeline: detect every threshold's candidate poses, choose the poses by the
    accelerometer's fit (or, failing that, the Ferraris protocol's six aligned ones), solve each
    triad. Raises DetectionError (poses too few or badly spread, the rest not still) or
    CalibrationError (the reference accelerometer cannot be solved) with a one-line message."""
    detection = detect_candidates(recording, settings.detector)
    station = place_gravity(station)
    choice = choose_poses(recording, detection, station, settings)
    if choice.best is None:
        aligned = _aligned_protocol(recording, station, detection, choice.tried, settings)
        if aligned is not None:
            return _with_unknown_gravity(aligned)
        most = max(choice.tried, key=lambda x: x[1])
        poses = next(c.poses for c in detection.candidates if c.multiple == most[0])
        faces = _faces_missing(detection, settings.detector.min_static_s)
        raise TooFewPoses(f"no threshold gave usable poses; with the most ({most[1]} at "
                          f"{most[0]:g}× the noise level): {most[2]}{too_short(poses, settings.detector)}"
                          f"{faces}")
    estimated = ()
    if settings.estimate_noise and detection.reference not in settings.noise:
        choice, settings = with_estimated_noise(recording, detection, choice, station, settings)
        estimated = (detection.reference,)
    return _with_unknown_gravity(solve_triads(recording, detection, choice, station, settings, estimated))


def _with_unknown_gravity(cal: RecordingCalibration) -> RecordingCalibration:
    """The specific-force triads' scale σ widened by an unknown place's g (see place_gravity),
    with a note for each whose σ that dominates."""
    relative = getattr(cal.place, "gravity_relative_sigma", 0.0)
    if not relative:
        return cal
    widened, notes = {}, []
    for name, solution in cal.specific_force.items():
        widened[name], note = with_gravity_uncertainty(solution, relative)
        notes += [note] if note else []
    return replace(cal, specific_force=widened, notes=cal.notes + tuple(notes))


def _faces_missing(detection: Detection, min_static_s: float) -> str:
    """For a refusal: when the poses found all lie on faces (a Ferraris session), which of the six
    faces were not found still, and what would help."""
    from fieldcal.recording.ferraris import missing_faces

    candidate = max(detection.candidates, key=lambda c: len(c.poses.intervals))
    missing = missing_faces(candidate.poses.up)
    if not missing:
        return ""
    return (f"; for the Ferraris protocol (six faces and a full turn about each axis) {', '.join(missing)} "
            f"{'was' if len(missing) == 1 else 'were'} not found still for {min_static_s:g} s: hold each face "
            "still for longer, or give --min-still S")


def solve_triads(recording: Recording, detection: Detection, choice: PoseChoice,
                 station: Station | UnknownPlace, settings: RecordingSettings,
                 estimated_names: tuple[str, ...] = ()) -> RecordingCalibration:
    """Every other specific-force triad on the chosen poses, then each gyro from the rotations
    between them; a triad that cannot be solved is a failure, not an error. ``estimated_names``:
    the triads whose noise model in ``settings`` was measured from the recording."""
    poses, reference, acc_solution = choice.best.poses, detection.reference, choice.reference_solution
    failures: dict[str, str] = {}
    specific_force = {reference: acc_solution}
    keep = poses.intervals
    for name in detection.forces:
        if name == reference:
            continue
        values = recording.triads[name]
        means, variance = interval_means(values, keep), np.var(values[keep[0, 0]:keep[0, 1]], axis=0, ddof=1)
        try:
            solution = solve_static(name, recording.units[name], means, keep, recording.t, variance,
                                     station.gravity, settings)
            if settings.estimate_noise and name not in settings.noise:  # as the reference's
                noise = estimated_force_noise(solution, means, keep, recording.t, variance, recording.rate_hz,
                                              station.gravity)
                settings = replace(settings, noise={**settings.noise, name: noise})
                estimated_names += (name,)
                solution = solve_static(name, recording.units[name], means, keep, recording.t, variance,
                                         station.gravity, settings, white=solution)
            specific_force[name] = solution
        except CalibrationError as exc:
            failures[name] = str(exc)
    turns = choice.best.turns
    angular_rate, bias_sigma, notes = {}, {}, []
    estimated = {n: settings.noise[n] for n in estimated_names}
    for name in detection.rates:
        try:
            angular_rate[name], bias_sigma[name], note, noise = solve_gyro(
                recording, name, poses, acc_solution, detection.noise.variance, station, settings, turns)
            notes += [note] if note else []
            estimated.update({name: noise} if noise is not None else {})
        except CalibrationError as exc:
            failures[name] = str(exc)
    used = bool(settings.table_rate_deg_s is not None and len(turns) and angular_rate)
    return RecordingCalibration(poses, choice.best.spread, choice.tried, specific_force, angular_rate, failures,
                                reference, bias_sigma, turns, used, detection.noise.source, station,
                                NORM_PROTOCOL if detection.rates else FORCE_ONLY_PROTOCOL,
                                notes=tuple(notes), estimated_noise=estimated)


def _aligned_protocol(recording: Recording, station: Station | UnknownPlace, detection: Detection,
                      tried, settings: RecordingSettings) -> RecordingCalibration | None:
    """The Ferraris protocol's solution when some threshold's poses are the six aligned ones
    (see ``fieldcal.recording.ferraris``); None when none is."""
    from fieldcal.recording import ferraris

    found = [(c.poses, axes) for c in detection.candidates if (axes := ferraris.aligned_axes(c.poses.up)) is not None]
    left_out = ""
    if not found:  # six faces among tilted poses too few for the norm method: the faces alone
        found = [(_only(c.poses, mask), axes) for c in detection.candidates
                 if (faces := ferraris.face_poses(c.poses.up)) is not None for mask, axes in [faces]]
        if not found:
            return None
        left_out = "the six faces alone (the norm method needs 9 distinct poses; {} tilted left out)"
    poses, axes = max(found, key=lambda pa: len(pa[0].intervals))  # the most intervals: more data
    if left_out:
        tilted = next(c.poses for c in detection.candidates if c.poses.multiple == poses.multiple)
        left_out = left_out.format(int(tilted.distinct.sum() - poses.distinct.sum()))
    reference, noise = detection.reference, detection.noise
    if detection.rates and noise.gyro_variance is not None:  # a turn's slow start kept in a pose
        trimmed = ferraris.trim_turning_edges(recording.triads[detection.rates[0]], poses.intervals,
                                              noise.gyro_variance, recording.rate_hz)
        means = interval_means(recording.triads[reference], trimmed)
        poses = replace(poses, intervals=trimmed, means=means)
    failures: dict[str, str] = {}
    specific_force, angular_rate, bias_sigma, estimated = {}, {}, {}, {}
    drift = ferraris.ScaleDrift(recording.t, recording.temperature, settings.scale_tempco_ppm_per_k)
    for name in detection.forces:
        values, unit = recording.triads[name], recording.units[name]
        means = interval_means(values, poses.intervals)
        # White noise of the detector's level (or this triad's first pose); with the device's
        # noise model the exact covariance, bias instability included, at the nominal scale.
        variance = noise.variance if name == reference else np.var(
            values[poses.intervals[0, 0]:poses.intervals[0, 1]], axis=0, ddof=1)
        # The nominal scale, from the faces' spread (±g on each axis): raw counts have an offset
        # that the means' norm would count as scale.
        scale = np.diag(np.ptp(means, axis=0) / (2 * station.gravity))
        covariance = means_covariance(poses.intervals, recording.t, variance, settings.noise.get(name), scale, unit)
        try:
            specific_force[name] = ferraris.solve_aligned_accelerometer(
                name, unit, means, axes, station.gravity, covariance, np.diff(poses.intervals, axis=1)[:, 0],
                drift=(drift.at(name, poses.intervals), drift.note(name)))
            if settings.estimate_noise and name not in settings.noise:
                specific_force[name], estimated[name] = _with_shared_flicker(
                    specific_force[name], means, poses.intervals, axes, recording.t, variance, recording.rate_hz,
                    scale)
        except CalibrationError as exc:
            if name == reference:
                raise
            failures[name] = str(exc)
    acc = specific_force[reference]
    up = ferraris.up_vectors(acc, interval_means(recording.triads[reference], poses.intervals))
    latitude = None if isinstance(station, UnknownPlace) else station.latitude_rad
    # The covariance of the reference's interval means, where the turn axes' error comes from
    # (ferraris.turn_up_variance): the config's noise model, else white noise. Not the estimated
    # flicker: its shared part cancels in the up, and what its faster part moves between faces
    # is in the faces' χ²/dof, which turn_up_variance scales by (with it, RMS z 0.71-0.74).
    up_noise = settings.noise.get(reference)
    up_means_cov = means_covariance(poses.intervals, recording.t, noise.variance, up_noise, acc.K,
                                     recording.units[reference])
    for name in detection.rates:
        gyro = recording.triads[name]
        t = regular_times(recording.t, recording.rate_hz)
        turns = ferraris.find_turns(gyro, recording.rate_hz, poses.intervals, up, RATE_UNITS.get(recording.units[name]),
                                    t=t)
        up_variance = ferraris.turn_up_variance(turns, poses.intervals, axes, up_means_cov, acc, station.gravity)
        solve = partial(ferraris.solve_turns_gyro, name, recording.units[name], gyro, recording.rate_hz,
                        poses.intervals, axes, turns, latitude, up_sigma=up_variance, t=t,
                        drift=replace(drift, t=t))
        try:
            angular_rate[name] = solve(noise=settings.noise.get(name))
            if settings.estimate_noise and name not in settings.noise:  # its flicker, then the σ again
                estimated[name] = ferraris.estimated_turns_noise(
                    gyro, poses.intervals, axes, t, recording.rate_hz, np.mean(np.abs(np.diag(angular_rate[name].K))))
                angular_rate[name] = solve(noise=estimated[name])
            bias_sigma[name] = angular_rate[name].sigma[:3]
        except DetectionError as exc:
            failures[name] = str(exc)
    spread = SpreadReport(count=6, ok=True, missing=[], design=0.0,
                          message="6 distinct poses, each along an axis (Ferraris)")
    notes = tuple(f"{name}: {drift.note(name)}" for name in (*specific_force, *angular_rate)) + (
        (left_out,) if left_out else ())
    return RecordingCalibration(poses, spread, tuple(tried), specific_force, angular_rate, failures, reference,
                                bias_sigma, np.zeros((0, 2), int), False, noise.source, station,
                                ALIGNED_PROTOCOL if detection.rates and not left_out else ALIGNED_FORCE_ONLY_PROTOCOL,
                                notes, estimated_noise=estimated)


def _only(poses: Poses, mask: np.ndarray) -> Poses:
    """The poses of ``mask`` alone."""
    return replace(poses, intervals=poses.intervals[mask], means=poses.means[mask], up=poses.up[mask],
                   distinct=poses.distinct[mask])


def _with_shared_flicker(solution: Calibration, means: np.ndarray, intervals: np.ndarray, axes: np.ndarray,
                         t: np.ndarray, variance: np.ndarray, rate_hz: float,
                         scale: np.ndarray) -> tuple[Calibration, MeasuredNoise]:
    """A Ferraris accelerometer's solution with its biases' σ widened by the bias instability
    that all faces share, and the noise model measured for it (SI; ``scale`` the nominal K).

    B is measured within placements (ferraris.placement_runs): a full turn on the table brings
    the unit back to the attitude it had, so the still intervals before and after it differ by
    noise alone. A face set down again later is another placement with another tilt: grouped by
    face, imucal's session put B at 14 mm/s² (its +x placements differ by 8 mm/s²), by placement
    1.6 mm/s². (The six faces' fit, two degrees of freedom per axis, mostly sees how each face
    was placed, not the sensor: it put B at 3 mg and every σ at 5 times.) Only the biases
    change: the faces' scatter already widens every σ (χ²/dof), and what no scatter shows is the
    part of the flicker all faces share, with the weights the solve gives each interval: each
    face's first placement (ferraris.first_placements), not every interval on the face. (The
    whole flicker of each axis's own two faces would count their difference from the others
    twice, once here and once in χ²/dof: Ferraris Monte Carlo bias RMS z 0.76-0.87, not 0.81-0.91.)"""
    from fieldcal.recording.ferraris import first_placements, placement_runs

    counts = np.diff(intervals, axis=1)[:, 0]
    run = placement_runs(axes)
    placements = (run[:, None] == np.arange(run[-1] + 1)[None, :]).astype(float)  # interval × placement
    white = float(np.mean(variance)) / counts
    weights = 1.0 / white
    root = np.sqrt(weights)[:, None]
    fitted = placements @ np.linalg.lstsq(placements * root, means * root, rcond=None)[0]
    flicker = flicker_covariance(t[intervals[:, 0]], counts / rate_hz)
    b = bias_instability(means - fitted, placements, white, flicker, weights=weights)  # output units
    # The flicker the six faces' means share, each face its first placement as the solve takes it
    # (the rest of a bias's flicker, its two faces against the others, is in the faces' scatter).
    common = first_placements(axes, counts).mean(axis=0)
    shared = b**2 * float(common @ flicker @ common)
    covariance = solution.covariance.copy()
    covariance[:3, :3] += shared * np.eye(3)
    sigma = solution.sigma.copy()
    sigma[:3] = np.sqrt(sigma[:3] ** 2 + shared)
    k = float(np.mean(np.abs(np.diag(scale))))
    noise = MeasuredNoise(white=float(np.sqrt(np.mean(variance) / rate_hz)) / k, bias_instability=b / k)
    return replace(solution, covariance=covariance, sigma=sigma), noise
