"""What a certificate shows beyond the parameter file, read from the session: each position's
residual (by re-solving the capture, as ``fieldcal replay`` does), the temperature the device
reported, the positions skipped, and the Allan plots ``fieldcal allan SESSION`` left there."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np


@dataclass(frozen=True)
class PositionResiduals:
    """One triad's residual per position, in the operator's ``unit``: signed where a position
    gives one equation, else the RMS of its equations (``signed`` False)."""

    triad: str
    unit: str
    labels: tuple[str, ...]
    values: np.ndarray
    signed: bool


@dataclass(frozen=True)
class Temperature:
    """What the device reported over the session, °C."""

    low: float
    high: float
    mean: float
    samples: int


@dataclass(frozen=True)
class Evidence:
    residuals: dict[str, PositionResiduals] = field(default_factory=dict)
    residual_note: str = ""  # how the residuals were obtained, or why there are none
    temperature: Temperature | None = None
    skipped: tuple[int, ...] = ()  # position ids
    completed: int | None = None  # steps done; None: not a procedure run
    allan: tuple[Path, ...] = ()  # PNGs, one per triad


class _TemperatureRange:
    """Range and running sum of the temperature column, chunk by chunk in the session's order."""

    def __init__(self) -> None:
        self.low, self.high, self.total, self.n = np.inf, -np.inf, 0.0, 0
        self.complete = False  # every chunk of the session added

    def add(self, chunk) -> None:
        t = chunk.temperature
        if t is None or not t.size:
            return
        t = t[np.isfinite(t)]
        if t.size:
            self.low, self.high = min(self.low, float(t.min())), max(self.high, float(t.max()))
            self.total, self.n = self.total + float(t.sum()), self.n + t.size

    def result(self) -> Temperature | None:
        return Temperature(self.low, self.high, self.total / self.n, self.n) if self.n else None


def session_temperature(reader) -> Temperature | None:
    """Range and mean of the temperature column, None when the device reports none."""
    found = _TemperatureRange()
    for chunk in reader.chunks():
        found.add(chunk)
    return found.result()


def _noting_temperature(items, found: _TemperatureRange):
    """The replay's items unchanged, each chunk's temperature noted on the way past."""
    for kind, item in items:
        if kind == "chunk":
            found.add(item)
        yield kind, item
    found.complete = True


def replayed_residuals(record, temperature: _TemperatureRange | None = None
                       ) -> tuple[dict[str, PositionResiduals], str]:
    """Each solved triad's residual per position from replaying the session (``record``: its
    ``RunRecord``); and a note that says whether the replay reproduces the run's parameter file.
    A session the replay refuses (its step averages not its samples', damaged data) is refused
    here too: a SessionError, never a certificate with a note. ``temperature``: given, it notes
    every chunk the replay reads and, after a replay that stopped before the end of the capture,
    the chunks left (the session's samples are read once, not again for the temperature); it is
    complete unless the replay failed."""
    from fieldcal.residuals import per_position
    from fieldcal.run.operators import ReplayOperator
    from fieldcal.run.replay import replay
    from fieldcal.session import SessionError

    operator = ReplayOperator(record)
    if temperature is not None:
        operator.items = _noting_temperature(operator.items, temperature)
    try:
        outcome = replay(record, operator)
    except SessionError:
        raise
    except (ValueError, OSError) as exc:
        why = str(exc).splitlines()[0]
        return {}, f"residuals per position not available: re-solving the session failed ({why})"
    if temperature is not None:
        for _ in operator.items:  # the rest of the capture, if the replay stopped before its end
            pass
    if outcome.unit is None or not outcome.unit.solutions:
        return {}, "residuals per position not available: re-solving the session solved no triad"
    found = {}
    for name, sol in outcome.unit.solutions.items():
        rows, unit = per_position(sol)
        found[name] = PositionResiduals(name, unit, tuple(r[0] for r in rows),
                                        np.array([r[1] for r in rows]), all(r[2] for r in rows))
    run, current = record.run_parameters, record.current_parameters
    if outcome.identical is True and run is current:
        note = "residuals from re-solving the session, which reproduces this parameter file"
    elif outcome.identical is True:
        note = (f"residuals from replaying the run, which reproduces the run's {run.file}; this parameter "
                f"file ({current.file}) was re-solved later from the same step averages")
    else:
        note = ("residuals from re-solving the session; NOTE: " + (outcome.comparison or
                "the re-solve could not be compared with the parameter file"))
    return found, note


def gather(record) -> Evidence:
    """Everything the certificate takes from the session (``record``: its ``RunRecord``, the
    spec rebuilt for a procedure run). An imported recording (no procedure) has no positions to
    re-solve: its certificate says so."""
    allan = tuple(sorted(Path(record.directory).glob("allan-*.png")))
    if record.spec is None:
        return Evidence({}, "an imported recording: no procedure positions to re-solve (`fieldcal calibrate "
                        "SESSION` shows each pose's residual)", session_temperature(record), allan=allan)
    positions = record.spec.procedure.positions
    # The steps the parameter file was solved from: not those a resume dropped (measured again)
    done = {s.record.step for s in record.steps}
    temperature = _TemperatureRange()
    found, note = replayed_residuals(record, temperature)
    # A failed replay read only part of the capture: the temperature then reads it whole.
    return Evidence(found, note, temperature.result() if temperature.complete else session_temperature(record),
                    tuple(positions[i].id for i in record.skipped),
                    len(done), allan)
