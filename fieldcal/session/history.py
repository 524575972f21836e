"""The previous calibration of the same unit: the newest parameter file among sibling sessions.

Sessions live side by side under one directory (``--out``); a unit is known by the device name
and serial its parameter files carry. A file that cannot be read is passed over (and counted):
an old or damaged session must not stop today's results from showing.

The file found is checked against the SHA-256 its session's log recorded when it was written: a
hand-edited file still loads (its values are consistent), but it is no longer what the
calibration produced, and the operator is told so.
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

from fieldcal.paramfile import ParameterFile, ParameterFileError, load
from fieldcal.session.capture import PARAMETERS, SessionError

VERIFIED = "verified"
EDITED = "edited after calibration"
UNRECORDED = "unverified"  # no session log, or the log recorded no checksum for this file


@dataclass(frozen=True)
class PreviousCalibration:
    path: Path
    parameters: ParameterFile
    check: str = UNRECORDED  # VERIFIED, EDITED or UNRECORDED

    @property
    def edited(self) -> bool:
        return self.check == EDITED

    def describe(self) -> str:
        """One line for the operator: where it is, and whether it is what was calibrated."""
        text = f"the previous calibration of this unit, {self.path}"
        if self.check == EDITED:
            return text + " (EDITED AFTER CALIBRATION: its SHA-256 differs from the one its session recorded)"
        if self.check == UNRECORDED:
            return text + " (not verified: its session recorded no checksum for it)"
        return text


def recorded_check(path: Path, record=None) -> str:
    """VERIFIED if ``path`` has the SHA-256 its session's log recorded for it, EDITED if not,
    UNRECORDED when there is no readable log or it names no such file. ``record``: the
    session's ``RunRecord`` where the caller has it (else it is read)."""
    from fieldcal.session.record import RunRecord

    try:
        reader = record if record is not None else RunRecord.open(path.parent, log_only=True)
        # parameters.yaml is a copy of the newest numbered file, which the log names instead
        docs = [d for d in reader.documents("parameters") if d["file"] == path.name
                or path.name == PARAMETERS]
    except (SessionError, OSError):
        return UNRECORDED
    if not docs:
        return UNRECORDED
    try:
        actual = hashlib.sha256(path.read_bytes()).hexdigest()
    except OSError:
        return UNRECORDED
    return VERIFIED if actual == docs[-1]["sha256"] else EDITED


def calibrated_at(path: Path) -> int:
    """When the session of ``path`` first calibrated (ns): its first numbered parameter file's
    modification time. A re-solve writes a newer numbered file and ``parameters.yaml`` again, but
    the unit was measured when the session ran, so re-solving an old session must not make it
    the unit's newest calibration. (Sessions from before numbered files: parameters.yaml's.)"""
    numbered = [p.stat().st_mtime_ns for p in path.parent.glob("parameters-*.yaml")]
    return min(numbered) if numbered else path.stat().st_mtime_ns


def previous_calibration(sessions: Path, device_name: str | None, device_serial: str | None,
                         exclude: Path | None = None) -> tuple[PreviousCalibration | None, int]:
    """The parameter file under ``sessions/*/`` of this unit's (model and serial; none without a
    serial) newest calibration, by when its session first calibrated (see ``calibrated_at``),
    other than ``exclude``'s, with its checksum verified; and how many unreadable parameter
    files were passed over."""
    if device_name is None or device_serial is None or not Path(sessions).is_dir():
        return None, 0  # a unit without a serial is never taken for another's: no drift
    skip = Path(exclude).resolve() if exclude is not None else None
    candidates, unreadable = [], 0
    for path in Path(sessions).glob(f"*/{PARAMETERS}"):
        if skip is not None and path.parent.resolve() == skip:
            continue
        try:
            pf = load(path)
            stamp = calibrated_at(path)
        except (ParameterFileError, OSError):
            unreadable += 1
            continue
        p = pf.provenance
        if p.device_name == device_name and p.device_serial == device_serial:
            candidates.append((stamp, str(path), pf))
    if not candidates:
        return None, unreadable
    _, newest, pf = max(candidates)
    return PreviousCalibration(Path(newest), pf, recorded_check(Path(newest))), unreadable
