"""Calibrated output from a recording: text in (an import map's layout), CSV out, in blocks.

Each input file is read ``block_bytes`` at a time through the import map's parser (which holds
an unfinished line back for the next block), every triad the parameter file calibrates is
corrected with ``Calibration.calibrate`` (K⁻¹(raw − bias), SI units out), and the block is
written as CSV before the next is read: memory stays bounded by the block, whatever the
recording's length. Numbers are formatted by ``fieldcal.apply.fixed`` (vectorised), not row by
row.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from typing import BinaryIO, Iterator

import numpy as np

from fieldcal.apply.fixed import format_rows

BLOCK_BYTES = 4 << 20
TIME_DECIMALS, TIME_DIGITS = 6, 10  # µs; up to 10^10 s (Unix time fits)
VALUE_DECIMALS, VALUE_DIGITS = 9, 5  # 1e-9 SI (0.0002 °/h, 0.1 ng); |x| < 10^5 m/s², rad/s


@dataclass(frozen=True)
class Plan:
    """What one input file gives: the calibrations of its triads, in the map's column order."""

    path: str
    file_spec: object  # fieldcal.recording.import_map.FileSpec
    calibrations: tuple  # Calibration per triad written
    skipped: tuple[str, ...]  # the file's triads the parameter file does not calibrate

    def header(self) -> bytes:
        cols = ["t_s"] + [f"{c.name}_{axis}_{c.input_unit}" for c in self.calibrations for axis in "xyz"]
        return (",".join(cols) + "\n").encode("ascii")


def plan(parameters, import_map, paths) -> list[Plan]:
    """One Plan per input file; one-line errors for a wrong number of files, a triad whose map
    unit is not the unit it was calibrated in, or a file with nothing to calibrate."""
    if len(paths) != len(import_map.files):
        n = len(import_map.files)
        raise ValueError(f"apply: {import_map.path} expects {n} file{'s' * (n != 1)} "
                         f"({', '.join(import_map.file_names)}), got {len(paths)}")
    plans = []
    for path, spec in zip(paths, import_map.files):
        cals, skipped = [], []
        for name in spec.channel_map.triads:
            if name not in parameters.names:
                skipped.append(name)
                continue
            cal = parameters.triad(name)
            if spec.units[name] != cal.output_unit:
                raise ValueError(f"apply: {import_map.path}: triad {name!r} is read in {spec.units[name]!r} "
                                 f"but was calibrated in {cal.output_unit!r}; give a map with unit "
                                 f"{cal.output_unit!r} (and the matching scale)")
            cals.append(cal)
        if not cals:
            raise ValueError(f"apply: {path}: none of its triads ({', '.join(spec.channel_map.triads)}) "
                             f"is in the parameter file ({', '.join(parameters.names)})")
        plans.append(Plan(os.fspath(path), spec, tuple(cals), tuple(skipped)))
    return plans


def calibrated_blocks(p: Plan, block_bytes: int = BLOCK_BYTES) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """(t (n,), calibrated (n, 3·triads)) per block of the file."""
    from drivers.protocols.delimited import DelimitedTextParser

    parser = DelimitedTextParser(p.file_spec.channel_map)
    with open(p.path, "rb") as fh:
        while True:
            data = fh.read(block_bytes)
            last = len(data) < block_bytes
            if last and data and not data.endswith(b"\n"):
                data += b"\n"  # an unterminated last line is a whole line at the end of the file
            chunk = parser.feed(data, 0.0) if data else None
            if chunk is not None and len(chunk):
                out = np.hstack([c.calibrate(chunk.triads[c.name]) for c in p.calibrations])
                yield chunk.t, out
            if last:
                return


def apply_file(p: Plan, out: BinaryIO, block_bytes: int = BLOCK_BYTES) -> int:
    """Write ``p``'s calibrated CSV to ``out``; the number of samples written."""
    out.write(p.header())
    n = 0
    for t, values in calibrated_blocks(p, block_bytes):
        out.write(format_rows([(t[:, None], TIME_DECIMALS, TIME_DIGITS),
                               (values, VALUE_DECIMALS, VALUE_DIGITS)]))
        n += len(t)
    return n
