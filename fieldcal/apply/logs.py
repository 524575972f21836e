"""Calibrated output from a flight-controller or robot log (PX4 ULog, ROS 1/2 bags, ArduPilot
DataFlash), read whole by the importer ``fieldcal import`` and ``fieldcal calibrate`` use
(:func:`fieldcal.recording.logs.import_log`: the same samples, the same times, NaN samples and
repeated timestamps dropped as it reports), then calibrated and written ``BLOCK_ROWS`` at a time.
Unlike text these formats are not streamed: the log's samples are held in memory.
"""
from __future__ import annotations

from typing import BinaryIO

import numpy as np

from fieldcal.apply import calibrations_for, output_columns, write_all, write_block

BLOCK_ROWS = 1 << 16


def apply_log(parameters, path: str, out: BinaryIO, topic: str | None = None, imu: int | None = None,
              hold_temperature_edge: bool = False, warn=None):
    """Write the log's calibrated CSV to ``out``: (samples written, the log's triads the
    parameter file does not calibrate, the import report). A triad with a thermal model is
    corrected at the log's temperature (``fieldcal.apply.thermal``: ``warn(line)`` is told when
    it has none, or of samples held at the range's edge)."""
    from fieldcal.apply.thermal import temperatures_for
    from fieldcal.recording.logs import import_log

    recording, report = import_log(path, topic, imu)
    calibrations, skipped = calibrations_for(parameters, recording.units, path, f"{path}: ",
                                             "the log holds SI units: calibrate in {unit!r} from a log")
    temperatures, line = temperatures_for(calibrations, recording.temperature, hold_temperature_edge, path)
    if line and warn is not None:
        warn(line)
    names = output_columns(calibrations)
    write_all(out, (",".join(names) + "\n").encode("ascii"))
    n = len(recording.t)
    for start in range(0, n, BLOCK_ROWS):
        rows = slice(start, start + BLOCK_ROWS)
        values = np.hstack([cal.calibrate(recording.triads[cal.name][rows], _rows(temperatures.get(cal.name), rows),
                                          extrapolate=True)  # the range is checked (or held) above
                            for cal in calibrations])
        write_block(out, names, recording.t[rows], values)
    return n, skipped, report


def _rows(temperature, rows: slice):
    """A block's temperatures: one per sample, or the one temperature of them all (or None)."""
    return temperature[rows] if np.ndim(temperature) else temperature
