"""The session recorder: the only code that writes a run's session documents.

It subscribes to a conductor: chunks, events, actions, one ``step`` document per completed step
(the step's record, the steps skipped so far and the bench's state: everything resuming after it
needs, in one document so a crash cannot separate them), ``resume`` where a run continues, the
parameter file and ``stop``. The documents are ``fieldcal.session.record``'s, and its
``RunRecord`` reads them back (older shapes through ``fieldcal.session.legacy``).
"""
from __future__ import annotations

from pathlib import Path

from fieldcal.procedure import events as ev
from fieldcal.run.conductor import Subscriber
from fieldcal.session.record import ResumePoint, StepDocument
from fieldcal.session.capture import PARAMETERS, SessionWriter


class SessionRecorder(Subscriber):
    """A conductor subscriber writing the session as the run goes."""

    def __init__(self, writer: SessionWriter):
        self.writer = writer

    @classmethod
    def create(cls, directory: Path, metadata: dict) -> SessionRecorder:
        return cls(SessionWriter.create(directory, metadata))

    @classmethod
    def append_to(cls, directory: Path) -> SessionRecorder:
        return cls(SessionWriter.append_to(directory))

    @property
    def directory(self) -> Path:
        return Path(self.writer.directory)

    def raw(self, t: float, data: bytes) -> None:
        """A bench's raw-byte tap (called on a port's reader thread; the writer is thread-safe)."""
        if not self.writer.closed:
            self.writer.write_raw("imu", t, data)

    # --- the subscriber ---------------------------------------------------------------------

    def chunk(self, chunk, run) -> None:
        self.writer.chunk(chunk)

    def action(self, action: ev.Action, run) -> None:
        self.writer.action(action.to_dict())

    def event(self, e: ev.Event, run) -> None:
        self.writer.event(e.to_dict())
        if isinstance(e, ev.StepComplete):
            engine = run.engine
            self.writer.step(StepDocument(engine.records[e.step], tuple(sorted(engine.skipped)),
                                          run.bench.get_state()).to_dict())

    def resumed(self, point: ResumePoint, run) -> None:
        """A resumed run, or (the writer active) a run starting over mid-way from ``point``."""
        self.writer.resume(point.to_dict(), mid_run=self.writer.active)

    def parameters(self, pf, run) -> Path:
        self.writer.write_parameters(pf)
        return self.directory / PARAMETERS

    def end(self, status: str, run) -> None:
        """``completed``/``aborted`` stop the run; anything else leaves it open to resume."""
        if self.writer.closed:
            return
        if status in ("completed", "aborted"):
            self.writer.stop(status)
        self.writer.close()
