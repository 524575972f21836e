"""Sessions: the append-only capture format, its writer and reader, the run record (what a
session means, read once; old shapes in legacy), history of a unit."""

# Here, not in capture (which needs numpy): a command checks its output paths against sessions
# (session.output, cli.paths) before it imports what its work needs.
LOG = "log.jsonl"  # a session's log: the file that makes a directory a session


class SessionError(ValueError):
    """A directory that is not a usable session; the message is one line naming file and line."""

    def __init__(self, message: str, path: str = "", line: int | None = None) -> None:
        super().__init__(message)
        self.path = path
        self.line = line
