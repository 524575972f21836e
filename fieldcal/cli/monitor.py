"""``fieldcal monitor``: is the unit wired up and sane? Decoded samples and parser counters."""
from __future__ import annotations

import io
import shutil
import time

import numpy as np

from drivers.transport import PORT_OPENED
from fieldcal.config import StationConfig
from fieldcal.run.devicetext import counters_line, no_samples_hint, port_event_line
from fieldcal.run.devices import DeviceConnection


def _columns(chunk) -> list[str]:
    cols = ["t_s"] + [f"{name}_{axis}" for name in sorted(chunk.triads) for axis in "xyz"]
    return cols + (["temperature_c"] if chunk.temperature is not None else [])


def _table(chunk) -> np.ndarray:
    parts = [chunk.t[:, None]] + [chunk.triads[name] for name in sorted(chunk.triads)]
    if chunk.temperature is not None:
        parts.append(chunk.temperature[:, None])
    return np.hstack(parts)


_SHORT = {"accelerometer": "acc", "gyroscope": "gyro", "inclinometer": "incl", "magnetometer": "mag"}


def _rate_words(rate_hz: float, configured_hz: float) -> str:
    """The measured rate, and the config's beside it where they differ by more than the 1 % a
    run is held for (``fieldcal.run.ratecheck``)."""
    from fieldcal.run.ratecheck import TOLERANCE

    off = rate_hz / configured_hz - 1.0
    return f"{rate_hz:.0f} Hz" + (f" (device.rate_hz {configured_hz:g} Hz: {100 * off:+.0f} %)"
                                  if abs(off) > TOLERANCE else "")


def _live_line(chunk, rate_hz: float, counters, units: dict[str, str], width: int,
               configured_hz: float | None = None) -> str:
    """One terminal line: the configured triads' latest sample (rates in °/s) and the counters."""
    parts = [f"t {chunk.t[-1]:.2f} s"]
    for name, unit in units.items():
        if name not in chunk.triads:
            continue
        xyz = chunk.triads[name][-1]
        if unit == "rad/s":
            xyz, unit = np.degrees(xyz), "°/s"
        parts.append(f"{_SHORT.get(name, name)} {' '.join(f'{v:+7.3f}' for v in xyz)} {unit}")
    c = counters
    parts.append(_rate_words(rate_hz, configured_hz) if configured_hz and rate_hz > 0 else f"{rate_hz:.0f} Hz")
    problems = [f"{n} {what}" for n, what in ((c.discarded_bytes, "B dropped"),
                                              (c.checksum_failures, "bad checksums"),
                                              (c.sequence_gaps, "gaps")) if n]
    parts.append(f"{c.frames} frames" + (": " + ", ".join(problems) if problems else " ok"))
    return " | ".join(parts)[: width - 1]


def run_monitor(config: StationConfig, out, err, max_samples: int | None = None,
                max_seconds: float | None = None, live: bool | None = None) -> int:
    """Print samples until stopped (Ctrl-C), or until ``max_samples`` / ``max_seconds``; exit
    status 1, with a hint at the port, protocol or baud rate, if no sample came."""
    live = out.isatty() if live is None else live
    units = {t.name: t.unit for t in config.device.triads}
    printed, header, last_draw, opened = 0, None, 0.0, False
    window: list[tuple[float, int]] = []  # (sample time, count) for the live rate
    span = None  # (first chunk's last sample time, the latest's, samples since): the whole run's rate
    with DeviceConnection(config) as conn:
        started = time.monotonic()
        where = conn.simulated.imu_url if conn.simulated else config.device.port.url
        print(f"monitoring {config.device.name} on {where} ({conn.protocol}); Ctrl-C to stop",
              file=err, flush=True)
        try:
            while max_seconds is None or time.monotonic() - started < max_seconds:
                chunks, events = conn.read()
                for event in events:
                    opened |= event.kind == PORT_OPENED
                    line = port_event_line(event, conn.reader.retry_s)
                    print(f"\n{line}" if live else line, file=err, flush=True)
                for chunk in chunks:
                    span = (span[0], chunk.t[-1], span[2] + len(chunk)) if span else (chunk.t[-1], chunk.t[-1], 0)
                    if max_samples is not None:
                        chunk_rows = _table(chunk)[: max_samples - printed]
                    else:
                        chunk_rows = _table(chunk)
                    if live:
                        window = [w for w in window if w[0] > chunk.t[-1] - 2.0] + [(chunk.t[-1], len(chunk))]
                        span = window[-1][0] - window[0][0]
                        rate = sum(n for _, n in window[1:]) / span if span > 0 else 0.0
                        if time.monotonic() - last_draw > 0.2:
                            width = shutil.get_terminal_size().columns
                            print("\r" + _live_line(chunk, rate, conn.counters, units, width,
                                                     config.device.rate_hz).ljust(width - 1),
                                  end="", file=out, flush=True)
                            last_draw = time.monotonic()
                    else:
                        if header is None:
                            header = _columns(chunk)
                            print(",".join(header), file=out)
                        buf = io.StringIO()
                        np.savetxt(buf, chunk_rows, fmt="%.9g", delimiter=",")
                        out.write(buf.getvalue())
                        out.flush()
                    printed += len(chunk_rows)
                    if max_samples is not None and printed >= max_samples:
                        break
                if max_samples is not None and printed >= max_samples:
                    break
                time.sleep(0.01)
        except KeyboardInterrupt:
            pass
        if live:
            print(file=out)
        print(f"{printed} samples; {counters_line(conn.counters)}", file=err, flush=True)
        if span and span[1] > span[0]:
            how = "the device's clock" if getattr(conn.parser, "device_time", False) else "host arrival times"
            print(f"sample rate: {_rate_words(span[2] / (span[1] - span[0]), config.device.rate_hz)} "
                  f"measured from {how}", file=err, flush=True)
        if printed:
            return 0
        print(f"fieldcal: {no_samples_hint(config, opened, conn.reader.bytes_read)}", file=err, flush=True)
    return 1
