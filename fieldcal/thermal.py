"""A triad's thermal error model (issue 28): how its bias and scale factors move with temperature.

    bias(T)  = b₀ + Σₖ bₖ·(T − T_ref)ᵏ,  k = 1 … order (order 0–3)
    K(T)     = diag(1 + s₁·(T − T_ref)) · K        (optional; s₁ in 1/K)

b₀ and K are the triad's calibration at T_ref (``fieldcal.calibration``); this model holds only
the temperature terms, their 1σ, T_ref and the range of temperatures the model was calibrated
over. Scaling K's rows keeps the named misalignment angles (ratios within a row) fixed, so
scale(T) = (1 + S)(1 + s₁ΔT) ≈ 1 + S + s₁ΔT, the issue's form, to first order in S·s₁ΔT.

Temperatures are in °C as devices report them (``SampleChunk.temperature``); differences, and
so every coefficient, are per kelvin. A polynomial says nothing outside the temperatures it was
fitted on: ``outside`` marks such samples and ``check_range`` refuses them in one line.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

MAX_ORDER = 3
# Below absolute zero, or hotter than any MEMS part survives: a typo, not a temperature.
TEMPERATURE_LIMITS_C = (-273.15, 200.0)


class TemperatureOutOfRange(ValueError):
    """A temperature outside the range a thermal model was calibrated over."""


def _array(values, shape: tuple[int, ...], what: str) -> np.ndarray:
    arr = np.array(values, dtype=np.float64)
    if arr.shape != shape:
        raise ValueError(f"{what}: expected shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{what}: expected finite numbers, got {arr.tolist()}")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class ThermalModel:
    """The temperature terms of one triad's calibration (see the module docstring).

    ``bias_terms[k-1]`` is bₖ per axis (output units per Kᵏ), shape (order, 3); ``scale_drift``
    is s₁ per axis (1/K) or None when the model has no scale term."""

    reference_c: float
    range_c: tuple[float, float]
    bias_terms: np.ndarray
    bias_terms_sigma: np.ndarray
    scale_drift: np.ndarray | None = None
    scale_drift_sigma: np.ndarray | None = None

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        low_limit, high_limit = TEMPERATURE_LIMITS_C
        ref = self.reference_c
        if isinstance(ref, bool) or not isinstance(ref, (int, float, np.floating, np.integer)) \
                or not low_limit < float(ref) < high_limit:
            raise ValueError(f"thermal.reference_c: expected a temperature in °C, got {ref!r}")
        set_(self, "reference_c", float(ref))
        try:
            low, high = (float(x) for x in self.range_c)
        except (TypeError, ValueError):
            raise ValueError(f"thermal.range_c: expected (low, high) in °C, got {self.range_c!r}") from None
        if not (low_limit < low <= high < high_limit):
            raise ValueError(f"thermal.range_c: expected low <= high within {low_limit:g}..{high_limit:g} °C, "
                             f"got {self.range_c!r}")
        set_(self, "range_c", (low, high))
        terms = np.array(self.bias_terms, dtype=np.float64).reshape(-1, 3) if np.size(self.bias_terms) \
            else np.zeros((0, 3))
        if len(terms) > MAX_ORDER:
            raise ValueError(f"thermal.bias_terms: expected order 0 to {MAX_ORDER}, got {len(terms)}")
        set_(self, "bias_terms", _array(terms, terms.shape, "thermal.bias_terms"))
        sigma = np.array(self.bias_terms_sigma, dtype=np.float64).reshape(-1, 3) if np.size(self.bias_terms_sigma) \
            else np.zeros((0, 3))
        set_(self, "bias_terms_sigma", _array(sigma, terms.shape, "thermal.bias_terms_sigma"))
        if np.any(self.bias_terms_sigma < 0):
            raise ValueError("thermal.bias_terms_sigma: expected values >= 0")
        if (self.scale_drift is None) != (self.scale_drift_sigma is None):
            raise ValueError("thermal: give the scale drift and its sigma, or neither")
        if self.scale_drift is not None:
            set_(self, "scale_drift", _array(self.scale_drift, (3,), "thermal.scale_drift"))
            set_(self, "scale_drift_sigma", _array(self.scale_drift_sigma, (3,), "thermal.scale_drift_sigma"))
            if np.any(self.scale_drift_sigma < 0):
                raise ValueError("thermal.scale_drift_sigma: expected values >= 0")

    @property
    def order(self) -> int:
        """The bias polynomial's order (0: the bias does not move with temperature)."""
        return len(self.bias_terms)

    def outside(self, temperature_c) -> np.ndarray:
        """True where a temperature is outside the calibrated range (NaN counts as outside)."""
        t = np.asarray(temperature_c, dtype=float)
        low, high = self.range_c
        return ~((t >= low) & (t <= high))

    def check_range(self, temperature_c, who: str) -> None:
        """Refuse, in one line, temperatures the model was not calibrated over."""
        out = self.outside(temperature_c)
        if np.any(out):
            t = np.asarray(temperature_c, dtype=float)[out]
            worst = "NaN" if np.isnan(t).any() else f"{t.min():.2f} to {t.max():.2f} °C"
            low, high = self.range_c
            raise TemperatureOutOfRange(
                f"{who}: {np.count_nonzero(out)} of {out.size} samples at {worst}, outside the thermal "
                f"model's calibrated range {low:.2f} to {high:.2f} °C (it does not extrapolate)")

    def bias_offset(self, temperature_c) -> np.ndarray:
        """Σₖ bₖ ΔTᵏ, shape (n, 3) for n temperatures (output units)."""
        dt = np.atleast_1d(np.asarray(temperature_c, dtype=float)) - self.reference_c
        powers = dt[:, None] ** np.arange(1, self.order + 1)
        return powers @ self.bias_terms

    def scale_ratio(self, temperature_c) -> np.ndarray:
        """1 + s₁ΔT, shape (n, 3): each row of K is multiplied by it (ones without a scale term)."""
        dt = np.atleast_1d(np.asarray(temperature_c, dtype=float)) - self.reference_c
        if self.scale_drift is None:
            return np.ones((len(dt), 3))
        return 1.0 + dt[:, None] * self.scale_drift

    def key(self) -> tuple:
        """Exact identity (bit for bit), for equality of calibrations."""
        drift = b"" if self.scale_drift is None else self.scale_drift.tobytes() + self.scale_drift_sigma.tobytes()
        return (np.float64(self.reference_c).tobytes(), np.array(self.range_c).tobytes(),
                self.bias_terms.tobytes(), self.bias_terms_sigma.tobytes(), drift)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, ThermalModel):
            return NotImplemented
        return self.key() == other.key()

    def __hash__(self) -> int:
        return hash(self.key())



def truth_about(theta, reference_c: float, bias_terms, scale_drift, new_reference_c: float):
    """A thermal truth given about ``reference_c`` (the nine PARAM_NAMES values there, the bias
    terms bₖ and the scale drift s₁) re-centred on ``new_reference_c``, where a fit states its
    own: (the nine values, the bias terms). With d the shift, b₀' = Σⱼ bⱼ dʲ (b₀ included),
    bₖ' = Σⱼ≥ₖ C(j, k) bⱼ dʲ⁻ᵏ, and each scale factor times 1 + s₁d; the angles do not move."""
    terms = np.asarray(bias_terms, dtype=float).reshape(-1, 3)
    coefficients = np.vstack([np.asarray(theta, dtype=float)[:3], terms])  # b₀ … b_order
    d = new_reference_c - reference_c
    j = np.arange(len(coefficients))
    # shift[k, j] = C(j, k) d^(j−k) for j ≥ k
    binomial = np.array([[math.comb(int(b), int(a)) if b >= a else 0 for b in j] for a in j], dtype=float)
    shift = binomial * np.where(j[None, :] >= j[:, None], d ** np.maximum(j[None, :] - j[:, None], 0), 0.0)
    moved = shift @ coefficients
    out = np.array(theta, dtype=float)
    out[:3] = moved[0]
    out[3:6] = out[3:6] * (1.0 + np.asarray(scale_drift, dtype=float) * d)
    return out, moved[1:]
