"""Calibrated output from a recording: text in (an import map's layout), CSV out, in blocks.

Each input file is read ``block_bytes`` at a time by polars' CSV reader
(:mod:`fieldcal.apply.text`: the columns read as float64 arrays; a malformed line stops the
read with its line number), every triad the parameter file calibrates is corrected as
``Calibration.calibrate`` does, K⁻¹(raw − bias) into SI units, by one numpy product over the
whole block, and the block is written by polars' CSV writer before the next is read: memory
stays bounded by the block, whatever the recording's length. A triad with a thermal model is
corrected at each sample's temperature, read from the map's temperature column
(:mod:`fieldcal.apply.thermal`: what is done without one, or outside the model's range). Every
number is written in the fewest digits that read back to the same double (``1.004``,
``-0.12345678901234567``): nothing is rounded off. polars is imported only when apply runs.
"""
from __future__ import annotations

import io
import itertools
import os
import stat
from dataclasses import dataclass
from typing import BinaryIO, Iterator

import numpy as np

BLOCK_BYTES = 4 << 20  # text read (and memory held) at a time


@dataclass(frozen=True)
class Plan:
    """What one input file gives: the calibrations of its triads, in the map's column order."""

    path: str
    file_spec: object  # fieldcal.recording.import_map.FileSpec
    calibrations: tuple  # Calibration per triad written
    skipped: tuple[str, ...]  # the file's triads the parameter file does not calibrate
    rate_hz: float | None = None  # the sample rate of a file with no time column
    hold_temperature_edge: bool = False  # correct samples outside a thermal range at its nearest edge

    def columns(self) -> list[str]:
        return output_columns(self.calibrations)


def output_columns(calibrations) -> list[str]:
    """The CSV's columns: t_s, then x, y, z of each triad in its SI unit."""
    return ["t_s"] + [f"{c.name}_{axis}_{c.input_unit}" for c in calibrations for axis in "xyz"]


def write_block(out: BinaryIO, names: list[str], t: np.ndarray, values: np.ndarray) -> None:
    """One block of rows (t (n,), values (n, 3·triads)) as CSV lines, written whole."""
    import polars as pl

    # polars writes each double in the fewest digits that read back to it bit for bit (Ryu).
    # Formatted into memory, then written by Python: a closed pipe (``| head``) is then
    # Python's BrokenPipeError, which the command takes as the reader's choice.
    text = io.BytesIO()
    pl.DataFrame(dict(zip(names, [t, *values.T]))).write_csv(text, include_header=False)
    write_all(out, text.getbuffer())


def write_all(out: BinaryIO, data) -> None:
    """All of ``data``: an unbuffered stream (``python -u``, PYTHONUNBUFFERED) writes only part
    of it when a signal (Ctrl-C) interrupts a write to a full pipe, and says how much."""
    view = memoryview(data)
    while view:
        view = view[out.write(view) or 0:]


def plan(parameters, import_map, paths, rate_hz: float | None = None,
         hold_temperature_edge: bool = False) -> list[Plan]:
    """One Plan per input file; one-line errors for a wrong number of files, a triad whose map
    unit is not the unit it was calibrated in, or a file with nothing to calibrate. ``rate_hz``
    (else the map's) times a file with no time column; ``hold_temperature_edge``: see Plan."""
    if len(paths) != len(import_map.files):
        n = len(import_map.files)
        raise ValueError(f"apply: {import_map.path} expects {n} file{'s' * (n != 1)} "
                         f"({', '.join(import_map.file_names)}), got {len(paths)}")
    if rate_hz is not None and all(spec.has_time for spec in import_map.files):
        raise ValueError(f"apply: --rate: {import_map.path}'s files have a time column, and their own times "
                         "are written: leave --rate out")
    plans = []
    for path, spec in zip(paths, import_map.files):
        _require_regular_file(os.fspath(path))
        cals, skipped = calibrations_for(parameters, spec.units, os.fspath(path), f"{import_map.path}: ",
                                         "give a map with unit {unit!r} (and the matching scale)")
        plans.append(Plan(os.fspath(path), spec, cals, skipped, rate_hz or spec.rate_hz, hold_temperature_edge))
    return plans


def _require_regular_file(path: str) -> None:
    """A pipe, /dev/stdin from a pipe, a device: refused in one line (its start and end are read
    before its samples, and a faulty line is found by reading it again). A file that does not
    exist is left to the reader's own error."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return
    if not stat.S_ISREG(mode):
        raise ValueError(f"apply: {path}: not a regular file (a pipe or a device): apply reads a file "
                         "more than once; save the text to a file and give that")


def calibrations_for(parameters, units: dict[str, str], source: str, where: str, fix: str) -> tuple[tuple, tuple]:
    """The parameter file's calibrations of the triads ``units`` names (name: the unit it is
    read in), in that order, and the names it has no calibration of. One-line errors naming
    ``where`` for a triad read in another unit than it was calibrated in (``fix``: what to do,
    ``{unit}`` the calibrated unit), and ``source`` when it has nothing to calibrate."""
    cals, skipped = [], []
    for name, unit in units.items():
        if name not in parameters.names:
            skipped.append(name)
            continue
        cal = parameters.triad(name)
        if unit != cal.output_unit:
            raise ValueError(f"apply: {where}triad {name!r} is read in {unit!r} but was calibrated in "
                             f"{cal.output_unit!r}; {fix.format(unit=cal.output_unit)}")
        cals.append(cal)
    if not cals:
        raise ValueError(f"apply: {source}: none of its triads ({', '.join(units)}) is in the parameter "
                         f"file ({', '.join(parameters.names)})")
    return tuple(cals), tuple(skipped)


def not_calibrated_lines(parameters) -> list[str]:
    """One line per triad with parameters the data did not determine (issue 27): they hold their
    nominal values (no bias, no misalignment, the unit's own scale), so K⁻¹(raw − bias) corrects
    only what was calibrated and passes the rest through as read."""
    return [f"apply: {t.name}: {', '.join(t.not_calibrated)} not calibrated: applied at their nominal values "
            f"(no correction); only {', '.join(t.calibrated) or 'nothing'} corrected"
            for t in parameters.triads if t.not_calibrated]


def calibrated_blocks(p: Plan, block_bytes: int = BLOCK_BYTES,
                      outside=None) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """(t (n,) in s, calibrated (n, 3·triads) in SI units) per block of the file. ``outside``
    (a ``thermal.OutsideCount``) counts the samples outside a thermal model's range; without
    ``p.hold_temperature_edge`` the first such sample stops the file (TemperatureOutside, once
    the rest of the file is counted, for the line to say how many)."""
    from fieldcal.apply.text import layout, read_blocks
    from fieldcal.apply.thermal import OutsideCount, TemperatureOutside, offsets_and_ratios, thermal_names

    if not p.file_spec.has_time and p.rate_hz is None:
        raise ValueError(f"apply: {p.path}: {p.file_spec.name} has no time column: give its sample rate "
                         f"(--rate HZ, or rate_hz in the map's {p.file_spec.where or 'entry'})")
    thermal = bool(thermal_names(p.calibrations)) and p.file_spec.has_temperature
    lay = layout(p.path, p.file_spec, [c.name for c in p.calibrations], temperature=thermal)
    cm = lay.channel_map
    slot = {role: i for i, (role, _) in enumerate(lay.roles)}
    scale, bias, inverse = _affine(p.calibrations, cm, slot)
    rows = {c.name: [slot[f"{c.name}.{axis}"] for axis in "xyz"] for c in p.calibrations}
    outside = OutsideCount() if outside is None else outside
    first = 0
    blocks = read_blocks(p.path, lay, block_bytes)
    for v in blocks:
        n = len(v)
        t = _seconds(v[:, slot["time"]], cm.time_scale) if cm.time_column is not None \
            else (first + np.arange(n)) / p.rate_hz
        first += n
        raw = v * scale - bias
        outside.samples += n
        temperature = v[:, slot["temperature"]] * cm.temperature_scale if thermal else None
        terms = offsets_and_ratios(p.calibrations, rows, len(slot), temperature, p.hold_temperature_edge,
                                   outside, p.path)
        if outside.counts and not p.hold_temperature_edge:  # refused: the rest read only to count
            for rest in blocks:
                outside.samples += len(rest)
                offsets_and_ratios(p.calibrations, rows, len(slot), rest[:, slot["temperature"]]
                                   * cm.temperature_scale, False, outside, p.path)
            raise TemperatureOutside(outside.line(p.path, p.calibrations, held=False))
        if terms is not None:  # K(T)⁻¹(raw − bias(T)) = K⁻¹((raw − b₀ − Σbₖ ΔTᵏ) / (1 + s₁ΔT))
            raw = (raw - terms[0]) / terms[1]
        # einsum's own loop, not BLAS: OpenBLAS spreads a (n, 7)·(7, 6) product over threads
        # that cost 10-25 times its CPU on a busy machine. Computed column by column (the
        # transpose returned is a view), so each output column is contiguous for the writer.
        yield t, np.einsum("nk,km->mn", raw, inverse).T


def _affine(calibrations, cm, slot) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``Calibration.calibrate`` of every triad, K⁻¹(text·scale − bias), as one product for the
    whole block: (scale (k,), bias (k,) per column read, K⁻¹ (k, 3·triads) block by block).
    The bias is taken off in the raw unit, as calibrate does: folded into an offset after K⁻¹
    it would cancel against counts of 32768 and lose 8 digits."""
    scale, bias = np.zeros(len(slot)), np.zeros(len(slot))
    inverse = np.zeros((len(slot), 3 * len(calibrations)))
    for j, cal in enumerate(calibrations):
        rows = [slot[f"{cal.name}.{axis}"] for axis in "xyz"]
        scale[rows], bias[rows] = cm.triads[cal.name].scale, cal.bias
        inverse[np.ix_(rows, range(3 * j, 3 * j + 3))] = np.linalg.inv(cal.K).T
    return scale, bias, inverse


def _seconds(time: np.ndarray, scale: float) -> np.ndarray:
    """Text time in seconds; divided by 1000 (not times 0.001) for ms, so that 1004 ms is the
    double nearest 1.004 s, as the text meant."""
    per_second = 1.0 / scale
    return time / per_second if per_second > 1 and per_second == round(per_second) else time * scale


def apply_file(p: Plan, out: BinaryIO, block_bytes: int = BLOCK_BYTES, warn=None) -> int:
    """Write ``p``'s calibrated CSV to ``out``; the number of samples written. ``warn(line)``
    (if given) is told once, at the end, how many sample times repeat or go back: every
    sample is written all the same, in the file's order (apply never drops one); and, for a
    thermal model, that it is applied at its reference temperature (the map names no
    temperature column; said first) or how many samples were held at its range's edge."""
    from fieldcal.apply.thermal import MAP_HINT, OutsideCount, at_reference_line, thermal_names

    names = p.columns()
    if warn is not None and thermal_names(p.calibrations) and not p.file_spec.has_temperature:
        warn(at_reference_line(p.calibrations, p.path, MAP_HINT))
    outside = OutsideCount()
    blocks = calibrated_blocks(p, block_bytes, outside)
    first = next(blocks, None)  # a file refused at its start (no sample, cut off) writes nothing
    write_all(out, (",".join(names) + "\n").encode("ascii"))
    n, not_forward, last = 0, 0, None
    for t, values in itertools.chain([first] if first is not None else [], blocks):
        write_block(out, names, t, values)
        not_forward += int(np.count_nonzero(np.diff(t if last is None else np.r_[last, t]) <= 0))
        last = t[-1] if len(t) else last
        n += len(t)
    held = outside.line(p.path, p.calibrations, held=True)
    if held and warn is not None:
        warn(held)
    if not_forward and warn is not None:
        warn(f"apply: {p.path}: {not_forward} sample time{'s' * (not_forward != 1)} repeat or go back "
             "(t_s not increasing); every sample is written, in the file's order")
    return n
