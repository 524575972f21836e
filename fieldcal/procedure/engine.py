"""The procedure engine: a pure state machine, fed sample chunks and operator actions.

``feed(chunk)`` and ``act(action)`` return events; nothing here reads a clock or touches a file.
Time is sample time: a 200 s dwell is 200 s of samples, counted at the nominal rate.

Per position: the operator places the unit and says ready; the engine waits until the unit is
still, checks that gravity points where the position expects, then averages a dwell while the
unit stays still (a bump restarts the dwell, or drops the disturbed stretch). With a rate step it
then commands the table to +ω, waits until the rate is steady, averages whole turns, does the
same at −ω, and stops the table. The stillness detector is reset when the operator says ready,
so a run resumed after a crash behaves exactly like an uninterrupted one from that step on.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fieldcal.procedure import events as ev
from fieldcal.procedure.positions import Procedure
from fieldcal.run.simrun import MINUS, PLUS, STATIC, Window
from fieldcal.procedure.stillness import StillnessDetector, StillnessSettings, check_orientation, gravity_direction

MIN_WINDOW_SAMPLES = 10  # fewer, and the window's spread says little about stillness

PLACE, SETTLING, CHECKING, WRONG, DWELL, RATE_WAIT, RATE_AVERAGE, DONE, ABORTED = (
    "place", "settling", "checking", "wrong", "dwell", "rate_wait", "rate_average", "done", "aborted")


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

    def __init__(self) -> None:
        self.blocks: list[tuple[float, float, int, dict[str, np.ndarray]]] = []

    @property
    def n(self) -> int:
        return sum(b[2] for b in self.blocks)

    def add(self, chunk, lo: int, hi: int) -> None:
        if hi > lo:
            sums = {name: v[lo:hi].sum(axis=0) for name, v in chunk.triads.items()}
            self.blocks.append((float(chunk.t[lo]), float(chunk.t[hi - 1]), hi - lo, sums))

    def drop_after(self, t: float) -> None:
        self.blocks = [b for b in self.blocks if b[1] < t]

    def means(self) -> dict[str, list[float]]:
        n = self.n
        names = self.blocks[0][3].keys()
        return {name: (sum(b[3][name] for b in self.blocks) / n).tolist() for name in names}


def windows_and_averages(records) -> tuple[list[Window], dict[str, np.ndarray]]:
    """Completed steps' windows, in step order, and the per-triad means of each window."""
    windows, rows = [], []
    for record in sorted(records, key=lambda r: r["step"]):
        for w in record["windows"]:
            windows.append(Window(w["kind"], record["step"], w["start"], w["duration"],
                                  math.radians(abs(w["rate_deg_s"]))))
            rows.append(w["means"])
    names = rows[0].keys() if rows else ()
    return windows, {name: np.array([r[name] for r in rows]) for name in names}


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
        self.records: dict[int, dict] = {}  # step -> completed record (JSON-able)
        self.skipped: set[int] = set()
        self.step = 0
        self.phase = PLACE
        self.t = 0.0
        self._detector: StillnessDetector | None = None
        self._average = _Average()
        self._windows: list[dict] = []  # this step's finished windows
        self._sign = 0.0
        self._next_progress = 0.0
        self._check: list[np.ndarray] = []
        self._check_rate: list[np.ndarray] = []
        self._turning_reported = False
        self._up = np.array([0.0, 0.0, 1.0])

    # --- public -------------------------------------------------------------------------------

    @property
    def position(self):
        return self.procedure.positions[self.step]

    def start(self) -> list[ev.Event]:
        """Begin at the first step not already completed or skipped (after ``restore``)."""
        return self._enter_step(self._first_open(0))

    def restore(self, records: list[dict], skipped: list[int] = ()) -> None:
        """Resume: take completed steps from a capture; ``start()`` then begins the next one."""
        self.records = {int(r["step"]): r for r in records}
        self.skipped = set(int(s) for s in skipped)
        ends = [w["start"] + w["duration"] for r in records for w in r["windows"]]
        self.t = max(ends, default=0.0)

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
            return out + self._enter_step(self._first_open(self.step + 1))
        if action.name == ev.READY and self.phase == PLACE:
            self._detector = StillnessDetector(self.settings.stillness, self.settings.rate_hz,
                                               self.settings.specific_force, self.settings.angular_rate)
            self.phase = SETTLING
            return [ev.WaitingForStillness(self.t)]
        return []

    def feed(self, chunk) -> list[ev.Event]:
        if len(chunk) == 0:
            return []
        out: list[ev.Event] = []
        still = self._detector.feed(chunk) if self._detector is not None else np.zeros(len(chunk), bool)
        i = 0
        while i < len(chunk) and self.phase not in (PLACE, DONE, ABORTED):
            i = getattr(self, f"_on_{self.phase}")(chunk, still, i, out)
        self.t = float(chunk.t[-1])
        return out

    def windows_and_averages(self) -> tuple[list[Window], dict[str, np.ndarray]]:
        return windows_and_averages(self.records.values())

    # --- phases: each consumes chunk samples from index i and returns where it stopped ---------

    def _on_settling(self, chunk, still, i, out) -> int:
        hits = np.flatnonzero(still[i:])
        if not len(hits):
            return len(chunk)
        self.phase, self._check = CHECKING, []
        return i + int(hits[0])

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
        step = self.procedure.rate_step
        if step is not None and turning > s.turning_fraction * step.rate_deg_s:
            if not self._turning_reported:
                out.append(ev.TableTurning(float(chunk.t[i - 1]), turning))
                self._turning_reported = True
            self.phase = SETTLING  # look again; the dwell waits for the table to stop
            return i
        self._turning_reported = False
        mean = np.concatenate(self._check).mean(axis=0)
        direction = gravity_direction(mean, zero=np.array(s.sf_zero), sensitivity=np.array(s.sf_sensitivity))
        check = check_orientation(direction, self.position, self.procedure.positions, s.tolerance_deg)
        t = float(chunk.t[i - 1])
        if not check.ok:
            self.phase = WRONG
            out.append(ev.WrongOrientation(t, self.position.id, tuple(p.id for p, _ in check.looks_like),
                                           float(check.angle_deg), check.message))
            return i
        out.append(ev.Still(t, float(check.angle_deg)))
        self._up = direction  # the table axis in sensor axes, for the sign of the rate steps
        self.phase = DWELL
        return i

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
        take = min(j, i + target - self._average.n)
        self._average.add(chunk, i, take)
        done_s = self._average.n / s.rate_hz
        while done_s >= self._next_progress + s.progress_every_s and self._average.n < target:
            self._next_progress += s.progress_every_s
            out.append(ev.DwellProgress(float(chunk.t[take - 1]), self._next_progress, self.procedure.dwell_s))
        if self._average.n >= target:
            t = float(chunk.t[take - 1])
            out.append(ev.DwellComplete(t, self.procedure.dwell_s))
            self._finish_window(STATIC, 0.0)
            return self._after_static(take, t, out)
        if j < len(chunk):
            restart = s.on_motion == "restart"
            out.append(ev.MotionDetected(float(chunk.t[j]), "dwell", restart))
            if restart:
                self._average = _Average()
                self._next_progress = 0.0
            else:
                self._average.drop_after(float(chunk.t[j]) - s.stillness.window_s)
            self.phase = SETTLING
        return j

    def _after_static(self, i, t, out) -> int:
        if self.procedure.rate_step is None:
            return self._complete_step(i, t, out)
        return self._command_rate(+1.0, i, t, out)

    def _command_rate(self, sign, i, t, out) -> int:
        self._sign = sign
        out.append(ev.CommandTable(t, sign * self.procedure.rate_step.rate_deg_s))
        self.phase = RATE_WAIT
        return i

    def _on_rate_wait(self, chunk, still, i, out) -> int:
        s = self.settings
        rate = math.radians(self.procedure.rate_step.rate_deg_s)
        gyro = (chunk.triads[s.angular_rate][i:] - np.array(s.rate_zero)) / np.array(s.rate_sensitivity)
        # Steady, and turning the commanded way about the table axis (local up, measured in the
        # dwell): a steady +ω must not pass for −ω.
        steady = still[i:] & (np.abs(gyro @ self._up - self._sign * rate) < s.rate_tolerance * rate)
        hits = np.flatnonzero(steady)
        if not len(hits):
            return len(chunk)
        start = i + int(hits[0])
        step = self.procedure.rate_step
        out.append(ev.RateSettled(float(chunk.t[start]), self._sign * step.rate_deg_s,
                                  step.turns * 360.0 / step.rate_deg_s))
        self.phase = RATE_AVERAGE
        return start

    def _on_rate_average(self, chunk, still, i, out) -> int:
        step = self.procedure.rate_step
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
            return self._complete_step(take, t, out)
        if j < len(chunk):
            out.append(ev.MotionDetected(float(chunk.t[j]), "rate", True))
            self._average = _Average()
            self.phase = RATE_WAIT
        return j

    # --- helpers ----------------------------------------------------------------------------

    @staticmethod
    def _still_until(still, i, n) -> int:
        moving = np.flatnonzero(~still[i:])
        return i + int(moving[0]) if len(moving) else n

    def _finish_window(self, kind: str, rate_deg_s: float) -> None:
        blocks = self._average.blocks
        self._windows.append({"kind": kind, "start": blocks[0][0],
                              "duration": self._average.n / self.settings.rate_hz,
                              "rate_deg_s": rate_deg_s, "means": self._average.means()})
        self._average = _Average()
        self._next_progress = 0.0

    def _complete_step(self, i, t, out) -> int:
        self.t = t
        self.records[self.step] = {"step": self.step, "position_id": self.position.id,
                                   "windows": self._windows}
        out.append(ev.StepComplete(t, self.step, self.position.id))
        out.extend(self._enter_step(self._first_open(self.step + 1)))
        return i

    def _first_open(self, step: int) -> int:
        while step < len(self.procedure.positions) and (step in self.records or step in self.skipped):
            step += 1
        return step

    def _enter_step(self, step: int) -> list[ev.Event]:
        self.step, self._windows, self._average = step, [], _Average()
        self._detector, self._next_progress, self._sign = None, 0.0, 0.0
        if step >= len(self.procedure.positions):
            self.phase = DONE
            return [ev.ProcedureComplete(self.t, len(self.records), len(self.skipped))]
        self.phase = PLACE
        p = self.position
        return [ev.StepStarted(self.t, step, p.id, p.description, len(self.procedure.positions)),
                ev.PlaceUnit(self.t, p.id, p.description)]

    def _stop_table(self) -> list[ev.Event]:
        if self.phase in (RATE_WAIT, RATE_AVERAGE):
            return [ev.CommandTable(self.t, 0.0)]
        return []
