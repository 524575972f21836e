"""Replay and re-solve a captured session.

Replay feeds the captured chunks and operator actions, in the order they happened, through a
conductor with a fresh engine; where a run was resumed after a crash, the engine restarts from
the steps that run kept, as the resumed run did. In the numeric environment the session was
recorded in, the parameter file comes out byte for byte the same as the one the run wrote.
"""
from __future__ import annotations

from pathlib import Path

from fieldcal.run.conductor import Conductor, Reporter
from fieldcal.run.operators import NoBench, ReplayOperator
from fieldcal.run.outcome import Outcome, Status
from fieldcal.run.runner import RunSpec
from fieldcal.session.capture import SessionReader


def replay_conductor(directory: str | Path, operator: ReplayOperator | None = None,
                     subscribers=()) -> Conductor:
    """A conductor that replays the session (``operator``: a paced one, else as fast as possible)."""
    operator = operator if operator is not None else ReplayOperator(Path(directory))
    spec = RunSpec.from_metadata(operator.reader.start)
    return Conductor(spec, NoBench(), operator, subscribers)


def replay(directory: str | Path, operator: ReplayOperator | None = None, subscribers=()) -> tuple[Outcome, Conductor]:
    """Replay to the end of the capture. A capture that ends before the procedure does is
    solved from the steps it completed (the outcome says ``incomplete``)."""
    conductor = replay_conductor(directory, operator, subscribers)
    outcome = conductor.run()
    outcome.replay_of = Path(directory)
    if outcome.status == Status.STOPPED:
        engine = conductor.engine
        outcome.status = Status.INCOMPLETE
        outcome.message = f"the capture ends during step {engine.step + 1} of {len(engine.procedure.positions)}"
        if engine.records:
            outcome.unit, outcome.parameter_file = conductor.solve()
    elif outcome.status == Status.ABORTED:
        outcome.message = "the recorded run was aborted"
    return outcome, conductor


def replay_session(directory: str | Path, speed: float | None = None, report=lambda e: None):
    """Re-run the engine on the capture; (solution, parameter file, samples replayed).

    ``speed``: None for as fast as possible, else that many times real (sample) time.
    """
    outcome, conductor = replay(directory, ReplayOperator(Path(directory), speed), [Reporter(report)])
    if outcome.unit is None:  # aborted, or nothing completed: solve what there is
        outcome.unit, outcome.parameter_file = conductor.solve()
    return outcome.unit, outcome.parameter_file, conductor.samples


def recorded_parameters(directory: str | Path) -> bytes | None:
    path = SessionReader(directory).parameters_path
    return Path(path).read_bytes() if path else None


def replay_matches(directory: str | Path) -> bool:
    """Does replaying the session give its parameter file byte for byte?"""
    from fieldcal.paramfile import dump

    _, pf, _ = replay_session(directory)
    recorded = recorded_parameters(directory)
    return pf is not None and recorded is not None and dump(pf).encode() == recorded


def resolve_session(directory: str | Path):
    """Solve again from the step averages the session stored (no samples read); (solution, file)."""
    from fieldcal.run.steps import completed_records

    reader = SessionReader(directory)
    conductor = Conductor(RunSpec.from_metadata(reader.start), NoBench(), None)
    conductor.engine.restore(completed_records(reader))
    return conductor.solve()
