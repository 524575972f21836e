"""Every kind of output path, and a disk that fills: one line on stderr, no traceback, a non-zero
exit, and a session that stays consistent (it resumes to the end).

Commands run in-process through ``fieldcal.cli.main.main``. A full disk is simulated by making
the session writer's sample (or parameter) write raise ENOSPC part-way through a run, as the
file system would. An unwritable directory is /sys when running as root (permission bits do not
stop root) and a chmod-ed directory otherwise.
"""
from __future__ import annotations

import contextlib
import errno
import os
import signal
import subprocess
import threading
from pathlib import Path

import pytest

from fieldcal.cli.main import main
from fieldcal.procedure.positions import PROCEDURES_DIR
from fieldcal.session.capture import LOG, SessionReader, SessionWriter

SHORT = """name: short
title: two positions, 3 s each
dwell_s: 3
positions:
  - {id: 1, axes: {x: south, y: east, z: up}}
  - {id: 2, axes: {x: north, y: east, z: down}}
"""


@pytest.fixture
def short(tmp_path) -> Path:
    path = tmp_path / "short.yaml"
    path.write_text(SHORT)
    return path


@pytest.fixture
def quick(tmp_path) -> Path:
    """field-18 with 3 s dwells: every triad but the gyro solves, so a parameter file is written."""
    path = tmp_path / "quick.yaml"
    path.write_text((PROCEDURES_DIR / "field-18.yaml").read_text()
                    .replace("dwell_s: 200", "dwell_s: 3").replace("name: field-18", "name: quick"))
    return path


@pytest.fixture
def unwritable(tmp_path) -> Path:
    if os.geteuid() == 0:
        if not os.path.isdir("/sys") or os.access("/sys/fieldcal-probe", os.F_OK):
            pytest.skip("no /sys to stand for an unwritable directory")
        yield Path("/sys")
        return
    d = tmp_path / "locked"
    d.mkdir()
    d.chmod(0o555)
    yield d
    d.chmod(0o755)


def one_line(capsys, argv, code=None) -> str:
    status = main([str(a) for a in argv])  # (paths given as they are)
    err = capsys.readouterr().err
    assert "Traceback" not in err
    lines = err.strip().splitlines()
    assert status != 0 and (code is None or status == code), (status, err)
    assert len(lines) == 1, err
    return lines[0]


def test_out_that_is_a_file(capsys, tmp_path, short):
    (tmp_path / "afile").write_text("x")
    line = one_line(capsys, ["run", "--headless", "--procedure", str(short), "--out", str(tmp_path / "afile")], 2)
    assert line == f"fieldcal: --out {tmp_path / 'afile'}: is a file, not a directory (name a directory)"
    line = one_line(capsys, ["run", "--headless", "--procedure", str(short), "--out",
                             str(tmp_path / "afile" / "below")], 2)
    assert f"{tmp_path / 'afile'} is a file, not a directory" in line


def test_out_that_is_unwritable(capsys, short, unwritable):
    line = one_line(capsys, ["run", "--headless", "--procedure", str(short), "--out", str(unwritable / "sessions")], 2)
    assert line.startswith(f"fieldcal: --out {unwritable / 'sessions'}: cannot write in {unwritable} (")


def test_out_that_does_not_exist_yet_is_created(capsys, tmp_path, short):
    out = tmp_path / "new" / "deeper"
    assert main(["run", "--headless", "--quiet", "--procedure", str(short), "--out", str(out)]) == 1
    assert len(list(out.iterdir())) == 1  # short cannot calibrate anything, but the session is there


def test_a_name_too_long_for_the_file_system(capsys, tmp_path, short):
    line = one_line(capsys, ["run", "--headless", "--procedure", str(short), "--out", str(tmp_path / ("x" * 300))], 2)
    assert "longer than the file system allows" in line


@pytest.mark.parametrize("kind", ["directory", "missing directory", "parent is a file", "unwritable"])
@pytest.mark.parametrize("flag", [["demo", "--params"], ["replay", "SESSION", "--out"],
                                  ["calibrate", "REC.csv", "--params"]])
def test_output_files_of_every_kind(capsys, tmp_path, unwritable, kind, flag):
    (tmp_path / "afile").write_text("x")
    target = {"directory": tmp_path, "missing directory": tmp_path / "no" / "p.yaml",
              "parent is a file": tmp_path / "afile" / "p.yaml", "unwritable": unwritable / "p.yaml"}[kind]
    argv = [str(tmp_path / a) if a.isupper() else a for a in flag] + [str(target)]
    line = one_line(capsys, argv, 2)
    assert line.startswith(f"fieldcal: {flag[-1]} {target}: ")
    assert {"directory": "is a directory", "missing directory": "does not exist",
            "parent is a file": "is a file", "unwritable": "cannot write in"}[kind] in line


@pytest.mark.parametrize("kind", ["file", "parent is a file", "unwritable"])
def test_allan_plot_dir(capsys, tmp_path, unwritable, kind):
    (tmp_path / "afile").write_text("x")
    target = {"file": tmp_path / "afile", "parent is a file": tmp_path / "afile" / "plots",
              "unwritable": unwritable / "plots"}[kind]
    record = tmp_path / "still.txt"
    record.write_text("".join(f"{i / 100:.2f} 0 0 {i % 3}\n" for i in range(200)))
    line = one_line(capsys, ["allan", str(record), "--plot-dir", str(target)], 2)
    assert line.startswith(f"fieldcal: --plot-dir {target}: ")


def full_disk_after(monkeypatch, method: str, calls: int) -> None:
    """SessionWriter.<method> raises ENOSPC on its ``calls``-th call, as a full disk would."""
    original = getattr(SessionWriter, method)
    count = {"n": 0}

    def failing(self, *args, **kwargs):
        count["n"] += 1
        if count["n"] >= calls:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(self.directory / "samples.bin"))
        return original(self, *args, **kwargs)
    monkeypatch.setattr(SessionWriter, method, failing)


def test_disk_full_during_a_run_then_resume(capsys, monkeypatch, tmp_path, quick):
    full_disk_after(monkeypatch, "chunk", 400)
    out = tmp_path / "out"
    line = one_line(capsys, ["run", "--headless", "--quiet", "--procedure", str(quick), "--out", str(out)], 1)
    (session,) = out.iterdir()
    assert line == (f"fieldcal: {session / 'samples.bin'}: No space left on device; the session in "
                    f"{session} is consistent up to its last completed step (free some space first): "
                    f"continue it with: fieldcal resume {session}")
    monkeypatch.undo()  # space freed
    assert main(["resume", "--quiet", str(session)]) == 0
    assert SessionReader(session).stopped and (session / "parameters.yaml").is_file()


def test_disk_full_writing_the_parameter_file(capsys, monkeypatch, tmp_path, quick):
    full_disk_after(monkeypatch, "write_parameters", 1)
    out = tmp_path / "out"
    line = one_line(capsys, ["run", "--headless", "--quiet", "--procedure", str(quick), "--out", str(out)], 1)
    (session,) = out.iterdir()
    assert "No space left on device" in line and f"fieldcal resume {session}" in line


def test_disk_full_during_resume(capsys, monkeypatch, tmp_path, short):
    out = tmp_path / "out"
    full_disk_after(monkeypatch, "chunk", 12)  # of 16, after the first step
    one_line(capsys, ["run", "--headless", "--quiet", "--procedure", str(short), "--out", str(out)], 1)
    (session,) = out.iterdir()
    monkeypatch.undo()
    full_disk_after(monkeypatch, "chunk", 3)
    line = one_line(capsys, ["resume", "--quiet", str(session)], 1)
    assert "No space left on device" in line and f"fieldcal resume {session}" in line


def test_resume_of_an_unwritable_session_runs_nothing(capsys, monkeypatch, tmp_path, short):
    out = tmp_path / "out"
    full_disk_after(monkeypatch, "chunk", 12)
    one_line(capsys, ["run", "--headless", "--quiet", "--procedure", str(short), "--out", str(out)], 1)
    monkeypatch.undo()
    (session,) = out.iterdir()
    size = (session / "log.jsonl").stat().st_size

    with read_only(session, monkeypatch):
        line = one_line(capsys, ["resume", str(session)], 2)
    assert line.startswith(f"fieldcal: {session}: cannot resume: ") and line.endswith("nothing was re-run")
    assert (session / "log.jsonl").stat().st_size == size


@contextlib.contextmanager
def read_only(directory: Path, monkeypatch):
    """The directory as a read-only file system (a read-only bind mount when running as root,
    which permission bits do not stop; else chmod). Without mount rights as root, the probe
    that checks writability is made to see EROFS, as it would on such a mount."""
    if os.geteuid() != 0:
        directory.chmod(0o555)
        (directory / "log.jsonl").chmod(0o444)
        try:
            yield
        finally:
            directory.chmod(0o755)
            (directory / "log.jsonl").chmod(0o644)
        return
    mounted = subprocess.run(["mount", "--bind", str(directory), str(directory)],
                             capture_output=True).returncode == 0
    if mounted and subprocess.run(["mount", "-o", "remount,bind,ro", str(directory)],
                                  capture_output=True).returncode == 0:
        try:
            yield
        finally:
            subprocess.run(["umount", str(directory)], check=True)
        return
    if mounted:
        subprocess.run(["umount", str(directory)], check=True)

    def refuse(*args, **kwargs):
        raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(directory))
    import fieldcal.cli.paths as paths
    monkeypatch.setattr(paths.tempfile, "TemporaryFile", refuse)
    yield


def _signal_after_first_step(monkeypatch, signum):
    """Deliver ``signum`` to this process when the run completes its first step."""
    original = SessionWriter.step

    def step(self, *args, **kwargs):
        seq = original(self, *args, **kwargs)
        os.kill(os.getpid(), signum)
        return seq
    monkeypatch.setattr(SessionWriter, "step", step)


@pytest.mark.parametrize("signum, code, said", [(signal.SIGINT, 130, "interrupted"),
                                                (signal.SIGTERM, 143, "terminated (SIGTERM)")])
def test_a_stopped_run_says_where_its_session_is(capsys, monkeypatch, tmp_path, short, signum, code, said):
    assert threading.current_thread() is threading.main_thread()
    _signal_after_first_step(monkeypatch, signum)
    out = tmp_path / "out"
    # Ctrl-C as an interactive shell leaves it: a suite started in the background of a script
    # inherits SIGINT ignored, which fieldcal rightly keeps (then this run would go on to its end)
    with sigint_handled_by(signal.default_int_handler):
        line = one_line(capsys, ["run", "--headless", "--quiet", "--procedure", str(short), "--out", str(out)], code)
    (session,) = out.iterdir()
    assert line == (f"fieldcal: {said}; the session in {session} is consistent up to its last "
                    f"completed step: continue it with: fieldcal resume {session}")
    assert signal.getsignal(signal.SIGTERM) is not None  # main() put the previous handler back
    monkeypatch.undo()
    assert main(["resume", "--quiet", str(session)]) == 1 and SessionReader(session).stopped


@contextlib.contextmanager
def sigint_handled_by(handler):
    """The process's SIGINT handler is ``handler`` within (a host program's, or one that earlier
    code in this process left), the previous one afterwards."""
    previous = signal.signal(signal.SIGINT, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def test_ctrl_c_stops_a_run_whatever_handler_the_process_had(capsys, monkeypatch, tmp_path, short):
    """Issue 26: `run` relied on the interpreter's default SIGINT handler. With another in place,
    Ctrl-C after the first step went to it and the run went on to its end: "status 1, nothing on
    stderr", as a loaded whole-suite run once saw. fieldcal's own handler takes it now."""
    taken_by_host = []

    def host(signum, frame):
        taken_by_host.append(signum)
    _signal_after_first_step(monkeypatch, signal.SIGINT)
    out = tmp_path / "out"
    with sigint_handled_by(host):
        line = one_line(capsys, ["run", "--headless", "--quiet", "--procedure", str(short), "--out", str(out)], 130)
        assert signal.getsignal(signal.SIGINT) is host  # main() put the host's handler back
    (session,) = out.iterdir()
    assert line == (f"fieldcal: interrupted; the session in {session} is consistent up to its last "
                    f"completed step: continue it with: fieldcal resume {session}")
    assert taken_by_host == []
    monkeypatch.undo()
    assert main(["resume", "--quiet", str(session)]) == 1 and SessionReader(session).stopped


def test_a_run_started_ignoring_sigint_keeps_ignoring_it(capsys, monkeypatch, tmp_path, short):
    """A background job of a script is started with SIGINT ignored, so that the script's Ctrl-C
    leaves it running: fieldcal does not take that back."""
    _signal_after_first_step(monkeypatch, signal.SIGINT)
    out = tmp_path / "out"
    with sigint_handled_by(signal.SIG_IGN):
        status = main(["run", "--headless", "--quiet", "--procedure", str(short), "--out", str(out)])
        assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    (session,) = out.iterdir()
    assert status == 1 and capsys.readouterr().err == ""  # ran to its end (short calibrates nothing)
    assert SessionReader(session).stopped


@pytest.fixture
def small_tmpfs(tmp_path):
    """A 1 MB tmpfs (root only): a real full disk; the test grows it to free space."""
    mount_point = tmp_path / "small"
    mount_point.mkdir()
    if os.geteuid() != 0 or subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(mount_point)],
                                           capture_output=True).returncode != 0:
        pytest.skip("cannot mount a small tmpfs here (needs root)")
    yield mount_point
    subprocess.run(["umount", str(mount_point)], check=True)


def test_a_really_full_disk_then_resume(capsys, quick, small_tmpfs):
    out = small_tmpfs / "out"
    line = one_line(capsys, ["run", "--headless", "--quiet", "--procedure", str(quick), "--out", str(out)], 1)
    (session,) = out.iterdir()
    assert line == (f"fieldcal: {session}: No space left on device; the session in {session} is consistent "
                    "up to its last completed step (free some space first): continue it with: "
                    f"fieldcal resume {session}")
    subprocess.run(["mount", "-o", "remount,size=64m", str(small_tmpfs)], check=True)
    assert main(["resume", "--quiet", str(session)]) == 0
    assert SessionReader(session).stopped and (session / "parameters.yaml").is_file()


def test_a_full_disk_at_an_imported_sessions_first_line_names_its_log(capsys, tmp_path, small_tmpfs):
    """Issue 25, round 4, item 2: `calibrate FILES --out FULL` said only "No space left on device"
    (the session's first line, written before the session is the command's, named no file)."""
    from drivers.sim.handheld import simulate_handheld, to_text

    acc, gyro = to_text(simulate_handheld(3), tmp_path / "text")
    with open(small_tmpfs / "filler", "wb", buffering=0) as filler:  # the disk full to its last byte
        with contextlib.suppress(OSError):
            while True:
                filler.write(b"\1" * 4096)
    line = one_line(capsys, ["calibrate", acc, gyro, "--map", "imu_tk", "--out", small_tmpfs / "cs"], 1)
    [session] = (small_tmpfs / "cs").iterdir()
    assert line.startswith(f"fieldcal: {session / LOG}: No space left on device"), line
