"""The run record's reading of a session's documents, on hand-written logs: every malformed step
or resume document named in one line (file, line, field), what a resume keeps, the skips, who
wrote each parameter file, and the check of a parameter file's bytes against its noted hash.

The log is given to ``RunRecord`` as the documents a ``SessionReader`` yields (type, seq, data),
written out here by hand, so each check stands on the session format, not on a run."""
import hashlib
import math
from pathlib import Path

import pytest

from fieldcal.procedure.windows import StepRecord, WindowKind, WindowRecord
from fieldcal.session import LOG, SessionError
from fieldcal.session.record import ParameterFileNote, ResumePoint, RunRecord, StepDocument

N = 3  # positions of the procedure the steps are checked against


class Log:
    """What RunRecord reads of a SessionReader: the documents in order (seq = line - 1)."""

    def __init__(self, directory: Path, *docs: dict) -> None:
        self.directory = directory
        self.docs = [{**doc, "seq": i} for i, doc in enumerate(docs)]
        self.torn, self.stopped, self.stop_reason = [], False, ""

    def documents(self, *types):
        return (d for d in self.docs if not types or d["type"] in types)


def window(kind="static", start=0.0, duration=10.0, rate=0.0, means=None, **more) -> dict:
    return {"kind": kind, "start": start, "duration": duration, "rate_deg_s": rate,
            "means": {"accelerometer": [0.0, 0.0, 9.8]} if means is None else means, **more}


def step(n, windows=None, **more) -> dict:
    return {"type": "step", "data": {"step": n, "position_id": 10 + n,
                                      "windows": [window(start=100.0 * n)] if windows is None else windows, **more}}


def start() -> dict:
    return {"type": "start", "data": {}}


def record(tmp_path, *docs) -> RunRecord:
    return RunRecord(Log(tmp_path, start(), *docs), None, N)


def refusal(tmp_path, *docs) -> str:
    with pytest.raises(SessionError) as refused:
        record(tmp_path, *docs)
    assert refused.value.path == str(tmp_path / LOG)
    assert refused.value.line == int(str(refused.value).split(": line ")[1].split(":")[0])
    return str(refused.value)


# --------------------------------------------------------------------------------------------
# The documents' shapes


def test_a_step_document_is_its_record_with_the_skips_and_the_bench():
    rec = StepRecord(1, 11, (WindowRecord(WindowKind.STATIC, 5.0, 10.0, 0.0, {"accelerometer": [0.0, 0.5, 9.8]}),))
    assert StepDocument(rec, (0, 2), {"table": "stopped"}).to_dict() == {
        "step": 1, "position_id": 11,
        "windows": [{"kind": "static", "start": 5.0, "duration": 10.0, "rate_deg_s": 0.0,
                     "means": {"accelerometer": [0.0, 0.5, 9.8]}}],
        "skipped": [0, 2], "bench": {"table": "stopped"}}
    assert StepDocument(rec, (), None).to_dict()["bench"] is None
    assert StepDocument(rec, (), None).line == 0


def test_a_resume_point_says_why_and_what_it_dropped_only_when_it_did():
    assert ResumePoint((0, 1), (2,)).to_dict() == {"completed_steps": [0, 1], "skipped": [2]}
    doc = ResumePoint((0,), (), "the device power-cycled", (1, 2)).to_dict()
    assert doc == {"completed_steps": [0], "skipped": [], "why": "the device power-cycled", "dropped": [1, 2]}
    assert ResumePoint.from_dict(doc) == ResumePoint((0,), (), "the device power-cycled", (1, 2))
    assert ResumePoint.from_dict({"completed_steps": [1], "skipped": [0]}) == ResumePoint((1,), (0,), "", ())


# --------------------------------------------------------------------------------------------
# A malformed step or resume document: one line naming the file, the line and the field


def _data(**changed):
    data = step(0)["data"]
    for key, value in changed.items():
        if value is KeyError:
            del data[key]
        else:
            data[key] = value
    return data


def _win(**changed):
    w = window()
    for key, value in changed.items():
        if value is KeyError:
            del w[key]
        else:
            w[key] = value
    return _data(windows=[w])


@pytest.mark.parametrize("data, why", [
    ([1, 2], "its data must be an object"),
    (_data(step=KeyError), "no 'step'"),
    (_data(step=3), "'step' must be a position index from 0 to 2, got 3"),
    (_data(step=-1), "'step' must be a position index from 0 to 2, got -1"),
    (_data(step=True), "'step' must be a position index from 0 to 2, got True"),
    (_data(step=1.0), "'step' must be a position index from 0 to 2, got 1.0"),
    (_data(step="x" * 300), ("'step' must be a position index from 0 to 2, got '" + "x" * 300)[:200]),
    (_data(position_id=KeyError), "no 'position_id'"),
    (_data(position_id="4"), "'position_id' must be an integer"),
    (_data(position_id=True), "'position_id' must be an integer"),
    (_data(windows=KeyError), "no 'windows' list"),
    (_data(windows={"0": window()}), "'windows' must be a list"),
    (_data(windows=[]), "'windows' is empty (a completed step has at least one averaged window)"),
    (_data(windows=[window(), 7]), "windows[1] must be an object"),
    (_win(kind=KeyError), "windows[0] has no 'kind'"),
    (_win(start=KeyError), "windows[0] has no 'start'"),
    (_win(duration=KeyError), "windows[0] has no 'duration'"),
    (_win(rate_deg_s=KeyError), "windows[0] has no 'rate_deg_s'"),
    (_win(means=KeyError), "windows[0] has no 'means'"),
    (_win(kind="spin"), "windows[0].kind must be static, plus or minus, got 'spin'"),
    (_win(start=math.nan), "windows[0].start must be a finite number, got nan"),
    (_win(start=True), "windows[0].start must be a finite number, got True"),
    (_win(start="0"), "windows[0].start must be a finite number, got '0'"),
    (_win(duration=-1.0), "windows[0].duration must be a finite number >= 0, got -1.0"),
    (_win(duration=math.inf), "windows[0].duration must be a finite number >= 0, got inf"),
    (_win(rate_deg_s=-math.inf), "windows[0].rate_deg_s must be a finite number, got -inf"),
    (_win(temperature_c="warm"), "windows[0].temperature_c must be a finite number (°C), got 'warm'"),
    (_win(temperature_c=None), "windows[0].temperature_c must be a finite number (°C), got None"),
    (_win(means=[]), "windows[0].means must be an object of triad means"),
    (_win(means={}), "windows[0].means must be an object of triad means"),
    (_win(means={"gyroscope": [1.0, 2.0]}), "windows[0].means.gyroscope must be 3 finite numbers, got [1.0, 2.0]"),
    (_win(means={"gyroscope": (1.0, 2.0, 3.0)}), "windows[0].means.gyroscope must be 3 finite numbers, got (1.0, 2.0, 3.0)"),
    (_win(means={"gyroscope": [1.0, 2.0, math.nan]}),
     "windows[0].means.gyroscope must be 3 finite numbers, got [1.0, 2.0, nan]"),
    (_data(skipped="1"), "'skipped' must be a list of position indices from 0 to 2"),
    (_data(skipped=[1, 3]), "'skipped' must be a list of position indices from 0 to 2"),
    (_data(bench=[1]), "'bench' must be an object or null"),
])
def test_a_malformed_step_document_is_one_line_naming_its_line_and_field(tmp_path, data, why):
    said = refusal(tmp_path, step(1), {"type": "step", "data": data})
    assert said == f"{tmp_path / LOG}: line 3: step document: {why}"


def test_a_well_formed_step_with_every_optional_field_reads(tmp_path):
    data = _win(temperature_c=21.5, duration=0.0, kind="plus", rate_deg_s=-10)
    data.update(skipped=[2], bench={"table": "stopped"})
    [doc] = record(tmp_path, {"type": "step", "data": data}).steps
    assert doc.line == 2 and doc.skipped == (2,) and doc.bench == {"table": "stopped"}
    assert doc.record.windows[0].temperature_c == 21.5 and doc.record.windows[0].kind == "plus"


def test_a_step_whose_triads_differ_from_the_earlier_steps_is_refused(tmp_path):
    later = step(1, [window(start=100.0), window(start=120.0, means={"gyroscope": [0.0, 0.0, 0.0]})])
    assert refusal(tmp_path, step(0), later) == (
        f"{tmp_path / LOG}: line 3: step document: windows[1].means has triads ['gyroscope'], "
        "earlier steps ['accelerometer']")


@pytest.mark.parametrize("data, key", [({"skipped": []}, "completed_steps"),
                                       ({"completed_steps": [0], "skipped": [3]}, "skipped"),
                                       ({"completed_steps": "0", "skipped": []}, "completed_steps"),
                                       ({"completed_steps": [True], "skipped": []}, "completed_steps")])
def test_a_malformed_resume_document_is_one_line_naming_its_field(tmp_path, data, key):
    assert refusal(tmp_path, step(0), {"type": "resume", "data": data}) == (
        f"{tmp_path / LOG}: line 3: resume document: {key!r} must be a list of position indices from 0 to 2")


# --------------------------------------------------------------------------------------------
# A step recorded again: only after what redoes it


def test_a_step_repeated_with_nothing_that_redoes_it_is_a_copied_line(tmp_path):
    assert refusal(tmp_path, step(0), {"type": "action", "data": {"action": "skip"}}, step(0)) == (
        f"{tmp_path / LOG}: line 4: step document: step 0 again (recorded at line 2) with no redo, unskip or "
        "resume before it: a repeated document, not a redo")


@pytest.mark.parametrize("between", [{"type": "action", "data": {"action": "redo"}},
                                     {"type": "action", "data": {"action": "unskip"}},
                                     {"type": "resume", "data": {"completed_steps": [0], "skipped": []}},
                                     {"type": "resume", "data": {}}])
def test_a_step_recorded_again_after_a_redo_unskip_or_resume_is_its_new_record(tmp_path, between):
    again = step(0, [window(start=50.0, means={"accelerometer": [0.0, 0.0, 9.7]})])
    rec = record(tmp_path, step(0), between, again)
    assert [d.line for d in rec.steps] == [2, 4]
    [last] = rec.completed
    assert last.windows[0].means["accelerometer"] == [0.0, 0.0, 9.7]
    assert [d.line for d in rec.completed_documents] == [4]


# --------------------------------------------------------------------------------------------
# What a resume keeps, and the skips


def skipped_event(n) -> dict:
    return {"type": "event", "data": {"event": "step_skipped", "t": 1.0, "step": n, "position_id": 10 + n}}


def test_skips_are_those_logged_less_the_steps_completed_since(tmp_path):
    rec = record(tmp_path, skipped_event(1), step(0), skipped_event(2), skipped_event(7),
                 {"type": "event", "data": {"event": "step_complete", "step": 0}},
                 {"type": "action", "data": {"action": "unskip"}}, step(1))
    assert rec.skipped == (2,)  # 1 done since; 7 is no position of the procedure
    assert [d.skipped for d in rec.steps] == [(1,), (1, 2)]  # old steps did not say: the skips so far
    assert [d.line for d in rec.steps] == [3, 8]


def test_a_resume_keeps_only_the_completed_steps_it_names_and_its_skips(tmp_path):
    resume = {"type": "resume", "data": {"completed_steps": [0], "skipped": [2], "why": "power-cycled",
                                         "dropped": [1]}}
    rec = record(tmp_path, step(0), skipped_event(2), step(1), skipped_event(1), resume)
    assert [d.record.step for d in rec.steps] == [0]
    assert rec.skipped == (2,)
    assert rec.resumes == (ResumePoint((0,), (2,), "power-cycled", (1,)),)
    assert [r.step for r in rec.completed] == [0]


def test_an_old_tui_checkpoint_gives_the_step_before_it_its_bench(tmp_path):
    checkpoint = {"type": "checkpoint", "data": {"step": 0, "bench": {"table": "stopped"}}}
    other = {"type": "checkpoint", "data": {"step": 2, "bench": {"table": "turning"}}}
    rec = record(tmp_path, skipped_event(2), step(0), checkpoint, step(1), other)
    assert [d.bench for d in rec.steps] == [{"table": "stopped"}, None]
    assert rec.steps[0].line == 3 and rec.steps[0].skipped == (2,)  # the step keeps its line and skips


def test_a_checkpoint_never_replaces_a_bench_the_step_document_holds(tmp_path):
    with_bench = step(0, bench={"table": "stopped"})
    rec = record(tmp_path, with_bench, {"type": "checkpoint", "data": {"step": 0, "bench": {"table": "x"}}})
    assert rec.steps[0].bench == {"table": "stopped"}


def test_no_positions_no_interpretation(tmp_path):
    rec = RunRecord(Log(tmp_path, start(), {"type": "step", "data": "not even an object"}), None, None)
    assert rec.steps == () and rec.resumes == () and rec.skipped == ()


# --------------------------------------------------------------------------------------------
# Windows that share sample time


def test_windows_of_two_steps_that_overlap_are_refused_naming_both_lines(tmp_path):
    early = step(0, [window(start=0.0, duration=10.0), window(start=20.0, duration=30.0)])
    late = step(1, [window(start=40.0, duration=5.0)])  # inside the first step's 20-50 s
    assert refusal(tmp_path, early, late) == (
        f"{tmp_path / LOG}: line 3: step document: a window from t 40.0 s overlaps one to t 50.0 s (step "
        "document at line 2): windows of the completed steps never share sample time (changed or forged windows)")


def test_windows_that_touch_or_overlap_by_rounding_only_are_accepted(tmp_path):
    a = step(0, [window(start=0.0, duration=10.0)])
    b = step(1, [window(start=10.0 - 1e-10, duration=5.0)])
    c = step(2, [window(start=15.0, duration=5.0)])
    assert len(record(tmp_path, a, b, c).completed) == 3


def test_a_redone_step_s_earlier_windows_do_not_count_as_an_overlap(tmp_path):
    first = step(0, [window(start=0.0, duration=10.0)])
    again = step(0, [window(start=5.0, duration=10.0)])  # overlaps the record it replaces, which no solve uses
    redo = {"type": "action", "data": {"action": "redo"}}
    rec = record(tmp_path, first, redo, again)
    assert [d.line for d in rec.completed_documents] == [4]


# --------------------------------------------------------------------------------------------
# Parameter files: who wrote each, and their bytes checked against the log


def parameters(name, data: bytes) -> dict:
    return {"type": "parameters", "file": name, "sha256": hashlib.sha256(data).hexdigest()}


def test_each_parameter_file_is_the_runs_or_a_re_solves_by_where_the_log_notes_it(tmp_path):
    for name in ("parameters-001.yaml", "parameters-002.yaml", "parameters-003.yaml"):
        (tmp_path / name).write_bytes(name.encode())
    rec = RunRecord(Log(tmp_path, start(), parameters("parameters-001.yaml", b"parameters-001.yaml"),
                        {"type": "stop", "data": {}}, parameters("parameters-002.yaml", b"parameters-002.yaml"),
                        {"type": "resume", "data": {}}, parameters("parameters-003.yaml", b"parameters-003.yaml"),
                        {"type": "stop", "data": {}}, parameters("parameters-004.yaml", b"gone")), None, None)
    notes = rec.parameter_files
    assert [(n.file, n.line, n.written_by) for n in notes] == [
        ("parameters-001.yaml", 2, "run"), ("parameters-002.yaml", 4, "re-solve"),
        ("parameters-003.yaml", 6, "run"), ("parameters-004.yaml", 8, "re-solve")]
    assert notes[0].path == tmp_path / "parameters-001.yaml"
    assert rec.current_parameters is notes[3] and rec.run_parameters is notes[2]
    assert rec.resolved_after(notes[0]) == [notes[1], notes[3]]
    assert rec.resolved_after(notes[2]) == [notes[3]]
    assert rec.resolved_after(notes[1]) == [notes[3]]  # not itself
    assert notes[1].sha256 == hashlib.sha256(b"parameters-002.yaml").hexdigest()
    assert rec.parameters_path is None  # the current one is not there
    assert [n.exists for n in notes] == [True, True, True, False]


def test_a_session_without_parameter_files_has_no_current_or_run_file(tmp_path):
    rec = RunRecord(Log(tmp_path, start(), {"type": "stop", "data": {}}), None, None)
    assert rec.parameter_files == () and rec.current_parameters is None and rec.run_parameters is None
    assert rec.parameters_path is None


def test_a_re_solve_alone_is_no_run_file(tmp_path):
    (tmp_path / "p.yaml").write_bytes(b"x")
    rec = RunRecord(Log(tmp_path, start(), {"type": "stop", "data": {}}, parameters("p.yaml", b"x")), None, None)
    assert rec.run_parameters is None and rec.parameters_path == tmp_path / "p.yaml"


def test_solved_at_is_the_last_solved_events_sample_time(tmp_path):
    solved = [{"type": "event", "data": {"event": "solved", "t": 12.5}},
              {"type": "event", "data": {"event": "aborted", "t": 99.0}},
              {"type": "event", "data": {"event": "solved", "t": 30}},
              {"type": "event", "data": {"event": "solved", "t": "later"}},
              {"type": "event", "data": None}]
    assert RunRecord(Log(tmp_path, start(), *solved), None, None).solved_at == 30.0
    assert RunRecord(Log(tmp_path, start()), None, None).solved_at is None


def note(tmp_path, data: bytes, line=7) -> ParameterFileNote:
    return ParameterFileNote("parameters.yaml", hashlib.sha256(data).hexdigest(), line, "run",
                             tmp_path / "parameters.yaml")


def test_a_parameter_file_reads_only_as_the_bytes_its_hash_notes(tmp_path):
    (tmp_path / "parameters.yaml").write_bytes(b"genuine\n")
    assert note(tmp_path, b"genuine\n").read_bytes() == b"genuine\n"
    edited = note(tmp_path, b"as written\n")
    with pytest.raises(SessionError) as refused:
        edited.read_bytes()
    assert str(refused.value) == (f"{tmp_path / 'parameters.yaml'}: not the file {LOG} line 7 notes (its SHA-256 "
                                  "differs): changed after it was written")
    assert refused.value.path == str(tmp_path / "parameters.yaml") and refused.value.line == 7
    assert edited.read_bytes(check=False) == b"genuine\n"  # to show where they differ


def test_an_old_sessions_replaced_parameter_file_is_found_under_its_number(tmp_path):
    (tmp_path / "parameters.yaml").write_bytes(b"the re-solve's\n")
    (tmp_path / "parameters-001.yaml").write_bytes(b"older\n")
    (tmp_path / "parameters-002.yaml").write_bytes(b"the run's\n")
    (tmp_path / "parameters-x.yaml").write_bytes(b"the run's?\n")
    assert note(tmp_path, b"the run's\n").read_bytes() == b"the run's\n"
    assert note(tmp_path, b"the run's\n").read_bytes(check=False) == b"the run's\n"
    # only a numbered file counts (parameters-x.yaml is no kept copy)
    with pytest.raises(SessionError, match="its SHA-256 differs"):
        note(tmp_path, b"the run's?\n").read_bytes()


def test_a_parameter_file_that_cannot_be_read_is_one_line(tmp_path):
    with pytest.raises(SessionError) as refused:
        note(tmp_path, b"x", line=9).read_bytes()
    assert str(refused.value) == (f"{tmp_path / 'parameters.yaml'}: the session's parameter file (noted in {LOG} "
                                  "line 9) cannot be read (No such file or directory)")
    assert refused.value.path == str(tmp_path / "parameters.yaml")


def test_the_other_window_kinds_are_accepted_and_a_long_kind_is_cut_to_200_characters(tmp_path):
    turning = step(0, [window(kind="plus", rate=10.0), window(kind="minus", start=20.0, rate=-10.0)])
    assert [w.kind for w in record(tmp_path, turning).completed[0].windows] == ["plus", "minus"]
    why = refusal(tmp_path, {"type": "step", "data": _win(kind="y" * 300)})
    assert why == f"{tmp_path / LOG}: line 2: step document: " + (
        "windows[0].kind must be static, plus or minus, got '" + "y" * 300)[:200]


GOLDEN = Path(__file__).parent / "data" / "golden" / "headless-resumed" / "parameters.yaml"


def test_a_parameter_files_provenance_is_read_from_its_checked_bytes(tmp_path):
    data = GOLDEN.read_bytes()
    (tmp_path / "parameters.yaml").write_bytes(data)
    genuine = note(tmp_path, data)
    # the file's own provenance lines (tests/data/golden/headless-resumed/parameters.yaml, lines 9-10)
    assert genuine.method() == "powell"
    assert genuine.input_sha256() == "b478e15eca6368b671c162c3b4e21a22d8545c442e0cb9d0e06b5b419e593fa2"
    assert genuine.provenance().method == "powell"
    not_parameters = b"x: 1\n"
    (tmp_path / "parameters.yaml").write_bytes(not_parameters)
    with pytest.raises(ValueError) as refused:
        note(tmp_path, not_parameters).provenance()
    assert str(refused.value).startswith(f"{tmp_path / 'parameters.yaml'}: schema: ")


@pytest.mark.parametrize("data, start", [
    (_win(start="s" * 300), "windows[0].start must be a finite number, got '"),
    (_win(temperature_c="t" * 300), "windows[0].temperature_c must be a finite number (°C), got '"),
    (_win(means={"gyroscope": ["m" * 300]}), "windows[0].means.gyroscope must be 3 finite numbers, got ['"),
])
def test_a_long_bad_value_is_cut_so_the_line_stays_at_200_characters(tmp_path, data, start):
    why = refusal(tmp_path, {"type": "step", "data": data})
    prefix = f"{tmp_path / LOG}: line 2: step document: "
    assert why.startswith(prefix + start) and len(why) == len(prefix) + 200


def test_the_record_keeps_the_spec_and_how_the_run_ended(tmp_path):
    log = Log(tmp_path, start())
    log.torn, log.stopped, log.stop_reason = ["a half-written line"], True, "operator quit"
    spec = object()
    rec = RunRecord(log, spec, None)
    assert rec.spec is spec and rec.directory == tmp_path and rec.reader is log
    assert rec.torn == ["a half-written line"] and rec.torn is not log.torn
    assert rec.stopped is True and rec.stop_reason == "operator quit"


# --------------------------------------------------------------------------------------------
# RunRecord.open on a session written by the session writer


def _session(tmp_path, *steps, raw: bytes = b"") -> Path:
    from fieldcal.session.capture import SessionWriter

    d = tmp_path / "s"
    w = SessionWriter.create(d, {"procedure": "three positions", "seed": 4})
    for data in steps:
        w.step(data)
    if raw:
        w.write_raw("imu", 1.5, raw)
    w.stop("done")
    w.close()
    return d


def _spec(n):
    from types import SimpleNamespace

    return SimpleNamespace(procedure=SimpleNamespace(positions=list(range(n))))


def test_open_checks_the_steps_against_the_spec_the_start_metadata_gives(tmp_path):
    d = _session(tmp_path, step(0)["data"], step(2)["data"], raw=b"\x01\x02 device bytes")
    given = []
    rec = RunRecord.open(d, spec_from=lambda meta: given.append(meta) or _spec(3))
    assert given == [{"procedure": "three positions", "seed": 4}]
    assert [s.record.step for s in rec.steps] == [0, 2] and [s.line for s in rec.steps] == [2, 3]
    assert rec.stopped and rec.stop_reason == "done" and rec.torn == []
    assert rec.start == {"procedure": "three positions", "seed": 4}
    assert rec.start_document["schema"] == "fieldcal-session/2"
    assert [doc["seq"] for doc in rec.documents("step")] == [1, 2]
    assert rec.n_samples == 0 and list(rec.chunks()) == []
    assert rec.raw_names == ["imu"] and list(rec.raw("imu")) == [(1.5, b"\x01\x02 device bytes")]
    assert list(rec.replay_items()) == [] and list(rec.replay_items(("step",))) != []
    with pytest.raises(SessionError, match=r"line 3: step document: 'step' must be a position index from 0 to 1, got 2"):
        RunRecord.open(d, spec_from=lambda meta: _spec(2))


def test_open_without_a_spec_reads_no_steps(tmp_path):
    d = _session(tmp_path, step(0)["data"])
    for rec in (RunRecord.open(d), RunRecord.open(d, log_only=True), RunRecord.open(d, spec_from=lambda meta: None)):
        assert rec.spec is None and rec.steps == () and rec.skipped == ()


@pytest.mark.parametrize("error", [KeyError, TypeError, AttributeError])
def test_metadata_that_is_no_procedure_runs_is_one_line_at_line_1(tmp_path, error):
    d = _session(tmp_path)

    def spec_from(meta):
        raise error("procedure")

    with pytest.raises(SessionError) as refused:
        RunRecord.open(d, spec_from=spec_from)
    said = "'procedure'" if error is KeyError else "procedure"
    assert str(refused.value) == (f"{d / LOG}: line 1: the start document's metadata is not a procedure run's "
                                  f"({error.__name__}: {said})")
    assert refused.value.path == str(d / LOG) and refused.value.line == 1


def test_a_long_reason_is_cut_at_300_characters(tmp_path):
    d = _session(tmp_path)

    def spec_from(meta):
        raise TypeError("x" * 400)

    with pytest.raises(SessionError) as refused:
        RunRecord.open(d, spec_from=spec_from)
    assert str(refused.value) == (f"{d / LOG}: line 1: the start document's metadata is not a procedure run's "
                                  "(TypeError: " + "x" * 400)[:300]


@pytest.mark.parametrize("message, said", [("a recording session, not a procedure run\nsee fieldcal calibrate",
                                            "a recording session, not a procedure run"), ("", "")])
def test_a_session_the_spec_refuses_is_its_first_line_naming_the_directory(tmp_path, message, said):
    d = _session(tmp_path)

    def spec_from(meta):
        raise ValueError(message)

    with pytest.raises(ValueError) as refused:
        RunRecord.open(d, spec_from=spec_from)
    assert type(refused.value) is ValueError and str(refused.value) == f"{d}: {said}"


def test_two_windows_that_overlap_by_half_a_second_are_refused(tmp_path):
    a = step(0, [window(start=0.0, duration=10.0)])
    b = step(1, [window(start=9.5, duration=5.5)])  # ends after the first: only its start overlaps
    assert refusal(tmp_path, a, b) == (
        f"{tmp_path / LOG}: line 3: step document: a window from t 9.5 s overlaps one to t 10.0 s (step "
        "document at line 2): windows of the completed steps never share sample time (changed or forged windows)")


def test_a_window_starting_within_the_tolerance_of_the_last_end_is_accepted(tmp_path):
    a = step(0, [window(start=0.0, duration=10.0)])
    b = step(1, [window(start=10.0 - 1e-9, duration=5.0)])  # exactly the tolerance: not an overlap
    assert len(record(tmp_path, a, b).completed) == 2


GOLDEN_SESSION = Path(__file__).parent / "data" / "golden" / "headless-resumed"


def test_open_requires_the_sample_data_unless_asked_for_the_log_only(tmp_path):
    import shutil

    d = tmp_path / "s"
    shutil.copytree(GOLDEN_SESSION, d)
    (d / "samples.bin").unlink()  # the log's chunks have no samples now (a copy of the log alone)
    with pytest.raises(SessionError, match=r"samples.bin: .* but log.jsonl line \d+ refers to it"):
        RunRecord.open(d)
    rec = RunRecord.open(d, log_only=True)
    assert len(rec.parameter_files) >= 1 and rec.n_samples > 0  # the log's count of them
