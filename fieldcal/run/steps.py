"""What a session keeps to continue a run: per completed step, the step's record with the steps
skipped so far and the bench's state (one ``step`` document), and where a run was resumed.

``steps_on_record`` reads the steps back, also from sessions written before the documents were
unified (the terminal UI then wrote ``step`` without ``skipped``/``bench`` and a separate
``checkpoint`` document).
"""
from __future__ import annotations

from dataclasses import dataclass

from fieldcal.procedure.windows import StepRecord
from fieldcal.session.capture import SessionReader


@dataclass(frozen=True)
class StepDocument:
    """A session's ``step`` document: a completed step and what resuming after it needs."""

    record: StepRecord
    skipped: tuple[int, ...]  # steps skipped so far
    bench: dict | None  # the bench's state right after the step (None: not recorded)

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
        doc: dict[str, object] = {"completed_steps": list(self.completed_steps), "skipped": list(self.skipped)}
        if self.why:
            doc["why"] = self.why
        if self.dropped:
            doc["dropped"] = list(self.dropped)
        return doc

    @classmethod
    def from_dict(cls, doc: dict) -> ResumePoint:
        return cls(tuple(int(s) for s in doc["completed_steps"]), tuple(int(s) for s in doc["skipped"]),
                   str(doc.get("why", "")), tuple(int(s) for s in doc.get("dropped", ())))


def steps_on_record(reader: SessionReader) -> list[StepDocument]:
    """Every ``step`` document in log order that the run still counts, in today's shape whatever
    shape it was written in: a resume that did not keep a completed step (a live device
    power-cycled: its steps measured again) drops that step's earlier documents."""
    steps: list[StepDocument] = []
    skipped: set[int] = set()  # for old TUI steps, which did not say: the skips logged so far
    for doc in reader.documents("step", "checkpoint", "event", "resume"):
        data = doc["data"]
        if doc["type"] == "event" and data.get("event") == "step_skipped":
            skipped.add(int(data["step"]))
        elif doc["type"] == "resume":
            point = ResumePoint.from_dict(data)
            skipped = set(point.skipped)
            steps = [s for s in steps if s.record.step in point.completed_steps]
        elif doc["type"] == "step":
            steps.append(StepDocument(StepRecord.from_dict(data),
                                      tuple(data["skipped"]) if "skipped" in data else tuple(sorted(skipped)),
                                      data.get("bench")))
        elif steps and steps[-1].bench is None and data.get("step") == steps[-1].record.step:
            steps[-1] = StepDocument(steps[-1].record, steps[-1].skipped, data["bench"])  # old checkpoint
    return steps


def skipped_on_record(reader: SessionReader) -> list[int]:
    """The steps the run skipped and did not complete since: the last resume's skips and those
    logged after it (a resume that started over says which skips it kept)."""
    skipped: set[int] = set()
    for doc in reader.documents("event", "resume"):
        data = doc["data"]
        if doc["type"] == "resume":
            skipped = set(ResumePoint.from_dict(data).skipped)
        elif data.get("event") == "step_skipped":
            skipped.add(int(data["step"]))
    return sorted(skipped - {s.record.step for s in steps_on_record(reader)})


def completed_records(reader: SessionReader) -> list[StepRecord]:
    """The completed steps a solve uses: per step, its last record (a resumed run may redo one)."""
    return list({s.record.step: s.record for s in steps_on_record(reader)}.values())
