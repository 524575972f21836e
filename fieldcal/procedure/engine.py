"""The procedure engine: a pure state machine, fed sample chunks and operator actions.

``feed(chunk)`` and ``act(action)`` return events; nothing here reads a clock or touches a file.
Time is sample time: a 200 s dwell is 200 s of samples, counted at the nominal rate.

Per position: the operator places the unit and says ready; the engine waits until the unit is
still, checks that gravity points where the position expects, then averages a dwell while the
unit stays still (a bump restarts the dwell, or drops the disturbed stretch). With a rate step it
then commands the table to +ω, waits until the rate is steady, averages whole turns, does the
same at −ω, and stops the table. The stillness detector is reset when the operator says ready,
so a run resumed after a crash behaves exactly like an uninterrupted one from that step on.

A procedure with ``any_order`` needs no "ready": from the first chunk after a step ends the engine
watches by itself, waits until the unit has left the position just measured and is still again,
recognises which remaining position gravity says it is in, and dwells there (``PositionRecognised``).
Positions gravity cannot tell apart (the same up direction: a heading, a rate step's presence) are
taken in procedure order and named in the event; the operator may choose another (``CHOOSE``)
while the dwell runs. Each step keeps its own index, so the records are as in procedure order.
"""
from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from enum import StrEnum
from typing import cast

import numpy as np

from fieldcal.procedure import events as ev
from fieldcal.procedure.positions import Procedure, RateStep, position_words
from fieldcal.procedure.stillness import (StillnessDetector, StillnessSettings, angle_between, check_orientation,
                                          closest_positions, describe_up, gravity_direction)
from fieldcal.procedure.windows import MINUS, PLUS, STATIC, StepRecord, Window, WindowKind, WindowRecord

MIN_WINDOW_SAMPLES = 10  # fewer, and the window's spread says little about stillness
SAME_UP_DEG = 1.0  # positions whose up directions are this close are the same to gravity



class Phase(StrEnum):
    PLACE = "place"  # waiting for the operator to place the unit and say ready
    SETTLING = "settling"
    CHECKING = "checking"
    WRONG = "wrong"  # still, in the wrong orientation: waiting for the operator to move it
    DWELL = "dwell"
    RATE_WAIT = "rate_wait"
    RATE_AVERAGE = "rate_average"
    DONE = "done"
    ABORTED = "aborted"


PLACE, SETTLING, CHECKING, WRONG, DWELL, RATE_WAIT, RATE_AVERAGE, DONE, ABORTED = Phase
WAITING_FOR_OPERATOR = (PLACE, WRONG)


@dataclass(frozen=True)
class EngineSettings:
    rate_hz: float  # nominal sample rate: sample counts are sample time
    stillness: StillnessSettings
    specific_force: str = "accelerometer"  # triad for stillness and orientation
    angular_rate: str = "gyroscope"  # triad for stillness and the table rate
    tolerance_deg: float = 15.0  # orientation tolerance
    on_motion: str = "restart"  # or "discard": drop only the disturbed stretch of a dwell
    check_s: float = 0.5  # still time averaged for the orientation check
    rate_tolerance: float = 0.03  # |measured rate| within this fraction of the commanded one
    # A still unit whose gyro reads more than this fraction of the procedure's table rate is on a
    # turning table (left running), not at rest. A fixed threshold cannot serve: cheap MEMS
    # biases reach a few °/s while field tables turn as slowly as 0.1 °/s.
    turning_fraction: float = 0.5
    progress_every_s: float = 10.0
    # Adaptive dwell (a procedure's adaptive_dwell): never shorter than this, for the stillness
    # check to mean something, nor longer than this many planned dwells.
    min_dwell_s: float = 5.0
    max_dwell_factor: float = 4.0
    # For devices reporting counts: nominal zero and sensitivity (output units per SI unit).
    sf_zero: tuple = (0.0, 0.0, 0.0)
    sf_sensitivity: tuple = (1.0, 1.0, 1.0)
    rate_zero: tuple = (0.0, 0.0, 0.0)
    rate_sensitivity: tuple = (1.0, 1.0, 1.0)

    def __post_init__(self) -> None:
        window = round(self.stillness.window_s * self.rate_hz)
        if window < MIN_WINDOW_SAMPLES:
            raise ValueError(f"rate_hz: {self.rate_hz:g} Hz gives {window} samples per "
                             f"{self.stillness.window_s:g} s stillness window; at least "
                             f"{MIN_WINDOW_SAMPLES} are needed to tell still from moving")
        if self.on_motion not in ("restart", "discard"):
            raise ValueError(f"on_motion: expected 'restart' or 'discard', got {self.on_motion!r}")


class _Average:
    """Sums per triad over accepted stretches, kept per stretch so a disturbed tail can go."""

    def __init__(self, track_noise: bool = False) -> None:
        self.blocks: list[tuple[float, float, int, dict[str, np.ndarray]]] = []
        self._n = 0  # samples in blocks, kept as they change: n is asked at every chunk
        # Per block: triad -> sum of squared sample-to-sample differences, and their count; the
        # white-noise level without the mean or slow drift (for the adaptive dwell only: every
        # sample passes here, so a fixed dwell does not pay for it).
        self.track_noise = track_noise
        self.diffs: list[tuple[dict[str, np.ndarray], int]] = []
        # Per block: the sum of the unit's temperature, None when a chunk carries none.
        self.temperatures: list[float | None] = []

    @property
    def n(self) -> int:
        return self._n

    def add(self, chunk, lo: int, hi: int, diffs: tuple[dict[str, np.ndarray], int] | None = None) -> None:
        """Samples lo:hi of a chunk; ``diffs``: their ``stretch_diffs`` when the caller has them
        already (the adaptive dwell judges the noise of a stretch before adding it)."""
        if hi > lo:
            sums = {name: v[lo:hi].sum(axis=0) for name, v in chunk.triads.items()}
            self.blocks.append((float(chunk.t[lo]), float(chunk.t[hi - 1]), hi - lo, sums))
            self.temperatures.append(None if chunk.temperature is None else float(chunk.temperature[lo:hi].sum()))
            self._n += hi - lo
            if self.track_noise:
                self.diffs.append(stretch_diffs(chunk, lo, hi) if diffs is None else diffs)

    def drop_after(self, t: float) -> None:
        kept = [b[1] < t for b in self.blocks]
        self.blocks = [b for b, k in zip(self.blocks, kept) if k]
        self.temperatures = [s for s, k in zip(self.temperatures, kept) if k]
        if self.track_noise:
            self.diffs = [d for d, k in zip(self.diffs, kept) if k]
        self._n = sum(b[2] for b in self.blocks)

    def white_variance(self, name: str, ahead: tuple[dict[str, np.ndarray], int] | None = None) -> np.ndarray | None:
        """Per-axis per-sample white-noise variance of a triad so far (None: too few samples);
        with ``ahead``, as if the stretch of those ``stretch_diffs`` had been added too."""
        diffs = self.diffs if ahead is None else [*self.diffs, ahead]
        count = sum(d[1] for d in diffs)
        if count < MIN_WINDOW_SAMPLES:
            return None
        return cast(np.ndarray, sum(d[0][name] for d in diffs)) / (2.0 * count)  # (diffs: not empty)

    def mean_temperature(self) -> float | None:
        """The unit's mean temperature over the window (°C); None unless every sample had one."""
        if not self.temperatures or any(s is None for s in self.temperatures):
            return None
        return sum(cast(float, s) for s in self.temperatures) / self.n

    def means(self) -> dict[str, list[float]]:
        n = self.n
        names = self.blocks[0][3].keys()
        return {name: (cast(np.ndarray, sum(b[3][name] for b in self.blocks)) / n).tolist() for name in names}


def stretch_diffs(chunk, lo: int, hi: int) -> tuple[dict[str, np.ndarray], int]:
    """Per triad, the sum of squared sample-to-sample differences over samples lo:hi, and their count."""
    return {name: (np.diff(v[lo:hi], axis=0) ** 2).sum(axis=0) for name, v in chunk.triads.items()}, hi - lo - 1


def windows_and_averages(records: Iterable[StepRecord]) -> tuple[list[Window], dict[str, np.ndarray]]:
    """Completed steps' windows, in step order, and the per-triad means of each window."""
    windows, rows = [], []
    for record in sorted(records, key=lambda r: r.step):
        for w in record.windows:
            windows.append(Window(w.kind, record.step, w.start, w.duration, math.radians(abs(w.rate_deg_s)),
                                  w.temperature_c))
            rows.append(w.means)
    names = rows[0].keys() if rows else ()
    return windows, {name: np.array([r[name] for r in rows]) for name in names}


def adaptive_dwell_samples(planned: int, noise_ratio: float | None, settings: EngineSettings) -> int:
    """Samples an adaptive dwell takes: the planned number, scaled by measured / expected noise
    variance (the same information as planned), within [min_dwell_s, max_dwell_factor × planned].

    Before the noise can be judged (``noise_ratio`` None), the planned number.
    """
    if noise_ratio is None:
        return planned
    low = round(settings.min_dwell_s * settings.rate_hz)
    return int(min(max(math.ceil(planned * noise_ratio), low), round(settings.max_dwell_factor * planned)))


def skipped_to_return_to(skipped, step: int) -> int | None:
    """The skipped step that "unskip" goes back to: the nearest one before ``step`` (the one
    skipped last, as steps run in order), else the last one after it; None if none is skipped."""
    before = [s for s in skipped if s < step]
    if before:
        return max(before)
    return max(skipped) if skipped else None


class Engine:
    def __init__(self, procedure: Procedure, settings: EngineSettings):
        self.procedure = procedure
        self.settings = settings
        self.records: dict[int, StepRecord] = {}  # step -> completed record
        self.skipped: set[int] = set()
        self.step = 0
        self.phase = PLACE
        self.t = 0.0
        self._detector: StillnessDetector | None = None
        self._average = _Average(self.procedure.adaptive_dwell)
        self._windows: list[WindowRecord] = []  # this step's finished windows
        self._sign = 0.0
        self._next_progress = 0.0
        self._check: list[np.ndarray] = []
        self._check_rate: list[np.ndarray] = []
        self._turning_reported = False
        self._up = np.array([0.0, 0.0, 1.0])
        # Any order: where the last completed step's dwell saw gravity (the unit must leave it
        # before the next recognition), whether it has moved since, the remaining steps gravity
        # cannot tell from the recognised one, and the operator's choice among them.
        self._last_up: np.ndarray | None = None
        self._moved = True
        self._seen = 0  # samples the stillness detector has had: its first window cannot judge
        self._table_stops_at = -math.inf  # sample time a stopping table has stopped by
        self._alike: tuple[int, ...] = ()
        self._chosen: int | None = None

    # --- public -------------------------------------------------------------------------------

    @property
    def position(self):
        return self.procedure.positions[self.step]

    def start(self) -> list[ev.Event]:
        """Begin at the first step not already completed or skipped (after ``restore``)."""
        return self._enter_step(self._first_open(0))

    def restore(self, records: Iterable[StepRecord], skipped: Iterable[int] = ()) -> None:
        """Resume: take completed steps from a capture; ``start()`` then begins the next one."""
        self.records = {r.step: r for r in records}
        self.skipped = set(int(s) for s in skipped)
        self.t = max((w.end for r in self.records.values() for w in r.windows), default=0.0)
        last = max(self.records.values(), key=lambda r: max(w.end for w in r.windows), default=None)
        self._last_up = self._rest_direction(last) if last is not None else None

    def act(self, action: ev.Action) -> list[ev.Event]:
        if self.phase in (DONE, ABORTED):
            return []
        if action.name == ev.ABORT:
            stop = self._stop_table()  # before the phase changes: it decides whether to stop
            self.phase = ABORTED
            return stop + [ev.Aborted(self.t, "operator")]
        if action.name == ev.REDO:
            return self._stop_table() + self._enter_step(self.step)
        if action.name == ev.UNSKIP:
            back = skipped_to_return_to(self.skipped, self.step)
            if back is None:
                return []
            self.skipped.discard(back)  # this step stays open: _first_open comes back to it
            return self._stop_table() + self._enter_step(back)
        if action.name == ev.SKIP:
            self.skipped.add(self.step)
            out = self._stop_table() + [ev.StepSkipped(self.t, self.step, self.position.id)]
            return out + self._enter_step(self._next_open(self.step + 1))
        if action.name == ev.READY and self.phase == PLACE:
            self._watch()
            return [ev.WaitingForStillness(self.t)]
        if action.name == ev.CHOOSE:
            return self._choose(action.position_id)
        return []

    def _watch(self) -> None:
        """Look for the unit to be still (a fresh detector: what it saw before does not count)."""
        self._detector = StillnessDetector(self.settings.stillness, self.settings.rate_hz,
                                           self.settings.specific_force, self.settings.angular_rate)
        self.phase, self._seen = SETTLING, 0

    def _choose(self, position_id: int | None) -> list[ev.Event]:
        """The operator says which of the positions gravity cannot tell apart the unit is in:
        taken while the dwell runs (its samples serve either), before any rate step."""
        steps = [k for k in self._alike if self.procedure.positions[k].id == position_id]
        if self.phase != DWELL or not steps:
            return []
        self.step = self._chosen = steps[0]
        return [self._recognised(self.t, chosen=True)]

    def feed(self, chunk) -> list[ev.Event]:
        if len(chunk) == 0:
            return []
        out: list[ev.Event] = []
        if self.phase == PLACE and self._detector is None and self.procedure.any_order:
            self._watch()  # from a chunk's start, so that a resumed run sees what this one does
        still = self._detector.feed(chunk) if self._detector is not None else np.zeros(len(chunk), bool)
        i = 0
        while i < len(chunk) and self.phase not in (DONE, ABORTED) \
                and not (self.phase == PLACE and self._detector is None):
            i = getattr(self, f"_on_{self.phase}")(chunk, still, i, out)
        if self._detector is not None:
            self._seen += len(chunk)
        self.t = float(chunk.t[-1])
        return out

    def windows_and_averages(self) -> tuple[list[Window], dict[str, np.ndarray]]:
        return windows_and_averages(self.records.values())

    # --- phases: each consumes chunk samples from index i and returns where it stopped ---------

    def _on_place(self, chunk, still, i, out) -> int:
        """Any order, the unit still where the last step measured it: wait for the operator to move it."""
        moving = np.flatnonzero(~still[i:])
        if not len(moving):
            return len(chunk)
        self._moved, self.phase = True, SETTLING
        return i + int(moving[0])

    def _on_settling(self, chunk, still, i, out) -> int:
        hits = np.flatnonzero(still[i:])
        end = i + int(hits[0]) if len(hits) else len(chunk)
        self._note_motion(chunk, i, end)
        if not len(hits):
            return len(chunk)
        self.phase, self._check = CHECKING, []
        return end

    def _note_motion(self, chunk, i: int, end: int) -> None:
        """Samples i..end are not still: the operator moved the unit, unless they are the stillness
        detector's first window (not judged yet) or a table still coming to a stop."""
        judged_from = max(i, self._detector.window_samples - 1 - self._seen if self._detector else i)
        if end > judged_from and float(chunk.t[end - 1]) >= self._table_stops_at:
            self._moved = True

    def _on_checking(self, chunk, still, i, out) -> int:
        need = max(1, round(self.settings.check_s * self.settings.rate_hz)) - sum(len(c) for c in self._check)
        j = self._still_until(still, i, len(chunk))
        take = min(j, i + need)
        self._check.append(chunk.triads[self.settings.specific_force][i:take])
        self._check_rate.append(chunk.triads[self.settings.angular_rate][i:take])
        if take == i + need:
            return self._judge_orientation(chunk, take, out)
        if j < len(chunk):  # moved before the check was done
            self.phase = SETTLING
        return j

    def _judge_orientation(self, chunk, i, out) -> int:
        s = self.settings
        rate = (np.concatenate(self._check_rate).mean(axis=0) - np.array(s.rate_zero)) / np.array(s.rate_sensitivity)
        turning = math.degrees(float(np.linalg.norm(rate)))
        # Still turning from a rate step (this position's or the one before): judged against the
        # slowest rate the procedure turns at.
        steps = self.procedure.rate_steps
        if steps and turning > s.turning_fraction * steps[0].rate_deg_s:
            if not self._turning_reported:
                out.append(ev.TableTurning(float(chunk.t[i - 1]), turning))
                self._turning_reported = True
            self.phase = SETTLING  # look again; the dwell waits for the table to stop
            return i
        self._turning_reported = False
        mean = np.concatenate(self._check).mean(axis=0)
        direction = gravity_direction(mean, zero=np.array(s.sf_zero), sensitivity=np.array(s.sf_sensitivity))
        t = float(chunk.t[i - 1])
        if self.procedure.any_order:
            found = self._recognise(direction, t, out)
            if found is None:
                return i
        check = check_orientation(direction, self.position, self.procedure.positions, s.tolerance_deg)
        if not check.ok:
            self.phase = WRONG
            out.append(ev.WrongOrientation(t, self.position.id, tuple(p.id for p, _ in check.looks_like),
                                           float(check.angle_deg), check.message))
            return i
        out.append(ev.Still(t, float(check.angle_deg)))
        self._up = direction  # the table axis in sensor axes, for the sign of the rate steps
        self.phase = DWELL
        return i

    def _open_steps(self) -> list[int]:
        return [k for k in range(len(self.procedure.positions)) if k not in self.records and k not in self.skipped]

    def _recognise(self, direction: np.ndarray, t: float, out: list) -> int | None:
        """Any order: make the remaining position the unit is in this step (None: none is, and
        the phase says what the engine waits for)."""
        tolerance = self.settings.tolerance_deg
        if not self._moved and self._last_up is not None \
                and float(angle_between(direction, self._last_up)) <= tolerance:
            self.phase = PLACE  # still where the last step was measured: not placed yet
            return None
        positions = self.procedure.positions
        open_steps = self._open_steps()
        near = closest_positions(direction, [positions[k] for k in open_steps], tolerance)
        if not near:
            self.phase = WRONG
            out.append(self._no_remaining_position(direction, t, open_steps))
            return None
        nearest = near[0][0].up_body
        alike = [k for k in open_steps if float(angle_between(positions[k].up_body, nearest)) <= SAME_UP_DEG]
        self._alike = tuple(alike)  # (procedure order)
        step = self._chosen if self._chosen in alike else alike[0]
        self.step = step
        out.append(self._recognised(t, chosen=step == self._chosen))
        return step

    def _recognised(self, t: float, chosen: bool) -> ev.PositionRecognised:
        p = self.position
        alike = tuple(self.procedure.positions[k].id for k in self._alike) if len(self._alike) > 1 else ()
        return ev.PositionRecognised(t, self.step, p.id, position_words(p), alike, chosen)

    def _no_remaining_position(self, direction, t: float, open_steps: list[int]) -> ev.WrongOrientation:
        positions = self.procedure.positions
        looks_like = closest_positions(direction, positions, self.settings.tolerance_deg)
        ids = tuple(p.id for p, _ in looks_like)
        done = f" (position {', '.join(map(str, ids))}, done or skipped)" if ids else ""
        remaining = ", ".join(str(positions[k].id) for k in open_steps)
        angle = float(angle_between(direction, self.position.up_body))
        return ev.WrongOrientation(t, self.position.id, ids, angle,
                                   f"the unit is {describe_up(direction)}{done}, like no remaining position; "
                                   f"place it in one of positions {remaining}")

    def _on_wrong(self, chunk, still, i, out) -> int:
        moving = np.flatnonzero(~still[i:])
        if not len(moving):
            return len(chunk)
        self.phase = SETTLING  # the operator is moving it: look again once it is still
        return i + int(moving[0])

    def _on_dwell(self, chunk, still, i, out) -> int:
        s = self.settings
        target = round(self.procedure.dwell_s * s.rate_hz)
        j = self._still_until(still, i, len(chunk))
        ahead = None
        if self.procedure.adaptive_dwell:
            # The noise level is judged on all the still samples of this chunk, then the dwell
            # takes what that level calls for: the rule sees only time and noise, never the mean.
            # Their differences, once: added with the samples when the dwell takes them all.
            ahead = stretch_diffs(chunk, i, j) if j > i else None
            target = adaptive_dwell_samples(target, self._noise_ratio(self._average, ahead), s)
        take = min(j, max(i, i + target - self._average.n))
        self._average.add(chunk, i, take, ahead if take == j else None)
        done_s = self._average.n / s.rate_hz
        while done_s >= self._next_progress + s.progress_every_s and self._average.n < target:
            self._next_progress += s.progress_every_s
            out.append(ev.DwellProgress(float(chunk.t[take - 1]), self._next_progress, self.procedure.dwell_s))
        if self._average.n >= target:
            t = float(chunk.t[take - 1]) if take > 0 else self.t  # met before this chunk's first sample
            adaptive = self.procedure.adaptive_dwell
            out.append(ev.DwellComplete(t, self._average.n / s.rate_hz if adaptive else self.procedure.dwell_s))
            self._finish_window(STATIC, 0.0)
            return self._after_static(take, t, out)
        if j < len(chunk):
            restart = s.on_motion == "restart"
            out.append(ev.MotionDetected(float(chunk.t[j]), "dwell", restart))
            if restart:
                self._average = _Average(self.procedure.adaptive_dwell)
                self._next_progress = 0.0
            else:
                self._average.drop_after(float(chunk.t[j]) - s.stillness.window_s)
            self.phase = SETTLING
        return j

    def _after_static(self, i, t, out) -> int:
        if self.procedure.rate_step_at(self.step) is None:
            return self._complete_step(i, t, out)
        return self._command_rate(+1.0, i, t, out)

    @property
    def _rate_step(self) -> RateStep:
        """This position's rate step: the rate phases are entered only for a position with one."""
        step = self.procedure.rate_step_at(self.step)
        assert step is not None
        return step

    def _command_rate(self, sign, i, t, out) -> int:
        self._sign = sign
        out.append(ev.CommandTable(t, sign * self._rate_step.rate_deg_s))
        self.phase = RATE_WAIT
        return i

    def _on_rate_wait(self, chunk, still, i, out) -> int:
        s = self.settings
        rate = math.radians(self._rate_step.rate_deg_s)
        gyro = (chunk.triads[s.angular_rate][i:] - np.array(s.rate_zero)) / np.array(s.rate_sensitivity)
        # Steady, and turning the commanded way about the table axis (local up, measured in the
        # dwell): a steady +ω must not pass for −ω.
        steady = still[i:] & (np.abs(gyro @ self._up - self._sign * rate) < s.rate_tolerance * rate)
        hits = np.flatnonzero(steady)
        if not len(hits):
            return len(chunk)
        start = i + int(hits[0])
        step = self._rate_step
        out.append(ev.RateSettled(float(chunk.t[start]), self._sign * step.rate_deg_s,
                                  step.turns * 360.0 / step.rate_deg_s))
        self.phase = RATE_AVERAGE
        self._average = _Average()  # (empty here) a rate window's noise is never judged: no differences
        return start

    def _on_rate_average(self, chunk, still, i, out) -> int:
        step = self._rate_step
        target = round(step.turns * 360.0 / step.rate_deg_s * self.settings.rate_hz)
        j = self._still_until(still, i, len(chunk))
        take = min(j, i + target - self._average.n)
        self._average.add(chunk, i, take)
        if self._average.n >= target:
            t = float(chunk.t[take - 1])
            rate = self._sign * step.rate_deg_s
            self._finish_window(PLUS if self._sign > 0 else MINUS, rate)
            out.append(ev.RateStepComplete(t, rate))
            if self._sign > 0:
                return self._command_rate(-1.0, take, t, out)
            out.append(ev.CommandTable(t, 0.0))
            self._table_stops_at = t + step.ramp_s + step.settle_s
            return self._complete_step(take, t, out)
        if j < len(chunk):
            out.append(ev.MotionDetected(float(chunk.t[j]), "rate", True))
            self._average = _Average(self.procedure.adaptive_dwell)
            self.phase = RATE_WAIT
        return j

    # --- helpers ----------------------------------------------------------------------------

    def _noise_ratio(self, average: _Average, ahead=None) -> float | None:
        """Measured / expected white-noise variance, the worse of the two stillness triads (with
        ``ahead``: as if that stretch's ``stretch_diffs`` were in the average)."""
        s = self.settings
        ratios = []
        for name, sigma in ((s.specific_force, s.stillness.specific_force_sigma),
                            (s.angular_rate, s.stillness.rate_sigma)):
            measured = average.white_variance(name, ahead)
            if measured is None:
                return None
            ratios.append(float(np.mean(measured / np.square(sigma))))
        return max(ratios)

    @staticmethod
    def _still_until(still, i, n) -> int:
        moving = np.flatnonzero(~still[i:])
        return i + int(moving[0]) if len(moving) else n

    def _finish_window(self, kind: WindowKind, rate_deg_s: float) -> None:
        blocks = self._average.blocks
        self._windows.append(WindowRecord(kind, blocks[0][0], self._average.n / self.settings.rate_hz,
                                          rate_deg_s, self._average.means(), self._average.mean_temperature()))
        self._average = _Average(self.procedure.adaptive_dwell)
        self._next_progress = 0.0

    def _rest_direction(self, record: StepRecord) -> np.ndarray | None:
        """Gravity's direction in a completed step's static window (None: it has none)."""
        s = self.settings
        static = [w for w in record.windows if w.kind == STATIC and s.specific_force in w.means]
        if not static:
            return None
        return gravity_direction(np.array(static[0].means[s.specific_force]), zero=np.array(s.sf_zero),
                                 sensitivity=np.array(s.sf_sensitivity))

    def _complete_step(self, i, t, out) -> int:
        self.t = t
        self.records[self.step] = StepRecord(self.step, self.position.id, tuple(self._windows))
        self._last_up = self._rest_direction(self.records[self.step])
        out.append(ev.StepComplete(t, self.step, self.position.id))
        out.extend(self._enter_step(self._next_open(self.step + 1)))
        return i

    def _first_open(self, step: int) -> int:
        while step < len(self.procedure.positions) and (step in self.records or step in self.skipped):
            step += 1
        return step

    def _next_open(self, step: int) -> int:
        """The next step to suggest: the first open one from ``step`` on; in any order, else the
        first open one before it (positions recognised out of order leave earlier ones open)."""
        found = self._first_open(step)
        return self._first_open(0) if found >= len(self.procedure.positions) and self.procedure.any_order else found

    def _enter_step(self, step: int) -> list[ev.Event]:
        self.step, self._windows, self._average = step, [], _Average(self.procedure.adaptive_dwell)
        self._detector, self._next_progress, self._sign = None, 0.0, 0.0
        self._moved, self._alike, self._chosen = False, (), None
        if step >= len(self.procedure.positions):
            self.phase = DONE
            return [ev.ProcedureComplete(self.t, len(self.records), len(self.skipped))]
        self.phase = PLACE
        p = self.position
        words = position_words(p)  # a corner the file does not describe: its attitude in words
        return [ev.StepStarted(self.t, step, p.id, words, len(self.procedure.positions)),
                ev.PlaceUnit(self.t, p.id, words)]

    def stop_table(self) -> list[ev.Event]:
        """The table's stop command if this step has it turning (else none), the phase unchanged:
        what a run that replaces this engine mid-step (a restart after a power cycle) publishes
        first, so that the operator is never told to place the unit on a turning table."""
        return self._stop_table()

    def _stop_table(self) -> list[ev.Event]:
        if self.phase in (RATE_WAIT, RATE_AVERAGE):
            return [ev.CommandTable(self.t, 0.0)]
        return []
