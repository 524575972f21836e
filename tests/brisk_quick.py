"""The quick procedure (tests/faults/quick.yaml) with its rate steps at 60 °/s: one turn is 6 s a
way, not 36 s, so a run is 645 s of simulated time, not 1565 s (issue 26). For the tests whose
sessions are read again by replays, re-solves, certificates and Allan plots and that assert
nothing about the rate steps' speed; the procedure keeps quick's name and positions."""
from __future__ import annotations

import re
from pathlib import Path

QUICK = Path(__file__).parent / "faults" / "quick.yaml"
BRISK_RATE_STEP = "rate_step: {rate_deg_s: 60, turns: 1, ramp_s: 0.5, settle_s: 0.5}"


def brisk_quick(directory: Path) -> Path:
    """quick.yaml with the brisk rate step, written into ``directory``; its path."""
    text = QUICK.read_text(encoding="utf-8")
    assert text.count("\nrate_step: ") == 1, "quick.yaml's rate step is no longer one line"
    path = directory / "quick.yaml"
    path.write_text(re.sub(r"\nrate_step: [^\n]*\n", f"\n{BRISK_RATE_STEP}\n", text), encoding="utf-8")
    return path
