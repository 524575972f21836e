"""The ellipsoid fits' corners (issue 26's mutation survivors in solvers/ellipsoid.py): averages
whose mean is not the bias (field-18's directions cancel, so its centre came out of the mean and
the fitted centre was never tested), and shape matrices whose off-diagonal couples one pair of
axes strongly, where a wrong lower-triangle cell turns a true ellipsoid indefinite. The truth is
the K and bias the points were made from: |K⁻¹(p − b)| = r exactly."""
import numpy as np
import pytest

from fieldcal.model import distort_with, k_from_params
from fieldcal.solvers.ellipsoid import fit_centred_ellipsoid, fit_offset_ellipsoid
from tests.test_ellipsoid_fit import RAW, TRUTH, UP18

G = 9.8
# The six axes and six diagonals all leaning toward +x+y+z: their mean is well off zero
_DIRECTIONS = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1],
                        [1, 1, 0], [1, 0, 1], [0, 1, 1], [1, 1, 1], [1, -1, 1], [2, 1, -1]], dtype=float)
LOPSIDED = _DIRECTIONS / np.linalg.norm(_DIRECTIONS, axis=1, keepdims=True)


def test_the_lopsided_directions_do_not_average_to_zero():
    assert np.linalg.norm(LOPSIDED.mean(axis=0)) > 0.3 and len(LOPSIDED) >= 9


@pytest.mark.parametrize("truth", [TRUTH, RAW], ids=["SI", "raw counts"])
def test_averages_whose_mean_is_not_the_bias_give_back_the_true_parameters(truth):
    fitted = fit_offset_ellipsoid(distort_with(truth, G * LOPSIDED), G)
    np.testing.assert_allclose(fitted, truth, rtol=1e-9, atol=1e-9)


def _k_of_shape(M):
    """A K with (K⁻¹)ᵀK⁻¹ = M (any such K: the points are the same set)."""
    return np.linalg.inv(np.linalg.cholesky(M).T)


# |K⁻¹v|² = vᵀMv with one strong coupling: x–z, or y–z
COUPLED = {"x-z": np.array([[1.0, 0.0, 0.9], [0.0, 1.0, 0.0], [0.9, 0.0, 1.0]]),
           "y-z": np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.9], [0.0, 0.9, 1.0]])}


@pytest.mark.parametrize("coupling", COUPLED)
def test_a_strongly_coupled_centred_ellipsoid_is_fitted_not_refused(coupling):
    M = COUPLED[coupling]
    radii = np.resize([1.0, 2.0, 3.0, 1.5, 2.5, 0.5], len(UP18))
    fitted = fit_centred_ellipsoid((radii[:, None] * UP18) @ _k_of_shape(M).T, radii)
    inverse = np.linalg.inv(fitted)
    np.testing.assert_allclose(inverse.T @ inverse, M, rtol=0, atol=1e-12)


@pytest.mark.parametrize("coupling", COUPLED)
def test_a_strongly_coupled_offset_ellipsoid_is_fitted_not_refused(coupling):
    K, bias = _k_of_shape(COUPLED[coupling]), np.array([0.3, -0.2, 0.1])
    fitted = fit_offset_ellipsoid(G * LOPSIDED @ K.T + bias, G)
    inverse = np.linalg.inv(k_from_params(fitted))
    np.testing.assert_allclose(inverse.T @ inverse, COUPLED[coupling], rtol=0, atol=1e-9)
    np.testing.assert_allclose(fitted[:3], bias, rtol=0, atol=1e-9)
