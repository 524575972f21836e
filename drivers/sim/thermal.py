"""The simulated unit's temperature and what it does to each triad (issue 28).

A ``TemperatureProfile`` gives the unit's temperature (°C) at each sample time: constant, an
exponential warm-up after switch-on, or a chamber's linear ramp after a soak. A triad's
``ThermalTruth`` is the same model fieldcal fits (``fieldcal.thermal``), with the truth's K and
bias holding at ``reference_c``:

    raw = diag(1 + s₁ΔT)·K·(true + noise) + bias + Σₖ bₖ ΔTᵏ,   ΔT = T − reference_c

Temperature is a function of sample time only, so a resumed run continues it exactly.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

PROFILES = ("constant", "warmup", "ramp")
MAX_ORDER = 3


@dataclass(frozen=True)
class TemperatureProfile:
    """``constant``: ``start_c`` throughout. ``warmup``: start_c + rise_k·(1 − exp(−t/τ)), τ =
    ``time_constant_s`` (a unit heating itself after switch-on). ``ramp``: ``start_c`` for
    ``soak_s``, then ``rate_k_per_s`` until it has risen (or fallen) by ``rise_k``, then held (a
    chamber)."""

    kind: str
    start_c: float
    rise_k: float = 0.0
    time_constant_s: float = 0.0
    rate_k_per_s: float = 0.0
    soak_s: float = 0.0

    def __post_init__(self) -> None:
        if self.kind not in PROFILES:
            raise ValueError(f"temperature profile: expected one of {', '.join(PROFILES)}, got {self.kind!r}")
        for name in ("start_c", "rise_k", "time_constant_s", "rate_k_per_s", "soak_s"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"temperature profile {name}: expected a finite number, got {getattr(self, name)!r}")
        if self.kind == "warmup" and not self.time_constant_s > 0:
            raise ValueError(f"warm-up time_constant_s: expected a number > 0, got {self.time_constant_s!r}")
        if self.kind == "ramp" and not self.rate_k_per_s > 0:
            raise ValueError(f"ramp rate_k_per_s: expected a number > 0, got {self.rate_k_per_s!r}")
        if self.soak_s < 0:
            raise ValueError(f"ramp soak_s: expected a number >= 0, got {self.soak_s!r}")

    def at(self, t) -> np.ndarray:
        """The temperature (°C) at sample times ``t`` (s since the unit started)."""
        t = np.asarray(t, dtype=float)
        if self.kind == "warmup":
            return self.start_c + self.rise_k * -np.expm1(-np.maximum(t, 0.0) / self.time_constant_s)
        if self.kind == "ramp":
            moved = np.clip((t - self.soak_s) * self.rate_k_per_s, 0.0, abs(self.rise_k))
            return self.start_c + math.copysign(1.0, self.rise_k) * moved
        return np.full(t.shape, float(self.start_c))

    def to_dict(self) -> dict:
        return {"kind": self.kind, "start_c": self.start_c, "rise_k": self.rise_k,
                "time_constant_s": self.time_constant_s, "rate_k_per_s": self.rate_k_per_s, "soak_s": self.soak_s}


def _powers(dt: np.ndarray, order: int) -> np.ndarray:
    """ΔT, ΔT², … ΔTᵒʳᵈᵉʳ as columns (n, order), by repeated products: a sixth of the CPU of
    ``dt[:, None] ** k`` (a pow per element, the simulator's per-chunk cost) and ΔT² rounded once."""
    powers = np.empty((len(dt), order))
    if order:
        powers[:, 0] = dt
    for k in range(1, order):
        powers[:, k] = powers[:, k - 1] * dt
    return powers


@dataclass(frozen=True)
class ThermalTruth:
    """One triad's true thermal terms: ``bias_terms[k-1]`` = bₖ per axis (output units per Kᵏ),
    ``scale_drift`` = s₁ per axis (1/K), both about ``reference_c``."""

    reference_c: float
    bias_terms: np.ndarray  # (order, 3)
    scale_drift: np.ndarray  # (3,)

    def __post_init__(self) -> None:
        terms = np.array(self.bias_terms, dtype=float).reshape(-1, 3) if np.size(self.bias_terms) else np.zeros((0, 3))
        if len(terms) > MAX_ORDER or not np.all(np.isfinite(terms)):
            raise ValueError(f"thermal bias terms: expected up to {MAX_ORDER} rows of 3 finite numbers")
        drift = np.array(self.scale_drift, dtype=float)
        if drift.shape != (3,) or not np.all(np.isfinite(drift)):
            raise ValueError("thermal scale drift: expected 3 finite numbers (1/K)")
        if not math.isfinite(self.reference_c):
            raise ValueError(f"thermal reference_c: expected a finite number, got {self.reference_c!r}")
        object.__setattr__(self, "bias_terms", terms)
        object.__setattr__(self, "scale_drift", drift)

    def offset_and_ratio(self, temperature_c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(Σₖ bₖ ΔTᵏ, 1 + s₁ΔT), each (n, 3)."""
        dt = np.asarray(temperature_c, dtype=float) - self.reference_c
        return _powers(dt, len(self.bias_terms)) @ self.bias_terms, 1.0 + dt[:, None] * self.scale_drift

    def to_dict(self) -> dict:
        return {"reference_c": self.reference_c, "bias_terms": self.bias_terms.tolist(),
                "scale_drift": self.scale_drift.tolist()}


@dataclass(frozen=True)
class SimThermal:
    """The simulated unit's temperature profile and the triads it moves (others hold still)."""

    profile: TemperatureProfile
    triads: dict  # triad name -> ThermalTruth

    def to_dict(self) -> dict:
        return {"profile": self.profile.to_dict(), "triads": {n: t.to_dict() for n, t in self.triads.items()}}

    @classmethod
    def from_dict(cls, d: dict) -> SimThermal:
        return cls(TemperatureProfile(**d["profile"]),
                   {n: ThermalTruth(t["reference_c"], np.array(t["bias_terms"]).reshape(-1, 3), t["scale_drift"])
                    for n, t in d["triads"].items()})
