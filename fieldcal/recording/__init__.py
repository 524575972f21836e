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

from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np


def median_step(t: np.ndarray) -> float:
    """The median step of the timestamps ``t`` (s, at least two): a diff and a median of every
    sample (7 ms on imu_tk's recording joined 16×). A Recording's is its ``period_s``, found
    once; the stages that turn sample counts into seconds are handed it."""
    return float(np.median(np.diff(t)))


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
    def period_s(self) -> float:
        """The median sample step (s); 0 with fewer than two samples. The importer gives the one
        it found while reading (no second median)."""
        return median_step(self.t) if len(self.t) > 1 else 0.0

    @cached_property
    def rate_hz(self) -> float:
        """The median sample rate."""
        return 1.0 / self.period_s if len(self.t) > 1 else 0.0

    def replaced(self, **changes) -> "Recording":
        """``dataclasses.replace``, its period and rate kept when the timestamps stay the same
        array (a serial number added: no median of every sample again)."""
        new = replace(self, **changes)
        if new.t is self.t:
            for name in ("period_s", "rate_hz"):  # the cached_properties' own slots, where found
                if name in self.__dict__:
                    new.__dict__[name] = self.__dict__[name]
        return new

    @property
    def duration_s(self) -> float:
        return float(self.t[-1] - self.t[0]) if len(self.t) else 0.0
