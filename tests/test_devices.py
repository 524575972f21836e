"""The simulated devices through real bytes: pty/TCP, pyserial, the protocol parsers."""
import math
import threading
import time

import numpy as np
import pytest

from drivers.sim.device import paper_mimu
from drivers.sim.serve import SimulatedDevices
from drivers.transport import PORT_LOST, PORT_OPENED, PORT_REGAINED, PortSettings, SerialReader
from fieldcal.run.devices import make_parser

LAT = math.radians(40.0)
# Worst-case disagreement per protocol, in the values' own units: float32 for Xsens, 9
# significant digits for delimited text, the fixed decimals of VectorNav's ASCII sentences.
TOLERANCE = {"xsens": dict(rtol=1e-6, atol=1e-9), "delimited": dict(rtol=1e-8, atol=1e-12),
             "vectornav": dict(rtol=0, atol=6e-4)}


def collect(reader, parser, until, timeout_s=60.0):
    """Read and parse until ``until(chunks, events)`` holds; the timeout only bounds a failure."""
    chunks, events = [], []
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        for t, data in reader.poll():
            chunk = parser.feed(data, t)
            if chunk is not None and len(chunk):
                chunks.append(chunk)
        events += reader.events()
        if until(chunks, events):
            break
        time.sleep(0.005)
    return chunks, events


def n_samples(chunks):
    return sum(len(c) for c in chunks)


@pytest.mark.parametrize("protocol", ["xsens", "vectornav", "delimited"])
def test_round_trip_through_a_pty_equals_the_source(protocol):
    sent = []
    devices = SimulatedDevices(paper_mimu(), 9.8, LAT, imu_protocol=protocol, table_protocol=None,
                               speed=0, on_chunk=sent.append)
    parser = make_parser(protocol)
    with SerialReader(PortSettings(devices.imu_url)) as reader:
        # the station's port is open (and flushed) before the device talks
        _, events = collect(reader, parser, lambda c, e: PORT_OPENED in [x.kind for x in e])
        assert PORT_OPENED in [x.kind for x in events]
        with devices:
            chunks, _ = collect(reader, parser, lambda c, e: n_samples(c) >= 2000)
    got_acc = np.concatenate([c.triads["accelerometer"] for c in chunks])[:2000]
    got_gyro = np.concatenate([c.triads["gyroscope"] for c in chunks])[:2000]
    src_acc = np.concatenate([c.triads["accelerometer"] for c in sent])[:2000]
    src_gyro = np.concatenate([c.triads["gyroscope"] for c in sent])[:2000]
    np.testing.assert_allclose(got_acc, src_acc, **TOLERANCE[protocol])
    np.testing.assert_allclose(got_gyro, src_gyro, **TOLERANCE[protocol])
    if protocol != "vectornav":  # VectorNav's sentences carry no time
        got_t = np.concatenate([c.t for c in chunks])[:2000]
        np.testing.assert_allclose(got_t, np.concatenate([c.t for c in sent])[:2000], atol=2e-4)
    c = parser.counters
    assert (c.discarded_bytes, c.checksum_failures, c.sequence_gaps) == (0, 0, 0)


class SampledWhileUnplugged:
    """The device's samples once the cable is out: sets ``enough`` at ``need`` of them.

    Every chunk counted here but the last was written while unplugged and is lost; the last one
    may be written after the replug. ``first_t``/``last_t``: sample time of the first counted
    sample and of the last counted chunk's first sample."""

    def __init__(self, need: int):
        self.need, self.count, self.unplugged = need, 0, False
        self.first_t = self.last_t = None
        self.enough = threading.Event()

    def __call__(self, chunk) -> None:  # the device's on_chunk, in its thread
        if self.unplugged and not self.enough.is_set():
            self.first_t = chunk.t[0] if self.first_t is None else self.first_t
            self.last_t = chunk.t[0]
            self.count += len(chunk)
            if self.count >= self.need:
                self.enough.set()


@pytest.mark.parametrize("transport", ["pty", "tcp"])
def test_pulled_cable_resumes_and_the_gap_is_reported(transport):
    # 50 Hz: the reader takes a socket:// port a byte per read (pyserial's in_waiting there is
    # 0 or 1), so on a loaded machine a 250 Hz stream would pile up ahead of it.
    meanwhile = SampledWhileUnplugged(25)  # 0.5 s of the device's 50 Hz
    devices = SimulatedDevices(paper_mimu(), 9.8, LAT, imu_protocol="xsens", table_protocol=None,
                               transport=transport, speed=1.0, on_chunk=meanwhile, rate_hz=50)
    parser = make_parser("xsens")
    with devices, SerialReader(PortSettings(devices.imu_url), max_backoff_s=0.05) as reader:
        before, _ = collect(reader, parser, lambda c, e: n_samples(c) >= 10)
        devices.imu_link.unplug()
        meanwhile.unplugged = True
        assert meanwhile.enough.wait(60.0), "the device stopped sampling"
        devices.imu_link.replug()
        # What was sent before the cable went out may still be in the link's buffers: read on
        # until samples from after the replug arrive.
        after, events = collect(reader, parser, lambda c, e: PORT_REGAINED in [x.kind for x in e]
                                and bool(c) and c[-1].t[-1] > meanwhile.last_t)
    kinds = [e.kind for e in events]
    assert PORT_LOST in kinds and PORT_REGAINED in kinds
    t = np.concatenate([c.t for c in before + after])
    counter = np.concatenate([c.extras["packet_counter"] for c in before + after])
    assert np.all(np.diff(t) > 0)  # nothing repeated, nothing out of order
    # The device kept sampling while unplugged: the hole is in the data, and the parser says so.
    assert not np.any((t >= meanwhile.first_t) & (t < meanwhile.last_t))
    assert np.max(np.diff(t)) > meanwhile.last_t - meanwhile.first_t > 0.3
    assert parser.counters.sequence_gaps >= 1
    assert parser.counters.missing_frames == pytest.approx(np.max(np.diff(counter)) - 1, abs=1)


@pytest.mark.parametrize("table_protocol", ["ascii", "grbl"])
def test_commanding_the_table_over_its_port_turns_the_simulated_unit(table_protocol):
    from drivers.tables import open_table

    devices = SimulatedDevices(paper_mimu(), 9.8, LAT, imu_protocol="xsens",
                               table_protocol=table_protocol, speed=4.0)
    parser = make_parser("xsens")
    with devices, SerialReader(PortSettings(devices.imu_url)) as reader:
        table = open_table(table_protocol, devices.table_url, timeout_s=2.0)
        try:
            table.set_rate(-10.0)
            table.wait_settled(-10.0, timeout_s=20.0)
            reader.poll()  # drop what was sent while ramping
            chunks, _ = collect(reader, parser, lambda c, e: n_samples(c) >= 500)
            state = table.query()
            table.stop()
        finally:
            table.close()
    gyro = np.concatenate([c.triads["gyroscope"] for c in chunks])
    # Body z is up (identity attitude): the gyro sees the commanded rate there, plus Earth rate
    # and its bias, which are tiny beside 10 °/s.
    assert np.degrees(gyro[:, 2].mean()) == pytest.approx(-10.0, abs=0.05)
    assert np.all(np.abs(np.degrees(gyro[:, :2].mean(axis=0))) < 0.05)
    assert state.status == "steady" and state.rate_deg_s == pytest.approx(-10.0, abs=0.02)


def test_every_simulated_protocol_has_a_parser_and_an_encoder_and_unknown_names_are_refused():
    from drivers.protocols import ENCODERS, PARSERS, make_encoder
    from fieldcal.config import SIM_IMU_PROTOCOLS

    assert set(PARSERS) == set(ENCODERS) == set(SIM_IMU_PROTOCOLS)
    with pytest.raises(ValueError, match="imu protocol: expected one of xsens, vectornav, delimited, got 'nmea'"):
        make_parser("nmea")
    with pytest.raises(ValueError, match="needs a channel map"):
        make_encoder("delimited")


def test_a_device_whose_station_quit_unread_stops_at_once():
    """A station that closes its port leaves the bytes written since unread: the unit runs on
    and what does not fit is lost, but its thread never waits on the station (at 25x a block,
    0.5 s of Xsens frames, is 6.7 kB, more than a pty's 4 kB input buffer: the pty's blocking
    write of it waited for a read that never came, and ``stop`` left the thread behind after
    its 2 s join, 2 s a device of test_tui_resume's power cycles)."""
    devices = SimulatedDevices(paper_mimu(), 9.8, LAT, imu_protocol="xsens", table_protocol=None, speed=25.0)
    parser = make_parser("xsens")
    with devices:
        with SerialReader(PortSettings(devices.imu_url)) as reader:
            chunks, _ = collect(reader, parser, lambda c, e: n_samples(c) >= 250)
            assert n_samples(chunks) >= 250, "the station read nothing"
        deadline = time.monotonic() + 60.0  # a hang guard: the unit fills the closed port's buffer
        while devices.imu_link.unread() < 4000 and time.monotonic() < deadline:
            time.sleep(0.005)
        assert devices.imu_link.unread() >= 4000, "the unit wrote nothing after the station quit"
    assert not any(thread.is_alive() for thread in devices._threads), "a device thread outlived stop()"
