"""Calibrated output from a live device: the station config's device opened as ``fieldcal
monitor`` opens it (a serial port, ``socket://``, or the simulated device on a pty), its frames
decoded by the protocol's parser, and every read's samples calibrated as one block,
K⁻¹(raw − bias) per triad in numpy, and written as CSV lines (as a recording's are) and flushed,
until Ctrl-C, a sample count or a duration. Ctrl-C ends it between blocks: the output ends
with a whole line.

``t_s`` is the device's own sample time where its frames carry one (Xsens SampleTimeFine, a
delimited time column); else, as the procedure engine counts, the sample's number over the
config's ``rate_hz`` (the host's arrival time is the same for every sample of a read), the
number counted by the device's packet counter where its frames carry one, so that frames lost
on the way leave their time out rather than shift every later sample.
"""
from __future__ import annotations

import threading
import time
from typing import BinaryIO, TextIO

import numpy as np

from fieldcal.apply import calibrations_for, output_columns, write_all, write_block

POLL_S = 0.01  # how often the reader's bytes are taken (the port is read in the background)


def device_calibrations(parameters, config) -> tuple[tuple, tuple[str, ...]]:
    """The calibrations of the device's triads that the parameter file holds, and the device's
    triads it does not (one-line errors as a file's: ``calibrations_for``)."""
    device = config.device
    return calibrations_for(parameters, {t.name: t.unit for t in device.triads}, f"{config.path}: {device.name}",
                            f"{config.path}: {device.name}'s ", "use the config it was calibrated with")


def calibrate_chunks(chunks, calibrations, hold_temperature_edge: bool = False,
                     outside=None) -> tuple[np.ndarray, np.ndarray]:
    """(t (n,) in s, calibrated (n, 3·triads) in SI units) of a read's chunks, as one block; a
    triad with a thermal model at the chunks' temperatures (``fieldcal.apply.thermal``:
    ``outside`` counts those outside its range, refused unless ``hold_temperature_edge``)."""
    from fieldcal.apply.thermal import temperatures_for

    missing = sorted({c.name for c in calibrations} - set.intersection(*(set(ch.triads) for ch in chunks)))
    if missing:
        raise ValueError(f"apply: the device sent samples without {', '.join(missing)}: check the "
                         "config's protocol and triads")
    t = np.concatenate([chunk.t for chunk in chunks])
    temperature = np.concatenate([chunk.temperature for chunk in chunks]) \
        if all(chunk.temperature is not None for chunk in chunks) else None
    temperatures, _ = temperatures_for(calibrations, temperature, hold_temperature_edge, "the device", outside)
    values = np.hstack([cal.calibrate(np.concatenate([chunk.triads[cal.name] for chunk in chunks]),
                                      temperatures.get(cal.name), extrapolate=True)  # checked or held above
                        for cal in calibrations])
    return t, values


def sample_numbers(counter: np.ndarray, modulus: int | None,
                   previous: tuple[int, int | None] | None) -> tuple[np.ndarray, int]:
    """Each sample's number since the first sample (number 0), from the device's packet counter:
    a frame's number is the last one's plus the counter's step, taken modulo ``modulus`` (where
    the counter wraps), so lost frames leave a gap. ``previous``: (number, counter) of the
    sample before ``counter``'s first (counter None: that sample had none, the step is one);
    None: its first is the first. A step that is not forward, or (modulo the wrap) more than
    half the counter's range forward, is a re-sent frame or a device restarted, not frames
    lost: it counts as one, so time never jumps back or a whole wrap ahead. Also returned:
    how many such steps there were."""
    c = np.rint(np.asarray(counter, dtype=float)).astype(np.int64)
    number, last = previous if previous is not None else (-1, None)
    steps = np.diff(np.concatenate([[c[0] - 1 if last is None else last], c]))
    if modulus:
        steps %= modulus
    backward = (steps <= 0) | (steps > modulus // 2) if modulus else steps <= 0
    return number + np.cumsum(np.where(backward, 1, steps)), int(np.count_nonzero(backward))


def apply_device(config, calibrations, out: BinaryIO, err: TextIO, stop: threading.Event,
                 max_samples: int | None = None, max_seconds: float | None = None,
                 hold_temperature_edge: bool = False) -> int:
    """Stream ``config``'s device, calibrated, to ``out`` until ``stop`` is set (Ctrl-C), or
    ``max_samples`` / ``max_seconds``; the samples written (none: a hint at the port, protocol
    or baud rate on ``err``). A read with samples outside a thermal model's range stops it
    (TemperatureOutside, with ``written``: the samples written before it), unless
    ``hold_temperature_edge``."""
    from drivers.transport import PORT_OPENED
    from fieldcal.apply.thermal import OutsideCount, TemperatureOutside, at_reference_line, thermal_names
    from fieldcal.run.devicetext import counters_line, no_samples_hint, port_event_line
    from fieldcal.run.devices import DeviceConnection

    from fieldcal.run.deviceclock import frame_counter

    names = output_columns(calibrations)
    written, opened, device_time, previous = 0, False, None, None
    outside, told_reference = OutsideCount(), not thermal_names(calibrations)
    with DeviceConnection(config) as conn:
        started = time.monotonic()
        where = conn.simulated.imu_url if conn.simulated else config.device.port.url
        print(f"applying to {config.device.name} on {where} ({conn.protocol}); Ctrl-C to stop",
              file=err, flush=True)
        write_all(out, (",".join(names) + "\n").encode("ascii"))
        out.flush()
        while not stop.is_set() and (max_samples is None or written < max_samples) \
                and (max_seconds is None or time.monotonic() - started < max_seconds):
            chunks, events = conn.read()
            for event in events:
                opened |= event.kind == PORT_OPENED
                print(port_event_line(event, conn.reader.retry_s), file=err, flush=True)
            if chunks:
                if not told_reference and any(chunk.temperature is None for chunk in chunks):
                    print(f"fieldcal {at_reference_line(calibrations, 'the device')}", file=err, flush=True)
                    told_reference = True
                try:
                    t, values = calibrate_chunks(chunks, calibrations, hold_temperature_edge, outside)
                except TemperatureOutside as exc:
                    print(f"{written} samples calibrated; {counters_line(conn.counters)}", file=err, flush=True)
                    exc.written = written
                    raise
                if device_time is None:  # decided by the first frames, kept for the whole output
                    device_time = conn.parser.device_time
                    if not device_time:
                        print(f"t_s: {conn.protocol} frames carry no sample time here: sample number / "
                              f"{config.device.rate_hz:g} Hz", file=err, flush=True)
                if not device_time:
                    counters = [frame_counter(chunk, conn.parser) for chunk in chunks]
                    if all(c is not None for c, _ in counters):
                        counter = np.concatenate([c for c, _ in counters])
                        numbers, restarts = sample_numbers(counter, counters[0][1], previous)
                        previous = int(numbers[-1]), int(round(float(counter[-1])))
                        if restarts:
                            print(f"apply: the device's packet counter stepped back or far ahead {restarts} "
                                  "time(s) (a frame re-sent, the device restarted): each counted as one "
                                  "sample step", file=err, flush=True)
                    else:  # counted on from the last number given, so t never goes back
                        numbers = (previous[0] + 1 if previous else written) + np.arange(len(t))
                        previous = int(numbers[-1]), None
                    t = numbers / config.device.rate_hz
                if max_samples is not None:
                    t, values = t[: max_samples - written], values[: max_samples - written]
                write_block(out, names, t, values)
                out.flush()
                if not written:
                    print(f"samples flowing: the first at t_s = {t[0]:.3f} s", file=err, flush=True)
                written += len(t)
            stop.wait(POLL_S)
        print(f"{written} samples calibrated; {counters_line(conn.counters)}", file=err, flush=True)
        held = outside.line("the device", calibrations, held=True)
        if held:
            print(f"fieldcal {held}", file=err, flush=True)
        if not written:
            print(f"fieldcal: {no_samples_hint(config, opened, conn.reader.bytes_read)}", file=err, flush=True)
    return written
