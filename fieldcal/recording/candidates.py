"""The detect stage of a recording's calibration (import → detect → choose the poses → solve
each triad → file): the noise level, measured once, then every threshold multiple's static poses,
the turntable turns the gyro sees split out of them, each with its spread report. The next
stage (``pose_choice.choose_poses``) solves the accelerometer on each and keeps the best fit.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fieldcal.model import ANGULAR_RATE, SPECIFIC_FORCE
from fieldcal.recording import Recording
from fieldcal.recording.detect import (DetectionError, DetectorSettings, NoiseLevel, Poses, SpreadReport,
                                       check_spread, noise_level, pose_candidates)
from fieldcal.recording.turns import split_poses, turning

# Output units per rad/s of rate units a text file may use; anything else (counts) is scanned.
RATE_UNITS = {"rad/s": 1.0, "mrad/s": 1e3, "deg/s": 180 / math.pi, "°/s": 180 / math.pi,
              "dps": 180 / math.pi, "mdeg/s": 180e3 / math.pi}
# Specific-force units with a known zero: gravity directions need no sphere fit.
FORCE_UNITS = ("m/s^2", "m/s2", "m/s²", "g", "mg")


@dataclass(frozen=True)
class Candidate:
    """One threshold multiple's poses: ``found`` as the accelerometer's stillness gives them,
    ``poses`` with the stretches the gyro sees turning taken out, ``turns`` (k, 2) [start, stop)
    the steady turns inside them, ``spread`` the distinct poses' report."""

    found: Poses
    poses: Poses
    turns: np.ndarray
    spread: SpreadReport

    @property
    def multiple(self) -> float:
        return self.poses.multiple


@dataclass(frozen=True)
class Detection:
    """The triads by kind, the reference (the accelerometer whose poses these are), its noise
    level and one candidate per ``DetectorSettings.multiples``."""

    forces: tuple[str, ...]
    rates: tuple[str, ...]
    reference: str
    noise: NoiseLevel
    candidates: tuple[Candidate, ...]


def _names(recording: Recording, kind: str) -> tuple[str, ...]:
    return tuple(n for n, k in recording.kinds.items() if k == kind)


def detect_candidates(recording: Recording, settings: DetectorSettings) -> Detection:
    """Raises DetectionError (no accelerometer, the rest not still, too short to find the noise)."""
    forces, rates = _names(recording, SPECIFIC_FORCE), _names(recording, ANGULAR_RATE)
    if not forces:
        raise DetectionError("the recording has no specific-force triad (accelerometer): its "
                             "poses cannot be found")
    reference = "accelerometer" if "accelerometer" in forces else forces[0]
    rate_hz = recording.rate_hz
    acc = recording.triads[reference]
    gyro = recording.triads[rates[0]] if rates else None
    noise = noise_level(acc, rate_hz, settings, gyro)  # weights every candidate's pose means
    zero = np.zeros(3) if recording.units[reference] in FORCE_UNITS else None
    # The poses first, then the turns: the temporaries of each come and go without the other's
    # (the smoothed rates, n × 3, are made only once the poses are found).
    every_found = pose_candidates(acc, rate_hz, settings, zero=zero, gyro=gyro, noise=noise)
    if gyro is not None:  # on a turntable the accelerometer is as still as in a pose
        turn_mask, smooth = turning(gyro, acc, rate_hz, noise, settings, RATE_UNITS.get(recording.units[rates[0]]))
    candidates, split_memo = [], {}  # an interval's split, worked out once for every threshold
    for found in every_found:
        poses, turns = found, np.zeros((0, 2), int)
        if gyro is not None:
            poses, turns = split_poses(found, acc, turn_mask, smooth, rate_hz, settings, zero, split_memo)
        spread = check_spread(poses.up[poses.distinct], settings.min_poses, settings.cover_deg, settings.min_design)
        candidates.append(Candidate(found, poses, turns, spread))
    return Detection(forces, rates, reference, noise, tuple(candidates))
