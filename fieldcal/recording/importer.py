"""Text recordings -> :class:`Recording`: one file per import-map entry, on one time base.

Each file is parsed in one vectorised pass by ``drivers.protocols.delimited`` (its ChannelMap
is built from the map entry). On top of the parser this module decides what a *recording*
needs that a live stream does not:

- Lines that do not parse are malformed: counted, and their 1-based line numbers reported,
  never used. The parser calls a line with no number in any mapped field a "header" line; only
  those before the first sample are taken as a header, later ones (binary junk, a stray text
  line) are malformed too. Text lines before the first sample that do not parse (metadata such
  as ``Fs,100``) are header lines as well. A last line with no line end is malformed: a log cut
  off mid-write ends so, and its last number may be cut short.
- Columns named in the map are found in the header line (the first text line before the data
  that holds every name). A file with no time column gets ``t = i / rate_hz``, the rate from
  the map or the caller (``--rate``). A file with more than 1 % malformed lines imports with a warning;
  a file with fewer than two valid samples is an error.
- Time must increase strictly: a repeated or backwards timestamp is an error naming the file
  and line (dropping samples silently would hide a logger fault). Gaps longer than five median
  sample periods are reported.
- Several files are put on the first file's timestamps, restricted to the time all files
  cover; a file on exactly those timestamps is copied bit for bit, any other is interpolated
  linearly (np.interp per axis). An overlap shorter than half the shortest file is an error:
  the files are not from one run, or not on one clock.
"""
from __future__ import annotations

import hashlib
import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from drivers.protocols.delimited import DelimitedTextParser
from fieldcal.recording import Recording
from fieldcal.recording.errors import RecordingImportError
from fieldcal.recording.containers import ContainerError, is_container, text_of
from fieldcal.recording.import_map import FileSpec, ImportMap, load_import_map

FIRST_FEW = 10  # malformed line numbers kept per file
HEADER_SEARCH_LINES, HEADER_SEARCH_BYTES = 200, 1 << 16  # where a header line with column names may be
MALFORMED_WARNING = 0.01  # fraction of a file's data lines
# No IMU output reaches this in any unit (a 32-bit count is 2.1e9): a bigger value is a corrupted
# line, and left in it would overflow the variances that find the poses.
MAX_READING = 1e12
GAP_PERIODS = 5.0  # a step in time longer than this many median periods is a gap
MIN_OVERLAP = 0.5  # of the shortest file's duration
FEED_BYTES = 1 << 18  # text parsed at once
# Lines that are no sample (blank, comment, text, malformed) a file may hold before it is refused
# for them: past this, once they outnumber the samples read so far. A valid recording followed
# by megabytes of junk or blank lines (a logger gone wrong) is refused there, in a second,
# instead of every junk line being kept and parsed line by line (issue 25: 20 MB of "x" lines
# took 5 GB).
NON_SAMPLE_FLOOR = 100_000
PRESCAN_BYTES = 4 << 20  # a bigger text file is parsed from the file a piece at a time, never held whole
FIRST_LINES = 1 << 19  # lines the parsed arrays are first made for (32 MiB) when they are short, grown as samples come
SAMPLE_LINE_BYTES = 16  # lines averaging this long may all be samples: the arrays made for all at once
REUSE_BYTES = 1 << 22  # freed memory malloc keeps for the pieces' temporaries (_let_malloc_keep)
# No recording's line comes near this (a sample is some 100 bytes): a longer line is no recording,
# and parsed it would take ~6x its length (issue 25: a 150 MB line took 900 MB, or MemoryError).
LONGEST_LINE = 1 << 16
LINE_CHECK_BYTES = 1 << 20  # read at once while lines are measured
_CONTROL = re.compile("[\x00-\x08\x0a-\x0c\x0e-\x1f\x7f]")  # all but tab and CR


@dataclass(frozen=True)
class FileReport:
    """What was read from one file of a recording: its lines, samples, rate and gaps."""
    path: str
    name: str  # the map entry's name
    sha256: str  # of the bytes parsed (a text file's NUL end is not)
    lines: int
    samples: int
    header_lines: int  # skipped before the first sample
    malformed: int
    malformed_lines: tuple[int, ...]  # the first FIRST_FEW, 1-based
    rate_hz: float  # median
    t_first: float
    t_last: float
    gaps: int  # steps longer than GAP_PERIODS median periods
    largest_gap_s: float  # largest step in time (a gap if gaps > 0)
    largest_gap_line: int  # the line after that step
    cut_off: bool = False  # the last line had no line end: malformed, not used
    item: str = "line"  # what is counted: a text file's lines, a log's samples (messages)
    zero_tail: int = 0  # NUL bytes that end the file (a pre-allocated logger file's unused end), not read

    @property
    def malformed_fraction(self) -> float:
        return self.malformed / max(self.samples + self.malformed, 1)


@dataclass(frozen=True)
class ImportReport:
    """How a recording was imported: the map, each file's report, the alignment done."""
    map_path: str
    map_text: str
    files: tuple[FileReport, ...]
    alignment: tuple[str, ...]  # what was done to put the files on one time base
    warnings: tuple[str, ...]


@dataclass
class _Parsed:
    """One file as parsed, before the files are put on one time base."""
    spec: FileSpec
    report: FileReport
    t: np.ndarray
    triads: dict[str, np.ndarray]
    period: float  # the median step of t


def import_recording(paths, import_map: ImportMap | str | os.PathLike, rate_hz: float | None = None) -> Recording:
    """The recording in ``paths`` (one per map entry, in order); see the module docstring.
    ``rate_hz``: the sample rate of files with no time column (overrides the map's)."""
    return import_with_report(paths, import_map, rate_hz)[0]


def import_with_report(paths, import_map: ImportMap | str | os.PathLike,
                       rate_hz: float | None = None) -> tuple[Recording, ImportReport]:
    """As import_recording, with what was found and done (for the summary and the session)."""
    im = import_map if isinstance(import_map, ImportMap) else load_import_map(import_map)
    paths = [os.fspath(p) for p in ([paths] if isinstance(paths, (str, os.PathLike)) else paths)]
    if len(paths) != len(im.files):
        n = len(im.files)
        raise RecordingImportError(f"{Path(im.path).name} expects {n} file{'s' * (n != 1)} "
                                   f"({', '.join(im.file_names)}), got {len(paths)}")
    resolved = [os.path.realpath(p) for p in paths]
    for i, p in enumerate(resolved):
        if p in resolved[:i]:
            raise RecordingImportError(f"{paths[i]}: given twice (for {im.files[resolved.index(p)].name} "
                                       f"and {im.files[i].name})", paths[i])
    parsed = [_read(path, spec, rate_hz) for path, spec in zip(paths, im.files)]
    t, triads, alignment = _align(parsed)
    warnings = tuple(
        f"{p.report.path}: {p.report.malformed} of {p.report.samples + p.report.malformed} data lines "
        f"({100 * p.report.malformed_fraction:.1f} %) are malformed and were not used: check the file "
        "and the map (delimiter, columns)" for p in parsed if p.report.malformed_fraction > MALFORMED_WARNING)
    kinds = {name: kind for p in parsed for name, kind in p.spec.kinds.items()}
    units = {name: unit for p in parsed for name, unit in p.spec.units.items()}
    recording = Recording(t=t, triads=triads, kinds=kinds, units=units, sources=tuple(paths),
                          malformed={p.report.path: (p.report.malformed, p.report.malformed_lines)
                                     for p in parsed})
    if t is parsed[0].t:  # the first file's timestamps as they are: its median rate is the recording's, found once
        recording.__dict__["rate_hz"] = parsed[0].report.rate_hz  # (the cached_properties' own slots)
        recording.__dict__["period_s"] = parsed[0].period  # and the period its stages are handed
    report = ImportReport(map_path=im.path, map_text=im.text, files=tuple(p.report for p in parsed),
                          alignment=tuple(alignment), warnings=warnings)
    return recording, report


def header_fields(data: bytes, spec: FileSpec, path: str) -> list[str]:
    """The fields of the first text line that holds every column name of ``spec``."""
    delimiter = spec.channels["delimiter"]
    comment = spec.channels["comment"]
    for line in data[:HEADER_SEARCH_BYTES].decode("utf-8", "replace").splitlines()[:HEADER_SEARCH_LINES]:
        if comment and line.lstrip().startswith(comment):
            continue
        fields = [f.strip() for f in (line.split() if delimiter is None else line.split(delimiter))]
        if all(name in fields for name in spec.names):
            return fields
    raise RecordingImportError(
        f"{path}: no header line names the columns {', '.join(spec.names)} of {spec.name} (in its first "
        f"{HEADER_SEARCH_LINES} lines); check the names and the delimiter in the map, or give column numbers", path)


def _read(path: str, spec: FileSpec, rate_hz: float | None = None) -> _Parsed:
    from fieldcal.recording.inputs import check_input, zero_tail

    check_input(path, f"{spec.name} recording")  # a FIFO, a device, a file of zeros: one line, at once
    _let_malloc_keep(REUSE_BYTES)  # before the bytes and the temporaries of the count and the pieces
    try:
        with open(path, "rb") as f:
            container = is_container(f.read(8))
            # a pre-allocated file's NUL end: not read, not held, said (a container's zeros are its own)
            size, zeros = (os.fstat(f.fileno()).st_size, 0) if container else zero_tail(path)
            if not container:
                f.seek(0)
                n_ends = check_line_lengths(_blocks(f, size - zeros), path)  # before the text is held or parsed
            streamed = not container and size - zeros > PRESCAN_BYTES
            f.seek(0)
            data = f.read(HEADER_SEARCH_BYTES if streamed else size - zeros)
    except OSError as exc:
        raise RecordingImportError(f"{path}: cannot read {spec.name} ({exc.strerror or exc})", path) from None
    if streamed:  # parsed a piece at a time from the file, never held whole: junk refused in bounded memory
        text: _Text = _FileText(path, spec.name, size - zeros)
    else:
        sha256 = hashlib.sha256(data).hexdigest()  # of the file as it is, compressed or a MAT-file
        try:
            data = text_of(data, path, spec)
        except ContainerError as exc:
            raise RecordingImportError(str(exc), path) from None
        if container:  # the text inside: measured as it is, a block at a time (no copy)
            view = memoryview(data)
            n_ends = check_line_lengths((view[lo:lo + LINE_CHECK_BYTES] for lo in range(0, len(data), LINE_CHECK_BYTES)),
                                        path)
        text = _HeldText(data)
    cm = spec.resolve(header_fields(data, spec, path), path) if spec.channel_map is None else spec.channel_map
    del data  # the head, or the text (the held source keeps it)
    rate_hz = rate_hz or spec.rate_hz
    if cm.time_column is None and rate_hz is None:
        raise RecordingImportError(f"{path}: {spec.name} has no time column: give its sample rate "
                                   f"(--rate HZ, or rate_hz in the map's {spec.where or 'entry'})", path)
    comment = cm.comment.encode("ascii") if cm.comment else None
    n_lines = n_ends
    # Every malformed and header line's number is needed below: taken after each piece (at most a line a byte),
    # and the rule on non-sample lines bounds their count.
    parser = DelimitedTextParser(cm, keep_malformed=max(min(n_lines, FEED_BYTES), 1))
    # Line numbers of the samples: the lines that are not blank, not comments, not malformed and
    # not header lines, in order (the parser returns values, not where they came from).
    t, triads, candidates, malformed, headers = _parse_pieces(parser, text.pieces(), cm.comment, n_lines, path,
                                                              size - zeros if streamed else len(text.held()))
    if streamed:
        sha256 = text.sha256()
    # A last line with no line end was cut off mid-write (its last number may be cut short): it
    # is not parsed, and counts as malformed.
    tail = text.tail().strip(b" \t\r")
    unterminated = bool(tail) and not (comment and tail.startswith(comment))
    n = len(t)
    rest = np.setdiff1d(candidates, malformed, assume_unique=True) if len(malformed) else candidates
    # cannot happen unless the parser's rules change
    if len(rest) != n + parser.header_lines or len(headers) != parser.header_lines:
        raise RuntimeError(f"{path}: line accounting disagrees with the parser "
                           f"({len(rest)} lines for {n} samples and {parser.header_lines} headers)")
    # Where each line is: needed for header and malformed lines only (a clean file has none).
    if parser.header_lines or len(malformed):
        data = text.held()
        ends = np.flatnonzero(np.frombuffer(data, dtype=np.uint8, count=text.cut) == 10)
        starts = np.r_[0, ends[:-1] + 1]
    else:
        data, starts = b"", np.zeros(0, dtype=np.int64)
        ends = starts
    lines = np.setdiff1d(rest, headers, assume_unique=True) if len(headers) else rest
    first = lines[0] if n else np.iinfo(np.int64).max
    # Text lines before the first sample are the header and metadata ("Fs,100" does not parse as
    # a sample, yet it is no fault); after it (or binary junk) a line is malformed.
    # The loop runs over the leading lines only, usually a few.
    leading = np.union1d(headers[headers < first], malformed[malformed < first])
    text = np.array([_is_header_text(data[starts[k - 1]:ends[k - 1]], cm.delimiter) for k in leading.tolist()],
                    dtype=bool)
    malformed = np.union1d(malformed[malformed > first], np.concatenate([headers[headers > first], leading[~text]]))
    header_count = int(np.count_nonzero(text))
    del data, text, starts, ends, candidates, rest  # the bytes and per-line arrays: not needed from here
    if unterminated:
        malformed = np.r_[malformed, n_ends + 1].astype(np.int64)
    if n < 2:
        what = "no valid sample" if n == 0 else f"only one valid sample (line {lines[0]})"
        raise RecordingImportError(
            f"{path}: {what} for {spec.name} in {n_ends} lines ({len(malformed)} malformed, "
            f"{header_count} header lines); check the map (delimiter, columns, time)", path)

    t = t if cm.time_column is not None else np.arange(n) / rate_hz
    dt = np.diff(t)
    back = np.flatnonzero(dt <= 0)
    if len(back):
        i = int(back[0]) + 1
        raise RecordingImportError(
            f"{path}: line {lines[i]}: time {t[i]:.9g} s is not after {t[i - 1]:.9g} s (line "
            f"{lines[i - 1]}); time must increase strictly ({len(back)} such line"
            f"{'s' * (len(back) != 1)} in the file)", path, int(lines[i]))
    for name, values in triads.items():
        if values.max() <= MAX_READING and values.min() >= -MAX_READING:  # (a NaN fails both)
            continue
        wild = np.flatnonzero(~(np.abs(values) <= MAX_READING).all(axis=1))
        if len(wild):
            i = int(wild[0])
            raise RecordingImportError(
                f"{path}: line {lines[i]}: {name} reads {_largest(values[i]):.6g} {spec.units[name]}, "
                f"beyond any sensor's range (|x| > {MAX_READING:.0e}): fix or delete the line "
                f"({len(wild)} such line{'s' * (len(wild) != 1)} in the file)", path, int(lines[i]))
    period = float(np.median(dt))
    widest = int(np.argmax(dt))
    report = FileReport(
        path=path, name=spec.name, sha256=sha256, lines=n_ends + unterminated, samples=n,
        header_lines=header_count, malformed=len(malformed),
        malformed_lines=tuple(int(x) for x in malformed[:FIRST_FEW]), rate_hz=1.0 / period,
        t_first=float(t[0]), t_last=float(t[-1]),
        gaps=int(np.count_nonzero(dt > GAP_PERIODS * period)), largest_gap_s=float(dt[widest]),
        largest_gap_line=int(lines[widest + 1]), cut_off=unterminated, zero_tail=zeros)
    return _Parsed(spec, report, t, triads, period)


def _parse_pieces(parser: DelimitedTextParser, pieces, comment: str | None, n_lines: int, path: str,
                  text_bytes: int):
    """(t, triads, the 1-based numbers of the lines that are neither blank nor comments, of the
    malformed lines and of the lines the parser calls headers, sorted) of the text's ``n_lines``
    whole lines, fed to the parser in ``pieces`` of whole lines (``_Text.pieces``): the
    temporaries are some ten times the bytes seen at once, and a piece of whole lines parses as
    it would within the file. Each piece's results go straight into arrays of the file's size
    (no list of pieces and its joined copy held at once). Refused as soon as the lines that are
    no sample break the NON_SAMPLE_FLOOR rule."""
    # Arrays of up to the file's lines, at most one sample a line: made so at once where the
    # lines are as long as samples' (``text_bytes`` of text), else for FIRST_LINES at first and
    # grown (to twice, at most to the file's lines) as the samples come: a file of 200 MB of
    # blank lines has 200 million lines and is refused long before that many would be held.
    capacity = n_lines if n_lines <= text_bytes // SAMPLE_LINE_BYTES else min(n_lines, FIRST_LINES)
    content, t, triads = np.empty(capacity, dtype=np.int64), np.empty(capacity), None
    malformed, headers = [], []
    n_content, n = 0, 0
    for piece in pieces:  # a dozen per MiB
        lines = parser.lines
        chunk = parser.feed(piece, 0.0)
        check_non_samples(parser, path)
        for numbers, kept in ((parser.malformed_line_numbers, malformed), (parser.header_line_numbers, headers)):
            if numbers:  # taken piece by piece: the parser keeps only so many
                kept.append(np.array(numbers, dtype=np.int64))
                numbers.clear()
        if parser.lines > capacity:  # every line of the piece may be content, and a sample
            capacity = min(n_lines, max(2 * capacity, parser.lines))
            content, t = _grown(content, n_content, capacity), _grown(t, n, capacity)
            triads = None if triads is None else {name: _grown(v, n, capacity) for name, v in triads.items()}
        k = 0 if chunk is None else len(chunk.t)
        if chunk is not None:
            if triads is None:
                triads = {name: np.empty((capacity, 3)) for name in chunk.triads}
            t[n:n + k] = chunk.t
            for name, values in chunk.triads.items():
                triads[name][n:n + k] = values
            n += k
        if k == parser.lines - lines:  # every line a sample: all are content
            part = np.arange(lines + 1, parser.lines + 1, dtype=np.int64)
        else:
            a = np.frombuffer(piece, dtype=np.uint8)
            end = np.flatnonzero(a == 10)
            part = lines + _content_lines(a, np.r_[0, end[:-1] + 1], end, comment)
        content[n_content:n_content + len(part)] = part
        n_content += len(part)
    malformed = np.sort(np.concatenate(malformed)) if malformed else np.zeros(0, dtype=np.int64)
    headers = np.sort(np.concatenate(headers)) if headers else np.zeros(0, dtype=np.int64)
    if triads is None:
        return np.zeros(0), {}, content[:n_content], malformed, headers
    return t[:n], {name: values[:n] for name, values in triads.items()}, content[:n_content], malformed, headers


def _grown(values: np.ndarray, used: int, capacity: int) -> np.ndarray:
    """``values``' first ``used`` rows in an array of ``capacity`` rows."""
    out = np.empty((capacity,) + values.shape[1:], dtype=values.dtype)
    out[:used] = values[:used]
    return out


class _Text:
    """A file's text for ``_parse_pieces``: its whole lines a piece at a time; then where the
    last line end is (``cut``), what follows it (``tail``) and, when line positions are needed,
    the text itself (``held``)."""

    cut: int = 0

    def pieces(self):
        raise NotImplementedError

    def tail(self) -> bytes:
        raise NotImplementedError

    def held(self) -> bytes:
        raise NotImplementedError


class _HeldText(_Text):
    """Text already in memory (a small file, or one unpacked from a container)."""

    def __init__(self, data: bytes):
        self.data = data
        self.cut = data.rfind(b"\n") + 1

    def pieces(self):
        data, cut, lo = self.data, self.cut, 0
        while lo < cut:
            hi = data.rfind(b"\n", lo, min(lo + FEED_BYTES, cut)) + 1 or data.find(b"\n", lo, cut) + 1
            yield data[lo:hi]
            lo = hi

    def tail(self) -> bytes:
        return self.data[self.cut:]

    def held(self) -> bytes:
        return self.data


class _FileText(_Text):
    """The first ``size`` bytes of a text file read a piece at a time (FEED_BYTES, cut at line
    ends), never held whole unless ``held`` is asked for; their SHA-256 made on the way. A big
    file is so parsed once, where it was scanned for junk first and parsed again once held."""

    def __init__(self, path: str, name: str, size: int):
        self.path, self.name, self.size = path, name, size
        self._digest = hashlib.sha256()
        self._tail = b""

    def pieces(self):
        carried, done = b"", 0
        try:
            with open(self.path, "rb") as f:
                while done < self.size:
                    block = f.read(min(FEED_BYTES, self.size - done))
                    if not block:
                        break
                    done += len(block)
                    self._digest.update(block)
                    end = block.rfind(b"\n") + 1
                    if end == 0:  # no line end in this block: the line goes on (LONGEST_LINE bounds it)
                        carried += block
                        continue
                    # one copy of the line's head and the block's whole lines (slicing, then
                    # adding, made two)
                    piece = b"".join((carried, memoryview(block)[:end])) if end < len(block) or carried else block
                    carried = block[end:]
                    self.cut += len(piece)
                    yield piece
        except OSError as exc:
            raise RecordingImportError(f"{self.path}: cannot read {self.name} ({exc.strerror or exc})",
                                       self.path) from None
        self._tail = carried

    def sha256(self) -> str:
        return self._digest.hexdigest()

    def tail(self) -> bytes:
        return self._tail

    def held(self) -> bytes:
        try:
            with open(self.path, "rb") as f:
                return f.read(self.size)
        except OSError as exc:
            raise RecordingImportError(f"{self.path}: cannot read {self.name} ({exc.strerror or exc})",
                                       self.path) from None


def check_non_samples(parser: DelimitedTextParser, path: str) -> None:
    """Refuse, in one line saying how many of which kind, a file whose lines read so far are
    mostly no sample: more than NON_SAMPLE_FLOOR of them, and more than its samples so far."""
    samples = parser.counters.frames
    other = parser.lines - samples
    if other <= max(NON_SAMPLE_FLOOR, samples):
        return
    blank = other - parser.malformed_lines - parser.header_lines
    raise RecordingImportError(
        f"{path}: {other} of its first {parser.lines} lines are no sample ({parser.malformed_lines} malformed, "
        f"{parser.header_lines} text with no number in the mapped columns, {blank} blank or comments) "
        f"against {samples} samples: not read further; cut the file to its samples and import that", path)


def check_line_lengths(blocks, path: str) -> int:
    """Refuse, in one line naming the line and its length, text with a line longer than
    LONGEST_LINE; else the number of line ends. ``blocks``: the text's bytes in order, a block
    at a time; memory is one block and its newline positions, whatever the lines' lengths."""
    line, since = 1, 0  # the current line's number, its bytes in earlier blocks
    for block in blocks:
        a = np.frombuffer(block, dtype=np.uint8)
        last = _last_end_if_short_lines(block, since)
        if last is not None:  # the usual text: its line ends counted, not listed
            if last >= 0:
                line += int(np.count_nonzero(a == 10))
                since = len(a) - 1 - last
            else:
                since += len(a)
        elif len(ends := np.flatnonzero(a == 10)):
            lengths = np.diff(ends, prepend=-1)  # each line's bytes in this block, its "\n" included
            lengths[0] += since
            longest = int(np.argmax(lengths))
            if lengths[longest] - 1 > LONGEST_LINE:
                _refuse_long_line(path, line + longest, int(lengths[longest]) - 1, complete=True)
            line += len(ends)
            since = len(a) - 1 - int(ends[-1])
        else:
            since += len(a)
        if since > LONGEST_LINE:  # no need to read to its end (there may be none)
            _refuse_long_line(path, line, since, complete=False)
    return line - 1


def _last_end_if_short_lines(block, since: int) -> int | None:
    """Where the last line end of ``block`` is (-1: none) when no line that ends in it is longer
    than LONGEST_LINE (``since``: bytes of its first line in earlier blocks); None when one may
    be, for the exact count to find it. From each line end, the last one at most LONGEST_LINE
    bytes on must exist: a step of a few dozen ``rfind`` calls per MiB (C's memrchr), not an
    array of every line end's position."""
    text = block if isinstance(block, bytes) else bytes(block)
    first = text.find(b"\n", 0, max(LONGEST_LINE - since + 1, 0))
    last = text.rfind(b"\n")
    if first < 0:  # no line end, or the first line too long: the exact count decides
        return -1 if last < 0 and since + len(text) <= LONGEST_LINE else None
    end = first
    while end < last:
        end = text.rfind(b"\n", end + 1, end + LONGEST_LINE + 1)
        if end < 0:
            return None
    return last


def _refuse_long_line(path: str, line: int, length: int, complete: bool) -> None:
    size = f"{length} bytes long" if complete else f"over {length} bytes long"
    raise RecordingImportError(
        f"{path}: line {line} is {size} (a recording's lines are under {LONGEST_LINE} bytes): this is no "
        "text recording, or it is damaged; cut the file to its samples and import that", path, line)


def _blocks(f, size: int):
    """The first ``size`` bytes of ``f``, LINE_CHECK_BYTES at a time."""
    done = 0
    while done < size:
        block = f.read(min(LINE_CHECK_BYTES, size - done))
        if not block:
            return
        done += len(block)
        yield block


def _let_malloc_keep(size: int) -> None:
    """Have malloc keep freed memory up to twice ``size`` for reuse, before temporaries of up to
    that size come and go.

    glibc's malloc serves blocks above 128 KiB by fresh mmaps, and gives freed memory above
    128 KiB back to the system, until a block that large is freed: from then on it keeps up to
    twice the largest one freed. So one untouched block of ``size`` is taken and given back
    (free: none of its pages is ever touched), and the temporaries of every piece reuse pages
    instead of faulting in new ones: on imu_tk's files 12,600 page faults become ~2,400
    (~14 ms CPU of a calibrate; its peak RSS ~1.5 MiB more). The setting is the process's for
    good: a long-running process that imports files (the TUI) may keep up to 8 MiB of freed
    memory mapped. Elsewhere (another malloc) this costs nothing."""
    np.empty(size, dtype=np.uint8)


def _largest(row: np.ndarray) -> float:
    return float(row[int(np.argmax(np.abs(row)))])


def _is_header_text(line: bytes, delimiter: str | None) -> bool:
    """UTF-8 without control characters (tab and CR allowed), with a field that is no number: a
    plausible header line. A line of numbers only (too few columns for the map) is a malformed
    sample line, not a header."""
    try:
        decoded = line.decode("utf-8")
    except UnicodeDecodeError:
        return False
    if _CONTROL.search(decoded) is not None:
        return False
    fields = [f.strip() for f in (decoded.split() if delimiter is None else decoded.split(delimiter))]
    return not all(_is_number(f) for f in fields if f)


def _is_number(field: str) -> bool:
    try:
        float(field)
    except ValueError:
        return False
    return True


def _content_lines(a: np.ndarray, starts: np.ndarray, ends: np.ndarray, comment: str | None) -> np.ndarray:
    """1-based numbers of the lines that are neither blank nor comments (the parser's rules).
    Works on the starts of the runs of non-blank bytes (a few per line), not on every byte."""
    solid = ~((a == 32) | (a == 9) | (a == 13) | (a == 10))
    if len(a) == 0 or not solid.any():
        return np.zeros(0, dtype=np.int64)
    run_start = np.flatnonzero(solid[1:] & ~solid[:-1]) + 1
    if solid[0]:
        run_start = np.r_[0, run_start]
    # A line starts after a "\n": its first non-blank byte, if any, starts a run.
    j = np.searchsorted(run_start, starts)
    first = run_start[np.minimum(j, len(run_start) - 1)]
    content = (j < len(run_start)) & (first < ends)
    if comment is not None:
        prefix = np.frombuffer(comment.encode("ascii"), dtype=np.uint8)
        idx = np.minimum(first[:, None] + np.arange(len(prefix)), len(a) - 1)
        content &= ~((first + len(prefix) <= ends) & (a[idx] == prefix).all(axis=1))
    return np.flatnonzero(content).astype(np.int64) + 1


def _align(parsed: list[_Parsed]) -> tuple[np.ndarray, dict[str, np.ndarray], list[str]]:
    """One time base: the first file's timestamps within the overlap of all files."""
    base = parsed[0]
    if len(parsed) == 1:
        return base.t, dict(base.triads), []
    lo = max(float(p.t[0]) for p in parsed)
    hi = min(float(p.t[-1]) for p in parsed)
    keep = (base.t >= lo) & (base.t <= hi)
    shortest = min(float(p.t[-1] - p.t[0]) for p in parsed)
    if hi - lo < MIN_OVERLAP * shortest or np.count_nonzero(keep) < 2:
        spans = "; ".join(f"{p.report.name} {p.t[0]:.6g} .. {p.t[-1]:.6g} s" for p in parsed)
        raise RecordingImportError(
            f"the files overlap in time for only {max(hi - lo, 0.0):.6g} s ({spans}); are they from "
            "one run, on one clock, with the right time unit in the map?")
    t = _kept(base.t, keep)
    dropped = len(base.t) - len(t)
    notes = [f"time base: {base.report.name}"
             + (f", {dropped} sample{'s' * (dropped != 1)} outside the other files' time dropped" if dropped else "")]
    triads = {name: _kept(v, keep) for name, v in base.triads.items()}
    for p in parsed[1:]:
        inside = (p.t >= lo) & (p.t <= hi)
        if np.array_equal(_kept(p.t, inside), t):
            triads.update({name: _kept(v, inside) for name, v in p.triads.items()})
            notes.append(f"{p.report.name}: same timestamps, values used as they are")
        else:
            for name, v in p.triads.items():
                triads[name] = np.column_stack([np.interp(t, p.t, v[:, k]) for k in range(3)])
            notes.append(f"{p.report.name}: other timestamps ({p.report.rate_hz:.6g} Hz), "
                         "interpolated linearly onto the time base")
    return t, triads, notes


def _kept(values: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """values[keep], without a copy when every sample is kept (files from one run usually are)."""
    return values if keep.all() else values[keep]
