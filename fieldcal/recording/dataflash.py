"""ArduPilot DataFlash logs (``.bin``) -> time, specific force (m/s²), rate (rad/s).

Indexed by ``pymavlink``'s ``DFReader`` (the ``logs`` extra), imported only when such a log is
given. The IMU's samples are the ``IMU`` messages (``TimeUS``, ``AccX/Y/Z`` m/s², ``GyrX/Y/Z``
rad/s) of one instance, ``--imu N`` (default 0): in logs since ArduPilot 3.7 or so by their
instance column ``I``, in older logs by name (``IMU`` is instance 0, ``IMU2`` 1, ``IMU3`` 2).
A log with no ``IMU`` messages but with the ``ACC`` and ``GYR`` pair (the fast-sampling logs)
is read from those, the gyro put on the accelerometer's time.

DFReader indexes where each message starts and knows every message's binary layout from the
log's own FMT messages; the samples are then read from the file in one numpy pass over those
offsets instead of one Python object per message (a flight log holds millions). The first
sample is also decoded by DFReader itself and must agree.
"""
from __future__ import annotations

import contextlib
import io

import numpy as np

from fieldcal.recording.importer import RecordingImportError
from fieldcal.recording.inputs import zero_tail
from fieldcal.recording.noise import captured_output

_HEADER_BYTES = 3  # 0xA3 0x95 and the message type
# DataFlash format characters of the fields read here (all fixed-size, little-endian).
_NUMPY_TYPES = {"b": "i1", "B": "u1", "h": "<i2", "H": "<u2", "i": "<i4", "I": "<u4", "f": "<f4", "d": "<f8",
                "q": "<i8", "Q": "<u8", "M": "u1", "c": "<i2", "C": "<u2", "e": "<i4", "E": "<u4", "L": "<i4",
                "g": "<f2", "n": "S4", "N": "S16", "Z": "S64", "a": "S64"}
LEGACY_NAMES = ("IMU", "IMU2", "IMU3")
_CHECKED = {"TimeUS", "TimeMS", "SampleUS", "I", "AccX", "AccY", "AccZ", "GyrX", "GyrY", "GyrZ"}  # against DFReader


def read_dataflash(path: str, instance: int | None = None):
    """(t s, accelerometer m/s², gyroscope rad/s, what was read, notes, damage) from the log at
    ``path``; damage: what could not be read, in words (empty for a whole log)."""
    try:
        from pymavlink import DFReader
    except ImportError:
        raise RecordingImportError(f"{path}: reading ArduPilot logs needs pymavlink: pip install "
                                   "'fieldcal[logs]'", path) from None
    instance = 0 if instance is None else instance
    _require_log_start(path)
    try:
        size, zeros = zero_tail(path)
    except OSError as exc:
        raise RecordingImportError(f"{path}: cannot read it ({exc.strerror or exc})", path) from None
    # A zero end is left out of the index, but for a slack longer than any message: a last message
    # whose own last bytes are zeros stays whole (DFReader passes that slack over quickly). So is
    # an end with no message header in it at all (a flash chip's erased 0xFF pages, a logger's
    # fill bytes): DFReader would walk it byte by byte, minutes and hundreds of MB for 200 MB.
    indexed = min(size, size - zeros + TRAILING_SLACK, _after_last_header(path, size) + TRAILING_SLACK)
    noise = None
    try:
        # DFReader's indexer writes a line per damaged byte to stderr (from C) and its warnings to
        # stdout: silenced, counted, and said in one line with what the damage cost.
        with captured_output() as noise:
            log = _indexed_reader(DFReader, indexed)(path)
    except Exception as exc:  # DFReader raises bare exceptions on files that are not DataFlash
        raise RecordingImportError(f"{path}: not a readable DataFlash log ({type(exc).__name__}: {exc})"
                                   f"{_noise_note(noise)}", path) from None
    try:
        # Our own map of the file: a numpy view of DFReader's would keep it from closing its map.
        data = np.memmap(path, dtype=np.uint8, mode="r")
        damage, cut_notes = _damage(path, log, data, noise)
        if "IMU" in log.name_to_id and log.counts[log.name_to_id["IMU"]]:
            read = _imu(path, log, data, instance)
        elif all(n in log.name_to_id and log.counts[log.name_to_id[n]] for n in ("ACC", "GYR")):
            read = _acc_gyr(path, log, data, instance)
        else:
            present = sorted(n for n, i in log.name_to_id.items() if log.counts[i])
            if damage:
                raise RecordingImportError(f"{path}: damaged: {'; '.join(damage)}; no IMU messages (nor ACC and "
                                           f"GYR) were found in what could be read ({', '.join(present) or 'none'})",
                                           path)
            raise RecordingImportError(f"{path}: no IMU messages (nor ACC and GYR) in the log: set LOG_BITMASK to "
                                       f"log IMU; its messages: {', '.join(present) or 'none'}", path)
        t, acc, gyro, name, notes = read
        return t, acc, gyro, name, (*notes, *cut_notes), damage
    finally:
        log.close()


HEADER = b"\xa3\x95"


LONGEST_MESSAGE = 256  # bytes: a message's length is one byte of its FMT


def _after_last_header(path: str, size: int) -> int:
    """Where the file's last message can end at the latest: its last message header (A3 95),
    found from the end backwards a MiB at a time, plus the longest message. 0 with no header."""
    block = 1 << 20
    end = size
    with open(path, "rb") as f:
        while end > 0:
            start = max(0, end - block)
            f.seek(start)
            chunk = np.frombuffer(f.read(min(size, end + 1) - start), dtype=np.uint8)  # +1: a header across blocks
            hits = np.flatnonzero((chunk[:-1] == HEADER[0]) & (chunk[1:] == HEADER[1]))
            if len(hits):
                return min(size, start + int(hits[-1]) + LONGEST_MESSAGE)
            end = start
    return 0


def _require_log_start(path: str) -> None:
    """A DataFlash log starts with a message header (its FMT messages): a file that does not is
    refused at once, before the indexer walks every byte of it one by one."""
    try:
        with open(path, "rb") as f:
            start = f.read(2)
    except OSError as exc:
        raise RecordingImportError(f"{path}: cannot read it ({exc.strerror or exc})", path) from None
    if start and start != HEADER:
        raise RecordingImportError(f"{path}: not a DataFlash log: it does not start with a message header "
                                   f"(A3 95), but {start.hex(' ').upper()}", path)


def _noise_note(noise) -> str:
    summary = noise.summary("pymavlink") if noise is not None else None
    return f"; {summary}" if summary else ""


TRAILING_SLACK = 528  # bytes after the last message DFReader itself passes over (a block log's last page)


def _damage(path: str, log, data: np.ndarray, noise) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """(damage, notes): what the indexer could not read, in words, measured from where the messages it indexed
    lie: bytes between them (no message header where one was due: DFReader skips them one by
    one), the part after the last one (it stops at a message type no FMT defines), a last
    message cut off. Empty for a whole log. (DFReader's own lines about it, written by C, are
    silenced: ``noise`` holds only what it printed from Python.) A last message cut off is a
    note, not damage."""
    size = len(data)
    starts, lengths = [], []
    for message_type, offsets in enumerate(log.offsets):
        if offsets and message_type in log.formats:
            starts.append(np.asarray(offsets, dtype=np.int64))
            lengths.append(np.full(len(offsets), log.formats[message_type].len, dtype=np.int64))
    if not starts:
        return (f"no message could be indexed in its {size} bytes",), ()
    starts, lengths = np.concatenate(starts), np.concatenate(lengths)
    order = np.argsort(starts, kind="stable")
    starts, ends = starts[order], starts[order] + lengths[order]
    gaps = np.r_[starts[0], starts[1:] - ends[:-1]]
    found, notes = [], []
    skipped = int(gaps[gaps > 0].sum())
    if skipped:
        first = int(ends[np.flatnonzero(gaps > 0)[0] - 1]) if gaps[0] <= 0 else 0
        found.append(f"{skipped} bytes between messages had no message header and were skipped "
                     f"(in {int(np.count_nonzero(gaps > 0))} place(s), the first at byte {first})")
    last_end = int(ends[-1])
    if last_end > size:  # a power cut mid-write, or a copy cut short: said, as a text file's last line
        notes.append(f"the log ends inside its last message (at byte {int(starts[-1])}; cut off mid-write, or a "
                     "copy cut short?): not used")
    elif size - last_end > TRAILING_SLACK and not data[last_end:].any():
        notes.append(f"its last {size - last_end} bytes are zeros (a pre-allocated file's unused end?): not read")
    elif size - last_end > TRAILING_SLACK:
        found.append(f"reading stopped at byte {last_end} (a message type no FMT message defines): the last "
                     f"{size - last_end} of its {size} bytes were not read")
    said = noise.summary("pymavlink")
    return ((*found, said) if found and said else tuple(found)), tuple(notes)


def _indexed_reader(DFReader, content_end: int):
    class IndexedReader(DFReader.DFReader_binary):
        """DFReader's index and formats, with the plain microsecond clock: the samples' times are
        their own TimeUS here, and DFReader's search for a GPS time base parses every message of a
        log with no GPS fix (a bench recording) one by one in Python, ~10 µs each.

        It indexes the file up to ``content_end`` only: a pre-allocated file's zero end would be
        walked byte by byte ("bad header" for each: a minute per 60 MB)."""

        def init_arrays_fast(self, progress_callback=None):
            self._map_content()
            super().init_arrays_fast(progress_callback)

        def init_arrays(self, progress_callback=None):
            self._map_content()
            super().init_arrays(progress_callback)

        def _map_content(self):
            import mmap

            if content_end < self.data_len:
                self.data_map.close()
                self.data_map = mmap.mmap(self.filehandle.fileno(), content_end, mmap.MAP_PRIVATE, mmap.PROT_READ)
                self.data_len = content_end

        def init_clock(self):
            self._rewind(keep_messages=True)
            self.init_clock_usec()

    return IndexedReader


def _imu(path, log, data, instance):
    columns = log.formats[log.name_to_id["IMU"]].columns
    if "I" in columns:  # one message name, an instance column
        values = _messages(path, log, data, "IMU")
        instances = np.unique(values["I"]).tolist()
        if instance not in instances:
            raise RecordingImportError(f"{path}: no IMU instance {instance}; the log has "
                                       f"{', '.join(map(str, instances))} (choose with --imu N)", path)
        values = values[values["I"] == instance]
        message, name = "IMU", f"IMU instance {instance}"
    else:
        present = [i for i, n in enumerate(LEGACY_NAMES) if n in log.name_to_id and log.counts[log.name_to_id[n]]]
        if instance not in present:
            raise RecordingImportError(f"{path}: no IMU instance {instance}; the log has "
                                       f"{', '.join(map(str, present))} (choose with --imu N)", path)
        message = LEGACY_NAMES[instance]
        values = _messages(path, log, data, message)
        name = f"{message} (instance {instance})"
    t = _seconds(path, values, "TimeUS")
    return t, _triad(path, values, message, "Acc"), _triad(path, values, message, "Gyr"), name, ()


def _acc_gyr(path, log, data, instance):
    acc_v, gyr_v = _messages(path, log, data, "ACC"), _messages(path, log, data, "GYR")
    if "I" in acc_v.dtype.names:
        have = sorted(set(np.unique(acc_v["I"]).tolist()) & set(np.unique(gyr_v["I"]).tolist()))
        if instance not in have:
            raise RecordingImportError(f"{path}: no ACC and GYR instance {instance}; the log has "
                                       f"{', '.join(map(str, have)) or 'none'} (choose with --imu N)", path)
        acc_v, gyr_v = acc_v[acc_v["I"] == instance], gyr_v[gyr_v["I"] == instance]
    elif instance != 0:
        raise RecordingImportError(f"{path}: the log's ACC and GYR have no instance column: only --imu 0", path)
    # SampleUS is when the sensor sampled; TimeUS when it was logged (batched, later).
    clock = "SampleUS" if "SampleUS" in acc_v.dtype.names else "TimeUS"
    t, tg = _seconds(path, acc_v, clock), _seconds(path, gyr_v, clock)
    acc = _triad(path, acc_v, "ACC", "Acc")
    gyro = np.column_stack([np.interp(t, tg, column) for column in _triad(path, gyr_v, "GYR", "Gyr").T])
    return t, acc, gyro, f"ACC + GYR instance {instance}", (
        "gyroscope interpolated onto the accelerometer's time",)


_TRIAD_UNITS = {"Acc": "m/s²", "Gyr": "rad/s"}


def _triad(path: str, values: np.ndarray, message: str, prefix: str) -> np.ndarray:
    """(n, 3) float: the ``prefix``X/Y/Z columns of ``message``'s messages; a one-line error
    naming the file, the message and the columns missing when the log's FMT has not got them."""
    wanted = [f"{prefix}{a}" for a in "XYZ"]
    missing = [c for c in wanted if c not in values.dtype.names]
    if missing:
        raise RecordingImportError(
            f"{path}: its {message} messages have no {', '.join(missing)} column{'s' * (len(missing) > 1)} (they "
            f"have {', '.join(values.dtype.names)}); fieldcal reads {', '.join(wanted)} ({_TRIAD_UNITS[prefix]}) "
            "from IMU messages, or ACC and GYR: for another layout export the log as text and import it with "
            "--map naming its columns", path)
    return np.column_stack([values[c] for c in wanted]).astype(float)


def _seconds(path: str, values: np.ndarray, column: str) -> np.ndarray:
    """The messages' time in s: ``column`` (µs), or TimeMS (ms) in logs older than ArduPilot 3.3."""
    if column in values.dtype.names:
        return values[column] * 1e-6
    if "TimeMS" in values.dtype.names:
        return values["TimeMS"] * 1e-3
    raise RecordingImportError(f"{path}: its IMU messages have no time column (TimeUS or TimeMS): "
                               f"{', '.join(values.dtype.names)}", path)


def _messages(path: str, log, data: np.ndarray, name: str) -> np.ndarray:
    """Every ``name`` message of the log as a structured array with its own column names."""
    fmt = log.formats[log.name_to_id[name]]
    dtype = np.dtype([(column, _NUMPY_TYPES[code]) for column, code in zip(fmt.columns, fmt.msg_fmts)])
    offsets = np.asarray(log.offsets[log.name_to_id[name]], dtype=np.int64) + _HEADER_BYTES
    offsets = offsets[offsets + dtype.itemsize <= len(data)]  # a message cut off at the end of the log
    # Rows of the file's bytes at those offsets (a view of every window, then one copy of the rows).
    values = np.lib.stride_tricks.sliding_window_view(data, dtype.itemsize)[offsets].copy().view(dtype)[:, 0]
    if len(values):
        with contextlib.redirect_stdout(io.StringIO()):
            log.rewind()
            first = log.recv_match(type=name)
        checked = [c for c in fmt.columns if c in _CHECKED]
        if first is None or any(float(getattr(first, c)) != float(values[0][c]) for c in checked):
            raise RecordingImportError(f"{path}: its {name} messages are not laid out as the log's FMT says; "
                                       "the log is damaged", path)
    return values
