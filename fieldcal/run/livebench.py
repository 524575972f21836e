"""A real device on its port and, when the config has one, its rate table.

The operator's hands move the unit; the station reads the port in the background (host stamps,
reconnection, raw-byte tap: ``drivers.transport``) and commands the table with its driver. What
the port does (opened, lost, silent, bytes the parser had to discard) is said in the operator's
log through ``say``.
"""
from __future__ import annotations

import time

from drivers.tables import RateTable, TableError, open_table
from drivers.transport import PORT_REGAINED
from fieldcal.config import StationConfig
from fieldcal.run.deviceclock import ClocklessStream, DeviceClock, clock_of, judge_restart, went_back
from fieldcal.run.devices import DeviceConnection


class LiveBench:
    # A table that refuses a command is the operator's to deal with (skip the step or abort).
    recoverable_errors = (ValueError, TableError)

    def __init__(self, config: StationConfig, tap=None, clock=time.monotonic, silence_s: float = 3.0,
                 wall_clock=time.time, silence_clock=None):
        """``tap(t, data)`` receives every byte read from the IMU port (the session's raw capture);
        ``silence_s`` without a sample is reported once, measured by ``silence_clock`` (default:
        ``clock``, the host's time; a test serving a simulated unit passes the unit's own time, so
        that the silence said is the unit's whatever the load on the host). ``wall_clock``: the
        host's Unix time, recorded beside the device's own clock (``device_clock``)."""
        self.config = config
        self.connection = DeviceConnection(config, tap=tap)
        self.table: RateTable | None = None
        self.url = config.device.port.url if config.device.port else "(simulated)"
        self.say = lambda text: None
        self.clock = clock
        self.silence_clock = clock if silence_clock is None else silence_clock
        self.silence_s = silence_s
        self._last_sample_wall = self.silence_clock()
        self._silent_reported = False
        self._trouble_reported = (0, 0, 0)
        self.wall_clock = wall_clock
        self.device_clock: DeviceClock | None = None  # the device's clock as last read
        self.recorded_clock: DeviceClock | None = None  # set_state's: the last completed step's
        self._pending: list = []  # (arrival, chunk) read and not yet handed out (first_clock, a regain)
        self._pending_events: list = []  # and the port's events meanwhile
        self._regained_at: float | None = None  # the port came back then; its first frames not yet read
        self.regain_check = None  # what the device's clock said when it may have restarted (ClockCheck)
        self.judged_port = ""  # what its port did meanwhile: "was lost", "stayed open"
        self._fed_clock: DeviceClock | None = None  # the device's clock in the last chunk handed out
        # A device whose frames carry no clock: its data's continuity since the port was opened
        # (or came back), and whether reads wait for its judgement (``_until_stream_broke``).
        self._stream: ClocklessStream | None = None
        self._stream_waiting = False

    def start(self) -> LiveBench:
        self.connection.__enter__()
        self._last_sample_wall = self.silence_clock()
        table = self.config.table
        if table is not None and table.port is not None:
            p = table.port
            self.table = open_table(table.protocol, p.url, timeout_s=2.0, baudrate=p.baudrate,
                                    bytesize=p.bytesize, parity=p.parity, stopbits=p.stopbits)
        return self

    def next_chunks(self) -> list:
        """The chunks read since last asked (never blocks), saying what the port and parser did.

        The device's clock is judged against the frames before (``judge_restart``: did the unit
        restart, i.e. was it power-cycled?) into ``regain_check`` where it may have: when the port
        comes back after it was lost (the first frames after it against the last before), and on
        every chunk read while it stays open (a unit on a powered adapter, a socket, its own
        supply restarts without the port noticing). The frames from the judged one on are handed
        out only on the next call, so that the operator can act on the judgement
        (``take_regain_check``) before they are fed."""
        fresh, port_events = self.connection.read_stamped()
        if self._pending_events:
            port_events, self._pending_events = self._pending_events + list(port_events), []
        for pe in port_events:
            if pe.kind == PORT_REGAINED and self._regained_at is None:
                self._regained_at = pe.t
                self._stream, self._stream_waiting = None, False  # (the loss is judged as such)
        held, self._pending = self._pending, []  # (first_clock's, or those after a judgement)
        stamped = held + fresh
        if self._regained_at is not None:
            # first_clock's frames too: those read after the regain wait for its judgement
            after = [(t, c) for t, c in stamped if t >= self._regained_at]
            stamped = [(t, c) for t, c in stamped if t < self._regained_at]
            if after:
                lost_at = self._clock_at(*stamped[-1]) if stamped else self._fed_clock
                if lost_at is not None:  # (none handed out yet: a resume judges the first frames)
                    self._judged(judge_restart(lost_at, self._clock_at(*after[0]), self.config.device.rate_hz),
                                 "was lost")
                self._regained_at, self._pending = None, after
        elif self._clockless(held + fresh):
            stamped = self._until_stream_broke(held, fresh)
        else:
            stamped = held + self._until_restart(self._clock_at(*held[-1]) if held else self._fed_clock, fresh)
        chunks = [c for _, c in stamped]
        if stamped:
            self.device_clock = self._fed_clock = self._clock_at(*stamped[-1])
        for pe in port_events:
            detail = f": {pe.message}" if pe.message and pe.message != self.url else ""
            self.say(f"port {self.url}: {pe.kind}{f' after {pe.gap_s:.1f} s' if pe.gap_s else ''}{detail}")
        now = self.silence_clock()
        if chunks or self._pending:  # (frames held back after a regain came too: not a silence)
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
        return chunks

    def _until_restart(self, before: DeviceClock | None, stamped: list) -> list:
        """``stamped`` up to the first chunk whose device clock went back against the one before
        it (``went_back``; ``before``: the last chunk's before them), judged into ``regain_check``;
        that chunk and the rest are held for the next call. All of them if none did, or one is
        already being judged."""
        for i, (arrival, chunk) in enumerate(stamped):
            now = self._clock_at(arrival, chunk)
            if before is not None and self.regain_check is None:
                check = went_back(before, now, self.config.device.rate_hz)
                if check is not None:
                    self._judged(check, "stayed open")
                    self._pending = stamped[i:]
                    return stamped[:i]
            before = now
        return stamped

    def _clockless(self, stamped: list) -> bool:
        """Do the device's frames carry no clock (no time, no packet counter), and has it a rate
        in host time (not a simulator served as fast as it is read)?"""
        clock = self._clock_at(*stamped[-1]) if stamped else self._fed_clock
        return clock is not None and clock.time_s is None and clock.counter is None and self._host_speed() > 0

    def _host_speed(self) -> float:
        """The device's sample time per host time: a simulator's speed, else 1."""
        device = self.config.device
        return device.sim.speed if device.protocol == "sim" and device.sim is not None else 1.0

    def _until_stream_broke(self, held: list, fresh: list) -> list:
        """``_until_restart`` for a device whose frames carry no clock, by its data's continuity
        (``ClocklessStream``): from a read after a gap in its stream on, the reads are held until
        it is judged; those before a break are handed out, the break judged into
        ``regain_check`` (cannot tell), and the rest held for the next call."""
        if self._stream is None:
            self._stream = ClocklessStream(self.config.device.rate_hz * self._host_speed())
        out, waiting = ([], list(held)) if self._stream_waiting else (list(held), [])
        for i, (arrival, chunk) in enumerate(fresh):
            verdict = self._stream.read(arrival, len(chunk))
            if verdict == "go":
                out, waiting = out + waiting + [(arrival, chunk)], []
            elif verdict == "wait":
                waiting.append((arrival, chunk))
            else:
                if self.regain_check is None:
                    self._judged(verdict, "stayed open")
                for later, c in fresh[i + 1:]:  # (counted: the stream goes on from the break)
                    self._stream.read(later, len(c))
                self._pending, self._stream_waiting = waiting + fresh[i:], False
                return out
        self._pending, self._stream_waiting = waiting, bool(waiting)
        return out

    def _judged(self, check, port: str) -> None:
        self.regain_check, self.judged_port = check, port

    def take_regain_check(self):
        """The judgement of the device's clock when its port came back (``ClockCheck``), once;
        None if there is none new."""
        check, self.regain_check = self.regain_check, None
        return check

    def _clock_at(self, arrival: float, chunk) -> DeviceClock:
        """The device's clock in ``chunk``, with the host's wall time when its bytes arrived."""
        age = max(0.0, self.connection.arrival_clock() - arrival)
        return clock_of(chunk, self.connection.parser, self.wall_clock() - age)

    def first_clock(self, timeout_s: float, cancelled=lambda: False, fresh_s: float = 1.0) -> DeviceClock | None:
        """Wait (up to ``timeout_s`` of wall time) for the first frames and return the device's
        clock in the newest of them; the chunks are kept for ``next_chunks``. None if nothing came.

        The first frames read may have waited in the port's buffer since the run was quit; the
        frames read over ``fresh_s`` after them are as new as the port delivers."""
        deadline, fresh_until = self.clock() + timeout_s, None
        while not cancelled():
            now = self.clock()
            if (fresh_until is not None and now >= fresh_until) or (fresh_until is None and now >= deadline):
                break
            stamped, port_events = self.connection.read_stamped()
            self._pending_events += list(port_events)  # said by next_chunks, in the run's log
            if stamped:
                self._pending += stamped
                self.device_clock = self._clock_at(*stamped[-1])
                fresh_until = fresh_until if fresh_until is not None else now + fresh_s
            else:
                time.sleep(0.02)  # the port's reader thread fills its queue meanwhile
        return self.device_clock if self._pending else None

    def measure_rate(self, timeout_s: float, nominal_hz: float, cancelled=lambda: False):
        """The device's sample rate from its first frames (``fieldcal.run.ratecheck``) and the
        rate expected of it in that measure (``nominal_hz``, the rate the engine counts samples
        at; a simulator's times its speed in host time): (MeasuredRate, expected Hz), or None when nothing
        came within ``timeout_s`` of wall time (or cancelled), or a simulator served as fast
        as it is read has no rate in host time. The frames read are kept for ``next_chunks``."""
        import numpy as np

        from fieldcal.run.ratecheck import (MEASURE_S, SETTLE_S, MeasuredRate, rate_from_arrivals,
                                            rate_from_device_time)

        device = self.config.device
        speed = device.sim.speed if device.protocol == "sim" and device.sim is not None else None
        reads: list = []  # (arrival, chunk) read here
        deadline = self.clock() + timeout_s
        while not cancelled():
            stamped, port_events = self.connection.read_stamped()
            self._pending_events += list(port_events)  # said by next_chunks, in the run's log
            self._pending += stamped
            reads += stamped
            if stamped:
                self.device_clock = self._clock_at(*stamped[-1])
            # (a parser knows whether its frames carry the device's time once it has read some)
            device_time = self._pending and getattr(self.connection.parser, "device_time", False)
            if device_time:
                rate = rate_from_device_time(np.concatenate([c.t for _, c in self._pending]))
                if rate is not None:
                    return MeasuredRate(rate, "from the device's clock"), nominal_hz
            elif speed == 0 and reads:
                return None  # a simulator served as fast as it is read: no rate in host time
            elif reads:
                expected = nominal_hz * (speed if speed is not None else 1.0)
                settled = [(a, len(c)) for a, c in reads if a >= reads[0][0] + SETTLE_S]
                if len(settled) > 1 and settled[-1][0] - settled[0][0] >= MEASURE_S:
                    arrivals, counts = zip(*settled)
                    rate = rate_from_arrivals(np.array(arrivals), np.array(counts))
                    if rate is not None:  # None: no read arrived after the first (a frozen host clock)
                        span = arrivals[-1] - arrivals[0]
                        return MeasuredRate(rate, f"from the host's arrival times over {span:.1f} s"), expected
            if self.clock() >= deadline:
                break
            if not stamped:
                time.sleep(0.02)  # the port's reader thread fills its queue meanwhile
        return None

    @property
    def last_sample_wall(self) -> float:
        """The time (``silence_clock``) at which samples last came (or the port was opened)."""
        return self._last_sample_wall

    @property
    def counters(self):
        return self.connection.counters

    def command_table(self, rate_deg_s: float) -> None:
        if self.table is None:
            raise ValueError("the procedure asks for a table rate, and the config has no table")
        try:
            if rate_deg_s == 0.0:
                self.table.stop()
            else:
                self.table.set_rate(rate_deg_s)
        except OSError as exc:  # its port is gone (unplugged, powered off; drivers.tables says so as an OSError)
            table = self.config.table
            assert table is not None and table.port is not None  # (self.table was opened on it)
            raise TableError(f"its port {table.port.url} failed ({exc}): is the table "
                             "plugged in and powered?") from exc

    def get_state(self) -> dict:
        """What a resumed run needs of a live bench: not its samples (a device cannot be rewound)
        but its clock, to tell whether it was power-cycled meanwhile."""
        state: dict[str, object] = {"live": True}
        if self.device_clock is not None:
            state["device_clock"] = self.device_clock.to_dict()
        return state

    def set_state(self, state: dict) -> None:
        """The last completed step's state: its device clock, for ``first_clock`` to compare."""
        self.recorded_clock = DeviceClock.from_dict(state.get("device_clock"))

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
