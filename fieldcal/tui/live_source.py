"""The terminal UI's source for a real device: the operator's hands move the unit, the port is
read as the samples come, and the table turns on the engine's command.

Samples flow all the time, also while the engine waits for the operator, so the readings and
the orientation error stay live as the unit is placed; the engine ignores them until the
operator says ready. Everything read is captured: chunks, raw bytes, events and actions.

A quit run is resumed (``LiveSource.resuming``) after its last completed step, the operator
placing the unit again for the next one. Unless the device shows, by its own clock, that it ran
on meanwhile (``fieldcal.run.deviceclock``), it is taken as power-cycled, and then every
completed step is measured again; see ``_kept_after``. A device whose frames carry no clock
shows it only by an unbroken stream while the station holds its port: a quit run of one has its
completed steps measured again, and a break in its stream mid-run restarts the run as a
regained port does (``_regained``).
"""
from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

from fieldcal.procedure import events as ev
from fieldcal.procedure.engine import PLACE, WAITING_FOR_OPERATOR, WRONG
from fieldcal.run.conductor import Act, Conductor, Restart, Say
from fieldcal.run.deviceclock import measured_again, power_cycle_banner, step_started_again
from fieldcal.run.outcome import Status
from fieldcal.session.record import ResumePoint
from fieldcal.tui.source import (ABORT, BUMP, CHOOSE_PREFIX, FLUSH_S, MISPLACE, READY, REDO, SKIP, UNSKIP, Mode, Note,
                                 ResumeNote, SimSource, Sink, choice_moves)

RATE_FRAMES_S = 10.0  # a run waits this long for the frames its device's rate is measured from
NO_SAMPLES_WARN_S = 3.0  # wall time without a sample before the log says so
SILENT_S = 0.5  # wall time without a sample before the readings, stillness and banner say so
FIRST_FRAMES_S = 30.0  # a resumed run waits this long for the device's first frames (its clock)


class LiveSource(SimSource):
    mode = Mode.LIVE

    def __init__(self, spec, config, sink: Sink, session_dir: Path | None,
                 clock: Callable[[], float] = time.monotonic, resume=None,
                 wall_clock: Callable[[], float] = time.time,
                 silence_clock: Callable[[], float] | None = None):
        """``resume``: the ``RunRecord`` of the unfinished live session in ``session_dir`` to
        continue (``resuming``).
        ``wall_clock``: the host's Unix time, against which the device's clock is judged.
        ``silence_clock``: what the device's silence is measured in (``SILENT_S``,
        ``NO_SAMPLES_WARN_S``); default ``clock``. A test serving a simulated unit faster than
        real time passes the unit's own time, so that a silence is the unit's, never the host's
        load."""
        from fieldcal.run.livebench import LiveBench

        self.config = config
        self.silence_clock = clock if silence_clock is None else silence_clock
        bench = LiveBench(config, tap=self._capture_raw, clock=clock, silence_s=NO_SAMPLES_WARN_S,
                          wall_clock=wall_clock, silence_clock=self.silence_clock)
        super().__init__(spec, sink, 0.0, session_dir, clock, bench=bench, resume=resume)
        self._caught_up = False  # everything read so far has been fed (then silence is the device's)
        self.clock_check = None  # a resumed run: what the device's clock said (deviceclock.ClockCheck)
        # A resumed run reads the device before it may write the session: those bytes wait here.
        self._raw_lock = threading.Lock()
        self._early_raw: list[tuple[float, bytes]] | None = [] if resume is not None else None

    @classmethod
    def resuming(cls, record, config, sink: Sink, clock: Callable[[], float] = time.monotonic,
                 wall_clock: Callable[[], float] = time.time,
                 silence_clock: Callable[[], float] | None = None) -> LiveSource:
        """Continue the unfinished live session of ``record`` (its ``RunRecord``) on the device
        of ``config`` (its ports; the device must be the session's): the run's spec is the session's."""
        spec = record.spec
        if spec.live is None:
            raise ValueError(f"{record.directory}: a simulated session; LiveSource resumes a live device's")
        check_same_device(spec.live, config, record.directory)
        return cls(spec, config, sink, record.directory, clock, resume=record, wall_clock=wall_clock,
                   silence_clock=silence_clock)

    def _capture_raw(self, t: float, data: bytes) -> None:
        """Called on the port's reader thread (the session writer is thread-safe)."""
        with self._raw_lock:
            if self.recorder is not None:
                self.recorder.raw(t, data)
            elif self._early_raw is not None:
                self._early_raw.append((t, data))

    def _record_to(self, recorder) -> None:
        """From now on the session is written: first what was read before."""
        with self._raw_lock:
            self.recorder = recorder
            for t, data in self._early_raw or ():
                recorder.raw(t, data)
            self._early_raw = None

    def _metadata(self) -> dict:
        return self.spec.session_metadata(None, "tui")

    def _conductor(self) -> Conductor:
        if self.resume:
            return self._resumed_conductor()
        conductor = super()._conductor()
        self.bench.say = conductor.say
        try:
            self.bench.start()
            self._check_rate(conductor.say)
        except BaseException:  # the port or the table would not open: close what did, keep the session
            try:
                self.bench.close()
            finally:
                if self.recorder is not None:
                    self.recorder.end(Status.ERROR, conductor)
            raise
        self._say_reading(conductor)
        return conductor

    def _check_rate(self, say) -> None:
        """Hold the run (a one-line ValueError) before any dwell counts when the device's real
        sample rate is more than 1 % off the config's (``fieldcal.run.ratecheck``); say it."""
        from fieldcal.run.ratecheck import held_line

        found = self.bench.measure_rate(RATE_FRAMES_S, self.spec.rate_hz, lambda: self.stopping)
        if found is None:
            if not self.stopping and self.config.device.protocol != "sim":
                say(f"WARNING: no samples from {self.bench.url} within {RATE_FRAMES_S:g} s to measure its rate")
            return
        measured, expected = found
        device = self.config.device
        say(f"sample rate: {measured.describe()}; device.rate_hz {self.spec.rate_hz:g} Hz")
        line = held_line(measured, expected, self.config.path,
                         device.sim.speed if device.protocol == "sim" and device.sim else None)
        if line is not None:
            raise ValueError(line)

    def _say_reading(self, conductor: Conductor) -> None:
        table = self.config.table
        conductor.say(f"reading {self.spec.device_name} on {self.bench.url} ({self.config.device.protocol}, "
                      f"{self.spec.rate_hz:g} Hz); table: "
                      f"{f'{table.protocol} on {table.port.url}' if table and table.port else 'none'}")

    def _resumed_conductor(self) -> Conductor:
        """The conductor after the session's last completed step, or, if the device was (or may
        have been) power-cycled since, after none of them. The ports are opened and the first
        frames read before the session is touched: what cannot go on leaves it unchanged."""
        from fieldcal.run.deviceclock import judge_restart
        from fieldcal.run.resume import refuse_ended, resume_conductor

        record = self.resume
        refuse_ended(record)  # before the ports are opened
        steps = record.steps
        self.bench.say = lambda text: self._items.append(Note(self._t(), text))
        try:
            self.bench.start()
            if steps:
                self.bench.set_state(steps[-1].bench or {})
                self._items.append(Note(0.0, f"reading the device's clock in its first frames from {self.bench.url}"))
                self._flush(force=True)
                now = self.bench.first_clock(FIRST_FRAMES_S, lambda: self.stopping)
                if now is None and self.stopping:
                    raise ValueError("quit before the device's first frames came; the session is unchanged")
                if now is None:
                    raise ValueError(f"no samples from {self.bench.url} within {FIRST_FRAMES_S:g} s, so its "
                                     "clock cannot be read: is the unit on and sending? The session is "
                                     "unchanged; resume it again")
                self.clock_check = judge_restart(self.bench.recorded_clock, now, self.spec.rate_hz)
            self._check_rate(self.bench.say)  # before the session is touched
            kept, why = self._kept_after(steps)
            # (locked by another station, read-only, damaged: the ports are closed again, so a
            # retry from the setup screen does not open the device a second time)
            conductor = resume_conductor(record, self.bench, self, [self], settings=self.settings,
                                         measured_again=why, attach=self._record_to)
            self.conductor = conductor
        except BaseException:
            self.bench.close()
            raise
        self.bench.say = conductor.say
        self._say_reading(conductor)
        note = self._resume_note(steps, kept, why, conductor.engine.t)
        self._items.append(replace(note, done=tuple(conductor.engine.records),
                                   skipped=tuple(conductor.engine.skipped)))
        return conductor

    def _kept_after(self, steps) -> tuple[list, str]:
        """The completed steps the resumed run keeps, and why not all (or ""): none unless the
        device's clock shows it ran on (``deviceclock.measured_again``). The old step documents
        stay in the session; the resume document says they are not kept."""
        why = measured_again(self.clock_check, len({s.record.step for s in steps}),
                             "since the last completed step")
        return ([], why) if why else (list(steps), "")

    def _resume_note(self, steps, kept, why: str, t: float) -> ResumeNote:
        """The log line and the banner of where the resumed run goes on."""
        done = len({s.record.step for s in steps})
        if not steps:
            return ResumeNote(t, f"resuming {self.session_dir.name}: no step was completed; place the unit "
                                 "for the first step", "RESUMED: no step was completed before")
        if kept:
            return ResumeNote(t, f"resuming {self.session_dir.name} after {done} completed step"
                                 f"{'s' if done != 1 else ''} ({self.clock_check.reason}): place the unit "
                                 "again for the next step",
                              f"RESUMED after {done} completed step{'s' if done != 1 else ''}: "
                              "place the unit again")
        return ResumeNote(t, f"WARNING: {why}", power_cycle_banner(self.clock_check, done, "since the last step"),
                          warn=True)

    def next_moves(self, run: Conductor):
        check = self.bench.take_regain_check()
        if check is not None:
            return self._regained(check, run)
        return super().next_moves(run)

    def _regained(self, check, run: Conductor) -> list:
        """The device's port came back (a cable, a power cycle), or its clock went back with the
        port open (a power cycle behind a powered adapter): unless its clock shows it ran on,
        the run starts over as a resume after a power cycle does (every completed step measured
        again; the session keeps the old step documents and says why they no longer count)."""
        e = run.engine
        done = len(e.records)
        port = self.bench.judged_port  # "was lost", or "stayed open" (its clock went back meanwhile)
        when = f"while its port {port}"
        why = measured_again(check, done, when)
        if not why and check.power_cycled is not False and e.phase != PLACE:
            why = step_started_again(check, when)
        if not why:
            kept = f"; the {done} completed step{'s are' if done != 1 else ' is'} kept" if done else ""
            news = "regained" if port == "was lost" else "open, the unit restarted"
            return [Say(f"port {self.bench.url} {news}: {check.reason}{kept}")]
        skipped = tuple(sorted(e.skipped))
        banner = power_cycle_banner(check, done, f"while the port {port}")
        self._items.append(ResumeNote(e.t, f"WARNING: {why}", banner, warn=True, skipped=skipped))
        return [Restart(ResumePoint((), skipped, why, tuple(sorted(e.records))))]

    def _holds_for_keys(self, run: Conductor) -> bool:
        return False  # samples flow all the time, also while the operator places the unit

    def idle(self, run: Conductor) -> None:
        """Nothing read: wait briefly for a key instead of spinning; the screen still learns
        that no samples come (``silent_s``)."""
        self._caught_up = True
        try:
            self._deferred.append(self._commands.get(timeout=min(0.02, FLUSH_S)))
        except queue.Empty:
            pass
        self._flush()

    def telemetry(self):
        telemetry = super().telemetry()
        # Silent only once everything read has been fed: a batch that takes a while to feed (a
        # loaded station) is not a device that stopped.
        silent = self.silence_clock() - self.bench.last_sample_wall
        return replace(telemetry, silent_s=silent) \
            if self.conductor is not None and self._caught_up and silent > SILENT_S \
            else telemetry

    def chunk(self, chunk, run: Conductor) -> None:
        self._caught_up = False
        super().chunk(chunk, run)

    def tick(self, run: Conductor) -> None:
        self._waiting = run.engine.phase in WAITING_FOR_OPERATOR  # on the operator's hands
        super().tick(run)

    def _moves(self, command: str, run: Conductor) -> list:
        e = run.engine
        if command.startswith(CHOOSE_PREFIX):
            return choice_moves(command)
        if command == READY and e.phase == PLACE:
            return [Say(f"operator: ready, the unit is in position {e.position.id}"), Act(ev.READY)]
        if command == READY and e.phase == WRONG:
            return [Say(f"waiting for the unit to be still in position {e.position.id}")]
        if command == READY:
            return [Say("(ready: nothing to do now)")]
        if command in (REDO, SKIP, ABORT, UNSKIP):
            return [Say(f"operator: {command}"), Act(command)]
        assert command in (BUMP, MISPLACE)
        return [Say(f"({command}: the simulator's keys; this is a real device)")]

    def resume_prospect(self) -> str:
        """A resume keeps the completed steps only where the device's clock shows the unit ran on
        meanwhile (``deviceclock.measured_again``); a device whose frames carry none cannot show
        it once the station has let go of its port, so those steps are measured again: said
        with how many, as the resume will say it."""
        if self.session_dir is None:
            return super().resume_prospect()
        clock = self.bench.device_clock  # as last read (the worker thread replaces it whole)
        if clock is None or (clock.time_s is None and clock.counter is None):
            done = len(self.conductor.engine.records) if self.conductor is not None else 0
            again = (f"it measures the {done} completed step{'s' if done != 1 else ''} again" if done
                     else "it starts from the first step")
            return ("The session is kept, but this device's frames carry no clock, so a resume cannot "
                    f"show the unit stayed powered: {again}.")
        return ("The session is kept: a resume continues after the last completed step if the unit "
                "stays powered (its clock tells).")

    def _stopped_message(self) -> str:
        if self.session_dir is None:
            return "stopped before the end"
        return ("stopped before the end; the session can be continued with "
                f"`fieldcal tui --resume {self.session_dir} --config {self.config.path}` (or at the "
                f"console: `fieldcal resume {self.session_dir} --config {self.config.path}`)")


def check_same_device(live, config, directory) -> None:
    """A one-line ValueError unless ``config`` describes the device the session was recorded
    from (its ports may differ: a unit plugged back in may get another one)."""
    device = config.device
    recorded = (live.name, live.serial, live.protocol)
    given = (device.name, device.serial, device.protocol)
    if recorded != given:
        raise ValueError(f"--resume: {directory} was recorded from {live.name} (serial {live.serial}, "
                         f"{live.protocol}); {config.path} is {device.name} (serial {device.serial}, "
                         f"{device.protocol}): give the config of that unit")
