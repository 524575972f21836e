"""A command's first imports, made without the cyclic garbage collector's passes."""
from __future__ import annotations

import contextlib
import gc


_frozen = False  # imports_uncollected froze objects that thaw has not yet given back

@contextlib.contextmanager
def imports_uncollected():
    """Run the imports inside with the cyclic collector paused, then freeze what they made.

    numpy, scipy and fieldcal's modules make some 47,000 long-lived tracked objects
    (functions, classes, dicts); the collections their allocations trigger scan them again and
    again: about 50 ms of a `fieldcal calibrate` run (generation 2 alone 25 ms), for no garbage.
    Frozen (``gc.freeze``: every object tracked at that moment), later collections skip them.
    Objects are still freed as soon as nothing refers to them; only cyclic garbage alive at the
    freeze is not collected while the command runs; ``thaw`` (called by ``main`` when the command
    is over) gives them back to the collector, so a process that goes on (a test calling ``main``
    again and again) does not keep them. The ``fieldcal`` command itself (``run``) leaves them
    frozen: its process ends there, and the collection at shutdown then skips them (~40 ms).
    The collector's setting is restored.
    """
    global _frozen
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        gc.freeze()
        _frozen = True
        if enabled:
            gc.enable()


def thaw() -> None:
    """What ``imports_uncollected`` froze, collectable again (the command is over)."""
    global _frozen
    if _frozen:
        gc.unfreeze()
        _frozen = False
