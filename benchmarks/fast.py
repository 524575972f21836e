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

    # the flicker cut-off as a modelling choice (DESIGN 12): the same plan under another one
    python benchmarks/fast.py mc --config sim --flicker-tau-max 1e6 --procedure field-18 --out f18-1e6.npz

``mc`` saves every run's errors, reported σ and operator time, so the two procedures (and the
long runs, in chunks of seeds: ``--first-seed``, several files to ``report``) can go separately
and in the background; ``report`` pairs the runs by seed and prints per parameter the RMS error
ratio planned / reference with its standard error, the ratio of the mean reported σ (the bound
at the runs' own windows), the RMS z (error / reported σ) per triad of each, and the
operator-time ratio (simulated time at the end of the run, handling included), then whether the
issue's done-condition holds. Scale factors and misalignments are judged against the truth,
biases against the bias at the end of calibration (the simulated bias process at the run's last
sample, what the unit is used with; the solver's ``bias_at_end``); the turn-on constant is
reported beside them, not judged. The noise is common per seed (``common_noise_bench``), which
makes the ratios scatter less without changing either procedure's errors in expectation.
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

from drivers.noise import DEFAULT_FLICKER_TAU_MAX_S, FLICKER_TAU_MAX_RANGE_S
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


def config_noise(config_name: str, flicker_tau_max_s: float = DEFAULT_FLICKER_TAU_MAX_S) -> tuple[tuple, float]:
    """The (triad, noise) pairs a config gives its accelerometer and gyroscope, and its rate; their
    flicker banks end at ``flicker_tau_max_s`` (the simulated unit's one cut-off)."""
    if config_name == "sim":
        return (), 250.0
    from fieldcal.config import load_config
    from fieldcal.planning.command import station_models
    config = load_config(config_name)
    models = station_models(config)
    return tuple((n, dataclasses.replace(models[n].noise, flicker_tau_max_s=flicker_tau_max_s))
                 for n in TRIADS_FROM_CONFIG if n in models), config.device.rate_hz


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


def one_run(seed: int, procedure_text: str, where: str, config_name: str,
            flicker_tau_max_s: float = DEFAULT_FLICKER_TAU_MAX_S):
    """Per solved triad (error, reported σ) of its nine parameters against the truth, of its bias
    at the end against the true bias at the run's last sample, and of the turn-on constant against
    that same end value; the failures; the operator time (s) of one headless run."""
    noise, rate_hz = config_noise(config_name, flicker_tau_max_s)
    spec = NoiseSpec(parse_procedure(procedure_text, where), DEFAULT_STATION, seed=seed,
                     rate_hz=rate_hz, noise=noise, flicker_tau_max_s=flicker_tau_max_s)
    conductor = Conductor(spec, common_noise_bench(spec), ScriptedOperator(spec.script, spec.procedure))
    outcome = conductor.run()
    truth, at_end = spec.truth(), outcome.bias_at_end
    result = {}
    for name, sol in outcome.unit.solutions.items():
        end = sol.bias_at_end
        result[name] = {"err": sol.theta - truth[name], "sig": sol.sigma,
                        "end": end.value - at_end[name], "endsig": end.sigma,
                        "constend": sol.theta[:3] - at_end[name]}
    return result, dict(outcome.unit.failures), conductor.engine.t


def procedure_text(name_or_path: str) -> tuple[str, str]:
    procedure = load_procedure(name_or_path)
    return procedure.text, procedure.name


KEYS = ("err", "sig", "end", "endsig", "constend")  # one_run's per-triad arrays, as saved


@dataclasses.dataclass
class MonteCarlo:
    """One procedure's runs: ``arrays[key][triad]`` is (runs, 9 or 3), in ``seeds`` order."""

    procedure: str
    config: str
    flicker_tau_max_s: float
    arrays: dict
    seconds: np.ndarray
    problems: list
    seeds: np.ndarray

    def rows(self, seeds) -> MonteCarlo:
        index = {int(s): i for i, s in enumerate(self.seeds)}
        rows = np.array([index[int(s)] for s in seeds], dtype=int)
        return dataclasses.replace(self, arrays={k: {n: v[rows] for n, v in by.items()} for k, by in self.arrays.items()},
                                   seconds=self.seconds[rows], seeds=np.asarray(seeds))


def monte_carlo(text: str, where: str, config_name: str, runs: int, workers: int, first_seed: int = 0,
                flicker_tau_max_s: float = DEFAULT_FLICKER_TAU_MAX_S) -> MonteCarlo:
    arrays: dict = {k: {} for k in KEYS}
    seconds, problems = [], []
    seeds = range(first_seed, first_seed + runs)
    with ProcessPoolExecutor(workers) as pool:
        work = partial(one_run, procedure_text=text, where=where, config_name=config_name,
                       flicker_tau_max_s=flicker_tau_max_s)
        for i, (result, failures, t) in enumerate(pool.map(work, seeds), start=1):
            problems += [f"{where} seed {seeds[i - 1]}: {name} not solved: {why}" for name, why in failures.items()]
            for name, values in result.items():
                for key in KEYS:
                    arrays[key].setdefault(name, []).append(values[key])
            seconds.append(t)
            print(f"\r{where} ({config_name}, flicker to {flicker_tau_max_s:g} s): {i}/{runs} runs", end="",
                  file=sys.stderr, flush=True)
    print(file=sys.stderr)
    return MonteCarlo(where, config_name, flicker_tau_max_s,
                      {k: {n: np.array(v) for n, v in by.items()} for k, by in arrays.items()},
                      np.array(seconds), problems, np.asarray(seeds))


def save(path: Path, mc: MonteCarlo) -> None:
    arrays = {f"{key}/{n}": v for key, by in mc.arrays.items() for n, v in by.items()}
    np.savez(path, procedure=mc.procedure, config=mc.config, flicker_tau_max_s=mc.flicker_tau_max_s,
             seconds=mc.seconds, seeds=mc.seeds, common_noise=True, problems=np.array(mc.problems, dtype=str),
             **arrays)


def load(paths: list[str]) -> MonteCarlo:
    """Saved Monte Carlos of one procedure (chunks of seeds), joined; chunks of another procedure,
    config or flicker cut-off, or seeds run twice, are refused in one line."""
    try:
        parts = [np.load(path) for path in paths]
    except (OSError, ValueError) as exc:
        raise SystemExit(f"report: cannot read {' '.join(paths)}: {exc}") from None
    for path, p in zip(paths, parts):
        if "common_noise" not in p.files:
            raise SystemExit(f"{path}: saved before the runs shared their noise per seed; run mc again")
        if "flicker_tau_max_s" not in p.files or "endsig/accelerometer" not in p.files:
            raise SystemExit(f"{path}: saved before the bias at the end of calibration was solved; run mc again")
    what = {(str(p["procedure"]), str(p["config"]), float(p["flicker_tau_max_s"])) for p in parts}
    if len(what) > 1:
        raise SystemExit(f"report: {' '.join(paths)} are runs of different procedures, configs or "
                         f"flicker cut-offs: {sorted(what)}")
    seeds = np.concatenate([p["seeds"] for p in parts])
    if len(set(seeds.tolist())) != len(seeds):
        raise SystemExit(f"report: {' '.join(paths)} run some seeds twice; give each chunk once")
    names = [k for k in parts[0].files if k.split("/")[0] in KEYS]
    arrays: dict = {k: {} for k in KEYS}
    for k in names:
        key, triad = k.split("/", 1)
        arrays[key][triad] = np.concatenate([p[k] for p in parts])
    (where, config, tau), = what
    return MonteCarlo(where, config, tau, arrays, np.concatenate([p["seconds"] for p in parts]),
                      [line for p in parts for line in p["problems"]], seeds)


def paired(ref: MonteCarlo, new: MonteCarlo) -> tuple[MonteCarlo, MonteCarlo]:
    """The two Monte Carlos on the seeds both ran, in the same order."""
    if (ref.config, ref.flicker_tau_max_s) != (new.config, new.flicker_tau_max_s):
        raise SystemExit(f"report: the reference ran {ref.config} with flicker to {ref.flicker_tau_max_s:g} s, "
                         f"the planned {new.config} with flicker to {new.flicker_tau_max_s:g} s")
    in_new = set(new.seeds.tolist())
    common = [int(s) for s in ref.seeds if int(s) in in_new]
    if not common:
        raise SystemExit("report: the two Monte Carlos share no seed")
    return ref.rows(common), new.rows(common)


def rms_ratio(new_err: np.ndarray, ref_err: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per parameter, RMS(new) / RMS(ref) over paired runs and its standard error (delta method on
    the paired squared errors, so the correlation the common noise gives is counted)."""
    a2, b2 = new_err ** 2, ref_err ** 2
    ratio = np.sqrt(a2.mean(axis=0) / b2.mean(axis=0))
    u = a2 / a2.mean(axis=0) - b2 / b2.mean(axis=0)  # d log(ratio²) per run
    return ratio, ratio * 0.5 * u.std(axis=0, ddof=1) / np.sqrt(len(a2))


# The done-condition (issue 22): the planned procedure's operator time, every targeted
# parameter's σ ratio and RMS error ratio against field-18's, and RMS z per triad.
TIME_RATIO_MAX, RATIO_MAX, Z_RANGE = 0.20, 1.10, (0.9, 1.1)
END_NAMES = tuple(f"{n} at end" for n in PARAM_NAMES[:3])


def targeted(mc: MonteCarlo, key_err: str, name: str) -> np.ndarray:
    """(runs, 9) of what the time target judges: the bias at the end of calibration in place of
    the turn-on constant, the scale factors and misalignments against the truth."""
    if key_err == "err":
        return np.hstack([mc.arrays["end"][name], mc.arrays["err"][name][:, 3:]])
    return np.hstack([mc.arrays["endsig"][name], mc.arrays["sig"][name][:, 3:]])


def rms_z(err: np.ndarray, sig: np.ndarray) -> float:
    return float(np.sqrt(np.mean((err / sig) ** 2)))


def table(rows_of, names, kind, unit, ref_err, ref_sig, new_err, new_sig, ref_where, new_where):
    """Markdown rows per parameter; (ratios, standard errors, σ ratios)."""
    ratio, se = rms_ratio(new_err, ref_err)
    sigma_ratio = new_sig.mean(axis=0) / ref_sig.mean(axis=0)
    ref_rms, new_rms = np.sqrt(np.mean(ref_err ** 2, axis=0)), np.sqrt(np.mean(new_err ** 2, axis=0))
    print(f"| parameter | unit | {ref_where} RMS | {new_where} RMS | RMS ratio ± s.e. | σ ratio |")
    print("|---|---|---|---|---|---|")
    for j, pname in enumerate(names):
        scale = display_scale(kind, unit, rows_of[j])
        print(f"| {pname} | {param_unit(kind, unit, rows_of[j])} | {ref_rms[j] * scale:.3g} | "
              f"{new_rms[j] * scale:.3g} | {ratio[j]:.3f} ± {se[j]:.3f} | {sigma_ratio[j]:.3f} |")
    return ratio, se, sigma_ratio


def report(ref: MonteCarlo, new: MonteCarlo) -> bool:
    """The tables, then whether the done-condition holds (True if it does)."""
    ref, new = paired(ref, new)
    runs = len(ref.seeds)
    time_ratio = new.seconds.mean() / ref.seconds.mean()
    print(f"{datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC, noise of {ref.config}, flicker "
          f"bank to {ref.flicker_tau_max_s:g} s: {runs} seeds run by both {ref.procedure} and {new.procedure} "
          f"(common noise per seed); operator time {ref.seconds.mean() / 60:.1f} min against "
          f"{new.seconds.mean() / 60:.1f} min: ratio {time_ratio:.3f}")
    print("biases are judged at the end of calibration: the bias process at the run's last sample (what "
          "the unit is used with), against the solver's bias_at_end; the turn-on constant is shown apart")
    from drivers.sim.device import paper_mimu
    device = paper_mimu()
    worst_sigma, worst_excess, worst_at = 0.0, -np.inf, ""
    z_bad = []
    for name in ref.arrays["err"]:
        if name not in new.arrays["err"]:
            continue
        kind, unit = device[name].kind, device[name].output_unit
        ref_err, ref_sig = targeted(ref, "err", name), targeted(ref, "sig", name)
        new_err, new_sig = targeted(new, "err", name), targeted(new, "sig", name)
        z = {w: (rms_z(e, s), rms_z(e[:, :3], s[:, :3])) for w, e, s in
             ((ref.procedure, ref_err, ref_sig), (new.procedure, new_err, new_sig))}
        # an RMS z over n honest errors scatters by about 1/√(2n): 0.04 over 50 runs × 9
        se = 1 / np.sqrt(2 * ref_err.size), 1 / np.sqrt(2 * ref_err[:, :3].size)
        print(f"\n{name}: RMS z (error / reported σ) of the nine judged (± {se[0]:.2f}), and of the bias at "
              f"the end alone (± {se[1]:.2f}): " + ", ".join(f"{w} {a:.2f} and {b:.2f}" for w, (a, b) in z.items()))
        z_bad += [f"{name} {w}: RMS z {v:.2f}" for w, pair in z.items() for v in pair
                  if not Z_RANGE[0] <= v <= Z_RANGE[1]]
        ratio, se, sigma_ratio = table(range(9), END_NAMES + PARAM_NAMES[3:], kind, unit, ref_err, ref_sig,
                                       new_err, new_sig, ref.procedure, new.procedure)
        for j, pname in enumerate(END_NAMES + PARAM_NAMES[3:]):
            if ratio[j] - 2 * se[j] - RATIO_MAX > worst_excess:
                worst_excess, worst_at = ratio[j] - 2 * se[j] - RATIO_MAX, f"{name} {pname} {ratio[j]:.3f} ± {se[j]:.3f}"
            worst_sigma = max(worst_sigma, sigma_ratio[j])
        turn_on = rms_z(new.arrays["err"][name][:, :3], new.arrays["sig"][name][:, :3])
        print(f"turn-on constant (solved and reported, not in the time target; RMS z {new.procedure} {turn_on:.2f}):")
        table(range(3), tuple(f"{n} turn-on" for n in PARAM_NAMES[:3]), kind, unit, ref.arrays["err"][name][:, :3],
              ref.arrays["sig"][name][:, :3], new.arrays["err"][name][:, :3], new.arrays["sig"][name][:, :3],
              ref.procedure, new.procedure)
    conditions = [
        (f"operator time ratio {time_ratio:.3f} <= {TIME_RATIO_MAX}", time_ratio <= TIME_RATIO_MAX),
        (f"worst σ ratio of the judged parameters {worst_sigma:.3f} <= {RATIO_MAX}", worst_sigma <= RATIO_MAX),
        (f"worst RMS error ratio {worst_at}: at most 2 s.e. above {RATIO_MAX}", worst_excess <= 0),
        ("RMS z per triad within 0.9-1.1" + (f": not {'; '.join(z_bad)}" if z_bad else ""), not z_bad),
    ]
    print(f"\ndone-condition over {runs} paired runs (issue 22):")
    for text, ok in conditions:
        print(f"  {'met   ' if ok else 'MISSED'} {text}")
    return all(ok for _, ok in conditions)


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
    mc = monte_carlo(text, where, args.config, args.runs, args.workers, args.first_seed, args.flicker_tau_max)
    save(Path(args.out), mc)
    print(f"{args.runs} runs of {where} ({args.config}, flicker to {args.flicker_tau_max:g} s) in "
          f"{time.perf_counter() - started:.0f} s -> {args.out}")
    for line in mc.problems:
        print(f"FAIL: {line}")
    return 1 if mc.problems else 0


def cmd_report(args) -> int:
    ref, new = load(args.reference), load(args.planned)
    met = report(ref, new)
    for line in ref.problems + new.problems:
        print(f"FAIL: {line}")
    return 0 if met and not ref.problems and not new.problems else 1


def cmd_quick(args) -> int:
    planned = Path(args.procedure).read_text() if args.procedure else \
        plan_text(args.config, args.slack, args.margin)
    field = load_procedure("field-18").text
    ref = monte_carlo(field, "field-18", args.config, args.runs, args.workers,
                      flicker_tau_max_s=args.flicker_tau_max)
    new = monte_carlo(planned, "planned", args.config, args.runs, args.workers,
                      flicker_tau_max_s=args.flicker_tau_max)
    report(ref, new)
    if args.runs < 200:
        print(f"{args.runs} runs: rough figures; the `mc` and `report` commands with --runs 200 give "
              "the ones to quote")
    for line in ref.problems + new.problems:
        print(f"FAIL: {line}")
    return 1 if ref.problems or new.problems else 0


def flicker_cut_off(text: str) -> float:
    """--flicker-tau-max: seconds within the range a config may give (drivers.noise)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected seconds, got {text!r}") from None
    low, high = FLICKER_TAU_MAX_RANGE_S
    if not low <= value <= high:
        raise argparse.ArgumentTypeError(f"expected {low:g} to {high:g} s, got {text}")
    return value


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
    tau_help = ("the simulated unit's longest flicker correlation time, s (overrides every triad's "
                f"flicker_tau_max_s; default {DEFAULT_FLICKER_TAU_MAX_S:g})")
    parser.add_argument("--flicker-tau-max", type=flicker_cut_off, default=DEFAULT_FLICKER_TAU_MAX_S, help=tau_help)
    parser.set_defaults(func=cmd_quick)
    sub = parser.add_subparsers()
    mc = sub.add_parser("mc", help="seeded runs of one procedure, saved to a .npz")
    mc.add_argument("--config", default="sim")
    mc.add_argument("--procedure", required=True, help="field-18 or a procedure file")
    mc.add_argument("--runs", type=int, default=200)
    mc.add_argument("--first-seed", type=int, default=0)
    mc.add_argument("--workers", type=int, default=1)
    mc.add_argument("--out", required=True)
    mc.add_argument("--flicker-tau-max", type=flicker_cut_off, default=DEFAULT_FLICKER_TAU_MAX_S, help=tau_help)
    mc.set_defaults(func=cmd_mc)
    rep = sub.add_parser("report", help="compare two saved Monte Carlos")
    rep.add_argument("--reference", nargs="+", required=True, help="the reference's .npz files")
    rep.add_argument("--planned", nargs="+", required=True, help="the planned procedure's .npz files")
    rep.set_defaults(func=cmd_report)
    args = parser.parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    raise SystemExit(main())
