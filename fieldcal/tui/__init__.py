"""The operator's terminal UI (Textual): ``run_tui`` and ``FieldcalApp``.

Imported lazily, so that ``fieldcal.cli.tui`` (the CLI's ``tui`` subcommand) costs the CLI
no Textual import until the UI actually runs.
"""
from __future__ import annotations

__all__ = ["FieldcalApp", "run_tui"]


def __getattr__(name: str):
    if name in __all__:
        from fieldcal.tui import app
        return getattr(app, name)
    raise AttributeError(f"module 'fieldcal.tui' has no attribute {name!r}")
