"""Plain-text tables of calibrations, in operator units with the unit beside every number.

Every table reads a ``fieldcal.calibration.Calibration``, whichever solver made it, and lists
each of its parameters (bias, scale factor and every misalignment term) ± 1σ. Columns are as
wide as their widest cell, so long unit strings (count/(°/s)) keep them aligned.
"""
from __future__ import annotations

import numpy as np

from fieldcal.model import PARAM_NAMES
from fieldcal.units import BIAS, DIMENSIONLESS, group_of, operator_unit

_ANGLE_LABELS = {"delta_yz": "Δyz", "delta_zy": "Δzy", "delta_zx": "Δzx"}


def label(parameter: str) -> str:
    """bias_x -> "bias x", delta_yz -> "Δyz", m_xy -> "m xy"."""
    return _ANGLE_LABELS.get(parameter, parameter.replace("_", " "))


def value_cells(value: float, unit: str) -> list[str]:
    """[number, unit]: a dimensionless factor (a scale factor near 1) to 7 decimals."""
    return [f"{value:.7f}", ""] if unit == DIMENSIONLESS else [f"{value:.5g}", unit]


def sigma_cells(sigma: float, unit: str) -> list[str]:
    """[number, unit]: a dimensionless σ (of a scale factor near 1) in ppm."""
    return [f"{sigma * 1e6:.3g}", "ppm"] if unit == DIMENSIONLESS else [f"{sigma:.3g}", unit]


def aligned(rows: list[list[str]], align: str, indent: str = "  ") -> str:
    """Rows of cells (the first the header) as columns, each as wide as its widest cell;
    ``align`` has one "l" or "r" per column."""
    widths = [max(len(r[i]) for r in rows) for i in range(len(align))]
    return "\n".join(indent + " ".join(c.ljust(w) if a == "l" else c.rjust(w)
                                       for c, w, a in zip(row, widths, align)).rstrip()
                     for row in rows)


def residual_text(cal) -> str:
    factor, unit = operator_unit(cal.kind, cal.residual_unit, BIAS)
    return f"residual RMS {cal.residual_rms * factor:.3g} {unit}"


def solution_header(cal, effort: bool = True) -> str:
    """Solver, effort and fit quality; residuals shown in the unit a bias of that kind uses.

    ``effort=False`` leaves out the iteration and evaluation counts, which differ between
    processors and BLAS builds (for views that must not hold numerically fragile text)."""
    fit, d = residual_text(cal), cal.diagnostics
    if d is None:
        return f"{cal.name} ({cal.method}; {fit})"
    if d.iterations == 0:  # closed form
        return f"{cal.name} ({cal.method} least squares over {len(cal.residuals)} averages; {fit})"
    quality = f"χ²/dof {d.reduced_chi2:.2f}" if d.dof else "exact fit, no χ²"
    spent = f": {d.iterations} iterations, {d.evaluations} evaluations" if effort else ""
    return f"{cal.name} ({d.search or cal.method}{spent}; {fit}; {quality})"


def solution_table(cal, truth: np.ndarray | None = None) -> str:
    """One row per parameter: solved ± 1σ, and, when the truth is known (a simulation's nine
    PARAM_NAMES values), the error in σ."""
    head = ["parameter", "solved", "", "±1σ", ""] + (["true", "", "error/σ"] if truth is not None else [])
    rows = [head]
    if truth is not None:
        true, errors = cal.theta_of(truth), cal.errors_in_sigma(truth)
    for j, name in enumerate(cal.parameter_names):
        factor, unit = operator_unit(cal.kind, cal.output_unit, group_of(name))
        row = [label(name), *value_cells(cal.theta[j] * factor, unit), *sigma_cells(cal.sigma[j] * factor, unit)]
        if name in getattr(cal, "not_calibrated", ()):  # nominal, with no σ: never shown as a σ
            row[3:5] = ["not calibrated", ""]
        if truth is not None:
            row += [*value_cells(true[j] * factor, unit), f"{errors[j]:+.2f}"]
        rows.append(row)
    return aligned(rows, "lrlrl" + ("rlr" if truth is not None else ""))


def comparison_table(cal, previous) -> str:
    """Each parameter of the file's nine against a previous calibration of the same triad: the
    previous value ± 1σ, the change, and the change in units of the combined σ."""
    rows = [["parameter", "previous", "", "±1σ", "", "change", "", "change/σ"]]
    now, now_sigma = cal.file_theta, cal.file_sigma
    before, before_sigma = previous.file_theta, previous.file_sigma
    for j, name in enumerate(PARAM_NAMES):
        factor, unit = operator_unit(cal.kind, cal.output_unit, group_of(name))
        if name in cal.not_calibrated or name in previous.not_calibrated:  # a nominal: no change to weigh
            rows.append([label(name), *value_cells(before[j] * factor, unit), "not calibrated", "", "", "", "-"])
            continue
        change = now[j] - before[j]
        combined = float(np.hypot(now_sigma[j], before_sigma[j]))
        rows.append([label(name), *value_cells(before[j] * factor, unit),
                     *sigma_cells(before_sigma[j] * factor, unit), *sigma_cells(change * factor, unit),
                     f"{change / combined:+.2f}" if combined > 0 else "-"])
    return aligned(rows, "lrlrlrlr")


def worst_error(calibrations: dict, truths: dict) -> float:
    """The largest |solved − true| / σ over every parameter of every calibration with a truth
    (its thermal terms too, when the truth is a ``thermal_truths`` pair)."""
    worst = 0.0
    for name, cal in calibrations.items():
        truth = truths.get(name)
        if truth is None:
            continue
        theta, terms = truth if isinstance(truth, tuple) else (truth, None)
        if theta is not None:
            worst = max(worst, float(np.nanmax(np.abs(cal.errors_in_sigma(theta)))))
        if terms is not None and cal.thermal is not None and cal.thermal.order:
            worst = max(worst, float(np.nanmax(np.abs(_thermal_errors(cal.thermal, terms)))))
    return worst


def thermal_truths(calibrations: dict, truths: dict, thermal: dict) -> dict:
    """Per triad with a thermal model: (its nine true values, its true bias terms) re-centred on
    the model's reference temperature (``fieldcal.thermal.truth_about``); a triad of a warming
    simulation without thermal truth has none (its bias holds still); a real device: {}."""
    from fieldcal.thermal import truth_about

    out = {}
    for name, cal in calibrations.items():
        if cal.thermal is None or truths.get(name) is None:
            continue
        t = thermal.get(name)
        if t is None:
            out[name] = (truths[name], np.zeros((0, 3)))
            continue
        out[name] = truth_about(truths[name], t.reference_c, t.bias_terms, t.scale_drift, cal.thermal.reference_c)
    return out


def _thermal_errors(model, true_terms: np.ndarray) -> np.ndarray:
    """(solved − true)/σ of each bias term the model fitted (a true term beyond its order is 0)."""
    true = np.zeros_like(model.bias_terms)
    k = min(len(true_terms), model.order)
    true[:k] = true_terms[:k]
    sigma = np.where(model.bias_terms_sigma > 0, model.bias_terms_sigma, np.nan)
    return (model.bias_terms - true) / sigma


def thermal_table(cal, true_terms: np.ndarray | None = None) -> str:
    """A thermal model's bias terms ± 1σ (and against the truth re-centred on its reference)."""
    model = cal.thermal
    factor, unit = operator_unit(cal.kind, cal.output_unit, BIAS)
    low, high = model.range_c
    head = (f"  thermal model about {model.reference_c:.2f} °C, calibrated over {low:.2f} to {high:.2f} °C: "
            f"bias polynomial of order {model.order}" + (" (the bias holds still)" if not model.order else ""))
    if model.scale_drift is not None:
        head += "; scale drift (ppm/K) " + ", ".join(
            f"{a} {v * 1e6:+.3g} ± {s * 1e6:.2g}" for a, v, s in zip("xyz", model.scale_drift, model.scale_drift_sigma))
    if not model.order:
        return head
    rows = [["term", "solved", "", "±1σ", ""] + (["true", "", "error/σ"] if true_terms is not None else [])]
    errors = _thermal_errors(model, true_terms) if true_terms is not None else None
    for k in range(model.order):
        per = f"{unit}/K" + ("" if k == 0 else "²³"[k - 1])
        for i, axis in enumerate("xyz"):
            row = [f"b{k + 1} {axis}", f"{model.bias_terms[k, i] * factor:.5g}", per,
                   f"{model.bias_terms_sigma[k, i] * factor:.3g}", per]
            if errors is not None:
                true = true_terms[k, i] if k < len(true_terms) else 0.0
                row += [f"{true * factor:.5g}", per, f"{errors[k, i]:+.2f}"]
            rows.append(row)
    return head + "\n" + aligned(rows, "lrlrl" + ("rlr" if true_terms is not None else ""))


def methods_table(calibrations: dict) -> str:
    """One triad solved by several methods (method -> Calibration, or None where it failed),
    every parameter of any of them ± 1σ side by side; "—" where a method has no such parameter."""
    order: list[str] = []
    for cal in calibrations.values():
        order += [n for n in (cal.parameter_names if cal is not None else ()) if n not in order]
    head = ["parameter"]
    for method in calibrations:
        head += [method, "", "±1σ", ""]
    rows = [head]
    for name in order:
        row = [label(name)]
        for cal in calibrations.values():
            if cal is None or name not in cal.parameter_names:
                row += ["—", "", "", ""]
                continue
            j = cal.parameter_names.index(name)
            factor, unit = operator_unit(cal.kind, cal.output_unit, group_of(name))
            row += [*value_cells(cal.theta[j] * factor, unit), *sigma_cells(cal.sigma[j] * factor, unit)]
            if name in getattr(cal, "not_calibrated", ()):  # nominal, with no σ
                row[-2:] = ["not calibrated", ""]
        rows.append(row)
    return aligned(rows, "l" + "rlrl" * len(calibrations))


def bias_at_end_table(cal, true_end: np.ndarray | None = None) -> str:
    """The bias at the end of the calibration ± 1σ per axis (and, in a simulation, its true value
    and the error in σ), under one line saying what it is; "" when the solve gave none."""
    end = cal.bias_at_end
    if end is None:
        return ""
    factor, unit = operator_unit(cal.kind, cal.output_unit, BIAS)
    head = ["parameter", "solved", "", "±1σ", ""] + (["true", "", "error/σ"] if true_end is not None else [])
    rows = [head]
    for j, axis in enumerate("xyz"):
        row = [f"bias {axis} at end", *value_cells(end.value[j] * factor, unit),
               *sigma_cells(end.sigma[j] * factor, unit)]
        if true_end is not None:
            row += [*value_cells(true_end[j] * factor, unit), f"{(end.value[j] - true_end[j]) / end.sigma[j]:+.2f}"]
        rows.append(row)
    return (f"  bias at the end of calibration (the bias process at the run's last sample, t = {end.time_s:.1f} s: "
            "the value the unit is used with; predicted from the averages):\n"
            + aligned(rows, "lrlrl" + ("rlr" if true_end is not None else "")))


TURN_ON_BIAS_NOTE = ("the gyro's turn-on bias (bias x, y, z above) is solved and reported with its σ but is not "
                     "part of a plan's time target: a MEMS gyro's turn-on bias does not repeat from one "
                     "power-up to the next and every INS re-estimates it at alignment")
