"""Device ends of virtual serial links: a pseudo-terminal pair, or a TCP socket on 127.0.0.1.

The station opens ``url`` with pyserial exactly as it would a real port. ``unplug()`` and
``replug()`` simulate a pulled cable: the pty's device end is closed and its stable symlink
removed, and a new pair is created behind the same symlink (as udev's /dev/serial/by-id links behave), or the TCP
connection is dropped and the listener keeps the same port number.
"""
from __future__ import annotations

import os
import select
import socket
import tempfile
import threading
import time
import tty
from pathlib import Path


class PtyLink:
    def __init__(self, link: str | os.PathLike | None = None):
        self._own_dir = link is None  # a temporary directory of ours, removed on close
        if link is None:
            link = Path(tempfile.mkdtemp(prefix="fieldcal-")) / "tty"
        self.link = Path(link)
        self._lock = threading.Lock()
        self._master: int | None = None
        self._slave: int | None = None
        self.replug()

    @property
    def url(self) -> str:
        return str(self.link)

    def replug(self) -> None:
        master, slave = os.openpty()
        tty.setraw(master)  # no echo, no newline translation on the device side
        tty.setraw(slave)
        os.set_blocking(master, False)  # (``write``: a blocking write waits past any timeout)
        tmp = self.link.with_name(self.link.name + ".new")
        if tmp.is_symlink() or tmp.exists():
            tmp.unlink()
        tmp.symlink_to(os.ttyname(slave))
        os.replace(tmp, self.link)
        with self._lock:
            self._master = master
            # Keep the slave open here too, so the device side never sees EIO before the station
            # has opened the port.
            self._slave = slave

    def unplug(self) -> None:
        with self._lock:
            fds = [fd for fd in (self._master, self._slave) if fd is not None]
            self._master = self._slave = None
        # The link goes with the device, as udev's by-id link does: left pointing at the closed
        # /dev/pts/N, a station retrying would open whichever process's pty takes that number next.
        if self.link.is_symlink():
            self.link.unlink()
        for fd in fds:
            os.close(fd)

    def write(self, data: bytes, timeout_s: float = 1.0) -> int:
        """Write what the station takes, giving up once it has taken nothing for ``timeout_s``
        (it may be slow, or absent: its port closed, or not read); bytes written. The device
        end does not block: a blocking write of more than the room left waited, past any
        timeout, until the station read it all, and a station that had quit never did (the
        device's thread then held up its ``stop`` until the join's timeout, 2 s a device)."""
        with self._lock:
            fd = self._master
        if fd is None:
            return 0
        written = 0
        view = memoryview(data)
        taken_by = time.monotonic() + timeout_s  # the station's next bytes, or it takes no more
        while written < len(data) and time.monotonic() < taken_by:
            try:
                _, ready, _ = select.select([], [fd], [], max(0.0, taken_by - time.monotonic()))
                if not ready:
                    break
                written += os.write(fd, view[written:])  # what fits now
                taken_by = time.monotonic() + timeout_s
            except BlockingIOError:  # writable, yet no room for what is written at once
                time.sleep(0.001)
            except OSError:
                break
        return written

    def unread(self) -> int:
        """Bytes written and not yet read by the station (0 while unplugged)."""
        import fcntl
        import struct
        import termios

        with self._lock:
            fd = self._slave  # (its input queue is what the station has not read)
            if fd is None:
                return 0
            try:
                return struct.unpack("i", fcntl.ioctl(fd, termios.FIONREAD, b"\0\0\0\0"))[0]
            except OSError:
                return 0

    def read(self, timeout_s: float = 0.05) -> bytes:
        with self._lock:
            fd = self._master
        if fd is None:
            return b""
        try:
            ready, _, _ = select.select([fd], [], [], timeout_s)
            return os.read(fd, 4096) if ready else b""
        except OSError:
            return b""

    def close(self) -> None:
        self.unplug()
        if self.link.is_symlink():
            self.link.unlink()
        if self._own_dir:
            try:
                self.link.parent.rmdir()
            except OSError:
                pass


class TcpLink:
    """Listens on 127.0.0.1; one station connection at a time.

    ``unplug()`` is a pulled cable: the connection drops and the port refuses connections until
    ``replug()`` listens again on the same port number (so the gap does not depend on how fast
    the station retries).
    """

    def __init__(self, port: int = 0):
        self._lock = threading.Lock()
        self._client: socket.socket | None = None
        self._server: socket.socket | None = None
        self._closed = False
        self.port = port
        self.replug()

    @property
    def url(self) -> str:
        return f"socket://127.0.0.1:{self.port}"

    def _accept_loop(self, server: socket.socket) -> None:
        while not self._closed:
            try:
                client, _ = server.accept()
            except OSError:
                return
            client.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            with self._lock:
                if server is not self._server:  # unplugged meanwhile
                    client.close()
                    return
                old, self._client = self._client, client
            if old is not None:
                old.close()

    def connected(self) -> bool:
        return self._client is not None

    def _drop_client(self) -> None:
        with self._lock:
            client, self._client = self._client, None
        if client is not None:
            client.close()

    def unplug(self) -> None:
        with self._lock:
            server, self._server = self._server, None
        if server is not None:
            try:  # wakes the acceptor blocked in accept() (Linux), so the port is free at once
                server.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            server.close()
        self._drop_client()

    def replug(self) -> None:
        with self._lock:
            if self._server is not None or self._closed:
                return
            self._server = server = socket.create_server(("127.0.0.1", self.port))
            self.port = server.getsockname()[1]
        threading.Thread(target=self._accept_loop, args=(server,), daemon=True).start()

    def write(self, data: bytes, timeout_s: float = 1.0) -> int:
        with self._lock:
            client = self._client
        if client is None:
            return 0
        try:
            client.settimeout(timeout_s)
            client.sendall(data)
            return len(data)
        except OSError:
            self._drop_client()
            return 0

    def read(self, timeout_s: float = 0.05) -> bytes:
        with self._lock:
            client = self._client
        if client is None:
            return b""
        try:
            ready, _, _ = select.select([client], [], [], timeout_s)
            if not ready:
                return b""
            data = client.recv(4096)
            if not data:
                self._drop_client()
            return data
        except OSError:
            return b""

    def close(self) -> None:
        self._closed = True
        self.unplug()
