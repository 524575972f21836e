"""Monte Carlo of field-18 against the planned adaptive procedure, through the headless run path.

Every run is a headless run through the conductor (simulated bench at 250 Hz, paper Table 3
errors and Table 4 noise, placement errors of 3° per axis, latitude 40°, the scripted operator,
stillness detection and the engine's windows); both procedures get the same seeds. The planned
procedure is `fieldcal plan --config sim --target field-18 --slack SLACK` (computed here unless
--procedure names a planned file). Prints per parameter the RMS error ratio planned / field-18,
each procedure's RMS z (error / reported σ) per triad, and the operator time ratio (sample time
at the end of the run, handling included).

    python benchmarks/fast.py [--runs 200] [--workers 2] [--slack 0.1] [--procedure FILE.yaml]

A few runs (the default) give rough figures; --runs 200 gives the real ones.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from functools import partial
from pathlib import Path

import numpy as np

from fieldcal.model import PARAM_NAMES
from fieldcal.procedure.positions import load_procedure, parse_procedure
from fieldcal.run.conductor import Conductor
from fieldcal.run.operators import ScriptedOperator
from fieldcal.run.runner import RunSpec, SimulatedBench
from fieldcal.run.simcal import DEFAULT_STATION
from fieldcal.units import display_scale, param_unit


def one_run(seed: int, procedure_text: str, where: str):
    """Errors, reported σ and operator time (s) of one headless run."""
    spec = RunSpec(parse_procedure(procedure_text, where), DEFAULT_STATION, seed=seed)
    conductor = Conductor(spec, SimulatedBench(spec), ScriptedOperator(spec.script, spec.procedure))
    outcome = conductor.run()
    truth = spec.truth()
    result = {name: (sol.theta - truth[name], sol.sigma) for name, sol in outcome.unit.solutions.items()}
    return result, dict(outcome.unit.failures), conductor.engine.t


def plan_text(slack: float) -> str:
    from fieldcal.cli.main import main
    with tempfile.TemporaryDirectory() as directory:
        out = Path(directory) / "fast-paper.yaml"
        if main(["plan", "--config", "sim", "--target", "field-18", "--slack", str(slack),
                 "--out", str(out)]) != 0:
            raise SystemExit("planning failed")
        return out.read_text()


def monte_carlo(text: str, where: str, runs: int, workers: int):
    errors, sigmas, seconds, problems = {}, {}, [], []
    with ProcessPoolExecutor(workers) as pool:
        for i, (result, failures, t) in enumerate(pool.map(partial(one_run, procedure_text=text, where=where),
                                                           range(runs)), start=1):
            problems += [f"{where} run {i - 1}: {name} not solved: {why}" for name, why in failures.items()]
            for name, (err, sig) in result.items():
                errors.setdefault(name, []).append(err)
                sigmas.setdefault(name, []).append(sig)
            seconds.append(t)
            print(f"\r{where}: {i}/{runs} runs", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    return ({n: np.array(v) for n, v in errors.items()}, {n: np.array(v) for n, v in sigmas.items()},
            float(np.mean(seconds)), problems)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--slack", type=float, default=0.1, help="the plan's allowance over field-18's σ")
    parser.add_argument("--procedure", help="a planned procedure file (default: plan one now)")
    args = parser.parse_args(argv)
    started = time.perf_counter()
    planned = Path(args.procedure).read_text() if args.procedure else plan_text(args.slack)
    field = load_procedure("field-18").text
    ref_err, ref_sig, ref_s, problems = monte_carlo(field, "field-18", args.runs, args.workers)
    new_err, new_sig, new_s, more = monte_carlo(planned, "planned", args.runs, args.workers)
    problems += more
    print(f"\n{args.runs} seeded runs each, {time.perf_counter() - started:.0f} s; operator time: "
          f"field-18 {ref_s / 60:.1f} min, planned {new_s / 60:.1f} min, ratio {new_s / ref_s:.3f}")
    from drivers.sim.device import paper_mimu
    device = paper_mimu()
    for name in ref_err:
        if name not in new_err:
            continue
        kind, unit = device[name].kind, device[name].output_unit
        ref_rms = np.sqrt(np.mean(ref_err[name] ** 2, axis=0))
        new_rms = np.sqrt(np.mean(new_err[name] ** 2, axis=0))
        z_ref = np.sqrt(np.mean((ref_err[name] / ref_sig[name]) ** 2))
        z_new = np.sqrt(np.mean((new_err[name] / new_sig[name]) ** 2))
        print(f"\n{name}: RMS z (error / reported σ) field-18 {z_ref:.2f}, planned {z_new:.2f}")
        print("| parameter | unit | field-18 RMS | planned RMS | ratio |")
        print("|---|---|---|---|---|")
        for j, pname in enumerate(PARAM_NAMES):
            scale = display_scale(kind, unit, j)
            print(f"| {pname} | {param_unit(kind, unit, j)} | {ref_rms[j] * scale:.3g} | "
                  f"{new_rms[j] * scale:.3g} | {new_rms[j] / ref_rms[j]:.2f} |")
    if args.runs < 200:
        print(f"\n{args.runs} runs: the RMS ratios scatter by about ±{np.sqrt(1 / args.runs):.0%}; "
              "use --runs 200 for figures to quote")
    for line in problems:
        print(f"FAIL: {line}")
    return 1 if problems else 0


if __name__ == "__main__":
    raise SystemExit(main())
