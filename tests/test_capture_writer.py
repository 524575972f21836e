"""The session writer's and reader's edges that whole runs do not show (session/capture.py's
mutants from `SessionWriter.create` on): its defaults, the paths its refusals name, each checked
against the files on disk or the format's own words."""
from __future__ import annotations

import os

import pytest

import fieldcal.session.capture as capture
from fieldcal.session import SessionError
from fieldcal.session.capture import SessionWriter


def _fsyncs(monkeypatch) -> list[int]:
    synced: list[int] = []
    real_fsync = os.fsync
    monkeypatch.setattr(capture.os, "fsync", lambda fd: (synced.append(fd), real_fsync(fd)))
    return synced


def test_by_default_the_writer_syncs_once_a_second(tmp_path, monkeypatch):
    synced = _fsyncs(monkeypatch)
    now = [50.0]
    w = SessionWriter.create(tmp_path / "s", {}, clock=lambda: now[0])  # the default interval
    synced.clear()
    now[0] = 50.999
    w.event({"kind": "x"})
    assert synced == []
    now[0] = 51.0
    w.event({"kind": "y"})
    assert len(synced) == 2  # samples, then the log: one second after the last sync
    w.close()


def test_a_directory_that_cannot_be_a_new_session_is_the_errors_path(tmp_path):
    used = tmp_path / "used"
    used.mkdir()
    (used / "notes.txt").write_text("the operator's")
    with pytest.raises(SessionError) as caught:
        SessionWriter.create(used, {})
    assert caught.value.path == str(used)
    assert str(caught.value) == (f"{used}: already exists and is not empty (a new session needs a new "
                                 "directory; to continue this one, resume it)")
    assert (used / "notes.txt").read_text() == "the operator's" and sorted(os.listdir(used)) == ["notes.txt"]
    a_file = tmp_path / "file"
    a_file.write_text("x")
    with pytest.raises(SessionError) as caught:
        SessionWriter.create(a_file, {})
    assert (str(caught.value), caught.value.path) == (f"{a_file}: exists and is not a directory", str(a_file))


def test_a_log_that_cannot_be_opened_is_one_line_and_leaves_the_directory_unlocked(tmp_path, monkeypatch):
    from fieldcal.session.lock import SessionLock

    def refuse(path, new=False):
        raise PermissionError(13, "Permission denied", str(path))

    monkeypatch.setattr(capture, "open_append", refuse)
    d = tmp_path / "s"
    with pytest.raises(SessionError) as caught:
        SessionWriter.create(d, {})
    assert (str(caught.value), caught.value.path) == (f"{d}: cannot write the session (Permission denied)", str(d))
    SessionLock.acquire(d).release()  # not left held by the refused writer


def test_a_raw_write_with_a_bad_time_or_name_is_refused_before_any_byte(tmp_path):
    w = SessionWriter.create(tmp_path / "s", {})
    log_before = (tmp_path / "s" / capture.LOG).read_bytes()
    with pytest.raises(TypeError) as caught:
        w.write_raw("imu", object(), b"\x01\x02")
    assert str(caught.value) == ("t: a object is not JSON-able (use dicts with string keys, lists, strings, numbers, "
                                 "bools, None, numpy arrays)")
    with pytest.raises(TypeError) as caught:
        w.write_raw("imu", True, b"\x01\x02")
    assert str(caught.value) == "raw t: expected a number, got True"
    with pytest.raises(ValueError) as caught:
        w.write_raw("../imu", 1.0, b"\x01\x02")
    assert str(caught.value) == "raw stream name: expected letters, digits, '_', '.', '-' (at most 64), got '../imu'"
    assert sorted(p.name for p in (tmp_path / "s").iterdir() if p.name.startswith("raw")) == []
    assert (tmp_path / "s" / capture.LOG).read_bytes() == log_before
    w.close()


def test_a_raw_streams_file_is_opened_once_and_its_bytes_follow_each_other(tmp_path, monkeypatch):
    """A live device writes thousands of pieces: a descriptor each would run the process out."""
    opened = []
    real_open_append = capture.open_append
    monkeypatch.setattr(capture, "open_append", lambda path, **kw: (opened.append(path.name), real_open_append(path, **kw))[1])
    w = SessionWriter.create(tmp_path / "s", {})
    for i in range(3):
        w.write_raw("imu", float(i), bytes([i, 255 - i]))
    w.close()
    assert opened.count("raw-imu.bin") == 1
    assert (tmp_path / "s" / "raw-imu.bin").read_bytes() == b"\x00\xff\x01\xfe\x02\xfd"


def test_a_log_found_in_the_new_directory_is_refused_as_a_session_already(tmp_path, monkeypatch):
    """new_directory refuses a directory that is not empty; a log appearing between that and the
    writer's own open (another process) is still refused, in words."""
    real_new_directory = capture.new_directory

    def racing(d):
        real_new_directory(d)
        (d / capture.LOG).write_text("")

    monkeypatch.setattr(capture, "new_directory", racing)
    d = tmp_path / "s"
    with pytest.raises(SessionError) as caught:
        SessionWriter.create(d, {})
    assert (str(caught.value), caught.value.path) == (
        f"{d}: already a session (a new session needs a new directory; to continue this one, resume it)", str(d))


def test_a_named_parameter_file_is_never_written_over(tmp_path):
    from tests.test_session import _parameter_file

    d = tmp_path / "s"
    w = SessionWriter.create(d, {})
    w.stop("imported")
    w.write_parameters(_parameter_file(0.01), "cal.yaml")
    assert w.parameters_written == d / "cal.yaml"  # what calibrate and resolve report as theirs
    first = (d / "cal.yaml").read_bytes()
    log_before = (d / capture.LOG).read_bytes()
    with pytest.raises(ValueError) as caught:
        w.write_parameters(_parameter_file(0.02), "cal.yaml")
    assert str(caught.value) == f"{d / 'cal.yaml'}: already exists; not overwritten (a session's files are never overwritten)"
    assert (d / "cal.yaml").read_bytes() == first and (d / capture.LOG).read_bytes() == log_before
    w.write_parameters(_parameter_file(0.03))
    assert w.parameters_written == d / "parameters-001.yaml"  # the numbered file, not parameters.yaml
    w.close()


def test_a_resumes_data_that_is_no_mapping_is_refused_naming_the_resume(tmp_path):
    w = SessionWriter.create(tmp_path / "s", {})
    w.stop("aborted")
    log_before = (tmp_path / "s" / capture.LOG).read_bytes()
    with pytest.raises(TypeError) as caught:
        w.resume([1, 2])
    assert str(caught.value) == "resume: expected a dict, got a list"
    assert (tmp_path / "s" / capture.LOG).read_bytes() == log_before
    w.resume({"why": "power came back"})  # the writer is not failed by the refusal
    w.close()


@pytest.mark.parametrize("name", [capture.LOG, capture.SAMPLES])
def test_a_file_that_appears_as_the_writer_opens_it_is_not_appended_to(tmp_path, monkeypatch, name):
    """Another process creating the log or the samples file at the very moment: the writer's
    exclusive open refuses."""
    real_open_append = capture.open_append

    def racing(path, **kw):
        if path.name == name:
            path.write_bytes(b"another writer's bytes\n")
        return real_open_append(path, **kw)

    monkeypatch.setattr(capture, "open_append", racing)
    d = tmp_path / "s"
    with pytest.raises(SessionError) as caught:
        SessionWriter.create(d, {})
    assert str(caught.value) == f"{d}: cannot write the session ({d / name}: cannot write (File exists))"
    assert (d / name).read_bytes() == b"another writer's bytes\n"


def test_an_active_or_completed_run_is_not_resumed(tmp_path):
    d = tmp_path / "s"
    w = SessionWriter.create(d, {})
    with pytest.raises(capture.SessionStateError) as caught:
        w.resume()
    assert str(caught.value) == f"{d}: cannot resume: the run is still active"
    w.stop("completed")  # line 2, after the start document
    with pytest.raises(SessionError) as caught:
        w.resume()
    assert str(caught.value) == (f"{d / capture.LOG}: line 2: this session completed; a completed session is "
                                 "never resumed (replay it, or run again into a new directory)")
    assert (caught.value.path, caught.value.line) == (str(d / capture.LOG), 2)
    w.close()


def test_a_full_disk_at_the_start_names_the_log_and_leaves_the_directory_unlocked(tmp_path, monkeypatch):
    from fieldcal.session.lock import SessionLock

    def full(self):
        raise OSError(28, "No space left on device")  # a buffered write's error names no file

    monkeypatch.setattr(SessionWriter, "sync", full)
    real_open_append = capture.open_append
    # their closes fail the same way (what is left to flush): the first error is the one said
    monkeypatch.setattr(capture, "open_append", lambda path, **kw: _CloseFails(real_open_append(path, **kw)))
    d = tmp_path / "s"
    with pytest.raises(OSError) as caught:
        SessionWriter.create(d, {})
    assert (caught.value.errno, caught.value.filename) == (28, str(d / capture.LOG))
    SessionLock.acquire(d).release()


class _CloseFails:
    """A file whose close's last flush fails (a full disk), as the writer's files can."""

    def __init__(self, fh):
        self._fh = fh

    def __getattr__(self, name):
        return getattr(self._fh, name)

    def close(self):
        self._fh.close()
        raise OSError(28, "No space left on device")


def test_a_close_that_fails_on_a_healthy_writer_is_said_and_still_unlocks(tmp_path):
    from fieldcal.session.lock import SessionLock

    d = tmp_path / "s"
    w = SessionWriter.create(d, {})
    w._samples = _CloseFails(w._samples)
    with pytest.raises(OSError) as caught:
        w.close()
    assert caught.value.errno == 28 and w.closed
    SessionLock.acquire(d).release()


def test_a_session_file_with_a_second_name_is_not_appended_to(tmp_path):
    d = tmp_path / "s"
    SessionWriter.create(d, {}).close()
    os.link(d / capture.LOG, tmp_path / "elsewhere.jsonl")
    with pytest.raises(SessionError) as caught:
        SessionWriter.append_to(d)
    assert str(caught.value) == (
        f"{d / capture.LOG}: has 2 names (hard links); fieldcal never changes a file that is also elsewhere (the "
        "other name's content would change too): copy the session (cp -r makes separate files) and use the copy")
    assert caught.value.path == str(d / capture.LOG)


def test_a_damaged_record_found_before_appending_names_the_samples_file(tmp_path):
    from tests.test_session import small_chunk

    d = tmp_path / "s"
    w = SessionWriter.create(d, {})
    w.chunk(small_chunk(0))  # seq 2, after the start document and the chunk's descriptor: log line 3
    w.stop("aborted")
    w.close()
    samples = bytearray((d / capture.SAMPLES).read_bytes())
    samples[:4] = b"XXXX"  # the record's magic
    (d / capture.SAMPLES).write_bytes(bytes(samples))
    with pytest.raises(SessionError) as caught:
        SessionWriter.append_to(d)
    assert str(caught.value) == f"{d / capture.SAMPLES}: chunk 2 at byte 0 (log line 3): bad record magic b'XXXX'"
    assert (caught.value.path, caught.value.line) == (str(d / capture.SAMPLES), 3)


def test_a_corrupt_raw_read_is_named_by_its_file_byte_and_log_line(tmp_path):
    from fieldcal.session.capture import SessionReader

    d = tmp_path / "s"
    w = SessionWriter.create(d, {})
    w.write_raw("imu", 0.5, b"ab")  # log line 2
    w.write_raw("imu", 0.7, b"cd")  # log line 3, at byte 2
    w.close()
    (d / "raw-imu.bin").write_bytes(b"abcX")
    reads = SessionReader(d).raw("imu")
    assert next(reads) == (0.5, b"ab")
    with pytest.raises(SessionError) as caught:
        next(reads)
    assert str(caught.value) == f"{d / 'raw-imu.bin'}: read at byte 2 (log line 3): checksum mismatch (corrupt data)"
    assert (caught.value.path, caught.value.line) == (str(d / "raw-imu.bin"), 3)


def test_a_session_that_cannot_be_written_is_refused_before_anything_is_cut(tmp_path, monkeypatch):
    d = tmp_path / "s"
    SessionWriter.create(d, {}).close()
    (d / capture.LOG).write_bytes((d / capture.LOG).read_bytes() + b'{"torn')
    before = {p.name: p.read_bytes() for p in d.iterdir()}
    monkeypatch.setattr(capture, "_writable", lambda directory: False)  # as a user without write permission
    with pytest.raises(SessionError) as caught:
        SessionWriter.append_to(d)
    assert (str(caught.value), caught.value.path) == (f"{d}: cannot write to this session (no permission)", str(d))
    assert {p.name: p.read_bytes() for p in d.iterdir()} == before


def test_a_session_whose_log_cannot_be_opened_for_appending_is_one_line_and_unlocked(tmp_path, monkeypatch):
    from fieldcal.session.lock import SessionLock

    d = tmp_path / "s"
    SessionWriter.create(d, {}).close()

    def refuse(path, new=False):
        raise PermissionError(13, "Permission denied", str(path))

    monkeypatch.setattr(capture, "open_append", refuse)
    with pytest.raises(SessionError) as caught:
        SessionWriter.append_to(d)
    assert (str(caught.value), caught.value.path) == (f"{d}: cannot write to this session (Permission denied)", str(d))
    SessionLock.acquire(d).release()


def test_after_a_write_breaks_off_every_write_is_refused_saying_how_to_go_on(tmp_path):
    d = tmp_path / "s"
    w = SessionWriter.create(d, {})

    class Full:
        def __init__(self, fh):
            self._fh = fh

        def __getattr__(self, name):
            return getattr(self._fh, name)

        def write(self, data):
            raise OSError(28, "No space left on device")

    w._log = Full(w._log)
    with pytest.raises(OSError):
        w.event({"kind": "x"})
    with pytest.raises(capture.SessionStateError) as caught:
        w.event({"kind": "y"})
    assert str(caught.value) == (f"{d}: an earlier write failed ([Errno 28] No space left on device); close() "
                                 "and continue with append_to(), which cuts any partial record")
    w._log = w._log._fh
    w.close()
