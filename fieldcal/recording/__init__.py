"""Calibration from a plain continuous recording (no procedure, no operator prompts).

A recording is the unit set down by hand in a dozen or more poses and turned between them.
The pipeline, each stage a function whose typed result the next one takes: ``importer`` turns
text files into a :class:`Recording` (and a session); ``candidates.detect_candidates`` finds
every threshold's static poses (``detect``) with the turns split out (``turns``): a
``Detection``; ``pose_choice.choose_poses`` keeps the best accelerometer fit (a ``PoseChoice``);
``calibrate.solve_triads`` solves each triad (the specific-force ones by the norm method,
``static_solve``; the gyroscope from the rotations between poses, ``gyro_solve``; six faces too
few for the norm method: ``aligned``) into a ``RecordingCalibration`` (``outcome``);
``results.parameter_file`` writes it. ``calibrate.calibrate_recording`` runs them for
``fieldcal calibrate``.
"""
from __future__ import annotations

import weakref
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np


# (a weak reference to the timestamps, their length, their median step) of the last few arrays
# asked for or read: weak, so that no recording's timestamps are kept alive for it.
_PERIOD_MEMO: list[tuple[weakref.ref, int, float]] = []
_PERIOD_MEMO_SIZE = 4


def sample_period(t: np.ndarray) -> float:
    """The median step of the timestamps ``t`` (s, at least two). The stages that turn a pose's
    sample count into seconds (the noise-weighted solve, the up vectors' covariance, the poses'
    spans) and a Recording's rate each ask for it of the same timestamps: a diff and a median of
    every sample (on imu_tk's recording joined 16×, 7 ms each time, four times), now once per
    timestamps array (the importer hands over its own, ``remember_period``)."""
    for held, length, period in _PERIOD_MEMO:
        if held() is t and length == len(t):
            return period
    period = float(np.median(np.diff(t)))
    remember_period(t, period)
    return period


def remember_period(t: np.ndarray, period: float) -> None:
    """``period`` is float(np.median(np.diff(t))), found by whoever made ``t``."""
    kept = [entry for entry in _PERIOD_MEMO if entry[0]() is not None and entry[0]() is not t]
    _PERIOD_MEMO[:] = [(weakref.ref(t), len(t), period)] + kept[:_PERIOD_MEMO_SIZE - 1]


@dataclass(frozen=True)
class Recording:
    """One continuous record of a unit, on one time base.

    ``t``: (n,) seconds, strictly increasing. ``triads[name]``: (n, 3) in that triad's output
    unit ``units[name]`` ("count" for raw integers), of kind ``kinds[name]`` (``specific_force``
    or ``angular_rate``, see ``fieldcal.model``). ``sources``: the files it came from.
    ``malformed``: file -> (count, first few 1-based line numbers) of lines not used.
    ``temperature``: (n,) the unit's temperature (K or °C) when the logger wrote it, else None.
    """

    t: np.ndarray
    triads: dict[str, np.ndarray]
    kinds: dict[str, str]
    units: dict[str, str]
    sources: tuple[str, ...] = ()
    malformed: dict[str, tuple[int, tuple[int, ...]]] = field(default_factory=dict)
    temperature: np.ndarray | None = None
    unit_serial: str | None = None  # the unit's serial (--unit-serial); None: not given

    def __post_init__(self) -> None:
        n = len(self.t)
        for name, values in self.triads.items():
            if values.shape != (n, 3):
                raise ValueError(f"recording: triad {name} has shape {values.shape}, expected ({n}, 3)")
            if name not in self.kinds or name not in self.units:
                raise ValueError(f"recording: triad {name} has no kind or unit")
        if self.temperature is not None and np.shape(self.temperature) != (n,):
            raise ValueError(f"recording: temperature has shape {np.shape(self.temperature)}, expected ({n},)")

    @cached_property  # a median over every sample: asked for by each stage, computed once
    def rate_hz(self) -> float:
        """The median sample rate."""
        return 1.0 / sample_period(self.t) if len(self.t) > 1 else 0.0

    @property
    def duration_s(self) -> float:
        return float(self.t[-1] - self.t[0]) if len(self.t) else 0.0
