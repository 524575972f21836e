"""Serial transport: any pyserial URL, read on a background thread, survives a pulled cable.

The caller never blocks: ``poll()`` returns what arrived since the last call, each read stamped
with the host's monotonic clock on arrival. Every byte also goes to an optional tap (for session
capture). When the port fails (cable pulled, pty closed, TCP peer gone) the reader reports it,
retries with exponential backoff, and resumes on the same URL; what was read before is kept, and
the gap is reported as an event, not hidden.
"""
from __future__ import annotations

import os
import queue
import threading
import time
from dataclasses import dataclass, field
from typing import Callable

import serial

PORT_LOST, PORT_OPENED, PORT_REGAINED, PORT_CLOSED = "lost", "opened", "regained", "closed"
TAP_FAILED = "tap failed"  # the raw-byte capture raised: reported once, reading goes on


@dataclass(frozen=True)
class PortSettings:
    url: str
    baudrate: int = 115200
    bytesize: int = 8
    parity: str = "N"
    stopbits: float = 1
    read_timeout_s: float = 0.05  # how long one read may block the reader thread

    def open(self) -> serial.SerialBase:
        return serial.serial_for_url(self.url, baudrate=self.baudrate, bytesize=self.bytesize,
                                     parity=self.parity, stopbits=self.stopbits,
                                     timeout=self.read_timeout_s, write_timeout=1.0)


def open_failure(exc: Exception) -> str:
    """Why a port did not open, once: pyserial's text repeats the errno and the path
    ("[Errno 2] could not open port X: [Errno 2] No such file or directory: 'X'")."""
    code = getattr(exc, "errno", None)
    if isinstance(code, int):
        return os.strerror(code)
    return str(exc).splitlines()[0] if str(exc) else type(exc).__name__


@dataclass(frozen=True)
class PortEvent:
    kind: str  # PORT_OPENED, PORT_LOST, PORT_REGAINED, PORT_CLOSED
    t: float  # host monotonic time, s
    message: str = ""
    gap_s: float = 0.0  # for PORT_REGAINED: how long the port was gone


@dataclass
class _Backoff:
    first_s: float = 0.05
    max_s: float = 2.0
    current: float = field(default=0.0)

    def next(self) -> float:
        self.current = self.first_s if self.current == 0 else min(2 * self.current, self.max_s)
        return self.current

    def reset(self) -> None:
        self.current = 0.0


READ_BLOCK = 65536  # the most one read takes


def read_available(port: serial.SerialBase) -> bytes:
    """What the port has, in one call: waiting up to its timeout for the first byte, then all that
    has come with it (a frame that was arriving is one read, not its first byte and the rest).
    pyserial's ``socket://`` says only whether anything waits (``in_waiting`` 0 or 1), so there a
    non-blocking read of a large block takes the rest (its timeout change costs nothing: a socket
    has no line settings to apply)."""
    waiting = getattr(port, "in_waiting", 0) or 0
    data = port.read(max(1, waiting))
    if not data or waiting > 1:
        return data
    if type(port).__module__.endswith("protocol_socket"):
        timeout = port.timeout
        port.timeout = 0
        try:
            return data + port.read(READ_BLOCK)
        finally:
            port.timeout = timeout
    more = getattr(port, "in_waiting", 0) or 0  # exact on a serial port or a pty: no waiting
    return data + port.read(more) if more else data


def _drain(q: queue.SimpleQueue) -> list:
    out = []
    while True:
        try:
            out.append(q.get_nowait())
        except queue.Empty:
            return out


class SerialReader:
    """Reads one port on a daemon thread; ``poll()``, ``events()`` and ``write()`` never block long."""

    def __init__(self, settings: PortSettings, tap: Callable[[float, bytes], None] | None = None,
                 opener: Callable[[PortSettings], serial.SerialBase] = PortSettings.open,
                 clock: Callable[[], float] = time.monotonic, max_backoff_s: float = 2.0,
                 max_buffered_bytes: int | None = None):
        """``max_buffered_bytes``: stop reading while this much is read and not yet polled, so a
        device that waits for its reader (a simulator serving as fast as it is read) cannot run
        ahead of the station; None for a real device, which never waits (what it sends is read)."""
        self.settings = settings
        self._max_buffered = max_buffered_bytes
        self._buffered = 0
        self._room = threading.Condition()
        self._tap = tap
        self._opener = opener
        self._clock = clock
        self._data: queue.SimpleQueue[tuple[float, bytes]] = queue.SimpleQueue()
        self._events: queue.SimpleQueue[PortEvent] = queue.SimpleQueue()
        self._stop = threading.Event()
        self._port: serial.SerialBase | None = None
        self._port_lock = threading.Lock()
        self._backoff = _Backoff(max_s=max_backoff_s)
        self._thread = threading.Thread(target=self._run, name=f"reader {settings.url}", daemon=True)
        self.bytes_read = 0

    def start(self) -> SerialReader:
        self._thread.start()
        return self

    def __enter__(self) -> SerialReader:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def retry_s(self) -> float:
        """The longest wait between attempts to open the port."""
        return self._backoff.max_s

    @property
    def connected(self) -> bool:
        return self._port is not None

    def poll(self) -> list[tuple[float, bytes]]:
        """Everything read since the last call: (arrival time, bytes) in arrival order."""
        items = _drain(self._data)
        if self._max_buffered is not None and items:
            with self._room:
                self._buffered -= sum(len(data) for _, data in items)
                self._room.notify_all()
        return items

    def events(self) -> list[PortEvent]:
        return _drain(self._events)

    def write(self, data: bytes) -> bool:
        """Send bytes if the port is up; False (nothing sent) while it is down."""
        with self._port_lock:
            port = self._port
            if port is None:
                return False
            try:
                port.write(data)
                return True
            except (serial.SerialException, OSError):
                return False

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)
        self._drop_port()
        self._events.put(PortEvent(PORT_CLOSED, self._clock(), self.settings.url))

    def _drop_port(self) -> None:
        with self._port_lock:
            port, self._port = self._port, None
        if port is not None:
            try:
                port.close()
            except (serial.SerialException, OSError):
                pass

    def _open(self, lost_at: float | None) -> bool:
        try:
            port = self._opener(self.settings)
        except (serial.SerialException, OSError, ValueError) as exc:
            if lost_at is None and self._backoff.current == 0:
                self._events.put(PortEvent(PORT_LOST, self._clock(),
                                           f"cannot open {self.settings.url}: {open_failure(exc)}"))
            return False
        with self._port_lock:
            self._port = port
        now = self._clock()
        if lost_at is None:
            self._events.put(PortEvent(PORT_OPENED, now, self.settings.url))
        else:
            self._events.put(PortEvent(PORT_REGAINED, now, self.settings.url, gap_s=now - lost_at))
        self._backoff.reset()
        return True

    def _run(self) -> None:
        lost_at: float | None = None
        first = True
        while not self._stop.is_set():
            if self._port is None:
                if self._open(None if first else lost_at):
                    first, lost_at = False, None
                else:
                    self._stop.wait(self._backoff.next())
                    continue
            if self._max_buffered is not None:
                with self._room:  # back-pressure: the device waits while the station catches up
                    while self._buffered >= self._max_buffered and not self._stop.is_set():
                        self._room.wait(0.05)
            try:
                port = self._port
                data = read_available(port)
            except (serial.SerialException, OSError, TypeError, AttributeError) as exc:
                # TypeError/AttributeError: pyserial's posix read on an fd closed under it.
                if self._stop.is_set():
                    break
                lost_at = self._clock()
                self._events.put(PortEvent(PORT_LOST, lost_at, f"{self.settings.url}: {exc}"))
                self._drop_port()
                first = False
                continue
            if data:
                t = self._clock()
                self.bytes_read += len(data)
                if self._max_buffered is not None:
                    with self._room:
                        self._buffered += len(data)
                self._data.put((t, data))
                if self._tap is not None:
                    try:
                        self._tap(t, data)
                    except Exception as exc:  # noqa: BLE001 -- e.g. disk full in the capture
                        self._tap = None
                        self._events.put(PortEvent(TAP_FAILED, t, f"raw capture stopped: {exc}"))
