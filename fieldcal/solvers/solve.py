"""Solve every triad of a unit from a procedure's window averages.

Shared by the simulated demo and the procedure engine: norm method (Powell by default) for field
procedures, classic least squares for aligned ones; weights from the covariance of the averages,
which follows from each triad's noise model and the windows' timing.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from drivers.noise import TriadNoise
from fieldcal.solvers.methods import METHODS, THERMAL_MODES, resolve_method  # noqa: F401  (re-exported)
from fieldcal.solvers.assemble import build_problem, classic_inputs
from fieldcal.solvers.problems import RateNormProblem
from fieldcal.earth import Station
from fieldcal.procedure.positions import Procedure
from fieldcal.procedure.windows import STATIC, Window
from fieldcal.solvers import CalibrationError, solve_classic, solve_norm


@dataclass(frozen=True)
class TriadModel:
    """What the station knows of a triad before calibrating it."""

    kind: str
    output_unit: str
    noise: TriadNoise  # SI input units
    sensitivity: np.ndarray  # (3, 3) nominal K, output units per SI unit
    lsb: float = 0.0  # output quantisation step


@dataclass(frozen=True)
class UnitSolution:
    solutions: dict  # triad -> Calibration (norm method, or classic for an aligned procedure)
    failures: dict[str, str]  # triad -> why it could not be calibrated
    problems: dict  # triad -> norm problem (field procedures)
    covariances: dict[str, np.ndarray]  # triad -> covariance of the data it was solved from
    inputs: dict[str, np.ndarray]  # triad -> the averages it was solved from, flattened
    # One line saying whether a thermal model was fitted, why, and its order per triad; None when
    # the windows carry no temperature and nobody asked for one (``thermal_statement``).
    thermal_note: str | None = None

    def parameter_file(self, procedure: Procedure, method: str, station: Station, **provenance):
        """The parameter file of the solved triads (None if none solved): its ``input_sha256``
        is the hash of the averages each triad was actually solved from (``inputs``), whichever
        method solved it. ``provenance``: device_name, device_serial, simulation, operator."""
        from fieldcal.paramfile import ParameterFile

        if not self.solutions:
            return None
        return ParameterFile.from_solutions(self.solutions.values(), inputs=list(self.inputs.values()),
                                            station=station, procedure=procedure.name,
                                            method=resolve_method(procedure, method), **provenance)


def average_covariance(model: TriadModel, windows: list[Window], rate_hz: float) -> np.ndarray:
    """Covariance of the flattened window means (window-major, then axis), output units.

    Each axis has the same noise, independent between axes, entering before K:
    cov(u_w, u_v) = C[w, v] · K Kᵀ with C the one-axis window covariance; quantisation adds
    lsb²/12 per sample.
    """
    C = model.noise.window_covariance([w.start for w in windows], [w.duration for w in windows])
    K = model.sensitivity
    cov = np.kron(C, K @ K.T)
    if model.lsb:
        samples = np.array([w.duration for w in windows]) * rate_hz
        cov += np.kron(np.diag(model.lsb**2 / 12.0 / samples), np.eye(3))
    return cov


# The horizontal Earth rate (Ωe·cos φ, 11.5 °/h at 40°) is used as a norm |a⊥| of a static dwell
# only when a typical dwell's per-axis noise is well below it. At a signal-to-noise ratio near 1
# (the VN-100's and MTi's 10 °/h bias instability over a 200 s dwell) that norm is dominated by
# noise: it is biased upwards and its linearised weight is taken in the direction of the noise,
# so the solver reported gyro bias σ 0.70-0.76 of the Cramér-Rao bound (crb.py, same windows and
# covariance) while the errors reached ~1.9 of it (headless field-18, RMS z 1.9 on the biases).
# Without the term the reported σ are the bound to 1 % (it holds ~1 % of the information there)
# and RMS z ≈ 1. The paper's unit (SNR 13 over 200 s, 5.4 over 20 s) keeps it; at SNR 3 the
# norm's upward bias is still below 0.2 σ.
_ACROSS_MIN_SNR = 3.0


def across_earth_rate_usable(model: TriadModel, static_windows: list[Window], station: Station) -> bool:
    """Whether the typical static dwell sees the horizontal Earth rate well above its noise."""
    if not static_windows:
        return True
    C = model.noise.window_covariance([w.start for w in static_windows],
                                      [w.duration for w in static_windows])
    return station.earth_rate_horizontal > _ACROSS_MIN_SNR * float(np.sqrt(np.median(np.diag(C))))


def solve_unit(procedure: Procedure, windows: list[Window], averages: dict[str, np.ndarray],
               models: dict[str, TriadModel], station: Station, rate_hz: float,
               method: str = "auto", thermal: str = "auto", end_s: float | None = None) -> UnitSolution:
    """``averages[name]`` is (len(windows), 3), one row per window, for every triad in models.
    ``thermal`` (THERMAL_MODES): fit the joint thermal model when the windows' temperatures span
    THERMAL_MIN_SPAN_K (auto), whenever they carry temperatures (on), or never (off).
    ``end_s``: the sample time of the run's last sample; with it, each triad solved by the norm
    method also reports its bias at that time and its σ (``endbias``, DESIGN 12)."""
    if thermal not in THERMAL_MODES:
        raise ValueError(f"thermal: expected one of {', '.join(THERMAL_MODES)}, got {thermal!r}")
    method = resolve_method(procedure, method)
    ids = [p.id for p in procedure.positions]
    up_body = np.array([p.up_body for p in procedure.positions])
    solutions, failures, problems, covs, inputs = {}, {}, {}, {}, {}
    for name, model in models.items():
        try:
            if method == "classic":
                if not procedure.aligned:
                    raise CalibrationError(f"{name}: the classic method needs an aligned procedure "
                                           f"(known orientations); {procedure.name} is not one")
                used, true_inputs = classic_inputs(model.kind, windows, up_body, station)
                covs[name] = average_covariance(model, [windows[i] for i in used], rate_hz)
                inputs[name] = averages[name][used].ravel()
                solutions[name] = solve_classic(averages[name][used], true_inputs, name, model.kind,
                                                model.output_unit, covariance=covs[name])
                continue
            problem, order = build_problem(name, model.kind, model.output_unit, windows,
                                           averages[name], station, ids)
            covs[name] = average_covariance(model, [windows[i] for i in order], rate_hz)
            if isinstance(problem, RateNormProblem) and not across_earth_rate_usable(
                    model, [w for w in windows if w.kind == STATIC], station):
                problem = replace(problem, use_across=False)
            problems[name], inputs[name] = problem, problem.data
            temperatures = _temperatures([windows[i] for i in order], thermal)
            if temperatures is not None:
                from fieldcal.solvers.thermal import solve_thermal_norm

                solutions[name] = solve_thermal_norm(problem, temperatures, covs[name]).calibration
                continue
            solutions[name] = solve_norm(problem, covs[name], method=method)
            if end_s is not None:
                solutions[name] = _with_bias_at_end(solutions[name], problem, model,
                                                    [windows[i] for i in order], end_s, covs[name])
        except CalibrationError as exc:
            failures[name] = str(exc)
    return UnitSolution(solutions, failures, problems, covs, inputs, thermal_statement(windows, solutions, thermal))


def _with_bias_at_end(calibration, problem, model: TriadModel, windows: list[Window], end_s: float,
                      covariance: np.ndarray):
    """The calibration with its bias at the end of the run, when the noise model gives one (a
    bias process with a stationary covariance: not with rate random walk)."""
    if model.noise.rate_random_walk:
        return calibration
    from fieldcal.solvers.endbias import bias_at_end

    end = bias_at_end(problem, calibration, model.noise, model.sensitivity, [w.start for w in windows],
                      [w.duration for w in windows], end_s, covariance)
    return replace(calibration, bias_at_end=end)


# A span of temperature below which no thermal term is fitted unless asked for (thermal: on): a
# unit held within a tenth of a kelvin (the VectorNav's resolution) gives its averages no lever on one.
THERMAL_MIN_SPAN_K = 0.5


def _temperatures(windows: list[Window], thermal: str = "auto") -> np.ndarray | None:
    """The windows' mean temperatures when a thermal model is to be fitted on them (every window
    has one, and ``thermal`` is on, or auto with a span of THERMAL_MIN_SPAN_K); else None."""
    values = [w.temperature_c for w in windows]
    if thermal == "off" or not values or any(v is None for v in values):
        return None
    temperatures = np.array(values, dtype=float)
    return temperatures if thermal == "on" or np.ptp(temperatures) >= THERMAL_MIN_SPAN_K else None


def thermal_statement(windows: list[Window], solutions: dict, thermal: str) -> str | None:
    """One line: whether the thermal model was fitted, the setting and the span that decided it,
    and the order per triad. None: no temperatures and thermal auto (nothing was decided)."""
    values = [w.temperature_c for w in windows if w.temperature_c is not None]
    if not values or len(values) < len(windows):
        if thermal != "on":
            return None
        return "thermal model not fitted (thermal: on), the windows do not all carry a temperature"
    span = float(np.ptp(values))
    why = f"thermal: {thermal}; window temperatures {min(values):.2f} to {max(values):.2f} °C, span {span:.2f} K"
    fitted = [f"{name} order {cal.thermal.order}" + (" + scale drift" if cal.thermal.scale_drift is not None else "")
              for name, cal in solutions.items() if cal.thermal is not None]
    if fitted:
        return f"thermal model fitted ({why}): {', '.join(fitted)}"
    if thermal == "auto" and span < THERMAL_MIN_SPAN_K:
        why += f", below the {THERMAL_MIN_SPAN_K} K auto needs"
    return f"thermal model not fitted ({why})"


def models_from_truth(device) -> dict[str, TriadModel]:
    """The station's knowledge of a simulated device: its true noise and scale."""
    return {name: TriadModel(t.kind, t.output_unit, t.noise, t.K, t.lsb) for name, t in device.items()}
