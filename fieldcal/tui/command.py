"""``fieldcal tui``: the operator's terminal UI against the simulated bench, or a replay.

Kept free of Textual imports so that building the CLI parser stays fast.
"""
from __future__ import annotations

import argparse
import datetime
from pathlib import Path



def _speed(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not value >= 0:
        raise argparse.ArgumentTypeError(f"expected a number >= 0 (0 = as fast as possible), got {text!r}")
    return value


def add_tui_parser(sub) -> argparse.ArgumentParser:
    """Add the ``tui`` subcommand to the CLI's subparsers."""
    tui = sub.add_parser("tui", help="the operator's terminal UI (simulated bench, or replay a session)",
                         description="Run a procedure in the operator's terminal UI against the "
                         "simulated bench (r: the unit is in place, d: redo, s: skip, a: abort, "
                         "b: bump, ?: help), capturing a session under --out; or replay a captured "
                         "session through the same screens with --replay.")
    from fieldcal.cli import add_run_options  # here: fieldcal.cli imports this module
    add_run_options(tui)
    tui.add_argument("--speed", type=_speed,
                     help="sample time per wall time: 1 = real time, 0 = as fast as possible "
                     "(default: the config's sim speed for a run, 10 for a replay)")
    tui.add_argument("--no-capture", action="store_true", help="do not write a session")
    tui.add_argument("--replay", metavar="SESSION", help="replay this session instead of running")
    tui.set_defaults(func=cmd_tui)
    return tui


def cmd_tui(args) -> int:
    from fieldcal.tui import run_tui

    if args.replay is not None:
        if not Path(args.replay, "log.jsonl").is_file():
            raise ValueError(f"--replay: {args.replay} is not a session directory (no log.jsonl)")
        return run_tui(None, 10.0 if args.speed is None else args.speed, None, Path(args.replay))
    from fieldcal.config import load_config
    from fieldcal.positions import load_procedure
    from fieldcal.runner import RunSpec

    config = load_config(args.config)
    procedure = load_procedure(args.procedure)
    if config.device.protocol != "sim":
        return run_tui(live_spec(config, procedure, args), 0.0, _session_dir(args, procedure.name, "live"),
                       None, config=config)
    if args.seed is not None and args.seed < 0:
        raise ValueError(f"--seed: expected a whole number >= 0, got {args.seed}")
    seed = config.device.sim.seed if args.seed is None else args.seed
    spec = RunSpec(procedure, config.station, seed=seed, rate_hz=config.device.rate_hz,
                   raw_counts=config.device.sim.raw_counts, method=args.method, on_motion=args.on_motion)
    speed = config.device.sim.speed if args.speed is None else args.speed
    return run_tui(spec, speed, _session_dir(args, procedure.name, f"seed{seed}"), None)


def _session_dir(args, procedure_name: str, what: str) -> Path | None:
    if args.no_capture:
        return None
    stamp = datetime.datetime.now().strftime("%Y%m%d-%H%M%S")
    return Path(args.out) / f"{procedure_name}-tui-{what}-{stamp}"


def live_spec(config, procedure, args):
    """The run of a real device: its model from the config; refused before any port is opened
    when the config cannot carry the procedure out."""
    from fieldcal.livedevice import LiveDevice
    from fieldcal.runner import RunSpec

    step = procedure.rate_step
    if step is not None:
        if config.table is None:
            raise ValueError(f"{config.path}: no table, and procedure {procedure.name} has rate steps "
                             f"at {step.rate_deg_s:g} °/s (add a table: section, or choose a static procedure)")
        if step.rate_deg_s > config.table.max_rate_deg_s:
            raise ValueError(f"procedure {procedure.name} turns the table at {step.rate_deg_s:g} °/s, above "
                             f"{config.path}'s table.max_rate_deg_s of {config.table.max_rate_deg_s:g} °/s")
    return RunSpec(procedure, config.station, rate_hz=config.device.rate_hz, method=args.method,
                   on_motion=args.on_motion, live=LiveDevice.from_config(config))
