"""What the recording pipeline is asked (RecordingSettings) and what it returns
(RecordingCalibration), with the names of the protocols it may choose."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fieldcal.calibration import Calibration
from fieldcal.earth import Station
from fieldcal.recording.detect import DetectorSettings, Poses, SpreadReport
from fieldcal.recording.place import UnknownPlace

NORM_PROTOCOL = "hand-held poses: the norm method for the accelerometer, the rotations for the gyro"
FORCE_ONLY_PROTOCOL = "static poses: the norm method for the accelerometer"
ALIGNED_PROTOCOL = ("Ferraris: six axis-aligned poses and full turns; the aligned six-position solution for "
                    "the accelerometer (the norm method needs 9 poses), the turns' ±2π integrals for the gyro")
SUBMODEL_PROTOCOL = ("the largest well-determined sub-model (the poses are too few or too alike for the norm "
                     "method): what they determine of each accelerometer, the gyro's bias from the still poses")
ALIGNED_FORCE_ONLY_PROTOCOL = ("six axis-aligned poses: the aligned six-position solution for the accelerometer "
                               "(the norm method needs 9 poses)")


@dataclass(frozen=True)
class RecordingSettings:
    """How ``calibrate_recording`` finds the poses and solves the triads."""
    detector: DetectorSettings = field(default_factory=DetectorSettings)
    method: str = "powell"  # the specific-force triads' norm solver
    gyro_method: str = "lsq"
    estimate_gyro_bias: bool = False  # else the poses' mean (less the vertical Earth rate)
    # The device's noise per triad (SI), e.g. from its config: pose means then get their exact
    # covariance, bias instability included. Without it, white noise measured over the rest.
    noise: dict = field(default_factory=dict)
    # Turns on a turntable at this rate (°/s) become rate-norm equations for the gyro solve.
    table_rate_deg_s: float | None = None
    # Each triad's scale temperature coefficient (ppm/K), e.g. from its device config: the σ of a
    # Ferraris session's scale factors hold that drift (fieldcal.recording.ferraris.ScaleDrift).
    scale_tempco_ppm_per_k: dict = field(default_factory=dict)
    # A triad with no noise model in ``noise``: its white noise and bias instability estimated
    # from the recording (see noise_estimate); False: white noise alone, as measured.
    estimate_noise: bool = True


@dataclass(frozen=True)
class RecordingCalibration:
    """What ``calibrate_recording`` found and solved, and what it did about the data."""
    poses: Poses
    spread: SpreadReport
    tried: tuple[tuple[float, int, str], ...]  # (multiple, distinct poses, χ²/dof or why not)
    specific_force: dict[str, Calibration]
    angular_rate: dict[str, Calibration]  # method classic: the Ferraris turns
    failures: dict[str, str]
    reference_triad: str
    gyro_bias_sigma: dict[str, np.ndarray]  # 1σ of each gyro's bias (output units)
    turns: np.ndarray  # (k, 2) [start, stop) samples of steady turntable turns found
    table_rate_used: bool = False  # the turns went into the gyro solve as rate equations
    noise_source: str = "the initial rest"  # where the detector's noise level was measured
    place: Station | UnknownPlace | None = None  # the station used (gravity filled in when unknown)
    protocol: str = NORM_PROTOCOL  # which solution was chosen, and why
    notes: tuple[str, ...] = ()  # what the solve did about the data, for the summary (e.g. clipped motions)
    estimated_noise: dict = field(default_factory=dict)  # triad -> MeasuredNoise (SI) from the recording
