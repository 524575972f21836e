"""benchmarks/fast.py's common random numbers: on one seed, every procedure's simulated unit has the
same noise at the same sample since power-on, however the hands moved it before; without them the
hand shake's draws shift the noise stream (what made the two procedures' errors only partly
shared)."""
import sys
from pathlib import Path

import numpy as np
import pytest

from fieldcal.procedure.positions import load_procedure
from fieldcal.run.runner import TABLE_ACCEL_DEG_S2, RunSpec, SimulatedBench
from fieldcal.run.simcal import DEFAULT_STATION

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from fast import common_noise_bench  # noqa: E402


def samples_after(bench, handled: bool) -> dict:
    """The unit at rest on a stopped table for samples 250-499, carried by hand or left still
    for samples 0-249."""
    sim, still = bench.sim, np.eye(3)
    if handled:
        sim.handle(250, still, still)  # the hand's shake draws from the simulator's stream
    else:
        sim.advance(250, still, 0.0, np.radians(TABLE_ACCEL_DEG_S2))
    return sim.advance(250, still, 0.0, np.radians(TABLE_ACCEL_DEG_S2)).triads


def test_the_noise_at_a_sample_is_the_seeds_whatever_came_before():
    spec = RunSpec(load_procedure("field-18"), DEFAULT_STATION, seed=3)
    carried, still = (samples_after(common_noise_bench(spec), handled) for handled in (True, False))
    for name in carried:
        assert np.array_equal(carried[name], still[name]), name
    other = samples_after(common_noise_bench(RunSpec(spec.procedure, DEFAULT_STATION, seed=4)), False)
    assert not np.allclose(other["gyroscope"], still["gyroscope"])
    plain = samples_after(SimulatedBench(spec), True), samples_after(SimulatedBench(spec), False)
    assert not np.allclose(plain[0]["gyroscope"], plain[1]["gyroscope"])


def test_chunks_merge_and_a_procedure_against_itself_is_ratio_one_and_misses_the_time(tmp_path, capsys):
    """mc in two chunks of seeds, report joining them: the planned procedure against itself has
    every RMS and σ ratio exactly 1 and operator-time ratio 1, so the time condition is missed
    (exit 1); chunks of another flicker cut-off or the same seeds twice are refused in one line."""
    import fast

    planned = str(Path(__file__).parent / "data" / "planned-field-18-sim.yaml")
    chunks = []
    for first in (0, 1):
        out = tmp_path / f"p{first}.npz"
        assert fast.main(["mc", "--procedure", planned, "--runs", "1", "--first-seed", str(first),
                          "--out", str(out)]) == 0
        chunks.append(str(out))
    capsys.readouterr()
    assert fast.main(["report", "--reference", *chunks, "--planned", *chunks]) == 1
    printed = capsys.readouterr().out
    assert "2 seeds run by both" in printed and "ratio 1.000" in printed
    rows = [line for line in printed.splitlines() if line.startswith("| ") and "±" in line and "s.e." not in line]
    assert len(rows) == 3 * 12  # per triad: 9 judged (biases at the end), 3 turn-on biases
    assert all("| 1.000 ± 0.000 | 1.000 |" in row for row in rows)
    assert "MISSED operator time ratio 1.000" in printed and "met    worst σ ratio" in printed
    other = tmp_path / "tau.npz"
    assert fast.main(["mc", "--procedure", planned, "--runs", "1", "--first-seed", "2",
                      "--flicker-tau-max", "1e5", "--out", str(other)]) == 0
    for bad in ([*chunks, str(other)], [chunks[0], chunks[0]]):
        with pytest.raises(SystemExit) as refused:
            fast.main(["report", "--reference", *bad, "--planned", chunks[0]])
        assert "\n" not in str(refused.value) and str(refused.value).startswith("report: ")
