"""Samples parsed per second for each wire protocol, fed in serial-sized reads; and text
recordings read as ``fieldcal calibrate`` reads them.

The bytes are what the simulated device sends (encoder of each protocol, 200,000 samples of the
paper's MIMU). Reported: median of 5 passes, and the margin over a 1 kHz device.

Then imu_tk's Xsens recording (tests/data/real, 2 × 51,175 lines of "t x y z", 409,400 numbers):
CPU seconds of ``read_recording`` (what ``fieldcal calibrate`` and ``fieldcal import`` call),
the first call in a fresh process (as a command pays it: new memory is faulted in) as the
median of ``--processes`` processes, and later calls in one process as the median of
``--passes``; and the number conversion alone, numbers per CPU second, of
``drivers.protocols.decimals.plain_decimals`` beside ``np.fromstring`` (strtod) on the same bytes,
checked to give the same bits.

    python benchmarks/parse.py [--passes 5] [--processes 7]
"""
from __future__ import annotations

import argparse
import datetime
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from drivers.protocols.decimals import plain_decimals
from drivers.sim.device import paper_mimu
from drivers.sim.physics import MimuSimulator, Segment
from drivers.sim.serve import _as_device_sends, make_encoder
from fieldcal.recording.importer import FEED_BYTES
from fieldcal.run.devices import make_parser

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from recording import xsens_files  # noqa: E402


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=200_000)
    parser.add_argument("--passes", type=int, default=5)
    parser.add_argument("--processes", type=int, default=7)
    args = parser.parse_args(argv)
    sim = MimuSimulator(paper_mimu(), 9.8, 0.7, rate_hz=1000.0, seed=1)
    chunk = _as_device_sends(next(sim.run_segment(Segment(args.samples / 1000.0, np.eye(3)),
                                                  chunk_len=args.samples)))
    print(f"{platform.node()}: {os.cpu_count()} cores, CPython {platform.python_version()}; "
          f"{args.samples} samples, median of {args.passes} passes")
    print("| protocol | bytes/sample | read size | samples/s | × a 1 kHz device |")
    print("|---|---|---|---|---|")
    worst = np.inf
    for protocol in ("xsens", "vectornav", "delimited"):
        data = make_encoder(protocol).encode(chunk)
        for block in (4096, 65536):
            rates = []
            for _ in range(args.passes):
                p = make_parser(protocol)
                started = time.perf_counter()
                got = 0
                for i in range(0, len(data), block):
                    out = p.feed(data[i:i + block], 0.0)
                    got += len(out) if out is not None else 0
                rates.append(got / (time.perf_counter() - started))
                assert got == args.samples, f"{protocol}: parsed {got} of {args.samples}"
            rate = float(np.median(rates))
            worst = min(worst, rate)
            print(f"| {protocol} | {len(data) / args.samples:.0f} | {block // 1024} KiB | "
                  f"{rate:,.0f} | {rate / 1000:.0f}× |")
    with tempfile.TemporaryDirectory() as tmp:
        recording(xsens_files(Path(tmp)), args.passes, args.processes)
    return 0 if worst >= 50_000 else 1


# The first read_recording of a fresh process, its CPU seconds on stdout.
_FIRST_CALL = """
import sys, time
from fieldcal.cli.importing import read_recording
import fieldcal.recording.importer, fieldcal.recording.import_map, fieldcal.recording.logs
started = time.process_time()
read_recording(sys.argv[1:], "imu_tk")
print(time.process_time() - started)
"""


def recording(files: list[Path], passes: int, processes: int) -> None:
    from fieldcal.cli.importing import read_recording

    print(f"\nimu_tk's Xsens recording, 2 × 51,175 lines ({datetime.datetime.now():%Y-%m-%d %H:%M}, "
          f"load average {os.getloadavg()[0]:.2f}):")
    first = [float(subprocess.run([sys.executable, "-c", _FIRST_CALL, *map(str, files)], check=True,
                                  capture_output=True, text=True).stdout) for _ in range(processes)]
    read_recording(files, "imu_tk")
    later = []
    for _ in range(passes):
        started = time.process_time()
        read_recording(files, "imu_tk")
        later.append(time.process_time() - started)
    print("| read_recording | CPU s |")
    print("|---|---|")
    print(f"| first call in a fresh process (median of {processes}) | {statistics.median(first):.3f} |")
    print(f"| later calls (median of {passes}) | {statistics.median(later):.3f} |")
    text = b"".join(path.read_bytes() for path in files)
    pieces, lo = [], 0  # as the importer feeds them: FEED_BYTES cut at line ends
    while lo < len(text):
        hi = text.rfind(b"\n", lo, lo + FEED_BYTES) + 1
        pieces.append(text[lo:hi])
        lo = hi
    rates, reference = {}, None
    for name, convert in (("plain_decimals (Clinger fast path)", plain_decimals),
                          ("np.fromstring (strtod)", lambda b: np.fromstring(b, dtype=np.float64, sep=" "))):
        times = []
        for _ in range(passes):
            started = time.process_time()
            values = [convert(piece) for piece in pieces]
            times.append(time.process_time() - started)
        values = np.concatenate(values)
        assert reference is None or np.array_equal(values.view(np.int64), reference)
        reference = values.view(np.int64)
        rates[name] = len(values) / statistics.median(times)
    print(f"| conversion, {len(reference):,} numbers in {FEED_BYTES // 1024} KiB pieces | numbers per CPU s |")
    print("|---|---|")
    for name, rate in rates.items():
        print(f"| {name} | {rate:,.0f} |")


if __name__ == "__main__":
    raise SystemExit(main())
