"""Session shapes written by older fieldcal, read here and nowhere else (as imucal keeps its old
calibration formats in a legacy module): format 1 (``fieldcal-session/1``, log lines without
checksums) and the terminal UI's step documents before the documents were unified (``step``
without ``skipped``/``bench``, the bench's state in a separate ``checkpoint`` document).

Format 1 is read only for what it is: sessions written before fieldcal 0.2.0. A format-1 start
document over content only a later writer produces (its version in the metadata, numbered
parameter files) is a format-2 session whose checksums were removed -- by hand, to change it
unseen -- and is refused.
"""
from __future__ import annotations

import re

from fieldcal.session import LOG, SessionError

SCHEMA_V1 = "fieldcal-session/1"
FIRST_FORMAT_2_VERSION = (0, 2)  # fieldcal 0.1.0 wrote format 1 and, from 737ae87, format 2
_VERSION = re.compile(r"(?:fieldcal )?(\d+)\.(\d+)")
_NUMBERED = re.compile(r"parameters-\d{3,}\.yaml")  # numbered parameter files came with format 2


def is_format_1(start_document: dict) -> bool:
    return start_document.get("schema") == SCHEMA_V1


def later_writer(documents: list[dict]) -> str | None:
    """What in a format-1 session's documents only a format-2 writer produces, or None."""
    meta = documents[0].get("metadata", {})
    env = meta.get("numeric_environment")
    for where, said in (("software", meta.get("software")),
                        ("numeric_environment.fieldcal", env.get("fieldcal") if isinstance(env, dict) else None)):
        m = _VERSION.match(said) if isinstance(said, str) else None
        if m and (int(m.group(1)), int(m.group(2))) >= FIRST_FORMAT_2_VERSION:
            return f"its metadata's {where} is {said!r}"
    for doc in documents:
        if doc.get("type") == "parameters" and _NUMBERED.fullmatch(str(doc.get("file"))):
            return f"line {doc['seq'] + 1} notes a numbered parameter file ({doc['file']})"
    return None


def refuse_a_later_writer(reader) -> None:
    """A SessionError if ``reader``'s session says format 1 but was written by fieldcal 0.2.0 or
    later (which writes format 2 only): its checksums were taken off, so nothing in it can be trusted."""
    docs = list(reader.documents())
    if not is_format_1(docs[0]):
        return
    why = later_writer(docs)
    if why is not None:
        path = reader.directory / LOG
        raise SessionError(f"{path}: line 1: says format 1 (no checksums), which only fieldcal before 0.2.0 "
                           f"wrote, but {why}: a later session with its checksums removed; refused "
                           "(restore it from a copy)", str(path), 1)


def old_tui_bench(doc: dict, last_step: int | None) -> dict | None:
    """The bench state an old TUI ``checkpoint`` document gives the step just before it, if it
    is that step's (the old TUI wrote ``step`` without ``bench``, then a checkpoint)."""
    data = doc["data"]
    return data.get("bench") if data.get("step") == last_step else None
