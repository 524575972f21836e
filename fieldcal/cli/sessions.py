"""``fieldcal run / resume / replay / solve``: runs that leave a session, and what to do with one."""
from __future__ import annotations

import datetime
import sys
from pathlib import Path

import numpy as np

from fieldcal.report import solution_header, solution_table


def _print_result(result, out) -> int:
    if result.aborted:
        print(f"session kept in {result.session}", file=out)
        return 1
    worst = 0.0
    for name, sol in result.unit.solutions.items():
        print(f"\n{solution_header(sol)}", file=out)
        print(solution_table(sol, result.truth.get(name)), file=out)
        worst = max(worst, float(np.max(np.abs(sol.theta - result.truth[name]) / sol.sigma)))
    for name, why in result.unit.failures.items():
        print(f"\n{name}: not calibrated: {why}", file=out)
    if result.unit.solutions:
        print(f"\nlargest error against the simulation truth: {worst:.2f}σ", file=out)
    print(f"session: {result.session}", file=out)
    if result.parameters:
        print(f"parameter file: {result.parameters}", file=out)
    return 0 if result.unit.solutions and not result.unit.failures else 1


def warn_if_torn(directory) -> bool:
    """Say what of a capture could not be read (a crash's torn tail); True if anything."""
    from fieldcal.session.capture import SessionReader

    torn = SessionReader(directory).torn
    for line in torn:
        print(f"warning: {directory}: {line}", file=sys.stderr)
    return bool(torn)


def cmd_run(args) -> int:
    from fieldcal.config import load_config
    from fieldcal.procedure.positions import load_procedure
    from fieldcal.run.progress import printer
    from fieldcal.run.runner import OperatorScript, RunSpec, run_headless

    config = load_config(args.config)
    if not args.headless:
        raise ValueError("run: without --headless there is no operator; use fieldcal tui for the "
                         "terminal UI, or add --headless for the automatic operator")
    if config.device.protocol != "sim":
        raise ValueError(f"run --headless: {config.path} is a real device; a headless run needs the "
                         "simulated one, whose fixture the automatic operator can move")
    procedure = load_procedure(args.procedure)
    n = len(procedure.positions)
    for flag in ("bump_step", "wrong_step"):
        value = getattr(args, flag)
        if value is not None and not 1 <= value <= n:
            raise ValueError(f"--{flag.replace('_', '-')}: expected a step from 1 to {n}, got {value}")
    for value in args.skip:
        if not 1 <= value <= n:
            raise ValueError(f"--skip: expected a step from 1 to {n}, got {value}")
    seed = config.device.sim.seed if args.seed is None else args.seed
    script = OperatorScript(bump_step=None if args.bump_step is None else args.bump_step - 1,
                            wrong_step=None if args.wrong_step is None else args.wrong_step - 1,
                            skip_steps=tuple(s - 1 for s in args.skip))
    spec = RunSpec(procedure, config.station, seed=seed, rate_hz=config.device.rate_hz,
                   raw_counts=config.device.sim.raw_counts, method=args.method,
                   on_motion=args.on_motion, script=script)
    stamp = datetime.datetime.now().strftime("%Y%m%d-%H%M%S")
    directory = Path(args.out) / f"{procedure.name}-seed{seed}-{stamp}"
    print(f"headless {procedure.name} against {config.device.name}, seed {seed}; session {directory}",
          flush=True)
    result = run_headless(spec, directory, printer(sys.stdout, args.quiet), serial=args.serial)
    return _print_result(result, sys.stdout)


def cmd_resume(args) -> int:
    from fieldcal.run.progress import printer
    from fieldcal.run.runner import resume_headless
    from fieldcal.session.capture import SessionReader

    reader = SessionReader(args.session)
    if reader.start.get("device", {}).get("link") == "pty":
        raise ValueError(f"{args.session}: a run through a serial device cannot be resumed (the "
                         "device cannot be rewound); replay it, or run again")
    if reader.stopped:
        raise ValueError(f"{args.session}: this session already ended ({reader.stop_reason}); "
                         "nothing to resume")
    done = len(reader.steps())
    warn_if_torn(args.session)  # what resuming will cut away
    print(f"resuming {args.session} after {done} completed step{'s' if done != 1 else ''}", flush=True)
    return _print_result(resume_headless(Path(args.session), printer(sys.stdout, args.quiet)), sys.stdout)


def cmd_replay(args) -> int:
    from fieldcal.paramfile import save
    from fieldcal.run.operators import ReplayOperator
    from fieldcal.run.progress import printer
    from fieldcal.run.replay import replay_session_outcome

    torn = warn_if_torn(args.session)
    outcome, samples = replay_session_outcome(args.session, ReplayOperator(Path(args.session), args.speed),
                                              printer(sys.stdout, args.quiet))
    print(f"replayed {samples} samples")
    if outcome.parameter_file is None:
        print("nothing could be calibrated from this session")
        return 1
    if args.out:
        save(outcome.parameter_file, args.out)
        print(f"parameter file written to {args.out}")
    if outcome.identical is None:
        print("the session has no parameter file to compare with (it did not finish)")
        return 1 if torn else 0
    print(outcome.comparison)
    return 0 if outcome.identical else 1


def cmd_solve(args) -> int:
    from fieldcal.solvers.compare import compare_methods
    from fieldcal.run.runner import RunSpec
    from fieldcal.session.capture import SessionReader

    warn_if_torn(args.session)
    if not SessionReader(args.session).steps():
        raise ValueError(f"{args.session}: no completed steps to solve from")
    methods = args.method
    if not methods:
        aligned = RunSpec.from_metadata(SessionReader(args.session).start).procedure.aligned
        methods = ["classic"] if aligned else ["powell", "lsq"]
    print(compare_methods(Path(args.session), methods))
    return 0
