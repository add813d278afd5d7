"""The one Kalman filter against an independent textbook per-run implementation."""

import numpy as np
import pytest

from trackreplay.cores.filters.kalman import gaussian_log_likelihood, kf_predict, kf_update, white_acceleration_model


def test_batched_filter_equals_per_run_textbook_loop():
    rng = np.random.default_rng(1)
    n_runs, n_steps = 7, 25
    F, Q = white_acceleration_model(2.0, 0.7)
    H = np.hstack([np.eye(2), np.zeros((2, 2))])
    R = np.array([[40.0, 5.0], [5.0, 90.0]])
    z = rng.normal(size=(n_runs, n_steps, 2)) * 10
    x = np.zeros((n_runs, 4))
    P = np.tile(np.eye(4) * 1e3, (n_runs, 1, 1))
    xs = []
    for k in range(n_steps):
        x, P = kf_predict(x, P, F, Q)
        x, P, *_ = kf_update(x, P, z[:, k], H, R)
        xs.append(x)
    xs = np.stack(xs, 1)
    for r in range(n_runs):
        xr, Pr = np.zeros(4), np.eye(4) * 1e3
        for k in range(n_steps):
            xr, Pr = F @ xr, F @ Pr @ F.T + Q
            S = H @ Pr @ H.T + R
            K = Pr @ H.T @ np.linalg.inv(S)  # textbook form, as the independent reference
            xr = xr + K @ (z[r, k] - H @ xr)
            Pr = (np.eye(4) - K @ H) @ Pr
        np.testing.assert_allclose(xs[r, -1], xr, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(P[r], Pr, rtol=1e-7, atol=1e-9)


def test_white_acceleration_model_matches_kron_form():
    T, q = 5.0, 0.98
    F, Q = white_acceleration_model(T, q)
    g = np.array([T * T / 2, T])
    Q1 = q * q * np.outer(g, g)
    # state order [x, y, vx, vy]
    assert np.allclose(Q[[0, 2]][:, [0, 2]], Q1) and np.allclose(Q[[1, 3]][:, [1, 3]], Q1)
    assert np.allclose(F[0, 2], T) and np.allclose(F[1, 3], T)


def test_log_likelihood_matches_dense_formula():
    rng = np.random.default_rng(2)
    A = rng.normal(size=(5, 3, 3))
    S = A @ A.transpose(0, 2, 1) + 3 * np.eye(3)
    v = rng.normal(size=(5, 3))
    ref = [-0.5 * (vi @ np.linalg.solve(Si, vi) + np.log(np.linalg.det(2 * np.pi * Si))) for vi, Si in zip(v, S)]
    np.testing.assert_allclose(gaussian_log_likelihood(v, S), ref, rtol=1e-12)


def test_cv_kernel_equals_generic_filter_to_rounding():
    from trackreplay.cores.filters.kalman import (
        components_to_matrix,
        cv_apply_gain_components,
        cv_position_gain_components,
        cv_posterior_components,
        cv_predict_components,
        matrix_to_components,
    )

    rng = np.random.default_rng(3)
    n = 50
    M = rng.normal(size=(n, 4, 4))
    P = M @ M.transpose(0, 2, 1) * 100 + np.eye(4)
    x = rng.normal(size=(n, 4)) * 1e3
    L = rng.normal(size=(n, 2, 2))
    Rm = L @ L.transpose(0, 2, 1) * 1e3 + np.eye(2)
    z = rng.normal(size=(n, 2)) * 1e3
    dt, q = 3.7, 1.3
    F, Q = white_acceleration_model(dt, q)
    H = np.hstack([np.eye(2), np.zeros((2, 2))])
    for _ in range(5):  # a few cycles, so errors would compound
        xp, Pp = kf_predict(x, P, F, Q)
        xg, Pg, *_ = kf_update(xp, Pp, z, H, Rm)
        xc, cc = cv_predict_components(x.T.copy(), matrix_to_components(P), dt, q)
        np.testing.assert_allclose(components_to_matrix(cc), Pp, rtol=1e-12, atol=1e-9)
        g = cv_position_gain_components(cc, Rm[:, 0, 0], Rm[:, 0, 1], Rm[:, 1, 1])
        xu = cv_apply_gain_components(xc, g, (z - xc[:2].T).T)
        cu = cv_posterior_components(cc, g)
        np.testing.assert_allclose(xu.T, xg, rtol=1e-10, atol=1e-8)
        np.testing.assert_allclose(components_to_matrix(cu), Pg, rtol=1e-8, atol=1e-6 * np.abs(Pg).max())
        x, P = xg, Pg
        z = z + rng.normal(size=z.shape) * 30


def test_relative_pivots_in_blocks_equal_the_whole_stack(monkeypatch):
    """cv_relative_pivots takes large stacks in blocks; every step is elementwise, so the blocks
    must give the same bits as one pass, NaN and indefinite members included."""
    from trackreplay.cores.filters import kalman

    rng = np.random.default_rng(3)
    A = rng.normal(size=(7 * 13, 4, 4))
    P = A @ np.swapaxes(A, -1, -2) + 1e-3 * np.eye(4)
    P[::11, 2, 2] = -1.0   # not positive definite: NaN pivot
    P[::17, 0, 1] = np.nan
    c = kalman.matrix_to_components(P).reshape(10, 7, 13)
    whole = kalman.cv_relative_pivots(c)
    for block in (1, 13, 20, 50):
        monkeypatch.setattr(kalman, "PIVOT_BLOCK", block)
        np.testing.assert_array_equal(kalman.cv_relative_pivots(c), whole)
        np.testing.assert_array_equal(kalman.cv_relative_pivots(np.moveaxis(np.moveaxis(c, 0, 1).copy(), 1, 0)), whole)
    assert np.isnan(whole.reshape(-1)[::11]).all() and np.isfinite(whole.reshape(-1)[1:11]).all()


def test_floor_on_matrix_entries_equals_floor_on_components():
    """cv_floor_components repairs a stack of 16 matrix entries exactly as the same stack given
    as its ten components: same repaired set, same matrices."""
    from trackreplay.cores.filters.kalman import (ENTRY_OF_COMPONENT, components_to_matrix, cv_floor_components,
                                               matrix_to_components)

    rng = np.random.default_rng(5)
    A = rng.normal(size=(40, 4, 4))
    P = A @ np.swapaxes(A, -1, -2) + 1e-2 * np.eye(4)
    w, V = np.linalg.eigh(P[::3])
    w[:, 0] = -1e-3 * w[:, -1]                       # indefinite: repaired
    P[::3] = (V * w[:, None, :]) @ np.swapaxes(V, -1, -2)
    P[::3] = 0.5 * (P[::3] + np.swapaxes(P[::3], -1, -2))
    P[5, 1, 1] = np.nan                                # not finite: left alone
    live = np.ones(40, bool)
    live[7] = False                                    # dead: left alone
    comps = matrix_to_components(P)
    entries = np.moveaxis(P.reshape(40, 16), -1, 0).copy()
    fixed_c, floored_c = cv_floor_components(comps, live)
    fixed_e, floored_e = cv_floor_components(entries, live)
    assert floored_c[::3][1:].all() and floored_c.sum() == floored_e.sum() > 0
    np.testing.assert_array_equal(floored_c, floored_e)
    np.testing.assert_array_equal(components_to_matrix(fixed_c), np.moveaxis(fixed_e, 0, -1).reshape(40, 4, 4))
    np.testing.assert_array_equal(fixed_e[list(ENTRY_OF_COMPONENT)], fixed_c)
    assert np.linalg.eigvalsh(components_to_matrix(fixed_c)[floored_c]).min() > 0


@pytest.mark.parametrize("shape", [(), (1,), (7,), (500,), (3, 9)])
@pytest.mark.parametrize("scalar_r", [False, True])
def test_cv_position_update_on_stacked_rows_equals_the_row_by_row_form_to_the_bit(monkeypatch, shape, scalar_r):
    """cv_position_update_components_fast takes batches up to ROWS_STACKED_RUNS on stacked rows
    (_kalman_fast.cv_position_update_components_fast, by _cv_position_update_rows): the same operations in the same order, so the same
    gain and posterior to the bit as the written-out form, for any batch shape and for R given
    per run or once; and that posterior is the textbook P − K H P to rounding."""
    from trackreplay.cores.filters import _kalman_fast, kalman

    rng = np.random.default_rng(11)
    M = rng.normal(size=shape + (4, 4))
    P = M @ np.swapaxes(M, -1, -2) * 100 + np.eye(4)
    c = np.moveaxis(P.reshape(shape + (16,))[..., list(kalman.ENTRY_OF_COMPONENT)], -1, 0).copy()
    if scalar_r:
        r = (30.0, -4.0, 55.0)
    else:
        L = rng.normal(size=shape + (2, 2))
        Rm = L @ np.swapaxes(L, -1, -2) * 10 + np.eye(2)
        r = (Rm[..., 0, 0], Rm[..., 0, 1], Rm[..., 1, 1])
    stacked = _kalman_fast.cv_position_update_components_fast(c, *r)
    monkeypatch.setattr(_kalman_fast, "ROWS_STACKED_RUNS", 0)
    written = _kalman_fast.cv_position_update_components_fast(c, *r)
    for a, b in zip(stacked, written):
        assert a.shape == b.shape
        np.testing.assert_array_equal(a, b)
    textbook = kalman.cv_posterior_components(c, written[0])
    np.testing.assert_allclose(stacked[1], textbook, rtol=1e-9, atol=1e-9 * np.abs(c).max())


@pytest.mark.parametrize("n_stack", [3, 5000])
def test_joseph_covariance_fast_equals_the_plain_form(n_stack):
    """The fast form (two contractions for a large stack, the plain function otherwise) against
    the textbook (I − KH) P (I − KH)ᵀ + K R Kᵀ."""
    from trackreplay.cores.filters import kalman
    from trackreplay.cores.filters._kalman_fast import joseph_covariance_fast

    rng = np.random.default_rng(3)
    root = rng.normal(size=(n_stack, 4, 4))
    P = root @ np.swapaxes(root, -1, -2) + 0.1 * np.eye(4)
    K = rng.normal(size=(n_stack, 4, 2))
    H = np.array([[1.0, 0, 0, 0], [0, 1.0, 0, 0]])
    R = np.array([[4.0, 0.5], [0.5, 9.0]])
    plain = kalman.joseph_covariance(P, K, H, R)
    np.testing.assert_allclose(joseph_covariance_fast(P, K, H, R), plain, rtol=1e-12, atol=1e-12 * np.abs(plain).max())



@pytest.mark.parametrize("runs, per_run_R", [(1, False), (7, False), (7, True)])
def test_two_component_whitened_update_equals_the_general_form_to_the_bit(runs, per_run_R):
    """The written-out 2-D update (_whitened_update_2) gives _whitened_update's bits, and
    stacked_kf_step takes it for a two-component measurement."""
    from trackreplay.cores.filters import kalman
    rng = np.random.default_rng(3)
    G, N, m = 3, 6, 2
    B = rng.standard_normal((G, N, N, runs))
    Pp = np.einsum("gikr,gjkr->gijr", B, B) + np.eye(N)[None, :, :, None]
    xp = rng.standard_normal((G, N, runs))
    H = rng.standard_normal((G, m, N, runs))
    C = rng.standard_normal((m, m, runs if per_run_R else 1))
    R_meas = np.einsum("ikr,jkr->ijr", C, C) + np.eye(m)[:, :, None]
    HP = np.einsum("gmnr,gnkr->gmkr", H, Pp)
    S = np.einsum("gmnr,gknr->gmkr", HP, H) + R_meas
    nu = rng.standard_normal((G, m, runs))
    fast = kalman._whitened_update_2(S, HP, nu, xp, Pp)
    plain = kalman._whitened_update(S, HP, nu, xp, Pp)
    for a, b in zip(fast, plain):
        assert a.shape == b.shape
        assert np.array_equal(a, b), np.max(np.abs(a - b))
    # and the whole step: P = P⁻ − K S Kᵀ, NIS = νᵀ S⁻¹ ν from the dense formulas
    F = np.broadcast_to(np.eye(N), (G, N, N))
    Q = np.zeros((G, N, N, 1))
    y = rng.standard_normal((m, runs))
    x, P, ll, nis, nu2, S2 = kalman.stacked_kf_step(F, Q, None, xp, Pp, y, H, R_meas)
    Sm = np.moveaxis(S2, -1, 1)                                  # (G, runs, m, m)
    K = np.einsum("gnkr,gmkr->grnm", Pp, H) @ np.linalg.inv(Sm)
    P_dense = np.moveaxis(Pp, -1, 1) - K @ Sm @ np.swapaxes(K, -1, -2)
    assert np.allclose(np.moveaxis(P, -1, 1), P_dense, atol=1e-10)
    nu_r = np.moveaxis(nu2, -1, 1)[..., None]
    assert np.allclose(nis, (np.swapaxes(nu_r, -1, -2) @ np.linalg.solve(Sm, nu_r))[..., 0, 0])
