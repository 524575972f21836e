"""sliding_std's edges (the block sums themselves are checked against np.var in test_stillness):
its shapes, its default ddof, its refusal of a one-sample window, and rest read as exactly 0."""
import numpy as np
import pytest
from numpy.lib.stride_tricks import sliding_window_view

from fieldcal.procedure import sliding
from fieldcal.procedure.sliding import sliding_std


def test_one_column_given_flat_is_one_column_out():
    x = [1.0, 2.0, 4.0, 8.0]
    got = sliding_std(x, 2)
    assert got.shape == (3, 1)
    # sample standard deviations (ddof 1) by hand: |a - b| / sqrt(2)
    np.testing.assert_allclose(got[:, 0], [1 / np.sqrt(2), 2 / np.sqrt(2), 4 / np.sqrt(2)], rtol=1e-12)


def test_ddof_0_is_the_population_deviation():
    x = np.array([[0.0, 10.0], [2.0, 10.0], [4.0, 13.0]])
    np.testing.assert_allclose(sliding_std(x, 3, ddof=0), [[np.sqrt(8 / 3), np.sqrt(2.0)]], rtol=1e-12)
    np.testing.assert_allclose(sliding_std(x, 3), [[2.0, np.sqrt(3.0)]], rtol=1e-12)


@pytest.mark.parametrize("n", [1, 0, -3])
def test_a_window_of_fewer_than_two_samples_is_refused(n):
    with pytest.raises(ValueError) as refused:
        sliding_std(np.zeros((10, 2)), n)
    assert str(refused.value) == f"window of {n} samples: need at least 2"


def test_fewer_rows_than_a_window_give_no_rows_and_exactly_a_window_one():
    assert sliding_std(np.zeros((4, 3)), 5).shape == (0, 3)
    assert sliding_std(np.zeros((5, 3)), 5).shape == (1, 3)


def test_rest_reads_exactly_zero_around_any_offset():
    x = np.full((700, 2), 32768.0)
    x[:, 1] = 9.80665
    assert not np.any(sliding_std(x, 50))


@pytest.mark.parametrize("m, n", [(64, 2), (65, 8), (97, 16), (33, 33), (33, 2), (40, 24)])
def test_inputs_worked_in_small_pieces_give_every_window(monkeypatch, m, n):
    monkeypatch.setattr(sliding, "_PIECE_ROWS", 16)  # pieces of 16 rows (or one window): many of them
    rng = np.random.default_rng(m * n)
    x = 1000.0 + rng.standard_normal((m, 2))
    truth = sliding_window_view(x, n, axis=0).std(axis=-1, ddof=1)
    np.testing.assert_allclose(sliding_std(x, n), truth, rtol=1e-9)


@pytest.mark.parametrize("m, n", [(64, 2), (97, 16), (33, 33), (40, 24)])
def test_variance_by_column_is_every_window_variance(monkeypatch, m, n):
    monkeypatch.setattr(sliding, "_PIECE_ROWS", 16)  # many pieces
    rng = np.random.default_rng(m + n)
    x = 32768.0 + rng.standard_normal((m, 3)) * [1.0, 5.0, 0.1]
    truth = sliding_window_view(x, n, axis=0).var(axis=-1, ddof=0)  # (windows, columns)
    got = sliding.sliding_variance_by_column(x, n, ddof=0)
    assert got.shape == (3, m - n + 1)
    np.testing.assert_allclose(got, truth.T, rtol=1e-9)
    assert sliding.sliding_variance_by_column(x[: n - 1], n).shape == (3, 0)
