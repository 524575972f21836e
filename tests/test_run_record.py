"""The run record: one reader gives a session's meaning to every command (issue 24).

The first tests pin five wrong results the scattered readers gave, each reproduced on a copy of
one completed headless run: a demo's parameter file hashing no inputs, a re-solve that trips on
a malformed step document, a certificate for a session replay refuses, a replay that compares
with a re-solve's file instead of the run's, and forged step averages that replay vouched for.
"""
import json
import re
import zlib
from pathlib import Path

import numpy as np
import pytest

from fieldcal.cli.main import main
from fieldcal.paramfile import hash_inputs, load
from test_production import _copy, pristine_session  # noqa: F401 (a module fixture, requested by name)


def _lines(session: Path) -> list[dict]:
    """The log's documents, each without its "crc" (as the writer composed them)."""
    docs = []
    for raw in (session / "log.jsonl").read_text().splitlines():
        doc = json.loads(raw)
        doc.pop("crc", None)
        docs.append(doc)
    return docs


def _write(session: Path, docs: list[dict], crc: bool = True) -> None:
    """The documents back as log lines, each with a CRC recomputed the writer's way (a forger
    who read docs/reference/session-format.md), or with none (format 1)."""
    out = []
    for doc in docs:
        body = json.dumps(doc, ensure_ascii=True, separators=(",", ":")).encode("ascii")
        out.append(body[:-1] + b',"crc":%d}' % zlib.crc32(body) if crc else body)
    (session / "log.jsonl").write_bytes(b"\n".join(out) + b"\n")


def _first_step(docs: list[dict]) -> int:
    return next(i for i, d in enumerate(docs) if d["type"] == "step")


def _registry(tmp_path) -> list[str]:
    return ["--registry", str(tmp_path / "r.sqlite")]


# --------------------------------------------------------------------------------------------
# 1. fieldcal demo --procedure classic-12 --params: the hash of the averages solved from


def test_the_demos_classic_parameter_file_hashes_the_averages_it_was_solved_from(tmp_path, capsys):
    hashes = []
    for seed in (1, 2):
        path = tmp_path / f"classic-{seed}.yaml"
        assert main(["demo", "--procedure", "classic-12", "--seed", str(seed), "--params", str(path)]) == 0
        hashes.append(load(path).provenance.input_sha256)
    capsys.readouterr()
    assert hash_inputs() not in hashes  # not the hash of no inputs
    assert hashes[0] != hashes[1]  # other seeds, other averages
    # the field procedure's hash was already right: the same builder now serves both
    path = tmp_path / "field.yaml"
    assert main(["demo", "--seed", "1", "--params", str(path)]) == 0
    assert load(path).provenance.input_sha256 not in (hash_inputs(), *hashes)


# --------------------------------------------------------------------------------------------
# 2. fieldcal resolve with malformed step documents: one line naming file, line and field


@pytest.mark.parametrize("damage, field", [
    (lambda w: w["means"].__setitem__("accelerometer", w["means"]["accelerometer"][:2]),
     "windows[0].means.accelerometer must be 3 finite numbers"),
    (lambda w: w.pop("duration"), "windows[0] has no 'duration'"),
])
def test_resolve_names_the_file_line_and_field_of_a_malformed_step(pristine_session, tmp_path, capsys,
                                                                    damage, field):
    session = _copy(pristine_session, tmp_path / "s")
    docs = _lines(session)
    i = _first_step(docs)
    damage(docs[i]["data"]["windows"][0])
    _write(session, docs)

    assert main(["resolve", str(session), "--method", "lsq", *_registry(tmp_path)]) == 1
    out = capsys.readouterr().out.splitlines()
    assert out[1] == (f"[1/1] FAILED {session}: {session / 'log.jsonl'}: line {i + 1}: step document: {field}"
                      + out[1][out[1].index(field) + len(field):])
    assert "inhomogeneous" not in out[1] and "KeyError" not in out[1]
    assert not (session / "parameters-002.yaml").exists()


# --------------------------------------------------------------------------------------------
# 3. fieldcal certificate: no certificate for a session replay refuses


def _flip_a_sample_byte(session: Path) -> None:
    """One bit of one sample changed inside samples.bin (the record's CRC no longer matches)."""
    docs = _lines(session)
    chunk = next(d for d in docs if d["type"] == "chunk" and d["n"] > 0)
    data = bytearray((session / "samples.bin").read_bytes())
    data[chunk["offset"] + chunk["length"] - 3] ^= 0x10
    (session / "samples.bin").write_bytes(bytes(data))


def _drop_a_duration(session: Path) -> None:
    docs = _lines(session)
    docs[_first_step(docs)]["data"]["windows"][0].pop("duration")
    _write(session, docs)


@pytest.mark.parametrize("damage, said", [(_drop_a_duration, "windows[0] has no 'duration'"),
                                          (_flip_a_sample_byte, "checksum mismatch")])
def test_certificate_refuses_a_session_replay_refuses(pristine_session, tmp_path, capsys, damage, said):
    session = _copy(pristine_session, tmp_path / "s")
    damage(session)
    assert main(["replay", str(session), "--quiet", *_registry(tmp_path)]) == 2
    assert said in capsys.readouterr().err

    out = tmp_path / "cert.html"
    assert main(["certificate", str(session), "--out", str(out), "--no-pdf"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and said in err[0], err
    assert not out.exists()


def test_certificate_refuses_a_session_with_forged_averages(pristine_session, tmp_path, capsys):
    session = _copy(pristine_session, tmp_path / "s")
    _forge_an_average(session)
    out = tmp_path / "cert.html"
    assert main(["certificate", str(session), "--out", str(out), "--no-pdf"]) == 2
    assert "differ" in capsys.readouterr().err
    assert not out.exists()


# --------------------------------------------------------------------------------------------
# 4. replay after resolve --method lsq compares with the run's own parameter file


def test_replay_after_a_re_solve_compares_with_the_file_the_run_wrote_and_names_the_re_solve(
        pristine_session, tmp_path, capsys):
    session = _copy(pristine_session, tmp_path / "s")
    assert main(["resolve", str(session), "--method", "lsq", *_registry(tmp_path)]) == 0
    assert (session / "parameters.yaml").read_bytes() == (session / "parameters-002.yaml").read_bytes()
    capsys.readouterr()

    replayed = tmp_path / "replayed.yaml"
    assert main(["replay", str(session), "--quiet", "--out", str(replayed), *_registry(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert replayed.read_bytes() == (session / "parameters-001.yaml").read_bytes()  # the run's, byte for byte
    assert "parameters-001.yaml" in out and "identical" in out and "DIFFERS" not in out
    assert re.search(r"re-solved later: parameters-002\.yaml \(lsq", out), out


# --------------------------------------------------------------------------------------------
# 5. forged step averages: replay refuses them


MG = 9.80665e-3


def _forge_an_average(session: Path, crc: bool = True, schema: str | None = None) -> int:
    """The first step's accelerometer mean moved by 0.01 mg along x, its CRC recomputed (or,
    with ``crc`` False, the whole log rewritten as format 1: no checksums). Its log line."""
    docs = _lines(session)
    i = _first_step(docs)
    for w in docs[i]["data"]["windows"]:
        if "accelerometer" in w["means"]:
            w["means"]["accelerometer"][0] += 0.01 * MG
    if schema is not None:
        docs[0]["schema"] = schema
    _write(session, docs, crc=crc)
    return i + 1


def test_replay_refuses_step_averages_that_are_not_the_samples_averages(pristine_session, tmp_path, capsys):
    session = _copy(pristine_session, tmp_path / "s")
    line = _forge_an_average(session)
    assert main(["replay", str(session), "--quiet", *_registry(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert f"{session / 'log.jsonl'}: line {line}: " in err[0]
    assert "accelerometer" in err[0] and "differ" in err[0] and "samples" in err[0]


@pytest.mark.parametrize("field, change", [("rate_deg_s", 0.5), ("start", 1e-3), ("duration", -1e-3)])
def test_replay_refuses_a_step_whose_window_was_moved_or_its_rate_changed(pristine_session, tmp_path, capsys,
                                                                           field, change):
    """Not only the means: a window's table rate or edges, forged with the CRC recomputed, change
    what the solvers read (a reviewer's forged rate moved the gyro bias σ from 0.4 to 56 °/h while
    replay said identical); replay refuses, naming the line and the field."""
    session = _copy(pristine_session, tmp_path / "s")
    docs = _lines(session)
    i = _first_step(docs)
    window = docs[i]["data"]["windows"][-1]
    window[field] += change
    _write(session, docs, crc=True)
    assert main(["replay", str(session), "--quiet", *_registry(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert f"{session / 'log.jsonl'}: line {i + 1}: " in err[0] and f"logged {field}" in err[0]


def test_a_step_document_without_windows_is_refused_by_solve_and_resolve(pristine_session, tmp_path, capsys):
    """A completed step with no window (CRC recomputed): solve once exited 0 and resolve wrote a
    new current parameter file from it (a reviewer's reproduction); now one line naming the line."""
    session = _copy(pristine_session, tmp_path / "s")
    docs = _lines(session)
    i = _first_step(docs)
    docs[i]["data"]["windows"] = []
    _write(session, docs, crc=True)
    for argv in (["solve", str(session)], ["resolve", str(session), *_registry(tmp_path)]):
        status = main(argv)
        captured = capsys.readouterr()
        assert status != 0, argv
        assert f"line {i + 1}" in captured.err + captured.out and "'windows' is empty" in captured.err + captured.out
    assert not (session / "parameters-002.yaml").exists()


def test_the_averages_check_passes_an_untouched_session(pristine_session, tmp_path, capsys):
    """The same check on the untouched copy: the averages agree bit for bit (same environment)."""
    session = _copy(pristine_session, tmp_path / "s")
    assert main(["replay", str(session), "--quiet", *_registry(tmp_path)]) == 0
    assert "identical" in capsys.readouterr().out


def test_a_format_1_session_written_by_a_later_fieldcal_is_refused(pristine_session, tmp_path, capsys):
    """Format 1 (no checksums) is still read for the sessions written before 0.2.0; today's run
    passed off as one (every crc deleted) shows its writer: fieldcal 0.2.0, numbered parameter files."""
    session = _copy(pristine_session, tmp_path / "s")
    _forge_an_average(session, crc=False, schema="fieldcal-session/1")
    for argv in (["replay", str(session), "--quiet", *_registry(tmp_path)], ["solve", str(session)],
                 ["resolve", str(session), "--method", "lsq", *_registry(tmp_path)]):
        status = main(argv)
        captured = capsys.readouterr()
        text = captured.err + captured.out
        assert status != 0, argv
        assert "format 1" in text and "0.2.0" in text, (argv, text)
    assert not (session / "parameters-002.yaml").exists()


# --------------------------------------------------------------------------------------------
# One scan: every command reads a session's log once


def _unfinished(session: Path) -> Path:
    from crashes import cut_before_step_record

    cut_before_step_record(session, 5)  # killed before its 6th step document
    return session


@pytest.mark.parametrize("command, prepare", [
    (lambda s, t: ["solve", str(s)], None),
    (lambda s, t: ["resolve", str(s), "--method", "lsq", *_registry(t)], None),
    (lambda s, t: ["replay", str(s), "--quiet", *_registry(t)], None),
    (lambda s, t: ["certificate", str(s), "--out", str(t / "c.html"), "--no-pdf"], None),
    (lambda s, t: ["allan", str(s), "--plot-dir", str(t / "plots")], None),
    (lambda s, t: ["resume", str(s), "--quiet"], _unfinished),
], ids=["solve", "resolve", "replay", "certificate", "allan", "resume"])
def test_every_command_reads_the_session_log_once(pristine_session, tmp_path, monkeypatch, capsys,
                                                  command, prepare):
    from fieldcal.session import capture

    session = _copy(pristine_session, tmp_path / "s")
    if prepare is not None:
        prepare(session)
    scans = []
    scan = capture._scan
    monkeypatch.setattr(capture, "_scan", lambda d, verb, **kw: scans.append((Path(d).resolve(), verb))
                        or scan(d, verb, **kw))
    assert main(command(session, tmp_path)) == 0, capsys.readouterr()
    reads = [verb for d, verb in scans if d == session.resolve() and verb == "ignored"]
    assert len(reads) == 1, scans
    # a command that writes into the session reopens it once more, under its lock, to append
    assert [verb for d, verb in scans if verb != "ignored"] == \
        (["cut"] if command(session, tmp_path)[0] in ("resolve", "resume") else [])


# --------------------------------------------------------------------------------------------
# The record's typed view


def test_the_record_says_who_wrote_each_parameter_file_and_from_which_averages(pristine_session, tmp_path, capsys):
    from fieldcal.run.runner import open_run

    session = _copy(pristine_session, tmp_path / "s")
    assert main(["resolve", str(session), "--method", "lsq", *_registry(tmp_path)]) == 0
    record = open_run(session)
    run, resolve = record.parameter_files
    assert (run.file, run.written_by) == ("parameters-001.yaml", "run")
    assert (resolve.file, resolve.written_by) == ("parameters-002.yaml", "re-solve")
    assert record.run_parameters is run and record.current_parameters is resolve
    assert record.resolved_after(run) == [resolve]
    assert (run.method(), resolve.method()) == ("powell", "lsq")
    # both solved from the same step averages: the same input hash, that of the log's averages
    assert run.input_sha256() == resolve.input_sha256()
    assert record.stop_reason == "completed" and not record.torn and record.skipped == ()
    assert [r.step for r in record.completed] == list(range(18))
    assert all(d.line > 1 and d.bench is not None for d in record.steps)


def _nudge_the_first_average(session: Path, ulps: int) -> None:
    docs = _lines(session)
    w = docs[_first_step(docs)]["data"]["windows"][0]
    x = w["means"]["accelerometer"][0]
    for _ in range(ulps):
        x = float(np.nextafter(x, np.inf))
    w["means"]["accelerometer"][0] = x
    _write(session, docs)


def test_replay_compares_averages_bit_for_bit_here_and_within_the_tolerance_elsewhere(
        pristine_session, tmp_path, monkeypatch):
    from fieldcal.run import environment, replay as replay_module
    from fieldcal.run.replay import replay
    from fieldcal.run.runner import open_run
    from fieldcal.session import SessionError

    session = _copy(pristine_session, tmp_path / "s")
    _nudge_the_first_average(session, 4)  # a few units in the last place: summation order elsewhere
    with pytest.raises(SessionError, match="compared bit for bit"):
        replay(open_run(session))
    recorded = open_run(session).start["numeric_environment"]
    elsewhere = {**recorded, "blas": "another BLAS 9.9"}
    monkeypatch.setattr(replay_module, "numeric_environment", lambda: elsewhere)
    monkeypatch.setattr(environment, "numeric_environment", lambda: elsewhere)
    outcome = replay(open_run(session))  # within AVERAGES_RTOL: vouched for
    assert outcome.identical is True and "within" in outcome.comparison
    forged = _copy(pristine_session, tmp_path / "forged")
    _forge_an_average(forged)  # 0.01 mg: far outside the tolerance, in any environment
    with pytest.raises(SessionError, match=f"within {replay_module.AVERAGES_RTOL:g} relative"):
        replay(open_run(forged))


def test_the_tui_replay_after_a_re_solve_compares_with_the_runs_file_and_names_the_re_solve(
        pristine_session, tmp_path, capsys):
    from fieldcal.run.runner import open_run
    from fieldcal.tui.source import ReplaySource
    from test_conductor import KeySink

    session = _copy(pristine_session, tmp_path / "s")
    assert main(["resolve", str(session), "--method", "lsq", *_registry(tmp_path)]) == 0
    sink = KeySink()
    source = sink.source = ReplaySource(open_run(session), sink, speed=0)
    outcome = source.run()
    assert outcome.identical is True and outcome.parameters == session / "parameters-001.yaml"
    said = [getattr(i, "text", "") for i in sink.items]
    assert any("parameters-001.yaml" in t and "byte for byte" in t for t in said), said
    assert any(t.startswith("re-solved later: parameters-002.yaml (lsq)") for t in said), said
