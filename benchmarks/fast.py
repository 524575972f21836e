"""Monte Carlo of field-18 against a planned adaptive procedure, through the headless run path.

Every run is a headless run through the conductor (the in-process simulated bench, paper Table 3
errors, 3° placement errors per axis, latitude 40°, the scripted operator, stillness detection
and the engine's windows, adaptive dwell when the procedure asks for it); every procedure gets
the same seeds. The noise is the paper's Table 4 (``--config sim``) or a device config's
accelerometer and gyroscope noise (``--config vn100``, ``--config mti``; the simulated unit keeps
its inclinometer at the paper's noise, and runs at the config's sample rate).

    python benchmarks/fast.py                      # a few runs of each, planned here: rough
    python benchmarks/fast.py mc --config sim --procedure field-18 --runs 200 --out f18.npz
    python benchmarks/fast.py mc --config sim --procedure planned.yaml --runs 200 --out plan.npz
    python benchmarks/fast.py report --reference f18.npz --planned plan.npz

``mc`` saves every run's errors, reported σ and operator time, so the two procedures (and the
long runs, in chunks of seeds) can go separately and in the background; ``report`` pairs the runs
by seed and prints per parameter the RMS error ratio planned / reference with its standard error,
the ratio of the mean reported σ (the bound at the runs' own windows), the RMS z (error /
reported σ) per triad of each, and the operator-time ratio (simulated time at the end of the
run, handling included). The noise is common per seed (``common_noise_bench``), which makes the
ratios scatter less without changing either procedure's errors in expectation.
"""
from __future__ import annotations

import argparse
import dataclasses
import datetime
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

TRIADS_FROM_CONFIG = ("accelerometer", "gyroscope")  # what a device config's noise replaces


@dataclasses.dataclass(frozen=True)
class NoiseSpec(RunSpec):
    """A headless run whose simulated unit has another noise (a device config's) per triad."""

    noise: tuple = ()  # (triad, TriadNoise) pairs

    def device(self):
        device = super().device()
        for name, noise in self.noise:
            device[name] = dataclasses.replace(device[name], noise=noise)
        return device


def config_noise(config_name: str) -> tuple[tuple, float]:
    """The (triad, noise) pairs a config gives its accelerometer and gyroscope, and its rate."""
    if config_name == "sim":
        return (), 250.0
    from fieldcal.config import load_config
    from fieldcal.planning.command import station_models
    config = load_config(config_name)
    models = station_models(config)
    return tuple((n, models[n].noise) for n in TRIADS_FROM_CONFIG if n in models), config.device.rate_hz


COMMON_NOISE_STREAM = 13  # the noise's own random stream per seed (any fixed number will do)


def common_noise_bench(spec: RunSpec) -> SimulatedBench:
    """The simulated bench, its sensor noise drawn from a stream of its own per seed.

    Common random numbers: the simulator draws its noise and the hand shake of each carry from one
    generator, so two procedures on the same seed would see unrelated noise. Drawn from its own
    stream, the noise at each sample since power-on is the same for every procedure on a seed (the
    placement errors already are: the operator's stream). Each run's noise is still an honest draw
    of the unit's noise, so neither procedure's RMS error changes in expectation, but both see the
    same bias-instability path, and the ratio of their RMS errors scatters far less over N seeds.
    """
    from drivers.sim.noise import InnovationNoise

    bench = SimulatedBench(spec)
    sim = bench.sim
    if sim.noise_model != "innovations":
        raise ValueError(f"common noise needs the innovations noise model, not {sim.noise_model!r}")
    stream = np.random.default_rng([spec.seed, COMMON_NOISE_STREAM])
    # The simulator's one place for its noise generator (MimuSimulator._make_noise): replaced
    # before the first sample is drawn.
    sim._noise = InnovationNoise([t.noise for t in sim.triads.values()], sim.rate_hz, stream)
    return bench


def one_run(seed: int, procedure_text: str, where: str, config_name: str):
    """Errors, reported σ and operator time (s) of one headless run."""
    noise, rate_hz = config_noise(config_name)
    spec = NoiseSpec(parse_procedure(procedure_text, where), DEFAULT_STATION, seed=seed,
                     rate_hz=rate_hz, noise=noise)
    conductor = Conductor(spec, common_noise_bench(spec), ScriptedOperator(spec.script, spec.procedure))
    outcome = conductor.run()
    truth = spec.truth()
    result = {name: (sol.theta - truth[name], sol.sigma) for name, sol in outcome.unit.solutions.items()}
    return result, dict(outcome.unit.failures), conductor.engine.t


def procedure_text(name_or_path: str) -> tuple[str, str]:
    procedure = load_procedure(name_or_path)
    return procedure.text, procedure.name


def monte_carlo(text: str, where: str, config_name: str, runs: int, workers: int, first_seed: int = 0):
    errors, sigmas, seconds, problems = {}, {}, [], []
    seeds = range(first_seed, first_seed + runs)
    with ProcessPoolExecutor(workers) as pool:
        work = partial(one_run, procedure_text=text, where=where, config_name=config_name)
        for i, (result, failures, t) in enumerate(pool.map(work, seeds), start=1):
            problems += [f"{where} seed {seeds[i - 1]}: {name} not solved: {why}" for name, why in failures.items()]
            for name, (err, sig) in result.items():
                errors.setdefault(name, []).append(err)
                sigmas.setdefault(name, []).append(sig)
            seconds.append(t)
            print(f"\r{where} ({config_name}): {i}/{runs} runs", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    return ({n: np.array(v) for n, v in errors.items()}, {n: np.array(v) for n, v in sigmas.items()},
            np.array(seconds), problems)


def save(path: Path, where: str, config_name: str, errors, sigmas, seconds, problems, seeds) -> None:
    arrays = {f"err/{n}": v for n, v in errors.items()} | {f"sig/{n}": v for n, v in sigmas.items()}
    np.savez(path, procedure=where, config=config_name, seconds=seconds, seeds=np.asarray(seeds),
             common_noise=True, problems=np.array(problems, dtype=str), **arrays)


def load(paths: list[str]):
    """Saved Monte Carlos of one procedure (chunks of seeds), joined."""
    parts = [np.load(path) for path in paths]
    if not all("common_noise" in p.files for p in parts):
        raise SystemExit(f"{' '.join(paths)}: saved before the runs shared their noise per seed; run mc again")
    names = [k for k in parts[0].files if k.startswith(("err/", "sig/"))]
    joined = {k: np.concatenate([p[k] for p in parts]) for k in names + ["seconds", "seeds"]}
    errors = {k[4:]: v for k, v in joined.items() if k.startswith("err/")}
    sigmas = {k[4:]: v for k, v in joined.items() if k.startswith("sig/")}
    return (str(parts[0]["procedure"]), str(parts[0]["config"]), errors, sigmas, joined["seconds"],
            [line for p in parts for line in p["problems"]], joined["seeds"])


def paired(ref, new):
    """The two Monte Carlos on the seeds both ran, in the same order: (errors, σ, seconds) each."""
    ref_seeds, new_seeds = list(ref[6]), list(new[6])
    common = [seed for seed in ref_seeds if seed in set(new_seeds)]
    if not common:
        raise SystemExit("report: the two Monte Carlos share no seed")
    out = []
    for part, seeds in ((ref, ref_seeds), (new, new_seeds)):
        rows = np.array([seeds.index(seed) for seed in common])
        out.append(({n: v[rows] for n, v in part[2].items()}, {n: v[rows] for n, v in part[3].items()},
                    part[4][rows]))
    return out, len(common)


def rms_ratio(new_err: np.ndarray, ref_err: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per parameter, RMS(new) / RMS(ref) over paired runs and its standard error (delta method on
    the paired squared errors, so the correlation the common noise gives is counted)."""
    a2, b2 = new_err ** 2, ref_err ** 2
    ratio = np.sqrt(a2.mean(axis=0) / b2.mean(axis=0))
    u = a2 / a2.mean(axis=0) - b2 / b2.mean(axis=0)  # d log(ratio²) per run
    return ratio, ratio * 0.5 * u.std(axis=0, ddof=1) / np.sqrt(len(a2))


def report(ref, new) -> None:
    ref_where, config_name = ref[0], ref[1]
    new_where = new[0]
    ((ref_err, ref_sig, ref_s), (new_err, new_sig, new_s)), runs = paired(ref, new)
    print(f"{datetime.date.today()}, noise of {config_name}: {runs} seeds run by both {ref_where} and "
          f"{new_where} (common noise per seed); operator time {ref_s.mean() / 60:.1f} min against "
          f"{new_s.mean() / 60:.1f} min: ratio {new_s.mean() / ref_s.mean():.3f}")
    from drivers.sim.device import paper_mimu
    device = paper_mimu()
    worst, worst_sigma, worst_se = 0.0, 0.0, 0.0
    for name in ref_err:
        if name not in new_err:
            continue
        kind, unit = device[name].kind, device[name].output_unit
        ref_rms = np.sqrt(np.mean(ref_err[name] ** 2, axis=0))
        new_rms = np.sqrt(np.mean(new_err[name] ** 2, axis=0))
        ratio, se = rms_ratio(new_err[name], ref_err[name])
        sigma_ratio = new_sig[name].mean(axis=0) / ref_sig[name].mean(axis=0)
        z_ref = np.sqrt(np.mean((ref_err[name] / ref_sig[name]) ** 2))
        z_new = np.sqrt(np.mean((new_err[name] / new_sig[name]) ** 2))
        print(f"\n{name}: RMS z (error / reported σ) {ref_where} {z_ref:.2f}, {new_where} {z_new:.2f}")
        print(f"| parameter | unit | {ref_where} RMS | {new_where} RMS | RMS ratio ± s.e. | σ ratio |")
        print("|---|---|---|---|---|---|")
        for j, pname in enumerate(PARAM_NAMES):
            scale = display_scale(kind, unit, j)
            if ratio[j] > worst:
                worst, worst_se = ratio[j], se[j]
            worst_sigma = max(worst_sigma, sigma_ratio[j])
            print(f"| {pname} | {param_unit(kind, unit, j)} | {ref_rms[j] * scale:.3g} | "
                  f"{new_rms[j] * scale:.3g} | {ratio[j]:.3f} ± {se[j]:.3f} | {sigma_ratio[j]:.3f} |")
    # σ ratio: the mean reported σ (the bound of each run's own windows), which scatters little.
    print(f"\nworst RMS ratio {worst:.3f} ± {worst_se:.3f} (one standard error over {runs} paired runs); "
          f"worst ratio of the mean reported σ {worst_sigma:.3f}")


def plan_text(config_name: str, slack: float, margin: float) -> str:
    from fieldcal.cli.main import main
    with tempfile.TemporaryDirectory() as directory:
        out = Path(directory) / f"fast-{config_name}.yaml"
        if main(["plan", "--config", config_name, "--target", "field-18", "--slack", str(slack),
                 "--margin", str(margin), "--out", str(out)]) != 0:
            raise SystemExit("planning failed")
        return out.read_text()


def cmd_mc(args) -> int:
    text, where = procedure_text(args.procedure)
    started = time.perf_counter()
    errors, sigmas, seconds, problems = monte_carlo(text, where, args.config, args.runs, args.workers,
                                                    args.first_seed)
    save(Path(args.out), where, args.config, errors, sigmas, seconds, problems,
         range(args.first_seed, args.first_seed + args.runs))
    print(f"{args.runs} runs of {where} ({args.config}) in {time.perf_counter() - started:.0f} s -> {args.out}")
    for line in problems:
        print(f"FAIL: {line}")
    return 1 if problems else 0


def cmd_report(args) -> int:
    ref, new = load(args.reference), load(args.planned)
    report(ref, new)
    for line in ref[5] + new[5]:
        print(f"FAIL: {line}")
    return 1 if ref[5] or new[5] else 0


def cmd_quick(args) -> int:
    planned = Path(args.procedure).read_text() if args.procedure else \
        plan_text(args.config, args.slack, args.margin)
    field = load_procedure("field-18").text
    ref = monte_carlo(field, "field-18", args.config, args.runs, args.workers)
    new = monte_carlo(planned, "planned", args.config, args.runs, args.workers)
    seeds = np.arange(args.runs)
    report(("field-18", args.config, *ref, seeds), ("planned", args.config, *new, seeds))
    if args.runs < 200:
        print(f"{args.runs} runs: rough figures; the `mc` and `report` commands with --runs 200 give "
              "the ones to quote")
    for line in ref[3] + new[3]:
        print(f"FAIL: {line}")
    return 1 if ref[3] or new[3] else 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--config", default="sim", help="whose noise: sim (paper Table 4), vn100, mti")
    parser.add_argument("--slack", type=float, default=0.1, help="the plan's allowance over field-18's σ")
    parser.add_argument("--margin", type=float, default=0.05,
                        help="the plan's bounds this fraction under the allowance, for the scatter of "
                        "a measured RMS ratio (about 1/√N)")
    parser.add_argument("--procedure", help="a planned procedure file (default: plan one now)")
    parser.set_defaults(func=cmd_quick)
    sub = parser.add_subparsers()
    mc = sub.add_parser("mc", help="seeded runs of one procedure, saved to a .npz")
    mc.add_argument("--config", default="sim")
    mc.add_argument("--procedure", required=True, help="field-18 or a procedure file")
    mc.add_argument("--runs", type=int, default=200)
    mc.add_argument("--first-seed", type=int, default=0)
    mc.add_argument("--workers", type=int, default=1)
    mc.add_argument("--out", required=True)
    mc.set_defaults(func=cmd_mc)
    rep = sub.add_parser("report", help="compare two saved Monte Carlos")
    rep.add_argument("--reference", nargs="+", required=True, help="the reference's .npz files")
    rep.add_argument("--planned", nargs="+", required=True, help="the planned procedure's .npz files")
    rep.set_defaults(func=cmd_report)
    args = parser.parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    raise SystemExit(main())
