"""Time a command as its own process: wall and CPU time, and its peak resident memory.

``os.wait4`` returns the resource usage of exactly that child (what ``resource.getrusage
(RUSAGE_CHILDREN)`` sums over all children), so commands measured one after another do not mix.
"""
from __future__ import annotations

import os
import statistics
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

BIN = Path(sys.executable).parent
# A Python child writes its bytecode on its first (warm-up) run, as an installed package has it
# from pip: with PYTHONDONTWRITEBYTECODE set (as in some shells and CI images) an editable
# install's own modules were compiled afresh in every timed run, ~0.25 s of CPU per calibrate.
_NO_BYTECODE = "PYTHONDONTWRITEBYTECODE"


@dataclass(frozen=True)
class Run:
    wall_s: float
    cpu_s: float  # user + system
    peak_mib: float
    status: int


def run_once(argv: list[str], cwd=None) -> Run:
    started = time.perf_counter()
    env = {name: value for name, value in os.environ.items() if name != _NO_BYTECODE}
    proc = subprocess.Popen(argv, cwd=cwd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - started
    proc.returncode = os.waitstatus_to_exitcode(status)
    # ru_maxrss is in KiB on Linux.
    return Run(wall, usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 1024, proc.returncode)


@dataclass(frozen=True)
class Summary:
    label: str
    wall_s: float  # medians
    cpu_s: float
    peak_mib: float
    status: int


def side_by_side(commands: dict[str, list[str]], repeats: int, cwd=None) -> list[Summary]:
    """Every command once per round, rounds repeated: a load change hits all of them alike."""
    runs: dict[str, list[Run]] = {label: [] for label in commands}
    for _ in range(repeats):
        for label, argv in commands.items():
            runs[label].append(run_once(argv, cwd))
    return [Summary(label, statistics.median(r.wall_s for r in rs), statistics.median(r.cpu_s for r in rs),
                    max(r.peak_mib for r in rs), rs[-1].status) for label, rs in runs.items()]


def table(rows: list[Summary], reference: str) -> list[str]:
    ref = next(r for r in rows if r.label == reference)
    lines = ["| command | wall (median) | CPU (median) | peak RSS | × reference wall |", "|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r.label} | {r.wall_s:.3f} s | {r.cpu_s:.3f} s | {r.peak_mib:.0f} MiB | "
                     f"{r.wall_s / ref.wall_s:.2f} |")
    return lines
