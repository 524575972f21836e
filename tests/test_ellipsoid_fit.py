"""The closed-form starts (fieldcal.solvers.ellipsoid) against the truth they were built from:
noise-free averages of a known K and bias lie exactly on the ellipsoid, so the fit must give that
K and bias to rounding (the mutation run of fieldcal/solvers, docs/benchmarks.md: the norm
solvers' tests reach these fits only as a start that Powell then corrects)."""
import numpy as np
import pytest

from fieldcal.model import distort_with, k_from_params
from fieldcal.procedure.positions import load_procedure
from fieldcal.solvers.ellipsoid import DegenerateError, fit_centred_ellipsoid, fit_offset_ellipsoid

G = 9.8
UP18 = np.array([p.up_body for p in load_procedure("field-18").positions])
TRUTH = np.array([0.3, -0.2, 0.1, 1.02, 0.97, 1.01, 0.01, -0.02, 0.015])
# A raw-count device: bias near 32768, ~415 counts per m/s²
RAW = np.array([32768.0, 32000.0, 33000.0, 415.0, 420.0, 410.0, 0.01, -0.02, 0.015])
ANGLES = np.linspace(0, 2 * np.pi, 8, endpoint=False)


@pytest.mark.parametrize("truth", [TRUTH, RAW], ids=["SI", "raw counts"])
def test_noise_free_averages_give_back_the_true_bias_scale_and_angles(truth):
    fitted = fit_offset_ellipsoid(distort_with(truth, G * UP18), G)
    np.testing.assert_allclose(fitted, truth, rtol=1e-12, atol=1e-12)


def test_rate_steps_of_known_sizes_give_back_the_true_k():
    radii = np.resize([1.0, 2.0, 3.0, 1.5, 2.5, 0.5], len(UP18))  # table rates differ per step
    K = k_from_params(TRUTH)
    fitted = fit_centred_ellipsoid((radii[:, None] * UP18) @ K.T, radii)
    np.testing.assert_allclose(fitted, K, rtol=0, atol=1e-13)
    assert np.all(np.triu(fitted, 1) == 0)  # lower-triangular, as the model's K is


def test_identical_averages_are_refused():
    with pytest.raises(DegenerateError, match="^all averages are identical$"):
        fit_offset_ellipsoid(np.ones((10, 3)), G)


def test_averages_in_one_plane_say_how_many_coefficients_they_determine():
    # An ellipse in a horizontal plane: after centring z is 0, so only x², y², xy, x and y remain.
    ellipse = np.c_[np.cos(ANGLES), 0.7 * np.sin(ANGLES), np.full(8, 0.4)]
    with pytest.raises(DegenerateError) as raised:
        fit_offset_ellipsoid(ellipse, 1.0)
    assert str(raised.value) == "the averages determine only 5 of the 9 ellipsoid coefficients"
    with pytest.raises(DegenerateError) as raised:  # centred: x², y² and xy of the six
        fit_centred_ellipsoid(np.c_[ellipse[:, :2], np.zeros(8)], np.ones(8))
    assert str(raised.value) == "the rate steps determine only 3 of the 6 ellipsoid coefficients"


@pytest.mark.parametrize("fit", [lambda p: fit_offset_ellipsoid(p, 1.0),
                                 lambda p: fit_centred_ellipsoid(p, np.ones(len(p)))], ids=["offset", "centred"])
def test_averages_on_a_hyperboloid_are_not_an_ellipsoid(fit):
    # x² + y² − z² = 1: a quadric through every point, but not a closed one.
    points = np.array([[np.cosh(s) * np.cos(a), np.cosh(s) * np.sin(a), np.sinh(s)]
                       for s in (-1.0, 0.5, 1.3) for a in np.linspace(0, 2 * np.pi, 6, endpoint=False)])
    with pytest.raises(DegenerateError) as raised:
        fit(points)
    assert str(raised.value) == "the averages do not lie on an ellipsoid (shape matrix not positive definite)"


def test_averages_off_a_plane_by_rounding_alone_count_as_planar():
    # Rounding-level flatness: the rank's tolerance (1e-9 per average of the normalised design)
    # sees these 1e-10 departures from the plane as none, so the same five coefficients.
    z = 0.4 + 1e-10 * np.random.default_rng(1).standard_normal(8)
    nearly = np.c_[np.cos(ANGLES), 0.7 * np.sin(ANGLES), z]
    with pytest.raises(DegenerateError) as raised:
        fit_offset_ellipsoid(nearly, 1.0)
    assert str(raised.value) == "the averages determine only 5 of the 9 ellipsoid coefficients"
    with pytest.raises(DegenerateError) as raised:  # and rate steps 1e-10 off a plane through zero
        fit_centred_ellipsoid(np.c_[nearly[:, :2], z - 0.4], np.ones(8))
    assert str(raised.value) == "the rate steps determine only 3 of the 6 ellipsoid coefficients"
