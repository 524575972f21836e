"""The certificate's figures, made with matplotlib (imported here only, when a certificate is
written): each triad's residual per position as an inline SVG, and PNGs as data: URIs, so the
page needs no other file."""
from __future__ import annotations

import base64
import io
import re
from pathlib import Path

import numpy as np

WIDTH_IN, HEIGHT_IN = 7.0, 1.8  # an A4 page's text width; two triads' tables and plots a page


HEADROOM = 1.25  # the plot's scale over the largest residual (or the RMS line)


def residual_scale(values, rms: float | None = None) -> float:
    """The top of a residual plot's y axis (and, signed, minus its bottom): the residuals' own
    size, never a spec limit's; a 1 mg limit would flatten 0.03 mg residuals to a line."""
    top = max(float(np.max(np.abs(values))) if len(values) else 0.0, rms or 0.0) * HEADROOM
    return top if top > 0 else 1.0


def residual_svg(res, rms: float | None = None, limit: float | None = None, skipped=()) -> str:
    """``res`` (an ``evidence.PositionResiduals``) as bars, one per position, with the ``skipped``
    position ids in their place marked "skipped"; dashed lines at the triad's RMS residual and,
    when a product spec gives one, dotted at its maximum RMS residual. The scale is the
    residuals' (``residual_scale``): a limit above it is marked by an arrow at the top edge
    with its value."""
    import matplotlib
    from matplotlib.backends.backend_svg import FigureCanvasSVG
    from matplotlib.figure import Figure

    with matplotlib.rc_context({"svg.fonttype": "none", "svg.hashsalt": "fieldcal-certificate",
                                "font.size": 8, "axes.titlesize": 8}):
        fig = Figure(figsize=(WIDTH_IN, HEIGHT_IN))
        FigureCanvasSVG(fig)
        ax = fig.add_subplot()
        names = [label.removeprefix("pos ") for label in res.labels]
        if skipped and all(n.isdigit() for n in names):  # positions in procedure order, gaps kept
            names = sorted({*names, *map(str, skipped)}, key=int)
        x = np.arange(len(names))
        at = {n: i for i, n in enumerate(names)}
        ax.bar([at[n.removeprefix("pos ")] for n in res.labels], res.values, color="#4a6fa5", width=0.7)
        for n in map(str, skipped):
            if n in at:
                ax.text(at[n], 0.02, "skipped", rotation=90, ha="center", va="bottom", fontsize=7,
                        color="#666", transform=ax.get_xaxis_transform())
        ax.set_xticks(x, names)
        ax.set_xlim(-0.6, len(x) - 0.4)
        if res.signed:
            ax.axhline(0.0, color="black", lw=0.6)
        top = residual_scale(res.values, rms)
        ax.set_ylim(-top if res.signed else 0.0, top)
        for value, style, text in ((rms, "--", "RMS"), (limit, ":", "spec maximum RMS")):
            if value is None:
                continue
            color = "#444" if style == "--" else "#a00"
            if value <= top:
                for v in ((value, -value) if res.signed else (value,)):
                    ax.axhline(v, color=color, ls=style, lw=0.9)
                label = f"{text} {value:.3g} {res.unit}"
            else:  # off the scale: an arrow up at the right edge says where it is
                ax.annotate("", xy=(0.995, 1.0), xytext=(0.995, 0.8), xycoords="axes fraction",
                            arrowprops={"arrowstyle": "->", "color": color, "lw": 0.9})
                label = f"{text} {value:.3g} {res.unit} (↑ {value / top * HEADROOM:.0f}× the largest, off the scale)"
            ax.plot([], [], color=color, ls=style, lw=0.9, label=label)
        if rms is not None or limit is not None:
            # above the axes, right: inside, it would hide the bars it explains
            ax.legend(loc="lower right", bbox_to_anchor=(1.0, 1.0), ncol=2, fontsize=7, frameon=False,
                      borderaxespad=0.1)
        ax.set_xlabel("position" if res.labels and res.labels[0].startswith("pos") else "average")
        ax.set_ylabel(f"{'residual' if res.signed else 'RMS residual'} ({res.unit})")
        ax.grid(True, axis="y", alpha=0.3)
        fig.tight_layout(pad=0.3)
        out = io.StringIO()
        fig.savefig(out, format="svg", metadata={"Date": None, "Creator": "fieldcal"})
    return _inline(out.getvalue())


def thermal_svg(temperature_c: np.ndarray, bias: np.ndarray, sigma: np.ndarray, unit: str,
                reference_c: float) -> str:
    """A triad's bias against temperature, one panel per axis (their biases differ by more than
    their drifts): the line and its ±1σ band over the calibrated range, the reference dotted."""
    import matplotlib
    from matplotlib.backends.backend_svg import FigureCanvasSVG
    from matplotlib.figure import Figure

    with matplotlib.rc_context({"svg.fonttype": "none", "svg.hashsalt": "fieldcal-certificate",
                                "font.size": 8, "axes.titlesize": 8}):
        fig = Figure(figsize=(WIDTH_IN, HEIGHT_IN))
        FigureCanvasSVG(fig)
        for i, axis in enumerate("xyz"):
            ax = fig.add_subplot(1, 3, i + 1)
            ax.fill_between(temperature_c, bias[:, i] - sigma[:, i], bias[:, i] + sigma[:, i], color="#4a6fa5",
                            alpha=0.25, lw=0, label="±1σ")
            ax.plot(temperature_c, bias[:, i], color="#4a6fa5", lw=1.2, label="bias")
            ax.axvline(reference_c, color="#444", ls=":", lw=0.9)
            ax.set_title(f"bias {axis}")
            ax.set_xlabel("temperature (°C)")
            if i == 0:
                ax.set_ylabel(unit)
            ax.set_xlim(temperature_c[0], temperature_c[-1])
            ax.grid(True, alpha=0.3)
        fig.tight_layout(pad=0.3)
        out = io.StringIO()
        fig.savefig(out, format="svg", metadata={"Date": None, "Creator": "fieldcal"})
    return _inline(out.getvalue())


def _inline(text: str) -> str:
    """An SVG file's text as an element of the page: no XML prolog nor DOCTYPE, and a width
    that scales with the page (the viewBox stays, the fixed size in pt goes)."""
    svg = text[text.index("<svg"):]
    return re.sub(r'<svg([^>]*?) width="[^"]*" height="[^"]*"', r'<svg\1 width="100%"', svg, count=1)


def png_data_uri(path: Path) -> str:
    return "data:image/png;base64," + base64.b64encode(Path(path).read_bytes()).decode("ascii")
