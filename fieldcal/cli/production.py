"""The production commands: ``fieldcal check`` (acceptance limits), ``export``, ``apply``,
``units``, ``history``, ``registry rebuild`` and ``certificate`` (``resolve``: its arguments here, the
command in cli.resolve, loaded only when it runs). The options they share with other commands
(--spec, --registry, --operator) are in cli.options."""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from fieldcal.cli.options import (add_registry_option, add_spec_option, find_sessions, open_registry,
                                  previous_calibration_of, report_acceptance)
from fieldcal.exit_status import EXIT_FAILED_SPEC, EXIT_SOME_FAILED


def cmd_check(args) -> int:
    from fieldcal.acceptance import load_spec
    verdict = report_acceptance(load_spec(args.spec), args.params, args.previous)
    return 0 if verdict.passed else EXIT_FAILED_SPEC


def cmd_export(args) -> int:
    from fieldcal.atomic import write_atomically
    from fieldcal.export import export
    from fieldcal.export.autopilot import diagonal_parameters
    from fieldcal.paramfile import load
    from fieldcal.session.output import check_output_path

    if args.out:
        check_output_path(args.out, force=args.force, option="--out", inputs=[args.params])
    elif sys.stdout is None or sys.stdout.closed:  # started with >&-
        raise ValueError("export: standard output is closed: give --out FILE")
    parameters = load(args.params)
    text = export(parameters, args.format, accelerometer=args.accelerometer, gyroscope=args.gyroscope)
    if args.format in ("ardupilot", "px4"):  # say what the format cannot hold, where people look
        for loss in diagonal_parameters(parameters, args.format, args.accelerometer, args.gyroscope,
                                        gyro_scale=False)[1]:
            print(f"fieldcal export: {args.format}: {loss.line()}", file=sys.stderr)
        from fieldcal.export.autopilot import NOT_WRITTEN
        for line in text.splitlines():  # what the file leaves out for want of a calibration
            if line.startswith(NOT_WRITTEN):
                print(f"fieldcal export: {args.format}: {line[2:]}", file=sys.stderr)
    if args.out:
        write_atomically(args.out, text.encode("utf-8"), overwrite=args.force, hint="give --force to replace it",
                         inputs=[args.params])
        print(f"{args.format} written to {args.out}", file=sys.stderr)
    else:
        from fieldcal.cli.paths import write_stdout
        write_stdout(text)
    return 0


def _apply_targets(args, paths) -> list[Path | None]:
    """Where each input's CSV goes: stdout (None), --out as a file (one input) or a directory."""
    from fieldcal.session.output import check_output_path

    if args.out is None:
        if len(paths) > 1:
            raise ValueError("apply: several input files give several CSVs: give --out DIR")
        return [None]
    out = Path(args.out)
    targets = [out] if len(paths) == 1 and not out.is_dir() else \
        [out / f"{Path(path).stem}-calibrated.csv" for path in paths]
    if len(paths) > 1 and not out.is_dir():
        raise ValueError(f"apply: --out {out}: several input files need an existing directory")
    written = {}
    for path, target in zip(paths, targets):
        if target.resolve() in written:
            raise ValueError(f"apply: {written[target.resolve()]} and {path} would both be written to {target}: "
                             "give them different file names, or apply them one at a time")
        written[target.resolve()] = path
    _refuse_own_files(targets, [*paths, args.params])
    for target in targets:
        check_output_path(target, force=args.force, option="--out")
    return targets


def _refuse_own_files(targets, sources) -> None:
    """An output that is one of the command's own inputs (or its parameter file) is refused,
    --force or not: it would be read while it is replaced."""
    for target in targets:
        for source in sources:  # (a --config name such as ``sim`` is no file: not compared)
            if Path(source).exists() and (Path(target).resolve() == Path(source).resolve() or (
                    Path(target).exists() and os.path.samefile(target, source))):
                raise ValueError(f"apply: --out {target} is the input {source}: give another output path")


def _write_csv(target: Path | None, write, source: str, force: bool = False) -> int:
    """``write(binary file)`` to stdout, or to ``target`` whole or not at all (the rule of
    fieldcal.atomic); what it returns (the samples written)."""
    from fieldcal.atomic import atomic_file

    if target is None:
        n = write(sys.stdout.buffer)
        sys.stdout.buffer.flush()
        return n
    with atomic_file(target, overwrite=force, hint="give --force to replace it", inputs=[source]) as pending:
        n = write(pending.file)
    print(f"{source}: {n} samples calibrated into {target}", file=sys.stderr)
    return n


# Which input each option is for, in its own words.
_APPLY_OPTIONS = {"samples": "live", "seconds": "live", "map": "text", "rate": "text", "topic": "log", "imu": "log"}
_APPLY_INPUTS = {"live": "a live device (--config)", "text": "text INPUT files", "log": "a log INPUT (.ulg, .bag, .bin)"}


def cmd_apply(args) -> int:
    from fieldcal.paramfile import load
    from fieldcal.recording.logs import LOG_NAMES, log_format

    if bool(args.input) == bool(args.config):
        raise ValueError("apply: give the recording's INPUT files or a live device (--config), one of the two")
    if args.input:  # '-' or a file mostly of zeros: one line before anything is read (pipes: plan's)
        from fieldcal.recording.inputs import check_input
        for path in args.input:
            if path == "-" or os.path.isfile(path):
                check_input(path, "recording")
    if args.out is None and (sys.stdout is None or sys.stdout.closed):  # started with >&-
        raise ValueError("apply: standard output is closed: give --out FILE")
    kind = "live" if args.config else "log" if (args.map is None and len(args.input) == 1
                                                and log_format(args.input[0]) is not None) else "text"
    for name, owner in _APPLY_OPTIONS.items():
        if getattr(args, name) is not None and owner != kind:
            raise ValueError(f"apply: --{name} is for {_APPLY_INPUTS[owner]}, not {_APPLY_INPUTS[kind]}")
    if kind == "live":
        return _apply_device(args, _said(load(args.params)))
    if kind == "log":
        from fieldcal.apply.logs import apply_log

        parameters = _said(load(args.params))
        [target] = _apply_targets(args, args.input)
        skipped = []
        _write_csv(target, lambda out: _logged(apply_log(parameters, args.input[0], out, args.topic, args.imu,
                                                         args.hold_temperature_edge, _say), skipped),
                   args.input[0], args.force)
        for name in skipped:
            print(f"fieldcal apply: {args.input[0]}: triad {name!r} is not in {args.params}: not written",
                  file=sys.stderr)
        return 0
    if args.map is None:
        raise ValueError(f"apply: text INPUT files need their import map: give --map MAP (see fieldcal "
                         f"import); {LOG_NAMES} needs none")
    if args.rate is not None and not args.rate > 0:
        raise ValueError(f"apply: --rate: expected a sample rate above 0 Hz, got {args.rate:g}")
    from fieldcal.apply import apply_file, plan
    from fieldcal.recording.import_map import load_import_map

    plans = plan(_said(load(args.params)), load_import_map(args.map), args.input, args.rate,
                 args.hold_temperature_edge)
    targets = _apply_targets(args, [p.path for p in plans])
    for p, target in zip(plans, targets):
        for name in p.skipped:
            print(f"fieldcal apply: {p.path}: triad {name!r} is not in {args.params}: not written",
                  file=sys.stderr)
        _write_csv(target, lambda out, p=p: apply_file(p, out, warn=_say), p.path, args.force)
    return 0


def _say(line: str) -> None:
    print(f"fieldcal {line}", file=sys.stderr)


def _said(parameters):
    """``parameters``, once stderr has said which of its parameters are not calibrated and so
    left uncorrected."""
    from fieldcal.apply import not_calibrated_lines

    for line in not_calibrated_lines(parameters):
        print(f"fieldcal {line}", file=sys.stderr)
    return parameters


def _logged(result, skipped: list) -> int:
    """apply_log's samples; its skipped triads into ``skipped``, what its import did said."""
    n, names, report = result
    skipped.extend(names)
    for note in (*report.alignment, *report.warnings):  # samples dropped, the IMU or topic read
        print(f"fieldcal apply: {note}", file=sys.stderr)
    return n


def _apply_device(args, parameters) -> int:
    """A live device's calibrated CSV, to stdout or --out (written as it comes, a block at a
    time); Ctrl-C ends it after the block being written, never inside a line."""
    import signal
    import threading

    from fieldcal.apply.live import apply_device, device_calibrations
    from fieldcal.apply.thermal import TemperatureOutside
    from fieldcal.config import load_config
    from fieldcal.session.output import check_output_path

    config = load_config(args.config)
    calibrations, skipped = device_calibrations(parameters, config)
    for name in skipped:
        print(f"fieldcal apply: {config.device.name}'s triad {name!r} is not in {args.params}: not written",
              file=sys.stderr)
    if args.out is not None:
        _refuse_own_files([args.out], [args.params, args.config])
        check_output_path(Path(args.out), force=args.force, option="--out")
    stop = threading.Event()
    in_main = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGINT, lambda *_: stop.set()) if in_main else None
    refused = None
    try:
        if args.out is None:
            written = apply_device(config, calibrations, sys.stdout.buffer, sys.stderr, stop,
                                   args.samples, args.seconds, args.hold_temperature_edge)
        else:  # into a partial file, renamed once samples were written: a start that fails
            # (no device, no samples) leaves the file --force would replace as it was
            from fieldcal.atomic import atomic_file
            with atomic_file(args.out, overwrite=args.force, hint="give --force to replace it",
                             inputs=[args.params, args.config]) as pending:
                try:
                    written = apply_device(config, calibrations, pending.file, sys.stderr, stop, args.samples,
                                           args.seconds, args.hold_temperature_edge)
                except TemperatureOutside as exc:  # the samples streamed before it are kept
                    written, refused = exc.written, exc
                pending.keep = bool(written)
            if written:
                print(f"{written} samples calibrated into {args.out}", file=sys.stderr)
            if refused is not None:
                raise refused
    finally:
        if in_main:
            signal.signal(signal.SIGINT, previous)
    return 0 if written else 1


def cmd_units(args) -> int:
    from fieldcal.registry import NO_SERIAL
    from fieldcal.report import aligned

    with open_registry(args, read_only=True) as registry:
        units = registry.units()
    if not units:
        print(f"no units in {registry.where} (fieldcal registry rebuild DIR indexes sessions)")
        return 0
    verdicts = {None: "-", 1: "PASS", 0: "FAIL"}
    rows = [["serial", "model", "calibrations", "last", "last result"]]
    rows += [[serial or NO_SERIAL, model or "(none)", str(n), last, verdicts[passed]]
             for serial, model, n, last, passed in units]
    print(aligned(rows, "llrll", indent=""))
    return 0


def cmd_history(args) -> int:
    from fieldcal.acceptance import load_spec
    from fieldcal.registry import NO_SERIAL, UNKNOWN
    from fieldcal.registry.drift import history_lines

    spec = load_spec(args.spec) if args.spec else None
    unnamed = args.serial == NO_SERIAL  # what `units` lists calibrations without a serial as
    with open_registry(args, read_only=True) as registry:
        calibrations = registry.history(UNKNOWN if unnamed else args.serial)
    if not calibrations:
        raise ValueError(f"history: no unit with serial {args.serial!r} in {registry.where} "
                         "(fieldcal units lists them)")
    for line in history_lines(calibrations, spec, one_unit=not unnamed):
        print(line)
    if args.plot:
        from fieldcal.registry.drift import plot_history
        for path in plot_history(calibrations, "no-serial" if unnamed else args.serial, args.plot,
                                 overwrite=args.force):
            print(f"plot: {path}")
    return 0


def cmd_registry_rebuild(args) -> int:
    from fieldcal.registry import session_parameter_files

    from fieldcal.session.history import EDITED, recorded_check

    sessions = find_sessions(args.directory, "registry rebuild")
    added = known = bad = edited = 0
    with open_registry(args) as registry:
        for session in sessions:
            for params in session_parameter_files(session):
                if recorded_check(params) == EDITED:  # not what the calibration produced: not indexed as such
                    edited += 1
                    print(f"warning: {params}: not indexed: {EDITED} (its SHA-256 differs from the one its "
                          "session logged); restore it, or re-solve the session (fieldcal resolve)", file=sys.stderr)
                    continue
                try:
                    if registry.record(params):
                        added += 1
                    else:
                        known += 1
                except (ValueError, OSError) as exc:  # one bad file never stops the rebuild
                    bad += 1
                    print(f"warning: {params}: not indexed: {str(exc).splitlines()[0]}", file=sys.stderr)
    print(f"{registry.where}: {len(sessions)} sessions, {added} calibrations added, {known} already "
          f"there, {bad} unreadable" + (f", {edited} edited after calibration (not indexed)" if edited else ""))
    return 0


def cmd_certificate(args) -> int:
    from fieldcal.acceptance import evaluate, load_spec
    from fieldcal.atomic import write_atomically
    from fieldcal.certificate import certificate_html
    from fieldcal.certificate.evidence import gather
    from fieldcal.paramfile import load
    from fieldcal.run.runner import open_run
    from fieldcal.session.history import recorded_check
    from fieldcal.session.output import check_output_path

    session = Path(args.session)
    out = Path(args.out) if args.out else Path(f"{session.resolve().name}-certificate.html")
    pdf = out.with_suffix(".pdf")
    check_output_path(out, force=args.force, option="--out")
    if not args.no_pdf:
        check_output_path(pdf, force=args.force, option="--out (its PDF)")
    spec = load_spec(args.spec) if args.spec else None
    record = open_run(session, recordings=True)  # one scan; every step document checked
    params = record.parameters_path
    if params is None:
        raise ValueError(f"certificate: {session}: the session has no parameter file (not calibrated)")
    parameters = load(params)
    verdict = previous = None
    if spec is not None:
        previous = previous_calibration_of(params)
        verdict = evaluate(spec, parameters, previous.parameters if previous is not None else None)
    page = certificate_html(session, params, parameters, recorded_check(params, record), verdict,
                            record.stop_reason, gather(record), spec, previous)
    write_atomically(out, page.encode("utf-8"), overwrite=args.force, hint="give --force to replace it")
    print(f"certificate: {out}")
    if not args.no_pdf:
        _certificate_pdf(out, pdf, args.force)
    return 0 if verdict is None or verdict.passed else EXIT_FAILED_SPEC


def _certificate_pdf(page: Path, pdf: Path, force: bool = False) -> None:
    """The PDF beside the page where a headless Chromium is installed; one line either way (a
    failed print is a warning: the HTML page is the certificate)."""
    from fieldcal.certificate.render import find_browser, print_pdf

    browser = find_browser()
    if browser is None:
        print("certificate: no PDF: no Chromium found on PATH (apt-get install chromium); the HTML "
              "page is the certificate")
        return
    try:
        print_pdf(page, pdf, browser, overwrite=force)
    except ValueError as exc:
        print(f"warning: certificate: no PDF: {exc}", file=sys.stderr)
        return
    print(f"certificate PDF: {pdf}")


def add_production_parsers(sub) -> None:
    from fieldcal.cli.importing import add_log_options
    from fieldcal.cli.options import _positive
    check = sub.add_parser(
        "check", help="PASS/FAIL of a parameter file against a product spec",
        description="Check every parameter of a parameter file against a product spec's acceptance "
        "limits (range, σ, residual, drift since the previous calibration), in operator units.",
        epilog=f"exit status: 0 every check passed, {EXIT_FAILED_SPEC} a check failed, 2 bad input")
    check.add_argument("params", metavar="PARAMS", help="parameter file")
    check.add_argument("--spec", metavar="SPEC", required=True, help="product spec YAML")
    check.add_argument("--previous", metavar="FILE", help="the unit's previous parameter file, for the "
                       "drift (default: the newest sibling session's, when PARAMS is in a session)")
    check.set_defaults(func=cmd_check)

    from fieldcal.export import FORMATS  # light: no heavy imports
    export = sub.add_parser(
        "export", help="a parameter file for ArduPilot, PX4, imucal, firmware (C) or as JSON",
        description="Write a parameter file in another tool's format. ardupilot and px4 hold only "
        "offsets and diagonal scales (ArduPilot no gyro scale): what is dropped, and the worst error "
        "it costs, is printed on stderr and written in the file's comments.")
    export.add_argument("params", metavar="PARAMS", help="parameter file")
    export.add_argument("--format", required=True, choices=FORMATS)
    export.add_argument("--out", metavar="FILE", help="write here (default: standard output)")
    export.add_argument("--force", action="store_true", help="replace the --out file if it exists")
    export.add_argument("--accelerometer", default="accelerometer", metavar="TRIAD",
                        help="the accelerometer triad (default accelerometer)")
    export.add_argument("--gyroscope", default="gyroscope", metavar="TRIAD",
                        help="the gyroscope triad (default gyroscope)")
    export.set_defaults(func=cmd_export)

    apply = sub.add_parser(
        "apply", help="calibrated CSV from a recording (text or a log) or a live device",
        description="Calibrate each triad, K⁻¹(raw − bias) into SI units (m/s^2, rad/s), and write "
        "CSV: a time column t_s, then x, y, z per triad, every number in the fewest digits that "
        "read back to it exactly. From a recording's text files in an import map's layout (--map): "
        "streamed, block by block (a malformed line stops it with the line's number). From a log "
        "(PX4 .ulg, ROS 1 .bag or a ROS 2 bag directory, ArduPilot .bin; no --map): read whole "
        "into memory by fieldcal import's reader, not streamed. From a live "
        "device (--config, as fieldcal monitor reads it: a serial port, socket://, or the "
        "simulated device): streamed and flushed a block at a time until Ctrl-C, --samples or "
        "--seconds; Ctrl-C ends it between lines.")
    apply.add_argument("params", metavar="PARAMS", help="parameter file")
    apply.add_argument("input", nargs="*", metavar="INPUT", help="text files, one per map entry, or one log")
    apply.add_argument("--map", metavar="MAP", help="import map of the INPUT files: a name in "
                       "configs/recordings or a YAML path (see fieldcal import)")
    apply.add_argument("--config", metavar="CONFIG", help="read this station config's device live "
                       "instead of files: a name in configs/ or a path")
    apply.add_argument("--out", metavar="PATH", help="the CSV (one input or a device) or a directory "
                       "for INPUT-calibrated.csv files (default: standard output, one input)")
    apply.add_argument("--force", action="store_true", help="replace existing output files")
    apply.add_argument("--rate", type=float, metavar="HZ",
                       help="sample rate of files with no time column (else rate_hz in the map)")
    apply.add_argument("--hold-temperature-edge", action="store_true",
                       help="correct samples outside a thermal model's calibrated temperature range at the "
                       "range's nearest edge (said in one line; default: refused, never extrapolated)")
    add_log_options(apply)
    apply.add_argument("--samples", type=_positive(int), metavar="N", help="live: stop after N samples")
    apply.add_argument("--seconds", type=_positive(float), metavar="S", help="live: stop after S seconds")
    apply.set_defaults(func=cmd_apply)

    units = sub.add_parser("units", help="the units in the registry, with their last calibration",
                           description="List every unit in the unit registry: serial, model, how "
                           "many calibrations, the last one's time and result.")
    add_registry_option(units)
    units.set_defaults(func=cmd_units)
    history = sub.add_parser(
        "history", help="one unit's calibrations over time, with the drift of every parameter",
        description="Every calibration of one unit, oldest first, each parameter ± 1σ in operator "
        "units and its drift since the calibration before in σ (the two calibrations' 1σ combined); "
        "with --spec, drift beyond the product's max_drift is flagged.")
    history.add_argument("serial", metavar="SERIAL", help="as `fieldcal units` lists it; \"(none)\": "
                         "the calibrations recorded without a serial (listed, never compared for drift)")
    history.add_argument("--spec", metavar="SPEC", help="product spec: flag drift beyond its max_drift")
    history.add_argument("--plot", metavar="DIR", help="also write a PNG per triad here: each "
                         "parameter over time with ± 1σ bars")
    history.add_argument("--force", action="store_true", help="replace the --plot PNGs if they exist")
    add_registry_option(history)
    history.set_defaults(func=cmd_history)
    registry = sub.add_parser("registry", help="the unit registry")
    registry_sub = registry.add_subparsers(dest="registry_command", required=True, metavar="COMMAND")
    rebuild = registry_sub.add_parser(
        "rebuild", help="index sessions into the registry",
        description="Index every calibration (parameters-NNN.yaml) of the sessions in each DIR (a "
        "session, or a directory of sessions). Files already indexed are left as they are.")
    rebuild.add_argument("directory", nargs="+", metavar="DIR")
    add_registry_option(rebuild)
    rebuild.set_defaults(func=cmd_registry_rebuild)

    add_resolve_parser(sub)

    certificate = sub.add_parser(
        "certificate", help="a self-contained HTML calibration certificate for a session",
        description="Write one HTML page (no scripts, no external files) with the unit, station, "
        "temperature, procedure, every parameter ± 1σ (PASS/FAIL with --spec), each triad's residual "
        "per position (from re-solving the session), the Allan plots `fieldcal allan SESSION` left in "
        "the session and the parameter file's SHA-256; and its PDF beside it where a headless "
        "Chromium is installed.",
        epilog=f"exit status: 0 written (and passed), {EXIT_FAILED_SPEC} written but a --spec check failed")
    certificate.add_argument("session", metavar="SESSION", help="session directory")
    certificate.add_argument("--spec", metavar="SPEC", help="product spec: PASS/FAIL per parameter")
    certificate.add_argument("--out", metavar="FILE", help="default ./SESSION-certificate.html")
    certificate.add_argument("--force", action="store_true", help="replace the --out file (and its PDF) "
                             "if it exists")
    certificate.add_argument("--no-pdf", action="store_true", help="only the HTML page, even where "
                             "Chromium is installed")
    certificate.set_defaults(func=cmd_certificate)


def _jobs(text: str) -> int:
    value = int(text) if text.isdigit() else 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a whole number of processes >= 1, got {text!r}")
    return value


def _cmd_resolve(args) -> int:
    """fieldcal.cli.resolve (its worker pool and result records) loads only when resolve runs."""
    from fieldcal.cli.resolve import cmd_resolve
    return cmd_resolve(args)


def add_resolve_parser(sub) -> None:
    from fieldcal.solvers.methods import METHODS

    parser = sub.add_parser(
        "resolve", help="re-solve many sessions in parallel, writing and registering the results",
        description="Re-solve every session in each DIR (a session, or a directory of sessions) from "
        "the step averages in its log, in N processes. A result that differs from the session's "
        "current parameter file goes into its next parameters-NNN.yaml (earlier files are kept); "
        "every result is recorded in the unit registry. A session that cannot be re-solved is "
        "reported in one line and skipped.",
        epilog=f"exit status: 0 all re-solved, {EXIT_SOME_FAILED} some could not be, 3 all re-solved "
        "but some failed --spec, 2 bad arguments")
    parser.add_argument("directory", nargs="+", metavar="DIR")
    parser.add_argument("-j", "--jobs", type=_jobs, default=1, metavar="N",
                        help="processes re-solving at once (default 1)")
    parser.add_argument("--method", choices=METHODS[1:], help="solve with this method instead of "
                        "each session's own")
    from fieldcal.cli.options import add_thermal_option
    add_thermal_option(parser, "each session's own")
    add_spec_option(parser)
    parser.set_defaults(func=_cmd_resolve)
