"""The stored form of a completed step's windows (a session's ``step`` documents), against
hand-written JSON documents: the unit's temperature over a window is kept when measured and
absent when not, both ways."""
from __future__ import annotations

import pytest

from fieldcal.procedure.windows import PLUS, STATIC, StepRecord, WindowRecord

# a step document as a session stores it, written by hand
_DOC = {"step": 2, "position_id": 7, "windows": [
    {"kind": "static", "start": 10.0, "duration": 5.0, "rate_deg_s": 0.0,
     "means": {"acc": [0.0, 0.0, 9.81]}, "temperature_c": 23.5},
    {"kind": "plus", "start": 20.0, "duration": 3.6, "rate_deg_s": 100.0,
     "means": {"gyro": [0.0, 0.0, 1.745]}},
]}


def test_a_step_document_reads_to_its_windows_with_the_temperature_where_one_was_measured():
    step = StepRecord.from_dict(_DOC)
    assert (step.step, step.position_id) == (2, 7)
    static, plus = step.windows
    assert static == WindowRecord(STATIC, 10.0, 5.0, 0.0, {"acc": [0.0, 0.0, 9.81]}, 23.5)
    assert plus == WindowRecord(PLUS, 20.0, 3.6, 100.0, {"gyro": [0.0, 0.0, 1.745]}, None)
    assert plus.end == 23.6


def test_a_step_writes_the_document_it_was_read_from():
    assert StepRecord.from_dict(_DOC).to_dict() == _DOC


def test_a_window_without_a_temperature_writes_no_temperature_key():
    # sessions written before temperatures were kept have none; a window of a device that
    # reports none writes the same document
    doc = WindowRecord(STATIC, 0.0, 1.0, 0.0, {"acc": [1.0, 2.0, 3.0]}).to_dict()
    assert doc == {"kind": "static", "start": 0.0, "duration": 1.0, "rate_deg_s": 0.0,
                   "means": {"acc": [1.0, 2.0, 3.0]}}



def test_the_solvers_windows_and_means_come_from_the_records_in_step_order():
    from fieldcal.procedure.engine import windows_and_averages
    from fieldcal.procedure.windows import MINUS, Window

    def record(step, kind, start, rate_deg_s, acc, temperature_c):
        return StepRecord(step, 10 + step, (WindowRecord(kind, start, 2.0, rate_deg_s,
                                                         {"acc": acc, "gyro": [0.0, 0.0, 0.5]}, temperature_c),))

    records = [record(3, MINUS, 50.0, -100.0, [4.0, 5.0, 6.0], 25.0),  # given out of step order
               record(1, STATIC, 10.0, 0.0, [1.0, 2.0, 3.0], None)]
    windows, means = windows_and_averages(records)
    omega = 1.7453292519943295  # 100 °/s in rad/s, by hand
    assert windows == [Window(STATIC, 1, 10.0, 2.0, 0.0, None),
                       Window(MINUS, 3, 50.0, 2.0, pytest.approx(omega, rel=1e-15), 25.0)]
    assert means["acc"].tolist() == [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]
    assert means["gyro"].tolist() == [[0.0, 0.0, 0.5], [0.0, 0.0, 0.5]]
    one_window, one_mean = windows_and_averages(records[1:])
    assert one_window == windows[:1] and one_mean["acc"].tolist() == [[1.0, 2.0, 3.0]]
    assert windows_and_averages([]) == ([], {})
