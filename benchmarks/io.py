"""Session and text-import speed: the figures the tests used to hold as wall-clock asserts.

Session: one hour of 250 Hz samples (three triads and a temperature, 900 chunks of 1000 samples)
written with ``SessionWriter`` and read back with ``SessionReader``. Import: ten minutes at
100 Hz in two imu_tk text files (60,000 lines each) through ``import_recording``. Best of 3.
Exits 1 when a budget is exceeded (2 s for each session direction, 0.3 s for the import).

    python benchmarks/io.py
"""
from __future__ import annotations

import os
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

from drivers.chunk import SampleChunk
from fieldcal.recording.importer import import_recording
from fieldcal.session.capture import SessionReader, SessionWriter

SESSION_BUDGET_S = 2.0
IMPORT_BUDGET_S = 0.3


def best_of(times: int, work) -> float:
    best = np.inf
    for _ in range(times):
        started = time.perf_counter()
        work()
        best = min(best, time.perf_counter() - started)
    return best


def session_times(directory: Path) -> tuple[float, float]:
    n, per = 900_000, 1000
    rng = np.random.default_rng(0)
    t = np.arange(n) / 250.0
    triads = {name: rng.standard_normal((n, 3)) for name in ("accelerometer", "gyroscope", "inclinometer")}
    temperature = rng.standard_normal(n)
    chunks = [SampleChunk(t=t[i:i + per], triads={k: v[i:i + per] for k, v in triads.items()},
                          temperature=temperature[i:i + per]) for i in range(0, n, per)]
    runs = iter(range(1000))

    def write():
        with SessionWriter.create(directory / f"s{next(runs)}", {}) as w:
            for c in chunks:
                w.chunk(c)
            w.stop("completed")

    def read():
        assert sum(len(c) for c in SessionReader(directory / "s0").chunks()) == n

    return best_of(3, write), best_of(3, read)


def write_rows(path: Path, t: np.ndarray, values: np.ndarray) -> Path:
    rows = np.column_stack([t, values]).tolist()
    path.write_text("".join("%.4f %d %d %d\n" % (r[0], *map(int, r[1:])) for r in rows))
    return path


def import_time(directory: Path) -> float:
    n = 60_000
    rng = np.random.default_rng(5)
    t = np.arange(n) * 0.01
    files = [write_rows(directory / "acc.txt", t, rng.integers(-32768, 32768, (n, 3))),
             write_rows(directory / "gyro.txt", t + 0.002, rng.integers(-32768, 32768, (n, 3)))]
    return best_of(3, lambda: import_recording(files, "imu_tk"))


def main() -> int:
    print(f"{platform.node()}: {os.cpu_count()} cores, CPython {platform.python_version()}; best of 3")
    with tempfile.TemporaryDirectory() as tmp:
        write_s, read_s = session_times(Path(tmp))
        imported_s = import_time(Path(tmp))
    print("| what | wall time | budget |")
    print("|---|---|---|")
    print(f"| write 1 h at 250 Hz (900,000 samples, 3 triads) | {write_s:.2f} s | {SESSION_BUDGET_S:g} s |")
    print(f"| read it back | {read_s:.2f} s | {SESSION_BUDGET_S:g} s |")
    print(f"| import 2 × 60,000 text lines (imu_tk) | {imported_s:.3f} s | {IMPORT_BUDGET_S:g} s |")
    ok = write_s < SESSION_BUDGET_S and read_s < SESSION_BUDGET_S and imported_s < IMPORT_BUDGET_S
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
