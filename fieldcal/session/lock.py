"""One writer per session: an OS file lock (``flock``) on ``<session>/lock``.

The writer holds an exclusive ``flock`` on the lock file for as long as it is open, and writes
who it is into the file (PID, host, start time) so that a refused second writer can say who holds
it. The kernel drops the lock when the holder's process dies, however it dies (SIGKILL
included), so a lock left by a dead process is simply taken over: no PID guessing, no stale-lock
heuristics. The file itself is never deleted (deleting a flock'ed file lets two processes each
lock a different inode); its text is only a note, the lock is the kernel's.

Readers do not take the lock; ``is_held`` tells them whether a writer is live (then bytes beyond
the log's last entry are a write in progress, not damage).
"""
from __future__ import annotations

import datetime
import fcntl
import os
import socket
import time
from pathlib import Path

LOCK = "lock"
# A reader's probe holds a shared lock for microseconds; a writer retries for this long before
# taking a refusal as a real second writer.
_RETRY_S, _RETRY_TRIES = 0.02, 10


class SessionLockedError(ValueError):
    """Another process is writing this session; the message is one line naming it."""

    def __init__(self, message: str, path: str = "") -> None:
        super().__init__(message)
        self.path = path


def _holder(path: Path) -> str:
    try:
        text = path.read_text(encoding="ascii", errors="replace").strip()
    except OSError:
        text = ""
    return text.splitlines()[0][:200] if text else "a process that has not yet said who it is"


class SessionLock:
    """The exclusive lock of one session directory, held until ``release()``."""

    def __init__(self, directory: Path, fd: int) -> None:
        self.directory = directory
        self._fd: int | None = fd

    @classmethod
    def acquire(cls, directory: str | os.PathLike) -> SessionLock:
        """Lock ``directory`` (an existing directory) or refuse in one line naming the holder."""
        from fieldcal.atomic import RefusedTarget, open_nofollow

        d = Path(directory)
        path = d / LOCK
        try:  # never through a link planted at ``lock`` (the note would land in its target)
            fd = open_nofollow(path, os.O_RDWR | os.O_CREAT)
        except RefusedTarget as exc:
            raise SessionLockedError(f"{d}: cannot write to this session ({exc})", str(path)) from None
        except OSError as exc:
            raise SessionLockedError(f"{d}: cannot write to this session ({exc.strerror or exc}: "
                                     f"{path})", str(path)) from None
        for attempt in range(_RETRY_TRIES):
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if attempt + 1 < _RETRY_TRIES:
                    time.sleep(_RETRY_S)
        else:
            os.close(fd)
            raise SessionLockedError(f"{d}: another fieldcal is writing this session ({_holder(path)}); "
                                     "wait for it to finish or stop it first", str(path))
        started = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")
        note = f"pid {os.getpid()} on {socket.gethostname()}, started {started}\n".encode("ascii", "replace")
        try:
            os.ftruncate(fd, 0)
            os.pwrite(fd, note, 0)
        except OSError:
            pass  # the note is a courtesy; the flock is the lock
        return cls(d, fd)

    def release(self) -> None:
        if self._fd is not None:
            fd, self._fd = self._fd, None
            os.close(fd)  # closing the only descriptor drops the flock

    @property
    def held(self) -> bool:
        return self._fd is not None


def is_held(directory: str | os.PathLike) -> bool:
    """Is a writer holding ``directory``'s lock right now? (False when there is no lock file.)"""
    try:
        fd = os.open(Path(directory) / LOCK, os.O_RDONLY | os.O_CLOEXEC | os.O_NOFOLLOW | os.O_NONBLOCK)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    except OSError:
        return False
    finally:
        os.close(fd)
    return False
