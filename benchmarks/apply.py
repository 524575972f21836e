"""fieldcal apply: samples calibrated per second end to end (read the text, calibrate, write the
CSV to a file), for each text layout apply reads: the single-csv map (one CSV: time, two
triads, a temperature), imu_tk (two blank-separated files, one triad each) and imucal (a CSV
with named columns and no time column). CPU seconds and wall seconds both: on a shared machine
the wall clock also counts other processes' time, CPU time does not. Target: 1 M samples/s.

    python benchmarks/apply.py [--samples 2000000] [--passes 3]
"""
from __future__ import annotations

import argparse
import datetime
import os
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

from fieldcal.apply import apply_file, calibrated_blocks, plan
from fieldcal.calibration import Calibration
from fieldcal.earth import Station
from fieldcal.paramfile import ParameterFile
from fieldcal.recording.import_map import load_import_map


def _calibration(name, kind, unit, k) -> Calibration:
    return Calibration(name=name, kind=kind, output_unit=unit, method="classic",
                       K=np.eye(3) * k + np.tril(np.full((3, 3), 1e-3), -1), bias=np.full(3, 1e-3),
                       sigma=np.zeros(9), residual_rms=0.0)


def _parameters(units: tuple[str, str]) -> ParameterFile:
    triads = [_calibration("accelerometer", "specific_force", units[0], 1 / 9.80665),
              _calibration("gyroscope", "angular_rate", units[1], 1.0)]
    return ParameterFile.build(triads, station=Station(40.0, 50.0), procedure="bench", method="classic",
                               input_sha256="0" * 64)


def _write_text(path: Path, columns: dict[str, np.ndarray], delimiter: str = ",", header: bool = True) -> None:
    """A device-like log: 6 decimals, written by polars (np.savetxt takes ~10 s for 2 M rows)."""
    import polars as pl

    frame = pl.DataFrame({name: np.round(v, 6) for name, v in columns.items()})
    frame.write_csv(path, include_header=header, separator=delimiter, quote_style="never")


def _layouts(tmp: Path, n: int, rng) -> list[tuple[str, object, list[Path], tuple[str, str]]]:
    """(label, map, files, units) of every layout, n samples each."""
    t_ms = 4.0 * np.arange(n)
    acc, gyr = rng.normal(0, 1000, (n, 3)), rng.normal(0, 50, (n, 3))
    single = tmp / "log.csv"
    _write_text(single, {"t": t_ms, **{f"a{i}": acc[:, i] for i in range(3)},
                         **{f"g{i}": gyr[:, i] for i in range(3)}, "T": np.full(n, 25.0)})
    imu_tk = [tmp / "acc.txt", tmp / "gyro.txt"]
    for path, v in zip(imu_tk, (acc, gyr)):
        _write_text(path, {"t": t_ms / 1e3, **{f"v{i}": v[:, i] for i in range(3)}}, delimiter=" ",
                    header=False)
    named = tmp / "imucal.csv"
    _write_text(named, {"gyr_x": gyr[:, 0], "gyr_y": gyr[:, 1], "gyr_z": gyr[:, 2],
                        "acc_x": acc[:, 0] / 100, "acc_y": acc[:, 1] / 100, "acc_z": acc[:, 2] / 100})
    return [("single-csv (CSV, 8 columns)", "single-csv", [single], ("g", "rad/s")),
            ("imu_tk (2 blank-separated files; a sample is a line of each)", "imu_tk", imu_tk, ("count", "count")),
            ("imucal (CSV, named columns, no time)", "imucal", [named], ("m/s^2", "deg/s"))]


def _time(plans, out_dir: Path, passes: int) -> tuple[float, float]:
    """Median wall and CPU seconds of apply over all the plans' files."""
    wall, cpu = [], []
    for _ in range(passes):
        start, start_cpu = time.perf_counter(), time.process_time()
        for i, p in enumerate(plans):
            with open(out_dir / f"out{i}.csv", "wb") as fh:
                apply_file(p, fh)
        wall.append(time.perf_counter() - start)
        cpu.append(time.process_time() - start_cpu)
    return float(np.median(wall)), float(np.median(cpu))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=2_000_000)
    parser.add_argument("--passes", type=int, default=3)
    args = parser.parse_args(argv)
    rng = np.random.default_rng(1)
    n = args.samples
    now = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    print(f"{now}, {platform.node()}: {os.cpu_count()} cores, CPython {platform.python_version()}; "
          f"{n} samples per layout, median of {args.passes}")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for label, map_name, files, units in _layouts(tmp, n, rng):
            import_map = load_import_map(map_name)  # a rate only where a file has no time column
            rate_hz = None if all(spec.has_time for spec in import_map.files) else 250.0
            plans = plan(_parameters(units), import_map, files, rate_hz=rate_hz)
            size = sum(f.stat().st_size for f in files)
            load = os.getloadavg()[0]
            wall, cpu = _time(plans, tmp, args.passes)
            print(f"{label}: {n / cpu / 1e6:.2f} M samples per CPU second, {n / wall / 1e6:.2f} M "
                  f"samples/s wall clock (load average {load:.1f}; {size / n:.0f} bytes in per sample)")
            if map_name == "single-csv":  # where the time goes
                start = time.process_time()
                for _ in calibrated_blocks(plans[0]):
                    pass
                read = time.process_time() - start
                print(f"  read + calibrate: {n / read / 1e6:.2f} M samples per CPU second; "
                      f"write: {n / max(cpu - read, 1e-9) / 1e6:.2f} M samples per CPU second")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
