"""Parameter files written where the user asks (``replay --out``, ``calibrate --params``,
``demo --params``): never inside a session, never over an existing file unless forced."""
from __future__ import annotations

import os
from pathlib import Path

from fieldcal.session import LOG, SessionError  # not capture: no numpy before a command's imports


def refuse_inside_session(path: str | os.PathLike, what: str) -> None:
    """A one-line SessionError if ``path`` is a session directory or a file in one: only the
    session writer writes there (and never over a file)."""
    p = Path(path)
    for d in (p, p.parent):
        if (d / LOG).is_file():
            raise SessionError(f"{p}: {what} would be written into the session {d}, whose files "
                               "are never overwritten nor added to by hand; give a path outside it",
                               str(p))


_HINT = "give --force to replace it"


def check_output_path(path: str | os.PathLike, *, force: bool, option: str, inputs=()) -> None:
    """What ``save_parameter_file`` would refuse, said before the work that leads to it."""
    from fieldcal.atomic import check_target

    refuse_inside_session(path, f"{option}'s parameter file")
    check_target(path, force=force, inputs=inputs, hint=_HINT, option=option)


def save_parameter_file(pf, path: str | os.PathLike, *, force: bool = False, option: str = "--out",
                        data: bytes | None = None, inputs=()) -> Path:
    """Write ``pf`` to ``path`` atomically; refused inside a session, and over an existing file
    unless ``force`` (the refusal names ``path`` and the --force flag). ``data``: ``pf``'s text
    as a file already holds it (a session's copy), so that it is not made again."""
    from fieldcal.atomic import write_atomically
    from fieldcal.paramfile import dump

    check_output_path(path, force=force, option=option, inputs=inputs)
    data = dump(pf).encode("utf-8") if data is None else data
    return write_atomically(path, data, overwrite=force, hint=_HINT, inputs=inputs)
