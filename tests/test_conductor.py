"""The one run loop: sessions written before it (tests/data/golden, format of commit 58c3726)
still resume, replay and re-solve to the same parameter file, and the terminal UI's sessions
resume headless."""
from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from fieldcal.earth import Station
from fieldcal.paramfile import dump
from fieldcal.procedure.positions import load_procedure, parse_procedure
from fieldcal.run.replay import replay_session, resolve_session
from fieldcal.run.runner import OperatorScript, RunSpec, resume_headless, run_headless
from fieldcal.run.steps import steps_on_record
from fieldcal.session.capture import SessionReader

GOLDEN = Path(__file__).parent / "data" / "golden"
STATION = Station(40.0, 50.0)


def golden_procedure():
    """The shortened field-18 the golden sessions ran (their metadata holds the same YAML)."""
    text = load_procedure("field-18").text.replace("name: field-18", "name: golden-mini") \
        .replace("dwell_s: 200", "dwell_s: 3") \
        .replace("rate_step: {rate_deg_s: 10, turns: 1, ramp_s: 2, settle_s: 1}",
                 "rate_step: {rate_deg_s: 60, turns: 1, ramp_s: 3, settle_s: 1}")
    return parse_procedure(text, "golden-mini.yaml")


def test_the_golden_procedure_is_the_one_recorded():
    recorded = SessionReader(GOLDEN / "tui-quit").start["procedure"]["yaml"]
    assert golden_procedure().text == recorded


def test_an_old_resumed_headless_session_replays_and_resolves_to_its_parameter_file():
    session = GOLDEN / "headless-resumed"
    recorded = (session / "parameters.yaml").read_bytes()
    _, pf, samples = replay_session(session)
    assert dump(pf).encode() == recorded
    assert samples == SessionReader(session).n_samples
    _, pf = resolve_session(session)
    assert dump(pf).encode() == recorded


def test_old_tui_steps_read_with_their_separate_checkpoints():
    steps = steps_on_record(SessionReader(GOLDEN / "tui-quit"))
    assert [s.record.step for s in steps] == [0, 1, 2, 3, 4, 5]
    assert all(s.skipped == () and s.bench is not None and "sim" in s.bench for s in steps)


def test_an_old_tui_session_quit_half_way_resumes_to_the_uninterrupted_run(tmp_path):
    """Defect 1 of issue 10 on a session the old terminal UI wrote (it died with KeyError 'skipped')."""
    session = tmp_path / "tui-quit"
    shutil.copytree(GOLDEN / "tui-quit", session)
    resumed = resume_headless(session)
    whole = run_headless(RunSpec(golden_procedure(), STATION, seed=8, rate_hz=20.0,
                                 script=OperatorScript(handling_s=2.0)), tmp_path / "whole")
    assert resumed.status == "completed" and not resumed.unit.failures
    assert resumed.parameters.read_bytes() == whole.parameters.read_bytes()
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
        resume_headless(session)
    assert log.read_bytes() == before  # refused before anything was written
