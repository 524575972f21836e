"""What a crash leaves in a session, made on purpose (shared by the resume and replay tests)."""
from __future__ import annotations

import json
from pathlib import Path


def cut_before_step_record(session: Path, nth: int) -> None:
    """The state a kill leaves after the chunk that completed a step was logged but before the
    step's record was: the log cut at the start of the nth step document (0-based), samples.bin
    up to the end of the last chunk the log still names, and no parameter file."""
    log = session / "log.jsonl"
    data = log.read_bytes()
    offset, seen = 0, -1
    for line in data.splitlines(keepends=True):
        if b'"type":"step"' in line:
            seen += 1
            if seen == nth:
                break
        offset += len(line)
    assert seen == nth, "not enough steps to cut at"
    log.write_bytes(data[:offset])
    chunks = [json.loads(line) for line in data[:offset].splitlines() if b'"type":"chunk"' in line]
    with open(session / "samples.bin", "r+b") as fh:
        fh.truncate(chunks[-1]["offset"] + chunks[-1]["length"])
    for parameters in session.glob("parameters*.yaml"):
        parameters.unlink()
