"""``--unit-serial``: which unit a run, a calibration or an import is of.

The serial is what the registry lists a unit by and what drift is taken across (never across
different or missing serials). It comes from the option, else the station config's
``device.serial``; a run with neither is recorded without one. The option is not ``--serial``:
on ``run`` that means "through a simulated serial port".
"""
from __future__ import annotations

import dataclasses

MAX_SERIAL_CHARS = 64  # a serial is a label on the unit, not a paragraph


def add_unit_serial_option(parser, what: str = "the unit") -> None:
    parser.add_argument("--unit-serial", metavar="SERIAL", type=_serial,
                        help=f"serial number of {what} (default: the config's device.serial; none: "
                        "recorded without one, and never compared for drift)")


def _serial(text: str) -> str:
    import argparse

    serial = text.strip()
    if not serial or len(serial) > MAX_SERIAL_CHARS or not serial.isprintable():
        raise argparse.ArgumentTypeError(f"expected the unit's serial number (printable text of 1 to "
                                         f"{MAX_SERIAL_CHARS} characters), got {text!r}")
    return serial


def unit_serial(args, config=None) -> str | None:
    """The serial of the unit: ``--unit-serial``, else the config's ``device.serial``, else None."""
    given = getattr(args, "unit_serial", None)
    if given is not None:
        return given
    return config.device.serial if config is not None else None


def with_unit_serial(config, args):
    """``config`` with its ``device.serial`` set from ``--unit-serial`` when given."""
    given = getattr(args, "unit_serial", None)
    if given is None or given == config.device.serial:
        return config
    return dataclasses.replace(config, device=dataclasses.replace(config.device, serial=given))


def check_recorded_serial(args, recorded: str | None, where) -> None:
    """``resume --unit-serial``: the session was recorded of one unit; a resume continues it, so
    a different serial (or one for a session recorded without any) is refused, not written."""
    given = getattr(args, "unit_serial", None)
    if given is None or given == recorded:
        return
    if recorded is None:
        raise ValueError(f"--unit-serial: {where} was recorded without a unit serial; a resume continues "
                         f"that run and cannot give it one (give --unit-serial when the run starts)")
    raise ValueError(f"--unit-serial: {where} is a run of unit {recorded!r}, not {given!r}: a resume "
                     "continues the same unit")
