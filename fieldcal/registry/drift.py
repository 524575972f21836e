"""A unit's parameters over its calibrations: the drift between consecutive calibrations, in
operator units and in σ (both calibrations' 1σ combined), against the product spec's max_drift."""
from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class Drift:
    triad: str
    parameter: str
    index: int  # the later calibration's, from 0 (oldest)
    drift: float  # operator units
    unit: str
    in_sigma: float | None  # None when both σ are 0
    limit: float | None  # the spec's max_drift, same unit

    @property
    def exceeded(self) -> bool:
        return self.limit is not None and abs(self.drift) > self.limit


def drifts(calibrations: list[dict], spec=None) -> list[Drift]:
    """Every parameter's drift between consecutive calibrations (``Registry.history`` entries)."""
    limits = {t.name: t for t in spec.triads} if spec is not None else {}
    out = []
    for i in range(1, len(calibrations)):
        before, after = calibrations[i - 1]["parameters"], calibrations[i]["parameters"]
        for key, (value, sigma, unit) in after.items():
            if key not in before or before[key][2] != unit:
                continue
            v0, s0, _ = before[key]
            combined = math.hypot(sigma, s0)
            limit = limits[key[0]].limit_for(key[1]) if key[0] in limits else None
            max_drift = limit.max_drift if limit is not None and limit.unit == unit else None
            out.append(Drift(key[0], key[1], i, value - v0, unit,
                             (value - v0) / combined if combined > 0 else None, max_drift))
    return out


def history_lines(calibrations: list[dict], spec=None, one_unit: bool = True) -> list[str]:
    """``one_unit`` False: calibrations recorded without a serial, listed but not known to be of
    one unit, so no drift is taken between them."""
    from fieldcal.report import aligned, label

    verdicts = {None: "no spec applied", 1: "PASS", 0: "FAIL"}
    lines = [f"#{i + 1} {c['time']} {c['procedure']} {c['method']}"
             f"{' [' + c['source'] + ']' if c.get('source') else ''}"
             f"{' by ' + c['operator'] if c.get('operator') else ''} "
             f"({verdicts[c['passed']]}): {c['path']}" for i, c in enumerate(calibrations)]
    found = {(d.triad, d.parameter, d.index): d for d in drifts(calibrations, spec)} if one_unit else {}
    keys = list(calibrations[-1]["parameters"])
    header = ["triad", "parameter", "unit"] + [f"#{i + 1}" for i in range(len(calibrations))] + ["flag"]
    rows = [header]
    flagged = 0
    for triad, name in keys:
        unit = calibrations[-1]["parameters"][triad, name][2]
        cells, flags = [], []
        for i, c in enumerate(calibrations):
            if (triad, name) not in c["parameters"]:
                cells.append("")
                continue
            value, sigma, _ = c["parameters"][triad, name]
            d = found.get((triad, name, i))
            shift = f" ({d.in_sigma:+.1f}σ)" if d is not None and d.in_sigma is not None else ""
            cells.append(f"{value:.6g} ±{sigma:.2g}{shift}")
            if d is not None and d.exceeded:
                flags.append(f"#{i + 1} drifted {d.drift:+.3g} {unit} > {d.limit:g}")
        flagged += bool(flags)
        rows.append([triad, label(name), unit, *cells, "; ".join(flags)])
    lines.append(aligned(rows, "lll" + "r" * len(calibrations) + "l", indent=""))
    if not one_unit:
        lines.append("recorded without a serial: not known to be one unit, so no drift is taken between "
                     "them (give --unit-serial when calibrating)")
    elif spec is not None:
        lines.append(f"{flagged} parameter{'s' * (flagged != 1)} drifted beyond {spec.path}'s max_drift")
    return lines


def plot_history(calibrations: list[dict], serial: str, directory, overwrite: bool = True) -> list:
    """One PNG per triad: each parameter over the calibrations, ± 1σ bars; the paths written."""
    import io

    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from fieldcal.atomic import check_target, directory_for_files, write_atomically
    from fieldcal.report import label

    directory = directory_for_files(directory, "--plot")
    triads = dict.fromkeys(t for t, _ in calibrations[-1]["parameters"])
    for triad in triads:  # every plot refused (a link, an existing file) before any is drawn
        check_target(directory / f"{serial}-{triad}-history.png", force=overwrite, option="--plot")
    paths = []
    for triad in triads:
        names = [n for t, n in calibrations[-1]["parameters"] if t == triad]
        fig = Figure(figsize=(7, 1.6 * len(names)))
        FigureCanvasAgg(fig)
        axes = fig.subplots(len(names), 1, sharex=True, squeeze=False)
        for ax, name in zip(axes[:, 0], names):
            points = [(i, *c["parameters"][triad, name]) for i, c in enumerate(calibrations)
                      if (triad, name) in c["parameters"]]
            x, v, s, units = zip(*points)
            ax.errorbar(x, v, yerr=s, fmt="o-", capsize=3)
            ax.set_ylabel(f"{label(name)}\n[{units[-1]}]", fontsize=8)
        axes[-1, 0].set_xticks(range(len(calibrations)), [c["time"][:10] for c in calibrations],
                               rotation=30, fontsize=7)
        fig.suptitle(f"{serial}: {triad}, ± 1σ")
        fig.tight_layout()
        path = directory / f"{serial}-{triad}-history.png"
        png = io.BytesIO()  # then written by the one rule: never through a link planted at ``path``
        fig.savefig(png, format="png", dpi=80)
        write_atomically(path, png.getvalue(), overwrite=overwrite, hint="give --force to replace it")
        paths.append(path)
    return paths
