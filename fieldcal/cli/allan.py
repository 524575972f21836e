"""``fieldcal allan``: noise terms and a recommended dwell from a still record.

The record is a session (the samples of its static dwells, not the handling between them) or a
text file of rows ``t, x, y, z`` (time in s, one triad in SI units, comma or whitespace
separated, ``#`` comments). The dwell to recommend is the shortest averaging time whose Allan
deviation is within 5 % of the curve's minimum: past it, longer averaging buys almost nothing.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from fieldcal.allan import allan_deviation, noise_terms, plot_allan, regular_stretches
from fieldcal.model import SI_UNIT

NEAR_MINIMUM = 1.05


def model_deviation(terms, taus: np.ndarray) -> np.ndarray:
    """The IEEE 952 model through the fitted terms: white, flicker floor and rate random walk."""
    var = terms.white**2 / taus + (0.664 * terms.bias_instability) ** 2
    if terms.rate_random_walk is not None:
        var = var + terms.rate_random_walk**2 * taus / 3.0
    return np.sqrt(var)


def recommended_dwell(taus: np.ndarray, terms: list) -> tuple[float, bool]:
    """Shortest τ at which every axis's fitted curve is within 5 % of its lowest value over the
    record; and whether that lowest value is a real floor (False: still falling at the end)."""
    worst, floor_seen = 0.0, True
    for t in terms:
        model = model_deviation(t, taus)
        low = int(np.argmin(model))
        worst = max(worst, float(taus[np.argmax(model <= NEAR_MINIMUM * model[low])]))
        floor_seen &= low < len(taus) - 1
    return worst, floor_seen


def _session_records(record) -> tuple[dict[str, np.ndarray], dict[str, str], float]:
    """The samples of a procedure run's longest static dwell (``record``: its ``RunRecord``)."""
    # After a resume, sample time starts over from the last checkpoint, so the samples of a
    # dwell are those of the run segment (between resumes) that recorded its step.
    counted = {s.line: s.record for s in record.steps}  # checked, and still counted after resumes
    segment, best = 0, None
    for doc in record.documents("resume", "step"):
        if doc["type"] == "resume":
            segment += 1
            continue
        for w in counted[doc["seq"] + 1].windows if doc["seq"] + 1 in counted else ():
            if w.kind == "static" and (best is None or w.duration > best[1].duration):
                best = (segment, w)
    if best is None:
        raise ValueError(f"{record.directory}: no completed static dwell to analyse")
    wanted, window = best
    lo, hi = window.start, window.end
    parts: dict[str, list[np.ndarray]] = {}
    segment = 0
    for kind, chunk in record.replay_items(("chunk", "resume")):
        if kind == "resume":
            segment += 1
            continue
        if segment != wanted:
            continue
        keep = (chunk.t >= lo) & (chunk.t < hi)
        if keep.any():
            for name, values in chunk.triads.items():
                parts.setdefault(name, []).append(values[keep])
    kinds = {n: t["kind"] for n, t in record.start["simulation_truth"].items()}
    return {n: np.concatenate(v) for n, v in parts.items()}, kinds, record.spec.rate_hz


def _text_record(path: Path, kind: str) -> tuple[dict[str, np.ndarray], dict[str, str], float]:
    """The rows of a text record, read as import reads a recording: refused at once if it is no
    regular file or mostly zeros, measured a block at a time (UTF-8, line lengths) before numpy
    reads it from the file, so that memory follows the rows, not the file's bytes."""
    import warnings

    from fieldcal.recording.importer import check_line_lengths
    from fieldcal.recording.inputs import check_input

    check_input(path, "still record")
    first_row = _checked_text(path, check_line_lengths)
    if first_row is None:
        raise ValueError(f"{path}: no data (expected at least 100 rows of 4 numbers 't, x, y, z')")
    delimiter = "," if "," in first_row else None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # said below in our words, not numpy's
            table = np.loadtxt(path, delimiter=delimiter, comments="#", ndmin=2, encoding="utf-8")
    except ValueError as exc:
        raise ValueError(f"{path}: expected rows of 4 numbers 't, x, y, z' ({str(exc).splitlines()[0]})") from None
    if len(table) == 0:
        raise ValueError(f"{path}: no data (expected at least 100 rows of 4 numbers 't, x, y, z')")
    if table.shape[1] != 4 or len(table) < 100:
        raise ValueError(f"{path}: expected at least 100 rows of 4 numbers 't, x, y, z', "
                         f"got {len(table)} rows of {table.shape[1]}")
    if not np.all(np.isfinite(table)):
        row = int(np.argmax(~np.all(np.isfinite(table), axis=1)))
        raise ValueError(f"{path}: data row {row + 1} holds nan or inf; cut the record around it")
    dt = np.diff(table[:, 0])
    if np.any(dt <= 0):
        raise ValueError(f"{path}: time (first column) must increase on every row "
                         f"(row {int(np.argmax(dt <= 0)) + 2} does not)")
    stretches, breaks = regular_stretches(table[:, 0])
    longest = max(stretches, key=lambda s: s.seconds)
    if breaks:
        print(f"{path}: the time column has {'; '.join(breaks)}; analysing data rows "
              f"{longest.start + 1}-{longest.stop} ({longest.seconds:.0f} s at {longest.rate_hz:.4g} Hz), "
              "the longest evenly sampled stretch")
        if longest.stop - longest.start < 100:
            raise ValueError(f"{path}: no evenly sampled stretch of 100 rows or more (the time column "
                             f"has {'; '.join(breaks[:3])}{'; ...' if len(breaks) > 3 else ''})")
    name = "gyroscope" if kind == "angular_rate" else "accelerometer"
    return {name: table[longest.start: longest.stop, 1:]}, {name: kind}, longest.rate_hz


def _checked_text(path: Path, check_line_lengths) -> str | None:
    """The first row that is neither blank nor a comment (None: there is none), after the whole
    file is checked a block at a time: UTF-8, and no line longer than a recording's."""
    import codecs

    decoder = codecs.getincrementaldecoder("utf-8")()
    first_row, done = None, 0

    def blocks(f):
        nonlocal first_row, done
        while block := f.read(1 << 20):
            held = len(decoder.getstate()[0])  # the end of the last block, a character cut in two
            try:
                text = decoder.decode(block)
            except UnicodeDecodeError as exc:  # its offset: within the bytes held and this block
                at = done - held + exc.start
                raise ValueError(f"{path}: not a text record (not UTF-8 at byte {at}; expected rows "
                                 "'t, x, y, z')") from None
            if first_row is None:  # the first block that holds one, usually the first
                first_row = next((line for line in text.splitlines()[:-1] or text.splitlines()
                                  if line.strip() and not line.lstrip().startswith("#")), None)
            done += len(block)
            yield block

    with open(path, "rb") as f:
        check_line_lengths(blocks(f), str(path))
    try:
        decoder.decode(b"", final=True)
    except UnicodeDecodeError:
        raise ValueError(f"{path}: not a text record (it ends inside a UTF-8 character; expected rows "
                         "'t, x, y, z')") from None
    return first_row


def cmd_allan(args) -> int:
    source = Path(args.source)
    from fieldcal.session import LOG
    if (source / LOG).is_file() and not args.plot_dir:  # plots go into the session: its one writer, or refused
        from fieldcal.session.lock import SessionLock
        lock = SessionLock.acquire(source)
        try:
            return _allan(args, source)
        finally:
            lock.release()
    return _allan(args, source)


def _allan(args, source: Path) -> int:
    if source.is_dir():
        from fieldcal.cli.sessions import warn_if_torn
        from fieldcal.run.runner import open_run
        record = open_run(source)  # one scan; every step document checked: file, line and field
        warn_if_torn(record)
        records, kinds, rate = _session_records(record)
        plot_dir = source
    elif source.is_file():
        records, kinds, rate = _text_record(source, args.kind)
        plot_dir = source.parent
    elif source.exists():  # /dev/zero, a FIFO: said what it is, never read (a device never ends)
        from fieldcal.atomic import file_kind
        raise ValueError(f"{source}: is {file_kind(source.stat().st_mode)}, not a session directory nor a "
                         "recording file")
    else:
        raise ValueError(f"{source}: no such session directory or file")
    from fieldcal.atomic import check_target, directory_for_files
    for name in records:  # every plot refused (a link, an earlier plot without --force) before the work
        if not args.triad or name in args.triad:
            check_target(Path(args.plot_dir or plot_dir) / f"allan-{name}.png", force=args.force)
    for name, samples in records.items():
        if args.triad and name not in args.triad:
            continue
        kind = kinds[name]
        taus, adev, clusters = allan_deviation(samples, rate)
        terms = [noise_terms(taus, adev[:, i], unit=SI_UNIT[kind], n_clusters=clusters) for i in range(3)]
        print(f"{name}: {len(samples)} samples at {rate:g} Hz ({len(samples) / rate / 3600:.2f} h)")
        for axis, t in zip("xyz", terms):
            print(f"  {axis}: " + ", ".join(f"{k} {v}" for k, v in t.describe(kind).items()))
        dwell, floor_seen = recommended_dwell(taus, terms)
        note = "" if floor_seen else "; the deviation still falls at the record's end, so a longer record may recommend more"
        print(f"  recommended dwell: {dwell:.0f} s (where the fitted deviation is within "
              f"{100 * (NEAR_MINIMUM - 1):.0f} % of its lowest{note})")
        # a folder the user names is created, never through a link; the default (the session, or
        # the recording's folder) is the input's own and exists
        folder = directory_for_files(args.plot_dir, "--plot-dir") if args.plot_dir else Path(plot_dir)
        path = folder / f"allan-{name}.png"
        plot_allan(taus, adev, terms, path, title=f"{name}: Allan deviation", kind=kind, overwrite=args.force)
        print(f"  plot: {path}")
    return 0
