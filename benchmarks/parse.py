"""Samples parsed per second for each wire protocol, fed in serial-sized reads.

The bytes are what the simulated device sends (encoder of each protocol, 200,000 samples of the
paper's MIMU). Reported: median of 5 passes, and the margin over a 1 kHz device.

    python benchmarks/parse.py
"""
from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np

from drivers.sim.device import paper_mimu
from drivers.sim.physics import MimuSimulator, Segment
from drivers.sim.serve import _as_device_sends, make_encoder
from fieldcal.run.devices import make_parser


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=200_000)
    parser.add_argument("--passes", type=int, default=5)
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
    return 0 if worst >= 50_000 else 1


if __name__ == "__main__":
    raise SystemExit(main())
