"""benchmarks/fast.py's common random numbers: on one seed, every procedure's simulated unit has the
same noise at the same sample since power-on, however the hands moved it before; without them the
hand shake's draws shift the noise stream (what made the two procedures' errors only partly
shared)."""
import sys
from pathlib import Path

import numpy as np

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
