"""Rate-table drivers and virtual tables.

Truth here is the protocol, not the code: the ASCII exchanges are copied from
drivers/tables/ASCII_TABLE_PROTOCOL.md, the GRBL ones from GRBL v1.1's documentation and
sources (gnea/grbl doc/markdown/jogging.md, commands.md, interface.md; grbl/report.c), the
motion from the closed-form trapezoid.
"""
from __future__ import annotations

import math
import os
import re
import select
import threading
import tty

import pytest
import serial
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.sim.tables import TableMotion, VirtualAsciiTable, VirtualGrblTable
from drivers.tables import (
    AsciiRateTable,
    GrblRateTable,
    RateTable,
    TableError,
    TableState,
    TableTimeout,
    open_table,
)
from drivers.tables.base import format_number, wrap_angle
from drivers.testing import FakePort, expected_protocol

# =============================================================================================
# PyMeasure-style exact byte exchanges


def ascii_table(port):
    return AsciiRateTable(port, timeout_s=1.0, poll_interval_s=0.0)


def grbl_table(port):
    return GrblRateTable(port, timeout_s=1.0, max_rate_deg_s=60.0, max_run_s=3600.0,
                         poll_interval_s=0.0, stop_timeout_s=2.0)


# -- ASCII driver ------------------------------------------------------------------------------


def test_a_port_gone_between_a_commands_write_and_its_flush_fails_as_an_oserror():
    """pyserial's flush (tcdrain) on a pty whose far end closed raises termios.error, not an
    OSError (pyserial issue 417): the driver says it as every other port gone, an OSError with
    the same errno, which the station turns into "its port failed" (a pulled cable as the table
    started ended the run with termios.error, 2026-11-28)."""
    termios = pytest.importorskip("termios")

    class PortGoneAtFlush:
        timeout = None

        def write(self, data):
            return len(data)

        def flush(self):
            raise termios.error(5, "Input/output error")

    with pytest.raises(OSError) as info:
        ascii_table(PortGoneAtFlush()).set_rate(10.0)
    assert info.value.errno == 5 and isinstance(info.value.__cause__, termios.error)


def test_ascii_identify():
    with expected_protocol(ascii_table, [(b"ID?\n", b"ID FCT-1 1.0.0\r\n")]) as t:
        assert t.identify() == "FCT-1 1.0.0"


@pytest.mark.parametrize("rate, sent", [(10, b"RATE 10\n"), (-10.0, b"RATE -10\n"),
                                        (2.5, b"RATE 2.5\n"), (-0.1234, b"RATE -0.123\n"),
                                        (0.0, b"RATE 0\n"), (-0.0006, b"RATE -0.001\n")])
def test_ascii_set_rate(rate, sent):
    with expected_protocol(ascii_table, [(sent, b"OK\r\n")]) as t:
        assert t.set_rate(rate) is None


def test_ascii_stop_clear_limits():
    with expected_protocol(ascii_table, [(b"STOP\n", b"OK\r\n"), (b"CLEAR\n", b"OK\n"),
                                         (b"LIMITS?\n", b"LIMITS 100.000 20.000\r\n")]) as t:
        t.stop()
        t.clear_fault()
        assert t.limits() == (100.0, 20.0)


@pytest.mark.parametrize("reply, state", [
    (b"STATE 0.000 0.000 IDLE\r\n", TableState(0.0, 0.0, "idle")),
    (b"STATE 0.625 5.000 ACCEL\r\n", TableState(0.625, 5.0, "accelerating")),
    (b"STATE 359.999 -10.000 STEADY\r\n", TableState(359.999, -10.0, "steady")),
    (b"STATE 12.000 0.000 FAULT\r\n", TableState(12.0, 0.0, "fault", "FAULT")),
    (b"STATE 12.000 -3.000 FAULT motor overcurrent\r\n",
     TableState(12.0, -3.0, "fault", "motor overcurrent")),
])
def test_ascii_query(reply, state):
    with expected_protocol(ascii_table, [(b"STATE?\n", reply)]) as t:
        assert t.query() == state


def test_ascii_skips_blank_lines_and_bare_lf():
    with expected_protocol(ascii_table, [(b"STOP\n", b"\r\n\n   \r\nOK\n"),
                                         (b"STATE?\n", b"\nSTATE 1.000 2.000 ACCEL\n")]) as t:
        t.stop()
        assert t.query() == TableState(1.0, 2.0, "accelerating")


@pytest.mark.parametrize("sent, reply, code, fragment", [
    (b"RATE 500\n", b"ERR 3 rate 500.000 outside +-100.000 deg/s\r\n", 3, "outside +-100.000"),
    (b"RATE 10\n", b"ERR 4 fault: motor overcurrent; send CLEAR\r\n", 4, "motor overcurrent"),
    (b"RATE 10\n", b"ERR 1 unknown command RATE\r\n", 1, "unknown command"),
    (b"RATE 10\n", b"ERR 2 bad number\r\n", 2, "bad number"),
])
def test_ascii_error_replies(sent, reply, code, fragment):
    rate = float(sent.split()[1])
    with expected_protocol(ascii_table, [(sent, reply)]) as t, \
            pytest.raises(TableError) as info:
        t.set_rate(rate)
    assert not isinstance(info.value, TableTimeout)
    assert info.value.code == code
    assert f"ERR {code}" in str(info.value) and fragment in str(info.value)


@pytest.mark.parametrize("call, sent, reply", [
    ("query", b"STATE?\n", b"STATE 12.5 fast STEADY\r\n"),
    ("query", b"STATE?\n", b"STATE 360.000 1.000 STEADY\r\n"),
    ("query", b"STATE?\n", b"STATE 1.000 1.000 SPINNING\r\n"),
    ("query", b"STATE?\n", b"STATE 1.000 1.000 STEADY extra\r\n"),
    ("query", b"STATE?\n", b"OK\r\n"),
    ("stop", b"STOP\n", b"\xff\xfeOK\r\n"),
    ("stop", b"STOP\n", b"ERRATIC\r\n"),
    ("identify", b"ID?\n", b"OK\r\n"),
])
def test_ascii_garbled_reply(call, sent, reply):
    with expected_protocol(ascii_table, [(sent, reply)]) as t, \
            pytest.raises(TableError, match="garbled reply to"):
        getattr(t, call)()


@pytest.mark.parametrize("reply", [b"", b"STATE 1.0"])
def test_ascii_timeout_is_prompt_and_clear(reply):
    with expected_protocol(ascii_table, [(b"STATE?\n", reply)]) as t:
        with pytest.raises(TableTimeout) as info:
            t.query()
        assert t._io.port.reads == 1  # one read timeout, then the error: no retry
    text = str(info.value)
    assert "'STATE?'" in text and "within 1 s" in text
    if reply:
        assert "STATE 1.0" in text


def test_ascii_wait_settled():
    script = [(b"STATE?\n", b"STATE 0.100 2.000 ACCEL\r\n"),
              (b"STATE?\n", b"STATE 1.000 8.000 ACCEL\r\n"),
              (b"STATE?\n", b"STATE 3.500 10.000 STEADY\r\n")]
    with expected_protocol(ascii_table, script) as t:
        assert t.wait_settled(10.0) == TableState(3.5, 10.0, "steady")
    with expected_protocol(ascii_table, [(b"STATE?\n", b"STATE 3.000 -0.500 ACCEL\r\n"),
                                         (b"STATE?\n", b"STATE 2.900 0.000 IDLE\r\n")]) as t:
        assert t.wait_settled(0.0).status == "idle"
    with expected_protocol(ascii_table, [(b"STATE?\n", b"STATE 3.000 0.000 FAULT jammed\r\n")]) as t, \
            pytest.raises(TableError, match="jammed"):
        t.wait_settled(10.0)


def test_ascii_late_reply_after_timeout_is_discarded():
    with expected_protocol(ascii_table, [(b"STATE?\n", b""), (b"STOP\n", b"OK\r\n")]) as t:
        with pytest.raises(TableTimeout):  # the exchange goes on after it
            t.query()
        t._io.port.rx += b"STATE 1.000 0.000 IDLE\r\n"  # the late reply
        t.stop()


def test_ascii_rejects_non_finite_rate_without_writing():
    with expected_protocol(ascii_table, []) as t:
        for bad in (math.nan, math.inf, 0.0004, -1e-9):
            with pytest.raises(ValueError):
                t.set_rate(bad)


def test_ascii_close_and_protocol_conformance():
    port = FakePort([])
    with AsciiRateTable(port) as t:
        assert isinstance(t, RateTable)
        assert port.timeout == 1.0
    assert port.closed


# -- GRBL driver ---------------------------------------------------------------------------------

JOG_P10 = b"$J=G91 G21 X36000 F600\n"
JOG_M10 = b"$J=G91 G21 X-36000 F600\n"


def report(state, x, feed, extra=""):
    return f"<{state}|MPos:{x:.3f},0.000,0.000|FS:{feed},0{extra}>\r\n".encode()


def test_grbl_set_rate_is_a_jog():
    with expected_protocol(grbl_table, [(JOG_P10, b"ok\r\n")]) as t:
        t.set_rate(10.0)
    with expected_protocol(grbl_table, [(b"$J=G91 G21 X-9000 F150\n", b"ok\r\n")]) as t:
        t.set_rate(-2.5)
    with expected_protocol(lambda p: GrblRateTable(p, max_run_s=60.0),
                           [(b"$J=G91 G21 X7.404 F7.404\n", b"ok\r\n")]) as t:
        t.set_rate(0.1234)


def test_grbl_same_rate_again_queues_another_jog_without_cancel():
    with expected_protocol(grbl_table, [(JOG_P10, b"ok\r\n"), (JOG_P10, b"ok\r\n")]) as t:
        t.set_rate(10.0)
        t.set_rate(10.0)


def test_grbl_rate_change_cancels_waits_for_idle_then_jogs():
    script = [(JOG_P10, b"ok\r\n"),
              (b"\x85", b""),  # jog cancel: real-time, no reply
              (b"?", report("Jog", 100.0, 300)),
              (b"?", report("Idle", 102.5, 0)),
              (JOG_M10, b"ok\r\n")]
    with expected_protocol(grbl_table, script) as t:
        t.set_rate(10.0)
        t.set_rate(-10.0)


def test_grbl_stop_is_jog_cancel_and_next_jog_waits_for_idle():
    script = [(JOG_P10, b"ok\r\n"), (b"\x85", b""),
              (b"?", report("Jog", 50.0, 120)),
              (b"?", report("Idle", 52.5, 0)),
              (JOG_P10, b"ok\r\n"),
              (b"\x85", b"")]
    with expected_protocol(grbl_table, script) as t:
        t.set_rate(10.0)
        t.stop()
        assert t.query() == TableState(50.0, 2.0, "accelerating", "stopping (jog cancelled)")
        t.set_rate(10.0)  # polls once more: Idle, then jogs
        t.set_rate(0.0)  # = stop


@pytest.mark.parametrize("line, expected", [
    (report("Idle", 725.5, 0), TableState(5.5, 0.0, "idle")),
    (report("Idle", -90.0, 0), TableState(270.0, 0.0, "idle")),
    (report("Jog", 12.345, 600), TableState(12.345, 10.0, "steady")),
    (report("Jog", 12.345, 420), TableState(12.345, 7.0, "accelerating")),
    (report("Jog", 0.0, 600, "|WCO:0.000,0.000,0.000"), TableState(0.0, 10.0, "steady")),
    (report("Jog", 1.0, 600, "|Ov:100,100,100|A:S"), TableState(1.0, 10.0, "steady")),
    (b"<Jog|MPos:1.000,0.000,0.000|Bf:15,128|F:600>\r\n", TableState(1.0, 10.0, "steady")),
    (b"<Jog|WPos:10.000,0.000,0.000|FS:600,0|WCO:-400.000,0.000,0.000>\r\n",
     TableState(330.0, 10.0, "steady")),
])
def test_grbl_query_after_jog(line, expected):
    with expected_protocol(grbl_table, [(JOG_P10, b"ok\r\n"), (b"?", line)]) as t:
        t.set_rate(10.0)
        assert t.query() == expected


def test_grbl_rate_takes_the_sign_of_the_jog():
    with expected_protocol(grbl_table, [(JOG_M10, b"ok\r\n"), (b"?", report("Jog", -5.0, 600))]) as t:
        t.set_rate(-10.0)
        assert t.query() == TableState(355.0, -10.0, "steady")


def test_grbl_wpos_uses_last_wco():
    script = [(b"?", b"<Idle|WPos:0.000,0.000,0.000|FS:0,0|WCO:20.000,0.000,0.000>\r\n"),
              (b"?", b"<Idle|WPos:5.000,0.000,0.000|FS:0,0>\r\n")]
    with expected_protocol(grbl_table, script) as t:
        assert t.query().angle_deg == 20.0
        assert t.query().angle_deg == 25.0


def test_grbl_wait_settled():
    script = [(JOG_P10, b"ok\r\n"), (b"?", report("Jog", 0.2, 120)),
              (b"?", report("Jog", 2.0, 599)), (b"?", report("Jog", 4.0, 600))]
    with expected_protocol(grbl_table, script) as t:
        t.set_rate(10.0)
        state = t.wait_settled(10.0)
    assert state == TableState(4.0, 10.0, "steady")


def test_grbl_error_reply():
    with expected_protocol(grbl_table, [(JOG_P10, b"error:15\r\n")]) as t, \
            pytest.raises(TableError, match=r"error:15 \(jog target exceeds machine travel\)") as info:
        t.set_rate(10.0)
    assert info.value.code == 15 and info.value.command == JOG_P10.decode().strip()


def test_grbl_unsolicited_alarm_is_a_fault():
    script = [(None, b"ALARM:1\r\n[MSG:Reset to continue]\r\n"),
              (b"?", report("Alarm", 10.0, 0)),
              (b"$X\n", b"[MSG:Caution: Unlocked]\r\nok\r\n"),
              (b"?", report("Idle", 10.0, 0))]
    with expected_protocol(grbl_table, script) as t:
        state = t.query()
        assert state.status == "fault" and "ALARM:1 (hard limit triggered)" in state.message
        t.clear_fault()
        assert t.query() == TableState(10.0, 0.0, "idle")
        assert "[MSG:Reset to continue]" in t.feedback


def test_grbl_alarm_then_error_names_both():
    with expected_protocol(grbl_table, [(JOG_P10, b"ALARM:1\r\nerror:8\r\n")]) as t, \
            pytest.raises(TableError, match=r"error:8 \(not idle\) after ALARM:1"):
        t.set_rate(10.0)


def test_grbl_identify_and_reset():
    script = [(b"$I\n", b"[VER:1.1h.20190825:]\r\n[OPT:V,15,128]\r\nok\r\n"),
              (b"\x18", b"\r\nGrbl 1.1h ['$' for help]\r\n"),
              (b"$I\n", b"[VER:1.1h.20190825:rate table 3]\r\n[OPT:V,15,128]\r\nok\r\n")]
    with expected_protocol(grbl_table, script) as t:
        assert t.identify() == "Grbl 1.1h build 20190825"
        assert t.reset() == "Grbl 1.1h ['$' for help]"
        assert t.identify() == "Grbl 1.1h build 20190825 rate table 3"


def test_grbl_banner_instead_of_ok_means_lost_command():
    with expected_protocol(grbl_table, [(JOG_P10, b"\r\nGrbl 1.1h ['$' for help]\r\n")]) as t:
        with pytest.raises(TableError, match="restarted"):  # more checks follow
            t.set_rate(10.0)
        assert t.banner == "Grbl 1.1h ['$' for help]"


@pytest.mark.parametrize("reply", [b"<Jog|MPos:abc,0,0|FS:600,0>\r\n", b"<Running|MPos:1,0,0>\r\n",
                                   b"<Jog|FS:600,0>\r\n", b"<Jog|MPos:1.0,0,0|FS600>\r\n",
                                   b"hello\r\n", b"\xff\xff\r\n"])
def test_grbl_garbled_status(reply):
    with expected_protocol(grbl_table, [(b"?", reply)]) as t, \
            pytest.raises(TableError, match="garbled"):
        t.query()


def test_grbl_garbled_command_reply():
    with expected_protocol(grbl_table, [(JOG_P10, b"okay\r\n")]) as t, \
            pytest.raises(TableError, match="garbled reply to '\\$J=G91 G21 X36000 F600'"):
        t.set_rate(10.0)


@pytest.mark.parametrize("call, sent", [("query", b"?"), ("identify", b"$I\n"),
                                        ("set_rate", JOG_P10)])
def test_grbl_timeout_is_prompt_and_clear(call, sent):
    with expected_protocol(grbl_table, [(sent, b"")]) as t:
        with pytest.raises(TableTimeout) as info:
            getattr(t, call)(*((10.0,) if call == "set_rate" else ()))
        assert t._io.port.reads == 1  # one read timeout, then the error: no retry
    assert repr(sent.decode().strip()) in str(info.value) and "within 1 s" in str(info.value)


def test_grbl_refuses_rates_beyond_max_without_writing():
    with expected_protocol(grbl_table, []) as t:
        for bad in (60.5, -61.0, math.nan, 1e-7):
            with pytest.raises(ValueError):
                t.set_rate(bad)


# =============================================================================================
# The virtual tables on their own


def test_motion_advance_matches_the_trapezoid():
    m = TableMotion(target_rate_deg_s=10.0)  # accel 20 deg/s²: ramp 0.5 s, 2.5 deg
    m.advance(0.25)
    assert m.rate_deg_s == pytest.approx(5.0) and m.status == "accelerating"
    assert m.angle_deg == pytest.approx(0.625)
    m.advance(1.25)
    assert m.rate_deg_s == 10.0 and m.status == "steady"
    assert m.angle_deg == pytest.approx(2.5 + 10.0)
    m.target_rate_deg_s = -10.0  # reverse: 1 s through zero, no net angle
    m.advance(1.0)
    assert m.rate_deg_s == -10.0 and m.angle_deg == pytest.approx(12.5)
    m.advance(36.0)
    assert m.angle_deg == pytest.approx(12.5 - 360.0 + 360.0) and m.position_deg == pytest.approx(-347.5)
    m.target_rate_deg_s = 0.0
    m.advance(10.0)
    assert m.status == "idle" and m.rate_deg_s == 0.0


@settings(max_examples=200, deadline=None)
@given(steps=st.lists(st.floats(0.0, 0.3), min_size=1, max_size=30),
       target=st.floats(-100, 100), r0=st.floats(-100, 100), accel=st.floats(1.0, 200.0))
def test_motion_advance_is_independent_of_step_split(steps, target, r0, accel):
    whole = TableMotion(target_rate_deg_s=target, rate_deg_s=r0, accel_deg_s2=accel)
    split = TableMotion(target_rate_deg_s=target, rate_deg_s=r0, accel_deg_s2=accel)
    T = sum(steps)
    whole.advance(T)
    for dt in steps:
        split.advance(dt)
    # closed form
    t_ramp = abs(target - r0) / accel
    if t_ramp >= T:
        r = r0 + math.copysign(accel * T, target - r0)
        disp = 0.5 * (r0 + r) * T
    else:
        r, disp = target, 0.5 * (r0 + target) * t_ramp + target * (T - t_ramp)
    for m in (whole, split):
        assert m.rate_deg_s == pytest.approx(r, abs=1e-8)
        assert m.position_deg == pytest.approx(disp, abs=1e-7)
        assert 0.0 <= m.angle_deg < 360.0
        assert math.isclose(m.angle_deg, wrap_angle(disp), abs_tol=1e-7) or \
            abs(abs(m.angle_deg - wrap_angle(disp)) - 360.0) < 1e-7


def test_motion_fault_zeroes_target():
    m = TableMotion(target_rate_deg_s=10.0, rate_deg_s=10.0)
    m.fault = True
    assert m.status == "fault"
    m.advance(1.0)
    assert m.rate_deg_s == 0.0 and m.target_rate_deg_s == 0.0
    m.fault = False
    assert m.status == "idle"


def test_virtual_ascii_example_session():
    m = TableMotion()
    v = VirtualAsciiTable(m)
    assert v.receive(b"ID?\n") == b"ID FCT-1 1.0.0\r\n"
    assert v.receive(b"LIMITS?\r\n") == b"LIMITS 100.000 20.000\r\n"
    assert v.receive(b"STA") == b""  # partial line buffered
    assert v.receive(b"TE?\n") == b"STATE 0.000 0.000 IDLE\r\n"
    assert v.receive(b"rate 10\n\n   \nSTATE?\n") == b"OK\r\nSTATE 0.000 0.000 ACCEL\r\n"
    m.advance(0.25)
    assert v.receive(b"STATE?\n") == b"STATE 0.625 5.000 ACCEL\r\n"
    m.advance(4.75)
    assert v.receive(b"STATE?\n") == b"STATE 47.500 10.000 STEADY\r\n"
    assert v.receive(b"RATE 500\n") == b"ERR 3 rate 500.000 outside +-100.000 deg/s\r\n"
    assert v.receive(b"SPIN 10\n") == b"ERR 1 unknown command SPIN\r\n"
    assert v.receive(b"RATE\nRATE ten\nRATE 1e3\nSTOP 5\n") == (
        b"ERR 2 RATE takes one number\r\nERR 2 bad number ten\r\nERR 2 bad number 1e3\r\n"
        b"ERR 2 STOP takes no argument\r\n")
    assert v.receive(b"X" * 65 + b"\n") == b"ERR 2 line too long\r\n"
    assert v.receive(b"RATE\t10\n").startswith(b"ERR 1 ")
    m.fault, m.fault_reason = True, "motor overcurrent"
    assert v.receive(b"RATE 10\n") == b"ERR 4 fault: motor overcurrent; send CLEAR\r\n"
    assert v.receive(b"STATE?\n").endswith(b" FAULT motor overcurrent\r\n")
    assert v.receive(b"CLEAR\nSTOP\n") == b"OK\r\nOK\r\n"
    m.advance(10.0)
    assert v.receive(b"STATE?\n").endswith(b" 0.000 IDLE\r\n")


def grbl_lines(v: VirtualGrblTable, data: bytes) -> list[str]:
    return v.receive(data).decode().split("\r\n")[:-1]


def test_virtual_grbl_line_handling_follows_grbl():
    m = TableMotion()
    v = VirtualGrblTable(m)
    assert v.startup() == b"\r\nGrbl 1.1h ['$' for help]\r\n"
    assert grbl_lines(v, b"\n") == ["ok"]  # an empty line is a line
    assert grbl_lines(v, b"$I\r\n") == ["[VER:1.1h.20190825:]", "[OPT:V,15,128]", "ok", "ok"]
    assert grbl_lines(v, b"G0 X10\n") == ["error:20"]
    assert grbl_lines(v, b"$Q\n") == ["error:3"]
    assert grbl_lines(v, b"$J G91 X1 F60\n") == ["error:3"]
    assert grbl_lines(v, b"$J=G91 X10\n") == ["error:22"]
    assert grbl_lines(v, b"$J=G91 M3 X10 F600\n") == ["error:16"]
    assert grbl_lines(v, b"$J=G91 X1.2.3 F600\n") == ["error:1"]
    assert grbl_lines(v, b"$J=G91 X F600\n") == ["error:2"]
    assert grbl_lines(v, b"$J=G91 " + b"X1" * 40 + b"\n") == ["error:11"]
    assert m.target_rate_deg_s == 0.0
    # lower case, spaces, comments, and a '?' in the middle of the line
    lines = grbl_lines(v, b"$j=g91 (turn) x3?6 f600 ; ten deg/s\n")
    assert lines[0].startswith("<Idle|MPos:0.000,0.000,0.000|FS:0,0") and lines[1] == "ok"
    assert m.target_rate_deg_s == 10.0
    assert grbl_lines(v, b"G0 X1\n") == ["error:9"]  # g-code locked out while jogging
    assert grbl_lines(v, b"?")[0].startswith("<Jog|")


def test_virtual_grbl_jog_ends_on_target_and_cancel_defers_lines():
    m = TableMotion()
    v = VirtualGrblTable(m)
    assert grbl_lines(v, b"$J=G91 G21 X5 F600\n") == ["ok"]
    for _ in range(400):
        m.advance(0.005)
        v.receive(b"")
    assert v.machine_state == "Idle"
    assert m.position_deg == pytest.approx(5.0, abs=0.06)
    assert grbl_lines(v, b"$J=G91 X-100 F600\n") == ["ok"]
    m.advance(1.0)
    assert grbl_lines(v, b"\x85$I\n") == []  # cancelling: the line waits for rest
    assert v.machine_state == "Jog" and m.target_rate_deg_s == 0.0
    m.advance(1.0)
    assert grbl_lines(v, b"") == ["[VER:1.1h.20190825:]", "[OPT:V,15,128]", "ok"]
    assert v.machine_state == "Idle"


def test_virtual_grbl_alarm_and_reset():
    m = TableMotion()
    v = VirtualGrblTable(m)
    grbl_lines(v, b"$J=G91 X1000 F600\n")
    m.advance(2.0)
    m.fault = True
    lines = grbl_lines(v, b"?")
    assert lines[0] == "ALARM:1" and lines[1].startswith("<Alarm|")
    assert grbl_lines(v, b"$J=G91 X10 F600\n") == ["error:8"]
    assert grbl_lines(v, b"$X\n") == ["[MSG:Caution: Unlocked]", "ok"]
    assert not m.fault
    m.advance(5.0)
    grbl_lines(v, b"$J=G91 X1000 F600\n")
    m.advance(1.0)
    assert grbl_lines(v, b"\x18") == ["ALARM:3", "", "Grbl 1.1h ['$' for help]",
                                      "[MSG:'$H'|'$X' to unlock]"]
    assert m.rate_deg_s == 0.0 and v.machine_state == "Alarm"


ASCII_REPLY = re.compile(r"OK|ID \S+ \S+|LIMITS \d+\.\d{3} \d+\.\d{3}|ERR [1-4] .+|"
                         r"STATE \d{1,3}\.\d{3} -?\d+\.\d{3} (IDLE|ACCEL|STEADY|FAULT( .+)?)")
GRBL_REPLY = re.compile(r"ok|error:\d+|ALARM:\d+|\[[^\]]*\]|Grbl \S+ \['\$' for help\]|\$\d+=[\d.]+|"
                        r"<[A-Za-z]+(:\d)?\|MPos:-?\d+\.\d{3},0\.000,0\.000\|FS:\d+,0"
                        r"(\|WCO:-?\d+\.\d{3},0\.000,0\.000|\|Ov:100,100,100)?>|")
motions = st.builds(TableMotion, target_rate_deg_s=st.floats(-100, 100),
                    rate_deg_s=st.floats(-100, 100), angle_deg=st.floats(0, 359.99),
                    position_deg=st.floats(-1e5, 1e5), fault=st.booleans())
garbage = st.lists(st.one_of(st.binary(max_size=40),
                             st.sampled_from([b"\n", b"\r\n", b"?", b"\x85", b"\x18", b"!", b"~",
                                              b"RATE 10\n", b"STATE?\n", b"CLEAR\n", b"rate -5.5",
                                              b"$J=G91 X10 F600\n", b"$J=", b"$X\n", b"(", b")",
                                              b";", b"X" * 70])),
                   max_size=25)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(motion=motions, chunks=garbage, dts=st.lists(st.floats(0, 2.0), min_size=25, max_size=25))
def test_virtual_ascii_never_raises_and_replies_per_spec(motion, chunks, dts):
    v = VirtualAsciiTable(motion)
    out = b"".join(v.receive(c) for c in chunks) + v.receive(b"")
    # independent count of the replies the spec promises: one per complete non-blank line
    lines = b"".join(chunks).split(b"\n")[:-1]
    expected = sum(1 for ln in lines
                   if len(ln.replace(b"\r", b"")) > 64 or ln.replace(b"\r", b"").strip(b" "))
    replies = out.decode("ascii").split("\r\n")
    assert replies[-1] == "" and len(replies) - 1 == expected
    for r in replies[:-1]:
        assert ASCII_REPLY.fullmatch(r), r
    for c, dt in zip(chunks, dts):  # interleaved with time
        motion.advance(dt)
        v.receive(c)
    assert math.isfinite(motion.rate_deg_s) and 0 <= motion.angle_deg < 360


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(motion=motions, chunks=garbage, dts=st.lists(st.floats(0, 2.0), min_size=25, max_size=25))
def test_virtual_grbl_never_raises_and_replies_are_grbl(motion, chunks, dts):
    v = VirtualGrblTable(motion)
    out = bytearray()
    for c, dt in zip(chunks, dts):
        out += v.receive(c)
        motion.advance(dt)
    out += v.receive(b"")
    for line in out.decode("ascii").split("\r\n")[:-1]:
        assert GRBL_REPLY.fullmatch(line), line
    assert math.isfinite(motion.rate_deg_s) and 0 <= motion.angle_deg < 360


class EchoPort(FakePort):
    """Answers any write with the same canned bytes."""

    def __init__(self, reply):
        super().__init__([])
        self.reply = reply

    def write(self, data):
        self.rx += self.reply
        return len(data)


@settings(max_examples=300, deadline=None)
@given(reply=st.one_of(st.binary(max_size=60),
                       st.builds(lambda a, b: a + b, st.sampled_from(
                           [b"STATE ", b"ERR ", b"<Jog|MPos:", b"<Idle|WPos:", b"ok", b"error:",
                            b"ALARM:", b"[VER:", b"ID "]), st.binary(max_size=30))))
def test_drivers_fail_only_with_table_errors(reply):
    for make, calls in ((ascii_table, ("query", "identify", "stop")),
                        (grbl_table, ("query", "identify", "stop"))):
        for call in calls:
            try:
                result = getattr(make(EchoPort(reply)), call)()
            except TableError:
                continue
            if call == "query":
                assert isinstance(result, TableState)


class LoopbackPort(FakePort):
    """Hands every write to a virtual table's ``receive`` and makes its reply readable."""

    def __init__(self, table):
        super().__init__([])
        self.table = table

    def write(self, data):
        self.rx += self.table.receive(bytes(data))
        return len(data)


@settings(max_examples=200, deadline=None)
@given(rates=st.lists(st.floats(-60, 60).filter(lambda r: abs(r) >= 0.01), min_size=1, max_size=4),
       grbl=st.booleans())
def test_drivers_track_the_virtual_motion(rates, grbl):
    """Whatever the sequence of rates, once settled the driver reports the motion's truth."""
    motion = TableMotion()
    if grbl:
        table = GrblRateTable(LoopbackPort(VirtualGrblTable(motion)), poll_interval_s=0.0,
                              stop_timeout_s=0.5)
        resolution = 1 / 120  # FS is printed in whole deg/min
    else:
        table = AsciiRateTable(LoopbackPort(VirtualAsciiTable(motion)), poll_interval_s=0.0)
        resolution = 0.0005  # RATE and STATE carry 3 decimals
    for rate in rates:
        if grbl:  # GRBL must be at rest before a new jog; no time passes inside the driver here
            table.stop()
            motion.advance(10.0)
        table.set_rate(rate)
        motion.advance(10.0)  # 10 s at 20 deg/s² settles any change within ±100 deg/s
        state = table.query()
        assert state.status == "steady"
        assert motion.status == "steady" and motion.rate_deg_s == pytest.approx(rate, abs=5e-4)
        assert abs(state.rate_deg_s - motion.rate_deg_s) <= resolution + 1e-9
        assert abs(angle_step(motion.angle_deg, state.angle_deg)) <= 5e-4 + 1e-9
    table.stop()
    motion.advance(10.0)
    assert table.query().status == "idle" and motion.status == "idle"


# =============================================================================================
# Drivers against the virtual tables over a real pty


class PtyTable:
    """A virtual table behind a pty master, served by a thread.

    Simulated time moves by ``step_s`` each time bytes arrive, not with the wall clock: the
    table turns between two queries by exactly what the test expects, however loaded the
    machine is.
    """

    def __init__(self, table, motion: TableMotion, step_s: float = 0.05):
        self.table, self.motion, self.step_s = table, motion, step_s
        self.master, self.slave = os.openpty()
        tty.setraw(self.master)
        self.path = os.ttyname(self.slave)
        self.received = bytearray()
        self.error: BaseException | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def _serve(self):
        try:
            while not self._stop.is_set():
                ready, _, _ = select.select([self.master], [], [], 0.01)
                if not ready:
                    continue
                data = os.read(self.master, 4096)
                self.motion.advance(self.step_s)
                self.received += data
                reply = self.table.receive(data)
                if reply:
                    os.write(self.master, reply)
        except Exception as exc:  # noqa: BLE001 -- re-raised in the test thread by close()
            self.error = exc

    def close(self):
        self._stop.set()
        self._thread.join(2.0)
        os.close(self.master)
        os.close(self.slave)
        if self.error is not None:
            raise self.error


def angle_step(a1: float, a2: float) -> float:
    """a2 - a1 folded into (-180, 180]."""
    d = (a2 - a1) % 360.0
    return d - 360.0 if d > 180.0 else d


def test_ascii_driver_against_virtual_table_over_pty():
    motion = TableMotion()
    server = PtyTable(VirtualAsciiTable(motion), motion)
    table = open_table("ascii", server.path, timeout_s=1.0, table_kwargs={"poll_interval_s": 0.005})
    try:
        assert table.identify() == "FCT-1 1.0.0"
        assert table.query().status == "idle"
        table.set_rate(10)
        state = table.wait_settled(10.0, timeout_s=5.0)
        assert state.status == "steady" and state.rate_deg_s == 10.0
        a1 = table.query().angle_deg
        assert 0.0 < angle_step(a1, table.query().angle_deg) < 90.0
        table.set_rate(-10)
        assert table.query().status == "accelerating"
        assert table.wait_settled(-10.0, timeout_s=5.0).rate_deg_s == -10.0
        a1 = table.query().angle_deg
        assert -90.0 < angle_step(a1, table.query().angle_deg) < 0.0
        with pytest.raises(TableError, match="ERR 3"):
            table.set_rate(150)
        table.stop()
        assert table.wait_settled(0.0, timeout_s=5.0).status == "idle"
        motion.fault, motion.fault_reason = True, "motor overcurrent"
        assert table.query() == TableState(table.query().angle_deg, 0.0, "fault", "motor overcurrent")
        with pytest.raises(TableError, match="ERR 4"):
            table.set_rate(10)
        table.clear_fault()
        assert table.query().status == "idle"
    finally:
        table.close()
        server.close()
    assert b"RATE 10\n" in server.received and b"RATE -10\n" in server.received


def test_grbl_driver_against_virtual_table_over_pty():
    motion = TableMotion()
    server = PtyTable(VirtualGrblTable(motion), motion)
    port = serial.Serial(server.path, baudrate=115200, timeout=1.0)
    table = GrblRateTable(port, timeout_s=1.0, max_rate_deg_s=60.0, poll_interval_s=0.005)
    try:
        assert table.identify() == "Grbl 1.1h build 20190825"
        assert table.query().status == "idle"
        table.set_rate(10.0)
        state = table.wait_settled(10.0, timeout_s=5.0)
        assert state.status == "steady" and state.rate_deg_s == 10.0
        a1 = table.query().angle_deg
        assert 0.0 < angle_step(a1, table.query().angle_deg) < 90.0
        table.set_rate(-10.0)  # jog cancel, '?' until Idle, jog the other way
        assert table.wait_settled(-10.0, timeout_s=5.0).rate_deg_s == -10.0
        a1 = table.query().angle_deg
        assert -90.0 < angle_step(a1, table.query().angle_deg) < 0.0
        table.stop()
        assert table.wait_settled(0.0, timeout_s=5.0).status == "idle"
        assert motion.rate_deg_s == 0.0
        # at rest, the GRBL MPos (the odometer) mod 360 is the table's angle
        assert abs(angle_step(motion.angle_deg, table.query().angle_deg)) < 1e-3
        motion.fault = True
        state = table.query()
        assert state.status == "fault" and "ALARM:1" in state.message
        with pytest.raises(TableError, match="error:8"):
            table.set_rate(10.0)
        table.clear_fault()
        assert table.query().status == "idle"
    finally:
        table.close()
        server.close()
    rx = bytes(server.received)
    assert rx.count(b"\x85") == 2 and rx.count(b"?") >= 6
    assert b"$J=G91 G21 X36000 F600\n" in rx and b"$J=G91 G21 X-36000 F600\n" in rx


def test_open_table_rejects_unknown_protocol():
    with pytest.raises(ValueError, match="unknown table protocol"):
        open_table("modbus", "loop://")


def test_helpers():
    assert format_number(36000.0) == "36000" and format_number(-2.5) == "-2.5"
    assert format_number(-0.0001) == "0" and format_number(7.4040001) == "7.404"
    assert wrap_angle(-1e-17) == 0.0 and wrap_angle(720.5) == 0.5 and wrap_angle(-90) == 270.0
    with pytest.raises(ValueError):
        TableState(360.0, 0.0, "idle")
    with pytest.raises(ValueError):
        TableState(0.0, 0.0, "spinning")


def test_expected_protocol_fails_on_a_wrong_write_and_on_an_unused_exchange():
    with pytest.raises(AssertionError, match=r"driver wrote b'STATE\?\\n', expected b'ID\?\\n'"):
        with expected_protocol(ascii_table, [(b"ID?\n", b"ID FCT-1 1.0.0\r\n")]) as t:
            t.query()
    with pytest.raises(AssertionError, match="exchange 0 never happened"):
        with expected_protocol(ascii_table, [(b"ID?\n", b"ID FCT-1 1.0.0\r\n")]):
            pass
    with pytest.raises(AssertionError, match="left b'OK\\\\r\\\\n' unread"):
        with expected_protocol(ascii_table, [(None, b"OK\r\n")]):
            pass


def test_every_table_protocol_has_a_driver_and_a_virtual_table():
    from drivers.sim.tables import VIRTUAL_TABLES
    from drivers.tables import PROTOCOLS

    assert set(VIRTUAL_TABLES) == set(PROTOCOLS)
