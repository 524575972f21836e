"""A triad held still in one pose while its temperature sweeps (PX4's thermal calibration: a
cold-soaked board warming on the bench), as a problem the joint thermal fit takes.

One pose shows only how the reading moves with temperature: u_i = c + Σₖ bₖ ΔT_iᵏ + noise, with
c the reading at T_ref (bias plus the unknown projection of gravity or the Earth rate). Its
scale factors and angles are not observable, so the problem pins them at their nominal values
by two pseudo-averages (k = 1, angles 0) that the thermal fit leaves at their reference
temperature; what remains is exactly the per-axis polynomial fit, and
``fieldcal.solvers.thermal.solve_thermal_norm`` (called with ``scale=False``: a scale drift is
a bias drift on the axis gravity is on, not separable here) chooses its order and gives its σ as
it does for every other thermal fit. The pins add six residuals and six unknowns, so χ² and its
degrees of freedom are those of the polynomial fit alone.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fieldcal.model import N_PARAMS

# theta[3:9] pinned: scale factors k = 1 and angles 0 (a triad in physical units)
PINNED = np.array([1.0, 1.0, 1.0, 0.0, 0.0, 0.0])


@dataclass(frozen=True)
class HeldPoseProblem:
    """``averages`` (n, 3): the triad's window means in ``output_unit``, in time order."""

    averages: np.ndarray
    name: str
    kind: str
    output_unit: str

    def __post_init__(self) -> None:
        averages = np.array(self.averages, dtype=float)
        if averages.ndim != 2 or averages.shape[1] != 3 or len(averages) < 2 or not np.all(np.isfinite(averages)):
            raise ValueError(f"{self.name}: expected (n, 3) finite averages, n >= 2, got shape {averages.shape}")
        averages.setflags(write=False)
        object.__setattr__(self, "averages", averages)

    @property
    def data(self) -> np.ndarray:
        """The averages, then the two pins, flattened (the pins as two more 3-vectors)."""
        return np.r_[self.averages.ravel(), PINNED]

    @property
    def pin_count(self) -> int:
        """How many of ``data``'s 3-vectors are pins (after the averages)."""
        return len(PINNED) // 3

    @property
    def residual_labels(self) -> tuple[str, ...]:
        held = tuple(f"window {i + 1} {a}" for i in range(len(self.averages)) for a in "xyz")
        return held + tuple(f"pinned {n}" for n in ("k_x", "k_y", "k_z", "delta_yz", "delta_zy", "delta_zx"))

    @property
    def reference_scale(self) -> float:
        """The reading's size: the unit the bias steps of the fit are measured in."""
        return max(float(np.linalg.norm(self.averages.mean(axis=0))), float(np.ptp(self.averages)), 1e-9)

    def residuals(self, theta, u: np.ndarray) -> np.ndarray:
        """u − c per window and axis, then the pins less θ[3:9]; u (..., 3n + 6) broadcasts."""
        u = np.asarray(u, dtype=float)
        theta = np.asarray(theta, dtype=float)
        n = 3 * len(self.averages)
        held = (u[..., :n].reshape(*u.shape[:-1], -1, 3) - theta[..., None, :3]).reshape(*u.shape[:-1], n)
        return np.concatenate([held, u[..., n:] - theta[..., 3:N_PARAMS]], axis=-1)

    def initial(self) -> np.ndarray:
        return np.r_[self.averages.mean(axis=0), PINNED]
