"""The terminal UI's source for a real device: the operator's hands move the unit, the port is
read as the samples come, and the table turns on the engine's command.

Samples flow all the time, also while the engine waits for the operator, so the readings and
the orientation error stay live as the unit is placed; the engine ignores them until the
operator says ready. Everything read is captured: chunks, raw bytes, events and actions.
"""
from __future__ import annotations

import queue
import time
from collections.abc import Callable
from pathlib import Path

from fieldcal.procedure import events as ev
from fieldcal.procedure.engine import PLACE, WAITING_FOR_OPERATOR, WRONG
from fieldcal.run.conductor import Act, Conductor, Say
from fieldcal.run.outcome import Status
from fieldcal.tui.source import ABORT, BUMP, FLUSH_S, MISPLACE, READY, REDO, SKIP, UNSKIP, Mode, SimSource, Sink

NO_SAMPLES_WARN_S = 3.0  # wall time without a sample before the log says so
SILENT_S = 0.5  # wall time without a sample before the readings, stillness and banner say so


class LiveSource(SimSource):
    mode = Mode.LIVE

    def __init__(self, spec, config, sink: Sink, session_dir: Path | None,
                 clock: Callable[[], float] = time.monotonic):
        from fieldcal.run.livebench import LiveBench

        self.config = config
        bench = LiveBench(config, tap=self._capture_raw, clock=clock, silence_s=NO_SAMPLES_WARN_S)
        super().__init__(spec, sink, 0.0, session_dir, clock, bench=bench)
        self._caught_up = False  # everything read so far has been fed (then silence is the device's)

    def _capture_raw(self, t: float, data: bytes) -> None:
        """Called on the port's reader thread (the session writer is thread-safe)."""
        if self.recorder is not None:
            self.recorder.raw(t, data)

    def _metadata(self) -> dict:
        return self.spec.session_metadata(None, "tui")

    def _conductor(self) -> Conductor:
        conductor = super()._conductor()
        self.bench.say = conductor.say
        try:
            self.bench.start()
        except BaseException:  # the port or the table would not open: close what did, keep the session
            try:
                self.bench.close()
            finally:
                if self.recorder is not None:
                    self.recorder.end(Status.ERROR, conductor)
            raise
        table = self.config.table
        conductor.say(f"reading {self.spec.device_name} on {self.bench.url} ({self.config.device.protocol}, "
                      f"{self.spec.rate_hz:g} Hz); table: "
                      f"{f'{table.protocol} on {table.port.url}' if table and table.port else 'none'}")
        return conductor

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
        from dataclasses import replace

        telemetry = super().telemetry()
        # Silent only once everything read has been fed: a batch that takes a while to feed (a
        # loaded station) is not a device that stopped.
        silent = self.clock() - self.bench.last_sample_wall
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

    def _stopped_message(self) -> str:
        if self.session_dir is not None:  # a device on a port cannot be rewound to resume
            return "stopped before the end; the session is kept (a live run is not resumed: start again)"
        return super()._stopped_message()
