"""A simulated production line: many units of one product, each with its own errors and serial,
calibrated against the simulator, checked against the product spec and recorded in the registry
as a line's stations would. Used by ``benchmarks/production.py`` (50 units) and the tests (a few).

Every unit is the paper's MIMU with its own biases and scale factors drawn around the paper's
values; a few are built out of spec (an accelerometer bias beyond the spec's range), and one unit
comes back for a second calibration months later with its accelerometer bias drifted beyond the
spec's max_drift. Each calibration is a parameter file under ``directory/SERIAL/`` whose time (the
file's mtime, which the registry records) is the simulated calibration date.
"""
from __future__ import annotations

import datetime
import os
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from fieldcal.units import STANDARD_GRAVITY

MG = STANDARD_GRAVITY * 1e-3
FIRST_DAY = datetime.datetime(2026, 1, 5, 8, 0, tzinfo=datetime.timezone.utc)
RECALIBRATION_AFTER = datetime.timedelta(days=180)
OUT_OF_SPEC_BIAS_MG = 14.0  # beyond the paper MIMU spec's ±10 mg
DRIFT_MG = 3.0  # the drifting unit's accelerometer bias x, six months on (spec max_drift 1 mg)


@dataclass(frozen=True)
class UnitBuild:
    serial: str
    index: int
    out_of_spec: bool = False
    drifting: bool = False


@dataclass(frozen=True)
class LineCalibration:
    serial: str
    params: Path
    passed: bool
    reasons: tuple[str, ...]  # the spec's failures, "triad parameter: why"


def plan_line(units: int, out_of_spec: int = 3, seed: int = 1) -> list[UnitBuild]:
    """Serials FC-0001...; ``out_of_spec`` units chosen at random are built out of spec, and one
    other (the last in-spec unit) drifts."""
    chosen = set(np.random.default_rng(seed).choice(units - 1, size=out_of_spec, replace=False).tolist())
    drifting = max(i for i in range(units) if i not in chosen)
    return [UnitBuild(f"FC-{i + 1:04d}", i, i in chosen, i == drifting) for i in range(units)]


def unit_device(build: UnitBuild, seed: int, drifted: bool = False) -> dict:
    """The unit's true errors: the paper's, each bias and scale factor moved by the unit's own
    random amount; out of spec: accelerometer bias x at OUT_OF_SPEC_BIAS_MG; drifted: + DRIFT_MG."""
    from drivers.sim.device import paper_mimu

    rng = np.random.default_rng([seed, build.index])
    device = {}
    for name, truth in paper_mimu().items():
        bias_step = 1.0 * MG if truth.output_unit == "m/s^2" else np.radians(0.005)
        bias = truth.bias + rng.normal(0.0, bias_step, 3)
        K = truth.K @ np.diag(1.0 + rng.normal(0.0, 2e-4, 3))
        if name == "accelerometer" and build.out_of_spec:
            bias[0] = OUT_OF_SPEC_BIAS_MG * MG
        if name == "accelerometer" and drifted:
            bias[0] += DRIFT_MG * MG
        device[name] = replace(truth, bias=bias, K=K)
    return device


def calibrate(build: UnitBuild, procedure, rate_hz: float, seed: int, drifted: bool = False):
    """One simulated calibration of the unit: its ParameterFile (with its serial)."""
    from fieldcal.paramfile import ParameterFile
    from fieldcal.run.simcal import DEFAULT_STATION, run_simulated_calibration
    from fieldcal.solvers.methods import resolve_method

    device = unit_device(build, seed, drifted)
    cal = run_simulated_calibration(seed * 1000 + build.index * 2 + drifted, procedure, device,
                                    DEFAULT_STATION, rate_hz)
    return ParameterFile.from_solutions(
        cal.solutions.values(), station=cal.station, procedure=cal.procedure.name,
        inputs=[p.data for p in cal.problems.values()], method=resolve_method(cal.procedure, "auto"),
        device_name="paper MIMU (simulated)", device_serial=build.serial, simulation=True)


def _calibrate_job(args):
    build, procedure, rate_hz, seed, drifted = args
    return build, drifted, calibrate(build, procedure, rate_hz, seed, drifted)


def run_line(directory, registry, spec, builds: list[UnitBuild], procedure, rate_hz: float = 250.0,
             seed: int = 1, jobs: int = 1, progress=lambda line: None) -> list[LineCalibration]:
    """Calibrate every unit (and the drifting one again), in ``jobs`` processes; check each file
    against ``spec`` (the second calibration's drift against the first) and record it in the
    registry at ``registry``; the calibrations in the order they were recorded."""
    from fieldcal.acceptance import evaluate
    from fieldcal.paramfile import save
    from fieldcal.registry import Registry

    directory = Path(directory)
    work = [(b, procedure, rate_hz, seed, False) for b in builds]
    work += [(b, procedure, rate_hz, seed, True) for b in builds if b.drifting]
    first: dict[str, object] = {}
    done = []
    with Registry(registry) as db:
        for build, drifted, pf in _map(_calibrate_job, work, jobs):
            params = directory / build.serial / f"calibration-{1 + drifted}.yaml"
            params.parent.mkdir(parents=True, exist_ok=True)
            save(pf, params)
            when = FIRST_DAY + datetime.timedelta(hours=build.index) + RECALIBRATION_AFTER * drifted
            os.utime(params, (when.timestamp(), when.timestamp()))
            verdict = evaluate(spec, pf, first.get(build.serial))
            first.setdefault(build.serial, pf)
            db.record(params, verdict.passed, source="run")
            reasons = tuple(f"{c.triad} {c.parameter}: {'; '.join(c.reasons)}" for c in verdict.failures)
            done.append(LineCalibration(build.serial, params, verdict.passed, reasons))
            progress(f"{build.serial} calibration {1 + drifted}: {'PASS' if verdict.passed else 'FAIL'}"
                     + (f" ({reasons[0]}{' …' if len(reasons) > 1 else ''})" if reasons else ""))
    return done


def _map(function, work: list, jobs: int):
    """``function`` over ``work`` in order, in ``jobs`` processes (in this one when 1)."""
    if jobs <= 1:
        yield from map(function, work)
        return
    import multiprocessing

    with multiprocessing.get_context("spawn").Pool(jobs) as pool:
        yield from pool.imap(function, work)
