"""The production commands: ``fieldcal check`` (acceptance limits), ``export`` and ``apply``;
and ``--spec`` for the commands that calibrate (run --headless, calibrate)."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

# The exit status of a calibration that finished but failed its product's acceptance limits
# (0: passed; 1: not calibrated; 2: bad input).
EXIT_FAILED_SPEC = 3

SPEC_HELP = (f"product spec YAML: PASS/FAIL per parameter with the reason; exit status "
             f"{EXIT_FAILED_SPEC} if any fails")


def add_spec_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--spec", metavar="SPEC", help=SPEC_HELP)


def load_spec_option(args):
    """The --spec file, read before any work is done (a bad spec stops nothing half-way)."""
    if getattr(args, "spec", None) is None:
        return None
    from fieldcal.acceptance import load_spec
    return load_spec(args.spec)


def _previous_of(params: Path):
    """The previous calibration of the unit whose parameter file is ``params``, when that file
    is in a session directory among its siblings; else None."""
    from fieldcal.paramfile import load
    from fieldcal.session.history import previous_calibration

    if not (params.parent / "log.jsonl").is_file():
        return None
    p = load(params).provenance
    found, _ = previous_calibration(params.parent.parent, p.device_name, p.device_serial,
                                    exclude=params.parent)
    return found


def report_acceptance(spec, params: str | Path, previous: str | Path | None = None, out=None) -> int:
    """Print the verdict of ``params`` against ``spec``; EXIT_FAILED_SPEC if it fails, else 0.
    The previous calibration (for the drift) is ``previous``, or the newest sibling session's."""
    from fieldcal.acceptance import evaluate, verdict_lines
    from fieldcal.paramfile import load

    out = out or sys.stdout
    params = Path(params)
    parameters = load(params)
    if previous is not None:
        prev, where = load(previous), Path(previous)
    else:
        found = _previous_of(params)
        prev, where = (found.parameters, found.path) if found is not None else (None, None)
    print(f"\nacceptance against {spec.path} ({spec.product}): {params}", file=out)
    if where is not None:
        print(f"drift since {where}", file=out)
    verdict = evaluate(spec, parameters, prev)
    for line in verdict_lines(verdict):
        print(line, file=out)
    return 0 if verdict.passed else EXIT_FAILED_SPEC


def accept_after(spec, params, status: int) -> int:
    """After a calibration command that exited ``status``: its verdict against the spec, if any."""
    if spec is None or status != 0 or params is None:
        return status
    return report_acceptance(spec, params)


def cmd_check(args) -> int:
    from fieldcal.acceptance import load_spec
    return report_acceptance(load_spec(args.spec), args.params, args.previous)


def cmd_export(args) -> int:
    from fieldcal.atomic import write_atomically
    from fieldcal.export import export
    from fieldcal.export.autopilot import diagonal_parameters
    from fieldcal.paramfile import load
    from fieldcal.session.output import check_output_path

    if args.out:
        check_output_path(args.out, force=args.force, option="--out")
    parameters = load(args.params)
    text = export(parameters, args.format, accelerometer=args.accelerometer, gyroscope=args.gyroscope)
    if args.format in ("ardupilot", "px4"):  # say what the format cannot hold, where people look
        for loss in diagonal_parameters(parameters, args.format, args.accelerometer, args.gyroscope,
                                        gyro_scale=False)[1]:
            print(f"fieldcal export: {args.format}: {loss.line()}", file=sys.stderr)
    if args.out:
        write_atomically(args.out, text.encode("utf-8"), overwrite=args.force, hint="give --force to replace it")
        print(f"{args.format} written to {args.out}", file=sys.stderr)
    else:
        sys.stdout.write(text)
    return 0


def _apply_targets(args, plans) -> list[Path | None]:
    """Where each input's CSV goes: stdout (None), --out as a file (one input) or a directory."""
    from fieldcal.session.output import check_output_path

    if args.out is None:
        if len(plans) > 1:
            raise ValueError("apply: several input files give several CSVs: give --out DIR")
        return [None]
    out = Path(args.out)
    targets = [out] if len(plans) == 1 and not out.is_dir() else \
        [out / f"{Path(p.path).stem}-calibrated.csv" for p in plans]
    if len(plans) > 1 and not out.is_dir():
        raise ValueError(f"apply: --out {out}: several input files need an existing directory")
    for target in targets:
        check_output_path(target, force=args.force, option="--out")
    return targets


def cmd_apply(args) -> int:
    from fieldcal.apply import apply_file, plan
    from fieldcal.paramfile import load
    from fieldcal.recording.import_map import load_import_map

    plans = plan(load(args.params), load_import_map(args.map), args.input)
    targets = _apply_targets(args, plans)
    for p, target in zip(plans, targets):
        for name in p.skipped:
            print(f"fieldcal apply: {p.path}: triad {name!r} is not in {args.params}: not written",
                  file=sys.stderr)
        if target is None:
            n = apply_file(p, sys.stdout.buffer)
            sys.stdout.buffer.flush()
            continue
        partial = target.with_name(f".{target.name}.partial")  # the CSV appears whole or not at all
        try:
            with open(partial, "wb") as fh:
                n = apply_file(p, fh)
            partial.replace(target)
        finally:
            partial.unlink(missing_ok=True)
        print(f"{p.path}: {n} samples calibrated into {target}", file=sys.stderr)
    return 0


def add_production_parsers(sub) -> None:
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
        "apply", help="calibrated CSV from a recording's text files",
        description="Read a recording's text files in an import map's layout, block by block, and "
        "write each calibrated triad K⁻¹(raw − bias) in SI units (m/s^2, rad/s) as CSV: a time "
        "column t_s, then x, y, z per triad.")
    apply.add_argument("params", metavar="PARAMS", help="parameter file")
    apply.add_argument("input", nargs="+", metavar="INPUT", help="text files, one per map entry")
    apply.add_argument("--map", required=True, metavar="MAP", help="import map: a name in "
                       "configs/recordings or a YAML path (see fieldcal import)")
    apply.add_argument("--out", metavar="PATH", help="the CSV (one input) or a directory for "
                       "INPUT-calibrated.csv files (default: standard output, one input)")
    apply.add_argument("--force", action="store_true", help="replace existing output files")
    apply.set_defaults(func=cmd_apply)
