"""Earth rate in the gyro reference: unbiased scale factors with it, a 3e-4 offset without.

One-way rate steps (the paper's formulation: each step's norm against the table rate) see
ω + Ωe·sin φ; ignoring the Earth term biases every scale factor by Ωe·sin φ / ω ≈ 2.7e-4 at 40°
and 10 °/s. Steps turned both ways cancel it in the scale factor by construction.
"""
import dataclasses
import math

import numpy as np

from fieldcal.earth import EARTH_RATE
from fieldcal.procedure.windows import PLUS
from fieldcal.solvers import RateNormProblem, solve_norm

LAT = math.radians(40.0)
RATE = math.radians(10.0)


def one_way_problem(run, rng, earth_rate_on: bool):
    noisy = run.problem("gyroscope", rng)
    order = run.orders["gyroscope"]
    plus_rows = [k for k, w in enumerate(order) if run.plan.windows[w].kind == PLUS]
    cov = run.covariances["gyroscope"]
    idx = np.ravel([[3 * k, 3 * k + 1, 3 * k + 2] for k in plus_rows])
    vertical = EARTH_RATE * math.sin(LAT) if earth_rate_on else 0.0
    problem = RateNormProblem(plus=np.empty((0, 3)), minus=np.empty((0, 3)), table_rate=np.empty(0),
                              static=np.empty((0, 3)), static_step=np.empty(0, int),
                              earth_rate=EARTH_RATE if earth_rate_on else 0.0,
                              earth_rate_vertical=vertical, single=noisy.plus,
                              single_rate=np.full(len(noisy.plus), RATE))
    return problem, cov[np.ix_(idx, idx)]


def scale_errors(run, earth_rate_on: bool, draws: int = 60):
    rng = np.random.default_rng(2)
    errs = []
    for _ in range(draws):
        problem, cov = one_way_problem(run, rng, earth_rate_on)
        errs.append(solve_norm(problem, cov).scale_factor - run.truth["gyroscope"][3:6])
    return np.array(errs)


def test_scale_factors_unbiased_with_earth_rate(field18):
    errs = scale_errors(field18, earth_rate_on=True)
    standard_error = errs.std(axis=0, ddof=1) / np.sqrt(len(errs))
    assert np.all(np.abs(errs.mean(axis=0)) < 3 * standard_error), errs.mean(axis=0) / standard_error


def test_ignoring_earth_rate_shows_the_offset(field18):
    errs = scale_errors(field18, earth_rate_on=False)
    expected = EARTH_RATE * math.sin(LAT) / RATE  # ≈ 2.69e-4
    np.testing.assert_allclose(errs.mean(axis=0), expected, rtol=0.1)


def test_two_way_steps_cancel_earth_rate_in_the_scale_factor(field18):
    rng = np.random.default_rng(3)
    problem = field18.problem("gyroscope", rng)
    off = dataclasses.replace(problem, static=np.empty((0, 3)), static_step=np.empty(0, int),
                              earth_rate=0.0, earth_rate_vertical=0.0)
    on = dataclasses.replace(problem, static=np.empty((0, 3)), static_step=np.empty(0, int))
    n = 6 * len(problem.plus)
    cov = field18.covariances["gyroscope"][:n, :n]
    with_earth, without = solve_norm(on, cov), solve_norm(off, cov)
    # Same scale factors to a small fraction of their σ; the bias misfit shows in χ² instead.
    assert np.all(np.abs(with_earth.scale_factor - without.scale_factor) < 0.05 * with_earth.sigma[3:6])
    assert without.diagnostics.chi2 > 10 * with_earth.diagnostics.chi2
