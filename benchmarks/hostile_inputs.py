"""Hostile inputs to `fieldcal import` (issue 25, items 14-15): time and peak memory per refusal.

For each format fieldcal reads (CSV/text, ArduPilot .BIN, PX4 .ulg, ROS 1 .bag): the first 64 KiB
of a real file of that format, then holes up to 2 GB (a sparse file). Also a real CSV followed by
NULs written out (no holes: a logger's pre-allocated file), SIZE_NUL_MB of them, which is read to
be measured. And a valid recording followed by SIZE_JUNK_MB of "x" lines, and by as many blank
lines (a logger gone wrong): refused once the lines that are no sample pass 100,000 and the
samples. Last, for scale, a valid CSV of VALID_SAMPLES samples, which imports (exit 0): its peak
RSS against its size shows what the text reader holds per sample. Each import runs in its own process; its wall time and peak RSS (wait4's rusage) are
printed. Exits 1 when a hostile one is not refused with exit status 2 and one line, takes more than
BUDGET_S or peaks above BUDGET_RSS_MB.

    python benchmarks/hostile_inputs.py
"""
from __future__ import annotations

import datetime
import gzip
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REAL = Path(__file__).resolve().parent.parent / "tests" / "data" / "real"
SPARSE_SIZE = 2 << 30
SIZE_NUL_MB = 512
SIZE_JUNK_MB = 256
VALID_SAMPLES = 2_000_000
BUDGET_S = 10.0
BUDGET_RSS_MB = 300.0
FORMATS = {".csv": ("mpu6050_tomisuarez_calibration.csv.gz", ("--map", "single-csv")),
           ".BIN": ("pymavlink_test.BIN.gz", ()), ".ulg": ("px4_sample_log_small.ulg.gz", ()),
           ".bag": ("robot_localization_test2.bag.gz", ())}


def timed_import(path: Path, extra, out: Path) -> tuple[int, str, float, float]:
    """(exit status, stderr, wall s, peak RSS MiB) of `fieldcal import path` in a child."""
    started = time.perf_counter()
    child = subprocess.Popen([sys.executable, "-m", "fieldcal.cli.main", "import", str(path), *extra,
                              "--out", str(out)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    err = child.stderr.read().decode()
    _, status, usage = os.wait4(child.pid, 0)
    child.returncode = os.waitstatus_to_exitcode(status)
    return child.returncode, err, time.perf_counter() - started, usage.ru_maxrss / 1024


def _valid_csv(samples: int) -> bytes:
    """A recording in the single-csv map's columns: ms, mg and °/s."""
    rows = "".join(f"{i * 10},{0.01 * i:.3f},0,1000,0.5,0,0\n" for i in range(samples))
    return ("time_ms,ax_mg,ay_mg,az_mg,gx_dps,gy_dps,gz_dps\n" + rows).encode()


def main() -> int:
    failed = False
    print(f"hostile inputs, {datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC, "
          f"budget {BUDGET_S:g} s and {BUDGET_RSS_MB:g} MiB each")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        cases = []
        for suffix, (name, extra) in FORMATS.items():
            path = tmp / f"sparse{suffix}"
            path.write_bytes(gzip.decompress((REAL / name).read_bytes())[:1 << 16])
            os.truncate(path, SPARSE_SIZE)
            cases.append((f"2 GB sparse {suffix}", path, extra))
        nul = tmp / "nul-tail.csv"
        with open(nul, "wb") as f:
            f.write(gzip.decompress((REAL / FORMATS[".csv"][0]).read_bytes()))
            block = bytes(1 << 20)
            for _ in range(SIZE_NUL_MB):
                f.write(block)
        cases.append((f"CSV + {SIZE_NUL_MB} MB of NULs", nul, FORMATS[".csv"][1]))
        for label, line in (("x", b"x\n"), ("blank", b"\n")):
            junk = tmp / f"junk-{label}.csv"
            with open(junk, "wb") as f:
                f.write(_valid_csv(20000))
                block = line * ((1 << 20) // len(line))
                for _ in range(SIZE_JUNK_MB):
                    f.write(block)
            cases.append((f"CSV + {SIZE_JUNK_MB} MB of {label} lines", junk, ("--map", "single-csv")))
        for i, (label, path, extra) in enumerate(cases):
            status, err, seconds, rss = timed_import(path, extra, tmp / f"out{i}")
            ok = status == 2 and err.count("\n") == 1 and seconds <= BUDGET_S and rss <= BUDGET_RSS_MB
            failed |= not ok
            print(f"  {label:24} exit {status}, {seconds:5.2f} s, peak RSS {rss:6.1f} MiB "
                  f"{'ok' if ok else 'OVER BUDGET'}: {err.strip()[:110]}")
            path.unlink()
        valid = tmp / "valid.csv"
        valid.write_bytes(_valid_csv(VALID_SAMPLES))
        size = valid.stat().st_size / 2**20
        status, err, seconds, rss = timed_import(valid, ("--map", "single-csv"), tmp / "out-valid")
        failed |= status != 0
        print(f"  valid CSV, {VALID_SAMPLES:,} samples, {size:.0f} MiB: exit {status}, {seconds:5.2f} s, "
              f"peak RSS {rss:6.1f} MiB ({(rss - 50) * 2**20 / VALID_SAMPLES:.0f} B a sample above ~50 MiB "
              f"of interpreter){': ' + err.strip()[:110] if status else ''}")
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
