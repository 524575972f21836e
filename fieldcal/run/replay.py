"""Replay and re-solve a captured session.

Replay feeds the captured chunks and operator actions, in the order they happened, through a
conductor with a fresh engine; where a run was resumed after a crash, the engine restarts from
the steps that run kept, as the resumed run did. In the numeric environment the session was
recorded in, the parameter file comes out byte for byte the same as the one the run wrote.
"""
from __future__ import annotations

from pathlib import Path

from fieldcal.run.conductor import Conductor, Operator, Reporter
from fieldcal.run.environment import compare_parameters
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


def finish_replay(conductor: Conductor, directory: str | Path, outcome: Outcome) -> Outcome:
    """What a replay's outcome says beyond a run's: the capture it replayed, whether the capture
    ended before the procedure did, and how the parameter file compares with the recorded one."""
    reader = SessionReader(directory)
    outcome.replay_of, outcome.session, outcome.parameters = Path(directory), None, reader.parameters_path
    if outcome.status == Status.STOPPED:
        engine = conductor.engine
        outcome.status = Status.INCOMPLETE
        outcome.message = f"the capture ends during step {engine.step + 1} of {len(engine.procedure.positions)}"
    elif outcome.status == Status.ABORTED:
        outcome.message = "the recorded run was aborted"
    recorded = recorded_parameters(directory)
    if outcome.parameter_file is not None and recorded is not None:
        found = compare_parameters(outcome.parameter_file, recorded, reader.start.get("numeric_environment"))
        outcome.identical, outcome.comparison = found.identical, found.text
    return outcome


def replay(directory: str | Path, operator: ReplayOperator | None = None, subscribers=()) -> tuple[Outcome, Conductor]:
    """Replay to the end of the capture."""
    conductor = replay_conductor(directory, operator, subscribers)
    return finish_replay(conductor, directory, conductor.run()), conductor


def replay_session_outcome(directory: str | Path, operator: ReplayOperator | None = None,
                           report=lambda e: None) -> tuple[Outcome, int]:
    """Replay (``fieldcal replay``); a capture that ends early or was aborted is solved from the
    steps it completed. The outcome and the number of samples replayed."""
    outcome, conductor = replay(directory, operator, [Reporter(report)])
    if outcome.unit is None:
        outcome.unit, outcome.parameter_file = conductor.solve()
    return outcome, conductor.samples


def replay_session(directory: str | Path, speed: float | None = None, report=lambda e: None):
    """Re-run the engine on the capture; (solution, parameter file, samples replayed).

    ``speed``: None for as fast as possible, else that many times real (sample) time.
    """
    outcome, samples = replay_session_outcome(directory, ReplayOperator(Path(directory), speed), report)
    return outcome.unit, outcome.parameter_file, samples


def recorded_parameters(directory: str | Path) -> bytes | None:
    path = SessionReader(directory).parameters_path
    return Path(path).read_bytes() if path else None


def replay_matches(directory: str | Path) -> bool:
    """Does replaying the session give its parameter file (byte for byte in the same numeric
    environment, within the stated tolerance elsewhere)?"""
    return replay(directory)[0].identical is True


def resolve_session(directory: str | Path, method: str | None = None):
    """Solve again from the step averages the session stored (no samples read); (solution, file).
    ``method``: another solver than the session's."""
    from dataclasses import replace

    from fieldcal.run.steps import completed_records

    reader = SessionReader(directory)
    spec = RunSpec.from_metadata(reader.start)
    conductor = Conductor(spec if method is None else replace(spec, method=method), NoBench(), Operator())  # (no loop is run)
    conductor.engine.restore(completed_records(reader))
    return conductor.solve()
