"""The certificate's temperature is noted while the replay reads the session (one read of the
samples, not two): every chunk counts, whether the replay reads to the end, stops early or fails.
The expected range and mean are worked by hand from the chunks below."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from drivers.chunk import SampleChunk
from fieldcal.certificate import evidence

# Three chunks, an action between them; a NaN and a chunk without temperature are left out:
# 20.0, 21.5, 19.0, 23.5 -> low 19.0, high 23.5, mean 84 / 4 = 21.0, 4 samples.
CHUNKS = [SampleChunk(t=np.array([0.0, 1.0]), triads={}, temperature=np.array([20.0, 21.5])),
          SampleChunk(t=np.array([2.0, 3.0]), triads={}, temperature=np.array([np.nan, 19.0])),
          SampleChunk(t=np.array([4.0]), triads={}),
          SampleChunk(t=np.array([5.0]), triads={}, temperature=np.array([23.5]))]
EXPECTED = evidence.Temperature(19.0, 23.5, 21.0, 4)


class FakeRecord:
    """What gather and the replay operator read of a RunRecord; counts the reads of the samples."""

    def __init__(self, directory):
        self.directory = directory
        self.spec = SimpleNamespace(procedure=SimpleNamespace(positions=[]))
        self.steps, self.skipped = [], []
        self.reads = 0

    def replay_items(self, types=("chunk", "action")):
        self.reads += 1
        items = [("chunk", CHUNKS[0]), ("action", {}), ("chunk", CHUNKS[1]), ("chunk", CHUNKS[2]),
                 ("chunk", CHUNKS[3])]
        return iter([(kind, item) for kind, item in items if kind in types])

    def chunks(self):
        return (item for _, item in self.replay_items(("chunk",)))


def fake_replay(read: int, fails: bool):
    def replay(record, operator=None):
        from fieldcal.run.operators import ReplayOperator
        operator = operator if operator is not None else ReplayOperator(record)
        for _ in range(read):
            next(operator.items)
        if fails:
            raise ValueError("the solve failed")
        return SimpleNamespace(unit=None)
    return replay


@pytest.mark.parametrize("read", [0, 2, 5])
def test_the_temperature_counts_every_chunk_however_far_the_replay_read_and_reads_the_samples_once(
        tmp_path, monkeypatch, read):
    monkeypatch.setattr("fieldcal.run.replay.replay", fake_replay(read, fails=False))
    record = FakeRecord(tmp_path)
    found = evidence.gather(record)
    assert found.temperature == EXPECTED
    assert record.reads == 1


def test_a_failed_replay_has_its_temperature_from_a_whole_read_of_the_session(tmp_path, monkeypatch):
    monkeypatch.setattr("fieldcal.run.replay.replay", fake_replay(2, fails=True))
    found = evidence.gather(FakeRecord(tmp_path))
    assert found.residual_note.endswith("re-solving the session failed (the solve failed)")
    assert found.temperature == EXPECTED
