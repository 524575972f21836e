"""The options several commands share, and what they do with them: --spec (the verdict against a
product spec), --registry (where calibrations are recorded), --operator, the run options of
``run`` and ``tui``, and the argparse types they parse with. Its own module, below every
command's, so that the commands import it and never one another."""
from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path

from fieldcal.exit_status import EXIT_FAILED_SPEC
from fieldcal.solvers.methods import METHODS, THERMAL_MODES


def _seed(text: str) -> int:
    value = int(text) if text.lstrip("-").isdigit() else -1
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a whole number >= 0, got {text!r}")
    return value


def _positive(kind, maximum: float = math.inf, unit: str = ""):
    """An argparse type: a finite number > 0 (and <= maximum); nan and inf are refused."""
    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            value = -1
        if not (math.isfinite(value) and 0 < value <= maximum):
            top = f" and <= {maximum:g}{unit}" if math.isfinite(maximum) else ""
            raise argparse.ArgumentTypeError(f"expected a number > 0{top}, got {text!r}")
        return value
    return parse


def _speed(text: str) -> float:
    """Times real time: a finite number >= 0 (0 = as fast as read)."""
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not (math.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"expected a number >= 0 (0 = as fast as read), got {text!r}")
    return value


SPEC_HELP = (f"product spec YAML: PASS/FAIL per parameter with the reason; exit status "
             f"{EXIT_FAILED_SPEC} if any fails")


def add_registry_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--registry", metavar="PATH|URL", help="the unit registry: an SQLite file "
                        "(default $XDG_DATA_HOME/fieldcal/registry.sqlite) or a PostgreSQL server, "
                        "postgresql://USER@HOST[:PORT]/DB (password from PGPASSWORD, ~/.pgpass or a "
                        "service file, never from this option; ?sslmode=require for TLS)")
    parser.add_argument("--registry-require-tls", action="store_true",
                        help="refuse a PostgreSQL registry connection without TLS (as sslmode=require)")


def open_registry(args, read_only: bool = False):
    """The registry the command's options name (``Registry``; a context manager). ``read_only``
    for a command that only reads it: none is created."""
    from fieldcal.registry import Registry
    return Registry(args.registry, require_tls=args.registry_require_tls, read_only=read_only)


def add_operator_option(parser: argparse.ArgumentParser) -> None:
    """--operator, for the commands that measure a unit (a re-solve keeps the session's)."""
    parser.add_argument("--operator", metavar="NAME", default=os.environ.get("FIELDCAL_OPERATOR"),
                        help="who calibrates: written into the session, the parameter file and the "
                        "registry (default $FIELDCAL_OPERATOR; none when unset)")


def operator_option(args) -> str | None:
    """The --operator given (or its default), checked; None when none was."""
    from fieldcal.paramfile.document import OPERATOR_MAX, valid_operator

    name = getattr(args, "operator", None)
    if name is not None and not valid_operator(name):
        raise ValueError(f"--operator: expected a name of 1 to {OPERATOR_MAX} printable characters "
                         f"without blanks around it, got {name!r}"[:200])
    return name


def add_spec_option(parser: argparse.ArgumentParser) -> None:
    """--spec and --registry, for the commands that calibrate."""
    parser.add_argument("--spec", metavar="SPEC", help=SPEC_HELP)
    add_registry_option(parser)


def load_spec_option(args):
    """The --spec file, read before any work is done (a bad spec stops nothing half-way)."""
    if getattr(args, "spec", None) is None:
        return None
    from fieldcal.acceptance import load_spec
    return load_spec(args.spec)


def previous_calibration_of(params: Path):
    """The previous calibration of the unit whose parameter file is ``params``, when that file
    is in a session directory among its siblings; else None."""
    from fieldcal.paramfile import load
    from fieldcal.session.history import previous_calibration

    from fieldcal.session.capture import LOG

    if not (params.parent / LOG).is_file():
        return None
    p = load(params).provenance
    found, _ = previous_calibration(params.parent.parent, p.device_name, p.device_serial,
                                    exclude=params.parent)
    return found


def report_acceptance(spec, params: str | Path, previous: str | Path | None = None, out=None):
    """Print the verdict of ``params`` against ``spec``; the Verdict.
    The previous calibration (for the drift) is ``previous``, or the newest sibling session's."""
    from fieldcal.acceptance import evaluate, verdict_lines
    from fieldcal.paramfile import load

    out = out or sys.stdout
    params = Path(params)
    parameters = load(params)
    if previous is not None:
        prev, where = load(previous), Path(previous)
    else:
        found = previous_calibration_of(params)
        prev, where = (found.parameters, found.path) if found is not None else (None, None)
    print(f"\nacceptance against {spec.path} ({spec.product}): {params}", file=out)
    from fieldcal.acceptance import not_the_same_unit
    if where is not None and not_the_same_unit(parameters, prev) is None:  # else evaluate says why not
        print(f"drift since {where}", file=out)
    verdict = evaluate(spec, parameters, prev)
    for line in verdict_lines(verdict):
        print(line, file=out)
    return verdict


def accept_after(args, spec, params, status: int, source: str = "run") -> int:
    """After a calibration command that exited ``status``: its verdict against the spec, if any,
    and the parameter file recorded in the unit registry (a failure there is a warning)."""
    if params is None or not Path(params).is_file():
        return status
    passed = None
    try:
        if spec is not None and status == 0:
            passed = report_acceptance(spec, params).passed  # a spec that fits no triad raises
            status = 0 if passed else EXIT_FAILED_SPEC
    finally:  # recorded whatever the spec made of it
        record_in_registry(args, params, passed, source)
    return status


def record_in_registry(args, params, passed: bool | None, source: str) -> bool:
    """Record a parameter file in the --registry; a failure is a warning on stderr."""
    from fieldcal.registry import record_safely

    return record_safely(params, passed, args.registry, warn=lambda text: print(text, file=sys.stderr),
                         source=source, require_tls=args.registry_require_tls)


def find_sessions(directories, command: str) -> list[Path]:
    """The sessions in each directory: itself if it is one, else the sessions directly in it."""
    from fieldcal.session.capture import LOG

    sessions = []
    for d in map(Path, directories):
        if not d.is_dir():
            raise ValueError(f"{command}: {d}: not a directory")
        sessions += [d] if (d / LOG).is_file() else sorted(p.parent for p in d.glob(f"*/{LOG}"))
    return sessions


def add_thermal_option(parser: argparse.ArgumentParser, default: str) -> None:
    """--thermal auto|on|off: whether the solve fits a thermal model (THERMAL_MODES)."""
    parser.add_argument("--thermal", choices=THERMAL_MODES, help="fit the thermal model beside the "
                        "calibration: auto (when the window temperatures span 0.5 K or more), on "
                        f"(whenever they carry a temperature) or off (default: {default})")


def add_run_options(parser: argparse.ArgumentParser) -> None:
    """Options shared by everything that runs a procedure (run, tui)."""
    parser.add_argument("--config", default="sim", help="station config (default: sim)")
    parser.add_argument("--procedure", default="field-18",
                        help="procedure name or YAML path (default field-18)")
    parser.add_argument("--seed", type=_seed, help="simulation seed (default: the config's)")
    parser.add_argument("--out", default="sessions", help="where sessions go (default ./sessions)")
    parser.add_argument("--method", choices=METHODS, default="auto",
                        help="solver: auto (default) is classic for an aligned procedure, else powell")
    add_thermal_option(parser, "the config's thermal setting, else auto")
    parser.add_argument("--on-motion", choices=("restart", "discard"), default="restart",
                        help="a bump during a dwell restarts it (default) or drops only the disturbed part")
    from fieldcal.cli.identity import add_unit_serial_option
    add_unit_serial_option(parser)


def procedure_session(directory, log_only: bool = False):
    """A procedure run's session read once (``RunRecord``: its spec rebuilt, every step checked);
    one-line errors. ``log_only``: read the log's documents alone (see ``SessionReader``)."""
    from fieldcal.run.runner import open_run

    return open_run(directory, log_only=log_only)
