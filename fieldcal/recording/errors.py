"""The one-line error of a recording that cannot be imported, in a module of its own so that the
input checks (``inputs``) and the readers (``importer``) both raise it without importing each other."""
from __future__ import annotations


class RecordingImportError(ValueError):
    """A recording that cannot be read, named by ``path`` (and ``line`` where one is at fault)."""

    def __init__(self, message: str, path: str = "", line: int | None = None):
        super().__init__(message)
        self.path, self.line = path, line
