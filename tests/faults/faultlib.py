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


def run_argv(out: Path, procedure: Path) -> list[str]:
    """The run of the shared session (conftest.py quick_session: ``procedure`` is its quick_procedure)."""
    return ["run", "--headless", "--quiet", "--seed", str(SEED), "--procedure", str(procedure), "--out", str(out)]


def unit_parameter_file(path: Path) -> Path:
    """A hand-built parameter file at ``path``: an identity accelerometer (g) and gyroscope
    (rad/s), every σ 1e-6, as the classic method writes one."""
    import numpy as np

    from fieldcal.calibration import Calibration
    from fieldcal.earth import Station
    from fieldcal.paramfile import ParameterFile, save

    triads = [Calibration(name=name, kind=kind, output_unit=unit, method="classic", K=np.eye(3),
                          bias=np.zeros(3), sigma=np.full(9, 1e-6), residual_rms=0.0)
              for name, kind, unit in (("accelerometer", "specific_force", "g"),
                                       ("gyroscope", "angular_rate", "rad/s"))]
    return save(ParameterFile.build(triads, station=Station(40.0, 50.0), procedure="classic-12",
                                    method="classic", input_sha256="b" * 64), path)
