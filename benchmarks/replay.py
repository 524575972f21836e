"""Replay speed: one hour of 250 Hz samples (three triads) through a fresh engine and solver.

A headless run of a one-hour still procedure makes the session once; each replay then reads the
capture, re-feeds every chunk to a new engine and solves. Median of 3.

    python benchmarks/replay.py
"""
from __future__ import annotations

import os
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

from fieldcal.earth import Station
from fieldcal.procedure.positions import parse_procedure
from fieldcal.run.replay import replay
from fieldcal.run.runner import RunSpec, open_run, run_headless

ONE_HOUR = """name: still-1h
dwell_s: 3600
positions:
  - {id: 1, description: "z-upward, x-south, y-east", axes: {x: south, y: east, z: up}}
"""


def main() -> int:
    with tempfile.TemporaryDirectory() as tmp:
        spec = RunSpec(parse_procedure(ONE_HOUR, "still-1h.yaml"), Station(40.0, 50.0), seed=1)
        run_headless(spec, Path(tmp) / "session")
        times, samples = [], 0
        for _ in range(3):
            started = time.perf_counter()
            replayed = replay(open_run(Path(tmp) / "session"))
            samples = replayed.samples
            times.append(time.perf_counter() - started)
    hours = samples / 250.0 / 3600.0
    median = float(np.median(times))
    print(f"{platform.node()}: {os.cpu_count()} cores, CPython {platform.python_version()}")
    print(f"replayed {samples} samples ({hours:.2f} h at 250 Hz, 3 triads): median {median:.2f} s "
          f"of 3 ({min(times):.2f}-{max(times):.2f} s), {samples / median / 1e6:.2f} M samples/s")
    return 0 if median / hours < 10.0 else 1


if __name__ == "__main__":
    raise SystemExit(main())
