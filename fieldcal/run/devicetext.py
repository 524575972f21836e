"""What a live device's stream says to the operator, one line each: its counters, a port event,
and why no sample came (in the station config's terms). Shared by ``fieldcal monitor`` and
``fieldcal apply --config``, so the library never imports the command line."""
from __future__ import annotations

from drivers.transport import PORT_LOST


def counters_line(counters) -> str:
    c = counters.as_dict()
    return (f"frames {c['frames']}, discarded {c['discarded_bytes']} B, bad checksums "
            f"{c['checksum_failures']}, sequence gaps {c['sequence_gaps']} "
            f"({c['missing_frames']} frames missing)")


def port_event_line(event, retry_s: float) -> str:
    """A port event as one line for the operator."""
    if event.kind == PORT_LOST and event.message.startswith("cannot open"):
        return f"{event.message}; retrying every {retry_s:g} s (Ctrl-C to stop)"
    gap = f" after {event.gap_s:.2f} s" if event.gap_s else ""
    return f"port {event.kind}{gap}: {event.message}"


def no_samples_hint(config, opened: bool, bytes_read: int) -> str:
    """Why a monitor saw nothing, in the config's terms: the port, the baud rate, the protocol."""
    device = config.device
    where = device.port.url if device.port else "the simulated device's port"
    baud = f"device.port.baudrate, now {device.port.baudrate}" if device.port else "device.port.baudrate"
    if not opened:
        return f"no samples: {where} never opened (is the unit plugged in, and is device.port.url in {config.path} right?)"
    if not bytes_read:
        return (f"no samples: {where} opened but sent no bytes (is the unit powered and set to send? "
                f"is the baud rate right: {baud} in {config.path}?)")
    return (f"no samples: {bytes_read} bytes read from {where} but none decoded as {device.protocol} "
            f"frames: check device.protocol and the baud rate ({baud}) in {config.path}")
