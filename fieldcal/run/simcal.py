"""A whole calibration against the simulated device: plan, simulate, average, solve, compare.

Used by ``fieldcal demo``, the accuracy benchmark and the tests. The solver is given the exact
covariance of the averages (the simulator's noise model over the procedure's timeline), which is
what a station computes from a device's Allan noise terms.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from drivers.sim import TriadTruth
from drivers.sim.device import paper_mimu
from fieldcal.solvers.crb import ThermalTerms, angular_rate_bound, specific_force_bound
from fieldcal.earth import EARTH_RATE, Station
from fieldcal.model import SPECIFIC_FORCE, params_from_k
from fieldcal.procedure.positions import Procedure, load_procedure
from fieldcal.run.simrun import Plan, plan_procedure, simulate_averages
from fieldcal.solvers.solve import models_from_truth, solve_unit

DEFAULT_STATION = Station(latitude_deg=40.0, height_m=50.0)


@dataclass(frozen=True)
class SimulatedCalibration:
    procedure: Procedure
    station: Station
    plan: Plan
    device: dict[str, TriadTruth]
    solutions: dict[str, object]  # triad -> Calibration
    truth: dict[str, np.ndarray]  # true parameters, PARAM_NAMES order
    problems: dict[str, object]
    covariances: dict[str, np.ndarray]  # of each problem's data
    static_table_angles: np.ndarray
    failures: dict[str, str]  # triads the procedure could not calibrate, and why
    unit: object = None  # fieldcal.solvers.solve.UnitSolution: all of the above, and the averages used

    def bound(self, name: str, thermal: ThermalTerms | None = None, theta: np.ndarray | None = None) -> np.ndarray:
        """Cramér-Rao bound (9x9) for one triad at the true parameters and orientations; with
        ``thermal`` (the averages' ΔT in the problem's data order), of the thermal model too, at
        ``theta`` (the truth about the model's reference; default the truth)."""
        truth = self.device[name]
        theta = self.truth[name] if theta is None else theta
        up_body = self.plan.attitudes[:, 2, :]
        if truth.kind == SPECIFIC_FORCE:
            return specific_force_bound(theta, up_body, self.station.gravity, self.covariances[name],
                                        thermal=thermal)
        angle = self.static_table_angles
        north_enu = np.column_stack([np.sin(angle), np.cos(angle), np.zeros_like(angle)])
        north_body = np.einsum("nij,ni->nj", self.plan.attitudes, north_enu)
        steps = [self.procedure.rate_step_at(i) for i in range(len(self.procedure.positions))]
        turning = [i for i, step in enumerate(steps) if step is not None]
        assert turning  # (a gyro is calibrated only with rate steps)
        rate = np.radians([step.rate_deg_s for step in steps if step is not None])  # in turning's order
        return angular_rate_bound(theta, up_body, rate, north_body, EARTH_RATE,
                                  self.station.latitude_rad, self.covariances[name], turning, thermal=thermal)


def run_simulated_calibration(seed: int, procedure: Procedure | str = "field-18",
                              device: dict[str, TriadTruth] | None = None,
                              station: Station = DEFAULT_STATION, rate_hz: float = 250.0,
                              placement_sigma_deg: float = 3.0, method: str = "auto",
                              progress=None) -> SimulatedCalibration:
    """Every triad solved (norm method; classic least squares for an aligned procedure).

    A triad the procedure cannot calibrate is listed in ``failures`` with the reason.
    """
    if isinstance(procedure, str):
        procedure = load_procedure(procedure)
    device = device or paper_mimu()
    # Independent streams, so placements and sensor noise never share random numbers.
    placement_seed, noise_seed = np.random.SeedSequence(seed).spawn(2)
    plan = plan_procedure(procedure, rate_hz, np.random.default_rng(placement_seed), placement_sigma_deg)
    averages, angles = simulate_averages(plan, device, station, rate_hz, seed=noise_seed,
                                         progress=progress)
    unit = solve_unit(procedure, list(plan.windows), averages, models_from_truth(device), station,
                      rate_hz, method)
    truths = {name: params_from_k(t.K, t.bias) for name, t in device.items()}
    return SimulatedCalibration(procedure, station, plan, device, unit.solutions, truths,
                                unit.problems, unit.covariances, angles, unit.failures, unit)
