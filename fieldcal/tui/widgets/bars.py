"""Text progress bars and meters (Rich ``Text``), one cell per character."""
from __future__ import annotations

import math

from rich.text import Text

_PARTS = " ▏▎▍▌▋▊▉"


def bar(fraction: float, width: int, style: str = "green", empty_style: str = "grey35") -> Text:
    """A bar ``width`` cells wide filled to ``fraction`` (clipped to 0..1), eighths resolved."""
    fraction = min(1.0, max(0.0, fraction)) if math.isfinite(fraction) else 0.0
    eighths = round(fraction * width * 8)
    full, part = divmod(eighths, 8)
    text = Text("█" * full, style=style)
    if full < width:
        text.append(_PARTS[part] if part else "░", style=style if part else empty_style)
        text.append("░" * (width - full - 1), style=empty_style)
    return text


def signed_bar(value: float, scale: float, width: int, style: str = "cyan") -> Text:
    """Half a bar each side of a centre mark: negative values left, positive right."""
    half = width // 2
    fraction = 0.0 if scale <= 0 else min(1.0, abs(value) / scale)
    cells = round(fraction * half)
    left = " " * (half - cells if value < 0 else half) + ("█" * cells if value < 0 else "")
    right = ("█" * cells if value >= 0 else "") + " " * (half - cells if value >= 0 else half)
    return Text.assemble((left, style), ("│", "grey50"), (right, style))
