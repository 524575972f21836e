"""The previous calibration of the same unit: the newest parameter file among sibling sessions.

Sessions live side by side under one directory (``--out``); a unit is known by the device name
and serial its parameter files carry. A file that cannot be read is passed over (and counted):
an old or damaged session must not stop today's results from showing.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from fieldcal.paramfile import ParameterFile, ParameterFileError, load
from fieldcal.session.capture import PARAMETERS


@dataclass(frozen=True)
class PreviousCalibration:
    path: Path
    parameters: ParameterFile


def previous_calibration(sessions: Path, device_name: str | None, device_serial: str | None,
                         exclude: Path | None = None) -> tuple[PreviousCalibration | None, int]:
    """The newest (by modification time) parameter file under ``sessions/*/`` for this device,
    other than ``exclude``'s; and how many unreadable parameter files were passed over."""
    if device_name is None or not Path(sessions).is_dir():
        return None, 0
    skip = Path(exclude).resolve() if exclude is not None else None
    candidates, unreadable = [], 0
    for path in Path(sessions).glob(f"*/{PARAMETERS}"):
        if skip is not None and path.parent.resolve() == skip:
            continue
        try:
            pf = load(path)
            stamp = path.stat().st_mtime_ns
        except (ParameterFileError, OSError):
            unreadable += 1
            continue
        p = pf.provenance
        if p.device_name == device_name and p.device_serial == device_serial:
            candidates.append((stamp, str(path), pf))
    if not candidates:
        return None, unreadable
    _, path, pf = max(candidates)
    return PreviousCalibration(Path(path), pf), unreadable
