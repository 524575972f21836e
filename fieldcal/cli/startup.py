"""A command's start: its first imports, made without the cyclic garbage collector's passes, and
malloc told to keep the memory its big temporaries free for the next ones."""
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


# Near the largest block whose free raises glibc's mmap threshold: its mapping (the bytes, malloc's
# header, rounded up to pages, and the flag bits the free compares along) must stay below
# DEFAULT_MMAP_THRESHOLD_MAX, 32 MiB on 64-bit systems (32 MiB less one page did not: two do).
REUSE_BYTES = (32 << 20) - (8 << 10)


def reuse_freed_memory(size: int = REUSE_BYTES) -> None:
    """Have malloc keep freed memory (up to twice ``size``) for the next allocations, instead of
    giving every big temporary back to the system and faulting its pages in anew the next time.

    glibc's malloc serves blocks above 128 KiB by fresh mmaps and unmaps them when freed, until
    such a block is freed: from then on blocks up to its size come from the heap, and up to
    twice that of freed memory stays mapped. So one untouched block of ``size`` is taken and
    given back (none of its pages is ever touched). A calibration's temporaries are a few
    n-long columns each (20 MiB at imu_tk's recording joined 16×): with this, `calibrate` there
    takes ~20,000 page faults instead of ~38,000, a tenth of its CPU in the kernel, for ~1.5 MiB
    more peak memory. The setting is the process's for good: for a command, whose process ends
    with it, not for a long-running one. Elsewhere (another malloc) this costs nothing.
    (``recording.importer`` does the same for its pieces' temporaries, 4 MiB, in any process.)"""
    import numpy as np

    np.empty(size, dtype=np.uint8)
