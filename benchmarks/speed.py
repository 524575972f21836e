"""Time per solve of one triad on the 18 positions of field-18: Powell and the least-squares
cross-check, with the full covariance of the averages (as the station solves) and without.

    python benchmarks/speed.py [--repeats 30]
"""
from __future__ import annotations

import argparse
import os
import platform
import time

import fieldcal  # noqa: F401  (first: its one-BLAS-thread default applies only before numpy loads)
import numpy as np

from fieldcal.run.simcal import run_simulated_calibration
from fieldcal.solvers import solve_norm


def median_ms(fn, repeats: int) -> tuple[float, float, float]:
    fn()  # warm caches and imports
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    q1, med, q3 = np.percentile(times, [25, 50, 75]) * 1e3
    return med, q1, q3


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=30)
    args = parser.parse_args(argv)
    cal = run_simulated_calibration(seed=1)
    print(f"{platform.node()}: {os.cpu_count()} cores, {platform.processor() or platform.machine()}, "
          f"CPython {platform.python_version()}; median of {args.repeats} solves (IQR)")
    print("| triad | equations | weights | method | time per solve | evaluations |")
    print("|---|---|---|---|---|---|")
    for name in ("accelerometer", "gyroscope"):
        problem = cal.problems[name]
        for weights, cov in (("full covariance", cal.covariances[name]), ("none", None)):
            for method in ("powell", "lsq"):
                sol = solve_norm(problem, cov, method=method)
                med, q1, q3 = median_ms(lambda: solve_norm(problem, cov, method=method), args.repeats)
                print(f"| {name} | {len(problem.residual_labels)} | {weights} | {method} | "
                      f"{med:.1f} ms ({q1:.1f}-{q3:.1f}) | {sol.diagnostics.evaluations} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
