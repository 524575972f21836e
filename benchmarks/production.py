"""A simulated production run: 50 units with serials calibrated, checked against the product spec
and recorded in the unit registry; a few built out of spec, one recalibrated six months later
with its accelerometer bias drifted. Prints each calibration's verdict, ``fieldcal units``,
``fieldcal history`` of the drifting unit, and the time it took.

    python benchmarks/production.py                      # 50 units, field-18 at 250 Hz
    python benchmarks/production.py --procedure tests/faults/quick.yaml --rate 50 -j 2
    python benchmarks/production.py --registry postgresql://line@db-host/fieldcal

The calibrations run in -j processes; the registry is written by this one (as a line's stations
would write theirs), so the registry figure is the time to record the line's files again in a
new registry (records/s).
"""
from __future__ import annotations

import argparse
import datetime
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--units", type=int, default=50)
    parser.add_argument("--out-of-spec", type=int, default=3)
    parser.add_argument("--procedure", default="field-18")
    parser.add_argument("--rate", type=float, default=250.0, help="Hz")
    parser.add_argument("-j", "--jobs", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--spec", default=str(ROOT / "configs" / "specs" / "paper-mimu.yaml"))
    parser.add_argument("--registry", help="default: a new SQLite file in a temporary directory")
    args = parser.parse_args()

    from fieldcal.acceptance import load_spec
    from fieldcal.cli.main import main as fieldcal
    from fieldcal.procedure.positions import load_procedure
    from fieldcal.registry import Registry
    from fieldcal.registry.backends import redact
    from fieldcal.registry.simulated_line import plan_line, run_line

    builds = plan_line(args.units, args.out_of_spec, args.seed)
    procedure = load_procedure(args.procedure)
    with tempfile.TemporaryDirectory() as tmp:
        registry = args.registry or str(Path(tmp) / "registry.sqlite")
        started = time.perf_counter()
        done = run_line(Path(tmp) / "line", registry, load_spec(args.spec), builds, procedure, args.rate,
                        args.seed, args.jobs, progress=lambda line: print(line, flush=True))
        line_s = time.perf_counter() - started
        print()
        fieldcal(["units", "--registry", registry])
        [drifting] = [b for b in builds if b.drifting]
        print()
        fieldcal(["history", drifting.serial, "--registry", registry, "--spec", args.spec])

        again = str(Path(tmp) / "again.sqlite")
        with Registry(again) as db:
            started = time.perf_counter()
            for c in done:
                db.record(c.params, c.passed, source="run")
            record_s = time.perf_counter() - started

    failed = sum(not c.passed for c in done)
    print(f"\n{datetime.date.today().isoformat()} {platform.node()}: {os.cpu_count()} cores, CPython "
          f"{platform.python_version()}; registry {redact(registry)}")
    print(f"{len(builds)} units, {len(done)} calibrations ({procedure.name} at {args.rate:g} Hz, "
          f"{args.jobs} processes): {line_s:.1f} s, {line_s / len(done):.2f} s per calibration")
    print(f"{failed} FAIL ({args.out_of_spec} built out of spec, 1 drifted), {len(done) - failed} PASS")
    print(f"registry (SQLite): {len(done)} records in {record_s * 1e3:.0f} ms, "
          f"{len(done) / record_s:.0f} records/s")
    expected_failures = args.out_of_spec + 1
    return 0 if failed == expected_failures else 1


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT))
    raise SystemExit(main())
