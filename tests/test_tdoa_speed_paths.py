"""The Gauss-Newton speed paths (issue 15, ``benchmarks/bench_tdoa.py`` section 2) compute what the
batched path computes, to the last bit: the one-run path (Python floats after the LAPACK QR), the
stacked QR called in place, and the fallback of a one-run call to the batched loop when a step is
irregular."""

import numpy as np
import pytest

from pipeline.cores.localisation import batched_least_squares as bls
from pipeline.cores.localisation.gauss_newton import _one_run, _prepare, gauss_newton
from pipeline.cores.localisation.tdoa_fdoa_model import all_pairs, measurement_model
from pipeline.vocabulary import CONVERGED, DIVERGED, INVALID_START, NOT_CONVERGED, RANK_DEFICIENT

FIELDS = ("theta", "iterates", "covariance", "cost", "flags", "iterations", "step_sigma")


def assert_same_run(one, batch, r=0):
    for field in FIELDS:
        a, b = getattr(one, field)[0], getattr(batch, field)[r]
        assert np.array_equal(a, b, equal_nan=True), (field, a, b)
        assert getattr(one, field).dtype == getattr(batch, field).dtype, field


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


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("free", [None, [0, 1]])
@pytest.mark.parametrize("tol", [1e-6, 0.0])
def test_one_run_path_equals_the_batched_loop(seed, free, tol):
    # two copies of a run make a batch (the batched loop); one alone takes the one-run path
    model, theta0, u, sigma = problem(seed, sensors=3 + seed % 3)
    taken = 0
    for r in range(len(u)):
        kw = dict(iterations=10, step_tolerance=tol, free=free)
        one = gauss_newton(model, theta0[r:r + 1], u[r:r + 1], sigma, **kw)
        pair = gauss_newton(model, theta0[[r, r]], u[[r, r]], sigma, **kw)
        assert_same_run(one, pair)
        f, measured, sig, measured_t, sigma_t = _prepare(theta0[r:r + 1].copy(), u[r:r + 1], sigma, free)
        with np.errstate(all="ignore"):
            taken += _one_run(model, theta0[r:r + 1].copy(), measured_t, sigma_t, f, 10, tol, {}, None) is not None
    assert taken == len(u)  # these runs are regular: the fast path is the one measured


def test_one_run_path_with_per_run_inputs_and_a_divergence_test():
    # the tracker's form: per-run sensors and carrier as batch rows, σ per run, a divergence test
    rng = np.random.default_rng(3)
    runs, sensors = 12, 4
    pairs = all_pairs(sensors)
    pos = rng.uniform(-2e4, 2e4, (runs, sensors, 2))
    vel = rng.uniform(-300, 300, (runs, sensors, 2))
    f0 = rng.uniform(1e9, 2e9, runs)
    truth = np.array([5e3, 3e4, 100.0, -50.0])
    sigma = np.r_[np.full(len(pairs), 1e-8), np.full(len(pairs), 1.0)] * rng.uniform(0.5, 2, (runs, 1))
    u = measurement_model(truth, pos, vel, pairs, f0, jacobian=False) + sigma * rng.standard_normal(sigma.shape)
    theta0 = truth + 0.05 * np.abs(truth) * rng.standard_normal((runs, 4))
    rows = [0, 1, 2, 3, 4, 6, 7]  # a subset of the measurements, as the tracker's kinds take

    def model(th, sensor_pos, sensor_vel, carrier_hz):
        g, H = measurement_model(th, sensor_pos, sensor_vel, pairs, carrier_hz)
        return g[:, rows], H[:, rows]

    def diverged(th, sensor_pos, sensor_vel, carrier_hz):
        return np.linalg.norm(th[:, :2] - sensor_pos.mean(axis=1), axis=1) > 1e5

    batch = {"sensor_pos": pos, "sensor_vel": vel, "carrier_hz": f0}
    kw = dict(iterations=10, step_tolerance=1e-6, diverged=diverged)
    whole = gauss_newton(model, theta0, u[:, rows], sigma[:, rows], batch=batch, **kw)
    for r in range(runs):
        one = gauss_newton(model, theta0[r:r + 1], u[r:r + 1, rows], sigma[r:r + 1, rows],
                           batch={k: v[r:r + 1] for k, v in batch.items()}, **kw)
        assert_same_run(one, whole, r)


def test_irregular_runs_fall_back_to_the_batched_loop():
    model, theta0, u, sigma = problem(7, runs=4, spread=0.3)
    theta0[0, 1] = np.nan                                   # invalid start
    theta0[1] = [0.0, 0.0, 0.0, 0.0]                        # far: diverges under the test below
    kw = dict(iterations=10, diverged=lambda th: np.linalg.norm(th[:, :2], axis=1) > 1e5)
    f, measured, sig, measured_t, sigma_t = _prepare(theta0[:1].copy(), u[:1], sigma, None)
    with np.errstate(all="ignore"):
        assert _one_run(model, theta0[:1].copy(), measured_t, sigma_t, f, 10, 1e-6, {}, None) is None
    whole = gauss_newton(model, theta0, u, sigma, **kw)
    assert whole.flags[0] & INVALID_START
    for r in range(len(u)):
        assert_same_run(gauss_newton(model, theta0[r:r + 1], u[r:r + 1], sigma, **kw), whole, r)
    # a rank-deficient Jacobian (the velocity columns zero: a model without FDOA dependence)
    def flat(th):
        g, H = model(th)
        H[:, :, 2:] = 0.0
        return g, H

    one = gauss_newton(flat, theta0[2:3], u[2:3], sigma, iterations=5)
    assert one.flags[0] & (RANK_DEFICIENT | DIVERGED) and not one.flags[0] & CONVERGED  # its step is NaN
    assert_same_run(one, gauss_newton(flat, theta0[[2, 2]], u[[2, 2]], sigma, iterations=5))


def test_one_run_path_flags_and_padding():
    model, theta0, u, sigma = problem(11, runs=1)
    stop = gauss_newton(model, theta0, u, sigma, iterations=10)
    assert stop.flags[0] == CONVERGED and 1 <= stop.iterations[0] < 10
    assert np.all(stop.iterates[0, stop.iterations[0]:] == stop.theta[0])
    fixed = gauss_newton(model, theta0, u, sigma, iterations=3, step_tolerance=0.0)
    assert fixed.flags[0] == NOT_CONVERGED and fixed.iterations[0] == 3
    assert not (fixed.flags[0] & DIVERGED)


def test_householder_equals_lapack_qr_to_rounding_and_the_one_member_form_to_the_bit():
    rng = np.random.default_rng(5)
    for m, n, b in ((6, 5, 1), (6, 5, 300), (12, 5, 7), (4, 3, 2), (30, 5, 3)):
        M = rng.standard_normal((m, n, b)) * 10.0 ** rng.uniform(-3, 3, (1, n, b))
        M[:, :n - 1] /= np.sqrt(np.add.reduce(M[:, :n - 1] ** 2, axis=0))  # unit columns, as _factor gives
        ref = M.copy()
        bls._qr_lapack(ref)
        ours = M.copy()
        bls._householder_in_place(ours)
        q = n - 1
        R_ref, R = np.triu(ref[:q].transpose(2, 0, 1)), np.triu(ours[:q].transpose(2, 0, 1))
        # R and Q₁ᵀb are unique up to the sign of each row
        sign = np.sign(R_ref[:, np.arange(q), np.arange(q)] * R[:, np.arange(q), np.arange(q)])
        np.testing.assert_allclose(R * sign[:, :, None], R_ref, rtol=0, atol=1e-13 * np.abs(R_ref).max())
        for r in range(b):  # one member alone, and as Python floats: the same bits
            alone = M[:, :, r:r + 1].copy()
            bls._householder_in_place(alone)
            cols = M[:, :, r].T.tolist()
            bls._householder_columns(cols)
            unrolled = M[:, :, r].T.tolist()
            bls._householder_unrolled(m, n)(unrolled)
            for k in range(q):
                assert np.array_equal(alone[k, k:, 0], ours[k, k:, r])
                assert [c[k] for c in cols[k:]] == ours[k, k:, r].tolist()
                assert [c[k] for c in unrolled[k:]] == ours[k, k:, r].tolist()
    assert bls._householder_unrolled(6, 5) is bls._householder_unrolled(6, 5)  # built once per shape
    with pytest.raises(ValueError, match="m ≥ q"):  # fewer equations than unknowns: refused, not solved
        bls._factor_one([[1.0, 2.0]] * 4, bls.ZERO_COLUMN_RTOL, bls.RANK_RTOL)
    zero = np.zeros((6, 5, 2))
    zero[:, 1, 1] = 1.0  # a zero column before a non-zero one
    bls._householder_in_place(zero)
    assert np.isfinite(zero).all()


@pytest.mark.parametrize("seed", range(20))
def test_one_member_helpers_equal_the_stacked_ones(seed):
    rng = np.random.default_rng(seed)
    m, q = int(rng.integers(4, 9)), int(rng.integers(1, 5))
    B = 50
    M = rng.standard_normal((m, q + 1, B)) * 10.0 ** rng.uniform(-8, 8, (1, q + 1, B))
    Rt, scale, bad, bad_any, cost = bls._factor(M.copy(), bls.ZERO_COLUMN_RTOL, bls.RANK_RTOL)
    x, norm = bls._step(Rt, scale, bad, bad_any)
    cov = bls._covariance_rows(Rt, scale, bad, bad_any)
    for r in range(B):
        R1, scale1, bad1, cost1 = bls._factor_one(M[:, :, r].T.tolist(), bls.ZERO_COLUMN_RTOL, bls.RANK_RTOL)
        assert bad1 == bad[r] and cost1 == cost[r] and scale1 == scale[:, r].tolist()
        assert R1 == [row[:, r].tolist() for row in Rt]
        if bad1:
            continue
        x1, norm1 = bls._step_one(R1, scale1)
        assert x1 == x[:, r].tolist() and norm1 == norm[r]
        assert bls._covariance_one(R1, scale1) == cov[r].tolist()
