"""Single-axis rate-table drivers: our ASCII protocol and GRBL v1.1 (rotary table on X).

    table = open_table("grbl", "/dev/ttyUSB0", baudrate=115200)
    table.set_rate(10.0); table.wait_settled(10.0); table.query(); table.stop(); table.close()
"""
from __future__ import annotations

from drivers.tables.ascii import AsciiRateTable
from drivers.tables.base import RateTable, TableError, TableState, TableTimeout
from drivers.tables.grbl import GrblRateTable

PROTOCOLS = {"ascii": AsciiRateTable, "grbl": GrblRateTable}


def open_table(protocol: str, url: str, *, timeout_s: float = 1.0, table_kwargs: dict | None = None,
               **serial_kwargs) -> RateTable:
    """Open ``url`` with ``serial.serial_for_url`` and wrap it in the ``protocol``'s driver.

    ``protocol`` is ``"ascii"`` or ``"grbl"``; ``serial_kwargs`` go to pyserial (``baudrate``
    defaults to 115200); ``table_kwargs`` to the driver (e.g. ``max_rate_deg_s`` for GRBL).
    """
    try:
        cls = PROTOCOLS[protocol.lower()]
    except KeyError:
        raise ValueError(f"unknown table protocol {protocol!r}; known: {sorted(PROTOCOLS)}") from None
    import serial  # only here: the drivers themselves never open ports

    serial_kwargs.setdefault("baudrate", 115200)
    port = serial.serial_for_url(url, timeout=timeout_s, **serial_kwargs)
    try:
        return cls(port, timeout_s=timeout_s, **(table_kwargs or {}))
    except Exception:
        port.close()
        raise


__all__ = [
    "PROTOCOLS",
    "AsciiRateTable",
    "GrblRateTable",
    "RateTable",
    "TableError",
    "TableState",
    "TableTimeout",
    "open_table",
]
