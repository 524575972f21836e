"""The full K = diag(k)·(I + M) and its six terms, and what params_from_k refuses, against
hand-worked matrices. Asked for by mutation testing of fieldcal/model.py (issue 26): k_from_terms
had no test of its own, and the refusal's text and its upper-triangle check survived mutants."""
import numpy as np
import pytest

from fieldcal.model import (FULL_PARAM_NAMES, PARAM_NAMES, calibrate_with, k_from, k_from_terms, params_from,
                            params_from_k, terms_from_k)

SCALE = (2.0, 3.0, 4.0)
TERMS = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6)  # m_xy, m_xz, m_yx, m_yz, m_zx, m_zy
# row i of I + M scaled by k_i, worked by hand
K_FULL = np.array([[2.0, 2.0 * 0.1, 2.0 * 0.2],
                   [3.0 * 0.3, 3.0, 3.0 * 0.4],
                   [4.0 * 0.5, 4.0 * 0.6, 4.0]])


def test_k_from_terms_scales_each_row_of_i_plus_m():
    np.testing.assert_allclose(k_from_terms(SCALE, TERMS), K_FULL, rtol=1e-15)
    np.testing.assert_allclose(k_from(np.r_[1.0, 2.0, 3.0, SCALE, TERMS], FULL_PARAM_NAMES), K_FULL, rtol=1e-15)


def test_terms_from_k_and_back():
    k, terms = terms_from_k(K_FULL)
    np.testing.assert_allclose(k, SCALE, rtol=1e-15)
    np.testing.assert_allclose(terms, TERMS, rtol=1e-15)
    np.testing.assert_allclose(params_from(K_FULL, [1.0, 2.0, 3.0], FULL_PARAM_NAMES),
                               np.r_[1.0, 2.0, 3.0, SCALE, TERMS], rtol=1e-15)


def test_the_named_angles_of_a_full_k_are_those_of_its_lower_triangle():
    # delta_yz = -K[1,0]/ky, delta_zy = K[2,0]/kz, delta_zx = -K[2,1]/kz; the upper triangle is left out
    np.testing.assert_allclose(params_from(K_FULL, [0.0] * 3, PARAM_NAMES),
                               [0, 0, 0, 2.0, 3.0, 4.0, -0.3, 0.5, -0.6], rtol=1e-15)


@pytest.mark.parametrize("cell", [(0, 1), (0, 2), (1, 2)])
def test_any_term_above_the_diagonal_is_refused_by_name(cell):
    K = np.eye(3)
    K[cell] = 1e-3
    with pytest.raises(ValueError) as info:
        params_from_k(K, [0.0] * 3)
    assert str(info.value) == "K must be a lower-triangular 3x3 matrix"
    params_from_k(K, [0.0] * 3, full=True)  # a full K is taken, its upper triangle unnamed


def test_a_k_that_is_not_3x3_is_refused_even_when_full():
    with pytest.raises(ValueError) as info:
        params_from_k(np.eye(2), [0.0] * 3, full=True)
    assert str(info.value) == "K must be a 3x3 matrix"


@pytest.mark.parametrize("convert", [k_from, lambda values, names: params_from(np.eye(3), [0] * 3, names)])
def test_an_unknown_parameter_set_is_refused(convert):
    with pytest.raises(ValueError, match=r"unknown parameter set \('bias_x',\)"):
        convert(np.zeros(9), ("bias_x",))


def test_integer_counts_and_an_integer_model_calibrate_to_fractions():
    """A device's counts are integers, and so may be a model written by hand: K⁻¹(raw − b) is not."""
    theta = np.array([1, 1, 1, 2, 2, 4, 0, 0, 0])
    np.testing.assert_array_equal(calibrate_with(theta, np.array([[4, 2, 3]])), [[1.5, 0.5, 0.5]])
