"""Issue 22's end-to-end check: `fieldcal plan --config configs/sim.yaml --target field-18 --out
FILE`, then `fieldcal run --config sim --procedure FILE --headless --seed 1`, takes at most 0.20×
field-18's operator time (the simulated time at the procedure's end, handling included) and
every scale factor's and misalignment's reported σ is at most 1.10× field-18's on the same seed.
"""
import re
from pathlib import Path

import numpy as np
import pytest

from fieldcal.cli.main import main
from fieldcal.paramfile import load

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "sim.yaml"


def headless(procedure: str, out: Path, capsys) -> tuple[float, object]:
    """(operator time in s, the parameter file) of a headless run with seed 1."""
    assert main(["run", "--config", "sim", "--procedure", procedure, "--headless", "--seed", "1",
                 "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    done = re.search(r"\[\s*([0-9.]+) s\] procedure complete", printed)
    assert done, printed
    return float(done.group(1)), load(next(out.glob("*/parameters.yaml")))


# The search costs ~4 s of one core on a quiet machine (~25 s before 2026-11-27); on one shared by eight engineers' test
# runs and benchmarks it got a twentieth of a core and outran the suite's 600 s.
@pytest.mark.timeout(1800)
def test_the_default_field_18_plan_takes_a_fifth_of_its_time_at_its_scale_and_angle_sigma(tmp_path, capsys):
    planned = tmp_path / "planned.yaml"
    assert main(["plan", "--config", str(CONFIG), "--target", "field-18", "--out", str(planned)]) == 0
    capsys.readouterr()
    plan_s, plan_pf = headless(str(planned), tmp_path / "planned-runs", capsys)
    field_s, field_pf = headless("field-18", tmp_path / "field-runs", capsys)
    assert plan_s <= 0.20 * field_s, (plan_s, field_s)
    for name in field_pf.names:
        ratio = plan_pf[name].file_sigma[3:] / field_pf[name].file_sigma[3:]
        assert np.all(ratio <= 1.10), (name, ratio)
        # and the bias each run reports at its end is there, with a σ
        assert plan_pf[name].bias_at_end is not None and np.all(plan_pf[name].bias_at_end.sigma > 0)
