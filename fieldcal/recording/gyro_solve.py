"""The angular-rate triads' solve on the chosen poses: every pose's up vector from the
accelerometer's solution, the gyro's prior from its still readings (bias less the vertical Earth
rate, its σ from their scatter; the scale scanned for raw counts), then the rotations between
poses (fieldcal.solvers.rotation). Neighbouring poses that move together count as fewer
(``drift.still_bias``); the horizontal Earth rate (an unknown heading's) widens each motion's
residual, and a motion during which the gyro clipped at its range is left out."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fieldcal.calibration import Calibration
from fieldcal.earth import EARTH_RATE, Station
from fieldcal.model import calibrate_with
from fieldcal.recording import Recording, median_step
from fieldcal.recording.candidates import RATE_UNITS
from fieldcal.recording.detect import Poses, interval_means
from fieldcal.recording.drift import regular_times, saturated_spans, still_bias, still_fit
from fieldcal.recording.noise_estimate import (MeasuredNoise, bias_instability, flicker_covariance,
                                               window_covariance)
from fieldcal.recording.outcome import RecordingSettings
from fieldcal.recording.place import UnknownPlace
from fieldcal.recording.static_solve import calibrated_jacobian
from fieldcal.recording.turns import rate_residuals
from fieldcal.recording.up_covariance import UpCovariance, means_parts
from fieldcal.solvers.rotation import Motions, RotationNoise, RotationStart, scan_scale, solve_rotations

_SCAN = np.geomspace(1e-3, 1e6, 73)  # candidate gyro sensitivities (output units per rad/s), 8 a decade


def _up_vectors(acc: Calibration, means: np.ndarray, windows: np.ndarray | None,
                own: np.ndarray) -> tuple[np.ndarray, UpCovariance]:
    """Every pose's unit up vector (m, 3) and their covariance, by its parts (see
    recording.up_covariance): each mean's own noise (``windows``, ``own``: ``means_parts``) and
    the accelerometer calibration's error, which all poses share."""
    a = calibrate_with(acc.theta, means)
    norm = np.linalg.norm(a, axis=1)
    u = a / norm[:, None]
    D = (np.eye(3)[None] - u[:, :, None] * u[:, None, :]) / norm[:, None, None]  # (P, 3, 3) ∂u/∂a, pose by pose
    shared = D @ calibrated_jacobian(acc.theta, means).reshape(len(means), 3, -1)
    return u, UpCovariance(D, windows, own, shared, acc.covariance)



@dataclass(frozen=True)
class GyroPrior:
    """What the still poses say about a gyro before its rotation solve: ``scale`` (output units
    per rad/s, the unit's or scanned for counts), ``bias`` (the mean of every pose's still
    reading less the vertical Earth rate, see ``drift.still_bias``) and its 1σ ``bias_sigma``
    (from the readings' scatter, drift counted), ``earth_variance`` (rad²/s² per axis the unknown heading leaves),
    ``rate_noise`` (angle random walk, rad/√s) and ``rest_variance`` (output units², per axis)."""

    scale: float
    bias: np.ndarray
    bias_sigma: np.ndarray
    earth_variance: float
    rate_noise: float
    rest_variance: np.ndarray
    wander_variance: float = 0.0  # rad²/s² per axis: how far the bias moves from pose to pose beyond the noise
    estimated_noise: MeasuredNoise | None = None  # measured from the recording when no model was given


def gyro_prior(recording: Recording, name: str, poses: Poses, up: np.ndarray, spans: np.ndarray,
               station: Station | UnknownPlace, noise=None, estimate: bool = False,
               motions: Motions | None = None) -> GyroPrior:
    """``noise``: the gyro's TriadNoise from a device config, if any: its bias instability moves
    every pose's reading alike, which their scatter cannot show, so it widens the bias's σ.
    Without one and with ``estimate``, the model is measured from the poses' still readings
    (see estimated_rate_noise). ``motions``: the solve's (its timestamps, maybe with the
    logger's jitter taken out): the scan then integrates them and makes the steps the solve
    integrates, once (made twice, they were a tenth of the gyro's work at 16×)."""
    t, gyro, iv = recording.t, recording.triads[name], poses.intervals
    counts = np.diff(iv, axis=1)[:, 0]
    rest = slice(iv[0, 0], iv[0, 1])
    rest_mean = gyro[rest].mean(axis=0)
    rest_var = np.var(gyro[rest], axis=0, ddof=1)
    k = RATE_UNITS.get(recording.units[name])
    if k is None:  # raw counts: the scale that makes the rotations fit
        k = scan_scale(t, gyro, spans, up[:-1], up[1:], rest_mean, _SCAN) if motions is None else \
            scan_scale(motions.t, motions.raw, motions.spans, motions.up_start, motions.up_end, rest_mean, _SCAN,
                       motions)
    # Every pose's still reading: each one an estimate of the bias.
    still, earth_var = _less_earth_rate(interval_means(gyro, iv), up, k, station)
    # A real gyro's still reading moves between poses (g-sensitivity, warm-up, temperature, bias
    # random walk): the mean over the poses, its σ from their scatter (see drift.still_bias); never
    # below what the Earth rate and the white noise alone leave in a mean over independent poses.
    white = np.mean(rest_var[None, :] / counts[:, None], axis=0) / len(iv)
    times = 0.5 * (t[iv[:, 0]] + t[iv[:, 1] - 1])
    b0, bias_sigma = still_bias(still, k**2 * earth_var / len(iv) + white, up, times, 0.5 * (t[0] + t[-1]))
    # What the model leaves of the readings' scatter beyond the noise and the Earth rate: the bias
    # wanders (random walk, warm-up's curve) and a motion between poses integrates that too.
    X, _, residuals = still_fit(still, up, times, 0.5 * (t[0] + t[-1]))
    wander = 0.0
    if len(iv) > X.shape[1]:
        spread = np.sum(residuals**2, axis=0) / (len(iv) - X.shape[1])
        noise_floor = k**2 * earth_var + np.mean(rest_var[None, :] / counts[:, None], axis=0)
        wander = float(np.mean(np.maximum(spread - noise_floor, 0.0))) / k**2
    estimated = None
    if noise is None and estimate:
        noise = estimated = estimated_rate_noise(still, up, iv, t, k, rest_var, k**2 * earth_var,
                                                 recording.rate_hz)
    if noise is not None and noise.bias_instability:
        weights = np.full(len(iv), 1.0 / len(iv))
        model = weights @ window_covariance(noise, t[iv[:, 0]], counts / recording.rate_hz) @ weights
        bias_sigma = np.sqrt(bias_sigma**2 + np.maximum(k**2 * model - white, 0.0))
    arw = float(np.sqrt(np.mean(rest_var)) / k / math.sqrt(recording.rate_hz))  # rad/√s
    return GyroPrior(k, b0, bias_sigma, earth_var, arw, rest_var, wander, estimated)


def _less_earth_rate(still: np.ndarray, up: np.ndarray, scale: float,
                     station: Station | UnknownPlace) -> tuple[np.ndarray, float]:
    """The poses' still readings (m, 3) less the vertical Earth rate each sees (``scale``: output
    units per rad/s), and the variance (rad²/s² per axis) of what is left of the Earth rate."""
    if isinstance(station, UnknownPlace):  # all of the Earth rate is an error of known size
        return still, EARTH_RATE**2 / 3
    sin_lat, cos_lat = math.sin(station.latitude_rad), math.cos(station.latitude_rad)
    # Unknown heading: the horizontal Earth rate is an error of known size, not a known offset.
    return still - scale * EARTH_RATE * sin_lat * up, (EARTH_RATE * cos_lat) ** 2 / 2


def estimated_rate_noise(still: np.ndarray, up: np.ndarray, intervals: np.ndarray, t: np.ndarray,
                         scale: float, rest_variance: np.ndarray, earth_variance: float,
                         rate_hz: float) -> MeasuredNoise:
    """A gyro's noise model (rad/s) from its poses' ``still`` readings (m, 3, the vertical Earth
    rate taken off) and their fit (``drift.still_fit``): the white noise of ``rest_variance``
    (output units² per sample, ``scale`` output units per rad/s) and the bias instability their
    scatter shows beyond it and beyond the horizontal Earth rate's ``earth_variance`` (output
    units², a heading's share per pose)."""
    counts = np.diff(intervals, axis=1)[:, 0]
    times = 0.5 * (t[intervals[:, 0]] + t[intervals[:, 1] - 1])
    design, _, residuals = still_fit(still, up, times)
    white = float(np.mean(rest_variance)) / counts + earth_variance
    b = bias_instability(residuals, design, white, flicker_covariance(t[intervals[:, 0]], counts / rate_hz))
    k = abs(scale)
    return MeasuredNoise(white=float(np.sqrt(np.mean(rest_variance) / rate_hz)) / k, bias_instability=b / k)


def solve_gyro(recording: Recording, name: str, poses: Poses, acc: Calibration, acc_var: np.ndarray,
               station: Station, settings: RecordingSettings,
               turns: np.ndarray) -> tuple[Calibration, np.ndarray, str, MeasuredNoise | None]:
    """The solution, its bias's 1σ, a note for the summary (or "") and the noise model
    measured from the recording (None: given, or not estimated)."""
    t, iv = regular_times(recording.t, recording.rate_hz), poses.intervals
    spans = np.column_stack([iv[:-1, 1] - 1, iv[1:, 0]])
    acc_noise = settings.noise.get(acc.name)  # quantisation as means_covariance counts it
    quantised = recording.units[acc.name] == "count" and not isinstance(acc_noise, MeasuredNoise)
    period = recording.period_s if t is recording.t else median_step(t)  # the jitter taken out: the grid's
    up, up_cov = _up_vectors(acc, poses.means, *means_parts(iv, t, acc_var, acc_noise, acc.K, quantised,
                                                           period=period))
    gyro = recording.triads[name]
    motions = Motions.of(t, gyro, spans, up[:-1], up[1:])
    prior = gyro_prior(recording, name, poses, up, spans, station, settings.noise.get(name),
                       settings.estimate_noise, motions)
    extra = None
    if settings.table_rate_deg_s is not None and len(turns):
        extra = rate_residuals(gyro, recording.triads[acc.name], acc.theta, turns, settings.table_rate_deg_s,
                               station, prior.bias, prior.scale, prior.rest_variance)
    duration = t[spans[:, 1]] - t[spans[:, 0]]
    # A motion during which the gyro sat at the end of its range integrates to a wrong rotation:
    # its residual gets a variance of a whole turn, so it weighs nothing (the chain of poses and
    # their covariance stay as they are).
    clipped = saturated_spans(gyro, spans + [0, 1])
    note = ""
    if clipped.any():
        note = (f"{name}: {int(clipped.sum())} of {len(spans)} motions left out of the solve: the gyro sat at "
                "the end of its range (turn more slowly, or set a wider range)")
    noise = RotationNoise(bias_sigma=prior.bias_sigma, up_covariance=up_cov, rate_noise=prior.rate_noise,
                          motion_variance=(prior.earth_variance + prior.wander_variance) * duration**2
                          + np.where(clipped, (2 * math.pi) ** 2, 0.0))
    solution = solve_rotations(motions,
                               RotationStart.of(prior.scale, prior.bias, settings.estimate_gyro_bias),
                               noise, extra, settings.gyro_method, name, recording.units[name])
    # Held, the bias's σ is bias_sigma (drift and g-sensitivity included); estimated, the fit's.
    return solution, solution.sigma[:3], note, prior.estimated_noise
