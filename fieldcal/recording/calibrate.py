"""Calibrate a unit from a plain recording, with no procedure and no operator: the pipeline.

Its stages, each one call: the recording (imported by ``recording.importer``) is searched for
still poses at every threshold multiple of the detector (``candidates.detect_candidates``); the
place gives g and the Earth rate (``place.place_gravity``: an unknown place's g is normal gravity
at 45°, its spread carried in the σ); the poses are chosen as imu_tk chooses them, the set whose
reference accelerometer fits best (``pose_choice.choose_poses``), the reference's noise model
measured from that fit when none is given (``pose_choice.with_estimated_noise``); each triad is
then solved on them (``solve_triads``): every other specific-force triad by the norm method
(``static_solve``), each gyro from the rotations between poses (``gyro_solve``). When no
threshold gives poses enough for the norm method but six of them lie on the faces, the Ferraris
protocol solves instead (``aligned``). The result, a RecordingCalibration (``outcome``), is what
``recording.results`` writes as the parameter file.

The noise comes from the device's noise model when one is given (exact covariance of the pose
means, bias instability included), else from a model of the same form measured from the
recording (``noise_estimate``); either way the σ are scaled up by χ²/dof when the fit says the
model is not all there is. The gyroscope's bias is the mean of every pose's still reading less
the vertical Earth rate, its σ from those readings' scatter (``drift.still_bias``); a gyro
reporting raw counts needs no nominal sensitivity: a scan over the scale finds the one that makes
the motions' rotations fit.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from fieldcal.earth import Station
from fieldcal.recording import Recording
from fieldcal.recording.aligned import aligned_protocol, faces_missing
from fieldcal.recording.candidates import Detection, detect_candidates
from fieldcal.recording.detect import TooFewPoses, interval_means, too_short
from fieldcal.recording.gyro_solve import solve_gyro
from fieldcal.recording.outcome import (FORCE_ONLY_PROTOCOL, NORM_PROTOCOL, RecordingCalibration,
                                        RecordingSettings)
from fieldcal.recording.place import UnknownPlace, place_gravity, with_gravity_uncertainty
from fieldcal.recording.pose_choice import PoseChoice, choose_poses, with_estimated_noise
from fieldcal.recording.static_solve import estimated_force_noise, solve_static
from fieldcal.recording.submodel import submodel_protocol
from fieldcal.solvers import CalibrationError


def calibrate_recording(recording: Recording, station: Station | UnknownPlace,
                        settings: RecordingSettings = RecordingSettings()) -> RecordingCalibration:
    """The pipeline: detect every threshold's candidate poses, choose the poses by the
    accelerometer's fit (or, failing that, the Ferraris protocol's six aligned ones), solve each
    triad. Raises DetectionError (poses too few or badly spread, the rest not still) or
    CalibrationError (the reference accelerometer cannot be solved) with a one-line message."""
    detection = detect_candidates(recording, settings.detector)
    station = place_gravity(station)
    choice = choose_poses(recording, detection, station, settings)
    estimated = ()
    if choice.best is not None and settings.estimate_noise and detection.reference not in settings.noise:
        try:
            choice, settings = with_estimated_noise(recording, detection, choice, station, settings)
            estimated = (detection.reference,)
        except CalibrationError as exc:  # its noise model leaves some parameter undetermined
            choice = replace(choice, best=None, reference_solution=None,
                             tried=choice.tried + ((choice.best.multiple, choice.best.spread.count,
                                                    f"with its measured noise: {exc}"),))
    if choice.best is None:  # too few poses for the norm method: the six faces, if they are there
        aligned = aligned_protocol(recording, station, detection, choice.tried, settings)
        if aligned is None:  # what the poses do determine, the rest marked not calibrated
            aligned = submodel_protocol(recording, station, detection, choice.tried, settings,
                                        faces_missing(detection, settings.detector.min_static_s))
        if aligned is None:
            raise _no_usable_poses(detection, choice, settings)
        return _with_unknown_gravity(aligned)
    return _with_unknown_gravity(solve_triads(recording, detection, choice, station, settings, estimated))


def _no_usable_poses(detection: Detection, choice: PoseChoice, settings: RecordingSettings) -> TooFewPoses:
    """The refusal when no threshold's poses fit and they are not the six faces either: the
    threshold that found the most poses, why they would not do, and what would help."""
    most = max(choice.tried, key=lambda x: x[1])
    poses = next(c.poses for c in detection.candidates if c.multiple == most[0])
    faces = faces_missing(detection, settings.detector.min_static_s)
    return TooFewPoses(f"no threshold gave usable poses; with the most ({most[1]} at "
                       f"{most[0]:g}× the noise level): {most[2]}{too_short(poses, settings.detector)}"
                       f"{faces}")


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
                                    station.gravity, settings, period=recording.period_s)
            if settings.estimate_noise and name not in settings.noise:  # as the reference's
                noise = estimated_force_noise(solution, means, keep, recording.t, variance, recording.rate_hz,
                                              station.gravity)
                settings = replace(settings, noise={**settings.noise, name: noise})
                estimated_names += (name,)
                solution = solve_static(name, recording.units[name], means, keep, recording.t, variance,
                                        station.gravity, settings, white=solution, period=recording.period_s)
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
