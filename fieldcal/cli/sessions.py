"""``fieldcal run / resume / replay / solve``: runs that leave a session, and what to do with one."""
from __future__ import annotations

import datetime
import sys

from fieldcal.cli.options import procedure_session
from fieldcal.model import ANGULAR_RATE
from fieldcal.report import (TURN_ON_BIAS_NOTE, bias_at_end_table, solution_header, solution_table, thermal_table,
                             thermal_truths, worst_error)


def _print_result(result, out) -> int:
    if result.aborted:
        print(f"session kept in {result.session}", file=out)
        return 1
    truths = thermal_truths(result.unit.solutions, result.truth, result.thermal_truth)
    for name, sol in result.unit.solutions.items():
        print(f"\n{solution_header(sol)}", file=out)
        print(solution_table(sol, truths.get(name, (result.truth.get(name), None))[0]), file=out)
        if sol.thermal is not None:
            print(thermal_table(sol, *truths.get(name, (None, None))[1:]), file=out)
        if sol.bias_at_end is not None:
            print(bias_at_end_table(sol, result.bias_at_end.get(name)), file=out)
            if sol.kind == ANGULAR_RATE:
                print(f"  {TURN_ON_BIAS_NOTE}", file=out)
    # every triad's truth, and the thermal terms' where a model was fitted
    worst = worst_error(result.unit.solutions, {**result.truth, **truths})
    if result.unit.thermal_note:
        print(f"\n{result.unit.thermal_note}", file=out)
    for name, why in result.unit.failures.items():
        print(f"\n{name}: not calibrated: {why}", file=out)
    if result.unit.solutions and result.truth:  # (a real device has no truth)
        print(f"\nlargest error against the simulation truth: {worst:.2f}σ", file=out)
    print(f"session: {result.session}", file=out)
    if result.parameters:
        print(f"parameter file: {result.parameters}", file=out)
    return 0 if result.unit.solutions and not result.unit.failures else 1


def warn_if_torn(record) -> bool:
    """Say what of a capture could not be read (a crash's torn tail); True if anything."""
    for line in record.torn:
        print(f"warning: {record.directory}: {line}", file=sys.stderr)
    return bool(record.torn)


def cmd_run(args) -> int:
    from fieldcal.config import load_config
    from fieldcal.procedure.positions import load_procedure
    from fieldcal.run.progress import printer
    from fieldcal.run.runner import OperatorScript, RunSpec, headless_time_to_go, run_headless

    from fieldcal.cli.identity import unit_serial
    from fieldcal.cli.options import accept_after, load_spec_option, operator_option

    config = load_config(args.config)
    spec = load_spec_option(args)
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
    if args.shuffle is not None and not procedure.any_order:
        raise ValueError(f"--shuffle: procedure {procedure.name} takes its positions in order; "
                         "add 'any_order: true' to it to place them in any order")
    seed = config.device.sim.seed if args.seed is None else args.seed
    script = OperatorScript(bump_step=None if args.bump_step is None else args.bump_step - 1,
                            wrong_step=None if args.wrong_step is None else args.wrong_step - 1,
                            skip_steps=tuple(s - 1 for s in args.skip), shuffle_seed=args.shuffle)
    run_spec = RunSpec(procedure, config.station, seed=seed, rate_hz=config.device.rate_hz,
                       raw_counts=config.device.sim.raw_counts, method=args.method,
                       flicker_tau_max_s=config.device.sim.flicker_tau_max_s,
                       on_motion=args.on_motion, script=script, operator=operator_option(args),
                       unit_serial=unit_serial(args, config), sim_thermal=config.device.sim.thermal,
                       thermal=args.thermal or config.thermal)
    stamp = datetime.datetime.now().strftime("%Y%m%d-%H%M%S")
    from fieldcal.atomic import new_named_directory
    # created here, exclusively (the next free name if this second's is taken, by a run or a link)
    directory = new_named_directory(args.out, f"{procedure.name}-seed{seed}-{stamp}", option="--out")
    args.session_path = directory  # for the interrupted / disk-full message (cli.main)
    print(f"headless {procedure.name} against {config.device.name}, seed {seed}; session {directory}",
          flush=True)
    result = run_headless(run_spec, directory, printer(sys.stdout, args.quiet, headless_time_to_go(run_spec)),
                          serial=args.serial)
    return accept_after(args, spec, result.parameters, _print_result(result, sys.stdout))


def cmd_resume(args) -> int:
    from fieldcal.run.progress import printer
    from fieldcal.run.runner import resume_headless

    from fieldcal.cli.identity import check_recorded_serial

    record = procedure_session(args.session)
    reader, spec, steps = record, record.spec, record.steps
    check_recorded_serial(args, spec.device_serial, args.session)
    if reader.start.get("device", {}).get("link") == "pty":
        raise ValueError(f"{args.session}: a run through a serial device cannot be resumed (the "
                         "device cannot be rewound); replay it, or run again")
    if reader.stopped:
        completed = reader.stop_reason == "completed"
        raise ValueError(f"{args.session}: this session already ended ({reader.stop_reason}); "
                         + ("a completed session is never resumed: replay it, or run again"
                            if completed else "nothing to resume"))
    if spec.live is None and args.config is not None:  # not a port to open: said, not ignored
        raise ValueError(f"--config is for a live session's ports; {args.session} ran on the simulator "
                         "(resume it without --config)")
    done = len(steps)
    warn_if_torn(record)  # what resuming will cut away
    from fieldcal.cli.options import accept_after
    if spec.live is not None:
        return accept_after(args, None, *_resume_live(args, record))
    print(f"resuming {args.session} after {done} completed step{'s' if done != 1 else ''}", flush=True)
    result = resume_headless(record, printer(sys.stdout, args.quiet))
    return accept_after(args, None, result.parameters, _print_result(result, sys.stdout))


def _resume_live(args, record) -> tuple:
    """A real device's session, on the ports of --config (else the terminal UI setup's last
    choice), the operator at the console: (parameter file or None, exit status)."""
    from fieldcal.cli.tui import resume_config
    from fieldcal.tui.console import resume_live

    config = resume_config(record, args.config)
    result = resume_live(record, config, sys.stdin, sys.stdout, args.quiet)
    if result.status in ("stopped", "error"):
        print(result.message, file=sys.stdout if result.status == "stopped" else sys.stderr)
        return None, 1
    return result.parameters, _print_result(result, sys.stdout)


def cmd_replay(args) -> int:
    from fieldcal.run.operators import ReplayOperator
    from fieldcal.run.progress import printer
    from fieldcal.run.replay import later_resolves, replay
    from fieldcal.session.output import check_output_path, save_parameter_file

    if args.out:  # never into a session, never over a file without --force: said before replaying
        check_output_path(args.out, force=args.force, option="--out")
    record = procedure_session(args.session)
    run_file = record.run_parameters
    if run_file is not None:  # the run's parameter file must be there to compare with: said before replaying
        run_file.read_bytes(check=False)
    torn = warn_if_torn(record)
    outcome = replay(record, ReplayOperator(record, args.speed), printer(sys.stdout, args.quiet))
    print(f"replayed {outcome.samples} samples")
    if outcome.parameter_file is None:
        print("nothing could be calibrated from this session")
        return 1
    from fieldcal.cli.options import record_in_registry
    if args.out:
        save_parameter_file(outcome.parameter_file, args.out, force=args.force, option="--out")
        print(f"parameter file written to {args.out}")
        record_in_registry(args, args.out, None, "replay")  # a calibration of the unit: indexed
    if run_file is None:
        print("the session has no parameter file its run wrote to compare with ("
              + (f"its run {record.stop_reason}" if record.stopped else "it did not finish") + ")")
        return 1 if torn else 0
    print(outcome.comparison)
    for line in later_resolves(record):
        print(line)
    if outcome.identical:  # the session's own calibration, confirmed: indexed if it was not yet
        record_in_registry(args, run_file.path, None, "run")
    return 0 if outcome.identical else 1


def cmd_solve(args) -> int:
    from fieldcal.run.compare import compare_methods

    # The averages are in the log: samples.bin is neither read nor required.
    record = procedure_session(args.session, log_only=True)  # every step checked
    warn_if_torn(record)
    if not record.steps:
        raise ValueError(f"{args.session}: no completed steps to solve from")
    methods = args.method
    if not methods:
        aligned = record.spec.procedure.aligned
        methods = ["classic"] if aligned else ["powell", "lsq"]
    print(compare_methods(record, methods, args.thermal))
    return 0
