"""Replay and re-solve a captured session.

Replay feeds the captured chunks and operator actions, in the order they happened, through a
conductor with a fresh engine; where a run was resumed after a crash, the engine restarts from
the steps that run kept, as the resumed run did. It vouches for the session only after checking
what it vouches for: the step averages the log holds (what ``solve`` and ``resolve`` use) must be
the averages of the samples (bit for bit in the numeric environment the session was recorded
in, within ``AVERAGES_RTOL`` elsewhere), and the parameter file comes out as the one the *run*
wrote (byte for byte in the same environment), whatever re-solves wrote after it.
"""
from __future__ import annotations

import math

import numpy as np

from fieldcal.run.conductor import Conductor, Operator, Reporter
from fieldcal.run.environment import compare_parameters, numeric_environment
from fieldcal.run.operators import NoBench, ReplayOperator
from fieldcal.run.outcome import Outcome, Status
from fieldcal.session import LOG, SessionError
from fieldcal.session.record import RunRecord

# Re-averaging the same samples elsewhere (another numpy's summation order) moves a mean by a few
# units in the last place; a changed average moves it by far more than this (0.01 mg is 1e-5 of g).
AVERAGES_RTOL = 1e-9


def replay_conductor(record: RunRecord, operator: ReplayOperator | None = None,
                     subscribers=()) -> Conductor:
    """A conductor that replays the session (``operator``: a paced one, else as fast as possible)."""
    operator = operator if operator is not None else ReplayOperator(record)
    return Conductor(record.spec, NoBench(), operator, subscribers)


def check_averages(record: RunRecord, conductor: Conductor) -> None:
    """A SessionError naming the log line of the first step whose logged averages are not the
    replayed samples' averages (the replay's engine ``conductor.engine``)."""
    exact = record.start.get("numeric_environment") == numeric_environment()
    replayed = conductor.engine.records
    for doc in record.completed_documents:
        logged = doc.record
        where = f"{record.directory / LOG}: line {doc.line}: step {logged.step + 1}"
        again = replayed.get(logged.step)
        if again is None:
            raise SessionError(f"{where}: the log holds its averages, but its samples do not complete it on "
                               "replay; the step documents are not the samples'", str(record.directory / LOG), doc.line)
        if [(w.kind, tuple(sorted(w.means))) for w in again.windows] != \
                [(w.kind, tuple(sorted(w.means))) for w in logged.windows]:
            raise SessionError(f"{where}: its windows differ from those the samples give on replay",
                               str(record.directory / LOG), doc.line)
        if again.position_id != logged.position_id:
            raise SessionError(f"{where}: its position id {logged.position_id} is not the one the samples give on "
                               f"replay ({again.position_id}); the step documents are not the samples'",
                               str(record.directory / LOG), doc.line)
        for i, (a, b) in enumerate(zip(logged.windows, again.windows)):
            # what the solvers read besides the means: where the window lies, its table rate and
            # temperature (a forged rate or edge moved the gyro's σ 140-fold while replay vouched)
            for field in ("start", "duration", "rate_deg_s", "temperature_c"):
                x, y = getattr(a, field), getattr(b, field)
                same = x == y if (exact or x is None or y is None) else \
                    math.isclose(x, y, rel_tol=AVERAGES_RTOL, abs_tol=1e-12)
                if not same:
                    raise SessionError(
                        f"{where}: window {i + 1} ({a.kind}): the logged {field} {x} and the samples' {y} differ; "
                        "the step document was changed after it was written: refused (restore the session "
                        "from a copy)", str(record.directory / LOG), doc.line)
            for name in a.means:
                x, y = np.asarray(a.means[name], float), np.asarray(b.means[name], float)
                same = np.array_equal(x, y) if exact else np.allclose(x, y, rtol=AVERAGES_RTOL, atol=0.0)
                if not same:
                    how = "bit for bit (same numeric environment)" if exact else f"within {AVERAGES_RTOL:g} relative"
                    raise SessionError(
                        f"{where}: window {i + 1} ({a.kind}): the logged {name} mean {a.means[name]} and the "
                        f"samples' {list(b.means[name])} differ (compared {how}); the step averages were changed "
                        "after they were written: refused (restore the session from a copy)",
                        str(record.directory / LOG), doc.line)


def finish_replay(conductor: Conductor, record: RunRecord, outcome: Outcome) -> Outcome:
    """What a replay's outcome says beyond a run's: the capture it replayed, whether the capture
    ended before the procedure did, and how the parameter file compares with the run's.
    A SessionError if the logged step averages are not the samples'."""
    check_averages(record, conductor)
    outcome.samples = conductor.samples
    note = record.run_parameters
    outcome.replay_of, outcome.session = record.directory, None
    outcome.parameters = note.path if note is not None else None
    if outcome.status == Status.STOPPED:
        engine = conductor.engine
        outcome.status = Status.INCOMPLETE
        outcome.message = f"the capture ends during step {engine.step + 1} of {len(engine.procedure.positions)}"
    elif outcome.status == Status.ABORTED:
        outcome.message = "the recorded run was aborted"
    if outcome.parameter_file is not None and note is not None:
        found = compare_parameters(outcome.parameter_file, note.read_bytes(check=False),
                                   record.start.get("numeric_environment"))
        outcome.identical = found.identical
        outcome.comparison = found.text.replace("the recorded one", f"the run's {note.file}", 1)
    return outcome


def later_resolves(record: RunRecord) -> list[str]:
    """One line per parameter file a re-solve wrote after the run's: its file and method."""
    note = record.run_parameters
    if note is None:
        return []
    lines = []
    for later in record.resolved_after(note):
        try:
            method = later.method()
        except ValueError as exc:  # changed or unreadable: said, the replay's verdict stands
            method = f"unreadable: {str(exc).splitlines()[0]}"
        current = " (the session's current calibration)" if later is record.current_parameters else ""
        lines.append(f"re-solved later: {later.file} ({method}){current}")
    return lines


def replay(record: RunRecord, operator: ReplayOperator | None = None, report=lambda e: None) -> Outcome:
    """Replay to the end of the capture (``fieldcal replay``, the certificate); a capture that
    ends early or was aborted is solved from the steps it completed. ``operator``: a paced one
    (``ReplayOperator(record, speed)``), else as fast as possible; ``report``: each event."""
    conductor = replay_conductor(record, operator, [Reporter(report)])
    outcome = finish_replay(conductor, record, conductor.run())
    if outcome.unit is None:
        outcome.unit, outcome.parameter_file = conductor.solve()
    return outcome


def recorded_parameters(record: RunRecord) -> bytes | None:
    """The bytes of the parameter file the run wrote (None: it wrote none)."""
    note = record.run_parameters
    return note.read_bytes() if note is not None else None


def resolve_session(record: RunRecord, method: str | None = None, thermal: str | None = None):
    """Solve again from the step averages the session stored (no samples read); (solution, file).
    ``method``, ``thermal``: another solver, or thermal setting, than the session's."""
    from dataclasses import replace

    spec = record.spec
    spec = spec if method is None else replace(spec, method=method)
    spec = spec if thermal is None else replace(spec, thermal=thermal)
    conductor = Conductor(spec, NoBench(), Operator())
    conductor.engine.restore(record.completed)
    # the bias at the end at the run's own last sample (the restored engine knows only its windows)
    return conductor.solve(record.solved_at)
