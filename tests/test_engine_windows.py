"""What the engine keeps of a dwell, against the samples it was fed: the window's mean is the
plain mean of the samples between its stated start and its stated length, its temperature their
mean temperature, whatever the chunks' boundaries (a dwell that starts or ends mid-chunk)."""
import numpy as np
import pytest

from drivers.chunk import SampleChunk
from fieldcal.procedure import events as ev
from fieldcal.procedure.engine import Engine, EngineSettings
from fieldcal.procedure.stillness import StillnessSettings
from fieldcal.procedure.positions import parse_procedure

RATE_HZ = 100.0
DWELL_S = 3
PROCEDURE = f"""name: one
dwell_s: {DWELL_S}
positions:
  - {{id: 1, description: "z-upward", axes: {{x: east, y: north, z: up}}}}
"""
# 37: not a divisor of anything the engine counts, windows start and end mid-chunk; 1000: the
# whole dwell inside one chunk
CHUNKS = (37, 1000)


def samples(k):
    """Sample k of a still unit, z up: a small known pattern on every axis (well inside the
    stillness thresholds), so that any other choice of samples gives another mean."""
    wiggle = 1e-4 * ((k * 7) % 11 - 5)[:, None] * np.array([1.0, -2.0, 3.0])
    sf = np.array([0.0, 0.0, 9.8]) + wiggle
    rate = 1e-6 * wiggle
    temperature = 20.0 + 1e-3 * (k % 13)
    return sf, rate, temperature


def run(with_temperature=True, chunk_n=37):
    engine = Engine(parse_procedure(PROCEDURE, "p.yaml"),
                    EngineSettings(rate_hz=RATE_HZ, stillness=StillnessSettings(specific_force_sigma=2e-3,
                                                                               rate_sigma=1e-4)))
    engine.start()
    engine.act(ev.Action(ev.READY))
    for first in range(0, 20 * int(RATE_HZ), chunk_n):
        k = np.arange(first, first + chunk_n)
        sf, rate, temperature = samples(k)
        chunk = SampleChunk(k / RATE_HZ, {"accelerometer": sf, "gyroscope": rate},
                            temperature if with_temperature else None)
        if any(isinstance(e, ev.ProcedureComplete) for e in engine.feed(chunk)):
            return engine
    raise AssertionError("the procedure never completed")


@pytest.mark.parametrize("chunk_n", CHUNKS)
def test_the_dwell_window_is_the_mean_of_exactly_the_samples_it_says_it_covers(chunk_n):
    (window,) = run(chunk_n=chunk_n).records[0].windows
    assert window.duration == DWELL_S  # the planned samples, counted at the nominal rate
    first = round(window.start * RATE_HZ)
    assert first % chunk_n != 0  # (the point: a dwell starting inside a chunk)
    k = np.arange(first, first + DWELL_S * int(RATE_HZ))
    sf, rate, temperature = samples(k)
    assert window.means["accelerometer"] == pytest.approx(sf.mean(axis=0).tolist(), abs=1e-12)
    assert window.means["gyroscope"] == pytest.approx(rate.mean(axis=0).tolist(), abs=1e-16)
    assert window.temperature_c == pytest.approx(temperature.mean(), abs=1e-12)


def test_a_device_without_temperatures_gives_windows_without_one():
    (window,) = run(with_temperature=False).records[0].windows
    assert window.temperature_c is None
