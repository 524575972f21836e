"""The stillness detector's corners left by the mutation run (issue 26): a bad sample's stretch
starts after it, and the steady path's variance, which rounding can take below zero after a
knock, is never read as NaN. Hand-worked on the small-integer signals of test_stillness_edges."""
from __future__ import annotations

import numpy as np
import pytest

from fieldcal.procedure.stillness import _trailing_std
from tests.test_stillness_edges import run


@pytest.mark.parametrize("sizes", [[11], [5, 6]], ids=["one chunk", "bad sample ends a chunk"])
def test_a_bad_sample_keeps_the_unit_moving_until_a_full_window_after_it(sizes):
    # Three-sample windows on zeros: still from sample 2. A NaN at sample 4 makes every window
    # holding it invalid: those ending at 4, 5 and 6; still again from 7, the first without it.
    values = [0.0] * 4 + [np.nan] + [0.0] * 6
    out = run(values, sizes, enter=0.5, leave=1.0)
    np.testing.assert_array_equal(out, [False, False, True, True, False, False, False, True, True, True, True])


def test_a_variance_rounding_takes_below_zero_is_read_as_zero_not_nan():
    # Two-sample windows after a knock of 1e4 σ: the cumulative sums carry 1e8, and the window
    # [0, 1.05e-5] (exact std 7.4e-6) comes out as s2 − s1²/n ≈ −5.5e-11 before the clamp.
    x = np.array([[1e4], [0.0], [1.0515454759455858e-05]])
    std = _trailing_std(x, 2)
    exact = np.array([np.std(x[:2], ddof=1), np.std(x[1:], ddof=1)])
    assert np.all(np.isfinite(std)) and np.all(std >= 0)
    # within what rounding at the sums' size allows: a variance error of some eps · 1e8
    np.testing.assert_allclose(std[:, 0] ** 2, exact ** 2, rtol=0, atol=8 * np.finfo(float).eps * 1e8)
