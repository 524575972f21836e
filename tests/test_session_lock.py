"""One writer per session (fieldcal.session.lock), tested on the lock itself: the note it leaves,
the refusal's line, the retries, and what a reader's probe says. flock locks belong to an open
file, so a second ``open`` in this process is a second writer (no subprocess needed)."""
import datetime
import fcntl
import os
import re
import socket

import pytest

from fieldcal.session import lock as session_lock
from fieldcal.session.lock import LOCK, SessionLock, SessionLockedError, is_held

NOTE = re.compile(r"pid (\d+) on (.+), started (\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ)\n")


def _flock_by_hand(directory, note: bytes = b""):
    """Another writer: an exclusive flock on ``directory``'s lock file with ``note`` in it."""
    fd = os.open(directory / LOCK, os.O_RDWR | os.O_CREAT)
    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    os.ftruncate(fd, 0)
    os.pwrite(fd, note, 0)
    return fd


def test_the_writer_notes_its_pid_host_and_start_time_over_an_older_note(tmp_path):
    (tmp_path / LOCK).write_text("pid 1 on an-old-host-with-a-long-name, started 2020-01-01T00:00:00Z\nmore\n")
    before = datetime.datetime.now(datetime.timezone.utc).replace(microsecond=0)
    held = SessionLock.acquire(tmp_path)
    after = datetime.datetime.now(datetime.timezone.utc)
    try:
        text = (tmp_path / LOCK).read_text(encoding="ascii")
        m = NOTE.fullmatch(text)  # the whole file: the old, longer note is gone
        assert m, text
        assert int(m.group(1)) == os.getpid() and m.group(2) == socket.gethostname()
        started = datetime.datetime.strptime(m.group(3), "%Y-%m-%dT%H:%M:%SZ").replace(tzinfo=datetime.timezone.utc)
        assert before <= started <= after
        assert held.held and held.directory == tmp_path
        assert is_held(tmp_path)
    finally:
        held.release()
    assert not held.held and not is_held(tmp_path)
    held.release()  # a second release does nothing
    SessionLock.acquire(tmp_path).release()  # and the session can be written again


def test_a_second_writer_is_refused_in_one_line_naming_the_holder(tmp_path, monkeypatch):
    slept = []
    monkeypatch.setattr(session_lock.time, "sleep", slept.append)
    first = SessionLock.acquire(tmp_path)
    try:
        note = (tmp_path / LOCK).read_text().strip()
        with pytest.raises(SessionLockedError) as refused:
            SessionLock.acquire(tmp_path)
    finally:
        first.release()
    assert str(refused.value) == (f"{tmp_path}: another fieldcal is writing this session ({note}); "
                                  "wait for it to finish or stop it first")
    assert refused.value.path == str(tmp_path / LOCK)
    # a reader's probe holds its shared lock for microseconds: ten tries, 20 ms apart, before refusing
    assert slept == [0.02] * 9


def test_a_lock_a_reader_probe_drops_meanwhile_is_taken(tmp_path, monkeypatch):
    probe = os.open(tmp_path / LOCK, os.O_RDONLY | os.O_CREAT)
    fcntl.flock(probe, fcntl.LOCK_SH | fcntl.LOCK_NB)
    slept = []

    def probe_done(seconds):
        slept.append(seconds)
        if len(slept) == 3:
            os.close(probe)

    monkeypatch.setattr(session_lock.time, "sleep", probe_done)
    try:
        SessionLock.acquire(tmp_path).release()
    finally:
        if len(slept) < 3:  # refused or taken before the probe was dropped: not left open
            os.close(probe)
    assert slept == [0.02] * 3


@pytest.mark.parametrize("note, said", [
    (b"", "a process that has not yet said who it is"),
    (b"   \n\n", "a process that has not yet said who it is"),
    (b"x" * 300 + b"\nsecond line\n", "x" * 200),  # its first line, cut to 200 characters
    (b"pid 7 on h\xff\n", "pid 7 on h\ufffd"),  # not ASCII: replaced, not a traceback
])
def test_the_refusal_quotes_the_holders_note_however_it_reads(tmp_path, monkeypatch, note, said):
    monkeypatch.setattr(session_lock.time, "sleep", lambda s: None)
    fd = _flock_by_hand(tmp_path, note)
    try:
        with pytest.raises(SessionLockedError) as refused:
            SessionLock.acquire(tmp_path)
    finally:
        os.close(fd)
    assert str(refused.value) == (f"{tmp_path}: another fieldcal is writing this session ({said}); "
                                  "wait for it to finish or stop it first")


def test_a_link_planted_at_the_lock_is_refused_and_its_target_untouched(tmp_path):
    target = tmp_path / "victim"
    target.write_bytes(b"precious")
    session = tmp_path / "s"
    session.mkdir()
    (session / LOCK).symlink_to(target)
    with pytest.raises(SessionLockedError) as refused:
        SessionLock.acquire(session)
    line = str(refused.value)
    assert line == (f"{session}: cannot write to this session ({session / LOCK}: is a symbolic link; fieldcal "
                    "never writes through a link (remove the link, or give another path))")
    assert refused.value.path == str(session / LOCK)
    assert target.read_bytes() == b"precious"


def test_a_missing_session_directory_is_one_line_naming_the_lock_file(tmp_path):
    missing = tmp_path / "nowhere"
    with pytest.raises(SessionLockedError) as refused:
        SessionLock.acquire(missing)
    assert str(refused.value) == (f"{missing}: cannot write to this session ({missing / LOCK}: cannot write "
                                  f"(no directory {missing}): {missing / LOCK})")
    assert refused.value.path == str(missing / LOCK)


def test_a_reader_probe_says_held_only_while_a_writer_holds_the_lock(tmp_path):
    assert not is_held(tmp_path)  # no lock file
    (tmp_path / LOCK).write_text("pid 1 on gone, started 2020-01-01T00:00:00Z\n")
    assert not is_held(tmp_path)  # a note left by a writer that ended
    fd = _flock_by_hand(tmp_path)
    try:
        assert is_held(tmp_path)
    finally:
        os.close(fd)
    assert not is_held(tmp_path)


def test_a_reader_probe_never_follows_a_link_at_the_lock(tmp_path):
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    fd = _flock_by_hand(elsewhere)  # a held lock, but another directory's
    try:
        session = tmp_path / "s"
        session.mkdir()
        (session / LOCK).symlink_to(elsewhere / LOCK)
        assert not is_held(session)
    finally:
        os.close(fd)


def test_the_start_time_is_utc_whatever_the_local_zone(tmp_path, monkeypatch):
    import time

    monkeypatch.setenv("TZ", "Asia/Kolkata")  # UTC+05:30 all year: a local time is never UTC's
    time.tzset()
    try:
        before = datetime.datetime.now(datetime.timezone.utc).replace(microsecond=0)
        SessionLock.acquire(tmp_path).release()
        after = datetime.datetime.now(datetime.timezone.utc)
    finally:
        monkeypatch.undo()
        time.tzset()
    started = NOTE.fullmatch((tmp_path / LOCK).read_text()).group(3)
    at = datetime.datetime.strptime(started, "%Y-%m-%dT%H:%M:%SZ").replace(tzinfo=datetime.timezone.utc)
    assert before <= at <= after


def test_a_host_name_beyond_ascii_is_noted_with_a_mark_not_refused(tmp_path, monkeypatch):
    monkeypatch.setattr(session_lock.socket, "gethostname", lambda: "hôte")
    SessionLock.acquire(tmp_path).release()
    assert (tmp_path / LOCK).read_bytes().startswith(f"pid {os.getpid()} on h?te, started ".encode())


def test_a_note_beyond_ascii_or_unreadable_still_gives_one_line(tmp_path, monkeypatch):
    monkeypatch.setattr(session_lock.time, "sleep", lambda s: None)
    fd = _flock_by_hand(tmp_path, "pid 7 on hôte\n".encode("utf-8"))  # the note is ASCII: read as such
    try:
        with pytest.raises(SessionLockedError, match="\\(pid 7 on h\ufffd\ufffdte\\); wait"):
            SessionLock.acquire(tmp_path)

        def unreadable(*args, **kwargs):
            raise PermissionError(13, "Permission denied")

        monkeypatch.setattr(session_lock.Path, "read_text", unreadable)
        with pytest.raises(SessionLockedError, match="\\(a process that has not yet said who it is\\); wait"):
            SessionLock.acquire(tmp_path)
    finally:
        os.close(fd)


def test_a_file_system_that_cannot_lock_reads_as_not_held(tmp_path, monkeypatch):
    import errno

    (tmp_path / LOCK).write_text("")

    def no_locks(fd, how):
        raise OSError(errno.ENOLCK, "No locks available")

    monkeypatch.setattr(session_lock.fcntl, "flock", no_locks)
    assert is_held(tmp_path) is False
