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

from drivers.tables import TableError
from fieldcal.procedure import events as ev
from fieldcal.procedure.engine import PLACE, WRONG
from fieldcal.tui.source import ABORT, BUMP, FLUSH_S, MISPLACE, QUIT, READY, REDO, SKIP, UNSKIP, SimSource, Sink

NO_SAMPLES_WARN_S = 3.0  # wall time without a sample before the operator is told


class LiveSource(SimSource):
    mode = "live"

    def __init__(self, spec, config, sink: Sink, session_dir: Path | None,
                 clock: Callable[[], float] = time.monotonic):
        from fieldcal.run.livebench import LiveBench

        self.config = config
        bench = LiveBench(config, tap=self._capture_raw)
        super().__init__(spec, sink, 0.0, session_dir, clock, bench=bench)
        self._last_sample_wall = clock()
        self._silent_reported = False
        self._trouble_reported = (0, 0, 0)

    def _capture_raw(self, t: float, data: bytes) -> None:
        """Called on the port's reader thread (the session writer is thread-safe)."""
        session = self.session
        if session is not None and not session.closed:
            session.write_raw("imu", t, data)

    def _run(self) -> None:
        from fieldcal.session.capture import SessionWriter

        if self.session_dir is not None:
            metadata = self.spec.to_metadata()
            metadata["front_end"] = "tui"
            self.session = SessionWriter.create(self.session_dir, metadata)
        try:
            self.bench.start()
            table = self.config.table
            self._note(f"reading {self.spec.device_name} on {self.bench.url} ({self.config.device.protocol}, "
                       f"{self.spec.rate_hz:g} Hz); table: "
                       f"{f'{table.protocol} on {table.port.url}' if table and table.port else 'none'}")
            self._handle(self.engine.start())
            while self.outcome is None and not self.stopping:
                command = self._next_command(wait=False)
                if command is not None:
                    self._do(command)
                    continue
                if not self._read():
                    self._commands_or_sleep()
                self._waiting = self.engine.phase in (PLACE, WRONG)  # on the operator's hands
                self._flush()
        finally:
            self.bench.close()
            if self.session is not None and not self.session.closed:
                self.session.close()

    def _commands_or_sleep(self) -> None:
        """Nothing read: wait briefly for a key instead of spinning."""
        try:
            self._deferred.append(self._commands.get(timeout=min(0.02, FLUSH_S)))
        except queue.Empty:
            pass

    def _read(self) -> bool:
        chunks, port_events = self.bench.poll()
        for pe in port_events:
            detail = f": {pe.message}" if pe.message and pe.message != self.bench.url else ""
            self._note(f"port {self.bench.url}: {pe.kind}{f' after {pe.gap_s:.1f} s' if pe.gap_s else ''}{detail}")
        now = self.clock()
        if chunks:
            self._last_sample_wall, self._silent_reported = now, False
        elif now - self._last_sample_wall > NO_SAMPLES_WARN_S and not self._silent_reported:
            self._silent_reported = True
            self._note(f"WARNING: no samples from {self.bench.url} for {NO_SAMPLES_WARN_S:g} s "
                       "(cable, power, baud rate, or the device's output settings?)")
        self._feed(chunks)
        c = self.bench.counters
        trouble = (c.discarded_bytes, c.checksum_failures, c.missing_frames)
        if trouble != self._trouble_reported:
            self._note(f"parser: {c.discarded_bytes} byte(s) discarded, {c.checksum_failures} checksum "
                       f"failure(s), {c.missing_frames} frame(s) missing so far")
            self._trouble_reported = trouble
        return bool(chunks)

    def _do(self, command: str) -> None:
        e = self.engine
        if command == QUIT:
            self._stop.set()
        elif command == READY and e.phase == PLACE:
            self._note(f"operator: ready, the unit is in position {e.position.id}")
            self._act(ev.READY)
        elif command == READY and e.phase == WRONG:
            self._note(f"waiting for the unit to be still in position {e.position.id}")
        elif command in (READY,):
            self._note("(ready: nothing to do now)")
        elif command in (REDO, SKIP, ABORT, UNSKIP):
            self._note(f"operator: {command}")
            self._act(command)
        elif command in (BUMP, MISPLACE):
            self._note(f"({command}: the simulator's keys; this is a real device)")

    def _stopped(self):
        out = super()._stopped()
        if self.session_dir is not None:  # a device on a port cannot be rewound to resume
            out.message = "stopped before the end; the session is kept (a live run is not resumed: start again)"
        return out

    def _handle(self, events) -> None:
        for e in events:  # one at a time: a table error must not lose the events after it
            try:
                super()._handle([e])
            except (ValueError, TableError) as exc:  # the operator decides what to do
                self._note(f"ERROR: table: {exc}; skip this step (s) or abort (a)")
