"""A recording's median sample step is found once: by the importer while it reads a file, then
handed to the recording's rate and to every stage that turns sample counts into seconds, instead
of a diff and a median over every timestamp each time one asks."""
from dataclasses import replace

import numpy as np
import pytest

from fieldcal.recording import Recording, sample_period
from fieldcal.recording.importer import import_recording


def test_the_period_is_the_median_step_and_is_worked_out_once_per_timestamps_array(monkeypatch):
    t = np.array([0.0, 1.0, 3.0, 4.0, 6.0, 7.5])  # steps 1, 2, 1, 2, 1.5: median 1.5
    assert sample_period(t) == 1.5
    medians = []
    real_median = np.median
    monkeypatch.setattr(np, "median", lambda *a, **k: medians.append(len(a[0])) or real_median(*a, **k))
    assert sample_period(t) == 1.5 and medians == []  # the same array: not again
    same_values = t.copy()
    assert sample_period(same_values) == 1.5 and medians == [5]  # another array: its own


def test_the_period_keeps_no_timestamps_alive():
    import gc
    import weakref

    t = np.arange(1000) * 0.01
    gone = weakref.ref(t)
    assert sample_period(t) == pytest.approx(0.01)
    del t
    gc.collect()
    assert gone() is None


def test_an_imported_recordings_rate_and_period_take_no_second_median(tmp_path, monkeypatch):
    steps = np.tile([0.01, 0.0101, 0.0099, 0.01], 50)  # jittered 100 Hz; median 0.01
    t = 3.0 + np.r_[0.0, np.cumsum(steps)]
    counts = np.column_stack([np.arange(len(t)) % 7, 100 + np.arange(len(t)) % 5, np.full(len(t), 9)])
    paths = []
    for name in ("acc", "gyro"):
        path = tmp_path / f"{name}.txt"
        path.write_text("".join(f"{ti:.6f} {a} {b} {c}\n" for ti, (a, b, c) in zip(t, counts)))
        paths.append(path)
    recording = import_recording(paths, "imu_tk")
    expected = float(np.median(np.diff(recording.t)))
    assert expected == pytest.approx(0.01, abs=1e-9)
    medians = []
    real_median = np.median
    monkeypatch.setattr(np, "median", lambda *a, **k: medians.append(len(a[0])) or real_median(*a, **k))
    again = replace(recording, unit_serial="A1")  # a new Recording (the CLI's): its cached rate gone
    assert again.rate_hz == 1.0 / expected
    assert sample_period(again.t) == expected
    assert medians == []
    assert isinstance(again, Recording)
