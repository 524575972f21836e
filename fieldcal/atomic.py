"""Every file fieldcal writes goes through one rule (DESIGN principle 11), here:

* never through a symbolic link (fieldcal writes no file through a link it did not create: a
  link planted in a copied session or beside an output would aim the write at any file the
  station user can write), nor into a FIFO or device;
* never over a file the command itself read (its config, procedure, parameter file: noted by
  ``note_read``) nor over one of its inputs, even with ``--force``;
* never over an existing file unless the caller allows it (``--force``);
* whole or not at all: a temp file beside the target (created exclusively, so never through a
  link), fsync, then ``os.replace`` (or, when the target must not be overwritten, ``os.link``,
  which fails if the name is taken);
* every error names the path the user gave, never the hidden temp file.

``check_target`` says the same refusals before a command's long work starts.

Directories fieldcal creates (sessions, plot folders) follow the same rule: ``directory_for_files``
(a folder the user named, whose files each go through the rule), ``new_directory`` (a session's,
created exclusively) and ``new_named_directory`` (a name fieldcal picks, e.g. by the second:
the next free one, never one planted before it). A name the user gave that is a link is refused,
whatever it points at.
"""
from __future__ import annotations

import contextlib
import errno
import os
import secrets
import stat
from collections.abc import Iterable, Iterator
from pathlib import Path


class WouldOverwrite(FileExistsError, ValueError):
    """The target exists and overwriting was not allowed; one line naming the path.

    A ValueError too, so the command line prints it as a one-line error."""

    def __init__(self, path: Path, hint: str = "") -> None:
        self.message = f"{path}: already exists; not overwritten{f' ({hint})' if hint else ''}"
        super().__init__(self.message)
        self.path = path

    def __str__(self) -> str:
        return self.message


class CannotWrite(OSError, ValueError):
    """The target could not be written (missing directory, no permission, disk full, ...)."""

    def __str__(self) -> str:
        return self.strerror


class RefusedTarget(ValueError):
    """A write the rule refuses whatever the options (a link, an input of the command, not a
    regular file); one line naming the path."""

    def __init__(self, message: str, path: Path) -> None:
        super().__init__(message)
        self.path = path


# -- the files this command read ---------------------------------------------------------------

# (st_dev, st_ino) of every file read since the command began; None outside a command, so that
# library callers (and tests) that read a file and save to it are not refused.
_read_files: set[tuple[int, int]] | None = None


@contextlib.contextmanager
def command_reads() -> Iterator[None]:
    """Within: every file noted by ``note_read`` is refused as a write target."""
    global _read_files
    previous, _read_files = _read_files, set()
    try:
        yield
    finally:
        _read_files = previous


def note_read(st: os.stat_result) -> None:
    """A file this command read (its ``fstat``): never written over, even with ``--force``."""
    if _read_files is not None and stat.S_ISREG(st.st_mode):
        _read_files.add((st.st_dev, st.st_ino))


def _identity(path) -> tuple[int, int] | None:
    try:
        st = os.stat(path)
    except (OSError, ValueError):
        return None
    return st.st_dev, st.st_ino


def file_kind(mode: int) -> str:
    """What a path that is no regular file is, for a one-line refusal: "a character device"..."""
    if stat.S_ISREG(mode):
        return "a file"
    if stat.S_ISDIR(mode):
        return "a directory"
    if stat.S_ISFIFO(mode):
        return "a FIFO (named pipe)"
    if stat.S_ISCHR(mode):
        return "a character device"
    if stat.S_ISBLK(mode):
        return "a block device"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "not a regular file"


def _lstat_refusing_a_link(path: Path, label: str, advice: str) -> os.stat_result | None:
    """``path``'s own status (None: nothing there), refused in one line if it is a link: every
    write fieldcal makes looks at the name itself, never at what a link points to."""
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return None
    except OSError as exc:
        raise _cannot(path, exc) from None
    if stat.S_ISLNK(st.st_mode):
        raise RefusedTarget(f"{label}: is a symbolic link; fieldcal never writes through a link ({advice})", path)
    return st


# -- the checks --------------------------------------------------------------------------------

def check_target(path: str | os.PathLike, *, force: bool = False, inputs: Iterable = (),
                 hint: str = "give --force to replace it", option: str = "", state: bool = False) -> Path:
    """Refuse writing ``path`` as ``write_atomically`` would, before any work: a link, a directory,
    a FIFO or device, an ``inputs`` file or one this command read (even with ``force``), an
    existing file without ``force``. ``option`` (e.g. ``--out``) prefixes the message.
    ``state``: a file fieldcal keeps for itself (the TUI's remembered setup), read and then
    replaced by design: not refused for having been read."""
    p = Path(path)
    label = f"{option} {p}" if option else str(p)
    st = _lstat_refusing_a_link(p, label, "remove the link, or give another path")
    if st is None:
        return p
    if stat.S_ISDIR(st.st_mode):
        raise RefusedTarget(f"{label}: is a directory; give a file name", p)
    if not stat.S_ISREG(st.st_mode):
        raise RefusedTarget(f"{label}: not a regular file (a FIFO, socket or device); not written", p)
    here = (st.st_dev, st.st_ino)
    for source in inputs:
        if source is not None and _identity(source) == here:
            raise RefusedTarget(f"{label} is the input {source} of this command: never written over, "
                                "even with --force; give another path", p)
    if not state and _read_files is not None and here in _read_files:
        raise RefusedTarget(f"{label}: this command read that file (its config, procedure or "
                            "parameter file); never written over, even with --force: give another path", p)
    if not force:
        raise WouldOverwrite(p, hint)
    return p


def check_appendable(path: str | os.PathLike, option: str = "") -> Path:
    """A file fieldcal adds to (a session's log, a registry): a regular file or none, never a link."""
    return check_target(path, force=True, option=option)


def open_nofollow(path: str | os.PathLike, flags: int, mode: int = 0o666) -> int:
    """``os.open`` that never follows a link at ``path`` and never blocks on a FIFO; the file
    must be regular. RefusedTarget or CannotWrite naming ``path``."""
    p = Path(path)
    try:
        fd = os.open(p, flags | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC, mode)
    except OSError as exc:
        if exc.errno == errno.ELOOP or (exc.errno == errno.EEXIST and p.is_symlink()):
            check_target(p, force=True)  # says which (a link)
        if exc.errno == errno.ENXIO:  # a FIFO with no reader
            raise RefusedTarget(f"{p}: not a regular file (a FIFO); not written", p) from None
        raise _cannot(p, exc) from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise RefusedTarget(f"{p}: not a regular file (a FIFO, socket or device); not written", p)
        if flags & (os.O_WRONLY | os.O_RDWR):
            refuse_other_names(p, st)
        os.set_blocking(fd, True)
    except BaseException:
        os.close(fd)
        raise
    return fd


def refuse_other_names(path: str | os.PathLike, st: os.stat_result | None = None) -> None:
    """A file changed in place (appended to, cut, locked) must have no other name: with a hard
    link elsewhere, the change would change that file too, outside what fieldcal owns."""
    try:
        st = st or os.lstat(path)
    except FileNotFoundError:
        return
    if stat.S_ISREG(st.st_mode) and st.st_nlink > 1:
        raise RefusedTarget(f"{path}: has {st.st_nlink} names (hard links); fieldcal never changes a file "
                            "that is also elsewhere (the other name's content would change too): copy the "
                            "session (cp -r makes separate files) and use the copy", Path(path))


def open_append(path: str | os.PathLike, *, new: bool = False):
    """A binary file opened for appending (``new``: created, refused if the name is taken),
    never through a link."""
    flags = os.O_WRONLY | os.O_APPEND | os.O_CREAT | (os.O_EXCL if new else 0)
    return os.fdopen(open_nofollow(path, flags), "ab")


# -- directories -------------------------------------------------------------------------------

# Names fieldcal tries after a taken one (``stem-2`` ... ): a planted link or a second run in the
# same second takes one; more taken than this is no accident.
NAME_TRIES = 100


def _refuse_link_or_file(path: Path, label: str) -> bool:
    """True if ``path`` is a directory (not a link to one); False if nothing is there."""
    st = _lstat_refusing_a_link(path, label, "give the directory it points at, or another path")
    if st is None:
        return False
    if not stat.S_ISDIR(st.st_mode):
        raise RefusedTarget(f"{label}: exists and is not a directory", path)
    return True


def directory_for_files(path: str | os.PathLike, option: str = "") -> Path:
    """A folder fieldcal writes files in (each through the rule), created with its missing parents
    if need be. Refused in one line: a link at ``path`` (the user named a link), a file there.
    Links among the parents are the user's file system's layout and are followed."""
    p = Path(path)
    label = f"{option} {p}" if option else str(p)
    if _refuse_link_or_file(p, label):
        return p
    if p.parent != p and not p.parent.exists():
        directory_for_files(p.parent, option)
    try:
        os.mkdir(p)  # never exist_ok: a name taken meanwhile is looked at again, never trusted
    except FileExistsError:
        _refuse_link_or_file(p, label)
    except OSError as exc:
        raise _cannot(p, exc) from None
    return p


def new_directory(path: str | os.PathLike, *, option: str = "", empty_ok: bool = True) -> Path:
    """A new session's directory: created by ``os.mkdir``, which fails on any existing name, a
    link included (dangling or not), so nothing is written through a link planted there. An
    existing empty directory (not a link) is taken when ``empty_ok`` (the user made it for this);
    anything else at ``path`` is refused in one line."""
    p = Path(path)
    label = f"{option} {p}" if option else str(p)
    if p.parent != p and not p.parent.exists() and not p.parent.is_symlink():
        directory_for_files(p.parent)
    try:
        os.mkdir(p)
        return p
    except FileExistsError:
        pass
    except OSError as exc:
        raise _cannot(p, exc) from None
    _refuse_link_or_file(p, label)
    if not empty_ok or any(os.scandir(p)):
        raise RefusedTarget(f"{label}: already exists and is not empty (a new session needs a new "
                            "directory; to continue this one, resume it)", p)
    return p


def new_named_directory(base: str | os.PathLike, stem: str, *, option: str = "") -> Path:
    """A new directory ``base/stem`` that fieldcal names itself (a session named by the second):
    created exclusively, or the next free ``stem-2``, ``stem-3``... when the name is taken (a
    second run in the same second, or a link planted at the names to come). ``base`` as in
    ``directory_for_files``."""
    base = directory_for_files(base, option)
    for i in range(1, NAME_TRIES + 1):
        candidate = base / (stem if i == 1 else f"{stem}-{i}")
        try:
            os.mkdir(candidate)
            return candidate
        except FileExistsError:
            continue
        except OSError as exc:
            raise _cannot(candidate, exc) from None
    raise RefusedTarget(f"{base / stem}: this name and the next {NAME_TRIES - 1} are taken (by links or "
                        "files planted there?); look at what is in the folder, or give another --out", base / stem)


# -- writing -----------------------------------------------------------------------------------

class _Pending:
    """The hidden temp file of one atomic write; ``keep = False`` drops it at the end."""

    def __init__(self, file) -> None:
        self.file = file
        self.keep = True


@contextlib.contextmanager
def atomic_file(path: str | os.PathLike, *, overwrite: bool = True, hint: str = "",
                inputs: Iterable = (), state: bool = False) -> Iterator[_Pending]:
    """Write ``pending.file`` (binary); at a clean exit it becomes ``path`` whole, unless
    ``pending.keep`` was set False. The rule of this module applies (``check_target``)."""
    path = Path(path)
    inputs = tuple(inputs)
    check_target(path, force=overwrite, inputs=inputs, hint=hint, state=state)
    directory = path.parent
    # The directory is held open from here: the temp file, the last check and the rename all act
    # in it by fd, so a link or another directory swapped in for it (or for a folder above it) later
    # cannot move the write elsewhere; the rename replaces whatever is at the name (a link slipped
    # in after the check included), never writes through it. What is left: a swap between the
    # check above and this open, a window of microseconds open only to someone who can rename
    # entries of the folder above, who could write the file there anyway.
    try:
        dir_fd = os.open(directory, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
    except OSError as exc:
        raise _cannot(path, exc) from None
    try:
        yield from _write_in(dir_fd, path, overwrite, hint, inputs, state)
    finally:
        os.close(dir_fd)


def _write_in(dir_fd: int, path: Path, overwrite: bool, hint: str, inputs: tuple, state: bool):
    """The body of ``atomic_file``, every name relative to the folder held open as ``dir_fd``."""
    tmp = f".{path.name}.{secrets.token_hex(6)}.tmp"
    try:  # O_EXCL: never through a link planted at the temp name; umask applies, unlike mkstemp
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC, 0o666,
                     dir_fd=dir_fd)
    except OSError as exc:
        raise _cannot(path, exc) from None
    try:
        with os.fdopen(fd, "wb") as fh:
            pending = _Pending(fh)
            try:
                yield pending
            except OSError as exc:  # the caller's write failed (a full disk): name the target
                if exc.filename is None and exc.errno in _WRITE_ERRNOS:
                    raise _cannot(path, exc) from None
                raise _Callers(exc) from exc
            if not pending.keep:
                raise _Discard
            fh.flush()
            os.fsync(fh.fileno())
        check_target(path, force=overwrite, inputs=inputs, hint=hint, state=state)  # again: the work took time
        names = {"src_dir_fd": dir_fd, "dst_dir_fd": dir_fd}
        if overwrite:
            os.replace(tmp, path.name, **names)  # replaces a name, never writes through one
        else:
            os.link(tmp, path.name, follow_symlinks=False, **names)  # FileExistsError if the name is taken
            os.unlink(tmp, dir_fd=dir_fd)
    except _Discard:
        _unlink(tmp, dir_fd)
        return
    except _Callers as wrapped:  # the caller's own error (reading its input, say): as it was
        _unlink(tmp, dir_fd)
        raise wrapped.error from None
    except BaseException as exc:
        _unlink(tmp, dir_fd)
        if isinstance(exc, FileExistsError) and not overwrite:
            raise WouldOverwrite(path, hint) from None
        if isinstance(exc, OSError) and not isinstance(exc, CannotWrite):
            raise _cannot(path, exc) from None
        raise
    try:
        os.fsync(dir_fd)  # the rename made durable
    except OSError:
        pass


_WRITE_ERRNOS = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EIO, errno.EROFS)


class _Discard(Exception):
    pass


class _Callers(Exception):
    def __init__(self, error: OSError) -> None:
        self.error = error


def write_atomically(path: str | os.PathLike, data: bytes, *, overwrite: bool = True,
                     hint: str = "", inputs: Iterable = (), state: bool = False) -> Path:
    """Write ``data`` to ``path`` so that a crash leaves the old file or the new one, never half.

    ``overwrite=False``: refuse (``WouldOverwrite``, naming the path and ``hint``) if ``path``
    exists, checked atomically at the moment the file appears, so two writers cannot both win.
    Refused whatever ``overwrite`` says: a link, a non-regular file, one of ``inputs``, a file
    this command read (``RefusedTarget``). An OSError comes back as ``CannotWrite`` (an OSError
    and a ValueError) naming the path.
    """
    with atomic_file(path, overwrite=overwrite, hint=hint, inputs=inputs, state=state) as pending:
        pending.file.write(data)
    return Path(path)


def _unlink(path, dir_fd: int | None = None) -> None:
    try:
        os.unlink(path, dir_fd=dir_fd)
    except FileNotFoundError:
        pass


def _cannot(path: Path, exc: OSError) -> CannotWrite:
    what = exc.strerror or type(exc).__name__
    if isinstance(exc, FileNotFoundError) and not path.parent.is_dir():
        what = f"no directory {path.parent}"
    elif isinstance(exc, IsADirectoryError) or path.is_dir():
        what = "it is a directory"
    return CannotWrite(exc.errno, f"{path}: cannot write ({what})")
