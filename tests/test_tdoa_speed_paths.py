"""A run's Gauss-Newton answer does not depend on the batch it is solved in, to the last bit: one
run alone (a single recording) and the same run beside others (a Monte Carlo set) take the same
batched path (``benchmarks/bench_tdoa.py`` section 2 times both)."""

import numpy as np
import pytest

from trackreplay.cores.localisation.gauss_newton import gauss_newton
from trackreplay.cores.localisation.tdoa_fdoa_model import all_pairs, measurement_model

FIELDS = ("theta", "iterates", "covariance", "cost", "flags", "iterations", "step_sigma")


def problem(seed, sensors=3, runs=30, spread=0.01):
    rng = np.random.default_rng(seed)
    pairs = all_pairs(sensors)
    pos, vel = rng.uniform(-2e4, 2e4, (sensors, 2)), rng.uniform(-300, 300, (sensors, 2))
    truth = np.array([rng.uniform(-3e4, 3e4), rng.uniform(1e4, 5e4), 100.0, -50.0])
    sigma = np.r_[np.full(len(pairs), 1e-8), np.full(len(pairs), 1.0)]
    clean = measurement_model(truth, pos, vel, pairs, 1e9, jacobian=False)
    u = clean + sigma * rng.standard_normal((runs, 2 * len(pairs)))
    theta0 = truth + spread * np.abs(truth) * rng.standard_normal((runs, 4))

    def model(th):
        return measurement_model(th, pos, vel, pairs, 1e9)

    return model, theta0, u, sigma


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("free", [None, [0, 1]])
@pytest.mark.parametrize("tol", [1e-6, 0.0])
def test_one_run_alone_equals_its_row_in_a_batch(seed, free, tol):
    model, theta0, u, sigma = problem(seed, sensors=3 + seed % 3)
    kw = dict(iterations=10, step_tolerance=tol, free=free)
    batch = gauss_newton(model, theta0, u, sigma, **kw)
    for r in range(0, len(u), 7):
        one = gauss_newton(model, theta0[r:r + 1], u[r:r + 1], sigma, **kw)
        for field in FIELDS:
            a, b = getattr(one, field)[0], getattr(batch, field)[r]
            assert np.array_equal(a, b, equal_nan=True), (field, r, a, b)


@pytest.mark.parametrize("seed", range(3))
def test_single_matrix_factor_equals_its_slice_of_the_stacked_factor(seed):
    """A stack of one goes to scipy's ``dgeqrf`` and a stack to numpy's stacked QR: the same
    LAPACK routine, so the factors must agree to the bit, badly scaled columns included."""
    from trackreplay.cores.localisation.batched_least_squares import _geqrf_rows

    rng = np.random.default_rng(seed)
    for m, q in [(6, 4), (12, 4), (3, 2), (20, 3), (5, 4), (4, 4)]:  # the last: as many rows as unknowns
        M = rng.standard_normal((m, q + 1, 9)) * 10.0 ** rng.uniform(-8, 8, (1, q + 1, 9))
        stacked = _geqrf_rows(M.copy(), q)
        for b in range(M.shape[2]):
            alone = _geqrf_rows(M[:, :, b:b + 1].copy(), q)
            assert alone.shape == (q, q + 1, 1)
            assert np.array_equal(alone[:, :, 0], stacked[:, :, b]), (m, q, b)
