"""Two windows with the same start among many out of time order (issue 26's mutation survivors in
session/record.py: the overlap check's sort made unstable). The refusal names the later step
document of the pair, the one the log wrote second, and the earlier one as the window it
overlaps: the same lines however the sort orders equal starts (numpy's default quicksort
reorders ties among more than 16 elements, so this order, found by trying permutations, swaps
the pair where the sort is not stable)."""
import pytest

from fieldcal.session import LOG, SessionError
from fieldcal.session.record import RunRecord
from tests.test_run_record_documents import Log, start, step, window

# twenty one-window steps, 5 s each, starts a shuffle of 0..180 s with steps 3 and 8 both at 20 s
STARTS = [100.0, 0.0, 40.0, 20.0, 120.0, 30.0, 180.0, 150.0, 20.0, 50.0, 170.0, 130.0, 80.0, 160.0,
          90.0, 140.0, 10.0, 70.0, 60.0, 110.0]


def test_a_tie_of_window_starts_names_the_later_document_as_the_overlapping_one(tmp_path):
    steps = [step(k, [window(start=s, duration=5.0)]) for k, s in enumerate(STARTS)]
    with pytest.raises(SessionError) as refused:
        RunRecord(Log(tmp_path, start(), *steps), None, len(STARTS))  # a procedure of twenty positions
    # line 1 is the start document: step k is at line k + 2, so steps 3 and 8 at lines 5 and 10
    assert str(refused.value) == (
        f"{tmp_path / LOG}: line 10: step document: a window from t 20.0 s overlaps one to t 25.0 s (step "
        "document at line 5): windows of the completed steps never share sample time (changed or forged windows)")
