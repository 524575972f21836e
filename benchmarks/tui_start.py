"""The terminal UI's start, as the operator sees it: from the command's process start to the
first frame that takes a key.

Each measured process runs the real command line (``fieldcal tui --sim`` or the setup screen's
``fieldcal tui``) through ``fieldcal.cli.main.main``, with Textual's headless driver in place of
the terminal; an auto-pilot reports once the app is ready and one more round of messages has
been processed (the first screen composed, mounted and painted), then quits. The figures are
the process's own CPU time up to that moment (``resource.getrusage``: the machine is shared, so
CPU time, not wall, is the fair measure) and the wall time from the parent's spawn; beside them,
the import of the terminal UI alone and ``python -c "import numpy"``.

    python benchmarks/tui_start.py [--repeats 5]
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

GOAL_S = 1.0

# The measured process. argv[1:] is the fieldcal command line (without "fieldcal").
CHILD = r"""
import resource, sys, time

def cpu():
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime

import textual.app

async def first_frame(pilot):
    await pilot.pause()  # the messages the first screen queued: composed, mounted, painted
    print(f"FIRST-FRAME {cpu():.4f} {time.time():.6f}", flush=True)
    pilot.app.exit(0)

_run = textual.app.App.run

def headless_run(self, **kw):
    return _run(self, headless=True, size=(120, 40), auto_pilot=first_frame)

textual.app.App.run = headless_run
from fieldcal.cli.main import main
main(sys.argv[1:])
"""

IMPORT_ONLY = r"""
import resource, time
import fieldcal.tui.app
r = resource.getrusage(resource.RUSAGE_SELF)
print(f"FIRST-FRAME {r.ru_utime + r.ru_stime:.4f} {time.time():.6f}", flush=True)
"""

NUMPY = r"""
import resource, time
import numpy
r = resource.getrusage(resource.RUSAGE_SELF)
print(f"FIRST-FRAME {r.ru_utime + r.ru_stime:.4f} {time.time():.6f}", flush=True)
"""


def measure(code: str, args: list[str], env: dict, cwd: str) -> tuple[float, float]:
    """(CPU s, wall s) of one process up to its FIRST-FRAME line."""
    started = time.time()
    proc = subprocess.run([sys.executable, "-c", code, *args], env=env, cwd=cwd, capture_output=True,
                          text=True, timeout=120)
    for line in proc.stdout.splitlines():
        if line.startswith("FIRST-FRAME "):
            _, cpu, at = line.split()
            return float(cpu), float(at) - started
    raise RuntimeError(f"{' '.join(args) or 'import'}: no first frame (exit {proc.returncode}):\n"
                       f"{proc.stdout[-2000:]}{proc.stderr[-2000:]}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="tui-start-") as home:
        # No remembered setup choice, no sessions left behind: the same start every time.
        env = {**os.environ, "XDG_CONFIG_HOME": home, "HOME": home}
        cases = {
            'python -c "import numpy"': (NUMPY, []),
            "import fieldcal.tui.app": (IMPORT_ONLY, []),
            "fieldcal tui --sim (procedure screen)": (CHILD, ["tui", "--sim", "--no-capture"]),
            "fieldcal tui (setup screen)": (CHILD, ["tui"]),
        }
        results: dict[str, list[tuple[float, float]]] = {label: [] for label in cases}
        for _ in range(args.repeats):  # interleaved: a load change hits every case alike
            for label, (code, cli) in cases.items():
                results[label].append(measure(code, cli, env, home))
    load = os.getloadavg()[0]
    print(f"{platform.node()}: {os.cpu_count()} cores, CPython {platform.python_version()}, "
          f"{datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC, load {load:.1f}; "
          f"median of {args.repeats}, interleaved")
    print("| start to first usable frame | CPU (median) | wall (median) |")
    print("|---|---|---|")
    medians = {}
    for label, runs in results.items():
        cpu = statistics.median(c for c, _ in runs)
        wall = statistics.median(w for _, w in runs)
        medians[label] = cpu
        print(f"| {label} | {cpu:.3f} s | {wall:.3f} s |")
    worst = max(medians["fieldcal tui --sim (procedure screen)"], medians["fieldcal tui (setup screen)"])
    print(f"goal (≤ {GOAL_S:g} s CPU to the first frame): {'met' if worst <= GOAL_S else 'NOT met'}")
    return 0 if worst <= GOAL_S else 1


if __name__ == "__main__":
    raise SystemExit(main())
