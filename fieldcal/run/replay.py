"""Replay and re-solve a captured session.

Replay feeds the captured chunks and operator actions, in the order they happened, through a
fresh engine and solver; where a run was resumed after a crash, the engine is restarted from the
steps completed so far, as the resumed run was. The parameter file comes out byte for byte the
same as the one the run wrote.
"""
from __future__ import annotations

import time
from pathlib import Path

from fieldcal.procedure import events as ev
from fieldcal.procedure.engine import Engine
from fieldcal.paramfile import ParameterFile, dump
from fieldcal.run.runner import RunSpec, _solve
from fieldcal.session.capture import SessionReader
from fieldcal.solvers.solve import UnitSolution


def replay_session(directory: str | Path, speed: float | None = None,
                   report=lambda e: None) -> tuple[UnitSolution, ParameterFile | None, int]:
    """Re-run the engine on the capture; (solution, parameter file, samples replayed).

    ``speed``: None for as fast as possible, else that many times real (sample) time.
    """
    reader = SessionReader(directory)
    spec = RunSpec.from_metadata(reader.start)
    settings = spec.engine_settings()
    engine = Engine(spec.procedure, settings)
    for e in engine.start():
        report(e)
    started, samples = time.monotonic(), 0
    first_t = None
    for kind, item in reader.replay_items(("chunk", "action", "resume")):
        if kind == "chunk":
            if speed:
                first_t = item.t[0] if first_t is None else first_t
                lag = started + (item.t[-1] - first_t) / speed - time.monotonic()
                if lag > 0:
                    time.sleep(lag)
            samples += len(item)
            out = engine.feed(item)
        elif kind == "action":
            out = engine.act(ev.action_from_dict(item))
        else:  # a resumed run restarted its engine from the steps it had on record
            keep = set(item["completed_steps"])
            records = [r for step, r in engine.records.items() if step in keep]
            engine = Engine(spec.procedure, settings)
            engine.restore(records, item["skipped"])
            out = engine.start()
            started, first_t = time.monotonic(), None  # sample time starts over from the checkpoint
        for e in out:
            report(e)
    unit, pf = _solve(spec, engine)
    return unit, pf, samples


def recorded_parameters(directory: str | Path) -> bytes | None:
    path = SessionReader(directory).parameters_path
    return Path(path).read_bytes() if path else None


def replay_matches(directory: str | Path) -> bool:
    """Does replaying the session give its parameter file byte for byte?"""
    _, pf, _ = replay_session(directory)
    recorded = recorded_parameters(directory)
    return pf is not None and recorded is not None and dump(pf).encode() == recorded
