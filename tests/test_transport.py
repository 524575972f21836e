"""The serial reader over real ptys and TCP sockets, including a pulled cable."""
import time

import pytest

from drivers.sim.ports import PtyLink, TcpLink
from drivers.transport import PORT_LOST, PORT_OPENED, PORT_REGAINED, PortSettings, SerialReader


def wait_for(predicate, timeout_s=30.0):
    """Poll ``predicate`` until it holds; the timeout only bounds a failure."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.01)
    return False


class Collector:
    def __init__(self, reader):
        self.reader, self.data, self.stamps, self.events = reader, b"", [], []

    def pump(self):
        for t, chunk in self.reader.poll():
            self.stamps.append(t)
            self.data += chunk
        self.events += self.reader.events()
        return self

    def kinds(self):
        return [e.kind for e in self.events]


@pytest.fixture(params=[PtyLink, TcpLink], ids=["pty", "tcp"])
def link(request):
    link = request.param()
    yield link
    link.close()


def test_bytes_arrive_stamped_and_tapped(link):
    tapped = []
    with SerialReader(PortSettings(link.url), tap=lambda t, d: tapped.append(d)) as reader:
        c = Collector(reader)
        assert wait_for(lambda: PORT_OPENED in c.pump().kinds())
        assert wait_for(lambda: link.write(b"abc\n" * 100) == 400)  # once the link has accepted
        assert wait_for(lambda: len(c.pump().data) == 400)
        assert c.data == b"abc\n" * 100 and b"".join(tapped) == c.data
        assert c.stamps == sorted(c.stamps)
        assert reader.poll() == []  # nothing new, and no waiting for it


def test_what_has_come_is_read_in_one_call_also_from_a_socket(link):
    """pyserial's socket:// says only whether bytes wait, not how many: read one at a time, a
    250 Hz device's 14 kB/s took thousands of reads a second."""
    size = 20000
    with SerialReader(PortSettings(link.url)) as reader:
        c = Collector(reader)
        assert wait_for(lambda: PORT_OPENED in c.pump().kinds())
        assert wait_for(lambda: link.write(bytes(range(256)) * (size // 256)) > 0)
        sent = size // 256 * 256
        assert wait_for(lambda: len(c.pump().data) >= sent)
        assert c.data.startswith(bytes(range(256)))
        assert len(c.stamps) < sent // 100  # reads of what had come, not of single bytes


def test_pulled_cable_is_survived_and_the_gap_reported(link):
    with SerialReader(PortSettings(link.url), max_backoff_s=0.05) as reader:
        c = Collector(reader)
        assert wait_for(lambda: PORT_OPENED in c.pump().kinds())
        assert wait_for(lambda: link.write(b"before|") == 7)
        assert wait_for(lambda: c.pump().data == b"before|")
        link.unplug()
        assert wait_for(lambda: PORT_LOST in c.pump().kinds())
        assert reader.write(b"x") is False or not reader.connected
        replugged_at = time.monotonic()  # the reader's clock (its default) and ours are one
        link.replug()
        assert wait_for(lambda: PORT_REGAINED in c.pump().kinds())
        assert wait_for(lambda: link.write(b"after") == 5)
        assert wait_for(lambda: c.pump().data == b"before|after")
        lost = next(e for e in c.events if e.kind == PORT_LOST)
        regained = next(e for e in c.events if e.kind == PORT_REGAINED)
        # The gap runs from the loss the reader noticed to the port it got back, which cannot
        # be before the cable went back in.
        assert regained.gap_s == pytest.approx(regained.t - lost.t)
        assert lost.t < replugged_at <= regained.t


def test_device_that_appears_later_is_picked_up(tmp_path):
    path = tmp_path / "late-tty"
    with SerialReader(PortSettings(str(path)), max_backoff_s=0.05) as reader:
        c = Collector(reader)
        assert wait_for(lambda: PORT_LOST in c.pump().kinds())
        assert "cannot open" in c.events[0].message
        link = PtyLink(path)
        try:
            assert wait_for(lambda: reader.connected)
            assert wait_for(lambda: link.write(b"hi") == 2)
            assert wait_for(lambda: c.pump().data == b"hi")
            # One report of the failure, not one per retry.
            assert c.kinds().count(PORT_LOST) == 1
        finally:
            link.close()


def test_a_failing_raw_capture_is_reported_and_reading_goes_on():
    from drivers.transport import TAP_FAILED

    def full_disk(t, data):
        raise OSError(28, "No space left on device")

    link = PtyLink()
    try:
        with SerialReader(PortSettings(link.url), tap=full_disk) as reader:
            c = Collector(reader)
            assert wait_for(lambda: PORT_OPENED in c.pump().kinds())
            assert wait_for(lambda: link.write(b"first") == 5)
            assert wait_for(lambda: TAP_FAILED in c.pump().kinds())
            assert wait_for(lambda: link.write(b"second") == 6)
            assert wait_for(lambda: c.pump().data == b"firstsecond")
            assert c.kinds().count(TAP_FAILED) == 1 and "No space left" in c.events[-1].message
    finally:
        link.close()
