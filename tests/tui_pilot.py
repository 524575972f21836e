"""What the terminal UI's Pilot tests share: async bodies run with asyncio, waiting for a state
(on an event loop turn, never on a wall-clock threshold but a generous time-out)."""
from __future__ import annotations

import asyncio
import functools
import time


def run_async(test):
    """Run an async test body with asyncio (no pytest-asyncio needed)."""
    @functools.wraps(test)
    def wrapper(*args, **kwargs):
        return asyncio.run(test(*args, **kwargs))
    return wrapper


async def until(pilot, predicate, timeout_s: float = 120.0) -> None:
    # A hang detector, not a speed check: a live run with turns takes ~9 s quiet, and more than
    # 30 s was seen once while CI's two workers and other jobs shared the 2 cores.
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < deadline, f"the UI did not get there in time; {what_it_shows(pilot.app)}"
        await pilot.pause(0.01)


def what_it_shows(app) -> str:
    """The state a hang leaves, for the failure's message: the banner, the run's phase, the last
    lines of the event log (a held rate, a silent device and a stuck step read differently) and,
    once the run has ended, how (its status and message: an error says which) with the log's
    last lines as the procedure screen kept them behind the results."""
    parts = [f"screen {type(app.screen).__name__}; telemetry {getattr(app, 'telemetry', None)!r}"]
    outcome = getattr(app, "outcome", None)
    if outcome is not None:
        parts.append(f"the run ended: {outcome.status}: {outcome.message or '(no message)'}")
    screens = [app.screen]
    behind = getattr(app, "procedure_screen", None)
    if behind is not None and behind is not app.screen:
        screens.append(behind)
    for screen, selector in [(s, sel) for s in screens for sel in ("#banner", "#log")]:
        try:
            widget = screen.query_one(selector)
        except Exception:  # another screen, or not mounted: say what there is
            continue
        lines = getattr(widget, "lines", None)
        text = " | ".join(line.text for line in lines[-5:]) if lines is not None else str(widget.render())
        parts.append(f"{selector}: {text}")
    return "; ".join(parts)


async def press_and_go_on(pilot, *keys: str) -> None:
    """The operator's ``keys``, posted to the app in order as its terminal driver posts them, for
    a test that then waits (``until``) for what they do. Pilot.press waits after each key for the
    process to go idle, up to 2 s a key, which a device served as fast as it is read never lets
    it: a run waiting for the operator only reads on (measured: 4 s for two keys)."""
    for key in keys:
        pilot.app.simulate_key(key)
    await pilot.pause(0)


async def ask(pilot, key: str) -> str:
    """Press ``key`` (as ``press_and_go_on``) and wait for the question it asks: its text. (A live
    device read all the time never lets Pilot.press see the process idle: 2 s a key.)"""
    await press_and_go_on(pilot, key)
    await until(pilot, lambda: question_asked(pilot.app) != "")
    return question_asked(pilot.app)


def question_asked(app) -> str:
    """The text of the question the screen's confirm bar asks ("" if none)."""
    bars = app.screen.query("#confirm")
    return str(bars.first().render()) if bars and bars.first().display else ""


def waiting_at(app, step: int) -> bool:
    """The run waits for the operator at ``step`` (0-based)."""
    t = app.telemetry
    return t is not None and t.waiting and t.step == step and app.outcome is None


def placed_and_still(app, carried_until: float, within_deg: float = 2.0, quiet_below: float = 3.0) -> bool:
    """The station's own readings show the unit at its position's attitude and still over a whole
    stillness window read after ``carried_until``, the sample time of the carry's last sample
    (what ``SimulatedDevices.carry`` resolves to). (A device served as fast as it is read can
    still hold the carry's motion in the port when the carry's future resolves; a "ready"
    pressed then sees that motion. And a carry that turns the unit about the vertical leaves the
    tilt as it was: the window read before the carry already looks placed and still, which made
    CI's run of 2026-11-27 see motion after "still" in the first step.)"""
    t = app.telemetry
    if t is None or t.t < carried_until + app.spec.engine_settings().stillness.window_s:
        return False
    return (t.angle_deg is not None and t.angle_deg < within_deg
            and t.quiet is not None and t.quiet < quiet_below)


def log_settled(app, last: str) -> bool:
    """The procedure screen's event log holds a line with ``last`` and is scrolled to its end
    (the log scrolls after it is written, a frame later on a loaded machine: a snapshot waits)."""
    logs = app.screen.query("#log")
    if not logs:
        return False
    log = logs.first()
    return any(last in line.text for line in log.lines) and log.scroll_y >= log.max_scroll_y


def hand_built_unit(unit):
    """``unit`` (a UnitSolution) with every solved triad replaced by round numbers of the same
    shape (its name, kind, units, method and residual labels kept), and the truth set to them
    less a round number of σ: what a snapshot of the results may show, since no solver, BLAS or
    noise stream moves it. In the operator's units: biases (1, 2, 3) ± 0.05 (mg, °/h), scale
    factors 1.001-1.003 ± 20 ppm, angles or terms 0.1, -0.2, ... mrad ± 0.05 mrad, residuals
    -0.01 ... +0.01 per equation; errors against the truth -1.5σ ... +2.5σ."""
    import dataclasses

    import numpy as np

    from fieldcal.calibration import Calibration, SolverDiagnostics
    from fieldcal.units import BIAS, operator_unit

    solutions, truth = {}, {}
    for name, sol in unit.solutions.items():
        factor, _ = operator_unit(sol.kind, sol.output_unit, BIAS)
        residual_factor, _ = operator_unit(sol.kind, sol.residual_unit, BIAS)
        p = len(sol.parameter_names)
        angles = np.array([0.1, -0.2, 0.3, 0.4, -0.5, 0.6])[:p - 6] * 1e-3
        theta = np.r_[np.array([1.0, 2.0, 3.0]) / factor, 1.001, 1.002, 1.003, angles]
        sigma = np.r_[np.full(3, 0.05 / factor), np.full(3, 2e-5), np.full(p - 6, 5e-5)]
        n = sol.residuals.size
        residuals = ((np.arange(n) - (n - 1) / 2) / max((n - 1) / 2, 1) * 0.01 / residual_factor)
        solutions[name] = Calibration(
            name=sol.name, kind=sol.kind, output_unit=sol.output_unit, method=sol.method, theta=theta,
            covariance=np.diag(sigma**2), residuals=residuals.reshape(sol.residuals.shape),
            residual_unit=sol.residual_unit, residual_labels=sol.residual_labels,
            parameter_names=sol.parameter_names,
            diagnostics=SolverDiagnostics(search=sol.method))  # no iterations: closed form, said so
        errors = np.array([-1.5, -1.0, -0.5, 0.0, 0.5, 1.0, 1.5, 2.0, 2.5, -2.0, -1.0, 1.0])[:p]
        truth[name] = theta - sigma * errors  # in the calibration's own parameters
    return dataclasses.replace(unit, solutions=solutions), truth


def show_hand_built_results(monkeypatch) -> None:
    """The terminal UI's results screen, when it opens, shows ``hand_built_unit``'s numbers in
    place of the run's solved ones (all else as the run left it: verdicts, files, skipped)."""
    import dataclasses
    import inspect
    from pathlib import Path

    from fieldcal.tui import app as app_module

    real = app_module.ResultsScreen

    class HandBuiltResults(real):
        CSS_PATH = str(Path(inspect.getfile(real)).parent / real.CSS_PATH)  # (relative to its module)

        def __init__(self, outcome, *args, **kwargs):
            outcome.unit, outcome.truth = hand_built_unit(outcome.unit)
            if outcome.parameter_file is not None:  # what the verdicts judge
                outcome.parameter_file = dataclasses.replace(outcome.parameter_file, triads=tuple(
                    outcome.unit.solutions[t.name] for t in outcome.parameter_file.triads))
            super().__init__(outcome, *args, **kwargs)

    monkeypatch.setattr(app_module, "ResultsScreen", HandBuiltResults)


def show_hand_built_readings(monkeypatch) -> None:
    """The live panel's readings, once samples come, are round numbers (1, -2, 1000 mg; 0.01,
    -0.02, 0.03 °/s; 0.5° from the expected up; quiet 0.8) in place of the simulator's noisy
    means, which a snapshot must not hold."""
    from fieldcal.tui.readings import RecentSamples

    def readings(self, expected_up):
        if len(self._sf) == 0:
            return {}
        return {"accel_mg": (1.0, -2.0, 1000.0), "gyro_deg_s": (0.01, -0.02, 0.03), "angle_deg": 0.5,
                "quiet": 0.8}

    monkeypatch.setattr(RecentSamples, "readings", readings)
