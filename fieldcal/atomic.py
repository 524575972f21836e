"""Files replaced whole or not at all: a temp file beside the target, fsync, then os.replace (or,
when the target must not be overwritten, os.link, which fails if the name is taken)."""
from __future__ import annotations

import os
import secrets
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


def write_atomically(path: str | os.PathLike, data: bytes, *, overwrite: bool = True,
                     hint: str = "") -> Path:
    """Write ``data`` to ``path`` so that a crash leaves the old file or the new one, never half.

    ``overwrite=False``: refuse (``WouldOverwrite``, naming the path and ``hint``) if ``path``
    exists, checked atomically at the moment the file appears, so two writers cannot both win.
    An OSError comes back as ``CannotWrite`` (an OSError and a ValueError) naming the path.
    """
    path = Path(path)
    if not overwrite and (path.exists() or path.is_symlink()):
        raise WouldOverwrite(path, hint)
    directory = path.parent
    tmp = directory / f".{path.name}.{secrets.token_hex(6)}.tmp"
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)  # umask applies, unlike mkstemp
    except OSError as exc:
        raise _cannot(path, exc) from None
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        if overwrite:
            os.replace(tmp, path)
        else:
            os.link(tmp, path)  # FileExistsError if another writer got there first
            os.unlink(tmp)
    except BaseException as exc:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        if isinstance(exc, FileExistsError) and not overwrite:
            raise WouldOverwrite(path, hint) from None
        if isinstance(exc, OSError):
            raise _cannot(path, exc) from None
        raise
    try:  # make the rename itself durable; not possible everywhere (e.g. Windows)
        dir_fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return path
    try:
        os.fsync(dir_fd)
    except OSError:
        pass
    finally:
        os.close(dir_fd)
    return path


def _cannot(path: Path, exc: OSError) -> CannotWrite:
    what = exc.strerror or type(exc).__name__
    if isinstance(exc, FileNotFoundError) and not path.parent.is_dir():
        what = f"no directory {path.parent}"
    elif isinstance(exc, IsADirectoryError) or path.is_dir():
        what = "it is a directory"
    return CannotWrite(exc.errno, f"{path}: cannot write ({what})")
