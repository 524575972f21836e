"""The headless run's bench with the simulated device reached only through bytes.

The simulator serves Xsens MTData2 frames on a pseudo-terminal as fast as they are read, and an
ASCII-protocol rate table on another; the station reads them with pyserial and the protocol
parser, and commands the table with its driver, exactly as with hardware. The automatic
operator's hands still reach into the simulator to carry the fixture.
"""
from __future__ import annotations

import math
import time
from collections import deque

import numpy as np
from scipy.spatial.transform import Rotation

from drivers.sim.serve import SimulatedDevices
from drivers.tables import open_table
from drivers.transport import PortSettings, SerialReader
from fieldcal.run.devices import make_parser
from fieldcal.run.simrun import placed_attitude

_READ_TIMEOUT_S = 30.0


class SerialBench:
    def __init__(self, spec, tap=None):
        """``tap(t, data)`` receives every byte read from the IMU port (the session's raw capture)."""
        self.spec = spec
        noise_seed, operator_seed = np.random.SeedSequence(spec.seed).spawn(2)
        self.rng = np.random.default_rng(operator_seed)
        self.devices = SimulatedDevices(spec.device(), spec.station.gravity, spec.station.latitude_rad,
                                        imu_protocol="xsens", table_protocol="ascii", speed=0,
                                        seed=noise_seed, rate_hz=spec.rate_hz)
        self.parser = make_parser("xsens")
        # The simulator serves as fast as it is read: held to about 2 s of samples ahead of the
        # engine, so a slow (loaded) station does not leave the table's commands minutes behind.
        self.reader = SerialReader(PortSettings(self.devices.imu_url), tap=tap,
                                   max_buffered_bytes=int(2 * spec.rate_hz * 54)).start()
        time.sleep(0.05)  # the port is open (and flushed) before the device starts talking
        self.devices.start()
        assert self.devices.table_url is not None  # (served: table_protocol is given above)
        self.table = open_table("ascii", self.devices.table_url, timeout_s=2.0)
        self.attitude = np.eye(3)
        self._ready: deque = deque()

    def next_chunks(self) -> list:
        return [self.next_chunk()]

    def next_chunk(self):
        deadline = time.monotonic() + _READ_TIMEOUT_S
        while not self._ready:
            for t, data in self.reader.poll():
                chunk = self.parser.feed(data, t)
                if chunk is not None and len(chunk):
                    self._ready.append(chunk)
            if not self._ready:
                if time.monotonic() > deadline:
                    raise TimeoutError(f"no samples from {self.devices.imu_url} for {_READ_TIMEOUT_S:.0f} s")
                time.sleep(0.001)
        return self._ready.popleft()

    def command_table(self, rate_deg_s: float) -> None:
        if rate_deg_s == 0.0:
            self.table.stop()
        else:
            self.table.set_rate(rate_deg_s)

    def _carry(self, target: np.ndarray, seconds: float, shake: float) -> list:
        moved = self.devices.carry(target, seconds, shake)
        chunks = []
        while not moved.done():  # keep reading meanwhile: the device waits for its reader
            chunks.append(self.next_chunk())
        end = moved.result()
        self.attitude = target
        while not chunks or chunks[-1].t[-1] < end - 0.5 / self.spec.rate_hz:
            chunks.append(self.next_chunk())
        return chunks

    def move_to(self, nominal: np.ndarray) -> list:
        target = nominal if self.spec.procedure.aligned else \
            placed_attitude(nominal, self.rng, self.spec.script.placement_sigma_deg)
        return self._carry(target, self.spec.script.handling_s, 0.3)

    def bump(self) -> list:
        nudged = self.attitude @ Rotation.from_rotvec(self.rng.normal(0, math.radians(0.3), 3)).as_matrix()
        return self._carry(nudged, 0.3, 3.0)

    def get_state(self) -> dict:
        return {"serial": True}  # a device on a port cannot be rewound: no resume

    def set_state(self, state: dict) -> None:
        raise ValueError("a run through a serial device cannot be resumed (the device cannot be rewound)")

    def close(self) -> None:
        self.table.close()
        self.reader.close()
        self.devices.stop()
