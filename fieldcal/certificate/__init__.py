"""A calibration certificate: one self-contained HTML page per session (no scripts, no links,
no external files: the plots are inline SVG or data: URIs), for the unit's file and the
customer; and its PDF where a headless Chromium is installed (``render``).

It states the unit, the station (latitude, height, gravity and where that came from, the
temperature the device reported), the procedure and method, every parameter ± 1σ in operator
units (with PASS/FAIL and the reason when a product spec is given), a triad's thermal model
(its range, terms ± 1σ and bias against temperature: ``thermal``), each triad's residual per
position as a plot, the Allan plots where ``fieldcal allan`` measured them in the session, and
the parameter file's SHA-256 with whether it is the one the session recorded.

``evidence`` reads the session, ``plots`` draws (matplotlib, imported only there).
"""
from __future__ import annotations

import hashlib
from html import escape
from pathlib import Path

_STYLE = """@page{size:A4;margin:14mm 14mm 16mm}
body{font-family:"DejaVu Sans",sans-serif;font-size:10pt;max-width:182mm;margin:1em auto;color:#111}
h1{font-size:17pt;margin:0 0 .4em}h2{font-size:12pt;margin:1.2em 0 .3em;break-after:avoid}
table{border-collapse:collapse;margin:.4em 0;width:100%}td,th{border:1px solid #999;padding:.15em .45em;
vertical-align:top}th{background:#eee;text-align:left}table#facts td:first-child{white-space:nowrap;width:9em}
td.num{text-align:right;font-family:"DejaVu Sans Mono",monospace;white-space:nowrap}
.PASS{color:#060}.FAIL{color:#a00;font-weight:bold}
.verdict{display:inline-block;border:2px solid;padding:.05em .5em;margin-left:.4em}
code{word-break:break-all;font-size:9pt}section.triad{break-inside:avoid}
figure{margin:.3em 0;break-inside:avoid}figure svg{display:block;max-width:100%;height:auto}
figcaption,.note{font-size:8.5pt;color:#333}.values span{white-space:nowrap}
img.allan{max-width:100%;max-height:120mm;display:block;margin:.3em auto}"""


def _row(cells, header=False, classes=None) -> str:
    tag = "th" if header else "td"
    classes = classes or [""] * len(cells)
    return "<tr>" + "".join(f"<{tag}{f' class={c!r}' if c else ''}>{escape(str(x))}</{tag}>"
                            for x, c in zip(cells, classes)) + "</tr>"


NOT_CHECKED = "– not in the spec"


def _result(check) -> str:
    """PASS, FAIL with the reasons, or (no check: a triad the spec does not name) not checked."""
    if check is None:
        return NOT_CHECKED
    if check.passed and not getattr(check, "calibrated", True):
        return NOT_CALIBRATED
    return "PASS" if check.passed else "FAIL: " + "; ".join(check.reasons)


NOT_CALIBRATED = "not calibrated (no limit)"  # a nominal value, never shown as a PASS


def _positions(evidence) -> str:
    from fieldcal.residuals import positions_phrase

    skipped = f"skipped: {positions_phrase(list(evidence.skipped))}" if evidence.skipped else "none skipped"
    return f"{evidence.completed} done, {skipped}"


def _temperature(evidence) -> str:
    t = evidence.temperature
    if t is None:
        return "not reported by the device"
    if t.high - t.low < 0.05:
        return f"{t.mean:.1f} °C reported by the device"
    return f"{t.low:.1f} to {t.high:.1f} °C (mean {t.mean:.1f} °C) reported by the device"


def _residual_figure(cal, res, limit, skipped) -> str:
    from fieldcal.certificate.plots import residual_scale, residual_svg
    from fieldcal.units import BIAS, operator_unit

    factor, unit = operator_unit(cal.kind, cal.residual_unit, BIAS)
    rms = cal.residual_rms * factor if unit == res.unit else None
    shown = "{:+.3g}" if res.signed else "{:.3g}"
    values = " · ".join(f"<span data-position='{escape(label)}' data-value='{v!r}'>"
                        f"{escape(label.removeprefix('pos '))}: {shown.format(v)}</span>"
                        for label, v in zip(res.labels, map(float, res.values)))
    what = "residual" if res.signed else "RMS of the residuals"
    top = residual_scale(res.values, rms)
    off = "" if limit is None or limit <= top else \
        f"; the spec's maximum RMS, {limit:g} {escape(res.unit)}, is above this scale"
    return (f"<figure class='residuals' data-triad='{escape(cal.name)}' data-unit='{escape(res.unit)}' "
            f"data-scale='{top!r}'>{residual_svg(res, rms, limit, skipped)}<figcaption>{escape(cal.name)}, "
            f"{what} per position ({escape(res.unit)}){off}: <span class='values'>{values}</span>"
            "</figcaption></figure>")


def _limits(limit, unit: str) -> str:
    """The tolerance a parameter was judged against, in its unit: "-50 to 50 mg; σ ≤ 1 mg; drift
    ≤ 5 mg"; "–" where the spec sets none."""
    if limit is None:
        return "–"
    u = "" if limit.unit == "1" else f" {limit.unit}"
    parts = []
    if limit.min is not None and limit.max is not None:
        parts.append(f"{limit.min:g} to {limit.max:g}{u}")
    elif limit.min is not None:
        parts.append(f"≥ {limit.min:g}{u}")
    elif limit.max is not None:
        parts.append(f"≤ {limit.max:g}{u}")
    if limit.max_sigma is not None:
        parts.append(f"σ ≤ {limit.max_sigma:g}{u}")
    if limit.max_drift is not None:
        parts.append(f"drift ≤ {limit.max_drift:g}{u}")
    return "; ".join(parts) or "–"


def _triad_section(cal, checks: dict, with_results: bool, evidence, spec) -> str:
    """One triad: its parameters ± 1σ (with the spec's limits and PASS/FAIL), its residual RMS
    (with its limit and verdict) and the plot of each position's residual."""
    from fieldcal.acceptance import operator_values
    from fieldcal.report import label
    from fieldcal.units import BIAS, operator_unit

    ts = next((t for t in spec.triads if t.name == cal.name), None) if spec is not None else None
    values, sigmas, units = operator_values(cal)
    rows = [_row(["parameter", "value", "±1σ", "unit"] + (["limits", "result"] if with_results else []),
                 header=True)]
    for name, v, s, u in zip(cal.parameter_names, values, sigmas, units):
        cell = [_result(checks.get((cal.name, name)))] if with_results else []
        styles = [c[:4] if c not in (NOT_CHECKED, NOT_CALIBRATED) else "" for c in cell]  # PASS or FAIL class
        limits = [_limits(ts.limit_for(name) if ts is not None else None, u)] if with_results else []
        shown = f"{s:.3g}" if name not in cal.not_calibrated else "not calibrated"  # nominal: no σ
        rows.append(_row([label(name), f"{v:.7g}", shown, u] + limits + cell,
                         classes=["", "num", "num", ""] + [""] * len(limits) + styles))
    factor, unit = operator_unit(cal.kind, cal.residual_unit, BIAS)
    residual_check = checks.get((cal.name, "residual"))
    residual_limit = "" if ts is None or ts.max_residual is None else \
        f" (limit {ts.max_residual[0]:g} {escape(ts.max_residual[1])})"
    verdict_text = "" if residual_check is None else \
        f"{residual_limit} <span class='{_result(residual_check)[:4]}'>{escape(_result(residual_check))}</span>"
    section = [f"<section class='triad'><h2>{escape(cal.name)} ({escape(cal.kind.replace('_', ' '))}, "
               f"output in {escape(cal.output_unit)})</h2>",
               f"<table class='triad' data-triad='{escape(cal.name)}'>{''.join(rows)}</table>",
               f"<p class='rms'>residual RMS {cal.residual_rms * factor:.3g} {escape(unit)} "
               f"({escape(cal.method)}){verdict_text}</p>"]
    from fieldcal.certificate.thermal import thermal_section

    section.append(thermal_section(cal, checks, with_results, ts))
    res = evidence.residuals.get(cal.name) if evidence is not None else None
    if res is not None:
        limit = ts.max_residual[0] if ts is not None and ts.max_residual is not None \
            and ts.max_residual[1] == res.unit else None
        section.append(_residual_figure(cal, res, limit, evidence.skipped))
    return "".join(section) + "</section>"


def _calibrated(params: Path) -> str:
    """When the session first calibrated (``history.calibrated_at``: a re-solve later does not
    move it), in UTC and in the station's local time."""
    import datetime

    from fieldcal.session.history import calibrated_at

    when = datetime.datetime.fromtimestamp(calibrated_at(params) / 1e9, datetime.timezone.utc)
    local = when.astimezone()
    zone = f"UTC{local.isoformat(timespec='seconds')[19:]}"  # "UTC+01:00"
    if local.tzname() and not local.tzname().startswith(("UTC", "+", "-")):
        zone = f"{local.tzname()}, {zone}"
    return f"{when:%Y-%m-%d %H:%M:%S} UTC; local time {local:%Y-%m-%d %H:%M:%S} ({zone})"


def certificate_html(session: Path, params: Path, parameters, check: str, verdict=None,
                     stop_reason: str | None = None, evidence=None, spec=None, previous=None) -> str:
    """The page. ``check`` is what ``fieldcal.session.history.recorded_check`` says of ``params``;
    ``verdict`` an ``acceptance.Verdict`` (of ``spec``, a ``ProductSpec``) or None; ``evidence``
    what ``evidence.gather`` read from the session (None: the parameter file alone); ``previous``
    the unit's previous calibration the drift was taken against (``PreviousCalibration``)."""
    from fieldcal.certificate.plots import png_data_uri

    p = parameters.provenance
    sha = hashlib.sha256(params.read_bytes()).hexdigest()
    result = "" if verdict is None else ("PASS" if verdict.passed else "FAIL")
    checks = {} if verdict is None else {(c.triad, c.parameter): c for c in verdict.checks}
    facts = [("Unit", f"{p.device_name or 'unnamed device'}, serial "
              f"{p.device_serial or 'not given (not compared with any other calibration)'}"
              + (" (simulated)" if p.simulation else "")),
             ("Calibrated", _calibrated(params)),
             ("Operator", p.operator or "not given"),
             ("Session", f"{session.name} ({stop_reason or 'state unknown'})"),
             ("Station", f"latitude {p.latitude_deg:.5f}°, height {p.height_m:g} m"),
             ("Local gravity", f"{p.gravity_m_s2:.6f} m/s² ({p.gravity_source})")]
    if evidence is not None:
        facts.append(("Temperature", _temperature(evidence)))
        if evidence.completed is not None:
            facts.append(("Positions", _positions(evidence)))
    facts += [("Procedure, method", f"{p.procedure}, {p.method}"),
              ("Software", f"fieldcal {p.software_version}"),
              ("Parameter file", f"{params.name}, SHA-256 {sha} ({check})")]
    if verdict is not None:
        facts.append(("Acceptance", f"{result} against {verdict.product}"))
        if previous is not None:
            facts.append(("Drift since", f"{previous.path} ({previous.check})"))
        facts += [("Note", n) for n in verdict.notes]
    if evidence is not None and evidence.residual_note:
        facts.append(("Residuals", evidence.residual_note))
    badge = f"<span class='verdict {result}'>{result}</span>" if result else ""
    head = f"<h1>Calibration certificate{badge}</h1>"
    body = [head, "<table id='facts'>" + "".join(_row(f) for f in facts) + "</table>"]
    missing = [c for c in (verdict.checks if verdict else ()) if c.parameter == "triad"]
    body += [f"<p class='FAIL'>{escape(c.triad)}: FAIL: {escape('; '.join(c.reasons))}</p>" for c in missing]
    body += [_triad_section(cal, checks, verdict is not None, evidence, spec) for cal in parameters.triads]
    if evidence is not None and evidence.allan:
        body.append("<section class='allan'><h2>Allan deviation (measured in this session with "
                    "fieldcal allan)</h2>")
        body += [f"<img class='allan' alt='{escape(path.stem)}' src='{png_data_uri(path)}'>"
                 for path in evidence.allan]
        body.append("</section>")
    return ("<!DOCTYPE html>\n<html lang='en'><head><meta charset='utf-8'>"
            f"<title>Calibration certificate {escape(p.device_serial or session.name)}</title>"
            f"<style>{_STYLE}</style></head><body>\n" + "\n".join(body) + "\n</body></html>\n")
