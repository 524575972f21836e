"""Step documents checked for the shape their readers rely on, before anything uses them.

A step document's data is the engine's record of a completed step (``Engine.records``): the step's
index into the procedure's positions, its windows (kind, start and duration in s, table rate in
°/s, per-triad means) and, from a headless run, the steps skipped so far. The session writer
stores any JSON; this is where a well-formed line of the wrong shape (a hand edit, another
program's output) becomes a one-line error naming the file and line instead of a KeyError or
IndexError deep in a solver.
"""
from __future__ import annotations

import math

from fieldcal.session.capture import LOG, SessionError, SessionReader


def _number(value) -> bool:
    return not isinstance(value, bool) and isinstance(value, (int, float)) and math.isfinite(value)


def _index(value, n_positions: int) -> bool:
    return not isinstance(value, bool) and isinstance(value, int) and 0 <= value < n_positions


def _problem(data, n_positions: int) -> str | None:
    """What is wrong with one step record, or None."""
    if "step" not in data:
        return "no 'step'"
    if not _index(data["step"], n_positions):
        return f"'step' must be a position index from 0 to {n_positions - 1}, got {data['step']!r}"[:200]
    windows = data.get("windows")
    if not isinstance(windows, list):
        return "no 'windows' list" if "windows" not in data else "'windows' must be a list"
    for i, w in enumerate(windows):
        where = f"windows[{i}]"
        if not isinstance(w, dict):
            return f"{where} must be an object"
        for key in ("kind", "start", "duration", "rate_deg_s", "means"):
            if key not in w:
                return f"{where} has no {key!r}"
        if not isinstance(w["kind"], str):
            return f"{where}.kind must be a string, got {w['kind']!r}"[:200]
        for key in ("start", "duration", "rate_deg_s"):
            if not _number(w[key]) or key == "duration" and w[key] < 0:
                return f"{where}.{key} must be a finite number{' >= 0' if key == 'duration' else ''}, got {w[key]!r}"[:200]
        means = w["means"]
        if not isinstance(means, dict) or not means:
            return f"{where}.means must be an object of triad means"
        for name, mean in means.items():
            if not (isinstance(mean, list) and len(mean) == 3 and all(_number(v) for v in mean)):
                return f"{where}.means.{name} must be 3 finite numbers, got {mean!r}"[:200]
    skipped = data.get("skipped", [])
    if not isinstance(skipped, list) or not all(_index(s, n_positions) for s in skipped):
        return f"'skipped' must be a list of position indices from 0 to {n_positions - 1}"
    return None


def checked_steps(reader: SessionReader, n_positions: int) -> list[dict]:
    """``reader.steps()``, each checked; a SessionError naming the log's file and line otherwise.

    Every triad's means must name the same triads as the first window's (the solvers stack them)."""
    steps, names = [], None
    for doc in reader.documents("step"):
        data, line = doc["data"], doc["seq"] + 1
        why = _problem(data, n_positions)
        if why is None:
            for i, w in enumerate(data["windows"]):
                names = set(w["means"]) if names is None else names
                if set(w["means"]) != names:
                    why = f"windows[{i}].means has triads {sorted(w['means'])}, earlier steps {sorted(names)}"
                    break
        if why is not None:
            path = reader.directory / LOG
            raise SessionError(f"{path}: line {line}: step document: {why}", str(path), line)
        steps.append(data)
    return steps
