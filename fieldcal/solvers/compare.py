"""``fieldcal solve``: re-solve a session from its stored averages, methods side by side.

The layout follows paper Table 5: per triad and axis, bias and scale factor for each method.
"""
from __future__ import annotations

from pathlib import Path

from fieldcal.procedure.engine import windows_and_averages
from fieldcal.run.runner import RunSpec
from fieldcal.run.steps import completed_records
from fieldcal.session.capture import SessionReader
from fieldcal.solvers.solve import models_from_truth, solve_unit
from fieldcal.units import display_scale, param_unit


def compare_methods(directory: Path, methods: list[str]) -> str:
    reader = SessionReader(directory)
    spec = RunSpec.from_metadata(reader.start)
    records = completed_records(reader)
    windows, averages = windows_and_averages(records)
    if not windows:
        return f"{directory}: no completed steps to solve from"
    models = models_from_truth(spec.device())
    results = {m: solve_unit(spec.procedure, windows, averages, models, spec.station, spec.rate_hz, m)
               for m in methods}
    width = 30
    lines = [f"{spec.procedure.name}: {len(records)} completed steps, re-solved from their averages",
             f"{'':20}" + "".join(f"{m:^{width}}" for m in methods),
             f"{'triad, axis':20}" + "".join(f"{'bias':>14}{'scale factor':>16}" for _ in methods)]
    for name, model in models.items():
        for axis, label in enumerate("xyz"):
            row = f"{name:13} {label:6}"
            for m in methods:
                sol = results[m].solutions.get(name)
                if sol is None:
                    row += f"{'—':>14}{'—':>16}"
                    continue
                scale = display_scale(model.kind, model.output_unit, axis)
                unit = param_unit(model.kind, model.output_unit, axis)
                row += f"{sol.theta[axis] * scale:>10.4f} {unit:<3}{sol.theta[3 + axis]:>16.7f}"
            lines.append(row)
    for m in methods:
        for name, why in results[m].failures.items():
            lines.append(f"{m}: {name}: {why}")
    return "\n".join(lines)
