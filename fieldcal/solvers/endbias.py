"""The bias at the end of the calibration: its best linear unbiased predictor and that one's σ.

What a unit is used with right after calibration is its bias at the run's last sample (DESIGN
12): the constant b plus K times the bias process (the flicker bank of ``drivers.noise``) at that
instant, not the turn-on constant b the norm method estimates. The averages the triad was solved
from carry what the data say of that process: their residuals at the solution r(θ̂), whose noise
G·n (G = ∂r/∂u, n the averages' noise of covariance Σ) is correlated with K·p(t_end) through the
bank (``TriadNoise.point_covariance``). Goldberger's best linear unbiased predictor from them is

    b̂_end = b̂ + Ĝᵀ S⁻¹ r(θ̂),  Ĝ = G·cov(n, K·p(t_end)),  S = G Σ Gᵀ,

and with the whitened Gw = L⁻¹Ĝ, Jw = L⁻¹ ∂r/∂θ (L Lᵀ = S) and E the bias rows of θ its error
covariance is V − GwᵀGw + (E + GwᵀJw)(JwᵀJw)⁻¹(E + GwᵀJw)ᵀ, V the covariance of K·p(t_end): the
same quantity ``fieldcal.solvers.crb`` bounds, here at the solution and the measured windows (the
sign of GwᵀJw is +, as r grows with θ̂ − θ where a mean's residual y − f(θ̂) shrinks). Linear in
the residuals, so exact to the first order the norm method's σ are.

Pure: arrays in, an estimate out (no I/O, no clock; the end time comes from the data).
"""
from __future__ import annotations

import numpy as np

from fieldcal.calibration import BiasAtEnd, Calibration
from fieldcal.solvers.crb import end_bias_terms
from fieldcal.solvers.norm import _jacobian, _natural_scales


def bias_at_end(problem, calibration: Calibration, noise, sensitivity: np.ndarray, starts, durations,
                end_s: float, covariance: np.ndarray) -> BiasAtEnd:
    """The triad's predicted bias at ``end_s`` (sample time of the run's last sample) and its σ.

    ``problem`` is the norm problem the triad was solved from, ``covariance`` that of its data
    (``solve.average_covariance``), ``starts``/``durations`` the windows in the data's order and
    ``noise`` (``drivers.noise.TriadNoise``) the model that covariance came from. A covariance
    scaled by the residuals (Birge, when the scatter is well beyond the stated noise) scales this
    one alike."""
    theta = np.asarray(calibration.theta, dtype=float)
    u = problem.data
    at_data = problem.residual_function(u)
    natural = _natural_scales(problem, theta)
    J = _jacobian(at_data, theta, 1e-7 * natural)  # ∂r/∂θ, (m, 9)
    # The residuals are smooth in the averages: central differences at 1e-6 of their size.
    steps = 1e-6 * np.maximum(np.abs(u), np.abs(theta[3:6]).max() * problem.reference_scale)
    G = _jacobian(lambda x: problem.residuals(theta, x), u, steps)  # ∂r/∂u, (m, data)
    # The end is no earlier than the last window's end (its last sample ends a sample interval
    # before the window's nominal end).
    end_s = max(float(end_s), float(np.max(np.asarray(starts) + np.asarray(durations))))
    end = end_bias_terms(noise, sensitivity, starts, durations, end_s)
    L = np.linalg.cholesky(G @ covariance @ G.T)
    Gw = np.linalg.solve(L, G @ end.cross)
    Jw = np.linalg.solve(L, J)
    rw = np.linalg.solve(L, at_data(theta))
    lead = np.eye(3, len(theta)) + Gw.T @ Jw
    error = end.point - Gw.T @ Gw + lead @ np.linalg.inv(Jw.T @ Jw) @ lead.T
    d = calibration.diagnostics
    if d is not None and d.scaled_by_residuals and d.dof and d.chi2 is not None:
        error = error * (d.chi2 / d.dof)
    return BiasAtEnd(value=theta[:3] + Gw.T @ rw, covariance=error, time_s=end_s)
