"""``fieldcal resolve DIR... -j N``: re-solve many sessions from their stored step averages, in
parallel processes, each new calibration written into its session and recorded in the registry.

A session the re-solve cannot handle (not a procedure run, a run that did not complete -- an
unfinished one is resumed, not re-solved, and an aborted one is no calibration of the unit --,
damaged, locked by a running station) is reported in one line and skipped; the batch always goes on, and the
exit status says whether any failed. A re-solve giving the bytes of the session's current
parameter file writes nothing (it is already there). Only the parent process writes the
registry, one record per session as it finishes, so the workers never contend for it. A registry
that cannot be written (a server down, or gone mid-batch) is said once and not tried again: the
batch re-solves every session all the same, and ends naming the ``fieldcal registry rebuild``
that indexes them later.
"""
from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

from fieldcal.exit_status import EXIT_FAILED_SPEC, EXIT_SOME_FAILED


@dataclass(frozen=True)
class Resolved:
    session: str
    params: str | None  # the parameter file the re-solve gave (new or the same); None: failed
    line: str  # what became of the session, one line


def resolve_one(session: str, method: str | None, thermal: str | None = None) -> Resolved:
    """Re-solve one session; never raises (a worker's exception would be the batch's)."""
    try:
        return _resolve(Path(session), method, thermal)
    except (ValueError, OSError) as exc:  # SessionError, ProcedureError, a file that went away
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    except Exception as exc:  # noqa: BLE001 -- one session's surprise must not stop the batch
        reason = f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
    return Resolved(session, None, f"FAILED {session}: {reason[:300]}")


def _resolve(session: Path, method: str | None, thermal: str | None = None) -> Resolved:
    from fieldcal.paramfile import dump
    from fieldcal.run.replay import resolve_session
    from fieldcal.run.runner import open_run
    from fieldcal.session.capture import SessionWriter

    record = open_run(session, log_only=True, recordings=True)  # every step document checked: file, line and field
    if record.start.get("kind") == "recording":
        return _resolve_recording(session, record, method)
    if record.stop_reason != "completed":  # its partial solve would enter the unit's history
        state = f"its run {record.stop_reason}" if record.stopped else "its run did not finish (resume it first)"
        return Resolved(str(session), None, f"FAILED {session}: not re-solved: {state}")
    unit, pf = resolve_session(record, method, thermal)
    if pf is None:
        why = "; ".join(f"{n}: {r}" for n, r in unit.failures.items()) or "no completed steps"
        return Resolved(str(session), None, f"FAILED {session}: nothing could be calibrated ({why})")
    current = record.parameters_path
    if current is not None and Path(current).read_bytes() == dump(pf).encode("utf-8"):
        return Resolved(str(session), str(current), f"unchanged {session}: {Path(current).name} "
                        f"({pf.provenance.method})")
    writer = SessionWriter.append_to(session)  # refused while a station is writing the session
    try:
        writer.write_parameters(pf)  # the next parameters-NNN.yaml: earlier ones are kept
    finally:
        writer.close()
    written = writer.parameters_written
    failed = f"; not calibrated: {', '.join(unit.failures)}" if unit.failures else ""
    return Resolved(str(session), str(written), f"re-solved {session}: {Path(written).name} "
                    f"({pf.provenance.method}, {len(unit.solutions)} triads{failed})")


def _resolve_recording(session: Path, record, method: str | None) -> Resolved:
    """An imported recording calibrated again as `fieldcal calibrate` does, at the place of its
    current parameter file (none: an unknown place), the noise measured from the recording."""
    from fieldcal.paramfile import dump, load
    from fieldcal.recording.calibrate import RecordingSettings, UnknownPlace, calibrate_recording
    from fieldcal.recording.results import parameter_file, place_of
    from fieldcal.recording.store import load_recording
    from fieldcal.session.capture import SessionWriter

    if method not in (None, "powell", "lsq"):  # "auto" and "classic" name procedure solvers
        return Resolved(str(session), None, f"FAILED {session}: not re-solved: a recording's accelerometer is "
                        f"solved by powell or lsq, not {method}")
    recording = load_recording(session)
    current = record.parameters_path
    previous = load(current) if current is not None else None
    station = place_of(previous.provenance) if previous is not None else UnknownPlace()
    cal = calibrate_recording(recording, station, RecordingSettings(method=method or "powell"))
    kept = previous.provenance if previous is not None else None
    pf = parameter_file(cal, recording, cal.place, device_name=kept.device_name if kept else None,
                        operator=kept.operator if kept else None)
    if current is not None and Path(current).read_bytes() == dump(pf).encode("utf-8"):
        return Resolved(str(session), str(current), f"unchanged {session}: {Path(current).name} (recording)")
    writer = SessionWriter.append_to(session)
    try:
        writer.write_parameters(pf)
    finally:
        writer.close()
    failed = f"; not calibrated: {', '.join(cal.failures)}" if cal.failures else ""
    return Resolved(str(session), str(writer.parameters_written), f"re-solved {session}: "
                    f"{writer.parameters_written.name} (recording, {len(pf.triads)} triads{failed})")


def _results(sessions: list[str], method: str | None, jobs: int, thermal: str | None = None):
    """Each session's Resolved, as they finish (in order with one job)."""
    if jobs == 1 or len(sessions) == 1:
        yield from (resolve_one(s, method, thermal) for s in sessions)
        return
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed

    # spawn: workers start clean (no copy of a parent's threads or open registry connection)
    with ProcessPoolExecutor(max_workers=jobs, mp_context=multiprocessing.get_context("spawn")) as pool:
        futures = {pool.submit(resolve_one, s, method, thermal): s for s in sessions}
        for future in as_completed(futures):
            try:
                yield future.result()
            except Exception as exc:  # noqa: BLE001 -- a worker killed (out of memory, a signal)
                yield Resolved(futures[future], None, f"FAILED {futures[future]}: its worker process "
                               f"died ({type(exc).__name__})")


def cmd_resolve(args) -> int:
    import shlex

    from fieldcal.cli.options import find_sessions, load_spec_option
    from fieldcal.registry import BatchRecorder
    from fieldcal.registry.backends import redact

    spec = load_spec_option(args)
    # each session once, however it was named (two workers on one session: one would be refused)
    sessions, seen = [], set()
    for session in find_sessions(args.directory, "resolve"):
        if session.resolve() not in seen:
            seen.add(session.resolve())
            sessions.append(str(session))
    if not sessions:
        raise ValueError(f"resolve: no sessions (directories with a log.jsonl) in {' '.join(args.directory)}")
    jobs = min(args.jobs, len(sessions))
    print(f"re-solving {len(sessions)} session{'s' * (len(sessions) != 1)} in {jobs} "
          f"process{'es' * (jobs != 1)}", flush=True)
    # One registry for the batch: a server that is down is found once, not waited for per session.
    rebuild = " ".join(["fieldcal registry rebuild", *map(shlex.quote, args.directory)]
                       + (["--registry", shlex.quote(redact(args.registry))] if args.registry else []))
    registry = BatchRecorder(args.registry, warn=lambda text: print(text, file=sys.stderr), source="resolve",
                             require_tls=args.registry_require_tls, rebuild=rebuild)
    failed = spec_failed = 0
    for done, result in enumerate(_results(sessions, args.method, jobs, args.thermal), start=1):
        passed = None
        if result.params is not None and spec is not None:
            try:
                passed, verdict_text = _verdict(spec, result.params)
                spec_failed += not passed
            except ValueError as exc:  # a spec that does not fit this unit: said, not the batch's end
                spec_failed += 1
                verdict_text = f"SPEC ERROR: {str(exc).splitlines()[0]}"
            result = Resolved(result.session, result.params, f"{result.line} {verdict_text}")
        failed += result.params is None
        print(f"[{done}/{len(sessions)}] {result.line}", flush=True)
        if result.params is not None:
            registry.record(result.params, passed)
    print(f"{len(sessions) - failed} re-solved, {failed} failed"
          + (f", {spec_failed} failed {spec.path}" if spec is not None else ""), flush=True)
    if (missed := registry.summary()) is not None:
        print(missed, file=sys.stderr)
    if failed:
        return EXIT_SOME_FAILED
    return EXIT_FAILED_SPEC if spec_failed else 0


def _verdict(spec, params: str) -> tuple[bool, str]:
    """(passed, "PASS" or "FAIL: first reason (+n more)") against the spec, drift included."""
    from fieldcal.acceptance import evaluate
    from fieldcal.cli.options import previous_calibration_of
    from fieldcal.paramfile import load

    previous = previous_calibration_of(Path(params))
    verdict = evaluate(spec, load(params), previous.parameters if previous is not None else None)
    if verdict.passed:
        return True, "PASS"
    first, more = verdict.failures[0], len(verdict.failures) - 1
    return False, (f"FAIL: {first.triad} {first.parameter} {first.reasons[0]}"
                   + (f" (+{more} more)" if more else ""))
