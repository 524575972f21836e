"""fieldcal apply: samples calibrated per second, text in (the single-csv layout: time, two
triads, a temperature), CSV out, through the same blocks as the command. Three stages timed
apart: parsing, calibrating (K⁻¹(raw − b) per triad), formatting the CSV. Target: 1 M samples/s.

    python benchmarks/apply.py [--samples 300000] [--passes 3]
"""
from __future__ import annotations

import argparse
import io
import os
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

from fieldcal.apply import TIME_DECIMALS, TIME_DIGITS, VALUE_DECIMALS, VALUE_DIGITS, apply_file, plan
from fieldcal.apply.fixed import format_rows
from fieldcal.calibration import Calibration
from fieldcal.earth import Station
from fieldcal.paramfile import ParameterFile
from fieldcal.recording.import_map import load_import_map


def _parameters() -> ParameterFile:
    triads = [Calibration(name=name, kind=kind, output_unit=unit, method="classic",
                          K=np.eye(3) * k + np.tril(np.full((3, 3), 1e-3), -1), bias=np.full(3, 1e-3),
                          sigma=np.zeros(9), residual_rms=0.0)
              for name, kind, unit, k in (("accelerometer", "specific_force", "g", 1 / 9.80665),
                                          ("gyroscope", "angular_rate", "rad/s", 1.0))]
    return ParameterFile.build(triads, station=Station(40.0, 50.0), procedure="bench", method="classic",
                               input_sha256="0" * 64)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=300_000)
    parser.add_argument("--passes", type=int, default=3)
    args = parser.parse_args(argv)
    rng = np.random.default_rng(1)
    n = args.samples
    rows = np.c_[4.0 * np.arange(n), rng.normal(0, 1000, (n, 3)), rng.normal(0, 50, (n, 3)), np.full(n, 25.0)]
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "log.csv"
        np.savetxt(path, rows, delimiter=",", fmt="%.6f", header="t,ax,ay,az,gx,gy,gz,T", comments="")
        [p] = plan(_parameters(), load_import_map("single-csv"), [path])
        totals, cpu = [], []
        for _ in range(args.passes):
            start, start_cpu = time.perf_counter(), time.process_time()
            apply_file(p, io.BytesIO())
            totals.append(time.perf_counter() - start)
            cpu.append(time.process_time() - start_cpu)
        # the stages apart, on the whole file at once
        from drivers.protocols.delimited import DelimitedTextParser
        data = path.read_bytes()
        start = time.perf_counter()
        chunk = DelimitedTextParser(p.file_spec.channel_map).feed(data, 0.0)
        parsed = time.perf_counter()
        values = np.hstack([c.calibrate(chunk.triads[c.name]) for c in p.calibrations])
        calibrated = time.perf_counter()
        format_rows([(chunk.t[:, None], TIME_DECIMALS, TIME_DIGITS), (values, VALUE_DECIMALS, VALUE_DIGITS)])
        formatted = time.perf_counter()
        stages = (parsed - start, calibrated - parsed, formatted - calibrated)
    best = n / np.median(totals)
    load = os.getloadavg()[0]
    print(f"{platform.node()}: {os.cpu_count()} cores (load average {load:.1f}), CPython "
          f"{platform.python_version()}; {n} samples, {len(data) / n:.0f} bytes each, median of {args.passes}")
    # On a shared machine the wall clock counts other processes' time too; CPU time does not.
    print(f"apply end to end: {best / 1e6:.2f} M samples/s wall clock, "
          f"{n / np.median(cpu) / 1e6:.2f} M samples per CPU second")
    for label, seconds in zip(("parse", "calibrate", "format CSV"), stages):
        print(f"  {label}: {n / seconds / 1e6:.2f} M samples/s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
