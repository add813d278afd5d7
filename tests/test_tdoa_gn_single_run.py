"""Gauss-Newton on one run and on many (issue 15, ``benchmarks/bench_tdoa.py`` section 2): a run's
answer does not depend on the rest of the batch, to the last bit, for any number of sensors, and
the measurement model's fast layout computes eqs. 1–5 and 9–14 exactly as written."""

import numpy as np
import pytest

from trackreplay.cores.localisation.gauss_newton import gauss_newton
from trackreplay.cores.localisation.tdoa_fdoa_model import (SPEED_OF_LIGHT_MPS, all_pairs, measurement_model,
                                                         ranges_and_rates)


def reference_model(theta, pos, vel, pairs, f0):
    """Eqs. 2–4 and 9–14 written out on the (…, M, 2) layout of :func:`ranges_and_rates`."""
    i, j = pairs[:, 0], pairs[:, 1]
    c = SPEED_OF_LIGHT_MPS
    k_f = np.asarray(f0, float)[..., None] / c
    r, rdot, u, w = ranges_and_rates(theta, pos, vel)
    g = np.concatenate([(r[..., i] - r[..., j]) / c, k_f * (rdot[..., i] - rdot[..., j])], axis=-1)
    drdot_dp = (w - rdot[..., None] * u) / r[..., None]
    du = u[..., i, :] - u[..., j, :]
    n = len(pairs)
    H = np.zeros(g.shape + (4,))
    H[..., :n, :2] = du / c
    H[..., n:, :2] = k_f[..., None] * (drdot_dp[..., i, :] - drdot_dp[..., j, :])
    H[..., n:, 2:] = k_f[..., None] * du
    return g, H


@pytest.mark.parametrize("sensors", [2, 3, 5])
def test_model_equals_the_written_out_equations_bit_for_bit(sensors):
    rng = np.random.default_rng(sensors)
    pairs = all_pairs(sensors)
    pos, vel = rng.uniform(-1e4, 1e4, (sensors, 2)), rng.uniform(-300, 300, (sensors, 2))
    cases = [(rng.uniform(-5e4, 5e4, 4), pos, vel, 1e9),                          # one state
             (rng.uniform(-5e4, 5e4, (7, 4)), pos, vel, np.full(7, 2.4e9)),       # runs
             (rng.uniform(-5e4, 5e4, (3, 5, 4)), pos, vel, 1e9),                  # a grid
             (rng.uniform(-5e4, 5e4, (4, 1, 4)), rng.uniform(-1e4, 1e4, (4, 6, sensors, 2)),
              rng.uniform(-1, 1, (4, 6, sensors, 2)), rng.uniform(1e9, 2e9, (4, 6)))]  # per-run sensors
    for theta, p, v, f0 in cases:
        g, H = measurement_model(theta, p, v, pairs, f0)
        g_ref, H_ref = reference_model(theta, p, v, pairs, f0)
        assert np.array_equal(g, g_ref) and np.array_equal(H, H_ref)
        assert np.array_equal(measurement_model(theta, p, v, pairs, f0, jacobian=False), g_ref)


@pytest.mark.parametrize("sensors", [3, 4, 6])
@pytest.mark.parametrize("free", [None, [0, 1]])
def test_one_run_equals_its_row_of_the_batch_bit_for_bit(sensors, free):
    """Also with 2N ≥ 8 measurements, where a sum's order could depend on the batch size."""
    rng = np.random.default_rng(10 + sensors)
    pairs = all_pairs(sensors)
    pos, vel = rng.uniform(-2e4, 2e4, (sensors, 2)), rng.uniform(-300, 300, (sensors, 2))
    truth = np.array([5e3, 3e4, 100.0, -50.0])
    sigma = np.r_[np.full(len(pairs), 1e-8), np.full(len(pairs), 1.0)]
    runs = 40
    clean = measurement_model(truth, pos, vel, pairs, 1e9, jacobian=False)
    u = clean + sigma * rng.standard_normal((runs, 2 * len(pairs)))
    theta0 = truth + 0.3 * np.abs(truth) * rng.standard_normal((runs, 4))  # some runs diverge
    theta0[3, 0] = np.nan

    def model(th):
        return measurement_model(th, pos, vel, pairs, 1e9)

    for tol in (1e-6, 0.0):
        kw = dict(iterations=10, step_tolerance=tol, free=free,
                  diverged=lambda th: np.linalg.norm(th[:, :2], axis=1) > 2e5)
        batch = gauss_newton(model, theta0, u, sigma, **kw)
        for r in range(runs):
            one = gauss_newton(model, theta0[r:r + 1], u[r:r + 1], sigma, **kw)
            for field in ("theta", "iterates", "covariance", "cost", "flags", "iterations", "step_sigma"):
                assert np.array_equal(getattr(one, field)[0], getattr(batch, field)[r], equal_nan=True), (r, field)
