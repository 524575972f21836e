"""Engine events as lines an operator (or a CI log) can read."""
from __future__ import annotations

from fieldcal.procedure import events as ev


def describe(e: ev.Event) -> str | None:
    """One line for an event, or None for events not worth a line of their own."""
    if isinstance(e, ev.StepStarted):
        return f"step {e.step + 1}/{e.total_steps}: position {e.position_id} ({e.description})"
    if isinstance(e, ev.PositionRecognised):
        text = f"  recognised position {e.position_id} ({e.description})"
        if e.chosen:
            return f"{text}: the operator's choice among positions {', '.join(map(str, e.alike))}"
        if e.alike:  # the operator may choose another (the terminal UI asks)
            text += (f"; positions {', '.join(map(str, e.alike))} look the same to gravity: "
                     f"taking {e.position_id}, the first in procedure order")
        return text
    if isinstance(e, ev.Still):
        return f"  still, {e.angle_to_expected_deg:.1f}° from the expected orientation: dwelling"
    if isinstance(e, ev.WrongOrientation):
        return f"  WRONG POSITION: {e.message}"
    if isinstance(e, ev.MotionDetected):
        what = {"dwell": "the dwell", "rate": "the rate step", "waiting": "the orientation check"}[e.phase]
        return f"  motion during {what}: {'restarting it' if e.restarted else 'dropping the disturbed part'}"
    if isinstance(e, ev.TableTurning):
        return f"  the table is turning ({e.rate_deg_s:.2f} °/s): stop it before the dwell"
    if isinstance(e, ev.DwellComplete):
        return f"  dwell complete ({e.duration_s:.0f} s)"
    if isinstance(e, ev.RateSettled):
        return f"  table steady at {e.rate_deg_s:+.1f} °/s: averaging {e.window_s:.0f} s of whole turns"
    if isinstance(e, ev.StepSkipped):
        return f"  skipped position {e.position_id}"
    if isinstance(e, ev.ProcedureComplete):
        return f"procedure complete: {e.completed} positions done, {e.skipped} skipped"
    if isinstance(e, ev.Aborted):
        return f"aborted ({e.reason}); the session is kept"
    if isinstance(e, ev.Solved):
        lines = [f"solved: {', '.join(e.solved) or 'nothing'}"]
        lines += [f"  {name}: not calibrated: {why}" for name, why in e.failures.items()]
        return "\n".join(lines)
    return None


def minutes(seconds: float) -> str:
    """A time to go as the log says it: '40 s', '12 min'."""
    return f"{seconds:.0f} s" if seconds < 90 else f"{seconds / 60:.0f} min"


def printer(stream, quiet: bool = False, time_to_go=None):
    """Print each event's line; if the reader goes away (``| head``), stop printing, not the run.
    ``time_to_go`` (a ``fieldcal.run.timetogo.TimeToGo``): each completed step says the time to go."""
    state = {"quiet": quiet}

    def report(e: ev.Event) -> None:
        text = describe(e)
        if time_to_go is not None:
            time_to_go.apply(e)
            if isinstance(e, ev.StepComplete) and time_to_go.open:
                text = f"  position {e.position_id} done: ≈{minutes(time_to_go.remaining_s(e.t))} to go"
            elif isinstance(e, ev.StepStarted) and time_to_go.procedure.any_order:
                left = len(time_to_go.open)
                text = (f"{left} position{'s' if left != 1 else ''} to go, in any order "
                        f"(next in the list: position {e.position_id}, {e.description})")
        if text is not None and not state["quiet"]:
            try:
                print(f"[{e.t:7.1f} s] {text}", file=stream, flush=True)
            except BrokenPipeError:
                state["quiet"] = True
    return report
