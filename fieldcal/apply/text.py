"""A recording's text file in an import map's layout, read block by block by polars' CSV reader
(``polars.read_csv`` on whole lines, ``block_bytes`` of text at a time, whatever the file's
length): the columns read (the time and the triads calibrated; other columns may hold anything)
as float64 numpy arrays.

What is read, and what is refused (a one-line :class:`TextError` naming the file and line):

- Lines before the first sample (column names, ``Fs,100`` metadata, comments) are skipped; the
  first sample is the first line with a number in every column read. Named columns are found
  in the header line as ``fieldcal import`` finds them.
- After it, blank lines and comment lines are skipped; every other line is a sample and must
  have as many fields as the first one, with a finite number in every column read. A line that
  does not (a short or long line, text, ``nan``) stops the read with its line number: apply
  never drops or guesses a sample.
- A last line with no line end is a recording cut off mid-write (its last number may be cut
  short): refused before anything is read.
- Blank-separated files (``delimiter: null``) have their runs of blanks made single spaces,
  block by block (numpy), before polars splits them on a space; other files have the blanks
  around their fields taken off (``1004, 1 ,2``), as ``fieldcal import`` does.
- A ``"`` is text, as ``fieldcal import`` reads it (never a quoted field over many lines), and
  polars must give one row per sample line: a block it reads otherwise is refused.

A block polars cannot read whole (a blank or comment line, or a fault) is read again without its
blank and comment lines; only if that fails too is the file scanned line by line, from the last
good block, to name the line (the line polars refuses, found by halving the block, where the
line check finds no fault).
"""
from __future__ import annotations

import math
import re
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from drivers.protocols.delimited import ChannelMap
from fieldcal.recording.import_map import FileSpec
from fieldcal.recording.importer import HEADER_SEARCH_BYTES, HEADER_SEARCH_LINES, header_fields

# what polars reads as a double (quotes are no quotes here: ``"`` is text, as fieldcal import reads it)
_PLAIN_NUMBER = re.compile(rb'[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?')
_LINES = re.compile(rb"[^\n]*\n|[^\n]+\Z")  # with their line ends, as file iteration gives them
_LF, _CR = 10, 13
_TAIL_BYTES = 1 << 16


class TextError(ValueError):
    """One line: the file, the line number where known, what is wrong and what to do."""

    def __init__(self, message: str, path: str, line: int | None = None):
        super().__init__(message)
        self.path, self.line = path, line


@dataclass(frozen=True)
class Layout:
    """How the file's samples are read: the resolved channel map, the (role, column) read (the
    time and the triads calibrated: other columns may hold anything), where the first sample
    starts (byte offset, and how many lines come before it), and its number of fields."""

    channel_map: ChannelMap
    roles: tuple[tuple[str, int], ...]
    start: int
    lines_before: int
    fields: int

    @property
    def squeezed(self) -> bool:
        return self.channel_map.delimiter is None

    def split(self, line: bytes) -> list[bytes]:
        return split_fields(self.channel_map, line)

    def skipped(self, line: bytes) -> bool:
        """A line that is no sample and no fault: blank, or a comment with another number of
        fields than a sample (a comment line with as many fields as a sample is read as one,
        and refused)."""
        text = line.strip(b" \t\r\n")
        comment = self.channel_map.comment
        return not text or (comment is not None and text.startswith(comment.encode("ascii"))
                            and len(self.split(line)) != self.fields)

    def fault(self, line: bytes) -> str | None:
        """Why a sample line cannot be read, or None if it can."""
        fields = self.split(line)
        if len(fields) != self.fields:
            return f"{len(fields)} fields where the first sample has {self.fields}"
        for role, column in self.roles:
            field = fields[column].strip(b" \t")
            if not _PLAIN_NUMBER.fullmatch(field) or not math.isfinite(float(field)):
                shown = field.decode("utf-8", "replace")
                return f"{role} (column {column + 1}) is {shown!r}, not a finite number" if shown \
                    else f"{role} (column {column + 1}) is empty"
        return None


def split_fields(cm: ChannelMap, line: bytes) -> list[bytes]:
    line = line.rstrip(b"\r\n")
    return line.split() if cm.delimiter is None else line.split(cm.delimiter.encode("ascii"))


def layout(path: str, spec: FileSpec, triads, temperature: bool = False) -> Layout:
    """Read the start of the file (and its end): the resolved channel map and the first sample;
    TextError for a file with no sample near its start or cut off mid-line. ``triads``: the
    names of the triads read; ``temperature``: read the map's temperature column too (a
    thermal model needs it; else it is not read, and may hold anything)."""
    with open(path, "rb") as fh:
        head = fh.read(HEADER_SEARCH_BYTES)
        fh.seek(0, 2)
        size = fh.tell()
        fh.seek(max(size - _TAIL_BYTES, 0))
        tail = fh.read()
    cm = spec.resolve(header_fields(head, spec, path), path) if spec.channel_map is None else spec.channel_map
    roles = tuple((role, c) for role, c in cm.columns
                  if role == "time" or (temperature and role == "temperature") or role.rsplit(".", 1)[0] in triads)
    complete = head if size <= len(head) else head[:head.rfind(b"\n") + 1]
    offset = 0
    for number, line in enumerate(_LINES.findall(complete)[:HEADER_SEARCH_LINES], 1):
        probe = Layout(cm, roles, offset, number - 1, len(split_fields(cm, line)))
        if max(c for _, c in roles) < probe.fields and not probe.skipped(line) and probe.fault(line) is None:
            _check_ending(path, tail, cm)
            return probe
        offset += len(line)
    raise TextError(f"apply: {path}: no sample of {spec.name} in its first {HEADER_SEARCH_LINES} lines (a line "
                    f"with a number in every column read: {', '.join(r for r, _ in roles)}); "
                    "check the map's delimiter and columns", path)


def _check_ending(path: str, tail: bytes, cm: ChannelMap) -> None:
    last = tail[tail.rfind(b"\n") + 1:]
    text = last.strip(b" \t\r")
    if text and not (cm.comment and text.startswith(cm.comment.encode("ascii"))):
        line = _count_lines(path) + 1
        raise TextError(f"apply: {path}: line {line}: the last line has no line end: the recording was cut "
                        f"off mid-write and its last number may be cut short ({last[:60].decode('utf-8', 'replace')!r}); "
                        "delete the line, or end it with a newline if it is whole", path, line)


def _count_lines(path: str) -> int:
    with open(path, "rb") as fh:
        return sum(block.count(b"\n") for block in iter(lambda: fh.read(1 << 22), b""))


def read_blocks(path: str, lay: Layout, block_bytes: int) -> Iterator[np.ndarray]:
    """(n, k) float64 per block: the columns read, in ``lay.roles`` order."""
    import polars as pl

    cm = lay.channel_map
    read = [c for _, c in lay.roles]
    last, beyond = lay.fields - 1, lay.fields
    # Every field of a sample typed (the columns read as doubles, the others left as text), and
    # one field more: a line with more fields than a sample puts text there, a shorter one
    # leaves its last field null (as an empty last field does: told apart line by line).
    schema = {f"f{i}": pl.Float64 if i in read else pl.String for i in range(beyond + 1)}
    shown = sorted({*read, last, beyond})
    # quote_char=None: a ``"`` in any field is text, never the start of a field over many lines
    options = dict(has_header=False, separator=" " if lay.squeezed else cm.delimiter, schema=schema,
                   columns=shown, missing_columns="insert", quote_char=None)
    numbers = [f"f{c}" for c in read]

    def parsed(block: bytes, lines: int, fields_checked: bool = False) -> np.ndarray | None:
        """The block's samples, or None if a line may not be a plain sample (or polars did not
        give one row per line: a sample is never dropped or merged unseen)."""
        try:
            try:
                frame = pl.read_csv(block, **options)
            except pl.exceptions.ComputeError:  # maybe other bytes than UTF-8 in a column not read
                # (``25\xb0C``), which fieldcal import reads: lossy only then (it costs ~10 %)
                frame = pl.read_csv(block, **options, encoding="utf8-lossy")
        except pl.exceptions.PolarsError:  # a field read that is no number
            return None
        if len(frame) != lines:
            return None
        nulls = dict(zip(frame.columns, frame.null_count().row(0)))
        long_line = nulls[f"f{beyond}"] != len(frame)
        short_line = nulls[f"f{last}"] > 0 and not fields_checked
        if long_line or short_line or any(nulls[n] for n in numbers):
            return None
        values = frame.select(numbers).to_numpy()
        return values if np.isfinite(values).all() else None

    rows = 0
    with open(path, "rb") as fh:
        fh.seek(lay.start)
        for block in _whole_lines(fh, block_bytes):
            block = squeeze_blanks(block) if lay.squeezed else strip_padding(block, cm.delimiter)
            values = parsed(block, block.count(b"\n") + (not block.endswith(b"\n")))
            if values is None:  # without its blank and comment lines, or line by line
                lines = [line for line in _LINES.findall(block) if not lay.skipped(line)]
                kept = b"".join(lines)
                values = parsed(kept, len(lines)) if kept else np.zeros((0, len(read)))
                if values is None and not any(lay.fault(line) for line in lines):
                    values = parsed(kept, len(lines), fields_checked=True)  # empty last fields, not missing ones
                if values is None:  # the first line polars cannot read alone, by halving
                    lo, hi = 0, len(lines)
                    while hi - lo > 1:
                        mid = (lo + hi) // 2
                        if parsed(b"".join(lines[lo:mid]), mid - lo, fields_checked=True) is None:
                            hi = mid
                        else:
                            lo = mid
                    raise _bad_line(path, lay, rows, rows + lo)
            rows += len(values)
            yield values


def _whole_lines(fh, block_bytes: int) -> Iterator[bytes]:
    """The file from where it stands, ``block_bytes`` or so at a time, each block ending at a
    line's end (a line longer than a block is read on to its end); the last as the file ends."""
    rest = b""
    while True:
        data = fh.read(block_bytes)
        if not data:
            if rest:
                yield rest
            return
        data = rest + data
        cut = data.rfind(b"\n") + 1
        if cut == 0:
            data += fh.readline()
            cut = len(data)
        rest = data[cut:]
        yield data[:cut]


def _bad_line(path: str, lay: Layout, from_row: int, unread_row: int) -> TextError:
    """The first sample line at or after sample ``from_row`` that cannot be read, or else the
    line of sample ``unread_row`` (the one polars could not read: the file is read again from
    the first sample, line by line: only ever on the way to an error)."""
    row = 0
    with open(path, "rb") as fh:
        fh.seek(lay.start)
        for number, line in enumerate(fh, lay.lines_before + 1):
            if lay.skipped(line):
                continue
            if row >= from_row:
                why = lay.fault(line)
                if why is not None or row == unread_row:
                    shown = line.rstrip(b"\r\n")[:60].decode("utf-8", "replace")
                    why = why or "not read as a sample by the CSV reader"
                    return TextError(f"apply: {path}: line {number}: {why} ({shown!r}); fix or delete the line",
                                     path, number)
            row += 1
    line = lay.lines_before + 1 + row
    return TextError(f"apply: {path}: line {line}: the file changed while it was read; apply it again",
                     path, line)


def strip_padding(block: bytes, delimiter: str) -> bytes:
    """Blanks (spaces, tabs) around each field taken off, as fieldcal import takes them
    (``1004, 1 ,2``); blanks inside a field kept, so ``1 2`` stays no number (vectorised; a
    block with no blank, the usual logger's output, is returned as it is)."""
    if b" " not in block and b"\t" not in block:
        return block
    a = np.frombuffer(block, dtype=np.uint8)
    sep = ord(delimiter)
    blank = ((a == 32) | (a == 9)) & (a != sep)
    index = np.arange(len(a))
    before = np.maximum.accumulate(np.where(blank, -1, index))  # the last byte no blank, at or before
    after = np.minimum.accumulate(np.where(blank, len(a), index)[::-1])[::-1]  # the next, at or after
    padded = np.concatenate([a, [_LF]])
    at_start = (before < 0) | (padded[before] == sep) | (padded[before] == _LF)
    at_end = (padded[after] == sep) | (padded[after] == _LF) | (padded[after] == _CR)
    drop = blank & (at_start | at_end)
    return a[~drop].tobytes() if drop.any() else block


def squeeze_blanks(block: bytes) -> bytes:
    """Runs of spaces and tabs as one space, none at the start or end of a line (vectorised;
    a block already so, the usual logger's output, is returned as it is)."""
    a = np.frombuffer(block, dtype=np.uint8)
    if not len(a):
        return block
    blank = (a == 32) | (a == 9)
    line_end = (a == _LF) | (a == _CR)
    follows_blank_or_line = np.empty_like(blank)
    follows_blank_or_line[0] = True
    np.logical_or(blank[:-1], a[:-1] == _LF, out=follows_blank_or_line[1:])
    drop = blank & follows_blank_or_line  # all of a run but its first blank; a line's leading run
    drop[:-1] |= blank[:-1] & line_end[1:]  # a run's last blank before a line's end
    drop[-1] |= blank[-1]
    if not drop.any():
        return block.replace(b"\t", b" ")
    kept = a[~drop]
    # a run's first blank, kept above, may now stand just before a line's end
    blank = (kept == 32) | (kept == 9)
    trailing = np.append(blank[:-1] & ((kept[1:] == _LF) | (kept[1:] == _CR)), blank[-1:])
    kept = kept[~trailing]
    kept[kept == 9] = 32
    return kept.tobytes()
