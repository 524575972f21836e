"""The poses stage: of every threshold's candidate poses, the set whose reference accelerometer
fits best (smallest χ²/dof), as imu_tk chooses; then, when no noise model is given, the
reference's noise model measured from that fit and its solution again with it. Every static
interval's mean is an equation, a pose seen twice (a duplicate) as well: it is more data, though
only distinct poses count for the spread."""
from __future__ import annotations

from dataclasses import dataclass, replace

from fieldcal.calibration import Calibration
from fieldcal.earth import Station
from fieldcal.recording import Recording
from fieldcal.recording.candidates import Candidate, Detection
from fieldcal.recording.outcome import RecordingSettings
from fieldcal.recording.place import UnknownPlace
from fieldcal.recording.static_solve import estimated_force_noise, reduced_chi2, solve_static
from fieldcal.solvers import CalibrationError
from fieldcal.solvers.norm import SCREEN

@dataclass(frozen=True)
class PoseChoice:
    """The poses stage's outcome: every multiple's (multiple, distinct poses, χ²/dof or why not),
    and the best-fitting candidate with its reference accelerometer solution (None: none fits)."""

    tried: tuple[tuple[float, int, str], ...]
    best: Candidate | None = None
    reference_solution: Calibration | None = None


def choose_poses(recording: Recording, detection: Detection, station: Station | UnknownPlace,
                 settings: RecordingSettings) -> PoseChoice:
    """The candidate whose reference accelerometer fits best (smallest χ²/dof), as imu_tk chooses.

    Each distinct set of poses is screened by the least χ² it allows (Gauss-Newton, the same
    minimum Powell finds, at a fraction of the cost); only the best is solved by the method asked
    for (the next best if that solve fails), so Powell runs once instead of once per set."""
    reference, unit = detection.reference, recording.units[detection.reference]

    def solve(poses, method=None):
        try:
            return solve_static(reference, unit, poses.means, poses.intervals, recording.t,
                                detection.noise.variance, station.gravity, settings, method,
                                period=recording.period_s)
        except CalibrationError as exc:
            return str(exc)

    screened: dict[bytes, Calibration | str] = {}  # several multiples often find the same intervals
    keys = []
    for candidate in detection.candidates:
        key = candidate.poses.intervals.tobytes() if candidate.spread.ok else None
        keys.append(key)
        if key is not None and key not in screened:
            screened[key] = solve(candidate.poses, SCREEN)
            if isinstance(screened[key], str):  # the method asked for says why (or does better)
                screened[key] = solve(candidate.poses)
    solved: dict[bytes, Calibration | str] = {}
    fits = [k for k in dict.fromkeys(k for k in keys if k is not None) if isinstance(screened[k], Calibration)]
    for key in sorted(fits, key=lambda k: reduced_chi2(screened[k])):  # stable: the first of equals wins
        solution = screened[key]
        if solution.diagnostics.search == SCREEN:
            solution = solve(detection.candidates[keys.index(key)].poses)
        solved[key] = solution
        if isinstance(solution, Calibration):
            break
    tried, best = [], None
    for candidate, key in zip(detection.candidates, keys):
        poses, spread = candidate.poses, candidate.spread
        if key is None:
            tried.append((poses.multiple, spread.count, spread.message))
            continue
        sol = solved.get(key, screened[key])
        tried.append((poses.multiple, spread.count, sol if isinstance(sol, str) else f"χ²/dof {reduced_chi2(sol):.3g}"))
        if best is None and isinstance(solved.get(key), Calibration):
            best = (candidate, solved[key])
    return PoseChoice(tuple(tried), *(best or ()))


def with_estimated_noise(recording: Recording, detection: Detection, choice: PoseChoice,
                         station: Station | UnknownPlace, settings: RecordingSettings):
    """The reference accelerometer's noise model measured from its chosen fit, and its solution
    again with it; the settings carry the model on to the gyro's up vectors."""
    reference, poses = detection.reference, choice.best.poses
    noise = estimated_force_noise(choice.reference_solution, poses.means, poses.intervals, recording.t,
                                  detection.noise.variance, recording.rate_hz, station.gravity)
    settings = replace(settings, noise={**settings.noise, reference: noise})
    solution = solve_static(reference, recording.units[reference], poses.means, poses.intervals, recording.t,
                            detection.noise.variance, station.gravity, settings, white=choice.reference_solution,
                            period=recording.period_s)
    return replace(choice, reference_solution=solution), settings
