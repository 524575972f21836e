"""What a live device says about its own clock, and whether it restarted while a run was away.

A live run records, with each completed step, the device's clock as last read (``DeviceClock``):
its sample time where the protocol carries one (Xsens SampleTimeFine, a delimited time column),
its packet counter where it carries one (Xsens PacketCounter, a delimited counter column), and
the host's wall clock then. VectorNav's ASCII sentences carry neither.

When the run is resumed, the first frames' clock is compared with the recorded one
(``judge_restart``): had the device run on, its clock would have advanced by the wall time
between the two, within the clocks' drift. A device that was power-cycled meanwhile restarted
its clock from zero, so it is behind that (it "went back", or advanced less than the time away).
A clock that wraps (Xsens: SampleTimeFine after 119 h, the 16-bit counter after 65536 frames) is
compared modulo its period; a counter that wraps too often to be sure, or no clock at all, is
"cannot tell" (``power_cycled`` None).

A device whose frames carry no clock (VectorNav ASCII) shows that it ran on only by its data's
continuity while the station holds its port (``ClocklessStream``): every sample it sent arrived,
late perhaps (a backlog), but none missing. Once the port is closed (the station quit) or lost,
or the stream broke with it open, that cannot be shown, and every completed step is measured
again (``measured_again`` says why).
"""
from __future__ import annotations

from dataclasses import dataclass

SLACK_S = 2.0  # reading latency, frames buffered in the port, the host's clock resolution
DRIFT = 1e-3  # the device's clock against the host's, per unit time (crystals do far better)
XSENS_TIME_PERIOD_S = 2.0**32 / 1e4  # SampleTimeFine: uint32 at 10 kHz
XSENS_COUNTER_MODULUS = 65536  # PacketCounter: uint16


@dataclass(frozen=True)
class DeviceClock:
    host_utc: float  # the host's wall clock (Unix time, s) when this clock was read
    time_s: float | None = None  # the device's sample time, s
    time_period_s: float | None = None  # where the device's time wraps (None: it does not)
    counter: int | None = None  # the device's packet counter
    counter_modulus: int | None = None  # where the counter wraps (None: it does not)

    def to_dict(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if v is not None}

    @classmethod
    def from_dict(cls, d: dict | None) -> DeviceClock | None:
        if not isinstance(d, dict) or not isinstance(d.get("host_utc"), (int, float)):
            return None
        return cls(float(d["host_utc"]), *(d.get(k) for k in ("time_s", "time_period_s", "counter",
                                                               "counter_modulus")))


def clock_of(chunk, parser, host_utc: float) -> DeviceClock:
    """The clock of a chunk's last sample, as far as ``parser``'s protocol tells it."""
    from drivers.protocols.xsens import XsensMtData2Parser

    time_s = float(chunk.t[-1]) if getattr(parser, "device_time", False) else None
    period = XSENS_TIME_PERIOD_S if isinstance(parser, XsensMtData2Parser) else None
    counter, modulus = frame_counter(chunk, parser)
    return DeviceClock(host_utc, time_s, period if time_s is not None else None,
                       None if counter is None else int(round(float(counter[-1]))),
                       modulus if counter is not None else None)


def frame_counter(chunk, parser):
    """The device's packet counter of each of the chunk's samples (None: its frames carry
    none: VectorNav, a delimited map without a counter column) and where it wraps (None: it
    does not)."""
    from drivers.protocols.delimited import DelimitedTextParser
    from drivers.protocols.xsens import XsensMtData2Parser

    if isinstance(parser, XsensMtData2Parser):
        return chunk.extras.get("packet_counter"), XSENS_COUNTER_MODULUS
    if isinstance(parser, DelimitedTextParser):
        return chunk.extras.get("counter"), parser.map.counter_modulus
    return None, None


@dataclass(frozen=True)
class ClockCheck:
    power_cycled: bool | None  # None: cannot tell
    reason: str  # in the operator's words, for the banner and the log


def _behind(last: float, now: float, advance: float, slack: float, period: float | None) -> bool:
    """Is ``now`` behind where a clock at ``last`` would be after ``advance``, beyond ``slack``?"""
    d = now - (last + advance)
    if period is None:
        return d < -slack
    d %= period
    return min(d, period - d) > slack


LUCK = 1e-3  # the most chance we accept of taking a restarted device for one that ran on


def _wraps_too_often(slack: float, period: float | None) -> bool:
    """A restarted clock that wraps every ``period`` lands within ±``slack`` of where a running one
    would be by chance 2·slack/period of the time: above LUCK it cannot tell a restart."""
    return period is not None and 2 * slack / period > LUCK


def judge_restart(recorded: DeviceClock | None, now: DeviceClock, rate_hz: float) -> ClockCheck:
    """Did the device restart between ``recorded`` (the last completed step) and ``now``?"""
    if recorded is None:
        return ClockCheck(None, "the session holds no device clock for its last step")
    away = max(0.0, now.host_utc - recorded.host_utc)
    slack = SLACK_S + DRIFT * away
    if recorded.time_s is not None and now.time_s is not None:
        period = recorded.time_period_s
        if _wraps_too_often(slack, period):
            return ClockCheck(None, f"its clock wraps every {period:.0f} s, too often to tell after "
                                    f"{away:.0f} s away")
        expected = recorded.time_s + away
        if _behind(recorded.time_s, now.time_s, away, slack, recorded.time_period_s):
            return ClockCheck(True, f"its clock reads {now.time_s:.1f} s where running on it would "
                                    f"read {expected:.1f} s, {away:.0f} s after the last step")
        return ClockCheck(False, f"its clock ran on: {now.time_s:.1f} s, {away:.0f} s after the last step")
    if recorded.counter is not None and now.counter is not None:
        modulus = recorded.counter_modulus
        advance, slack_counts = away * rate_hz, slack * rate_hz
        if modulus is not None and _wraps_too_often(slack_counts, modulus):
            return ClockCheck(None, f"its packet counter wraps every {modulus / rate_hz:.0f} s, too often "
                                    f"to tell after {away:.0f} s away")
        if _behind(recorded.counter, now.counter, advance, slack_counts, modulus):
            return ClockCheck(True, f"its packet counter reads {now.counter} where running on it would "
                                    f"read about {round(recorded.counter + advance) % (modulus or 2**63)}")
        return ClockCheck(False, f"its packet counter ran on ({now.counter}, {away:.0f} s after the last step)")
    return ClockCheck(None, NO_CLOCK)


NO_CLOCK = "its frames carry no packet counter or time, so that it stayed powered cannot be shown"


def went_back(before: DeviceClock, now: DeviceClock, rate_hz: float) -> ClockCheck | None:
    """A restart seen between two reads with the port open: the device's time (else its packet
    counter) went back from ``before`` to ``now`` by more than SLACK_S, judged then against the
    host's time (``judge_restart``); None if it did not. A running clock only moves forward:
    frames read late (a backlog drained, a device faster than the host) make it run ahead of the
    host's time or lag it, never go back."""
    if before.time_s is not None and now.time_s is not None:
        step, period, slack = now.time_s - before.time_s, before.time_period_s, SLACK_S
    elif before.counter is not None and now.counter is not None:
        step, period, slack = now.counter - before.counter, before.counter_modulus, SLACK_S * rate_hz
    else:
        return None
    if period is not None:
        step = (step + period / 2) % period - period / 2  # the nearer way round
    if step >= -slack:
        return None
    check = judge_restart(before, now, rate_hz)
    return check if check.power_cycled else None


SETTLE_S = 1.0  # reads after a stream's gap before its continuity is judged (a backlog drains)
MEMORY_S = 10.0  # the reads before a gap that its continuity is judged against


class ClocklessStream:
    """The data's continuity of a device whose frames carry no clock, read with its port open.

    Each read's lateness is its arrival less the time its samples took at the device's rate
    (``rate_hz``, in host time): a read is never early, only late, so the promptest reads lie
    on the device's own time line. A read after more than SLACK_S without one may be a backlog
    (the host read late; every sample is there, and the reads after it are prompt again) or a
    device that sent nothing meanwhile (restarted: the samples it did not send never come, and
    the promptest reads stay that much later). So ``read`` answers "wait" from such a read on
    until SETTLE_S of reads after it, then judges: a ``ClockCheck`` (cannot tell) when the
    promptest reads after it are more than SLACK_S later than those of the MEMORY_S before,
    else "go". A rate off by the 1 % the rate check allows moves that by 0.1 s over MEMORY_S.
    A power cycle shorter than SLACK_S (reading latency included) is not seen.
    """

    def __init__(self, rate_hz: float):
        self.rate_hz = rate_hz
        self._samples = 0  # read since the stream was first seen (or last judged broken)
        self._reads: list[tuple[float, float]] = []  # (arrival, lateness), the last MEMORY_S
        self._gap: tuple[float, float] | None = None  # (floor before it, arrival after it)

    def read(self, arrival: float, samples: int):
        """"go", "wait" (hold this read and those after it) or a ClockCheck (the stream broke)."""
        self._samples += samples
        last = self._reads[-1][0] if self._reads else None
        self._reads.append((arrival, arrival - self._samples / self.rate_hz))
        if self._gap is None:
            if last is not None and arrival - last > SLACK_S:
                self._gap = (min(late for _, late in self._reads[:-1]), arrival)
                return "wait"
            self._reads = [r for r in self._reads if r[0] >= arrival - MEMORY_S]
            return "go"
        floor_before, after = self._gap
        if arrival - after < SETTLE_S:
            return "wait"
        self._gap = None
        since = [r for r in self._reads if r[0] >= after]
        missing_s = min(late for _, late in since) - floor_before
        if missing_s <= SLACK_S:
            return "go"
        self._reads = since  # the stream as it goes on from here
        return ClockCheck(None, f"its frames carry no clock, and {missing_s:.1f} s of its samples never came: "
                                "it stopped sending, so that it stayed powered cannot be shown")


def measured_again(check: ClockCheck | None, done: int, when: str) -> str:
    """Why the ``done`` completed steps are measured again after ``check`` (a device's clock
    judged ``when``: "since the last completed step", "while its port was lost"); "" if they
    are kept (it ran on, or no step was completed).

    A power cycle gives a MEMS gyro a new turn-on bias (bias repeatability, often far above
    the Earth rate the static dwells measure). The solver fits one bias per triad to all
    the windows (fieldcal.solvers.problems.RateNormProblem): every static dwell's average
    (a = K⁻¹(u − b)) and every rate step's pair mean ((u₊ + u₋)/2 − b) carries it; only the
    half-difference of a ± pair is free of it, and it is never used alone. So no gyro window
    of a step before the power cycle can be combined with one after, and every position's
    step has gyro windows: all completed steps are measured again (the accelerometer's
    turn-on bias, shared the same way by its static norms, is renewed with them).
    A device that cannot say (no counter or time in its frames) may have been cycled: the
    same, since a calibration mixing two biases is wrong without any sign of it.
    The scale factors and misalignments do repeat across a power cycle, so the steps before it
    could still serve them beside a bias per switch-on; the solvers fit one bias per triad, so
    until they fit one per switch-on, every step that has windows is measured again."""
    if not done or (check is not None and check.power_cycled is False):
        return ""
    return (f"{_cycled(check)} {when}{f' ({check.reason})' if check is not None else ''}; the gyro's turn-on "
            f"bias may have changed, so the {done} completed step{'s are' if done != 1 else ' is'} measured again")


def _cycled(check: ClockCheck | None) -> str:
    return "the unit was power-cycled" if check is not None and check.power_cycled \
        else "the unit may have been power-cycled"


def step_started_again(check: ClockCheck, when: str) -> str:
    """``measured_again`` for a run with no completed step whose first step had begun."""
    return f"{_cycled(check)} {when} ({check.reason}); the step in progress starts over"


def power_cycle_banner(check: ClockCheck, done: int, when: str) -> str:
    """The banner's line when completed steps are measured again (or, ``done`` 0, the step in
    progress starts over): what happened, in capitals."""
    again = f"the {done} completed step{'s are' if done != 1 else ' is'} measured again" if done \
        else "the step in progress starts over"
    return (f"POWER-CYCLED {when}" if check.power_cycled else "CANNOT TELL whether the unit was power-cycled") + \
        f": its gyro turn-on bias may have changed; {again}"
