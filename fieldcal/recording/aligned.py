"""The six-faces (Ferraris) protocol, for a recording whose poses are too few for the norm method:
the aligned six-position solution for the specific-force triads, the turns' ±2π integrals for
the gyros (fieldcal.recording.ferraris, imported only when this protocol runs)."""
from __future__ import annotations

from dataclasses import replace
from functools import partial

import numpy as np

from fieldcal.calibration import Calibration
from fieldcal.model import ANGULAR_RATE
from fieldcal.earth import Station
from fieldcal.recording import Recording
from fieldcal.recording.candidates import RATE_UNITS, Detection
from fieldcal.recording.detect import DetectionError, Poses, SpreadReport, interval_means
from fieldcal.recording.drift import regular_times
from fieldcal.recording.noise_estimate import MeasuredNoise, bias_instability, flicker_covariance
from fieldcal.recording.outcome import (ALIGNED_FORCE_ONLY_PROTOCOL, ALIGNED_PROTOCOL, RecordingCalibration,
                                        RecordingSettings)
from fieldcal.recording.place import UnknownPlace
from fieldcal.recording.static_solve import means_covariance
from fieldcal.recording.submodel import nominal_theta, still_gyro
from fieldcal.solvers import CalibrationError

def aligned_protocol(recording: Recording, station: Station | UnknownPlace, detection: Detection,
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
        covariance = means_covariance(poses.intervals, recording.t, variance, settings.noise.get(name), scale, unit,
                                      period=recording.period_s)
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
                                    recording.units[reference], period=recording.period_s)
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
        except DetectionError as exc:  # no turns: the faces' still readings still give the bias
            if nominal_theta(ANGULAR_RATE, recording.units[name]) is None:  # counts: no nominal scale to leave
                failures[name] = str(exc)
                continue
            angular_rate[name], measured = still_gyro(recording, name, poses, up, station, settings.noise.get(name),
                                                      str(exc), settings.estimate_noise)
            if measured is not None:
                estimated[name] = measured
            bias_sigma[name] = angular_rate[name].sigma[:3]
    spread = SpreadReport(count=6, ok=True, missing=[], design=0.0,
                          message="6 distinct poses, each along an axis (Ferraris)")
    scaled = [n for n, sol in angular_rate.items() if not sol.not_calibrated]  # a gyro's bias alone has no scale
    notes = tuple(f"{name}: {drift.note(name)}" for name in (*specific_force, *scaled)) + (
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


def faces_missing(detection: Detection, min_static_s: float) -> str:
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
