"""The thermal model where apply meets it (issue 28): each sample corrected at its own temperature.

A triad with a thermal model is corrected as ``Calibration.calibrate`` does it at temperature T,
K(T)⁻¹(raw − bias(T)) with K(T) = diag(1 + s₁ΔT)·K and bias(T) = b₀ + Σₖ bₖΔTᵏ: here the
temperature terms as one (n, columns) offset and one ratio per block, taken off the raw values
before the block's single K⁻¹ product (numpy throughout, no loop over samples).

What the user is told, and why:

- A sample outside a model's calibrated range is refused by default, in one line with the count,
  the temperatures and the range: a polynomial fitted over 20–30 °C says nothing at 40 °C (a
  cubic's terms grow as ΔT³), and a calibration engineer would rather hear it than get output
  that looks calibrated and is not. ``hold_edge`` (``--hold-temperature-edge``) corrects them at
  the nearest edge of the range instead, said in the same one line: the error is then the drift
  beyond the edge, bounded and chosen knowingly, never a silent extrapolation.
- A recording with no temperature (no column in its map, a log or device without one) is applied
  at the model's reference temperature, said in one line: that is exactly the static calibration
  (b₀, K) the thermal fit estimated beside its terms, the best the file has without a temperature;
  refusing would leave the user nothing better to apply.
- A triad without a thermal model (every parameter file from before issue 28) is untouched: its
  samples go through the very arithmetic they went through before, bit for bit.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


def thermal_names(calibrations) -> list[str]:
    """The triads among ``calibrations`` that have a thermal model."""
    return [c.name for c in calibrations if c.thermal is not None]


MAP_HINT = "name the temperature column in the map to correct each sample at its own"


def at_reference_line(calibrations, source: str, hint: str = "") -> str:
    """One line: ``source`` has no temperature, so each thermal model is applied at its reference
    (``hint``: what would give one)."""
    models = [(c.name, c.thermal) for c in calibrations if c.thermal is not None]
    told = "; ".join(f"{name} at {m.reference_c:.2f} °C (calibrated over {m.range_c[0]:.2f} to {m.range_c[1]:.2f} °C)"
                     for name, m in models)
    return (f"apply: {source}: no temperature read, so the thermal model is applied at its reference "
            f"temperature: {told}" + (f"; {hint}" if hint else ""))


class TemperatureOutside(ValueError):
    """Samples outside a thermal model's calibrated range, refused (one line). ``written``: the
    samples a device's stream wrote before them."""

    written = 0


@dataclass
class OutsideCount:
    """Samples found outside each triad's calibrated range so far (name: count, min, max °C), of
    ``samples`` seen."""

    counts: dict = field(default_factory=dict)
    samples: int = 0

    def add(self, name: str, temperature_c: np.ndarray, outside: np.ndarray) -> None:
        if not outside.any():
            return
        t = temperature_c[outside]
        n, low, high = self.counts.get(name, (0, np.inf, -np.inf))
        self.counts[name] = (n + int(np.count_nonzero(outside)), min(low, float(t.min())), max(high, float(t.max())))

    def line(self, source: str, calibrations, held: bool) -> str | None:
        """One line for every triad with samples outside its range, or None if none was."""
        if not self.counts:
            return None
        ranges = {c.name: c.thermal.range_c for c in calibrations if c.thermal is not None}
        parts = "; ".join(f"{n} of {self.samples} samples at {low:.2f} to {high:.2f} °C are outside {name}'s "
                          f"calibrated range {ranges[name][0]:.2f} to {ranges[name][1]:.2f} °C"
                          for name, (n, low, high) in self.counts.items())
        if held:
            return f"apply: {source}: {parts}: corrected at the nearest edge of the range (--hold-temperature-edge)"
        return (f"apply: {source}: {parts}: refused, the thermal model does not extrapolate; give "
                "--hold-temperature-edge to correct them at the nearest edge of the range")


def offsets_and_ratios(calibrations, rows: dict[str, list[int]], width: int, temperature_c: np.ndarray | None,
                       hold_edge: bool, outside: OutsideCount, source: str) -> tuple[np.ndarray, np.ndarray] | None:
    """The temperature terms of a block's raw values: (offset, ratio), each (n, ``width``), so
    that (raw − bias − offset) / ratio is K⁻¹'s input; zero and one in the columns of triads with
    no model. ``rows``: each triad's x, y, z columns among the ``width``. ``temperature_c``
    (n,) or None (no temperature: each model at its reference). None when no triad has a
    model. Samples outside a range are counted into ``outside`` and, with ``hold_edge``,
    corrected at its nearest edge."""
    models = [(c.name, c.thermal) for c in calibrations if c.thermal is not None]
    if not models:
        return None
    if temperature_c is not None and np.isnan(temperature_c).any():
        raise TemperatureOutside(f"apply: {source}: {np.count_nonzero(np.isnan(temperature_c))} samples have no "
                                 "temperature (NaN): the thermal model cannot correct them")
    n = 1 if temperature_c is None else len(temperature_c)
    offset, ratio = np.zeros((n, width)), np.ones((n, width))
    for name, model in models:
        t = np.array([model.reference_c]) if temperature_c is None else temperature_c
        if temperature_c is not None:
            out = model.outside(t)
            outside.add(name, t, out)
            if hold_edge and out.any():
                t = np.clip(t, *model.range_c)
        offset[:, rows[name]] = model.bias_offset(t)
        ratio[:, rows[name]] = model.scale_ratio(t)
    return offset, ratio


def temperatures_for(calibrations, temperature_c: np.ndarray | None, hold_edge: bool, source: str,
                     outside: OutsideCount | None = None) -> tuple[dict, str | None]:
    """Each thermal triad's temperatures to correct a whole recording (or a device's read) at
    (name: (n,) °C, or its reference where the samples have none; held at the range's edges
    with ``hold_edge``), and the line to say: (temperatures, line or None). TemperatureOutside,
    before anything is written, for samples outside a range without ``hold_edge``. ``outside``:
    a count to add to (a device's reads), else a new one."""
    outside = OutsideCount() if outside is None else outside
    outside.samples += 0 if temperature_c is None else len(temperature_c)
    used = {}
    for cal in calibrations:
        model = cal.thermal
        if model is None:
            continue
        if temperature_c is None:
            used[cal.name] = model.reference_c
            continue
        t = np.asarray(temperature_c, dtype=float)
        if np.isnan(t).any():
            raise TemperatureOutside(f"apply: {source}: {np.count_nonzero(np.isnan(t))} samples have no "
                                     "temperature (NaN): the thermal model cannot correct them")
        outside.add(cal.name, t, model.outside(t))
        used[cal.name] = np.clip(t, *model.range_c) if hold_edge else t
    if outside.counts and not hold_edge:
        raise TemperatureOutside(outside.line(source, calibrations, held=False))
    if temperature_c is None and used:
        return used, at_reference_line(calibrations, source)
    return used, outside.line(source, calibrations, held=True)
