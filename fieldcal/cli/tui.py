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


HELP_WIDTH = 80  # the help fits an 80-column terminal, whatever the terminal's width


class _HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """The description is wrapped (to HELP_WIDTH), the key list in the epilog kept as written."""

    def _fill_text(self, text, width, indent):
        return argparse.HelpFormatter._fill_text(self, text, width, indent) if "\n" not in text \
            else super()._fill_text(text, width, indent)


def _keys_epilog(setup_keys: str, run_keys: str) -> str:
    def indented(text: str) -> str:
        return "\n".join("  " + line if line else "" for line in text.splitlines())

    return (f"keys on the setup screen:\n{indented(setup_keys)}\n\n"
            f"keys during a run (b and w: the simulator only; in a replay only v, ? and q):\n"
            f"{indented(run_keys)}")


def add_tui_parser(sub) -> argparse.ArgumentParser:
    """Add the ``tui`` subcommand to the CLI's subparsers."""
    from fieldcal.tui.keys import SETUP_KEYS, SIM_KEYS

    tui = sub.add_parser(
        "tui", help="the operator's terminal UI: set up and run a calibration, or replay a session",
        description="The operator's terminal UI. It opens on the setup screen (device config, ports, "
        "procedure, station; the last choice is remembered, --config/--procedure override it), then "
        "runs the procedure on that device, capturing a session under --out. --sim skips the setup "
        "and runs the simulated bench at once; --replay shows a captured session through the same "
        "screens. The keys are listed below.",
        epilog=_keys_epilog(SETUP_KEYS, SIM_KEYS),
        formatter_class=lambda prog: _HelpFormatter(prog, width=HELP_WIDTH))
    from fieldcal.cli.options import add_run_options
    add_run_options(tui)
    tui.set_defaults(config=None, procedure=None)  # given or not: given ones override the setup's
    tui.add_argument("--sim", action="store_true",
                     help="no setup screen: run the simulated bench (config sim unless --config) now")
    tui.add_argument("--go", action="store_true",
                     help="no setup screen: run --config and --procedure now")
    tui.add_argument("--speed", type=_speed,
                     help="simulator: sample time per wall time, 1 = real time, 0 = as fast as possible "
                     "(default: the config's sim speed for a run, 10 for a replay)")
    tui.add_argument("--no-capture", action="store_true", help="do not write a session")
    tui.add_argument("--replay", metavar="SESSION", help="replay this session instead of running")
    from fieldcal.exit_status import EXIT_FAILED_SPEC
    tui.add_argument("--spec", metavar="SPEC", help="product spec YAML: the results say PASS/FAIL per "
                     f"parameter with the reason; exit status {EXIT_FAILED_SPEC} if any fails")
    tui.add_argument("--resume", metavar="SESSION",
                     help="continue this unfinished (quit) session after its last completed step; a live "
                     "device's on the ports of --config (default: the setup's last config)")
    from fieldcal.cli.options import add_operator_option, add_registry_option
    add_registry_option(tui)  # where the calibrations are recorded when the UI closes
    add_operator_option(tui)
    tui.set_defaults(func=cmd_tui)
    return tui


def cmd_tui(args) -> int:
    from fieldcal.cli.options import load_spec_option
    from fieldcal.tui import run_tui

    accept = {"product_spec": load_spec_option(args)}  # a bad spec stops it before any run
    if args.replay is not None:
        from fieldcal.run.runner import open_run

        if not Path(args.replay, "log.jsonl").is_file():
            raise ValueError(f"--replay: {args.replay} is not a session directory (no log.jsonl)")
        return run_tui(None, 10.0 if args.speed is None else args.speed, None, open_run(args.replay), **accept)
    if args.resume is not None:
        record = resumable(args.resume)
        if record.spec.live is None:
            status = run_tui(None, _resume_speed(args), None, None, resume=record, **accept)
        else:
            status = run_tui(None, 0.0, None, None, config=resume_config(record, args.config),
                             resume=record, **accept)
        record_sessions(args, [record.directory])
        return status
    if args.seed is not None and args.seed < 0:
        raise ValueError(f"--seed: expected a whole number >= 0, got {args.seed}")

    sessions: list[Path | None] = []
    make_run = _remembering(run_maker(args), sessions)
    if args.sim or args.go:
        from fieldcal.config import load_config
        from fieldcal.procedure.positions import load_procedure

        config = load_config(args.config or "sim")
        procedure = load_procedure(args.procedure or "field-18")
        spec, session_dir, speed = make_run(config, procedure)
        status = run_tui(spec, speed, session_dir, None, config=config, **accept)
    else:
        make_resume = _remembering_resume(resume_maker(args), sessions)
        status = run_tui(None, 0.0, None, None, setup=(_initial_choice(args), make_run, Path(args.out), make_resume),
                         **accept)
    record_sessions(args, sessions)
    return status


def _remembering(make_run, sessions: list):
    """``make_run`` that also notes each session directory it hands out."""
    def remembering(config, procedure, choice=None):
        made = make_run(config, procedure, choice)
        sessions.append(made[1])
        return made
    return remembering


def _remembering_resume(make_resume, sessions: list):
    """``make_resume`` that also notes each session the setup screen resumes."""
    def remembering(session, config):
        made = make_resume(session, config)
        sessions.append(session)
        return made
    return remembering


def record_sessions(args, sessions) -> None:
    """The calibrations the UI's sessions ended with, recorded in the registry once the terminal
    is back (a failure there is a warning; a session quit before calibrating has none)."""
    from fieldcal.cli.options import record_in_registry
    from fieldcal.session.record import RunRecord

    for session in sessions:
        if session is None or not Path(session, "log.jsonl").is_file():
            continue  # --no-capture, or never started
        try:
            params = RunRecord.open(session, log_only=True).parameters_path
        except (ValueError, OSError):  # damaged: the UI has said what became of it
            continue
        if params is not None:
            record_in_registry(args, params, None, "run")


def resumable(session: str):
    """The ``RunRecord`` of the session ``--resume`` continues; a one-line ValueError for one it cannot."""
    from fieldcal.cli.options import procedure_session
    from fieldcal.tui.choices import resume_refusal

    if not Path(session, "log.jsonl").is_file():
        raise ValueError(f"--resume: {session} is not a session directory (no log.jsonl)")
    record = procedure_session(session)
    refusal = resume_refusal(record)
    if refusal is not None:
        raise ValueError(f"--resume: {session} {refusal}")
    return record


def resume_config(record, config_name: str | None):
    """The station config whose ports a live session (``record``: its ``RunRecord``) is resumed
    on: ``--config``, else the setup screen's last choice (with its ports); a one-line ValueError
    if neither is of the session's device or its ports cannot be opened."""
    session, live = record.directory, record.spec.live
    from fieldcal.tui.choices import load_choice_config, load_last_choice, resolve_choice

    if config_name is not None:
        config = load_choice_config(config_name)
    else:
        choice = load_last_choice()
        if choice is None:
            raise ValueError(f"--resume: {session} is a live device's session: give its station config "
                             "(the ports) with --config")
        config = resolve_choice(choice)[0]
    return _checked_for(live, config, session)


def _checked_for(live, config, session: Path):
    """``config``, if it is the session's device (``live``) and its ports open."""
    from fieldcal.tui.live_source import check_same_device

    check_same_device(live, config, session)
    check_ports(config)
    return config


def resume_maker(args):
    """``make_resume(session, config) -> (speed, config, record)`` for the setup screen's Resume: a
    simulated session at the command line's speed (no config needed), a live one on the ports
    of the setup's ``config``; a one-line ValueError for what cannot be resumed."""
    from fieldcal.tui.choices import config_for_session

    def make_resume(session: Path, config):
        record = resumable(str(session))
        live = record.spec.live
        if live is None:
            return _resume_speed(args), None, record
        # the session's own device: the config chosen on the setup screen if it is that one's,
        # else a shipped config of that device on the session's port, with the session's serial
        return 0.0, _checked_for(live, config_for_session(live, config), session), record
    return make_resume


def _resume_speed(args) -> float:
    if args.speed is not None:
        return args.speed
    from fieldcal.config import load_config
    sim = load_config(args.config or "sim").device.sim  # (a real device's config has none)
    return (sim or load_config("sim").device.sim).speed


def run_maker(args):
    """``make_run(config, procedure, choice=None) -> (spec, session directory, speed)`` for the
    command line's options, the setup ``choice``'s operator and sessions directory in place of
    theirs; a live device's ports are opened (and closed) first, so that a port that cannot be
    opened is one line on the setup screen and no session directory is made for it."""
    def make_run(config, procedure, choice=None):
        if choice is not None:
            args_now = argparse.Namespace(**vars(args))
            args_now.operator = choice.operator or args.operator
            args_now.out = choice.out or args.out
        else:
            args_now = args
        return _make_run(config, procedure, args_now)

    def _make_run(config, procedure, args):
        if config.device.protocol != "sim":
            spec = live_spec(config, procedure, args)
            check_ports(config)
            return spec, _session_dir(args, procedure.name, "live"), 0.0
        return sim_run(config, procedure, args)
    return make_run


def check_ports(config) -> None:
    """Open and close the IMU's and the table's ports; a one-line ValueError naming the port
    that cannot be opened, and why."""
    import serial

    ports = [("IMU", config.device.port)]
    if config.table is not None and config.table.port is not None:
        ports.append(("table", config.table.port))
    for what, port in ports:
        try:
            serial.serial_for_url(port.url, baudrate=port.baudrate, timeout=0).close()
        except (serial.SerialException, OSError, ValueError) as exc:
            raise ValueError(f"{what} port {port.url}: cannot open it: {_reason(exc)}") from None


def _reason(exc: BaseException) -> str:
    """pyserial's text without the port it repeats: "No such file or directory"."""
    errno = getattr(exc, "errno", None)
    if isinstance(errno, int):
        import os
        return os.strerror(errno)
    text = " ".join(str(exc).split())
    return text.rsplit(": ", 1)[-1] if ": " in text else text


def _initial_choice(args):
    """The remembered choice, with the config and procedure given on the command line."""
    from dataclasses import replace

    from fieldcal.tui.choices import SetupChoice, load_last_choice

    choice = load_last_choice()
    # (--unit-serial, where the command line has it, fills the setup's unit serial field)
    given = {k: getattr(args, k, None) for k in ("operator", "out", "spec", "unit_serial")
             if getattr(args, k, None) is not None}
    if choice is None:
        if args.config is None and args.procedure is None and not given:
            return None
        from fieldcal.config import load_config
        config = load_config(args.config or "sim")
        choice = SetupChoice(args.config or "sim", None, args.procedure or "field-18",
                             config.station.latitude_deg, config.station.height_m)
    elif args.config is not None:
        from fieldcal.config import load_config
        config = load_config(args.config)
        choice = replace(choice, config=args.config, port=None, latitude_deg=config.station.latitude_deg,
                         height_m=config.station.height_m)
    if args.procedure is not None:
        choice = replace(choice, procedure=args.procedure)
    return replace(choice, **given)  # the command line's operator, sessions directory, spec, serial


def sim_run(config, procedure, args):
    """The simulated bench's run: (spec, session directory, speed)."""
    from fieldcal.cli.identity import unit_serial
    from fieldcal.cli.options import operator_option
    from fieldcal.run.runner import RunSpec

    seed = config.device.sim.seed if args.seed is None else args.seed
    spec = RunSpec(procedure, config.station, seed=seed, rate_hz=config.device.rate_hz,
                   raw_counts=config.device.sim.raw_counts, method=args.method, on_motion=args.on_motion,
                   flicker_tau_max_s=config.device.sim.flicker_tau_max_s,
                   operator=operator_option(args), unit_serial=unit_serial(args, config),
                   sim_thermal=config.device.sim.thermal, thermal=args.thermal or config.thermal)
    speed = config.device.sim.speed if args.speed is None else args.speed
    return spec, _session_dir(args, procedure.name, f"seed{seed}"), speed


def _session_dir(args, procedure_name: str, what: str) -> Path | None:
    if args.no_capture:
        return None
    from fieldcal.atomic import new_named_directory

    stamp = datetime.datetime.now().strftime("%Y%m%d-%H%M%S")
    return new_named_directory(args.out, f"{procedure_name}-tui-{what}-{stamp}", option="--out")


def live_spec(config, procedure, args):
    """The run of a real device: its model from the config; refused before any port is opened
    when the config cannot carry the procedure out."""
    from fieldcal.run.livedevice import LiveDevice
    from fieldcal.cli.identity import with_unit_serial
    from fieldcal.cli.options import operator_option
    from fieldcal.run.runner import RunSpec

    step = procedure.rate_steps[-1] if procedure.rate_steps else None  # the fastest
    if step is not None:
        if config.table is None:
            raise ValueError(f"{config.path}: no table, and procedure {procedure.name} has rate steps "
                             f"at {step.rate_deg_s:g} °/s (add a table: section, or choose a static procedure)")
        if step.rate_deg_s > config.table.max_rate_deg_s:
            raise ValueError(f"procedure {procedure.name} turns the table at {step.rate_deg_s:g} °/s, above "
                             f"{config.path}'s table.max_rate_deg_s of {config.table.max_rate_deg_s:g} °/s")
    return RunSpec(procedure, config.station, rate_hz=config.device.rate_hz, method=args.method,
                   on_motion=args.on_motion, live=LiveDevice.from_config(with_unit_serial(config, args)),
                   operator=operator_option(args), thermal=args.thermal or config.thermal)
