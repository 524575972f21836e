"""The bound's rank rule: a parameter the data cannot tell apart has an infinite σ ("not yet
determined"), never a huge finite one that rounding turns into another number or into inf.

Hand-built linear data y = A·x + noise, covariance diag(σ₀², σ₁², σ₂²), three parameters:
y₀ = a, y₁ = a + b₁ + b₂, y₂ = ε·b₂. Solved by hand: a = y₀, b₂ = y₂/ε, b₁ = y₁ − y₀ − y₂/ε, so
σ_a = σ₀, σ_b₂ = σ₂/ε, σ_b₁ = √(σ₀² + σ₁² + σ₂²/ε²) for any ε > 0. At ε = 0 the data see only
b₁ + b₂: b₁ and b₂ are undetermined, a is still exactly σ₀ (it is told by y₀ alone, although the
information matrix couples it with both)."""
from __future__ import annotations

import numpy as np
import pytest

from fieldcal.solvers.crb import RANK_TOL, EndBias, _bound

SIGMAS = np.array([0.3, 0.7, 1.9])
STEPS = np.full(3, 1e-6)


def _design(eps: float) -> np.ndarray:
    return np.array([[1.0, 0.0, 0.0], [1.0, 1.0, 1.0], [0.0, 0.0, eps]])


def _sigmas(eps: float, scale: float = 1.0, end: EndBias | None = None):
    A = _design(eps)
    covariance = np.diag((scale * SIGMAS) ** 2)
    out = _bound(lambda x: x @ A.T, np.zeros(3), STEPS, covariance, end, wanted=3)
    bound = out if end is None else out[0]
    with np.errstate(invalid="ignore"):
        sigmas = np.sqrt(np.diag(bound))
    return sigmas if end is None else (sigmas, out[1])


def _by_hand(eps: float) -> np.ndarray:
    s0, s1, s2 = SIGMAS
    return np.array([s0, np.sqrt(s0**2 + s1**2 + (s2 / eps) ** 2), s2 / eps])


@pytest.mark.parametrize("eps", [1.0, 1e-3, 1e-5, 1e-6])
def test_a_weak_but_seen_direction_has_its_exact_sigma(eps):
    # 1e-5 and 1e-6: the information's inverse is past the Cholesky path's trace, the singular
    # value decomposition inverts it; a gyro's Earth-rate-only misalignments sit about there.
    assert np.allclose(_sigmas(eps), _by_hand(eps), rtol=1e-6, atol=0)


@pytest.mark.parametrize("eps", [0.0, 1e-13, RANK_TOL / 10])
@pytest.mark.parametrize("scale", [1.0, 0.37, 7.3])  # other roundings of the same design
def test_a_direction_the_data_do_not_see_leaves_its_parameters_undetermined_and_the_rest_exact(eps, scale):
    sigmas = _sigmas(eps, scale)
    assert sigmas[1] == np.inf and sigmas[2] == np.inf
    assert sigmas[0] == pytest.approx(scale * SIGMAS[0], rel=1e-9)


def test_the_sigma_only_falls_as_the_unseen_direction_comes_into_view():
    """Information only grows with ε: the σ never goes from finite to inf or nan."""
    eps = np.r_[0.0, np.geomspace(1e-16, 1.0, 49)]
    b2 = np.array([_sigmas(e)[2] for e in eps])
    assert not np.any(np.isnan(b2))
    assert all(later <= earlier for earlier, later in zip(b2, b2[1:]))
    seen = eps > RANK_TOL * 10  # the largest singular value is ~1.6 (unit columns), the smallest ~ε
    assert np.allclose(b2[seen], SIGMAS[2] / eps[seen], rtol=1e-6)


def test_the_bias_at_the_end_is_undetermined_where_the_bias_is():
    """With the bias at the end (a point uncorrelated with the data, variance 1): the predictor of
    a determined parameter has its own variance plus the point's; an undetermined one is inf."""
    end = EndBias(cross=np.zeros((3, 3)), point=np.eye(3))
    sigmas, ends = _sigmas(0.0, end=end)
    predicted = np.sqrt(np.diag(ends.predicted))
    assert predicted[0] == pytest.approx(np.sqrt(SIGMAS[0] ** 2 + 1.0), rel=1e-9)
    assert predicted[1] == np.inf and predicted[2] == np.inf
    assert np.isinf(np.diag(ends.constant)[1:]).all()
    _, determined = _sigmas(1e-2, end=end)
    assert np.sqrt(np.diag(determined.predicted)) == pytest.approx(np.sqrt(_by_hand(1e-2) ** 2 + 1.0), rel=1e-9)
