"""A live session resumed without the terminal UI (``fieldcal resume SESSION --config CONFIG``).

The run is the terminal UI's own ``LiveSource.resuming``, so the device's clock is read and
judged, and the completed steps kept or measured again, exactly as ``fieldcal tui --resume``
does; only the front end differs: the log is printed as lines, and the operator's commands are
read as lines (Enter when the unit is in place). No Textual is imported.
"""
from __future__ import annotations

import threading
import time

from fieldcal.procedure import events as ev
from fieldcal.run.progress import describe
from fieldcal.tui.source import ABORT, QUIT, READY, REDO, SKIP, UNSKIP, Note

# A line's command; an empty line (Enter) is "ready".
LINE_COMMANDS = {"": READY, "r": READY, "d": REDO, "s": SKIP, "u": UNSKIP, "a": ABORT, "q": QUIT}
KEYS = "Enter: the unit is in place; d: redo the step; s: skip it; u: back to a skipped one; a: abort; q: quit"


class ConsoleSink:
    """The source's log items as lines on ``out`` (``quiet``: none; the result is still printed)."""

    def __init__(self, out, quiet: bool = False):
        self.out = out
        self.quiet = quiet

    def update(self, items: tuple, telemetry) -> None:
        for item in items:
            if isinstance(item, Note):
                text = item.text
            elif isinstance(item, ev.PlaceUnit):
                text = f"  place the unit in position {item.position_id} ({item.description}), then press Enter"
            else:
                text = describe(item)
            if text is not None and not self.quiet:
                try:
                    print(f"[{item.t:7.1f} s] {text}", file=self.out, flush=True)
                except BrokenPipeError:  # the reader went away (| head): the run goes on
                    self.quiet = True

    def finished(self, outcome) -> None:
        """(The caller prints the result.)"""


def read_commands(stream, source, out) -> None:
    """Each line of ``stream`` a command for ``source``; the end of the input quits (the session
    is kept, to resume again). Run on a daemon thread: reading blocks."""
    for line in stream:
        command = LINE_COMMANDS.get(line.strip().lower())
        if command is None:
            print(f"({line.strip()!r}: not a command; {KEYS})", file=out, flush=True)
        elif command == QUIT:
            break
        else:
            source.send(command)
    source.stop()


def resume_live(record, config, stdin, out, quiet: bool = False, wall_clock=time.time):
    """Continue the unfinished live session of ``record`` (its ``RunRecord``) on the device of
    ``config``; the Outcome."""
    from fieldcal.tui.live_source import LiveSource

    source = LiveSource.resuming(record, config, ConsoleSink(out, quiet), wall_clock=wall_clock)
    print(f"the operator's commands, one a line: {KEYS}", file=out, flush=True)
    threading.Thread(target=read_commands, args=(stdin, source, out), name="fieldcal-commands",
                     daemon=True).start()
    return source.run()
