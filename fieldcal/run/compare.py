"""``fieldcal solve``: re-solve a session from the step averages in its log, methods side by side.

Only ``log.jsonl`` is read: the averages are there, so a session whose samples.bin is missing
(or was never copied) can still be solved. Every parameter is shown ± 1σ in operator units, one
column pair per method (paper Table 5 extended to the misalignments).
"""
from __future__ import annotations

from fieldcal.procedure.engine import windows_and_averages
from fieldcal.report import methods_table, solution_header
from fieldcal.session import LOG
from fieldcal.solvers.solve import solve_unit


def compare_methods(record, methods: list[str], thermal: str | None = None) -> str:
    """``record``: a procedure run's ``RunRecord`` (its spec rebuilt); ``thermal``: another
    thermal setting than the session's."""
    spec = record.spec
    thermal = spec.thermal if thermal is None else thermal
    records = record.completed  # the last record of each step (a resumed run redoes one)
    windows, averages = windows_and_averages(records)
    if not windows:
        return f"{record.directory}: no completed steps to solve from"
    models = spec.models()  # the live device's noise models, or the simulator's
    results = {m: solve_unit(spec.procedure, windows, averages, models, spec.station, spec.rate_hz, m, thermal)
               for m in methods}
    lines = [f"{spec.procedure.name}: {len(records)} completed steps, re-solved from their averages "
             f"in {LOG}"]
    lines += sorted({r.thermal_note for r in results.values() if r.thermal_note})
    for name in models:
        solved = {m: results[m].solutions.get(name) for m in methods}
        lines += [""] + [solution_header(cal) for cal in solved.values() if cal is not None]
        lines.append(methods_table(solved))
        lines += [f"  {m}: not calibrated: {results[m].failures[name]}" for m in methods
                  if name in results[m].failures]
    return "\n".join(lines)
