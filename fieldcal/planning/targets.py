"""The planner's σ targets as the operator types them: ``TRIAD.GROUP=σ,...`` (``--target``,
``--thermal-target``)."""
from __future__ import annotations

import math


def sigma_pairs(text: str, models, groups, option: str):
    """(triad, group, σ) of each ``TRIAD.GROUP=σ`` in ``text``, σ as given (operator units);
    one line naming ``option`` and what is wrong otherwise."""
    for item in filter(None, (s.strip() for s in text.split(","))):
        key, _, value = item.partition("=")
        triad, _, group = key.strip().partition(".")
        if triad not in models or group not in groups:
            raise ValueError(f"{option}: expected TRIAD.GROUP=σ with TRIAD one of {', '.join(models)} "
                             f"and GROUP one of {', '.join(groups)}, got {item!r}")
        try:
            sigma = float(value)
        except ValueError:
            sigma = -1.0
        if not (math.isfinite(sigma) and sigma > 0):
            raise ValueError(f"{option}: {key.strip()}: expected a finite σ > 0, got {value.strip()!r}")
        yield triad, group, sigma
