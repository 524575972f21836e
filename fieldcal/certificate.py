"""A calibration certificate: one self-contained HTML page per session (no scripts, no links,
no external files), for the unit's file and the customer.

It states the unit, the station (latitude, height, gravity and where that came from), the
procedure and method, every parameter ± 1σ in operator units (with PASS/FAIL and the reason
when a product spec is given), each triad's residual, and the parameter file's SHA-256 with
whether it is the one the session recorded.
"""
from __future__ import annotations

import hashlib
from html import escape
from pathlib import Path

_STYLE = """body{font-family:sans-serif;max-width:60em;margin:2em auto;color:#111}
table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #999;padding:.25em .6em}
td.num{text-align:right;font-family:monospace}.PASS{color:#060}.FAIL{color:#a00;font-weight:bold}
code{word-break:break-all}"""


def _row(cells, header=False, classes=None) -> str:
    tag = "th" if header else "td"
    classes = classes or [""] * len(cells)
    return "<tr>" + "".join(f"<{tag}{f' class={c!r}' if c else ''}>{escape(str(x))}</{tag}>"
                            for x, c in zip(cells, classes)) + "</tr>"


def certificate_html(session: Path, params: Path, parameters, check: str, verdict=None,
                     stop_reason: str | None = None) -> str:
    """The page. ``check`` is what ``fieldcal.session.history.recorded_check`` says of ``params``;
    ``verdict`` an ``acceptance.Verdict`` or None."""
    from fieldcal.acceptance import operator_values
    from fieldcal.report import label
    from fieldcal.units import BIAS, operator_unit

    p = parameters.provenance
    sha = hashlib.sha256(params.read_bytes()).hexdigest()
    result = "" if verdict is None else ("PASS" if verdict.passed else "FAIL")
    checks = {} if verdict is None else {(c.triad, c.parameter): c for c in verdict.checks}
    facts = [("Unit", f"{p.device_name or 'unnamed device'}, serial {p.device_serial or 'not given'}"
              + (" (simulated)" if p.simulation else "")),
             ("Session", f"{session.name} ({stop_reason or 'state unknown'})"),
             ("Station", f"latitude {p.latitude_deg:.5f}°, height {p.height_m:g} m"),
             ("Local gravity", f"{p.gravity_m_s2:.6f} m/s² ({p.gravity_source})"),
             ("Procedure, method", f"{p.procedure}, {p.method}"),
             ("Software", f"fieldcal {p.software_version}"),
             ("Parameter file", f"{params.name}, SHA-256 {sha} ({check})")]
    if verdict is not None:
        facts.append(("Acceptance", f"{result} against {verdict.product}"))
    body = [f"<h1>Calibration certificate{f' — {result}' if result else ''}</h1>",
            "<table id='facts'>" + "".join(_row(f) for f in facts) + "</table>"]
    for cal in parameters.triads:
        values, sigmas, units = operator_values(cal)
        rows = [_row(["parameter", "value", "1σ", "unit"] + (["result"] if verdict else []), header=True)]
        for name, v, s, u in zip(cal.parameter_names, values, sigmas, units):
            c = checks.get((cal.name, name))
            verdict_cell = [] if verdict is None else \
                ["PASS" if c is None or c.passed else "FAIL: " + "; ".join(c.reasons)]
            rows.append(_row([label(name), f"{v:.7g}", f"{s:.3g}", u] + verdict_cell,
                             classes=["", "num", "num", ""] + [cell[:4] for cell in verdict_cell]))
        factor, unit = operator_unit(cal.kind, cal.residual_unit, BIAS)
        body += [f"<h2>{escape(cal.name)} ({escape(cal.kind.replace('_', ' '))}, output in "
                 f"{escape(cal.output_unit)})</h2>",
                 f"<table class='triad' data-triad='{escape(cal.name)}'>{''.join(rows)}</table>",
                 f"<p>residual RMS {cal.residual_rms * factor:.3g} {escape(unit)} ({escape(cal.method)})</p>"]
    return ("<!DOCTYPE html>\n<html lang='en'><head><meta charset='utf-8'>"
            f"<title>Calibration certificate {escape(p.device_serial or session.name)}</title>"
            f"<style>{_STYLE}</style></head><body>\n" + "\n".join(body) + "\n</body></html>\n")
