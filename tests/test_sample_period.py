"""A recording's median sample step is found once: by the importer while it reads a file, kept as
the Recording's own ``period_s`` (and its rate), and handed to every stage that turns sample
counts into seconds, instead of a diff and a median over every timestamp each time one asks. No
module keeps a memo of timestamps arrays (a hidden cache): the period belongs to its recording."""
import numpy as np
import pytest

import fieldcal.recording as recording_module
from fieldcal.recording import Recording, median_step
from fieldcal.recording.importer import import_recording


def counting_medians(monkeypatch) -> list[int]:
    medians: list[int] = []
    real_median = np.median
    monkeypatch.setattr(np, "median", lambda *a, **k: medians.append(len(a[0])) or real_median(*a, **k))
    return medians


def test_the_period_is_the_median_step_worked_out_once_per_recording(monkeypatch):
    t = np.array([0.0, 1.0, 3.0, 4.0, 6.0, 7.5])  # steps 1, 2, 1, 2, 1.5: median 1.5
    assert median_step(t) == 1.5
    recording = Recording(t=t, triads={"a": np.zeros((6, 3))}, kinds={"a": "specific_force"}, units={"a": "count"})
    medians = counting_medians(monkeypatch)
    assert recording.period_s == 1.5 and recording.rate_hz == 1 / 1.5
    assert recording.period_s == 1.5 and medians == [5]  # once, for both
    with_serial = recording.replaced(unit_serial="A1")  # the same timestamps: the same period, not again
    assert with_serial.unit_serial == "A1" and with_serial.period_s == 1.5 and medians == [5]
    other = recording.replaced(t=t * 2.0)  # other timestamps: their own period
    assert other.period_s == 3.0 and other.rate_hz == 1 / 3.0 and medians == [5, 5]
    assert Recording(t=t[:1], triads={}, kinds={}, units={}).period_s == 0.0


def test_no_module_level_memo_of_timestamps():
    assert not [name for name in vars(recording_module) if "memo" in name.lower()]
    assert not hasattr(recording_module, "sample_period") and not hasattr(recording_module, "remember_period")


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
    medians = counting_medians(monkeypatch)
    again = recording.replaced(unit_serial="A1")  # a new Recording (the CLI's)
    assert again.rate_hz == 1.0 / expected
    assert again.period_s == expected
    assert medians == []
    assert isinstance(again, Recording)


def test_the_stages_take_the_recordings_period_not_another_median(monkeypatch):
    """The noise-weighted solve's covariance of the pose means is made from the period handed
    to it: a pose of 100 samples at a given period lasts 100 periods (its flicker's window)."""
    from fieldcal.recording.noise_estimate import MeasuredNoise
    from fieldcal.recording.static_solve import means_covariance

    t = np.arange(1000) * 0.01
    intervals = np.array([[0, 100], [500, 700]])
    noise = MeasuredNoise(white=0.0, bias_instability=1e-3)
    medians = counting_medians(monkeypatch)
    at_period = means_covariance(intervals, t, np.ones(3), noise, np.eye(3), "m/s^2", period=0.01)
    assert medians == []
    # Half the period: each pose half as long, its mean's flicker variance different.
    at_half = means_covariance(intervals, t, np.ones(3), noise, np.eye(3), "m/s^2", period=0.005)
    assert not np.allclose(at_period, at_half)
    with pytest.raises(TypeError):
        means_covariance(intervals, t, np.ones(3), noise, np.eye(3), "m/s^2")  # the period is required
