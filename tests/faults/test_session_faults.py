"""Fault injection on sessions (issue 16): two writers, damage at seeded offsets, SIGKILL.

Every refusal is checked to be one line naming the file (and line or byte); damage is never
repaired: the files are byte for byte as the test left them. A torn tail, which a crash does
leave, is cut with the cut bytes kept beside the file.
"""
from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest

from fieldcal.cli.main import main
from fieldcal.session.capture import LOG, SAMPLES, SessionReader

from faultlib import ROOT, run_argv


def cli(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def one_line_error(err: str) -> str:
    lines = [line for line in err.splitlines() if line.startswith("fieldcal: ")]
    assert len(lines) == 1, err
    return lines[0]


def digest(directory: Path) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(directory.iterdir())
            if p.name != "lock"}


def lines_of(path: Path) -> list[bytes]:
    return path.read_bytes().splitlines(keepends=True)


def resign(line: bytes) -> bytes:
    """A log line edited on purpose with its checksum made right (format 2: CRC-32 of the line's
    JSON without its last key "crc"), to reach the checks behind the checksum."""
    body = line.rstrip(b"\n")
    body = body[:body.rindex(b',"crc":')] + b"}"
    return body[:-1] + b',"crc":%d}\n' % zlib.crc32(body)


# --------------------------------------------------------------------------------------------
# Two writers


def _wait_for_log(directory: Path, proc: subprocess.Popen, min_bytes: int) -> Path:
    """The session directory under ``directory`` once its log holds ``min_bytes``."""
    for _ in range(6000):
        sessions = list(directory.glob("*/log.jsonl")) if directory.is_dir() else []
        if sessions and sessions[0].stat().st_size >= min_bytes:
            return sessions[0].parent
        if proc.poll() is not None:
            raise AssertionError(f"the run ended (code {proc.returncode}) before its log reached {min_bytes} bytes")
        proc_wait(proc, 0.02)
    raise AssertionError("the run did not write its log in time")


def proc_wait(proc: subprocess.Popen, seconds: float) -> None:
    try:
        proc.wait(timeout=seconds)
    except subprocess.TimeoutExpired:
        pass


def test_a_resume_while_the_run_is_writing_is_refused_and_the_run_is_unharmed(tmp_path, quick_procedure,
                                                                            quick_session, capsys):
    """Issue 16 item 1: `run --out X & resume X/...` left runs of NUL bytes in log.jsonl."""
    run = subprocess.Popen([sys.executable, "-m", "fieldcal.cli.main", *run_argv(tmp_path / "out", quick_procedure)],
                           cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        session = _wait_for_log(tmp_path / "out", run, 20_000)
        # stopped mid-run (SIGSTOP), its lock held: the second writers below meet a run that is
        # writing however fast it would have finished (no race with the run's end). They are
        # this process: the writer they meet is the other one.
        run.send_signal(signal.SIGSTOP)
        code, _, err = cli(capsys, "resume", session, "--quiet")
        assert code == 2
        message = one_line_error(err)
        assert message.startswith(f"fieldcal: {session}: another fieldcal is writing this session (pid {run.pid} on ")
        assert ", started 20" in message
        # and the second writer of a replay: never into a session
        code, _, err = cli(capsys, "replay", session, "--out", session / "parameters.yaml", "--force")
        assert code == 2 and "would be written into the session" in one_line_error(err)
    finally:
        run.send_signal(signal.SIGCONT)  # (a no-op once the run has ended)
        assert run.wait(timeout=300) == 0, run.stderr.read()
    assert b"\x00" not in (session / LOG).read_bytes()
    assert (session / "parameters.yaml").read_bytes() == (quick_session / "parameters.yaml").read_bytes()


# --------------------------------------------------------------------------------------------
# Damage at seeded offsets: refused and named, never repaired


def _last_chunk_line_end(log: bytes) -> int:
    """Byte offset just after the last chunk's log line: a log cut beyond it loses no samples'
    index, so it is a torn tail (what a crash in the final documents leaves), not damage."""
    end = 0
    for line in log.splitlines(keepends=True):
        end += len(line)
        if b'"type":"chunk"' in line:
            last = end
    return last


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_truncated_or_flipped_session_files_are_refused_by_name(session_copy, capsys, seed):
    rng = np.random.default_rng(seed)
    log, samples = (session_copy / LOG).read_bytes(), (session_copy / SAMPLES).read_bytes()
    last_line_start = log.rindex(b"\n", 0, len(log) - 1) + 1
    cases = {
        # a log cut before its last chunk's line leaves samples no crash could have left
        "log truncated": (LOG, "truncate", int(rng.integers(len(log) // 20, _last_chunk_line_end(log) - 1))),
        "samples truncated": (SAMPLES, "truncate", int(rng.integers(0, len(samples)))),
        # a flip in the last line could make it look torn (its newline): the lines before it
        "log byte flipped": (LOG, "flip", int(rng.integers(0, last_line_start))),
        "samples byte flipped": (SAMPLES, "flip", int(rng.integers(0, len(samples)))),
    }
    original = digest(session_copy)
    for name, (file, how, offset) in cases.items():
        path = session_copy / file
        data = path.read_bytes()
        if how == "truncate":
            path.write_bytes(data[:offset])
        else:
            mask = int(rng.integers(1, 256))
            path.write_bytes(data[:offset] + bytes([data[offset] ^ mask]) + data[offset + 1:])
        damaged = digest(session_copy)
        commands = [("replay", session_copy, "--quiet"), ("resume", session_copy, "--quiet")]
        if file == LOG:  # solve reads the log only
            commands.append(("solve", session_copy))
        for argv in commands:
            code, out, err = cli(capsys, *argv)
            message = one_line_error(err)
            assert code == 2, (name, argv[0], out, err)
            if argv[0] == "resume" and "never resumed" in message:  # the intact log says completed:
                assert file == SAMPLES  # refused before any sample is needed
                continue
            named = [f for f in (LOG, SAMPLES) if f"{session_copy / f}" in message]
            assert named, (name, argv[0], message)
            assert "line " in message or "byte " in message, (name, message)
            assert digest(session_copy) == damaged, (name, argv[0])  # nothing repaired, nothing cut
        assert not list(session_copy.glob("*.torn*"))
        path.write_bytes(data)
        assert digest(session_copy) == original


def test_one_changed_digit_of_a_step_average_is_refused_by_solve_and_resume(session_copy, capsys):
    """Issue 16 item 5: a changed digit moved the accelerometer z bias and solve took it."""
    lines = lines_of(session_copy / LOG)
    i = next(i for i, line in enumerate(lines) if b'"type":"step"' in line)
    doc = json.loads(lines[i])
    mean = doc["data"]["windows"][0]["means"]["accelerometer"][2]
    edited = repr(mean).replace(repr(mean)[-2], "0" if repr(mean)[-2] != "0" else "1", 1).encode()
    assert lines[i].count(repr(mean).encode()) == 1 and edited != repr(mean).encode()
    lines[i] = lines[i].replace(repr(mean).encode(), edited)
    (session_copy / LOG).write_bytes(b"".join(lines))
    for command in ("solve", "resume", "replay"):
        code, _, err = cli(capsys, command, session_copy)
        assert code == 2
        assert one_line_error(err).startswith(f"fieldcal: {session_copy / LOG}: line {i + 1} (byte "
                                              f"{sum(map(len, lines[:i]))}): damaged: checksum mismatch")


# --------------------------------------------------------------------------------------------
# Torn tails: cut, with what was cut kept


def test_a_torn_tail_is_cut_and_kept_and_the_resumed_run_matches(session_copy, quick_session, capsys):
    """A crash's state: the log ends inside a line, samples.bin inside an unlogged record."""
    lines = lines_of(session_copy / LOG)
    fifth_step = [i for i, line in enumerate(lines) if b'"type":"step"' in line][4]
    k = next(i for i in range(fifth_step, len(lines)) if b'"type":"chunk"' in lines[i])
    chunk = json.loads(lines[k])
    log_cut = sum(map(len, lines[:k])) + len(lines[k]) // 2
    samples_cut = chunk["offset"] + chunk["length"] // 3
    log, samples = (session_copy / LOG).read_bytes(), (session_copy / SAMPLES).read_bytes()
    (session_copy / LOG).write_bytes(log[:log_cut])
    (session_copy / SAMPLES).write_bytes(samples[:samples_cut])
    for p in session_copy.glob("parameters*.yaml"):
        p.unlink()
    code, out, err = cli(capsys, "resume", session_copy, "--quiet")
    assert code == 0, out + err
    assert "log.jsonl: ignored a torn last line" in err and "samples.bin: ignored" in err
    assert (session_copy / "log.jsonl.torn").read_bytes() == log[sum(map(len, lines[:k])):log_cut]
    assert (session_copy / "samples.bin.torn").read_bytes() == samples[chunk["offset"]:samples_cut]
    assert (session_copy / "parameters.yaml").read_bytes() == (quick_session / "parameters.yaml").read_bytes()
    resume = list(SessionReader(session_copy).documents("resume"))[0]
    assert [r.split(" (")[0] for r in resume["repaired"]] == [
        "log.jsonl: cut a torn last line", f"samples.bin: cut {samples_cut - chunk['offset']} bytes after the "
        "last logged chunk"]


# --------------------------------------------------------------------------------------------
# SIGKILL at seeded points of run and resume, then resume: the same parameter file


def _kill_when(proc: subprocess.Popen, log: Path, size: int) -> None:
    for _ in range(15000):
        if log.exists() and log.stat().st_size >= size:
            break
        if proc.poll() is not None:
            raise AssertionError(f"exited ({proc.returncode}) before its log reached {size} bytes")
        proc_wait(proc, 0.02)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(timeout=60)


def test_sigkill_in_run_and_in_resume_then_resume_gives_the_same_parameter_file(tmp_path, quick_procedure,
                                                                                quick_session, capsys):
    full = (quick_session / LOG).stat().st_size
    rng = np.random.default_rng(16)
    first, second = sorted(rng.uniform(0.15, 0.85, size=2))
    run = subprocess.Popen([sys.executable, "-m", "fieldcal.cli.main", *run_argv(tmp_path / "out", quick_procedure)],
                           cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    session = _wait_for_log(tmp_path / "out", run, 1)
    _kill_when(run, session / LOG, int(first * full))
    assert not (session / "parameters.yaml").exists()
    resume = subprocess.Popen([sys.executable, "-m", "fieldcal.cli.main", "resume", str(session), "--quiet"],
                              cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    _kill_when(resume, session / LOG, int(second * full))
    # the two processes killed, the rest in this one: what it reads is on disk
    code, out, err = cli(capsys, "resume", session, "--quiet")
    assert code == 0, out + err
    assert (session / "parameters.yaml").read_bytes() == (quick_session / "parameters.yaml").read_bytes()
    code, out, _ = cli(capsys, "replay", session, "--quiet")
    assert code == 0 and "identical to the run's parameters-001.yaml" in out
    code, _, err = cli(capsys, "resume", session)
    assert code == 2 and "a completed session is never resumed" in one_line_error(err)


# --------------------------------------------------------------------------------------------
# Output files (issue 16 item 2) and messages


def test_replay_out_never_writes_into_a_session_nor_over_a_file_without_force(session_copy, tmp_path, capsys):
    """Issue 16 item 2: `replay S --out S/log.jsonl` destroyed a 5,657-document log."""
    before = digest(session_copy)
    for target in (session_copy / LOG, session_copy / "parameters.yaml", session_copy / "new.yaml", session_copy):
        for force in ((), ("--force",)):
            code, _, err = cli(capsys, "replay", session_copy, "--quiet", "--out", target, *force)
            assert code == 2
            assert one_line_error(err).startswith(f"fieldcal: {target}: --out's parameter file would be written "
                                                  f"into the session {session_copy}")
    assert digest(session_copy) == before
    mine = tmp_path / "mine.yaml"
    mine.write_text("my notes\n")
    code, _, err = cli(capsys, "replay", session_copy, "--quiet", "--out", mine)
    assert code == 2 and one_line_error(err) == (f"fieldcal: {mine}: already exists; not overwritten "
                                                 "(give --force to replace it)")
    assert mine.read_text() == "my notes\n"
    code, out, _ = cli(capsys, "replay", session_copy, "--quiet", "--out", mine, "--force")
    assert code == 0 and mine.read_bytes() == (session_copy / "parameters.yaml").read_bytes()


def test_demo_and_calibrate_params_refuse_an_existing_file_before_working(tmp_path, capsys):
    mine = tmp_path / "mine.yaml"
    mine.write_text("my notes\n")
    for argv in (["demo", "--params", mine],
                 ["calibrate", tmp_path / "no-such.txt", "--map", "imu_tk", "--latitude", "40", "--params", mine]):
        code, _, err = cli(capsys, *argv)
        assert code == 2 and one_line_error(err) == (f"fieldcal: {mine}: already exists; not overwritten "
                                                     "(give --force to replace it)")
    assert mine.read_text() == "my notes\n"


def test_replay_names_a_deleted_parameter_file_and_fails(session_copy, capsys):
    """Issue 16: it said "it did not finish" and exited 0."""
    noted = list(SessionReader(session_copy).documents("parameters"))[-1]
    (session_copy / noted["file"]).unlink()
    code, _, err = cli(capsys, "replay", session_copy, "--quiet")
    assert code == 2
    assert one_line_error(err).startswith(f"fieldcal: {session_copy / noted['file']}: the session's parameter "
                                          f"file (noted in log.jsonl line {noted['seq'] + 1}) cannot be read")


@pytest.mark.parametrize("edit, message", [
    (lambda d: d["data"].pop("windows"), "step document: no 'windows' list"),
    (lambda d: d["data"].update(step=99), "step document: 'step' must be a position index from 0 to 17, got 99"),
    (lambda d: d["data"].pop("step"), "step document: no 'step'"),
    (lambda d: d["data"]["windows"][0]["means"].update(accelerometer=[1.0, "x", 2.0]),
     "step document: windows[0].means.accelerometer must be 3 finite numbers"),
])
def test_a_step_document_of_the_wrong_shape_is_named_by_file_and_line(session_copy, capsys, edit, message):
    """Issue 16 item 15: KeyError: 'windows', IndexError on "step": 99, KeyError: 'step'."""
    lines = lines_of(session_copy / LOG)
    i = [i for i, line in enumerate(lines) if b'"type":"step"' in line][2]
    doc = json.loads(lines[i])
    doc.pop("crc")
    edit(doc)
    lines[i] = resign(json.dumps(doc, separators=(",", ":")).encode()[:-1] + b',"crc":0}\n')
    (session_copy / LOG).write_bytes(b"".join(lines))
    for command in ("solve", "allan", "resume", "replay"):
        code, _, err = cli(capsys, command, session_copy)
        assert code == 2, command
        assert one_line_error(err).startswith(f"fieldcal: {session_copy / LOG}: line {i + 1}: {message}"), command


def test_solve_on_a_session_that_is_no_procedure_run_names_it(tmp_path, capsys):
    """Issue 16: `solve` errors came without file and line."""
    from fieldcal.recording import Recording
    from fieldcal.recording.store import save_recording

    data = Path(__file__).resolve().parents[1] / "data" / "session-v1"  # start metadata of no run
    code, _, err = cli(capsys, "solve", data)
    assert code == 2
    assert one_line_error(err).startswith(f"fieldcal: {data / LOG}: line 1: the start document's metadata is "
                                          "not a procedure run's")
    t = np.arange(10) / 100.0
    recording = Recording(t=t, triads={"accelerometer": np.zeros((10, 3))}, kinds={"accelerometer": "specific_force"},
                          units={"accelerometer": "m/s^2"}, sources=(), malformed={})
    session = save_recording(recording, tmp_path / "rec")
    for command in ("solve", "replay", "resume"):
        code, _, err = cli(capsys, command, session)
        assert code == 2
        assert one_line_error(err).startswith(f"fieldcal: {session}: this session is an imported recording")
