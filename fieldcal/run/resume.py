"""One resume assembly for every front end: headless (``fieldcal resume``), the terminal UI's
simulator and its live device. What differs between them is the bench, the operator and, for a
live device, one judgement -- whether it was power-cycled since its last completed step (then
those steps are measured again) -- which the live front end passes in; the rest is here once.
"""
from __future__ import annotations

from collections.abc import Callable, Iterable

from fieldcal.run.conductor import Conductor, Operator
from fieldcal.run.recorder import SessionRecorder
from fieldcal.session.record import RunRecord


def refuse_ended(record: RunRecord) -> None:
    """A one-line ValueError for a session whose run ended (a completed one is never resumed)."""
    if record.stopped:
        raise ValueError(f"{record.directory}: this session already ended ({record.stop_reason}); "
                         "nothing to resume")


def resume_conductor(record: RunRecord, bench, operator: Operator, subscribers: Iterable = (), *,
                     settings=None, measured_again: str = "",
                     attach: Callable[[SessionRecorder], None] | None = None) -> Conductor:
    """The conductor continuing ``record``'s run after its last completed step: engine and bench
    restored before the session is touched (what cannot be continued is refused first), then the
    session reopened for appending, its recorder the first subscriber (it has each chunk before
    anyone reacts).

    ``measured_again``: why the completed steps are not kept (a live device power-cycled since),
    "" to keep them. ``attach``: called with the recorder before it subscribes (a live source
    first writes the bytes it read while the session could not be written yet).
    """
    refuse_ended(record)
    steps = list(record.steps)
    kept = [] if measured_again else steps
    conductor = Conductor(record.spec, bench, operator, subscribers, session=record.directory, settings=settings)
    conductor.restore(kept, skipped=steps[-1].skipped if steps else (), why=measured_again,
                      dropped=sorted({s.record.step for s in steps} - {s.record.step for s in kept}))
    recorder = SessionRecorder.append_to(record.directory)
    if attach is not None:
        attach(recorder)
    conductor.subscribers.insert(0, recorder)
    return conductor
