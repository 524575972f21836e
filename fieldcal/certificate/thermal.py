"""A triad's thermal model on its certificate (issue 28): the reference temperature, the range it
was calibrated over, the bias polynomial's order, every term ± 1σ in operator units (with the
spec's thermal limits and PASS/FAIL), and the bias against temperature over the range with a
±1σ band. A triad without a model shows nothing, unless the spec limits its thermal terms: then
one line says it was not calibrated for temperature (the checks' FAIL)."""
from __future__ import annotations

from html import escape

import numpy as np

POWERS = ("", "²", "³")


def bias_band(cal, temperature_c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """bias(T) = b₀ + Σₖ bₖΔTᵏ and its 1σ, each (n, 3) in the file's output units. The file
    holds each term's σ and not their covariance, so the σ is that of independent terms,
    √(σ_b₀² + Σₖ (σₖ ΔTᵏ)²), as the caption says."""
    model = cal.thermal
    dt = np.asarray(temperature_c, dtype=float) - model.reference_c
    powers = dt[:, None] ** np.arange(1, model.order + 1)
    bias = cal.bias + powers @ model.bias_terms
    sigma_b0 = np.asarray(cal.file_sigma[:3])
    sigma = np.sqrt(sigma_b0 ** 2 + (powers ** 2) @ (model.bias_terms_sigma ** 2))
    return bias, sigma


def _rows(cal, checks: dict, ts, with_results: bool) -> list[list[str]]:
    """[term, value, ±1σ, unit, (limits, result)] per axis of each term: bₖ, then s₁."""
    from fieldcal.acceptance import thermal_units
    from fieldcal.certificate import _limits, _result

    model, units = cal.thermal, thermal_units(cal)
    factor, per_k = units["bias_drift"]
    limits = (ts.thermal or {}) if ts is not None else {}
    rows = []
    terms = [(f"b{k + 1}", model.bias_terms[k] * factor, model.bias_terms_sigma[k] * factor,
              per_k + POWERS[k], "bias_drift" if k == 0 else None) for k in range(model.order)]
    if model.scale_drift is not None:
        scale, ppm = units["scale_drift"]
        terms.append(("scale drift", model.scale_drift * scale, model.scale_drift_sigma * scale, ppm, "scale_drift"))
    for name, values, sigmas, unit, key in terms:
        for i, axis in enumerate("xyz"):
            row = [f"{name} {axis}", f"{values[i]:.5g}", f"{sigmas[i]:.3g}", unit]
            if with_results:
                limit = limits.get(key) if key is not None else None
                result = _result(checks.get((cal.name, f"{key}_{axis}"))) if limit else "–"
                row += [_limits(limit, unit), result if ts is not None else _result(None)]
            rows.append(row)
    return rows


def thermal_section(cal, checks: dict, with_results: bool, spec_triad) -> str:
    """The triad's thermal part of its certificate section ("" for a triad without a model and
    no thermal limits)."""
    from fieldcal.certificate import _row

    if cal.thermal is None:
        failed = [c for key, c in checks.items() if key[0] == cal.name and key[1] in ("bias_drift", "scale_drift")]
        return "".join(f"<p class='thermal FAIL'>{escape(c.parameter.replace('_', ' '))}: FAIL: "
                       f"{escape('; '.join(c.reasons))}</p>" for c in failed)
    model = cal.thermal
    low, high = model.range_c
    order = f"bias polynomial of order {model.order}" + (" (the bias holds still)" if not model.order else "")
    scale = "with a scale drift" if model.scale_drift is not None else "no scale drift"
    head = ["term", "value", "±1σ", "unit"] + (["limits", "result"] if with_results else [])
    rows = [_row(head, header=True)]
    for row in _rows(cal, checks, spec_triad, with_results):
        styles = ["", "num", "num", ""] + (["", row[-1][:4] if row[-1][:4] in ("PASS", "FAIL") else ""]
                                           if with_results else [])
        rows.append(_row(row, classes=styles))
    return (f"<div class='thermal' data-triad='{escape(cal.name)}' data-reference-c='{model.reference_c!r}' "
            f"data-low-c='{low!r}' data-high-c='{high!r}' data-order='{model.order}'>"
            f"<p class='thermal'>Thermal model: reference {model.reference_c:.2f} °C, calibrated over "
            f"{low:.2f} to {high:.2f} °C; {order}, {scale}. Outside the range it is not applied "
            "(fieldcal apply refuses, or holds the edge when asked).</p>"
            f"<table class='thermal' data-triad='{escape(cal.name)}'>{''.join(rows)}</table>"
            f"{_figure(cal)}</div>")


def _figure(cal) -> str:
    from fieldcal.certificate.plots import thermal_svg
    from fieldcal.units import BIAS, operator_unit

    factor, unit = operator_unit(cal.kind, cal.output_unit, BIAS)
    low, high = cal.thermal.range_c
    temperature = np.linspace(low, high, 61)
    bias, sigma = bias_band(cal, temperature)
    return (f"<figure class='thermal' data-triad='{escape(cal.name)}' data-unit='{escape(unit)}'>"
            f"{thermal_svg(temperature, bias * factor, sigma * factor, unit, cal.thermal.reference_c)}"
            f"<figcaption>{escape(cal.name)}, bias against temperature over the calibrated range "
            f"({escape(unit)}), each axis with its ±1σ band (each term's σ taken as independent: the "
            "parameter file holds no covariance between them); dotted: the reference temperature"
            "</figcaption></figure>")
