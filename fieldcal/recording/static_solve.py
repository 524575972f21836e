"""The specific-force (accelerometer-like) triads' static solve: the norm method on the pose
means, weighted by white noise or a noise model's exact covariance (bias instability included),
the σ scaled up by χ²/dof; and the noise model measured from the fit when none is given: the
white noise of the detector's noise level (the initial rest given by ``--rest``, or the
recording's quietest windows), the bias instability from how far the pose means scatter about the
fit beyond it (``noise_estimate``)."""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from fieldcal.calibration import Calibration
from fieldcal.model import calibrate_with
from fieldcal.recording import median_step
from fieldcal.recording.noise_estimate import MeasuredNoise, bias_instability, flicker_covariance, window_covariance
from fieldcal.recording.up_covariance import MeansCovariance
from fieldcal.solvers import CalibrationError, solve_norm
from fieldcal.solvers.problems import StaticNormProblem

def reduced_chi2(solution: Calibration) -> float:
    return solution.diagnostics.chi2 / max(solution.diagnostics.dof, 1)


def solve_static(name, unit, means, intervals, t, variance, gravity, settings, method=None,
                 white: Calibration | None = None, *, period: float | None = None) -> Calibration:
    """``method``: the norm solver, settings.method unless given (SCREEN: only the minimum χ²).
    ``white``: this very problem's solution by ``method`` on white-noise weights when it is at
    hand (the solve a noise model's weights start from: not done again). ``period``: the
    median step of ``t`` (a Recording's ``period_s``), found again when not given."""
    method = method or settings.method
    problem = StaticNormProblem(means, gravity, name=name, output_unit=unit,
                                labels=tuple(f"pose {i + 1}" for i in range(len(means))))
    # White noise: each mean's per-axis 1σ, the (n, 3) form solve_norm weighs without an n×n matrix.
    solution = white if white is not None else solve_norm(
        problem, np.sqrt(variance[None, :] / np.diff(intervals, axis=1)), method=method)
    noise = settings.noise.get(name)
    if noise is not None:  # bias instability correlates the pose means; its covariance needs the scale
        period = median_step(t) if period is None else period
        solution = solve_norm(problem, means_covariance(intervals, t, variance, noise, solution.K, unit, parts=True,
                                                        period=period), method=method)
    # The noise alone under-states the σ when the poses scatter more than it says (the bias
    # wanders, the temperature moves the scale, a hand trembles: χ²/dof > 1 says so), with a
    # noise model as without one: the σ are scaled up by χ²/dof, never down.
    fit = solution.diagnostics
    ratio = fit.reduced_chi2 or 1.0
    if ratio > 1.0 and not fit.scaled_by_residuals:
        solution = replace(solution, covariance=solution.covariance * ratio, sigma=None,
                           diagnostics=replace(fit, scaled_by_residuals=True))
    return solution


def means_covariance(intervals, t, variance, noise, K, unit, parts: bool = False, *, period: float):
    """Covariance of the flattened pose means (output units): white noise measured over the rest,
    or, with the device's noise model and scale K, the exact one, bias instability included
    (``parts``: kept by its parts, a MeansCovariance, as a norm solve weighs it in O(m²)).
    ``period``: the median step of ``t`` (s), a pose's sample count times it its duration."""
    counts = np.diff(intervals, axis=1)[:, 0]
    if noise is None:
        return np.diag((variance[None, :] / counts[:, None]).ravel())
    durations = counts * period
    if parts:
        quantised = unit == "count" and not isinstance(noise, MeasuredNoise)
        own = np.broadcast_to((1.0 / 12.0 / counts if quantised else np.zeros(len(counts)))[:, None], (len(counts), 3))
        return MeansCovariance(window_covariance(noise, t[intervals[:, 0]], durations), K, own)
    cov = np.kron(window_covariance(noise, t[intervals[:, 0]], durations), K @ K.T)
    if unit == "count" and not isinstance(noise, MeasuredNoise):  # quantisation, one count (measured: in it)
        cov += np.kron(np.diag(1.0 / 12.0 / counts), np.eye(3))
    return cov



def calibrated_jacobian(theta: np.ndarray, means: np.ndarray) -> np.ndarray:
    """(3m, 9): ∂ calibrate_with(theta, means) / ∂theta, flattened pose by pose (central differences)."""
    steps = 1e-6 * np.maximum(np.abs(theta), 1e-3)
    return np.column_stack([((calibrate_with(theta + h * e, means)
                              - calibrate_with(theta - h * e, means)) / (2 * h)).ravel()
                            for h, e in zip(steps, np.eye(len(steps)))])


def estimated_force_noise(solution: Calibration, means: np.ndarray, intervals: np.ndarray, t: np.ndarray,
                          variance: np.ndarray, rate_hz: float, gravity: float) -> MeasuredNoise:
    """A specific-force triad's noise model (SI) from its norm fit on white-noise weights: the
    white noise of ``variance`` (output units² per sample, per axis), and the bias instability
    that the pose means' scatter about the fit shows beyond it (``noise_estimate``). A norm
    residual |a| − g sees a pose's noise along its up direction only, so two poses' flicker
    is shared as uᵢ·uⱼ."""
    m = len(means)
    if solution.diagnostics.dof is not None and solution.diagnostics.dof < 1:
        # An exact fit's residuals are zero whatever the noise, and the scatter's likelihood is
        # then undefined (it gave B = nan, whose solve was refused as "degenerate"): say why.
        raise CalibrationError(f"{solution.name}: {m} poses leave the norm fit no degree of freedom: "
                               "their scatter cannot measure the noise")
    a = calibrate_with(solution.theta, means)
    u = a / np.linalg.norm(a, axis=1)[:, None]
    design = np.einsum("ik,ikp->ip", u, calibrated_jacobian(solution.theta, means).reshape(m, 3, -1))
    counts = np.diff(intervals, axis=1)[:, 0]
    along = np.linalg.solve(solution.K.T, u.T).T  # K⁻ᵀu: an output-unit error's share along up
    white = (along**2 @ variance) / counts
    durations = counts / rate_hz
    flicker = flicker_covariance(t[intervals[:, 0]], durations) * (u @ u.T)
    b = bias_instability(np.linalg.norm(a, axis=1) - gravity, design, white, flicker, weights=1.0 / white)
    K_inv = np.linalg.inv(solution.K)
    white_si = float(np.sqrt(np.trace(K_inv @ np.diag(variance) @ K_inv.T) / 3 / rate_hz))
    return MeasuredNoise(white=white_si, bias_instability=b)
