"""Issue 25, part A: one rule for every file fieldcal writes (fieldcal.atomic, DESIGN principle 11).

Never through a symbolic link, never over a file the command read or one of its inputs (even
with --force), never over an existing file without --force, checked before the long work, and
every error names the path the user gave. A test per defect of the issue (items 1-4, 11, 17),
then a fault test that plants a link at every path each command writes and shows its target
untouched.

Commands run in-process through ``fieldcal.cli.main.main`` on small inputs: the quick
procedure's simulated session (conftest), a simulated hand-held recording imported as a
session, a 50-line CSV.
"""
from __future__ import annotations

import errno
import json
import os
import shutil
from pathlib import Path

import pytest

from fieldcal.cli.main import main
from fieldcal.session.capture import LOG, SAMPLES, SessionReader
from fieldcal.session.lock import SessionLock
from faultlib import unit_parameter_file
from test_outputs import one_line

VICTIM = b"the user's own file: never to be written by fieldcal\n"


def plant(link: Path, victims: Path, content: bytes = VICTIM) -> Path:
    """A symbolic link at ``link`` to a file of the user's (outside the output) holding ``content``."""
    victims.mkdir(exist_ok=True)
    victim = victims / f"victim-{len(list(victims.iterdir()))}-{link.name}"
    victim.write_bytes(content)
    if link.exists() or link.is_symlink():
        link.unlink()
    link.symlink_to(victim)
    return victim


# ------------------------------------------------------------------------------------------
# inputs


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    """A simulated hand-held recording (imu_tk text files), imported as a session, not calibrated."""
    from drivers.sim.handheld import simulate_handheld, to_text

    base = tmp_path_factory.mktemp("recording")
    acc, gyro = to_text(simulate_handheld(3), base / "text")
    assert main(["import", str(acc), str(gyro), "--map", "imu_tk", "--out", str(base / "session")]) == 0
    return base / "session"


@pytest.fixture
def recording_copy(recording, tmp_path) -> Path:
    d = tmp_path / "rec-session"
    shutil.copytree(recording, d)
    return d


@pytest.fixture(scope="module")
def params_csv(tmp_path_factory) -> tuple[Path, Path]:
    """A parameter file and a 50-line CSV for it (the single-csv import map)."""
    base = tmp_path_factory.mktemp("params")
    params = unit_parameter_file(base / "p.yaml")
    csv = base / "one.csv"
    csv.write_text("t_ms,ax,ay,az,gx,gy,gz,T\n" + "".join(f"{1000 + 4 * i},{i % 7}.5,{2 * i},-{i % 5},0.1,0.2,0.3,25\n"
                                                             for i in range(50)))
    return params, csv


def unfinished(session: Path) -> Path:
    """Cut a completed procedure session back into the middle of its run (as a crash leaves it)."""
    lines = (session / LOG).read_bytes().splitlines(keepends=True)
    fifth_step = [i for i, line in enumerate(lines) if b'"type":"step"' in line][4]
    k = next(i for i in range(fifth_step, len(lines)) if b'"type":"chunk"' in lines[i])
    (session / LOG).write_bytes(b"".join(lines[:k]))
    with open(session / SAMPLES, "r+b") as fh:
        fh.truncate(json.loads(lines[k])["offset"])
    for p in session.glob("parameters*.yaml"):
        p.unlink()
    return session


# ------------------------------------------------------------------------------------------
# the helper


def test_write_atomically_never_writes_through_a_link_nor_over_a_read_file(tmp_path):
    from fieldcal.atomic import RefusedTarget, WouldOverwrite, check_target, command_reads, note_read, write_atomically

    victim = tmp_path / "victim"
    victim.write_bytes(VICTIM)
    link = tmp_path / "out"
    link.symlink_to(victim)
    for overwrite in (False, True):
        with pytest.raises(RefusedTarget, match=f"^{link}: is a symbolic link"):
            write_atomically(link, b"new", overwrite=overwrite)
    assert victim.read_bytes() == VICTIM and link.is_symlink()
    with pytest.raises(RefusedTarget, match="is the input"):
        write_atomically(victim, b"new", inputs=[str(tmp_path / "missing"), str(link)])
    with command_reads():
        with open(victim, "rb") as fh:
            note_read(os.fstat(fh.fileno()))
        with pytest.raises(RefusedTarget, match="this command read that file"):
            check_target(victim, force=True)
    write_atomically(victim, b"new")  # outside a command, a file read earlier is no input
    assert victim.read_bytes() == b"new"
    with pytest.raises(WouldOverwrite, match="give --force"):
        write_atomically(victim, b"again", overwrite=False, hint="give --force to replace it")
    os.mkfifo(tmp_path / "fifo")
    with pytest.raises(RefusedTarget, match="not a regular file"):
        write_atomically(tmp_path / "fifo", b"x")


def test_errors_name_the_path_given_not_a_temporary(tmp_path, monkeypatch):
    from fieldcal.atomic import CannotWrite, atomic_file, write_atomically

    with pytest.raises(CannotWrite) as caught:
        write_atomically(tmp_path / "nodir" / "x.csv", b"x")
    assert str(caught.value) == f"{tmp_path / 'nodir' / 'x.csv'}: cannot write (no directory {tmp_path / 'nodir'})"

    def full(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    monkeypatch.setattr(os, "fsync", full)
    with pytest.raises(CannotWrite) as caught:
        with atomic_file(tmp_path / "x.csv") as pending:
            pending.file.write(b"x")
    assert str(caught.value) == f"{tmp_path / 'x.csv'}: cannot write (No space left on device)"
    assert os.listdir(tmp_path) == []  # no temp file left behind


# ------------------------------------------------------------------------------------------
# one test per defect


@pytest.mark.parametrize("command", ["calibrate", "resume"])
def test_item1_a_lock_link_in_a_session_is_never_followed(capsys, tmp_path, recording_copy, session_copy,
                                                          command):
    session = recording_copy if command == "calibrate" else unfinished(session_copy)
    victim = plant(session / "lock", tmp_path / "victims")
    argv = ["calibrate", session, "--latitude", "40"] if command == "calibrate" else ["resume", session, "--quiet"]
    line = one_line(capsys, argv, 2)
    assert f"{session / 'lock'}: is a symbolic link" in line
    assert victim.read_bytes() == VICTIM


def test_item2_plan_out_never_over_its_config_nor_a_file_without_force(capsys, tmp_path, monkeypatch):
    from fieldcal.paths import CONFIGS_DIR
    from fieldcal.planning.search import Planner
    from fieldcal.procedure.positions import PROCEDURES_DIR

    searched = []
    monkeypatch.setattr(Planner, "search", lambda self, pool: searched.append(pool))
    config = tmp_path / "st.yaml"
    config.write_bytes((CONFIGS_DIR / "sim.yaml").read_bytes())
    before = config.read_bytes()
    line = one_line(capsys, ["plan", "--config", config, "--slack", "0.3", "--out", config, "--force"], 2)
    assert line == (f"fieldcal: --out {config} is the input {config} of this command: never written over, "
                    "even with --force; give another path")
    assert config.read_bytes() == before
    reference = PROCEDURES_DIR / "field-18.yaml"
    shipped = reference.read_bytes()
    line = one_line(capsys, ["plan", "--config", "sim", "--out", reference, "--force"], 2)
    assert f"--out {reference} is the input" in line and reference.read_bytes() == shipped
    existing = tmp_path / "mine.yaml"
    existing.write_bytes(VICTIM)
    line = one_line(capsys, ["plan", "--config", "sim", "--out", existing], 2)
    assert line == f"fieldcal: {existing}: already exists; not overwritten (give --force to replace it)"
    assert existing.read_bytes() == VICTIM
    assert searched == []  # every refusal came before the search


def test_item3_export_never_over_its_own_parameter_file(capsys, tmp_path, params_csv):
    q = tmp_path / "q.yaml"
    q.write_bytes(params_csv[0].read_bytes())
    before = q.read_bytes()
    line = one_line(capsys, ["export", q, "--format", "json", "--out", q, "--force"], 2)
    assert f"--out {q} is the input {q}" in line
    link = tmp_path / "link.json"
    link.symlink_to(q)
    line = one_line(capsys, ["export", q, "--format", "json", "--out", link, "--force"], 2)
    assert f"--out {link}: is a symbolic link" in line
    hard = tmp_path / "hard.json"
    os.link(q, hard)  # the same file under another name
    line = one_line(capsys, ["export", q, "--format", "json", "--out", hard, "--force"], 2)
    assert f"--out {hard} is the input {q}" in line
    assert q.read_bytes() == before


def test_item4_allan_never_follows_a_plot_link(capsys, tmp_path, session_copy):
    victims = [plant(session_copy / f"allan-{name}.png", tmp_path / "victims")
               for name in ("accelerometer", "gyroscope", "inclinometer")]
    status = main(["allan", str(session_copy)])
    err = capsys.readouterr().err
    assert status == 2 and "Traceback" not in err
    assert f"{session_copy / 'allan-accelerometer.png'}: is a symbolic link" in err
    assert all(v.read_bytes() == VICTIM for v in victims)


def test_item11_allan_refuses_a_session_a_run_is_writing(capsys, session_copy):
    held = SessionLock.acquire(session_copy)  # a live run's lock
    try:
        line = one_line(capsys, ["allan", session_copy], 2)
    finally:
        held.release()
    assert line.startswith(f"fieldcal: {session_copy}: another fieldcal is writing this session")
    assert not list(session_copy.glob("allan-*.png"))
    assert main(["allan", str(session_copy)]) == 0  # once the run is over
    assert {"allan-accelerometer.png", "allan-gyroscope.png"} <= {p.name for p in session_copy.glob("allan-*.png")}


def test_item17_apply_into_a_missing_directory_names_the_path(capsys, tmp_path, params_csv):
    params, csv = params_csv
    target = tmp_path / "nodir" / "x.csv"
    line = one_line(capsys, ["apply", params, csv, "--map", "single-csv", "--out", target], 2)
    assert line == f"fieldcal: --out {target}: the directory {target.parent} does not exist"


def test_item17_resume_of_an_unwritable_session_names_the_folder(capsys, monkeypatch, session_copy):
    import tempfile

    session = unfinished(session_copy)

    def immutable(*args, dir=None, **kwargs):  # what chattr +i gives: EPERM on the probe's temp file
        raise PermissionError(errno.EPERM, os.strerror(errno.EPERM), os.path.join(dir, "tmpn6t5o051"))
    monkeypatch.setattr(tempfile, "TemporaryFile", immutable)
    line = one_line(capsys, ["resume", session], 2)
    assert line == (f"fieldcal: {session}: cannot resume: the folder cannot be written "
                    f"({os.strerror(errno.EPERM)}); nothing was re-run")


@pytest.mark.parametrize("command", ["calibrate", "apply", "export"])
def test_item17_a_full_disk_names_the_file(capsys, monkeypatch, tmp_path, recording_copy, params_csv, command):
    params, csv = params_csv
    out = tmp_path / "out.file"
    argv = {"calibrate": ["calibrate", recording_copy, "--latitude", "40"],
            "apply": ["apply", params, csv, "--map", "single-csv", "--out", out],
            "export": ["export", params, "--format", "json", "--out", out]}[command]

    def full(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    monkeypatch.setattr(os, "fsync", full)
    line = one_line(capsys, argv)
    where = recording_copy if command == "calibrate" else out
    assert line.startswith(f"fieldcal: {where}") and "No space left on device" in line
    assert not out.exists()


# ------------------------------------------------------------------------------------------
# the fault test: a link at every path each command writes


CASES = {
    # command: (the session or folder it needs, its argv, every path it writes)
    "calibrate": ("recording", ["calibrate", "{S}", "--latitude", "40", "--params", "{W}/p.yaml", "--force",
                                "--registry", "{W}/reg.sqlite"],
                  ["{S}/lock", "{S}/log.jsonl", "{S}/samples.bin", "{S}/parameters-001.yaml",
                   "{S}/parameters.yaml", "{W}/p.yaml", "{W}/reg.sqlite", "{W}/reg.sqlite-journal"]),
    "resume": ("unfinished", ["resume", "{S}", "--quiet", "--registry", "{W}/reg.sqlite"],
               ["{S}/lock", "{S}/log.jsonl", "{S}/samples.bin", "{S}/parameters-001.yaml",
                "{S}/parameters.yaml", "{W}/reg.sqlite"]),
    "resume-torn": ("torn", ["resume", "{S}", "--quiet"], ["{S}/log.jsonl.torn"]),
    "run": ("none", ["run", "--headless", "--quiet", "--procedure", "{Q}", "--out", "{W}/new",
                     "--registry", "{W}/reg.sqlite"], ["{W}/reg.sqlite", "{W}/reg.sqlite-wal"]),
    "import": ("none", ["import", "{T}/acc.txt", "{T}/gyro.txt", "--map", "imu_tk", "--out", "{W}/new"],
               ["{W}/new/lock", "{W}/new/log.jsonl"]),
    "demo": ("none", ["demo", "--params", "{W}/p.yaml", "--force"], ["{W}/p.yaml"]),
    "replay": ("session", ["replay", "{S}", "--quiet", "--out", "{W}/p.yaml", "--force"], ["{W}/p.yaml"]),
    "resolve": ("session", ["resolve", "{S}", "--method", "lsq", "--registry", "{W}/reg.sqlite"],
                ["{S}/lock", "{S}/parameters.yaml", "{W}/reg.sqlite"]),
    "plan": ("none", ["plan", "--config", "sim", "--out", "{W}/plan.yaml", "--force"], ["{W}/plan.yaml"]),
    "export": ("none", ["export", "{P}", "--format", "px4", "--out", "{W}/x.params", "--force"],
               ["{W}/x.params"]),
    "apply": ("none", ["apply", "{P}", "{C}", "--map", "single-csv", "--out", "{W}/x.csv", "--force"],
              ["{W}/x.csv"]),
    "apply-into-a-folder": ("calibrated", ["apply", "{S}/parameters.yaml", "{T}/acc.txt", "{T}/gyro.txt",
                                           "--map", "imu_tk", "--out", "{W}", "--force"],
                            ["{W}/acc-calibrated.csv", "{W}/gyro-calibrated.csv"]),
    "allan": ("session", ["allan", "{S}"], ["{S}/lock", "{S}/allan-accelerometer.png",
                                           "{S}/allan-gyroscope.png", "{S}/allan-inclinometer.png"]),
    "allan-plot-dir": ("session", ["allan", "{S}", "--plot-dir", "{W}"], ["{W}/allan-accelerometer.png"]),
    "certificate": ("calibrated", ["certificate", "{S}", "--out", "{W}/c.html", "--force"],
                    ["{W}/c.html", "{W}/c.pdf"]),
    "registry-rebuild": ("session", ["registry", "rebuild", "{S}", "--registry", "{W}/reg.sqlite"],
                         ["{W}/reg.sqlite", "{W}/reg.sqlite-journal", "{W}/reg.sqlite-wal", "{W}/reg.sqlite-shm"]),
}
LINKS = [(case, path) for case, (_, _, paths) in CASES.items() for path in paths]


@pytest.mark.parametrize("case, written", LINKS, ids=[f"{c}:{p.rsplit('/', 1)[1]}" for c, p in LINKS])
def test_a_link_at_every_path_a_command_writes_leaves_its_target_untouched(
        capsys, tmp_path, case, written, recording, session_copy, params_csv):
    """One link per run, so that each is reached (an earlier refusal would hide a later one);
    the link's target holds what a writer following it would change: a copy of the session's
    own log or samples, an empty file for a registry (SQLite takes it as a new database)."""
    from faultlib import QUICK

    needs, argv, _ = CASES[case]
    work = tmp_path / "work"
    work.mkdir()
    if needs == "recording":
        session = tmp_path / "rec-session"
        shutil.copytree(recording, session)
    elif needs == "calibrated":
        session = tmp_path / "rec-session"
        shutil.copytree(recording, session)
        assert main(["calibrate", str(session), "--latitude", "40"]) == 0
    elif needs in ("unfinished", "torn"):
        session = unfinished(session_copy)
        if needs == "torn":  # a crash inside a log line: resume keeps the cut bytes in log.jsonl.torn
            with open(session / LOG, "ab") as fh:
                fh.write(b'{"seq": 4')
    else:
        session = session_copy
    names = {"{S}": str(session), "{W}": str(work), "{Q}": str(QUICK), "{P}": str(params_csv[0]),
             "{C}": str(params_csv[1]), "{T}": str(recording.parent / "text")}
    if written.endswith(".pdf") and shutil.which("chromium") is None:
        pytest.skip("no Chromium: the certificate makes no PDF")

    def fill(text: str) -> str:
        for key, value in names.items():
            text = text.replace(key, value)
        return text
    path = Path(fill(written))
    path.parent.mkdir(parents=True, exist_ok=True)
    content = (path.read_bytes() if path.name in (LOG, SAMPLES) and path.is_file()
               else b"" if path.name.endswith(".sqlite") else VICTIM)
    victim = plant(path, tmp_path / "victims", content)
    capsys.readouterr()
    status = main([fill(a) for a in argv])
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert victim.read_bytes() == content, (status, err)
    assert path.is_symlink()  # refused, not replaced
    if needs != "none":
        SessionReader(session)  # the session is still a consistent session


def test_calibrate_params_never_over_its_own_recording(capsys, tmp_path, recording):
    """The rule's 'never over an input': --params naming the recording, even with --force."""
    text = tmp_path / "text"
    shutil.copytree(recording.parent / "text", text)
    before = (text / "acc.txt").read_bytes()
    line = one_line(capsys, ["calibrate", text / "acc.txt", text / "gyro.txt", "--map", "imu_tk", "--latitude", "40",
                             "--out", tmp_path / "sessions", "--params", text / "acc.txt", "--force"], 2)
    assert line.startswith(f"fieldcal: --params {text / 'acc.txt'} is the input {text / 'acc.txt'}")
    assert (text / "acc.txt").read_bytes() == before and not (tmp_path / "sessions").exists()


def test_history_plots_never_follow_a_link(tmp_path):
    """``history --plot DIR``: a link planted at a unit's plot name is refused, its target untouched."""
    from fieldcal.atomic import RefusedTarget
    from fieldcal.registry.drift import plot_history

    calibrations = [{"time": f"2026-0{m}-01T00:00:00+00:00",
                     "parameters": {("accelerometer", "bias_x"): (0.01 * m, 0.001, "mg")}} for m in (1, 2)]
    victim = plant(tmp_path / "SN1-accelerometer-history.png", tmp_path / "victims")
    with pytest.raises(RefusedTarget, match="is a symbolic link"):
        plot_history(calibrations, "SN1", tmp_path)
    assert victim.read_bytes() == VICTIM
    (tmp_path / "SN1-accelerometer-history.png").unlink()
    (path,) = plot_history(calibrations, "SN1", tmp_path)
    assert path.read_bytes().startswith(b"\x89PNG")


def test_allan_never_over_an_earlier_plot_without_force(capsys, session_copy):
    assert main(["allan", str(session_copy), "--triad", "gyroscope"]) == 0
    plot = session_copy / "allan-gyroscope.png"
    before = plot.read_bytes()
    line = one_line(capsys, ["allan", session_copy, "--triad", "gyroscope"], 2)
    assert line == f"fieldcal: {plot}: already exists; not overwritten (give --force to replace it)"
    assert plot.read_bytes() == before
    assert main(["allan", str(session_copy), "--triad", "gyroscope", "--force"]) == 0


def test_the_tuis_remembered_setup_is_replaced_but_never_through_a_link(tmp_path):
    """The remembered setup is read at start and replaced by design (not an input of the command);
    a link at its name is still refused."""
    from fieldcal.atomic import RefusedTarget, command_reads
    from fieldcal.tui.choices import SetupChoice, load_last_choice, save_last_choice

    path = tmp_path / "last-setup.yaml"
    first = SetupChoice("sim", None, "field-18", 40.0, 0.0)
    second = SetupChoice("sim", None, "classic-12", 45.0, 10.0)
    save_last_choice(first, path)
    with command_reads():  # as inside `fieldcal tui`
        assert load_last_choice(path) == first
        save_last_choice(second, path)
    assert load_last_choice(path) == second
    victim = plant(path, tmp_path / "victims")
    with pytest.raises(RefusedTarget, match="is a symbolic link"):
        save_last_choice(first, path)
    assert victim.read_bytes() == VICTIM


def test_a_lock_link_is_refused_before_resume_says_it_resumes(capsys, tmp_path, session_copy):
    """Issue 25, round 4, item 5: the link was refused only after `resume` printed "resuming ...
    after 5 completed steps"; now with the other early checks, before a word of the run."""
    session = unfinished(session_copy)
    victim = plant(session / "lock", tmp_path / "victims")
    status = main(["resume", str(session), "--quiet"])
    captured = capsys.readouterr()
    assert status == 2 and captured.out == ""
    assert captured.err == (f"fieldcal: {session}: cannot resume: {session / 'lock'}: is a symbolic link"
                            + captured.err.split(": is a symbolic link", 1)[1])
    assert captured.err.count("\n") == 1 and "nothing was re-run" in captured.err
    assert victim.read_bytes() == VICTIM
