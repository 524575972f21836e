"""Test helpers for drivers, shipped with them as PyMeasure ships ``pymeasure.test``.

``expected_protocol(Driver, [(sent, reply), (None, unsolicited)])`` checks that a driver writes
exactly the expected bytes, in order, answers with the scripted replies, and that the script is
used up: the protocol document, not the code, is the truth of such a test.

    from drivers.testing import expected_protocol
    with expected_protocol(AsciiRateTable, [(b"ID?\n", b"ID FCT-1 1.0.0\r\n")]) as table:
        assert table.identify() == "FCT-1 1.0.0"
"""
from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager


class FakePort:
    """Asserts the driver writes exactly the expected bytes, in order, and plays the replies.

    ``pairs``: ``(sent, reply)`` — after the driver wrote ``sent`` (in one or several writes),
    ``reply`` becomes readable; ``(None, unsolicited)`` — readable as soon as the exchange
    before it completed (at once, if first). Reading past the available bytes returns what there
    is, as pyserial does when its timeout expires.
    """

    def __init__(self, pairs):
        self.pairs = list(pairs)
        self.index = 0
        self.pending = bytearray()  # written, not yet matched
        self.rx = bytearray()
        self.timeout = None
        self.closed = False
        self.reads = 0  # read calls (read_until counts once): a timeout must not be retried
        self._queue_unsolicited()

    def _queue_unsolicited(self):
        while self.index < len(self.pairs) and self.pairs[self.index][0] is None:
            self.rx += self.pairs[self.index][1]
            self.index += 1

    def write(self, data: bytes) -> int:
        assert isinstance(data, (bytes, bytearray)), f"write() got {type(data).__name__}"
        self.pending += data
        while self.pending:
            if self.index >= len(self.pairs):
                raise AssertionError(f"driver wrote {bytes(self.pending)!r}; "
                                     f"no more exchanges expected")
            sent, reply = self.pairs[self.index]
            n = min(len(self.pending), len(sent))
            if self.pending[:n] != sent[:n]:
                raise AssertionError(f"exchange {self.index}: driver wrote "
                                     f"{bytes(self.pending)!r}, expected {sent!r}")
            if len(self.pending) < len(sent):
                break
            del self.pending[:len(sent)]
            self.rx += reply or b""
            self.index += 1
            self._queue_unsolicited()
        return len(data)

    def read(self, size: int = 1) -> bytes:
        self.reads += 1
        out = bytes(self.rx[:size])
        del self.rx[:size]
        return out

    def read_until(self, expected: bytes = b"\n", size: int | None = None) -> bytes:
        i = self.rx.find(expected)
        n = len(self.rx) if i < 0 else i + len(expected)
        if size is not None:
            n = min(n, size)
        return self.read(n)

    def flush(self):
        pass

    def reset_input_buffer(self):
        self.rx.clear()

    def close(self):
        self.closed = True

    def check_done(self):
        assert not self.pending, f"driver wrote {bytes(self.pending)!r} beyond the script"
        assert self.index == len(self.pairs), \
            f"exchange {self.index} never happened: {self.pairs[self.index]!r}"
        assert not self.rx, f"driver left {bytes(self.rx)!r} unread"


@contextmanager
def expected_protocol(driver_factory: Callable, pairs: Sequence[tuple[bytes | None, bytes]]) -> Iterator:
    """``with expected_protocol(Driver, [(sent, reply), (None, unsolicited)]) as drv: ...``

    ``driver_factory`` is called with the fake port; on leaving the block every exchange must
    have happened, nothing written beyond the script and every reply read."""
    port = FakePort(pairs)
    driver = driver_factory(port)
    yield driver
    port.check_done()


__all__ = ["FakePort", "expected_protocol"]
