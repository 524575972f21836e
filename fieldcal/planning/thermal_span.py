"""The temperature span a planned procedure needs for a thermal target (issue 28).

The joint thermal fit (``fieldcal.solvers.thermal``) determines a triad's bias drift b₁ and scale
drift s₁ from how the averages move with the unit's temperature during the run, so their σ are
set by how far the temperature moves, not by the positions alone. For the design's windows and a
steady warm-up (temperature linear in time from the first second to the last: the thermal model's
linear part, which a warm-up of a few kelvin mostly is), the Cramér–Rao bound of the thermal
terms (``fieldcal.solvers.crb.ThermalTerms``) is taken at a 1 K span. At the nominal parameters the
averages depend on b₁ and s₁ only through ΔT·b₁ and ΔT·s₁, so their σ scale exactly as 1/span: the
span a target σ needs is σ(1 K) / target. A data-chosen higher order (a curved warm-up) widens them.
"""
from __future__ import annotations

import numpy as np

from fieldcal.earth import Station
from fieldcal.planning.design import Design, OperatorModel, timeline, triad_sigmas
from fieldcal.solvers.crb import ThermalTerms
from fieldcal.solvers.solve import TriadModel

# The thermal targets' groups: b₁ per axis in the triad's bias unit per kelvin, s₁ in ppm/K.
THERMAL_GROUPS = ("bias_drift", "scale_drift")
PPM = 1e-6


def drift_sigmas_per_kelvin(design: Design, operator: OperatorModel, models: dict[str, TriadModel],
                            station: Station, rate_hz: float) -> dict[str, dict[str, np.ndarray]]:
    """Per triad, the σ (solver units: bias unit per K; s₁ per K) of the bias drift b₁ and the
    scale drift s₁ of a run of ``design`` whose temperature rises steadily by 1 K from its first
    second to its last; inf or nan where the design cannot tell the parameters apart."""
    windows, end_s = timeline(design, operator)
    attitudes = np.array(design.attitudes)

    def steady_1k(used) -> ThermalTerms:
        mid_s = np.array([w.start + w.duration / 2 for w in used])
        return ThermalTerms(delta_t=mid_s / end_s - 0.5, bias_terms=np.zeros((1, 3)), scale_drift=np.zeros(3))

    out = {}
    for name, model in models.items():
        try:
            sigmas = triad_sigmas(model, windows, attitudes, design.rate_deg_s, station, rate_hz,
                                  thermal=steady_1k)[9:15]
        except np.linalg.LinAlgError:  # too few positions, or no rate step for a gyro
            sigmas = np.full(6, np.nan)
        out[name] = {"bias_drift": sigmas[:3], "scale_drift": sigmas[3:]}
    return out


def parse_thermal_targets(text: str, models: dict[str, TriadModel]) -> dict[str, dict[str, float]]:
    """``TRIAD.bias_drift=σ`` (the triad's bias unit per K: mg/K, °/h/K) and ``TRIAD.scale_drift=σ``
    (ppm/K) pairs to σ in solver units; one line naming what is wrong otherwise."""
    from fieldcal.planning.targets import sigma_pairs
    from fieldcal.units import display_scale

    targets: dict[str, dict[str, float]] = {}
    for triad, group, sigma in sigma_pairs(text, models, THERMAL_GROUPS, "--thermal-target"):
        model = models[triad]
        scale = display_scale(model.kind, model.output_unit, 0) if group == "bias_drift" else 1 / PPM
        targets.setdefault(triad, {})[group] = sigma / scale
    if not targets:
        raise ValueError("--thermal-target: no σ given; expected TRIAD.bias_drift=σ or TRIAD.scale_drift=σ pairs")
    return targets


def needed_spans(per_kelvin: dict[str, dict[str, np.ndarray]], targets: dict[str, dict[str, float]]
                 ) -> dict[str, dict[str, float]]:
    """Per triad and group, the least temperature span (K) whose worst axis's σ meets the target
    (inf where the design cannot determine the group at any span)."""
    out: dict[str, dict[str, float]] = {}
    for triad, groups in targets.items():
        for group, target in groups.items():
            worst = float(np.max(per_kelvin[triad][group]))
            out.setdefault(triad, {})[group] = worst / target if np.isfinite(worst) else float("inf")
    return out


def thermal_lines(per_kelvin, targets, models, min_span_k: float) -> list[str]:
    """One line per thermal target: the span it needs, its σ at 1 K, and what is assumed."""
    from fieldcal.units import display_scale, param_unit

    lines = []
    for triad, groups in needed_spans(per_kelvin, targets).items():
        model = models[triad]
        for group, span in groups.items():
            if group == "bias_drift":
                scale, unit = display_scale(model.kind, model.output_unit, 0), param_unit(model.kind, model.output_unit, 0) + "/K"
            else:
                scale, unit = 1 / PPM, "ppm/K"
            target, at_1k = targets[triad][group] * scale, float(np.max(per_kelvin[triad][group])) * scale
            if not np.isfinite(span):
                lines.append(f"{triad} {group.replace('_', ' ')} σ {target:.3g} {unit}: this plan cannot "
                             "determine it at any temperature span")
                continue
            floor = (f"; {span:.2g} K would do, but the fit is made from {min_span_k:g} K on (thermal: auto)"
                     if span < min_span_k else "")
            lines.append(f"{triad} {group.replace('_', ' ')} σ {target:.3g} {unit} needs the unit's temperature to "
                         f"change by at least {max(span, min_span_k):.3g} K during the run (σ {at_1k:.3g} {unit} "
                         "per kelvin of span, worst axis; a steady warm-up and a linear model assumed, a "
                         f"curved one needs more{floor})")
    return lines
