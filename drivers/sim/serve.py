"""The simulated MIMU and rate table as serial devices: real bytes on a pty or TCP port.

One thread runs the physics in blocks of sample time, encodes each block in the chosen wire
protocol and writes it to the IMU link, in real time (or ``speed`` times faster), or as fast as
the station reads (``speed=0``: the link's buffer paces it). Another thread answers the table
protocol; the table's commanded rate drives the simulator's table, and the simulator's table
angle and rate are what the virtual table reports. Device timestamps tell the truth either way.
"""
from __future__ import annotations

import math
import queue
import threading
import time
from concurrent.futures import Future
from dataclasses import dataclass

import numpy as np

from drivers.chunk import SampleChunk
from drivers.sim.physics import MimuSimulator, TriadTruth
from drivers.sim.ports import PtyLink, TcpLink
from drivers.sim.thermal import SimThermal

SIM_TEMPERATURE_C = 25.0


def simulator_channel_map():
    """The column layout the simulated delimited-text device writes."""
    from drivers.protocols.delimited import ChannelMap
    return ChannelMap.from_mapping({
        "delimiter": ",", "time_column": 0, "time_scale": 1.0,
        "triads": {"accelerometer": {"columns": [1, 2, 3], "scale": 1.0, "unit": "m/s^2"},
                   "gyroscope": {"columns": [4, 5, 6], "scale": 1.0, "unit": "rad/s"}},
        "temperature_column": 7}, "simulator")


def make_encoder(protocol: str):
    """The encoder of the simulated device's wire protocol (delimited text in its own layout)."""
    from drivers.protocols import make_encoder as encoder_for
    return encoder_for(protocol, simulator_channel_map() if protocol == "delimited" else None)


def make_virtual_table(protocol: str, motion):
    from drivers.sim.tables import VIRTUAL_TABLES
    if protocol not in VIRTUAL_TABLES:
        raise ValueError(f"table protocol: expected one of {', '.join(VIRTUAL_TABLES)}, got {protocol!r}")
    return VIRTUAL_TABLES[protocol](motion)


def _as_device_sends(chunk: SampleChunk) -> SampleChunk:
    """Add what a real unit sends and the physics does not model (a still magnetometer,
    temperature unless the simulator's thermal profile gives it, pressure), so every protocol's
    frames are complete."""
    n = len(chunk)
    triads = dict(chunk.triads)
    triads.setdefault("magnetometer", np.tile([0.2, 0.0, 0.4], (n, 1)))
    return SampleChunk(t=chunk.t, triads=triads, temperature=chunk.temperature if chunk.temperature is not None
                       else np.full(n, SIM_TEMPERATURE_C),
                       extras={"pressure": np.full(n, 101.325)})


@dataclass(frozen=True)
class TurnOnBias:
    """A MEMS unit's bias repeatability: each switch-on's biases differ from the nominal ones by
    an offset on the input, 1σ per axis ``gyro_deg_s`` (gyroscope) and ``accel_mg``
    (accelerometer); a power cycle draws a new one. 0: the biases repeat exactly."""

    gyro_deg_s: float = 0.0
    accel_mg: float = 0.0

    def __post_init__(self) -> None:
        for name in ("gyro_deg_s", "accel_mg"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"turn-on bias {name}: expected a finite number >= 0, got {value}")

    def switched_on(self, triads: dict[str, TriadTruth], seed) -> dict[str, TriadTruth]:
        """``triads`` with the biases of the switch-on ``seed`` stands for (drawn from its own
        stream, so the samples that follow are the seed's as without a spread)."""
        if not (self.gyro_deg_s or self.accel_mg):
            return triads
        from drivers.sim.realworld import RealWorld, turn_on

        spread = RealWorld(turn_on_bias_deg_s=self.gyro_deg_s, turn_on_bias_mg=self.accel_mg)
        entropy, key = (seed.entropy, seed.spawn_key) if isinstance(seed, np.random.SeedSequence) else (seed, ())
        stream = np.random.SeedSequence(entropy, spawn_key=(*key, TURN_ON_STREAM))
        return turn_on(dict(triads), spread, np.random.default_rng(stream))


TURN_ON_STREAM = 0x7475726E  # "turn": a stream of the seed apart from the noise's
PTY_PIECE = 4000  # bytes: within a pty's 4096-byte input buffer (Linux's N_TTY_BUF_SIZE)


class SimulatedDevices:
    def __init__(self, triads: dict[str, TriadTruth], gravity: float, latitude_rad: float,
                 imu_protocol: str = "xsens", table_protocol: str | None = "ascii",
                 transport: str = "pty", speed: float = 1.0, seed: int | np.random.SeedSequence = 1, rate_hz: float = 250.0,
                 attitude: np.ndarray | None = None, block_s: float = 0.02, on_chunk=None,
                 thermal: SimThermal | None = None, turn_on_bias: TurnOnBias | None = None,
                 waits_for_reader: bool = False):
        """``turn_on_bias``: how far each switch-on's biases fall from ``triads``' (None: not at
        all, the unit's biases repeat exactly, as every simulator before it had them).
        ``waits_for_reader``: the unit goes on only once the station has read what it sent
        (a pty's link; never losing bytes that do not fit), and so its time (``world_time``)
        runs a block or two at most ahead of what the station has read: a test whose station stamps
        its reads with the unit's time sees the same stream at any ``speed``, however loaded
        the host. (A real device waits for nobody.)"""
        from drivers.sim.tables import TableMotion
        if transport not in ("pty", "tcp"):
            raise ValueError(f"transport: expected 'pty' or 'tcp', got {transport!r}")
        if not (math.isfinite(speed) and speed >= 0):
            raise ValueError(f"speed: expected a finite number >= 0 (0 = as fast as read), got {speed}")
        if not (math.isfinite(rate_hz) and rate_hz > 0):
            raise ValueError(f"rate_hz: expected a finite number > 0, got {rate_hz}")
        # A power cycle starts the unit, and so its warm-up, again, with this switch-on's biases
        # (drawn from the seed first, so a seed stands for one switch-on: the same seed, the same
        # biases; the noise that follows is the seed's as before when there is no spread).
        self.turn_on_bias = turn_on_bias or TurnOnBias()
        self._make_simulator = lambda seed: MimuSimulator(
            self.turn_on_bias.switched_on(triads, seed), gravity=gravity, latitude_rad=latitude_rad,
            rate_hz=rate_hz, seed=seed, thermal=thermal)
        self.simulator = self._make_simulator(seed)
        self._make_encoder = lambda: make_encoder(imu_protocol)
        self.encoder = self._make_encoder()
        self._cycles: queue.SimpleQueue = queue.SimpleQueue()  # power cycles asked for, not yet made
        self._delays: queue.SimpleQueue = queue.SimpleQueue()  # late deliveries asked for, not yet begun
        self._time_lock = threading.Lock()
        self._time_before_cycles = 0.0  # sample time run before the last power cycle, s
        # Pieces written by ``_write_read`` (counted before each is written), and how many had
        # been when a stamp (``arrival_time``) last found nothing unread: None until one has.
        self._pieces_written = 0
        self._stamped_pieces: int | None = None
        self.motion = TableMotion()
        self.table = make_virtual_table(table_protocol, self.motion) if table_protocol else None
        link = PtyLink if transport == "pty" else TcpLink
        self.imu_link = link()
        self.table_link = link() if self.table else None
        self.speed = speed
        self.waits_for_reader = waits_for_reader
        self.attitude = np.eye(3) if attitude is None else np.asarray(attitude, dtype=float)
        # Real time: small blocks, like a device's steady trickle. Faster: blocks grow with speed,
        # so the simulator's per-block overhead does not cap the rate (as fast as read: 0.5 s).
        block_s = 0.5 if speed == 0 else min(0.5, block_s * max(1.0, speed))
        self._block = max(1, int(round(block_s * rate_hz)))
        self._stop = threading.Event()
        self._threads = [threading.Thread(target=self._imu_loop, name="sim imu", daemon=True)]
        if self.table:
            self._threads.append(threading.Thread(target=self._table_loop, name="sim table", daemon=True))
        self.samples_sent = 0
        self._on_chunk = on_chunk  # sees every chunk as encoded (tests compare against it)
        self._moves: queue.SimpleQueue = queue.SimpleQueue()

    def carry(self, attitude: np.ndarray, seconds: float, shake: float = 0.3) -> Future:
        """Carry the fixture to a new attitude (after the table has stopped); the future gives
        the sample time of the motion's last sample."""
        done: Future = Future()
        self._moves.put((np.asarray(attitude, dtype=float), seconds, shake, done))
        return done

    def power_cycle(self, seed: int, off_s: float = 0.0) -> Future:
        """The unit switched off and on again with its port left open (a powered adapter, a
        socket, a unit with its own supply): it sends nothing for ``off_s`` of sample time (the
        time it was off and booting; 0: an instant restart), then its clock and packet counter
        start from zero and its turn-on biases are ``seed``'s, drawn from ``turn_on_bias``
        (the simulated table, modelled with the unit, starts again at rest). The future is done
        once it is."""
        if not (math.isfinite(off_s) and off_s >= 0):
            raise ValueError(f"off_s: expected a finite number >= 0, got {off_s}")
        done: Future = Future()
        self._cycles.put((seed, off_s, done))
        return done

    def deliver_late(self, seconds: float, released: threading.Event | None = None) -> Future:
        """The unit runs on, powered, but its bytes reach the port only after ``seconds`` of
        sample time, all at once (a USB adapter's latency, a hub's hiccup): late, none lost.
        ``released``: held, beyond ``seconds``, until that event is set too (a test that must
        see the station notice the silence first: the unit's time goes on meanwhile at
        ``speed``, however long a loaded host takes to look). The future is done once they are
        written."""
        if not (math.isfinite(seconds) and seconds > 0):
            raise ValueError(f"seconds: expected a finite number > 0, got {seconds}")
        if released is not None and self.speed == 0:  # (held samples are made as fast as the CPU can)
            raise ValueError("deliver_late(released=): the unit needs a speed > 0 to run on while held")
        done: Future = Future()
        self._delays.put((seconds, released, done))
        return done

    @property
    def truth(self) -> dict[str, TriadTruth]:
        """The unit's triads as switched on last: their biases are this switch-on's."""
        return dict(self.simulator.triads)

    @property
    def world_time(self) -> float:
        """The sample time run since the devices started, across power cycles, s."""
        with self._time_lock:
            return self._time_before_cycles + self.simulator.time

    def arrival_time(self) -> float:
        """``world_time``, for a station that stamps each read's arrival with the unit's time
        (a test's): called by its reader right after a read. Once it is used (from the first
        stamp on: the first block or two may not wait for theirs), a unit that
        ``waits_for_reader`` goes on only after a stamp was taken with every byte it wrote read,
        so each read that empties the port is stamped with the time of its last sample, however
        late the reader's thread comes to take it: the promptest reads, which a rate from
        arrivals and a stream's continuity go by, lie on the unit's time line. (Going on at
        once, the unit could run a block ahead before the stamp: at 0.2 s blocks a loaded run
        measured 232.8 Hz of a 250 Hz unit over the rate check's 3 s.)"""
        pieces, now = self._pieces_written, self.world_time
        if getattr(self.imu_link, "unread", lambda: 0)() == 0:  # this read took the last byte written
            self._stamped_pieces = pieces
        elif self._stamped_pieces is None:  # the first stamp: from now on the unit waits for them
            self._stamped_pieces = 0
        return now

    @property
    def imu_url(self) -> str:
        return self.imu_link.url

    @property
    def table_url(self) -> str | None:
        return self.table_link.url if self.table_link else None

    def start(self) -> SimulatedDevices:
        for thread in self._threads:
            thread.start()
        return self

    def __enter__(self) -> SimulatedDevices:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def stop(self) -> None:
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout=2.0)
        self.imu_link.close()
        if self.table_link:
            self.table_link.close()

    def _imu_loop(self) -> None:
        started = time.monotonic()
        sim, motion = self.simulator, self.motion
        pending = None
        late_until, release, late = None, None, []  # a delivery held (``deliver_late``): until then, its bytes
        while not self._stop.is_set():
            if not self._cycles.empty():
                seed, off_s, cycled = self._cycles.get()
                if off_s and self.speed > 0:
                    self._stop.wait(off_s / self.speed)  # switched off: the port open, nothing sent
                with self._time_lock:
                    self._time_before_cycles += sim.time + off_s
                    sim = self.simulator = self._make_simulator(seed)
                self.encoder, started = self._make_encoder(), time.monotonic()
                cycled.set_result(None)
            if pending is None and not self._moves.empty():
                pending = self._moves.get()
            with motion.lock:
                target = 0.0 if motion.fault else motion.target_rate_deg_s
                accel = motion.accel_deg_s2 if motion.accel_deg_s2 > 0 else math.inf
            if pending is not None and sim.table_rate == 0.0:
                attitude, seconds, shake, done = pending
                chunk = sim.handle(max(1, int(round(seconds * sim.rate_hz))), self.attitude, attitude, shake)
                self.attitude, pending = attitude, None
                done.set_result(float(chunk.t[-1]))
            else:
                chunk = sim.advance(self._block, self.attitude, math.radians(target), math.radians(accel))
            with motion.lock:
                motion.rate_deg_s = math.degrees(sim.table_rate)
                motion.position_deg = math.degrees(sim.table_angle)
                motion.angle_deg = motion.position_deg % 360.0
            sent = _as_device_sends(chunk)
            if self._on_chunk is not None:
                self._on_chunk(sent)
            data = self.encoder.encode(sent)
            if not self._delays.empty():
                seconds, release, delayed = self._delays.get()
                late_until, late = sim.time + seconds, [delayed]
            if self.speed > 0:
                lag = started + sim.time / self.speed - time.monotonic()
                if lag > 0:
                    self._stop.wait(lag)
            if late_until is not None and (sim.time < late_until or (release is not None and not release.is_set())):
                late.append(data)  # sent, and held on the way
            elif late_until is not None:
                self._write_read(b"".join(late[1:]) + data)  # all of it at once, nothing lost
                late[0].set_result(None)
                late_until, release, late = None, None, []
            elif self.speed > 0 and not self.waits_for_reader:
                # A real device does not wait for a slow host: what does not fit is lost.
                self.imu_link.write(data, timeout_s=0.05)
            else:
                self._write_read(data)
            self.samples_sent += len(chunk)

    def _write_read(self, data: bytes) -> None:
        """Write ``data``; a unit that ``waits_for_reader`` writes it a pty's input buffer at a time
        (PTY_PIECE), each piece once the one before was read (and stamped: ``_until_read``). A
        larger write waits in the kernel for room: a read that took the first 4 KB then saw the
        port empty, and the unit went on before the read that took the rest was stamped."""
        if not self.waits_for_reader:
            self._write_all(data)
            return
        for start in range(0, len(data), PTY_PIECE):
            self._pieces_written += 1  # (before: a stamp of its read must count it)
            self._write_all(data[start:start + PTY_PIECE])
            self._until_read()

    def _write_all(self, data: bytes) -> None:
        written = 0
        while written < len(data) and not self._stop.is_set():
            sent = self.imu_link.write(data[written:], timeout_s=0.1)
            written += sent
            if not sent:  # unplugged: wait for the cable rather than spin
                self._stop.wait(0.05)

    def _until_read(self) -> None:
        """Until the station has read every byte written (``waits_for_reader``) and, once it
        stamps its reads with ``arrival_time``, stamped the read that took the last of them; or
        the devices stop. A pty shows bytes just written to its reader a moment later (the kernel
        pushes them on from a work queue): nothing unread is believed only when seen twice 2 ms
        apart. (No byte is written meanwhile, so the read that empties the port is stamped with
        nothing unread: the wait ends.)"""
        unread = getattr(self.imu_link, "unread", None)
        empty_seen = 0
        while unread is not None and not self._stop.is_set():
            empty_seen = empty_seen + 1 if unread() == 0 else 0
            stamped = self._stamped_pieces
            if empty_seen >= 2 and (stamped is None or stamped >= self._pieces_written):
                return
            self._stop.wait(0.002)

    def _table_loop(self) -> None:
        while not self._stop.is_set():
            data = self.table_link.read(timeout_s=0.05)
            if data:
                reply = self.table.receive(data)
                if reply:
                    self.table_link.write(reply, timeout_s=0.5)
