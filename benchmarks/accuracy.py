"""Monte Carlo accuracy of a whole headless calibration against the Cramér-Rao bound.

Every run is a headless run through the conductor, the path a station takes: the simulated
bench makes the full 250 Hz sample stream of the field-18 procedure (200 s dwells, one turn each
way at 10 °/s per position, placement errors of 3° per axis, paper Table 4 noise, latitude 40°),
the automatic operator places the unit, the engine detects stillness and averages the windows,
and the conductor solves each triad; the result is compared with the truth. The bound accounts
for the unknown orientation of every position (the attitudes and table angles the bench really
had); it is averaged over the runs (the placements differ from run to run).

It fails (exit 1) when a triad fails to solve in any run, when the mean reported σ leaves
[0.90, 1.10] × CRB, when |mean error / SE| exceeds 4 (checked from 30 runs on), or, from
1,000 runs on, when any RMS/CRB ratio leaves [0.90, 1.10] (both sides: an overstated noise model
inflates σ and the bound together). Fewer runs print the ratios without judging them.

    python benchmarks/accuracy.py [--runs 1000] [--workers 2]
"""
from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from fieldcal.model import PARAM_NAMES
from fieldcal.procedure import events as ev
from fieldcal.run.conductor import Conductor, Subscriber
from fieldcal.run.operators import ScriptedOperator
from fieldcal.run.runner import RunSpec, SimulatedBench
from fieldcal.run.simcal import DEFAULT_STATION, SimulatedCalibration
from fieldcal.run.simrun import Plan
from fieldcal.procedure.positions import load_procedure
from fieldcal.units import display_scale, param_unit

RATIO_LIMITS = (0.90, 1.10)  # RMS/CRB and reported σ/CRB
MAX_MEAN_Z = 4.0  # |mean error / SE|
RMS_CHECK_RUNS = 1000  # the RMS scatters by ~1/sqrt(2n): ±2.2% at 1,000 runs
MEAN_CHECK_RUNS = 30


class Witness(Subscriber):
    """What the bound needs that only the bench knows: each dwell's true attitude and table angle."""

    def __init__(self, bench: SimulatedBench):
        self.bench, self.attitudes, self.angles = bench, {}, {}

    def event(self, e, run) -> None:
        if isinstance(e, ev.DwellComplete):
            self.attitudes[run.engine.step] = self.bench.attitude.copy()
            self.angles[run.engine.step] = self.bench.sim.table_angle


def one_run(seed: int):
    spec = RunSpec(load_procedure("field-18"), DEFAULT_STATION, seed=seed)
    bench = SimulatedBench(spec)
    witness = Witness(bench)
    conductor = Conductor(spec, bench, ScriptedOperator(spec.script, spec.procedure), [witness])
    outcome = conductor.run()
    unit = outcome.unit
    steps = sorted(witness.attitudes)
    windows = conductor.engine.windows_and_averages()[0]
    cal = SimulatedCalibration(spec.procedure, spec.station, Plan((), tuple(windows),
                               np.array([witness.attitudes[s] for s in steps])), spec.device(),
                               unit.solutions, spec.truth(), unit.problems, unit.covariances,
                               np.array([witness.angles[s] for s in steps]), unit.failures)
    return {name: (sol.theta - cal.truth[name], np.diag(cal.bound(name)), sol.sigma)
            for name, sol in cal.solutions.items()}, cal.truth, \
        {n: (cal.device[n].kind, cal.device[n].output_unit) for n in cal.device}, dict(unit.failures)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=200)
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    args = parser.parse_args(argv)
    started = time.perf_counter()
    errors, bounds, sigmas, problems = {}, {}, {}, []
    with ProcessPoolExecutor(args.workers) as pool:
        # (truth and kinds are the same in every run: the last run's are used below)
        for i, (result, truth, kinds, failures) in enumerate(pool.map(one_run, range(args.runs)), start=1):  # noqa: B007
            problems += [f"run {i - 1}: {name} not solved: {why}" for name, why in failures.items()]
            for name, (err, crb, sig) in result.items():
                errors.setdefault(name, []).append(err)
                bounds.setdefault(name, []).append(crb)
                sigmas.setdefault(name, []).append(sig)
            print(f"\r{i}/{args.runs} runs", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    elapsed = time.perf_counter() - started
    print(f"{args.runs} runs, {elapsed:.0f} s on {platform.node()} ({os.cpu_count()} cores, "
          f"{platform.python_implementation()} {platform.python_version()})")
    judge_rms, judge_mean = args.runs >= RMS_CHECK_RUNS, args.runs >= MEAN_CHECK_RUNS
    lo, hi = RATIO_LIMITS
    for name in errors:
        err = np.array(errors[name])
        rms = np.sqrt(np.mean(err**2, axis=0))
        crb = np.sqrt(np.mean(bounds[name], axis=0))
        sigma_ratio = np.mean(sigmas[name], axis=0) / crb
        mean_z = err.mean(axis=0) / (err.std(axis=0, ddof=1) / np.sqrt(len(err)))
        kind, unit = kinds[name]
        print(f"\n{name}")
        print("| parameter | unit | truth | RMS error | CRB | RMS/CRB | mean error / SE | reported σ / CRB |")
        print("|---|---|---|---|---|---|---|---|")
        for j, pname in enumerate(PARAM_NAMES):
            scale = display_scale(kind, unit, j)
            ratio = rms[j] / crb[j]
            print(f"| {pname} | {param_unit(kind, unit, j)} | {truth[name][j] * scale:.6g} | "
                  f"{rms[j] * scale:.3g} | {crb[j] * scale:.3g} | {ratio:.3f} | "
                  f"{mean_z[j]:+.2f} | {sigma_ratio[j]:.3f} |")
            if judge_rms and not lo <= ratio <= hi:
                problems.append(f"{name} {pname}: RMS/CRB {ratio:.3f} outside [{lo}, {hi}]")
            if not lo <= sigma_ratio[j] <= hi:
                problems.append(f"{name} {pname}: reported σ/CRB {sigma_ratio[j]:.3f} outside [{lo}, {hi}]")
            if judge_mean and not abs(mean_z[j]) <= MAX_MEAN_Z:
                problems.append(f"{name} {pname}: mean error/SE {mean_z[j]:+.2f} beyond ±{MAX_MEAN_Z:g}")
    # With n runs the RMS itself scatters by about 1/sqrt(2n) relative.
    print(f"\nRMS/CRB statistical scatter ±{1 / np.sqrt(2 * args.runs):.3f} at {args.runs} runs; "
          f"RMS/CRB {'judged' if judge_rms else f'not judged below {RMS_CHECK_RUNS} runs'}, "
          f"mean error/SE {'judged' if judge_mean else f'not judged below {MEAN_CHECK_RUNS} runs'}")
    for line in problems:
        print(f"FAIL: {line}")
    if not errors:
        print("FAIL: no triad solved in any run")
        return 1
    return 1 if problems else 0


if __name__ == "__main__":
    raise SystemExit(main())
