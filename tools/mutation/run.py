"""`make mutants`: generate mutmut's mutants of the core, run them module by module, print a table.

    python tools/mutation/run.py [--modules 'procedure/positions.py session/*'] [--first N] [--sample N]
                                [--names FILE] [--tests FILES] [--again survived] [--jobs N] [--report]

Run from the repository's top with the mutation environment's Python (.venv-mutants). Each module
runs in one pytest process (inprocess.py) over the quick tests tests.toml lists for it, niced, with
its own --basetemp, deleted after it. Verdicts are kept in mutants/results/<module>.tsv: a second
run runs only the mutants without one (so it reports at once when all have one); `--again
survived` runs a module's survivors again (after adding tests for them). tools/mutation/equivalent.txt
lists the survivors sorted out as equivalent, each with its reason.

`--sample N` runs N of each module's mutants, drawn with a fixed seed (the same N each time, and the
first N of a larger draw, so a second run only reports and a larger one adds to it); the table then
says "sampled N of M" and gives each kill rate with its 95 % Wilson score interval.
"""
from __future__ import annotations

import argparse
import fnmatch
import json
import math
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import tomllib
from collections import Counter
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

HERE = Path(__file__).resolve().parent
MUTANTS = Path("mutants")
RESULTS = MUTANTS / "results"
GOAL = 0.90
KILLED = ("killed", "timeout")
SAMPLE_SEED = "fieldcal mutants"  # with the module's path: each module its own fixed draw
Z95 = 1.959963984540054  # the standard normal's 97.5 % quantile: a two-sided 95 % interval
RUNNING: set[subprocess.Popen] = set()  # the batches' pytest processes, stopped with this one


def _stop(signum, frame):
    for process in list(RUNNING):
        process.terminate()  # each batch's thread then deletes its scratch


def core_modules() -> dict[str, list[str]]:
    """Each mutated module (path under fieldcal/, as tests.toml names it) and its mutants' names,
    in file order, from mutmut's .meta files."""
    modules = {}
    for meta in sorted((MUTANTS / "fieldcal").rglob("*.py.meta")):
        names = list(json.loads(meta.read_text(encoding="utf-8"))["exit_code_by_key"])
        if names:
            modules[meta.relative_to(MUTANTS / "fieldcal").as_posix().removesuffix(".meta")] = names
    return modules


def tests_for(module: str, listing: dict[str, list[str]]) -> list[str]:
    for pattern, files in listing.items():
        if fnmatch.fnmatch(module, pattern):
            return [f"tests/{name}" for name in files]
    return []


def results_path(module: str) -> Path:
    return RESULTS / (module.removesuffix(".py").replace("/", ".") + ".tsv")


def read_verdicts(module: str) -> dict[str, tuple[str, str]]:
    """name -> (verdict, killing test); the last line for a name wins (a re-run), but "no tests"
    from a re-run against other files than its first run's leaves the earlier verdict."""
    verdicts: dict[str, tuple[str, str]] = {}
    path = results_path(module)
    if path.exists():
        for line in path.read_text(encoding="utf-8").splitlines():
            fields = line.split("\t")
            if len(fields) >= 3 and not line.startswith("#"):
                if fields[1] != "no tests" or fields[0] not in verdicts:
                    verdicts[fields[0]] = (fields[1], fields[2])
    return verdicts


def read_equivalent(path: Path) -> dict[str, str]:
    """name -> why it is equivalent (lines `name<TAB>reason`; `#` starts a comment line)."""
    if not path.exists():
        return {}
    equivalent = {}
    for line in path.read_text(encoding="utf-8").splitlines():
        if line.strip() and not line.startswith("#"):
            name, _, reason = line.partition("\t")
            equivalent[name.strip()] = reason.strip()
    return equivalent


def sample_of(module: str, names: list[str], size: int) -> list[str]:
    """`size` of a module's mutants, in file order, drawn by a fixed shuffle of them all: the same
    for the same mutants, and a larger sample holds every smaller one."""
    order = list(names)
    random.Random(f"{SAMPLE_SEED} {module}").shuffle(order)  # a str seed is hashed by SHA-512: stable
    drawn = set(order[:size])
    return [name for name in names if name in drawn]


def wilson_interval(killed: int, run: int, z: float = Z95) -> tuple[float, float]:
    """The Wilson score interval of a proportion killed/run (closed form: the mutation environment
    need not have scipy); it stays inside [0, 1] and is not empty when all or none were killed."""
    if not run:
        return 0.0, 1.0
    rate, z2 = killed / run, z * z
    centre = (rate + z2 / (2 * run)) / (1 + z2 / run)
    half = z / (1 + z2 / run) * math.sqrt(rate * (1 - rate) / run + z2 / (4 * run * run))
    return max(0.0, centre - half), min(1.0, centre + half)


def weighted_estimate(rows: list[tuple[str, Counter]], z: float = Z95) -> tuple[float, float, float] | None:
    """The kill rate of all the rows' mutants, estimated from samples: each module's sampled rate
    weighted by its number of mutants (a stratified sample), and a 95 % interval: the modules'
    Agresti-Coull centres and variances, weighted alike, each variance times its finite-population
    correction (a module run whole adds no uncertainty, and its own rate is its centre). For one
    sampled module that is the Agresti-Coull interval (fpc aside), which holds Wilson's. Returns
    (estimate, low, high); None when no row has a mutant run."""
    strata = [(c["population"] or c["mutants"], c["mutants"] - c["not run"], c["killed"] + c["timeout"])
              for _, c in rows]
    strata = [(size, run, killed) for size, run, killed in strata if run]
    if not strata:
        return None
    total = sum(size for size, _, _ in strata)
    rate = sum(size * killed / run for size, run, killed in strata) / total
    centre = variance = 0.0
    for size, run, killed in strata:
        tilde_n = run + z * z
        tilde_p = (killed + z * z / 2) / tilde_n if run < size else killed / run
        unsampled = (size - run) / (size - 1) if size > 1 else 0.0
        centre += size / total * tilde_p
        variance += (size / total) ** 2 * tilde_p * (1 - tilde_p) / tilde_n * unsampled
    half = z * math.sqrt(variance)
    return rate, max(0.0, centre - half), min(1.0, centre + half)


def run_module(module: str, names: list[str], tests: list[str], floor: float) -> None:
    RESULTS.mkdir(parents=True, exist_ok=True)
    scratch = Path(tempfile.mkdtemp(prefix="fieldcal-mutants-"))
    try:
        todo = scratch / "names.txt"
        todo.write_text("\n".join(names) + "\n", encoding="utf-8")
        env = dict(os.environ, MUTANTS_NAMES=str(todo), MUTANTS_OUT=str(results_path(module).resolve()),
                   MUTANTS_FLOOR=str(floor), PYTHONPATH=str(HERE))
        command = ["nice", "-n", "19", sys.executable, "-m", "pytest", "-p", "inprocess", "-p", "no:cacheprovider",
                   "-n", "0", "-m", "not slow", "--tb=native", f"--basetemp={scratch / 'tmp'}", *tests]
        print(f"{module}: {len(names)} mutants against {' '.join(t.removeprefix('tests/') for t in tests)}",
              flush=True)
        with open(scratch / "pytest.log", "w", encoding="utf-8") as log:
            process = subprocess.Popen(command, cwd=MUTANTS, env=env, stdout=log, stderr=subprocess.STDOUT)
            RUNNING.add(process)
            process.wait()
            RUNNING.discard(process)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def tally(names: list[str], verdicts: dict[str, tuple[str, str]], equivalent: dict[str, str],
          population: int = 0) -> Counter:
    """The verdicts of `names`; `population`, when they are a sample, is the module's number of mutants."""
    counts: Counter = Counter(mutants=len(names))
    if population:
        counts["population"] = population
    for name in names:
        verdict = verdicts.get(name, ("not run", ""))[0]
        if verdict == "survived" and name in equivalent:
            verdict = "equivalent"
        counts[verdict] += 1
    return counts


def table(rows: list[tuple[str, Counter]]) -> str:
    """One line a module and one for them all; when some were sampled, also each module's "sampled
    N of M" and its kill rate's 95 % Wilson interval (of all the rows: the weighted estimate's)."""
    columns = ("mutants", "killed", "timeout", "survived", "equivalent", "no tests", "not run")
    sampled = any(counts["population"] for _, counts in rows)
    lines = [f"{'module':<28}" + "".join(f"{c:>11}" for c in columns) + f"{'killed %':>10}"
             + (f"{'sampled':>16}{'95 % interval':>16}" if sampled else "")]
    total: Counter = Counter()
    for module, counts in rows + [("all, weighted" if sampled else "all listed", None)]:
        counts = total if counts is None else counts
        if counts is not total:
            total.update(counts)
        run = counts["mutants"] - counts["not run"]
        killed = counts["killed"] + counts["timeout"]
        rate = f"{100 * killed / run:.1f}" if run else "-"
        line = f"{module:<28}" + "".join(f"{counts[c]:>11}" for c in columns) + f"{rate:>10}"
        if sampled:
            low, high = wilson_interval(killed, run)
            if counts is total:
                of = f"{counts['mutants']} of {sum(c['population'] or c['mutants'] for _, c in rows)}"
                estimate = weighted_estimate(rows)
                rate_weighted = "-" if estimate is None else f"{100 * estimate[0]:.1f}"
                low, high = (0.0, 1.0) if estimate is None else estimate[1:]
                line = line[:-10] + f"{rate_weighted:>10}"  # each module's rate weighted by its mutants
            else:
                of = f"{counts['mutants']} of {counts['population']}" if counts["population"] else "all"
            interval = f"{100 * low:.1f}–{100 * high:.1f}" if run else "-"
            if counts is not total and not counts["population"] and not counts["not run"]:
                interval = "(all run)"  # no sampling error: the rate is the module's own
            line += f"{of:>16}{interval:>16}"
        lines.append(line)
    return "\n".join(lines)


def summary(total: Counter) -> str:
    run = total["mutants"] - total["not run"]
    if not run:
        return "no mutant run yet"
    rate = (total["killed"] + total["timeout"]) / run
    real = run - total["equivalent"]
    return (f"{total['killed'] + total['timeout']} of {run} run killed: {100 * rate:.1f} % "
            f"({'meets' if rate >= GOAL else 'below'} the {100 * GOAL:.0f} % goal; "
            f"{100 * (total['killed'] + total['timeout']) / real:.1f} % of the {real} not equivalent)"
            + (f"; {total['not run']} not run yet" if total["not run"] else ""))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--modules", default="", help="globs under fieldcal/, by spaces or commas (default: all)")
    parser.add_argument("--first", type=int, default=0, help="run only a module's first N mutants")
    parser.add_argument("--sample", type=int, default=0, help="run only N of each module's mutants, a fixed "
                        "random draw, and give each kill rate with its 95 %% interval")
    parser.add_argument("--names", type=Path, help="run only the mutants this file names (one a line)")
    parser.add_argument("--again", choices=("survived", "all"), help="run these again")
    parser.add_argument("--report", action="store_true", help="only print the table of the kept verdicts")
    parser.add_argument("--tests", default="", help="test files (under tests/) to run instead of tests.toml's: "
                        "a quick first pass, its survivors then run again against the listed ones")
    parser.add_argument("--jobs", type=int, default=1, help="pytest processes per module, each on a slice")
    parser.add_argument("--floor", type=float, default=10.0, help="least CPU seconds a test may take")
    args = parser.parse_args(argv)
    if args.sample < 0:
        sys.exit(f"tools/mutation/run.py: --sample {args.sample}: a number of mutants, 1 or more (0: all)")
    if not Path("pyproject.toml").exists():
        sys.exit("tools/mutation/run.py: run it from the repository's top folder")
    listing = tomllib.loads((HERE / "tests.toml").read_text(encoding="utf-8"))
    equivalent = read_equivalent(HERE / "equivalent.txt")
    if not args.report:
        from generate import generate  # imports mutmut: only in .venv-mutants

        generate()
    modules = core_modules()
    wanted = args.modules.replace(",", " ").split()
    chosen = [m for m in modules if any(fnmatch.fnmatch(m, w) for w in wanted)] if wanted else list(modules)
    if wanted and not chosen:
        sys.exit(f"tools/mutation/run.py: --modules {args.modules!r} names no mutated module "
                 f"(they are: {', '.join(modules)})")
    rows, unlisted, survivors = [], [], []
    for module in chosen:
        names, tests = modules[module], tests_for(module, listing)
        population = len(names) if args.sample and args.sample < len(names) else 0
        if population:
            names = sample_of(module, names, args.sample)
        if args.tests and tests:
            tests = [f"tests/{name}" for name in args.tests.replace(",", " ").split()]
        if not tests:
            unlisted.append(module)
            continue
        if not args.report:
            verdicts = read_verdicts(module)
            again = {"survived": ("survived",), "all": ("survived", "no tests") + KILLED}.get(args.again or "", ())
            selected = names[:args.first] if args.first else names
            if args.names:
                listed = set(args.names.read_text(encoding="utf-8").split())
                selected = [n for n in selected if n in listed]
            todo = [n for n in selected if n not in verdicts or verdicts[n][0] in again]
            parts = [todo[i * len(todo) // args.jobs:(i + 1) * len(todo) // args.jobs] for i in range(args.jobs)]
            with ThreadPoolExecutor(args.jobs) as pool:  # neighbours stay together: their killers are shared
                list(pool.map(lambda part: run_module(module, part, tests, args.floor), filter(None, parts)))
        verdicts = read_verdicts(module)
        rows.append((module, tally(names, verdicts, equivalent, population)))
        survivors += [n for n in names if verdicts.get(n, ("",))[0] == "survived" and n not in equivalent]
    print(table(rows))
    total: Counter = sum((counts for _, counts in rows), Counter())
    print(summary(total))
    estimate = weighted_estimate(rows) if total["population"] else None
    if estimate:
        print(f"sampled: {100 * estimate[0]:.1f} % of these modules' "
              f"{sum(c['population'] or c['mutants'] for _, c in rows)} mutants estimated killed "
              f"(95 % interval {100 * estimate[1]:.1f}–{100 * estimate[2]:.1f}; each module's Wilson "
              f"interval in the table)")
    if survivors:
        RESULTS.mkdir(parents=True, exist_ok=True)
        (RESULTS / "survivors.txt").write_text("\n".join(survivors) + "\n", encoding="utf-8")
        print(f"{len(survivors)} survivors not listed as equivalent: {RESULTS / 'survivors.txt'} "
              f"(`.venv-mutants/bin/mutmut show NAME` prints one's change)")
    if unlisted:
        print(f"no tests listed in tools/mutation/tests.toml, not run: {', '.join(unlisted)}")
    return 0


if __name__ == "__main__":
    signal.signal(signal.SIGTERM, _stop)
    sys.exit(main())
