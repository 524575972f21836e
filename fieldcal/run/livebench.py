"""A real device on its port and, when the config has one, its rate table.

The operator's hands move the unit; the station reads the port in the background (host stamps,
reconnection, raw-byte tap: ``drivers.transport``) and commands the table with its driver. What
the port does (opened, lost, silent, bytes the parser had to discard) is said in the operator's
log through ``say``.
"""
from __future__ import annotations

import time

from drivers.tables import TableError, open_table
from fieldcal.config import StationConfig
from fieldcal.run.devices import DeviceConnection


class LiveBench:
    # A table that refuses a command is the operator's to deal with (skip the step or abort).
    recoverable_errors = (ValueError, TableError)

    def __init__(self, config: StationConfig, tap=None, clock=time.monotonic, silence_s: float = 3.0):
        """``tap(t, data)`` receives every byte read from the IMU port (the session's raw capture);
        ``silence_s`` of wall time without a sample is reported once."""
        self.config = config
        self.connection = DeviceConnection(config, tap=tap)
        self.table = None
        self.url = config.device.port.url if config.device.port else "(simulated)"
        self.say = lambda text: None
        self.clock = clock
        self.silence_s = silence_s
        self._last_sample_wall = clock()
        self._silent_reported = False
        self._trouble_reported = (0, 0, 0)

    def start(self) -> LiveBench:
        self.connection.__enter__()
        self._last_sample_wall = self.clock()
        table = self.config.table
        if table is not None and table.port is not None:
            p = table.port
            self.table = open_table(table.protocol, p.url, timeout_s=2.0, baudrate=p.baudrate,
                                    bytesize=p.bytesize, parity=p.parity, stopbits=p.stopbits)
        return self

    def poll(self):
        """New sample chunks and port events; never blocks."""
        return self.connection.read()

    def next_chunks(self) -> list:
        """The chunks read since last asked (never blocks), saying what the port and parser did."""
        chunks, port_events = self.poll()
        for pe in port_events:
            detail = f": {pe.message}" if pe.message and pe.message != self.url else ""
            self.say(f"port {self.url}: {pe.kind}{f' after {pe.gap_s:.1f} s' if pe.gap_s else ''}{detail}")
        now = self.clock()
        if chunks:
            self._last_sample_wall, self._silent_reported = now, False
        elif now - self._last_sample_wall > self.silence_s and not self._silent_reported:
            self._silent_reported = True
            self.say(f"WARNING: no samples from {self.url} for {self.silence_s:g} s "
                     "(cable, power, baud rate, or the device's output settings?)")
        c = self.counters
        trouble = (c.discarded_bytes, c.checksum_failures, c.missing_frames)
        if trouble != self._trouble_reported:
            self.say(f"parser: {c.discarded_bytes} byte(s) discarded, {c.checksum_failures} checksum "
                     f"failure(s), {c.missing_frames} frame(s) missing so far")
            self._trouble_reported = trouble
        return list(chunks)

    @property
    def last_sample_wall(self) -> float:
        """The wall time (``clock``) at which samples last came (or the port was opened)."""
        return self._last_sample_wall

    @property
    def counters(self):
        return self.connection.counters

    def command_table(self, rate_deg_s: float) -> None:
        if self.table is None:
            raise ValueError("the procedure asks for a table rate, and the config has no table")
        if rate_deg_s == 0.0:
            self.table.stop()
        else:
            self.table.set_rate(rate_deg_s)

    def get_state(self) -> dict:
        return {"live": True}  # a device on a port cannot be rewound: no resume

    def set_state(self, state: dict) -> None:
        raise ValueError("a live run cannot be resumed (the device cannot be rewound): start again")

    def close(self) -> None:
        """Stop the table and close both ports; a port already gone (unplugged, its far end
        closed) is said in the log, never raised, so quitting after a lost device is clean."""
        try:
            if self.table is not None:
                try:
                    self.table.stop()  # never leave a table turning behind a closed station
                except Exception as exc:  # noqa: BLE001 -- the port is gone: say so, close the rest
                    self.say(f"WARNING: could not stop the table ({type(exc).__name__}: {exc}); "
                             "check that it is not turning")
                finally:
                    try:
                        self.table.close()
                    except Exception as exc:  # noqa: BLE001
                        self.say(f"table port: closing it failed ({type(exc).__name__}: {exc})")
        finally:
            try:
                self.connection.__exit__(None, None, None)
            except Exception as exc:  # noqa: BLE001
                self.say(f"port {self.url}: closing it failed ({type(exc).__name__}: {exc})")
