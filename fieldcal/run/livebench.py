"""A real device on its port and, when the config has one, its rate table.

The operator's hands move the unit; the station reads the port in the background (host stamps,
reconnection, raw-byte tap: ``drivers.transport``) and commands the table with its driver.
"""
from __future__ import annotations

from drivers.tables import open_table
from fieldcal.config import StationConfig
from fieldcal.run.devices import DeviceConnection


class LiveBench:
    def __init__(self, config: StationConfig, tap=None):
        """``tap(t, data)`` receives every byte read from the IMU port (the session's raw capture)."""
        self.config = config
        self.connection = DeviceConnection(config, tap=tap)
        self.table = None
        self.url = config.device.port.url if config.device.port else "(simulated)"

    def start(self) -> LiveBench:
        self.connection.__enter__()
        table = self.config.table
        if table is not None and table.port is not None:
            p = table.port
            self.table = open_table(table.protocol, p.url, timeout_s=2.0, baudrate=p.baudrate,
                                    bytesize=p.bytesize, parity=p.parity, stopbits=p.stopbits)
        return self

    def poll(self):
        """New sample chunks and port events; never blocks."""
        return self.connection.read()

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

    def close(self) -> None:
        try:
            if self.table is not None:
                try:
                    self.table.stop()  # never leave a table turning behind a closed station
                finally:
                    self.table.close()
        finally:
            self.connection.__exit__(None, None, None)
