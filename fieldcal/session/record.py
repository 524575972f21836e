"""The run record: what a written session means, read once, for every command and front end.

A session's log is scanned and checked once (``SessionReader``); here its documents get their
meaning, in one place for the writer's side (``StepDocument``, ``ResumePoint``: what the
recorder writes) and for every reader: the run's spec, every step document checked for the
shape the solvers rely on (one line naming the file, line and field otherwise), which completed
steps a resume kept, the steps skipped, the parameter files with who wrote each, the torn tail
and how the run stopped. Older shapes are read by ``fieldcal.session.legacy`` only.

The record is built below the run layer: the spec (``fieldcal.run.runner.RunSpec``) is rebuilt
by the caller's ``spec_from`` (``fieldcal.run.runner.open_run`` gives it), so the session layer
imports nothing above it.
"""
from __future__ import annotations

import math
import os
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from fieldcal.procedure import events as ev
from fieldcal.procedure.windows import StepRecord
from fieldcal.session import LOG, SessionError
from fieldcal.session.capture import PARAMETERS_NUMBERED, SessionReader
from fieldcal.session.legacy import old_tui_bench, refuse_a_later_writer


# --------------------------------------------------------------------------------------------
# The documents a run writes (the recorder's side)


@dataclass(frozen=True)
class StepDocument:
    """A session's ``step`` document: a completed step and what resuming after it needs."""

    record: StepRecord
    skipped: tuple[int, ...]  # steps skipped so far
    bench: dict | None  # the bench's state right after the step (None: not recorded)
    line: int = 0  # its line in log.jsonl (0: not read from a log)

    def to_dict(self) -> dict:
        return {**self.record.to_dict(), "skipped": list(self.skipped), "bench": self.bench}


@dataclass(frozen=True)
class ResumePoint:
    """Where a run continued: the steps it kept (and, so, the ones it did again). ``why``: why
    completed steps were not kept (a live device power-cycled meanwhile), if any were not, and
    ``dropped``: which."""

    completed_steps: tuple[int, ...]
    skipped: tuple[int, ...]
    why: str = ""
    dropped: tuple[int, ...] = ()  # the completed steps not kept (measured again), if any

    def to_dict(self) -> dict:
        doc: dict[str, Any] = {"completed_steps": list(self.completed_steps), "skipped": list(self.skipped)}
        if self.why:
            doc["why"] = self.why
        if self.dropped:
            doc["dropped"] = list(self.dropped)
        return doc

    @classmethod
    def from_dict(cls, doc: dict) -> ResumePoint:
        return cls(tuple(int(s) for s in doc["completed_steps"]), tuple(int(s) for s in doc["skipped"]),
                   str(doc.get("why", "")), tuple(int(s) for s in doc.get("dropped", ())))


@dataclass(frozen=True)
class ParameterFileNote:
    """A parameter file the log notes: which file, its SHA-256, and who wrote it -- ``"run"``
    (the run concluding, between its start or resume and its stop) or ``"re-solve"`` (written
    into the session after its run ended: ``fieldcal resolve``)."""

    file: str
    sha256: str
    line: int
    written_by: str
    path: Path

    @property
    def exists(self) -> bool:
        return self.path.is_file()

    def read_bytes(self, check: bool = True) -> bytes:
        """The file's bytes, checked against the SHA-256 the log noted (a one-line SessionError
        if they differ; ``check`` False: the edited bytes are returned, for a comparison to
        show where they differ)."""
        import hashlib

        try:
            data = self.path.read_bytes()
        except OSError as exc:
            raise SessionError(f"{self.path}: the session's parameter file (noted in {LOG} line {self.line}) "
                               f"cannot be read ({exc.strerror or exc})", str(self.path)) from None
        if hashlib.sha256(data).hexdigest() != self.sha256:
            # a session from before numbered files: its run wrote parameters.yaml, which a later
            # re-solve replaced after keeping it under the next number
            for kept in sorted(self.path.parent.glob("parameters-*.yaml")):
                if PARAMETERS_NUMBERED.fullmatch(kept.name) and \
                        hashlib.sha256(old := kept.read_bytes()).hexdigest() == self.sha256:
                    return old
            if not check:
                return data
            raise SessionError(f"{self.path}: not the file {LOG} line {self.line} notes (its SHA-256 differs): "
                               "changed after it was written", str(self.path), self.line)
        return data

    def provenance(self):
        """The file's provenance (``fieldcal.paramfile.Provenance``: method, ``input_sha256`` of
        the averages it was solved from, station, device, ...), the file checked against the log."""
        from fieldcal.paramfile import loads

        return loads(self.read_bytes().decode("utf-8"), str(self.path)).provenance

    def method(self) -> str:
        return self.provenance().method

    def input_sha256(self) -> str:
        return self.provenance().input_sha256


# --------------------------------------------------------------------------------------------
# Checking a step document


def _number(value) -> bool:
    return not isinstance(value, bool) and isinstance(value, (int, float)) and math.isfinite(value)


def _index(value, n_positions: int) -> bool:
    return not isinstance(value, bool) and isinstance(value, int) and 0 <= value < n_positions


def _problem(data, n_positions: int) -> str | None:
    """What is wrong with one step record, or None."""
    if not isinstance(data, dict):
        return "its data must be an object"
    if "step" not in data:
        return "no 'step'"
    if not _index(data["step"], n_positions):
        return f"'step' must be a position index from 0 to {n_positions - 1}, got {data['step']!r}"[:200]
    if not isinstance(data.get("position_id"), int) or isinstance(data.get("position_id"), bool):
        return "no 'position_id'" if "position_id" not in data else "'position_id' must be an integer"
    windows = data.get("windows")
    if not isinstance(windows, list):
        return "no 'windows' list" if "windows" not in data else "'windows' must be a list"
    if not windows:  # a completed step averaged at least its static dwell
        return "'windows' is empty (a completed step has at least one averaged window)"
    for i, w in enumerate(windows):
        where = f"windows[{i}]"
        if not isinstance(w, dict):
            return f"{where} must be an object"
        for key in ("kind", "start", "duration", "rate_deg_s", "means"):
            if key not in w:
                return f"{where} has no {key!r}"
        if w["kind"] not in ("static", "plus", "minus"):
            return f"{where}.kind must be static, plus or minus, got {w['kind']!r}"[:200]
        for key in ("start", "duration", "rate_deg_s"):
            if not _number(w[key]) or key == "duration" and w[key] < 0:
                return f"{where}.{key} must be a finite number{' >= 0' if key == 'duration' else ''}, got {w[key]!r}"[:200]
        if "temperature_c" in w and not _number(w["temperature_c"]):
            return f"{where}.temperature_c must be a finite number (°C), got {w['temperature_c']!r}"[:200]
        means = w["means"]
        if not isinstance(means, dict) or not means:
            return f"{where}.means must be an object of triad means"
        for name, mean in means.items():
            if not (isinstance(mean, list) and len(mean) == 3 and all(_number(v) for v in mean)):
                return f"{where}.means.{name} must be 3 finite numbers, got {mean!r}"[:200]
    skipped = data.get("skipped", [])
    if not isinstance(skipped, list) or not all(_index(s, n_positions) for s in skipped):
        return f"'skipped' must be a list of position indices from 0 to {n_positions - 1}"
    bench = data.get("bench")
    if bench is not None and not isinstance(bench, dict):
        return "'bench' must be an object or null"
    return None


def _resume_problem(data, n_positions: int) -> str | None:
    for key in ("completed_steps", "skipped"):
        value = data.get(key)
        if not isinstance(value, list) or not all(_index(s, n_positions) for s in value):
            return f"{key!r} must be a list of position indices from 0 to {n_positions - 1}"
    return None


# --------------------------------------------------------------------------------------------
# The record


class RunRecord:
    """A session read once: its documents with their meaning. Build it with ``RunRecord.open``
    (or ``fieldcal.run.runner.open_run``, which rebuilds a procedure run's spec).

    ``spec``: the run's spec (None when not asked for, or an imported recording); ``steps``: the
    step documents the run still counts, in log order (a resume that did not keep a completed
    step drops its earlier documents); ``completed``: per step its last record, what a solve
    uses; ``skipped``: steps skipped and not completed since; ``parameter_files``: every
    parameter file the log notes, in order, with who wrote it; ``torn``: what a crash left
    beyond the consistent prefix; ``stopped``/``stop_reason``: how the last run ended.
    """

    def __init__(self, reader: SessionReader, spec: Any = None, n_positions: int | None = None) -> None:
        self.reader = reader
        self.directory = reader.directory
        self.spec = spec
        self.torn: list[str] = list(reader.torn)
        self.stopped, self.stop_reason = reader.stopped, reader.stop_reason
        self.steps: tuple[StepDocument, ...] = ()
        self.resumes: tuple[ResumePoint, ...] = ()
        self.skipped: tuple[int, ...] = ()
        if n_positions is not None:
            self._interpret(n_positions)
        self.parameter_files = self._parameter_files()

    @classmethod
    def open(cls, directory: str | os.PathLike, *, log_only: bool = False,
             spec_from: Callable[[dict], Any] | None = None) -> RunRecord:
        """Scan and check the session once. ``log_only``: the log alone, not requiring the data
        files (see ``SessionReader``). ``spec_from``: rebuilds the run's spec from the start
        metadata (its ``procedure`` gives the positions the step documents are checked against);
        a session that is not a procedure run is then one line naming what it is (or, where
        ``spec_from`` gives None for it, a record without spec and steps)."""
        reader = SessionReader(directory, log_only=log_only)
        refuse_a_later_writer(reader)
        spec = n_positions = None
        if spec_from is not None:
            log = reader.directory / LOG
            try:
                spec = spec_from(reader.start)
            except (KeyError, TypeError, AttributeError) as exc:
                raise SessionError(f"{log}: line 1: the start document's metadata is not a procedure run's "
                                   f"({type(exc).__name__}: {exc})"[:300], str(log), 1) from None
            except ValueError as exc:  # a recording session, a procedure or station out of bounds
                raise ValueError(f"{reader.directory}: {str(exc).splitlines()[0] if str(exc) else exc}") from None
            n_positions = len(spec.procedure.positions) if spec is not None else None
        return cls(reader, spec, n_positions)

    # --- what the documents mean ------------------------------------------------------------

    def _fail(self, line: int, what: str):
        path = self.directory / LOG
        raise SessionError(f"{path}: line {line}: {what}", str(path), line)

    def _interpret(self, n_positions: int) -> None:
        """Every step and resume document checked, and the resumes, skips and dropped steps
        applied in log order."""
        steps: list[StepDocument] = []
        resumes: list[ResumePoint] = []
        skipped: set[int] = set()  # the skips logged so far (old TUI steps did not say)
        names = None
        # A step recorded again must follow what redoes one: the operator's redo (or unskip), or
        # a resume; a step document repeated with none in between is a copied line, not a redo.
        recorded_at: dict[int, int] = {}  # step -> line of its last document
        redone_at = 0  # line of the last redo, unskip or resume
        for doc in self.reader.documents("step", "checkpoint", "event", "resume", "action"):
            data, line, kind = doc["data"], doc["seq"] + 1, doc["type"]
            if kind == "action":
                if isinstance(data, dict) and data.get("action") in (ev.REDO, ev.UNSKIP):
                    redone_at = line
                continue
            if kind == "event":
                if data.get("event") == "step_skipped" and _index(data.get("step"), n_positions):
                    skipped.add(data["step"])
            elif kind == "resume":
                redone_at = line
                if data:  # a resume document of a run that was no procedure run has no data
                    why = _resume_problem(data, n_positions)
                    if why is not None:
                        self._fail(line, f"resume document: {why}")
                    point = ResumePoint.from_dict(data)
                    resumes.append(point)
                    skipped = set(point.skipped)
                    steps = [s for s in steps if s.record.step in point.completed_steps]
            elif kind == "step":
                why = _problem(data, n_positions)
                if why is None:
                    for i, w in enumerate(data["windows"]):
                        names = set(w["means"]) if names is None else names
                        if set(w["means"]) != names:
                            why = f"windows[{i}].means has triads {sorted(w['means'])}, earlier steps {sorted(names)}"
                            break
                if why is None and data["step"] in recorded_at and recorded_at[data["step"]] > redone_at:
                    why = (f"step {data['step']} again (recorded at line {recorded_at[data['step']]}) with no "
                           "redo, unskip or resume before it: a repeated document, not a redo")
                if why is not None:
                    self._fail(line, f"step document: {why}")
                recorded_at[data["step"]] = line
                steps.append(StepDocument(StepRecord.from_dict(data),
                                          tuple(data["skipped"]) if "skipped" in data else tuple(sorted(skipped)),
                                          data.get("bench"), line))
            elif steps and steps[-1].bench is None:  # an old TUI checkpoint (fieldcal.session.legacy)
                bench = old_tui_bench(doc, steps[-1].record.step)
                if bench is not None:
                    steps[-1] = StepDocument(steps[-1].record, steps[-1].skipped, bench, steps[-1].line)
        self.steps, self.resumes = tuple(steps), tuple(resumes)
        self._refuse_overlapping_windows()
        # the skips since the last resume, less the steps completed since
        self.skipped = tuple(sorted(skipped - {s.record.step for s in steps}))

    def _refuse_overlapping_windows(self) -> None:
        """The windows a solve averages never share sample time (the solver's covariance of their
        means needs it, and said only "windows overlap"): one that does is refused naming the
        step documents of both."""
        found = [(w.start, w.start + w.duration, doc.line)
                 for doc in self.completed_documents for w in doc.record.windows]
        if len(found) < 2:
            return
        spans = np.array([(start, end) for start, end, _ in found])
        order = np.argsort(spans[:, 0], kind="stable")
        ends_before = np.maximum.accumulate(spans[order, 1])[:-1]
        clash = np.flatnonzero(spans[order[1:], 0] < ends_before - 1e-9)  # the noise model's tolerance
        if clash.size:
            later = int(order[clash[0] + 1])
            earlier = int(order[:clash[0] + 1][np.argmax(spans[order[:clash[0] + 1], 1])])
            self._fail(found[later][2], f"step document: a window from t {found[later][0]!r} s overlaps one "
                       f"to t {found[earlier][1]!r} s (step document at line {found[earlier][2]}): windows "
                       "of the completed steps never share sample time (changed or forged windows)")

    @property
    def completed(self) -> list[StepRecord]:
        """The completed steps a solve uses: per step, its last record (a resumed run may redo one)."""
        return list({s.record.step: s.record for s in self.steps}.values())

    @property
    def completed_documents(self) -> list[StepDocument]:
        """Per completed step, the step document of its last record."""
        return list({s.record.step: s for s in self.steps}.values())

    def _parameter_files(self) -> tuple[ParameterFileNote, ...]:
        notes, in_run = [], False
        for doc in self.reader.documents("start", "resume", "stop", "parameters"):
            kind = doc["type"]
            if kind in ("start", "resume"):
                in_run = True
            elif kind == "stop":
                in_run = False
            else:
                notes.append(ParameterFileNote(doc["file"], doc["sha256"], doc["seq"] + 1,
                                               "run" if in_run else "re-solve", self.directory / doc["file"]))
        return tuple(notes)

    @property
    def current_parameters(self) -> ParameterFileNote | None:
        """The parameter file the log noted last (the session's current calibration)."""
        return self.parameter_files[-1] if self.parameter_files else None

    @property
    def run_parameters(self) -> ParameterFileNote | None:
        """The parameter file the run itself wrote when it concluded (the last one, after a resume)."""
        written = [n for n in self.parameter_files if n.written_by == "run"]
        return written[-1] if written else None

    def resolved_after(self, note: ParameterFileNote) -> list[ParameterFileNote]:
        """The parameter files re-solves wrote after ``note``."""
        return [n for n in self.parameter_files if n.line > note.line and n.written_by == "re-solve"]

    @property
    def solved_at(self) -> float | None:
        """The sample time the run concluded at (its last sample, where its bias at the end of
        calibration was predicted), as its last ``solved`` event holds it; None: never solved."""
        at = None
        for doc in self.reader.documents("event"):
            event = doc.get("data") or {}
            if event.get("event") == "solved" and _number(event.get("t")):
                at = float(event["t"])
        return at

    @property
    def parameters_path(self) -> Path | None:
        """The current parameter file, if it is there."""
        note = self.current_parameters
        return note.path if note is not None and note.exists else None

    # --- the session's contents (one scan: the reader's) -------------------------------------

    @property
    def start(self) -> dict:
        """The runner's start metadata."""
        return self.reader.start

    @property
    def start_document(self) -> dict:
        return self.reader.start_document

    def documents(self, *types: str) -> Iterator[dict]:
        return self.reader.documents(*types)

    def chunks(self):
        return self.reader.chunks()

    def replay_items(self, types: Iterable[str] = ("chunk", "action")):
        return self.reader.replay_items(types)

    @property
    def raw_names(self) -> list[str]:
        return self.reader.raw_names

    def raw(self, name: str):
        return self.reader.raw(name)

    @property
    def n_samples(self) -> int:
        return self.reader.n_samples
