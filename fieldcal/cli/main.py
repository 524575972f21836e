"""The ``fieldcal`` command."""
from __future__ import annotations

import argparse
import math
import os
import sys

from fieldcal import __version__
from fieldcal.cli.options import _positive, _seed, _speed, add_run_options, add_thermal_option
from fieldcal.solvers.methods import METHODS

MAX_SERVE_RATE_HZ = 4000.0  # the fastest MEMS IMU output rates; above it the simulator cannot keep up


def _progress_printer(stream):
    interactive = stream.isatty()

    def progress(done: int, total: int, label: str) -> None:
        if interactive:
            print(f"\r  simulating segment {done}/{total} ({label})   ", end="", file=stream, flush=True)
            if done == total:
                print(file=stream)
        elif done == total or done % 9 == 0:
            print(f"  simulated segment {done}/{total}", file=stream, flush=True)
    return progress


def cmd_demo(args) -> int:
    from drivers.sim.device import paper_mimu
    from fieldcal.cli.station import station_from_options
    from fieldcal.report import solution_header, solution_table, worst_error
    from fieldcal.run.simcal import run_simulated_calibration

    station = station_from_options(args.latitude, args.height, args.gravity)
    if args.params:  # refused before the simulation, not after it
        from fieldcal.session.output import check_output_path
        check_output_path(args.params, force=args.force, option="--params")
    device = paper_mimu(raw_counts=args.raw_counts)
    print(f"fieldcal {__version__} demo: procedure {args.procedure} against the simulated MIMU "
          f"(paper Tables 3-4{', raw 16-bit counts' if args.raw_counts else ''}), seed {args.seed}")
    print(f"station: latitude {station.latitude_deg:.4f}°, height {station.height_m:.0f} m, "
          f"g = {station.gravity:.6f} m/s² ({station.gravity_source})")
    cal = run_simulated_calibration(args.seed, args.procedure, device, station,
                                    method=args.method, progress=_progress_printer(sys.stderr))
    seconds = cal.plan.windows[-1].start + cal.plan.windows[-1].duration
    print(f"simulated {seconds:.0f} s of {len(cal.plan.attitudes)} positions at 250 Hz; "
          "solved from the window averages\n")
    for name, sol in cal.solutions.items():
        print(solution_header(sol))
        print(solution_table(sol, cal.truth[name]))
        print()
    worst = worst_error(cal.solutions, cal.truth)
    for name, reason in cal.failures.items():
        print(f"{name}: not calibrated: {reason}")
    if not cal.solutions:
        return 1
    print(f"largest error: {worst:.2f}σ")
    if args.params:
        from fieldcal.session.output import save_parameter_file
        # the run's builder: the hash of the averages each triad was solved from (a classic
        # procedure's too, which has no norm problems)
        pf = cal.unit.parameter_file(cal.procedure, args.method, station, simulation=True)
        save_parameter_file(pf, args.params, force=args.force, option="--params")
        print(f"parameter file written to {args.params}")
    return 0


def cmd_monitor(args) -> int:
    from fieldcal.config import load_config
    from fieldcal.cli.monitor import run_monitor

    config = load_config(args.config)
    return run_monitor(config, sys.stdout, sys.stderr, max_samples=args.samples,
                       max_seconds=args.seconds)


def _at_least_zero(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not (math.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text!r}")
    return value


def cmd_sim_serve(args) -> int:
    import time

    from drivers.sim.device import paper_mimu
    from drivers.sim.serve import SimulatedDevices, TurnOnBias
    from fieldcal.cli.station import station_from_options
    from fieldcal.procedure.positions import load_procedure

    station = station_from_options(args.latitude, args.height)
    positions = load_procedure("field-18").positions
    if not 1 <= args.position <= len(positions):
        raise ValueError(f"--position: expected 1..{len(positions)} (field-18), got {args.position}")
    devices = SimulatedDevices(
        paper_mimu(raw_counts=args.raw_counts), station.gravity, station.latitude_rad,
        imu_protocol=args.imu_protocol, table_protocol=args.table_protocol, transport=args.transport,
        speed=args.speed, seed=args.seed, rate_hz=args.rate,
        attitude=positions[args.position - 1].attitude,
        turn_on_bias=TurnOnBias(args.turn_on_bias_deg_s, args.turn_on_bias_mg))
    with devices:
        try:  # from the first line on: a signal right after "serving" is a normal stop too
            print(f"simulated MIMU ({args.imu_protocol}, {args.rate:g} Hz, field-18 position "
                  f"{args.position}): {devices.imu_url}")
            if devices.table_url:
                print(f"simulated rate table ({args.table_protocol}): {devices.table_url}")
            print("serving until Ctrl-C", flush=True)
            while True:
                time.sleep(1.0)
        except (KeyboardInterrupt, Terminated):  # the ports and their links go with the block
            print(f"stopped after {devices.samples_sent} samples", flush=True)
    return 0


def _lazy(name: str):
    """A command handler from fieldcal.cli.sessions, imported only when that command runs."""
    def handler(args):
        from fieldcal.cli import sessions as sessions_cli
        return getattr(sessions_cli, name)(args)
    return handler


# Commands whose whole parser one function adds (module, function): a command line naming one of
# them is parsed by the top-level parser with that subcommand alone, the same parse and the same
# messages, without building (and importing) the other thirty-odd commands' parsers.
_ONE_FUNCTION_PARSERS = {"calibrate": ("fieldcal.cli.calibrate", "add_calibrate_parser"),
                         "import": ("fieldcal.cli.importing", "add_import_parser"),
                         "thermal": ("fieldcal.cli.thermal_log", "add_thermal_parser")}


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The ``fieldcal`` parser; ``command``: the command line's first word, when it may be built
    with only that subcommand's parser (``_ONE_FUNCTION_PARSERS``), else every command's."""
    parser = argparse.ArgumentParser(prog="fieldcal", description="Field calibration station for "
                                     "MIMU accelerometer, gyroscope and inclinometer triads.")
    parser.add_argument("--version", action="version", version=f"fieldcal {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    if command in _ONE_FUNCTION_PARSERS:
        import importlib
        module, function = _ONE_FUNCTION_PARSERS[command]
        getattr(importlib.import_module(module), function)(sub)
        return parser
    demo = sub.add_parser("demo", help="calibrate the simulated MIMU headless and compare with its truth",
                          description="Run a procedure against the simulated MIMU (errors of paper "
                          "Table 3, noise of Table 4), solve every triad with the norm method and "
                          "print the solved parameters beside the simulator's truth.")
    demo.add_argument("--seed", type=_seed, default=1, help="random seed (default 1)")
    demo.add_argument("--procedure", default="field-18", help="procedure name or YAML path "
                      "(default field-18)")
    demo.add_argument("--method", choices=METHODS, default="auto",
                      help="solver: auto (default) is classic for an aligned procedure, else powell")
    demo.add_argument("--latitude", type=float, default=40.0, help="station latitude, degrees (default 40)")
    demo.add_argument("--height", type=float, default=50.0, help="station height, m (default 50)")
    demo.add_argument("--gravity", type=float, metavar="M_S2",
                      help="measured local gravity, m/s² (default: WGS84 normal gravity)")
    demo.add_argument("--raw-counts", action="store_true", help="simulate a device reporting 16-bit counts")
    demo.add_argument("--params", metavar="FILE", help="also write the parameter file here")
    demo.add_argument("--force", action="store_true", help="replace the --params file if it exists")
    demo.set_defaults(func=cmd_demo)

    monitor = sub.add_parser("monitor", help="print decoded samples and parser counters from a device",
                             description="Connect to the configured device and print its decoded "
                             "samples (CSV when piped, a live line on a terminal) and the parser's "
                             "counters, until Ctrl-C.")
    monitor.add_argument("--config", required=True, help="station config: a name in configs/ or a path")
    monitor.add_argument("--samples", type=_positive(int), metavar="N", help="stop after N samples")
    monitor.add_argument("--seconds", type=_positive(float), metavar="S", help="stop after S seconds")
    monitor.set_defaults(func=cmd_monitor)

    run = sub.add_parser("run", help="run a procedure (headless: against the simulated device)",
                         description="Run a calibration procedure. With --headless, an automatic "
                         "operator moves the simulated unit through every position; the session "
                         "(every sample, action and event) and the parameter file are written "
                         "under --out, and the solved parameters are printed beside the truth.")
    add_run_options(run)
    run.add_argument("--headless", action="store_true", help="no terminal UI: the automatic operator")
    run.add_argument("--bump-step", type=int, metavar="N", help="the operator bumps the unit in step N")
    run.add_argument("--wrong-step", type=int, metavar="N",
                     help="the operator first puts the unit in a wrong position at step N")
    run.add_argument("--skip", type=int, action="append", default=[], metavar="N",
                     help="the operator skips step N (repeatable)")
    run.add_argument("--shuffle", type=int, metavar="SEED",
                     help="the operator places the positions in an order shuffled with SEED (a procedure "
                          "with any_order: true)")
    run.add_argument("--serial", action="store_true",
                     help="reach the simulated device only through bytes on a pty (Xsens frames, "
                     "ASCII table), as hardware would be; slower, and cannot be resumed")
    run.add_argument("--quiet", action="store_true", help="only the result, no progress lines")
    run.set_defaults(func=_lazy("cmd_run"))

    resume = sub.add_parser("resume", help="continue a run that was killed or quit (headless)",
                            description="Continue a session after its last completed step; the "
                            "result is what the uninterrupted run would have given. A real device's "
                            "session is continued on the ports of --config, its clock checked for a "
                            "power cycle as `fieldcal tui --resume` does, the operator at the console.")
    resume.add_argument("session", help="session directory")
    resume.add_argument("--config", metavar="CONFIG", help="a real device's session: the station config "
                        "whose ports it is resumed on (the same device; default: the terminal UI setup's "
                        "last choice); the operator places the unit and presses Enter at the console")
    from fieldcal.cli.identity import add_unit_serial_option
    add_unit_serial_option(resume, "the unit the session was recorded of (checked, never changed)")
    resume.add_argument("--quiet", action="store_true")
    resume.set_defaults(func=_lazy("cmd_resume"))

    replay = sub.add_parser("replay", help="feed a captured session through a fresh engine and solver",
                            description="Replay a session's samples and operator actions through a "
                            "fresh engine and solver, and check that the parameter file comes out "
                            "byte for byte the same.")
    replay.add_argument("session", help="session directory")
    replay.add_argument("--speed", type=_positive(float), help="times real time (default: as fast as possible)")
    replay.add_argument("--out", metavar="FILE", help="also write the replayed parameter file here "
                        "(never inside a session)")
    replay.add_argument("--force", action="store_true", help="replace the --out file if it exists")
    replay.add_argument("--quiet", action="store_true")
    replay.set_defaults(func=_lazy("cmd_replay"))

    solve = sub.add_parser("solve", help="re-solve a session from its averages, methods side by side",
                           description="Re-solve a session from its stored per-step averages and "
                           "print the methods side by side, as paper Table 5 does.")
    solve.add_argument("session", help="session directory")
    solve.add_argument("--method", choices=METHODS[1:], action="append",
                       help="powell, lsq or classic (repeatable; default: powell and lsq, or "
                       "classic for an aligned procedure)")
    add_thermal_option(solve, "the session's")
    solve.set_defaults(func=_lazy("cmd_solve"))

    allan = sub.add_parser("allan", help="Allan noise terms, recommended dwell and a plot from a still record",
                           description="Allan deviation (paper eq. 3) of a still record: a session "
                           "(its longest static dwell) or a text file of rows 't, x, y, z' (s, SI). "
                           "Prints the IEEE 952 noise terms per axis and the recommended dwell, and "
                           "writes a log-log plot per triad.")
    allan.add_argument("source", help="session directory or text file")
    allan.add_argument("--kind", choices=("specific_force", "angular_rate"), default="angular_rate",
                       help="what a text file holds (default angular_rate)")
    allan.add_argument("--triad", action="append", help="only this triad of a session (repeatable)")
    allan.add_argument("--plot-dir", help="where the PNGs go (default: beside the source)")
    allan.add_argument("--force", action="store_true", help="replace plots left by an earlier allan")
    allan.set_defaults(func=lambda args: __import__("fieldcal.cli.allan", fromlist=["cmd_allan"]).cmd_allan(args))

    sim = sub.add_parser("sim", help="the simulated MIMU and rate table")
    sim_sub = sim.add_subparsers(dest="sim_command", required=True, metavar="SIM_COMMAND")
    serve = sim_sub.add_parser("serve", help="serve the simulated devices on virtual serial ports",
                               description="Serve the simulated MIMU and rate table over "
                               "pseudo-terminals (or TCP on 127.0.0.1) in real device protocols, and "
                               "print the ports to point the station at. Runs until Ctrl-C.")
    serve.add_argument("--imu-protocol", choices=("xsens", "vectornav", "delimited"), default="xsens")
    serve.add_argument("--table-protocol", choices=("ascii", "grbl"), default="ascii")
    serve.add_argument("--transport", choices=("pty", "tcp"), default="pty")
    serve.add_argument("--speed", type=_speed, default=1.0,
                       help="1 = real time (default), 10 = ten times faster, 0 = as fast as read")
    serve.add_argument("--rate", type=_positive(float, MAX_SERVE_RATE_HZ, " Hz"), default=250.0,
                       help=f"sample rate, Hz (default 250, at most {MAX_SERVE_RATE_HZ:g})")
    serve.add_argument("--position", type=int, default=1, help="field-18 position of the unit (default 1)")
    serve.add_argument("--seed", type=_seed, default=1)
    serve.add_argument("--latitude", type=float, default=40.0, help="degrees (default 40)")
    serve.add_argument("--height", type=float, default=50.0, help="m (default 50)")
    serve.add_argument("--raw-counts", action="store_true", help="the unit reports 16-bit counts")
    serve.add_argument("--turn-on-bias-deg-s", type=_at_least_zero, default=0.0, metavar="SIGMA",
                       help="gyro bias repeatability, 1σ per axis in °/s: each switch-on (each --seed) "
                            "draws its own bias (default 0: the biases repeat exactly)")
    serve.add_argument("--turn-on-bias-mg", type=_at_least_zero, default=0.0, metavar="SIGMA",
                       help="accelerometer bias repeatability, 1σ per axis in mg (default 0)")
    serve.set_defaults(func=cmd_sim_serve)

    from fieldcal.cli.tui import add_tui_parser
    add_tui_parser(sub)
    from fieldcal.cli.calibrate import add_calibrate_parser
    from fieldcal.cli.importing import add_import_parser
    add_import_parser(sub)
    add_calibrate_parser(sub)
    from fieldcal.cli.thermal_log import add_thermal_parser
    add_thermal_parser(sub)
    from fieldcal.cli.options import add_operator_option, add_registry_option, add_spec_option
    from fieldcal.cli.production import add_production_parsers
    add_spec_option(run)
    add_operator_option(run)
    add_registry_option(replay)
    add_registry_option(resume)
    add_production_parsers(sub)
    from fieldcal.planning.command import add_plan_parser
    add_plan_parser(sub)
    return parser


class Terminated(BaseException):
    """SIGTERM, raised in the main thread so that it unwinds like Ctrl-C (files closed)."""


def _raise_terminated(signum, frame):
    raise Terminated


def _raise_interrupted(signum, frame):
    """Ctrl-C as fieldcal's own handler, not whatever the process had (issue 26: a host that had
    replaced the interpreter's default handler turned an operator's Ctrl-C into a run that went on)."""
    raise KeyboardInterrupt


def _session(args):
    """The session directory the command was writing, if any."""
    return getattr(args, "session_path", None) or (args.session if args.command == "resume" else None)


def _session_note(args, what: str) -> str:
    """What became of the session a command was writing when it stopped, and how to go on."""
    session = _session(args)
    if session is None:
        return ""
    if getattr(args, "serial", False):
        return f"; the session so far is in {session} (a serial run cannot be resumed: run again)"
    return (f"; the session in {session} is consistent up to its last completed step{what}: "
            f"continue it with: fieldcal resume {session}")


def _os_error(exc: OSError, args) -> str:
    """One line for a failed read or write: the file, what the system said, and for a session,
    where it stands."""
    import errno

    # a buffered write's error carries no file name: the session being written is the place
    place = exc.filename or _session(args)
    where = f"{place}: " if place else ""
    reason = exc.strerror or str(exc)
    if exc.errno in (errno.ENOSPC, errno.EDQUOT):
        return f"{where}{reason}" + _session_note(args, " (free some space first)")
    if exc.errno == errno.ENAMETOOLONG:
        return f"{where}a name in this path is too long for the file system"
    return f"{where}{reason}" + _session_note(args, "")


def run() -> int:
    """The ``fieldcal`` command's entry point: ``main``, in a process that ends with it."""
    return main(ending_process=True)


def main(argv=None, *, ending_process: bool = False) -> int:
    """``ending_process``: the interpreter exits when this returns, so what the command's imports
    froze (imports_uncollected) stays frozen: the collection at shutdown then skips those some
    50,000 long-lived objects (about 40 ms). What the command itself made is collected as ever."""
    import signal
    import threading

    argv = sys.argv[1:] if argv is None else list(argv)
    args = build_parser(argv[0] if argv else None).parse_args(argv)
    # The terminal UI restores the terminal on its own way out; everything else unwinds on
    # SIGTERM as on Ctrl-C, closing its files and saying where its session is. Ctrl-C is caught
    # by fieldcal's own handler too, unless the process was started ignoring it (a background job).
    catch_sigterm = threading.current_thread() is threading.main_thread() and args.command != "tui"
    previous = signal.signal(signal.SIGTERM, _raise_terminated) if catch_sigterm else None
    catch_sigint = catch_sigterm and signal.getsignal(signal.SIGINT) is not signal.SIG_IGN
    previous_sigint = signal.signal(signal.SIGINT, _raise_interrupted) if catch_sigint else None
    try:
        from fieldcal.atomic import command_reads
        from fieldcal.cli.paths import check_paths, flush_stdout, stdout_named
        with command_reads(), stdout_named(args.command):  # what the command reads, it never writes over
            check_paths(args)
            status = args.func(args)
            flush_stdout()  # a failure to show the result is the command's failure, said now
            return status
    except ValueError as exc:  # ConfigError, ProcedureError, ParameterFileError, bad arguments
        print(f"fieldcal: {exc}", file=sys.stderr)
        return getattr(exc, "exit_status", 2)  # 1: input read whole but nothing to calibrate from
    except BrokenPipeError:  # output piped into head: not an error
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except OSError as exc:  # disk full, unwritable, removed under us: one line, never a traceback
        if exc.filename == "standard output":  # what is left unwritten: dropped, not said again at exit
            try:
                os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            except (OSError, ValueError, AttributeError):  # a stream with no descriptor (a test's capture)
                pass
        print(f"fieldcal: {_os_error(exc, args)}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"fieldcal: interrupted{_session_note(args, '')}", file=sys.stderr)
        return 130
    except Terminated:
        print(f"fieldcal: terminated (SIGTERM){_session_note(args, '')}", file=sys.stderr)
        return 128 + signal.SIGTERM
    finally:
        if not ending_process:
            from fieldcal.cli.startup import thaw
            thaw()  # what a command froze for its own run (imports_uncollected), collectable again
        if catch_sigterm:  # None: a handler not set from Python; the default is what it did
            signal.signal(signal.SIGTERM, signal.SIG_DFL if previous is None else previous)
        if catch_sigint:
            signal.signal(signal.SIGINT, signal.SIG_DFL if previous_sigint is None else previous_sigint)


if __name__ == "__main__":
    raise SystemExit(run())
