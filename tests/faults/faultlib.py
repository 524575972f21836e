"""Helpers of the fault-injection tests: the command as a user runs it, the quick procedure."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
QUICK = Path(__file__).resolve().parent / "quick.yaml"
SEED = 3


def fieldcal(*argv: str, timeout: float = 300) -> subprocess.CompletedProcess:
    """The command as a user runs it; never a traceback, whatever happens."""
    proc = subprocess.run([sys.executable, "-m", "fieldcal.cli.main", *map(str, argv)], cwd=ROOT,
                          capture_output=True, text=True, timeout=timeout)
    assert "Traceback" not in proc.stderr, proc.stderr
    return proc


def run_argv(out: Path) -> list[str]:
    return ["run", "--headless", "--quiet", "--seed", str(SEED), "--procedure", str(QUICK), "--out", str(out)]
