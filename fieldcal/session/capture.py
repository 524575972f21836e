"""The on-disk session: one calibration run (and its resumptions), captured append-only.

The format (log.jsonl documents, samples.bin records, durability rules, use) is specified in
docs/reference/session-format.md; change the two together.
"""
from __future__ import annotations

import functools
import hashlib
import json
import math
import os
import re
import struct
import threading
import time
import zlib
from collections.abc import Callable, Iterable, Iterator, Mapping
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Self

import numpy as np

from drivers.chunk import SampleChunk
from fieldcal.atomic import (CannotWrite, RefusedTarget, WouldOverwrite, check_target, file_kind, new_directory,
                             open_append, open_nofollow, refuse_other_names, write_atomically)
from fieldcal.session.lock import SessionLock, is_held
from fieldcal.session import LOG, SessionError  # noqa: F401 (this module's names too)

SCHEMA = "fieldcal-session/2"  # 2: every log line ends with "crc" (version 1, without, still reads)
SCHEMA_V1 = "fieldcal-session/1"
SAMPLES = "samples.bin"
PARAMETERS = "parameters.yaml"  # the current parameter file: a copy of the newest numbered one
PARAMETERS_NUMBERED = re.compile(r"parameters-(\d{3,})\.yaml")
TORN_SUFFIX = ".torn"
RAW_PREFIX, RAW_SUFFIX = "raw-", ".bin"
RECORD_MAGIC = b"FCS1"
RECORD_HEADER = struct.Struct("<4sIQQQQ")  # magic, crc32(payload), chunk seq, descriptor seq, n, payload bytes
ALIGN = 8

TIME, TRIAD, TEMPERATURE, EXTRA = "time", "triad", "temperature", "extra"
ROLES = (TIME, TRIAD, TEMPERATURE, EXTRA)
DOC_TYPES = ("start", "descriptor", "chunk", "event", "action", "step", "checkpoint", "stop",
             "resume", "raw", "parameters")
RUN_TYPES = ("chunk", "event", "action", "step", "checkpoint", "stop")  # need an active run
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")
_SHA256 = re.compile(r"[0-9a-f]{64}")


class SessionStateError(RuntimeError):
    """A writer call out of order (data after stop, data before resume, a closed writer)."""


# --------------------------------------------------------------------------------------------
# JSON


def to_plain(value: Any, where: str = "data") -> Any:
    """``value`` as plain JSON types (dict with str keys, list, str, int, float, bool, None).

    numpy arrays become (nested) lists, numpy scalars Python numbers, tuples lists. Anything else
    (and a non-string key, which JSON would silently turn into a string) is a TypeError naming
    where it is, so what is read back is exactly what was written.
    """
    if value is None or value is True or value is False:
        return value
    if isinstance(value, str):
        return str.__str__(value)
    if isinstance(value, int):
        return int(value)
    if isinstance(value, float):
        return float(value)
    if isinstance(value, np.generic):
        if isinstance(value, np.bool_):
            return bool(value)
        if isinstance(value, np.integer):
            return int(value)
        if isinstance(value, np.floating):
            return float(value)
    elif isinstance(value, np.ndarray):
        if value.dtype.kind in "biuf":
            return value.tolist()
        if value.dtype.kind == "O":
            return to_plain(value.tolist(), where)
    elif isinstance(value, Mapping):
        out = {}
        for key, item in value.items():
            if not isinstance(key, str):
                raise TypeError(f"{where}: keys must be strings, got {key!r}")
            out[str.__str__(key)] = to_plain(item, f"{where}.{key}")
        return out
    elif isinstance(value, (list, tuple)):
        return [to_plain(item, f"{where}[{i}]") for i, item in enumerate(value)]
    raise TypeError(f"{where}: a {type(value).__name__} is not JSON-able "
                    "(use dicts with string keys, lists, strings, numbers, bools, None, numpy arrays)")


# Built once: json.dumps with any option builds an encoder per call, and a run writes a line per chunk.
_ENCODER = json.JSONEncoder(ensure_ascii=True, separators=(",", ":"), allow_nan=True)


def _dumps(doc: dict) -> bytes:
    """One log line: the document's canonical JSON with ``"crc"`` (CRC-32 of that JSON) appended
    as its last key, so a reader checks the bytes exactly as written, without re-serialising."""
    body = _ENCODER.encode(doc).encode("ascii")
    return body[:-1] + b',"crc":%d}\n' % zlib.crc32(body)


_CRC_TAIL = re.compile(rb',"crc":(\d{1,10})\}$')


def _parse_line(raw: bytes, checked: bool | None) -> dict:
    """A log line as a document (without its "crc"). ``checked``: True if the session's format
    requires a checksum (version 2), None while the format is not known yet (line 1).
    ValueError (with a one-line reason) for a line that is not a valid document."""
    m = _CRC_TAIL.search(raw)
    if m is None:
        if checked:
            raise ValueError("no checksum (\"crc\") at the end of the line")
        return json.loads(raw)
    body = raw[:m.start()] + b"}"
    if zlib.crc32(body) != int(m.group(1)):
        raise ValueError("checksum mismatch: the line was changed after it was written")
    return json.loads(body)


def _data(value, where: str) -> dict:
    if not isinstance(value, Mapping):
        raise TypeError(f"{where}: expected a dict, got a {type(value).__name__}")
    return to_plain(value, where)


# --------------------------------------------------------------------------------------------
# Sample records


@dataclass(frozen=True)
class Column:
    """One column of a session's sample records: its name, role and dtype."""
    name: str
    role: str
    dtype: np.dtype

    @property
    def width(self) -> int:
        return 3 if self.role == TRIAD else 1

    def block_bytes(self, n: int) -> int:
        raw = n * self.width * self.dtype.itemsize
        return -(-raw // ALIGN) * ALIGN

    def to_doc(self) -> dict:
        return {"name": self.name, "role": self.role, "dtype": self.dtype.str}


def _payload_bytes(columns: tuple[Column, ...], n: int) -> int:
    return sum(c.block_bytes(n) for c in columns)


def _column_array(values, what: str, ndim: int) -> np.ndarray:
    a = np.asarray(values)
    if a.dtype.kind not in "biuf":
        raise TypeError(f"chunk {what}: expected a numeric array, got dtype {a.dtype}")
    if a.ndim != ndim:
        raise ValueError(f"chunk {what}: expected {ndim} dimension(s), got shape {a.shape}")
    return np.ascontiguousarray(a, dtype=a.dtype.newbyteorder("<"))


def _chunk_columns(chunk: SampleChunk) -> list[tuple[Column, np.ndarray]]:
    cols = [("t", TIME, _column_array(chunk.t, "t", 1))]
    cols += [(str(name), TRIAD, _column_array(v, f"triad {name!r}", 2)) for name, v in chunk.triads.items()]
    if chunk.temperature is not None:
        cols.append(("temperature", TEMPERATURE, _column_array(chunk.temperature, "temperature", 1)))
    cols += [(str(name), EXTRA, _column_array(v, f"channel {name!r}", 1)) for name, v in chunk.extras.items()]
    return [(_column(name, role, a.dtype), a) for name, role, a in cols]


@functools.lru_cache(maxsize=256)
def _column(name: str, role: str, dtype: np.dtype) -> Column:
    """The Column of a name, role and dtype, made once: every chunk of a run asks for the same few."""
    return Column(name, role, dtype)


# --------------------------------------------------------------------------------------------
# Scanning a session directory (shared by the reader and append_to)


@dataclass
class _Scan:
    """What scanning a session's files found: the consistent prefix of each, and what is beyond."""
    directory: Path
    docs: list[dict]
    kept_log_bytes: int  # the log's consistent prefix, in bytes
    log_size: int
    samples_end: int  # end of the last kept chunk record
    samples_size: int
    raw_ends: dict[str, int]  # per raw stream: end of the last kept raw record
    raw_sizes: dict[str, int]  # per raw file on disk
    descriptors: dict[int, tuple[Column, ...]]
    last_chunk: int | None
    beyond: list[str] = field(default_factory=list)  # the torn tail, one line per finding

    @property
    def log_path(self) -> Path:
        return self.directory / LOG


def raw_path(directory: Path, name: str) -> Path:
    return directory / f"{RAW_PREFIX}{name}{RAW_SUFFIX}"


def _plural(n: int, word: str) -> str:
    return f"{n} {word}{'' if n == 1 else 's'}"


class _DocChecker:
    """Validates documents in order; every failure is one line naming the log file and line."""

    def __init__(self, log_path: Path) -> None:
        self.path = log_path
        self.descriptors: dict[int, tuple[Column, ...]] = {}
        self.samples_end = 0
        self.raw_ends: dict[str, int] = {}
        self.last_chunk: int | None = None
        # per descriptor (one layout, one stream of samples), the last sample time of the run so
        # far and its chunk: a chunk starts at or after it (a device without a clock stamps the
        # frames of one read with one host time); a resume, its clock restarted or continued
        # from an earlier step, starts a new run of times
        self.last_t: dict[int, tuple[float, int]] = {}

    def fail(self, line: int, what: str):
        raise SessionError(f"{self.path}: line {line}: {what}", str(self.path), line)

    def field(self, doc: dict, key: str, kinds, line: int, what: str):
        if key not in doc:
            self.fail(line, f"{doc['type']} document without {key!r}")
        value = doc[key]
        if isinstance(value, bool) and bool not in kinds or not isinstance(value, kinds):
            self.fail(line, f"{doc['type']} document: {key!r} must be {what}, got {value!r}"[:300])
        return value

    def count(self, doc: dict, key: str, line: int) -> int:
        value = self.field(doc, key, (int,), line, "an integer >= 0")
        if value < 0:
            self.fail(line, f"{doc['type']} document: {key!r} must be an integer >= 0, got {value}")
        return value

    def check(self, doc, index: int) -> None:
        line = index + 1
        if not isinstance(doc, dict):
            self.fail(line, f"expected a JSON object, got {type(doc).__name__}")
        seq = doc.get("seq")
        if isinstance(seq, bool) or not isinstance(seq, int) or seq != index:
            self.fail(line, f"expected seq {index}, got {seq!r}"[:200])
        kind = doc.get("type")
        if kind not in DOC_TYPES:
            self.fail(line, f"unknown document type {kind!r}"[:200])
        if (kind == "start") != (index == 0):
            self.fail(line, "the first document must be the start document, and only the first"
                      if index == 0 else "a second start document")
        getattr(self, f"check_{kind}")(doc, line)

    def check_start(self, doc, line):
        if doc.get("schema") not in (SCHEMA, SCHEMA_V1):
            self.fail(line, f"expected a start document of schema {SCHEMA!r} (or {SCHEMA_V1!r}), got "
                      f"{doc.get('schema')!r}"[:200])
        self.field(doc, "metadata", (dict,), line, "an object")

    def check_descriptor(self, doc, line):
        cols = self.field(doc, "columns", (list,), line, "a list")
        out, seen = [], set()
        for i, c in enumerate(cols):
            if not (isinstance(c, dict) and set(c) == {"name", "role", "dtype"}
                    and isinstance(c["name"], str) and c["role"] in ROLES and isinstance(c["dtype"], str)):
                self.fail(line, f"descriptor column {i}: expected name, role and dtype, got {c!r}"[:200])
            try:
                dtype = np.dtype(c["dtype"])
            except Exception:  # noqa: BLE001 -- numpy raises TypeError, ValueError, SyntaxError...
                dtype = None
            if dtype is None or dtype.kind not in "biuf" or dtype.str != c["dtype"] or dtype.byteorder == ">":
                self.fail(line, f"descriptor column {i}: not a little-endian numeric dtype: {c['dtype']!r}"[:200])
            key = (c["role"], c["name"])
            if key in seen:
                self.fail(line, f"descriptor column {i}: {c['name']!r} appears twice")
            seen.add(key)
            out.append(Column(c["name"], c["role"], dtype))
        roles = [c.role for c in out]
        if not out or roles[0] != TIME or roles.count(TIME) != 1 or roles.count(TEMPERATURE) > 1:
            self.fail(line, "descriptor: expected the time column first and at most one temperature")
        self.descriptors[doc["seq"]] = tuple(out)

    def check_chunk(self, doc, line):
        d = self.field(doc, "descriptor", (int,), line, "a descriptor's seq")
        if d not in self.descriptors:
            self.fail(line, f"chunk refers to descriptor {d}, which is not an earlier descriptor")
        offset, length, n = (self.count(doc, k, line) for k in ("offset", "length", "n"))
        self.count(doc, "crc32", line)
        for key in ("t_first", "t_last"):
            self.field(doc, key, (int, float, type(None)), line, "a number or null")
        if (doc["t_first"] is None) != (n == 0) or (doc["t_last"] is None) != (n == 0) or (
                n and not doc["t_first"] <= doc["t_last"]):
            self.fail(line, f"chunk of {n} samples from t {doc['t_first']!r} to {doc['t_last']!r}: "
                      "expected the times of its first and last samples (null for none)"[:200])
        if n and not (math.isfinite(doc["t_first"]) and math.isfinite(doc["t_last"])):
            self.fail(line, f"chunk {doc['seq']}: sample time {doc['t_first']!r} .. {doc['t_last']!r} s is "
                      "not a finite number (forged or damaged times)")
        last_t, last_chunk = self.last_t.get(d, (-math.inf, None))
        if n and not doc["t_first"] >= last_t:
            self.fail(line, f"chunk {doc['seq']}: its samples start at t {doc['t_first']!r} s, before chunk "
                      f"{last_chunk}'s last sample at t {last_t!r} s (time within a run never "
                      "goes back: forged or damaged times in one of them)")
        if n:
            self.last_t[d] = (doc["t_last"], doc["seq"])
        if offset != self.samples_end:
            self.fail(line, f"chunk at byte {offset} of {SAMPLES}, expected {self.samples_end} "
                      "(records are contiguous)")
        expected = RECORD_HEADER.size + _payload_bytes(self.descriptors[d], n)
        if length != expected:
            self.fail(line, f"chunk of {n} samples has length {length}, its descriptor needs {expected}")
        self.samples_end = offset + length
        self.last_chunk = doc["seq"]

    def check_after_chunk(self, doc, line):
        if "after_chunk" not in doc or doc["after_chunk"] != self.last_chunk:
            self.fail(line, f"{doc['type']} document: after_chunk {doc.get('after_chunk')!r} but the "
                      f"last chunk before it is {self.last_chunk!r}"[:200])
        self.field(doc, "data", (dict,), line, "an object")

    check_event = check_action = check_step = check_checkpoint = check_after_chunk

    def check_stop(self, doc, line):
        self.field(doc, "reason", (str,), line, "a string")
        self.field(doc, "data", (dict,), line, "an object")

    def check_resume(self, doc, line):
        self.check_after_chunk(doc, line)
        self.last_t = {}  # a new run of sample times (a power-cycled device's clock restarts)
        repaired = self.field(doc, "repaired", (list,), line, "a list")
        if not all(isinstance(r, str) for r in repaired):
            self.fail(line, "resume document: 'repaired' must be a list of strings")

    def check_raw(self, doc, line):
        name = self.field(doc, "name", (str,), line, "a string")
        if not _NAME.fullmatch(name):
            self.fail(line, f"raw document: bad stream name {name!r}"[:200])
        self.field(doc, "t", (int, float), line, "a number")
        offset, length = self.count(doc, "offset", line), self.count(doc, "length", line)
        self.count(doc, "crc32", line)
        end = self.raw_ends.get(name, 0)
        if offset != end:
            self.fail(line, f"raw {name!r} at byte {offset}, expected {end} (records are contiguous)")
        self.raw_ends[name] = offset + length

    def check_parameters(self, doc, line):
        name = self.field(doc, "file", (str,), line, "a file name")
        if not _NAME.fullmatch(name):
            self.fail(line, f"parameters document: bad file name {name!r}"[:200])
        sha = self.field(doc, "sha256", (str,), line, "a SHA-256 hex digest")
        if not _SHA256.fullmatch(sha):
            self.fail(line, f"parameters document: bad sha256 {sha!r}"[:200])


def _not_a_file(path: Path) -> str:
    """What is at ``path`` instead of a regular file, in words: a directory or a link to
    /dev/zero is not "missing"."""
    import stat

    if not os.path.lexists(path):
        return "missing"
    try:
        mode = path.stat().st_mode
    except OSError:
        return f"a link to {os.readlink(path)!r}, which does not exist" if path.is_symlink() else "unreadable"
    kind = ("a directory" if stat.S_ISDIR(mode) else "a character device" if stat.S_ISCHR(mode)
            else "a FIFO" if stat.S_ISFIFO(mode) else "a block device" if stat.S_ISBLK(mode) else "a special file")
    link = f" (a link to {os.readlink(path)})" if path.is_symlink() else ""
    return f"{kind}{link}, not a file"


def _file_size(path: Path) -> int:
    try:
        return path.stat().st_size
    except FileNotFoundError:
        return 0


def _scan(directory: str | os.PathLike, verb: str, live: bool = False, log_only: bool = False) -> _Scan:
    """Read and check the whole log; find the torn tail (at most the last write of each file, as
    a crash leaves it) and refuse anything else as damage, naming the file and byte or line.

    ``live``: a writer holds the session's lock, so bytes beyond what the log indexes are a write
    in progress, not damage. ``log_only``: the data files are neither needed nor checked.
    """
    d = Path(directory)
    log_path = _session_log(d)
    try:
        data = log_path.read_bytes()  # read the log before sizing the data files it indexes
    except OSError as exc:
        raise SessionError(f"{log_path}: cannot read ({exc.strerror or exc})", str(log_path)) from None
    samples_size = 0 if log_only else _file_size(d / SAMPLES)
    # regular files only: a dangling link or a directory at a raw file's name is no raw stream
    # (named as what it is when the log refers to it, below), not a traceback or 4096 bytes
    raw_sizes = {} if log_only else {p.name[len(RAW_PREFIX):-len(RAW_SUFFIX)]: p.stat().st_size
                                     for p in sorted(d.glob(f"{RAW_PREFIX}*{RAW_SUFFIX}")) if p.is_file()}

    complete = data.rfind(b"\n") + 1
    checker = _DocChecker(log_path)
    docs: list[dict] = []
    beyond: list[str] = []
    if complete < len(data):
        beyond.append(f"{LOG}: {verb} a torn last line ({_plural(len(data) - complete, 'byte')} at byte {complete})")
    if complete == 0:
        raise SessionError(f"{log_path}: not a session log (no complete start document: the file is "
                           f"{'empty' if not data else 'one torn line'})", str(log_path), 1)
    checked: bool | None = None
    pos = 0
    for index, raw in enumerate(data[:complete - 1].split(b"\n")):
        try:
            doc = _parse_line(raw, checked)
        except ValueError as exc:  # JSONDecodeError, UnicodeDecodeError or a checksum
            detail = getattr(exc, "msg", None) or str(exc) or type(exc).__name__
            if index == 0:
                raise SessionError(f"{log_path}: line 1: not a session log ({detail})", str(log_path), 1) from None
            raise SessionError(f"{log_path}: line {index + 1} (byte {pos}): damaged: {detail}; the session "
                               "is not repaired automatically (restore it from a copy)", str(log_path),
                               index + 1) from None
        checker.check(doc, index)
        if index == 0:
            checked = doc["schema"] != SCHEMA_V1
            if checked and not _CRC_TAIL.search(raw):
                raise SessionError(f"{log_path}: line 1: no checksum (\"crc\"), which {SCHEMA} requires",
                                   str(log_path), 1)
        pos += len(raw) + 1
        docs.append(doc)

    # Data the log indexes must all be there: a crash writes the data before the log line, so a
    # log that points past the end of a file is damage (the file was cut or replaced), never a tail.
    samples_path = d / SAMPLES
    samples_is_file = not log_only and samples_path.is_file()  # asked once, not at each of its chunks
    for i, doc in enumerate(() if log_only else docs):
        kind = doc["type"]
        if kind not in ("chunk", "raw"):
            continue
        path = samples_path if kind == "chunk" else raw_path(d, doc["name"])
        size = samples_size if kind == "chunk" else raw_sizes.get(doc["name"])
        if kind == "chunk" and not samples_is_file or size is None:
            raise SessionError(f"{path}: {_not_a_file(path)}, but {LOG} line {i + 1} refers to it", str(path), i + 1)
        end = doc["offset"] + doc["length"]
        if end > size:
            raise SessionError(f"{path}: damaged: the file ends at byte {size}, but {LOG} line {i + 1} "
                               f"({doc['type']} {doc['seq']}) says it was written up to byte {end} (the "
                               "file was cut short; restore it from a copy)", str(path), i + 1)
    samples_end, raw_ends = checker.samples_end, dict(checker.raw_ends)
    if samples_size > samples_end:
        tail = samples_size - samples_end
        if not live:
            _check_torn_record(d / SAMPLES, samples_end, tail, len(docs))
        beyond.append(f"{SAMPLES}: {verb} {_plural(tail, 'byte')} after the last logged chunk "
                      f"(from byte {samples_end})")
    for name, size in raw_sizes.items():
        if size > raw_ends.get(name, 0):
            beyond.append(f"{RAW_PREFIX}{name}{RAW_SUFFIX}: {verb} {_plural(size - raw_ends.get(name, 0), 'byte')} "
                          f"after the last logged read (from byte {raw_ends.get(name, 0)})")
    return _Scan(d, docs, complete, len(data), samples_end, samples_size, raw_ends, raw_sizes,
                 dict(checker.descriptors), checker.last_chunk, beyond)


def _session_log(d: Path) -> Path:
    if not d.exists():
        raise SessionError(f"{d}: no such session directory", str(d))
    if not d.is_dir():
        raise SessionError(f"{d}: is {file_kind(d.stat().st_mode)}, not a directory (a session is one)", str(d))
    log_path = d / LOG
    if not log_path.is_file():
        raise SessionError(f"{d}: not a session directory (no {LOG})", str(d))
    return log_path


def _check_torn_record(path: Path, start: int, tail: int, next_seq: int) -> None:
    """Bytes after the last logged chunk are a torn tail only if they are (a prefix of) the one
    record a crash could have written before its log line: the next seq, no longer than itself."""
    with open(path, "rb") as fh:
        fh.seek(start)
        head = fh.read(RECORD_HEADER.size)
    why = None
    if not head.startswith(RECORD_MAGIC[:len(head)]):
        why = "they do not start with a record header"
    elif len(head) >= 16 and struct.unpack_from("<Q", head, 8)[0] != next_seq:  # the header's seq, once there
        why = f"they hold chunk {struct.unpack_from('<Q', head, 8)[0]}, not the next one ({next_seq})"
    elif len(head) == RECORD_HEADER.size and tail > RECORD_HEADER.size + RECORD_HEADER.unpack(head)[5]:
        why = "they are more than one unlogged record"
    if why:
        raise SessionError(f"{path}: damaged: {_plural(tail, 'byte')} from byte {start} on are not indexed by "
                           f"{LOG}, and {why} (the log was cut short or the file damaged; restore it from a "
                           "copy)", str(path))


def _run_state(docs: list[dict]) -> tuple[bool, str | None]:
    """(stopped, reason) of the last run: stopped when its last start/resume/stop is a stop."""
    for doc in reversed(docs):
        if doc["type"] == "stop":
            return True, doc["reason"]
        if doc["type"] in ("start", "resume"):
            return False, None
    return False, None


def _read_record(fh, doc: dict, columns: tuple[Column, ...], path: Path, line: int) -> SampleChunk:
    offset, length, n = doc["offset"], doc["length"], doc["n"]
    where = f"{path}: chunk {doc['seq']} at byte {offset} (log line {line})"
    fh.seek(offset)
    buf = bytearray(length)
    if fh.readinto(buf) != length:
        raise SessionError(f"{where}: the file ends inside the record", str(path), line)
    magic, crc, seq, dseq, count, payload = RECORD_HEADER.unpack_from(buf)
    if magic != RECORD_MAGIC:
        raise SessionError(f"{where}: bad record magic {magic!r}", str(path), line)
    if (seq, dseq, count, payload) != (doc["seq"], doc["descriptor"], n, length - RECORD_HEADER.size):
        raise SessionError(f"{where}: the record header (seq {seq}, descriptor {dseq}, n {count}, "
                           f"{payload} bytes) does not match the log", str(path), line)
    if crc != doc["crc32"] or zlib.crc32(memoryview(buf)[RECORD_HEADER.size:]) != crc:
        raise SessionError(f"{where}: checksum mismatch (corrupt data)", str(path), line)
    pos = RECORD_HEADER.size
    t, triads, temperature, extras = None, {}, None, {}
    for col in columns:
        a = np.frombuffer(buf, dtype=col.dtype, count=n * col.width, offset=pos)
        pos += col.block_bytes(n)
        if col.role == TIME:
            t = a
        elif col.role == TRIAD:
            triads[col.name] = a.reshape(n, 3)
        elif col.role == TEMPERATURE:
            temperature = a
        else:
            extras[col.name] = a
    assert t is not None  # (a descriptor's first column is the time: checked by the scan)
    # The log's span of the chunk is read without the record (the time a resume continues from):
    # it must be the record's own, not a forged one that the CRC of the line alone would pass.
    span = (t[0].item(), t[-1].item()) if n else (None, None)
    if (doc["t_first"], doc["t_last"]) != span:
        raise SessionError(f"{where}: the log gives its samples t {doc['t_first']!r} .. {doc['t_last']!r} s, "
                           f"the record holds {span[0]!r} .. {span[1]!r} s", str(path), line)
    # finite and never going back inside the record (the scan holds the log's spans in order;
    # equal times are a clockless device's frames of one read, stamped with one host time)
    if np.isfinite(t).all() and (t[1:] >= t[:-1]).all():  # nearly every record: no sample to name
        bad = t[:0]
    else:
        bad = np.flatnonzero(~np.isfinite(t) | np.r_[False, ~(np.diff(t) >= 0)])
    if bad.size:
        i = int(bad[0])
        what = "is not a finite number" if not np.isfinite(t[i]) else f"is before sample {i - 1}'s {t[i - 1].item()!r} s"
        raise SessionError(f"{where}: sample {i}'s time {t[i].item()!r} s {what} (time within a chunk never "
                           "goes back: forged or damaged times)", str(path), line)
    return SampleChunk(t=t, triads=triads, temperature=temperature, extras=extras)


# --------------------------------------------------------------------------------------------
# Writing


class SessionWriter:
    """Appends documents and data to a session directory; see the module docstring.

    Thread-safe (``write_raw`` is meant to be a transport's tap, called on its reader thread).
    Every method that writes a document returns that document's seq.
    """

    def __init__(self, directory: Path, log, samples, scan: _Scan | None, *, fsync_interval_s: float,
                 clock: Callable[[], float], active: bool, repaired: list[str],
                 session_lock: SessionLock | None = None) -> None:
        self.directory = directory
        self._session_lock = session_lock  # the OS lock that makes this the session's only writer
        self._log = log
        self._samples = samples
        self._raw: dict[str, Any] = {}
        self._lock = threading.RLock()
        self.parameters_written: Path | None = None  # the last file write_parameters wrote
        self._clock = clock
        self.fsync_interval_s = float(fsync_interval_s)
        self._active = active
        self._closed = False
        self._failed = ""
        self.repaired = list(repaired)  # what append_to cut; goes into the resume document
        if scan is None:
            self._seq, self._samples_end, self._raw_ends, self._last_chunk = 0, 0, {}, None
            self._layouts: dict[tuple, int] = {}
        else:
            self._seq = len(scan.docs)
            self._samples_end = scan.samples_end
            self._raw_ends = dict(scan.raw_ends)
            self._last_chunk = scan.last_chunk
            self._layouts = {cols: seq for seq, cols in scan.descriptors.items()}
        self._completed_line = None if scan is None else next(
            (doc["seq"] + 1 for doc in scan.docs if doc["type"] == "stop" and doc["reason"] == "completed"), None)
        self._last_sync = clock()

    # -- opening ------------------------------------------------------------------------------

    @classmethod
    def create(cls, directory: str | os.PathLike, start_metadata: Mapping, *, fsync_interval_s: float = 1.0,
               clock: Callable[[], float] = time.monotonic) -> SessionWriter:
        """A new session in ``directory`` (created; refused if it exists and is not empty)."""
        _check_interval(fsync_interval_s)
        d = Path(directory)
        metadata = _data(start_metadata, "start_metadata")
        try:  # created exclusively: never a directory, or a link to one, planted at the name
            new_directory(d)
        except (CannotWrite, RefusedTarget) as exc:
            raise SessionError(str(exc), str(d)) from None
        session_lock = SessionLock.acquire(d)  # two runs given the same directory: one is refused
        log = samples = None
        try:
            if (d / LOG).exists():
                raise SessionError(f"{d}: already a session (a new session needs a new directory; to "
                                   "continue this one, resume it)", str(d))
            log = open_append(d / LOG, new=True)  # held open by the writer until close()
            samples = open_append(d / SAMPLES, new=True)
        except BaseException as exc:
            for fh in (log, samples):
                if fh is not None:
                    fh.close()
            session_lock.release()
            if isinstance(exc, OSError):
                raise SessionError(f"{d}: cannot write the session ({exc.strerror or exc})", str(d)) from None
            raise
        writer = cls(d, log, samples, None, fsync_interval_s=fsync_interval_s, clock=clock,
                     active=True, repaired=[], session_lock=session_lock)
        try:
            writer._write({"seq": 0, "type": "start", "schema": SCHEMA, "metadata": metadata})
            writer.sync()
        except OSError as exc:
            if exc.filename is None:  # a buffered write names no file (a full disk): the log it was for
                exc.filename = str(d / LOG)
            for fh in (log, samples):  # closed (a flush of what is left fails the same way), unlocked
                with suppress(OSError):
                    fh.close()
            session_lock.release()
            raise
        _fsync_directory(d)
        return writer

    @classmethod
    def append_to(cls, directory: str | os.PathLike, *, fsync_interval_s: float = 1.0,
                  clock: Callable[[], float] = time.monotonic) -> SessionWriter:
        """Reopen a session to continue it: cut any torn tail, then the caller must ``resume()``.

        What was cut is in ``writer.repaired`` (one line each) and goes into the resume document.
        """
        _check_interval(fsync_interval_s)
        d = Path(directory)
        _session_log(d)
        for name in (LOG, SAMPLES, *(p.name for p in sorted(d.glob(f"{RAW_PREFIX}*{RAW_SUFFIX}")))):
            try:  # before anything is cut or appended
                refuse_other_names(d / name)
            except RefusedTarget as exc:
                raise SessionError(str(exc), str(d / name)) from None
        session_lock = SessionLock.acquire(d)  # before reading: nobody may write while we repair
        try:
            scan = _scan(d, "cut")
            if not _writable(d):  # before anything is cut or re-run
                raise SessionError(f"{d}: cannot write to this session (no permission)", str(d))
            if scan.last_chunk is not None:  # do not build on damaged records: read every one
                _verify_records(scan)
            repaired = []
            for path, keep in [(d / LOG, scan.kept_log_bytes), (d / SAMPLES, scan.samples_end),
                               *((raw_path(d, name), scan.raw_ends.get(name, 0)) for name in scan.raw_sizes)]:
                kept_in = _cut_torn(path, keep)
                if kept_in is not None:
                    repaired += [f"{line} (kept in {kept_in.name})" for line in scan.beyond
                                 if line.startswith(f"{path.name}:")]
            log = open_append(d / LOG)  # held open by the writer until close()
            samples = open_append(d / SAMPLES)
        except BaseException as exc:
            session_lock.release()
            if isinstance(exc, OSError):
                raise SessionError(f"{d}: cannot write to this session ({exc.strerror or exc})", str(d)) from None
            raise
        writer = cls(d, log, samples, scan, fsync_interval_s=fsync_interval_s, clock=clock,
                     active=False, repaired=repaired, session_lock=session_lock)
        for name in scan.raw_ends:
            writer._raw[name] = open_append(raw_path(d, name))
        return writer

    # -- state --------------------------------------------------------------------------------

    @property
    def next_seq(self) -> int:
        return self._seq

    @property
    def last_chunk(self) -> int | None:
        return self._last_chunk

    @property
    def active(self) -> bool:
        """True between start/resume and stop."""
        return self._active

    @property
    def closed(self) -> bool:
        return self._closed

    def _require(self, kind: str) -> None:
        if self._closed:
            raise SessionStateError(f"{self.directory}: the session writer is closed")
        if self._failed:
            raise SessionStateError(f"{self.directory}: an earlier write failed ({self._failed}); close() "
                                    "and continue with append_to(), which cuts any partial record")
        if kind == "resume" and self._active:
            raise SessionStateError(f"{self.directory}: cannot resume: the run is still active")
        if kind in RUN_TYPES and not self._active:
            raise SessionStateError(f"{self.directory}: cannot write {kind!r}: no active run "
                                    "(after stop() or append_to(), call resume() first)")

    @contextmanager
    def _writing(self, kind: str):
        """Hold the lock, check the state, and mark the writer failed if a write breaks off: after
        a partial line or record, appending more would turn a torn tail into corruption."""
        with self._lock:
            self._require(kind)
            try:
                yield
            except BaseException as exc:
                self._failed = (str(exc).splitlines() or [""])[0][:200] or type(exc).__name__
                if isinstance(exc, OSError) and exc.filename is None:  # a buffered write names no file:
                    exc.filename = str(self.directory)  # the session it was for (a full disk, say)
                raise

    def _write(self, doc: dict) -> int:
        self._log.write(_dumps(doc))
        self._log.flush()
        self._seq += 1
        return doc["seq"]

    def _doc(self, kind: str, data: Mapping | None, **fields) -> int:
        payload = _data({} if data is None else data, kind)
        with self._writing(kind):
            if kind in ("event", "action", "step", "checkpoint"):
                fields = {"after_chunk": self._last_chunk}
            seq = self._write({"seq": self._seq, "type": kind, **fields, "data": payload})
            self._maybe_sync()
            return seq

    # -- documents ----------------------------------------------------------------------------

    def chunk(self, chunk: SampleChunk) -> int:
        """Append a chunk of samples (bit for bit); returns its seq."""
        cols = _chunk_columns(chunk)
        with self._writing("chunk"):
            n = len(cols[0][1])
            layout = tuple(c for c, _ in cols)
            dseq = self._layouts.get(layout)
            if dseq is None:
                dseq = self._write({"seq": self._seq, "type": "descriptor",
                                    "columns": [c.to_doc() for c in layout]})
                self._layouts[layout] = dseq
            seq = self._seq
            blocks: list = []
            for col, a in cols:
                b = a.reshape(-1).view(np.uint8)
                pad = col.block_bytes(n) - b.nbytes
                blocks.append(b)
                if pad:
                    blocks.append(bytes(pad))
            # The blocks joined: one CRC (the CRC chained over them) and one write after the header.
            data = b"".join(blocks)
            crc = zlib.crc32(data)
            payload = _payload_bytes(layout, n)
            fh = self._samples
            fh.write(RECORD_HEADER.pack(RECORD_MAGIC, crc, seq, dseq, n, payload))
            fh.write(data)
            fh.flush()
            offset = self._samples_end
            length = RECORD_HEADER.size + payload
            self._samples_end += length
            t = cols[0][1]
            self._write({"seq": seq, "type": "chunk", "descriptor": dseq, "offset": offset, "length": length,
                         "n": n, "t_first": t[0].item() if n else None, "t_last": t[-1].item() if n else None,
                         "crc32": crc})
            self._last_chunk = seq
            self._maybe_sync()
            return seq

    def event(self, data: Mapping) -> int:
        """An engine event (any JSON-able dict)."""
        return self._doc("event", data)

    def action(self, data: Mapping) -> int:
        """An operator action, recorded after the last chunk so replay interleaves it exactly."""
        return self._doc("action", data)

    def step(self, data: Mapping) -> int:
        """A completed step: its averages and metadata."""
        return self._doc("step", data)

    def checkpoint(self, data: Mapping) -> int:
        """State the runner needs to resume from here (e.g. the simulator's RNG state)."""
        return self._doc("checkpoint", data)

    def stop(self, reason: str, data: Mapping | None = None) -> int:
        """End the run (completed, aborted, ...); synced to disk at once."""
        if not isinstance(reason, str) or not reason:
            raise ValueError(f"stop reason: expected a non-empty string, got {reason!r}")
        with self._lock:
            seq = self._doc("stop", data, reason=reason)
            self._active = False
            if reason == "completed" and self._completed_line is None:
                self._completed_line = seq + 1
            self.sync()
            return seq

    def resume(self, data: Mapping | None = None, *, mid_run: bool = False) -> int:
        """Start a new run continuing this session (after ``append_to``, or after ``stop``).
        ``mid_run``: the active run starts over from a resume point without having stopped (a
        live device power-cycled mid-run, its completed steps measured again).

        A session whose run completed is never resumed (SessionError naming its stop line)."""
        payload = _data({} if data is None else data, "resume")
        kind = "resume mid-run" if mid_run else "resume"
        with self._lock:  # refused before _writing: a call that writes nothing does not fail the writer
            self._require(kind)
            if mid_run and not self._active:
                raise SessionStateError(f"{self.directory}: cannot resume mid-run: no active run")
            if self._completed_line is not None:
                raise SessionError(f"{self.directory / LOG}: line {self._completed_line}: this session "
                                   "completed; a completed session is never resumed (replay it, or run "
                                   "again into a new directory)", str(self.directory / LOG), self._completed_line)
            with self._writing(kind):
                seq = self._write({"seq": self._seq, "type": "resume", "after_chunk": self._last_chunk,
                                   "repaired": list(self.repaired), "data": payload})
                self.repaired = []
                self._active = True
                self.sync()
                return seq

    def write_raw(self, name: str, t: float, data: bytes) -> int:
        """Raw bytes from a live device with their host arrival time, into ``raw-<name>.bin``.

        Fits a transport tap: ``functools.partial(writer.write_raw, "imu")``.
        """
        if not isinstance(name, str) or not _NAME.fullmatch(name):
            raise ValueError(f"raw stream name: expected letters, digits, '_', '.', '-' (at most 64), got {name!r}")
        t = to_plain(t, "t")
        if isinstance(t, bool) or not isinstance(t, (int, float)):
            raise TypeError(f"raw t: expected a number, got {t!r}")
        view = memoryview(data).cast("B")
        with self._writing("raw"):
            fh = self._raw.get(name)
            if fh is None:
                fh = self._raw[name] = open_append(raw_path(self.directory, name))
            offset = self._raw_ends.get(name, 0)
            fh.write(view)
            fh.flush()
            self._raw_ends[name] = offset + view.nbytes
            seq = self._write({"seq": self._seq, "type": "raw", "name": name, "t": t, "offset": offset,
                               "length": view.nbytes, "crc32": zlib.crc32(view)})
            self._maybe_sync()
            return seq

    def write_parameters(self, pf, filename: str | None = None) -> int:
        """Save a ParameterFile into the session and note it with its SHA-256.

        Every calibration is kept: by default it goes into the next free ``parameters-NNN.yaml``
        (never over an existing file) and ``parameters.yaml`` is then replaced by a copy of it, the
        current one. A ``filename`` writes that file instead (refused if it exists).
        """
        from fieldcal.paramfile import dump

        if filename is not None and (not isinstance(filename, str) or not _NAME.fullmatch(filename)
                                     or filename in (LOG, SAMPLES, PARAMETERS) or filename.startswith(RAW_PREFIX)):
            raise ValueError(f"parameter file name: expected a plain file name, got {filename!r}")
        data = dump(pf).encode("utf-8")
        with self._lock:
            self._require("parameters")
            if filename is None:
                check_target(self.directory / PARAMETERS, force=True)  # before the numbered file: a link is refused
                self._keep_current_parameters()
            name = filename or self._next_parameters_name()
            # atomic and never over another file: a failure leaves the log as it was
            path = write_atomically(self.directory / name, data, overwrite=False,
                                    hint="a session's files are never overwritten")
            self.parameters_written = path  # this writer's file: parameters.yaml may be another's later
            with self._writing("parameters"):
                seq = self._write({"seq": self._seq, "type": "parameters", "file": name,
                                   "sha256": hashlib.sha256(data).hexdigest()})
                self._maybe_sync()
            if filename is None:  # the current copy; the log names the numbered file it copies
                write_atomically(self.directory / PARAMETERS, path.read_bytes())
            return seq

    def _numbered_parameters(self) -> list[tuple[int, Path]]:
        return sorted((int(m.group(1)), p) for p in self.directory.iterdir()
                      if (m := PARAMETERS_NUMBERED.fullmatch(p.name)))

    def _next_parameters_name(self) -> str:
        taken = self._numbered_parameters()
        return f"parameters-{(taken[-1][0] if taken else 0) + 1:03d}.yaml"

    def _keep_current_parameters(self) -> None:
        """A parameters.yaml that is no copy of a numbered file (a session written before files
        were numbered) is kept under the next number before a new calibration replaces it."""
        current = self.directory / PARAMETERS
        if not current.is_file():
            return
        old = current.read_bytes()
        if not any(p.read_bytes() == old for _, p in self._numbered_parameters()):
            write_atomically(self.directory / self._next_parameters_name(), old, overwrite=False)

    # -- durability ---------------------------------------------------------------------------

    def _maybe_sync(self) -> None:
        if self._clock() - self._last_sync >= self.fsync_interval_s:
            self.sync()

    def sync(self) -> None:
        """fsync the data files, then the log (also done every ``fsync_interval_s`` and on stop,
        resume and close; a runner that may go quiet for long can call it on its own tick)."""
        if self._closed:
            return
        with self._writing("sync"):
            for fh in (self._samples, *self._raw.values(), self._log):
                fh.flush()
                os.fsync(fh.fileno())
            self._last_sync = self._clock()

    def close(self) -> None:
        """Sync and close. The run stays unstopped unless ``stop`` was called (resumable)."""
        with self._lock:
            if self._closed:
                return
            try:
                if not self._failed:
                    self.sync()
            finally:
                self._closed = True
                try:  # closing flushes, which can fail (a full disk): the lock is released anyway
                    for fh in (self._samples, *self._raw.values(), self._log):
                        try:
                            fh.close()
                        except OSError:
                            if not self._failed:
                                raise
                finally:
                    if self._session_lock is not None:
                        self._session_lock.release()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _check_interval(seconds) -> None:
    if isinstance(seconds, bool) or not isinstance(seconds, (int, float)) or not seconds >= 0:
        raise ValueError(f"fsync_interval_s: expected a number >= 0, got {seconds!r}")


def _cut_torn(path: Path, size: int) -> Path | None:
    """Cut ``path`` back to ``size`` bytes, first keeping what is cut in ``<name>.torn`` (or
    ``.torn-2``, ... : an earlier cut's copy is never overwritten). The copy's path, or None."""
    if _file_size(path) <= size:
        return None
    with open(path, "rb") as fh:
        fh.seek(size)
        cut = fh.read()
    for n in range(1, 1000):
        kept = path.with_name(f"{path.name}{TORN_SUFFIX}{'' if n == 1 else f'-{n}'}")
        try:
            write_atomically(kept, cut, overwrite=False)
            break
        except WouldOverwrite:
            continue
    else:
        raise SessionError(f"{path}: too many earlier {TORN_SUFFIX} copies beside it", str(path))
    with os.fdopen(open_nofollow(path, os.O_RDWR), "r+b") as fh:  # never cut a link's target
        fh.truncate(size)
        fh.flush()
        os.fsync(fh.fileno())
    return kept


def _writable(d: Path) -> bool:
    return all(os.access(p, os.W_OK) for p in (d, d / LOG) if p.exists())


def _verify_records(scan: _Scan) -> None:
    """Read every chunk record back against its log line (SessionError naming the first bad one)."""
    path = scan.directory / SAMPLES
    with open(path, "rb") as fh:
        for doc in scan.docs:
            if doc["type"] == "chunk":
                _read_record(fh, doc, scan.descriptors[doc["descriptor"]], path, doc["seq"] + 1)


def _fsync_directory(directory: Path) -> None:
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


# --------------------------------------------------------------------------------------------
# Reading


class SessionReader:
    """A snapshot of a session's consistent prefix, taken when constructed.

    Safe on a session that is being written or whose writer was killed: a torn tail is ignored
    (listed in ``torn``). Chunks are verified against their log entries as they are read.
    """

    def __init__(self, directory: str | os.PathLike, *, log_only: bool = False) -> None:
        """``log_only``: the log's documents alone (step averages, events, actions), not
        requiring samples.bin and the raw files (e.g. to re-solve without them); where samples.bin
        is there it is still checked against the log, so damage is named all the same."""
        log_only = log_only and not (Path(directory) / SAMPLES).exists()
        self._scan = _scan(directory, "ignored", live=is_held(directory), log_only=log_only)
        self.directory = self._scan.directory
        self.torn: list[str] = list(self._scan.beyond)
        self.stopped, self.stop_reason = _run_state(self._scan.docs)

    @property
    def start_document(self) -> dict:  # kept: the start whole, its schema saying which format wrote it
        return self._scan.docs[0]

    @property
    def start(self) -> dict:
        """The runner's start metadata."""
        return self._scan.docs[0]["metadata"]

    def documents(self, *types: str) -> Iterator[dict]:
        """All documents in order (or only those of ``types``). Do not mutate them."""
        for t in types:
            if t not in DOC_TYPES:
                raise ValueError(f"unknown document type {t!r} (known: {', '.join(DOC_TYPES)})")
        for doc in self._scan.docs:
            if not types or doc["type"] in types:
                yield doc

    def _data_of(self, kind: str) -> list[dict]:
        return [doc["data"] for doc in self.documents(kind)]

    def events(self) -> list[dict]:
        return self._data_of("event")

    def actions(self) -> list[dict]:  # kept: what the operator did, the TUI tests' check of a run
        return self._data_of("action")

    def steps(self) -> list[dict]:
        return self._data_of("step")

    # n_chunks, n_samples, raw_names: kept, what a session holds, checked against the writer's counts
    @property
    def n_chunks(self) -> int:
        return sum(1 for _ in self.documents("chunk"))

    @property
    def n_samples(self) -> int:
        return sum(doc["n"] for doc in self.documents("chunk"))

    def chunks(self) -> Iterator[SampleChunk]:
        """The sample chunks in order, each verified against its log entry."""
        for _, chunk in self.replay_items(("chunk",)):
            yield chunk

    def replay_items(self, types: Iterable[str] = ("chunk", "action")) -> Iterator[tuple[str, Any]]:
        """(type, item) in recorded order: a SampleChunk for "chunk", the data dict otherwise.

        The default, chunks and actions, is what re-feeding a fresh engine needs to reproduce the
        run; add "resume" or "checkpoint" to see where runs were continued.
        """
        types = tuple(types)
        for t in types:
            if t not in DOC_TYPES:
                raise ValueError(f"unknown document type {t!r} (known: {', '.join(DOC_TYPES)})")
        path = self.directory / SAMPLES
        fh = open(path, "rb") if "chunk" in types else None  # noqa: SIM115 -- closed in finally
        try:
            for doc in self._scan.docs:
                kind = doc["type"]
                if kind not in types:
                    continue
                if kind == "chunk":
                    yield kind, _read_record(fh, doc, self._scan.descriptors[doc["descriptor"]], path, doc["seq"] + 1)
                else:
                    yield kind, doc.get("data", doc)
        finally:
            if fh is not None:
                fh.close()

    @property
    def raw_names(self) -> list[str]:
        return sorted(self._scan.raw_ends)

    def raw(self, name: str) -> Iterator[tuple[float, bytes]]:
        """(host arrival time, bytes) of each logged read of raw stream ``name``, verified."""
        docs = [doc for doc in self.documents("raw") if doc["name"] == name]
        if not docs:
            return
        path = raw_path(self.directory, name)
        with open(path, "rb") as fh:
            for doc in docs:
                fh.seek(doc["offset"])
                data = fh.read(doc["length"])
                if len(data) != doc["length"] or zlib.crc32(data) != doc["crc32"]:
                    raise SessionError(f"{path}: read at byte {doc['offset']} (log line {doc['seq'] + 1}): "
                                       "checksum mismatch (corrupt data)", str(path), doc["seq"] + 1)
                yield doc["t"], data

    @property
    def parameters_path(self) -> Path | None:
        """The parameter file last noted in the log, if it is there."""
        docs = list(self.documents("parameters"))
        if not docs:
            return None
        path = self.directory / docs[-1]["file"]
        return path if path.is_file() else None
