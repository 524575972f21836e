"""A command's first imports, made without the cyclic garbage collector's passes."""
from __future__ import annotations

import contextlib
import gc


@contextlib.contextmanager
def imports_uncollected():
    """Run the imports inside with the cyclic collector paused, then freeze what they made.

    numpy, scipy.optimize and fieldcal's modules make some 47,000 long-lived tracked objects
    (functions, classes, dicts); the collections their allocations trigger scan them again and
    again: about 50 ms of a `fieldcal calibrate` run (generation 2 alone 25 ms), for no garbage.
    Frozen (``gc.freeze``: every object tracked at that moment), later collections skip them.
    Objects are still freed as soon as nothing refers to them; only cyclic garbage alive at the
    freeze is never collected (in a process that goes on after the command, such as a test
    calling ``main``, whatever cycles it held then). The collector's setting is restored.
    """
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        gc.freeze()
        if enabled:
            gc.enable()
