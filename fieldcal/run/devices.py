"""A configured device, connected: its port read in the background, its bytes parsed.

For a ``sim`` device the simulator is started on a pseudo-terminal first and then read exactly
like hardware, so the whole path (pyserial, protocol parser, counters) is the real one.
"""
from __future__ import annotations

import math
import time

from drivers.chunk import SampleChunk
from drivers.transport import PortEvent, PortSettings, SerialReader
from fieldcal.config import StationConfig


def make_parser(protocol: str, channels: dict | None = None):
    """The parser of ``protocol``; delimited text reads ``channels`` (a config's mapping) or,
    without one, the simulated device's layout."""
    from drivers.protocols import ChannelMap
    from drivers.protocols import make_parser as parser_for

    if protocol != "delimited":
        return parser_for(protocol)
    if channels is None:
        from drivers.sim.serve import simulator_channel_map
        cmap = simulator_channel_map()
    else:
        cmap = ChannelMap.from_mapping(channels, "channels")
    return parser_for(protocol, cmap)


class DeviceConnection:
    """Context manager; ``read()`` never blocks and returns new chunks and port events."""

    def __init__(self, config: StationConfig, tap=None):
        self.config = config
        device = config.device
        self.simulated = None
        if device.protocol == "sim":
            from drivers.sim.device import paper_mimu
            from drivers.sim.serve import SimulatedDevices
            sim = device.sim
            assert sim is not None  # (the config gives a simulated device its settings)
            table = config.table.protocol if config.table else None
            self.simulated = SimulatedDevices(
                paper_mimu(raw_counts=sim.raw_counts, flicker_tau_max_s=sim.flicker_tau_max_s), config.station.gravity,
                math.radians(config.station.latitude_deg), imu_protocol=sim.imu_protocol,
                table_protocol=table, speed=sim.speed, seed=sim.seed, rate_hz=device.rate_hz,
                thermal=sim.thermal)
            self.protocol = sim.imu_protocol
            settings = PortSettings(self.simulated.imu_url)
            self.parser = make_parser(self.protocol)
        else:
            self.protocol = device.protocol
            assert device.port is not None  # (the config gives a real device its port)
            settings = device.port
            self.parser = make_parser(self.protocol, device.channels)
        self.arrival_clock = time.monotonic  # what the reader stamps each read's arrival with
        self.reader = SerialReader(settings, tap=tap, clock=self.arrival_clock)

    def __enter__(self) -> DeviceConnection:
        if self.simulated:
            self.simulated.start()
        self.reader.start()
        return self

    def __exit__(self, *exc) -> None:
        self.reader.close()
        if self.simulated:
            self.simulated.stop()

    @property
    def counters(self):
        return self.parser.counters

    def read(self) -> tuple[list[SampleChunk], list[PortEvent]]:
        chunks, events = self.read_stamped()
        return [chunk for _, chunk in chunks], events

    def read_stamped(self) -> tuple[list[tuple[float, SampleChunk]], list[PortEvent]]:
        """``read``, each chunk with the host time its bytes arrived (to order them among the
        port's events: read before or after the port was regained)."""
        chunks = []
        for t, data in self.reader.poll():
            chunk = self.parser.feed(data, t)
            if chunk is not None and len(chunk):
                chunks.append((t, chunk))
        return chunks, self.reader.events()  # after: each event put before bytes polled is in it
