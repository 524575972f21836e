"""Start-up of the ``fieldcal`` command against ``python -c "import numpy"``, side by side.

`fieldcal --help` and a command that rejects its arguments should cost at most twice numpy's
import and 60 MB: they load neither numpy nor the solvers, the simulator, the plots or the TUI
(tests/test_imports.py checks what they import; this measures what it costs).

    python benchmarks/startup.py [--repeats 15]
"""
from __future__ import annotations

import argparse
import datetime
import os
import platform
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from processes import BIN, side_by_side, table  # noqa: E402


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=15)
    args = parser.parse_args(argv)
    python, fieldcal = sys.executable, str(BIN / "fieldcal")
    commands = {
        'python -c "import numpy"': [python, "-c", "import numpy"],
        "fieldcal --help": [fieldcal, "--help"],
        "fieldcal run --seed x (rejected)": [fieldcal, "run", "--seed", "x"],
        "fieldcal calibrate --help": [fieldcal, "calibrate", "--help"],
        'python -c "pass"': [python, "-c", "pass"],
    }
    rows = side_by_side(commands, args.repeats)
    print(f"{platform.node()}: {os.cpu_count()} cores, CPython {platform.python_version()}, "
          f"{datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC, "
          f"load {os.getloadavg()[0]:.1f}; median of {args.repeats}, interleaved")
    print("\n".join(table(rows, 'python -c "import numpy"')))
    ref = rows[0]
    worst = max(rows[1:3], key=lambda r: r.wall_s)
    ok = worst.wall_s <= 2 * ref.wall_s and max(r.peak_mib for r in rows[1:3]) <= 60
    print(f"goal (≤ 2 × numpy's import, ≤ 60 MB): {'met' if ok else 'NOT met'}")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
