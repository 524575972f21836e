"""Plain-text tables of solutions, in operator units with the unit beside every number."""
from __future__ import annotations

import numpy as np

from fieldcal.model import PARAM_NAMES
from fieldcal.units import display_scale, param_unit

_ROW_NAMES = ("bias x", "bias y", "bias z", "scale x", "scale y", "scale z",
              "Δyz", "Δzy", "Δzx")


def _fmt(value: float, unit: str, index: int) -> str:
    if 3 <= index < 6 and unit == "1":
        return f"{value:.7f}"
    return f"{value:.5g} {unit}"


def _fmt_sigma(sigma: float, unit: str, index: int) -> str:
    if 3 <= index < 6 and unit == "1":
        return f"{sigma * 1e6:.3g} ppm"
    return f"{sigma:.3g} {unit}"


def solution_header(sol, effort: bool = True) -> str:
    """Solver, effort and fit quality; residuals shown in the unit a bias of that kind uses.

    ``effort=False`` leaves out the iteration and evaluation counts, which differ between
    processors and BLAS builds (for views that must not hold numerically fragile text)."""
    rms = sol.residual_rms * display_scale(sol.kind, sol.residual_unit, 0)
    fit = f"residual RMS {rms:.3g} {param_unit(sol.kind, sol.residual_unit, 0)}"
    if sol.method == "classic":
        return f"{sol.name} (classic least squares over {len(sol.residuals)} averages; {fit})"
    quality = f"χ²/dof {sol.chi2 / sol.dof:.2f}" if sol.dof else "exact fit, no χ²"
    spent = f": {sol.iterations} iterations, {sol.evaluations} evaluations" if effort else ""
    return f"{sol.name} ({sol.method}{spent}; {fit}; {quality})"


def solution_table(sol, truth: np.ndarray | None = None) -> str:
    """One row per parameter: solved ± 1σ, and, when the truth is known, the error in σ."""
    head = f"  {'parameter':<9} {'solved':>18} {'±1σ':>12}"
    if truth is not None:
        head += f" {'true':>18} {'error/σ':>8}"
    lines = [head]
    for j, _ in enumerate(PARAM_NAMES):
        scale = display_scale(sol.kind, sol.output_unit, j)
        unit = param_unit(sol.kind, sol.output_unit, j)
        row = (f"  {_ROW_NAMES[j]:<9} {_fmt(sol.theta[j] * scale, unit, j):>18} "
               f"{_fmt_sigma(sol.sigma[j] * scale, unit, j):>12}")
        if truth is not None:
            row += (f" {_fmt(truth[j] * scale, unit, j):>18} "
                    f"{(sol.theta[j] - truth[j]) / sol.sigma[j]:>+8.2f}")
        lines.append(row)
    return "\n".join(lines)


def comparison_table(sol, previous) -> str:
    """Each parameter against a previous calibration (``TriadParameters``) of the same triad:
    the previous value ± 1σ, the change, and the change in units of the combined σ."""
    lines = [f"  {'parameter':<9} {'previous':>18} {'±1σ':>12} {'change':>14} {'change/σ':>9}"]
    for j, _ in enumerate(PARAM_NAMES):
        scale = display_scale(sol.kind, sol.output_unit, j)
        unit = param_unit(sol.kind, sol.output_unit, j)
        change = sol.theta[j] - previous.theta[j]
        combined = float(np.hypot(sol.sigma[j], previous.sigma[j]))
        in_sigma = f"{change / combined:>+9.2f}" if combined > 0 else f"{'-':>9}"
        lines.append(f"  {_ROW_NAMES[j]:<9} {_fmt(previous.theta[j] * scale, unit, j):>18} "
                     f"{_fmt_sigma(previous.sigma[j] * scale, unit, j):>12} "
                     f"{_fmt_sigma(change * scale, unit, j):>14} {in_sigma}")
    return "\n".join(lines)
