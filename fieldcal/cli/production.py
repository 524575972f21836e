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
