"""Sessions in the shapes older fieldcal wrote, read by ``fieldcal.session.legacy`` only: format 1
(no checksums; tests/data/session-v1, and the golden sessions of commit 58c3726 in
tests/data/golden) and the old terminal UI's separate ``checkpoint`` documents. They still read,
resume, replay and re-solve to the same parameter file."""
from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from fieldcal.paramfile import dump, load
from fieldcal.run.environment import compare_parameters
from fieldcal.run.replay import replay, resolve_session
from fieldcal.run.runner import OperatorScript, RunSpec, open_run, resume_headless, run_headless
from fieldcal.session.capture import LOG, SessionReader, SessionWriter

from test_conductor import GOLDEN, STATION, _as_recorded, _shift_in_sigma, golden_procedure
from test_session import assert_all_identical, lines_of, small_chunk

DATA = Path(__file__).resolve().parent / "data"


def test_the_golden_procedure_is_the_one_recorded():
    recorded = SessionReader(GOLDEN / "tui-quit").start["procedure"]["yaml"]
    assert golden_procedure().text == recorded


def test_an_old_resumed_headless_session_replays_and_resolves_to_its_parameter_file():
    session = GOLDEN / "headless-resumed"
    recorded = load(session / "parameters.yaml")
    # Recorded before sessions named their numeric environment, and before the Powell search
    # was re-fed (issue 12): compared parameter by parameter in units of each recorded σ.
    replayed = replay(open_run(session))
    pf, samples = replayed.parameter_file, replayed.samples
    assert _as_recorded(pf, recorded), _shift_in_sigma(pf, recorded)
    assert samples == SessionReader(session).n_samples
    _, resolved = resolve_session(open_run(session))
    assert dump(resolved) == dump(pf)  # the re-solve from the log's averages is the replay's result
    found = compare_parameters(resolved, (session / "parameters.yaml").read_bytes(), None)
    assert "does not record its numeric environment" in found.text


def test_old_tui_steps_read_with_their_separate_checkpoints():
    steps = open_run(GOLDEN / "tui-quit").steps
    assert [s.record.step for s in steps] == [0, 1, 2, 3, 4, 5]
    assert all(s.skipped == () and s.bench is not None and "sim" in s.bench for s in steps)


def test_an_old_tui_session_quit_half_way_resumes_to_the_uninterrupted_run(tmp_path):
    """Defect 1 of issue 10 on a session the old terminal UI wrote (it died with KeyError 'skipped')."""
    session = tmp_path / "tui-quit"
    shutil.copytree(GOLDEN / "tui-quit", session)
    resumed = resume_headless(open_run(session))
    # The old session's simulator drew its noise one normal number per process ("bank"): the
    # uninterrupted run to compare with draws it the same way.
    whole = run_headless(RunSpec(golden_procedure(), STATION, seed=8, rate_hz=20.0,
                                 script=OperatorScript(handling_s=2.0), sim_noise="bank"), tmp_path / "whole")
    assert resumed.status == "completed" and not resumed.unit.failures
    # Its first six steps were averaged by the code of 58c3726, whose simulator noise summed in
    # another order (issue 12 made it closed-form): equal within 1e-3σ, not to the last bit.
    found = compare_parameters(load(resumed.parameters), whole.parameters.read_bytes(), None)
    assert found.identical, found.text
    # The golden copy itself is left as it was: resuming works on the copy only.
    assert not (GOLDEN / "tui-quit" / "parameters.yaml").exists()


def test_an_old_tui_session_killed_between_step_and_checkpoint_is_refused_in_one_line(tmp_path):
    session = tmp_path / "s"
    shutil.copytree(GOLDEN / "tui-quit", session)
    log = session / "log.jsonl"
    text = log.read_text()
    log.write_text(text[:text.rindex('{"seq"', 0, text.rindex('"type":"checkpoint"'))])
    before = log.read_bytes()
    with pytest.raises(ValueError, match="step 6: the session holds no bench state"):
        resume_headless(open_run(session))
    assert log.read_bytes() == before  # refused before anything was written


def test_fieldcal_resume_continues_an_old_tui_session(tmp_path):
    import subprocess
    import sys

    session = tmp_path / "tui-quit"
    shutil.copytree(GOLDEN / "tui-quit", session)
    done = subprocess.run([sys.executable, "-m", "fieldcal.cli.main", "resume", str(session), "--quiet"],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "resuming" in done.stdout and "after 6 completed steps" in done.stdout
    assert "Traceback" not in done.stderr and (session / "parameters.yaml").is_file()


def test_a_version_1_session_written_by_the_old_code_still_reads_and_resumes(tmp_path):
    """tests/data/session-v1 was written by the session writer of commit 58c3726 (format 1)."""
    import shutil

    d = tmp_path / "v1"
    shutil.copytree(DATA / "session-v1", d)
    r = SessionReader(d)
    assert r.start_document["schema"] == "fieldcal-session/1"
    assert [doc["type"] for doc in r.documents()] == ["start", "descriptor", "chunk", "event", "chunk", "event",
                                                      "chunk", "event", "step", "stop"]
    assert_all_identical(r.chunks(), [small_chunk(i) for i in range(3)])
    assert r.steps() == [{"step": 0, "value": 1.5}] and r.stopped and r.stop_reason == "completed"
    w = SessionWriter.append_to(d)  # continued with checksummed lines; version 1 ones stay as they are
    w.write_raw("imu", 1.0, b"abc")
    w.close()
    assert lines_of(d / LOG)[:10] == lines_of(DATA / "session-v1" / LOG)
    assert lines_of(d / LOG)[10].endswith(b'}\n') and b',"crc":' in lines_of(d / LOG)[10]
    assert [t for t, _ in SessionReader(d).raw("imu")] == [1.0]


def test_the_genuine_format_1_session_still_reads(tmp_path):
    from fieldcal.session.legacy import refuse_a_later_writer
    from fieldcal.session.capture import SessionReader

    golden = Path(__file__).parent / "data" / "session-v1"
    reader = SessionReader(golden)
    refuse_a_later_writer(reader)  # no exception: written before 0.2.0
    assert reader.start_document["schema"] == "fieldcal-session/1"
    assert np.isfinite(next(reader.chunks()).t).all()
