"""What a recording's reader is given, checked before it reads a byte of it.

- Only regular files (and a ROS 2 bag's directory of them) are read: a FIFO with no writer would
  block the import for ever, a character device (``/dev/zero``) never ends, and ``-`` is not
  standard input here. Each is refused in one line, whatever the format.
- A file whose bytes are mostly zeros is no recording: the holes of a sparse file, a logger's
  pre-allocated file of NULs after its data, zero pages. Every reader would otherwise read (and
  some hold, or parse byte by byte) all of it: a 2 GB sparse file took 86 s and 2.1 GB in the
  text reader, and pymavlink printed a line per byte for minutes. Files above ``CHECKED_BYTES``
  are measured first: holes by ``SEEK_DATA``/``SEEK_HOLE`` (no read at all), the rest a block at
  a time into one buffer, counting whole zero pages (a block with no NUL byte, as text has, has
  none: one memchr instead of a scan of its pages) and stopping as soon as the answer is known.
  Memory: one block. Time: none for holes, a read of at most the file's data bytes otherwise.
"""
from __future__ import annotations

import errno
import os
import stat
from pathlib import Path

import numpy as np

from fieldcal.atomic import file_kind
from fieldcal.recording.errors import RecordingImportError

CHECKED_BYTES = 1 << 20  # below this, no reader takes long whatever the bytes (pymavlink: ~1 s per MB of junk)
ZERO_FRACTION = 0.5  # of a file's bytes in holes and zero pages: refused above this
PAGE = 4096
BLOCK = 8 << 20  # bytes read at once while looking for a zero tail
COUNT_BLOCK = 1 << 20  # bytes read at once (into one buffer) while counting zero pages


def check_input(path: str | os.PathLike, what: str = "recording") -> None:
    """One-line RecordingImportError unless ``path`` is a regular file (or a directory: a ROS 2
    bag's, checked file by file) that is not mostly zeros. A path that does not exist is left to
    the reader's own error."""
    path = os.fspath(path)
    if path == "-":
        raise RecordingImportError(f"-: fieldcal reads a {what} from a file, not from standard input (a "
                                   "pipe): save it to a file and give that", path)
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return
    if stat.S_ISDIR(mode):
        for entry in sorted(Path(path).iterdir()):
            if not entry.is_dir():
                check_input(entry, what)
        return
    if not stat.S_ISREG(mode):
        raise RecordingImportError(f"{path}: is {file_kind(mode)}, not a file: fieldcal reads a {what} "
                                   "from a regular file (save the stream to a file and give that)", path)
    check_mostly_zeros(path)


def check_mostly_zeros(path: str) -> None:
    """Refuse a regular file above CHECKED_BYTES whose holes and zero pages exceed ZERO_FRACTION
    of its size."""
    try:
        with open(path, "rb", buffering=0) as f:
            size = os.fstat(f.fileno()).st_size
            if size <= CHECKED_BYTES:
                return
            zeros = _zero_bytes(f, size, limit=ZERO_FRACTION * size)
    except OSError as exc:
        raise RecordingImportError(f"{path}: cannot read it ({exc.strerror or exc})", path) from None
    if zeros > ZERO_FRACTION * size:
        raise RecordingImportError(
            f"{path}: at least {100 * zeros // size}% of its {size / 2**20:.0f} MiB are zeros (holes of a sparse "
            "file, a pre-allocated logger file, zero pages), not samples: cut the file to its data and "
            "import that", path)


def _data_regions(fd: int, size: int):
    """(start, end) of the parts of the file that hold data; the rest are holes (read as zeros).
    A file system without SEEK_DATA gives the whole file."""
    start = 0
    while start < size:
        try:
            start = os.lseek(fd, start, os.SEEK_DATA)
        except OSError as exc:
            if exc.errno == errno.ENXIO:  # no data after ``start``: a hole to the end
                return
            yield start, size  # SEEK_DATA not supported: all data
            return
        end = os.lseek(fd, start, os.SEEK_HOLE)
        yield start, end
        start = end


def _zero_bytes(f, size: int, limit: float) -> int:
    """Bytes in holes and whole zero pages, counted until the count passes ``limit`` or can no
    longer reach it (the file's remaining bytes too few)."""
    fd = f.fileno()
    data = 0
    regions = list(_data_regions(fd, size))
    holes = size - sum(end - start for start, end in regions)
    zeros = holes
    buffer = bytearray(COUNT_BLOCK)  # reused: fresh pages for every block cost more than reading them
    for start, end in regions:
        f.seek(start)
        position = start
        while position < end:
            if zeros > limit:
                return zeros
            if zeros + (size - holes - data) <= limit:  # even if the rest were zeros: not enough
                return zeros
            got = f.readinto(memoryview(buffer)[:min(COUNT_BLOCK, end - position)])
            if not got:
                break
            if buffer.find(0, 0, got) >= 0:  # else no byte, so no page, of it is zero
                whole = got // PAGE * PAGE
                pages = np.frombuffer(buffer, dtype=np.uint64, count=whole // 8).reshape(-1, PAGE // 8)
                zeros += PAGE * int(np.count_nonzero(~pages.any(axis=1)))
            data += got
            position += got
    return zeros


def zero_tail(path: str) -> tuple[int, int]:
    """(size, the zero bytes that end the file): a pre-allocated logger file's unused end, holes
    or NULs written out. Found from the end backwards (holes by SEEK_DATA, then blocks growing
    from 64 KiB), so a reader can leave them unread: its memory then follows the samples."""
    with open(path, "rb", buffering=0) as f:
        size = os.fstat(f.fileno()).st_size
        regions = list(_data_regions(f.fileno(), size))
        position = regions[-1][1] if regions else 0  # after the last data: a hole to the end
        step = 1 << 16
        while position > 0:
            start = max(0, position - step)
            f.seek(start)
            block = f.read(position - start)
            kept = len(block.rstrip(b"\0"))
            if kept:
                return size, size - (start + kept)
            position, step = start, min(2 * step, BLOCK)
        return size, size
