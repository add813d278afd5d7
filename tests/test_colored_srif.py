"""The square-root information filter against the Kalman filter (spec colored-noise-imm-srif.md)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from trackreplay.errors import InputError
from trackreplay.cores.filters.kalman import gaussian_log_likelihood, kf_predict, kf_update
from trackreplay.cores.filters.srif import (information_factor, srif_filter, srif_from_moments, srif_measurement_update,
                           srif_moments, srif_time_update)


def ca_model(T):
    F = np.array([[1.0, T, T * T / 2], [0.0, 1.0, T], [0.0, 0.0, 1.0]])
    G = np.array([[T**3 / 6], [T * T / 2], [T]])
    return F, G


def kalman_reference(x0, P0, F, Q, H, y, R, dtype=np.float64, likelihood=True):
    """The foundation's Kalman filter run over a record (state, covariance, log-likelihood)."""
    runs, scans, _ = y.shape
    n = F.shape[0]
    x = np.asarray(x0, dtype)
    P = np.broadcast_to(np.asarray(P0, dtype), (runs, n, n)).astype(dtype)
    xs, Ps, lls = [x], [P], [np.full(runs, np.nan)]
    for k in range(1, scans):
        x, P = kf_predict(x, P, F.astype(dtype), Q.astype(dtype))
        x, P, nu, S, _ = kf_update(x, P, y[:, k].astype(dtype), H.astype(dtype), R.astype(dtype))
        x, P = x.astype(dtype), P.astype(dtype)   # single precision stays single precision between steps
        lls.append(gaussian_log_likelihood(nu, S) if likelihood else np.full(runs, np.nan))
        xs.append(x)
        Ps.append(P)
    return np.stack(xs, 1), np.stack(Ps, 1), np.stack(lls, 1)


def test_srif_equals_kalman_filter_state_covariance_and_likelihood():
    rng = np.random.default_rng(3)
    T = 0.05
    F, G = ca_model(T)
    q = np.array([[400.0]])
    H = np.array([[1.0, 0.0, 0.0]])
    R = np.array([[100.0]])
    runs, scans = 6, 400
    truth = 1000 + 150 * T * np.arange(scans) + 0.5 * 20 * (T * np.arange(scans)) ** 2
    y = truth[None, :, None] + 10 * rng.standard_normal((runs, scans, 1))
    x0 = np.tile([1000.0, 150.0, 0.0], (runs, 1))
    P0 = 100 * np.eye(3)
    s = srif_filter(x0, P0, F, G, q, H, y, R)
    xk, Pk, llk = kalman_reference(x0, P0, F, G @ q @ G.T, H, y, R)
    scale_x = np.abs(xk).max()
    assert np.max(np.abs(s["state"] - xk)) <= 1e-9 * scale_x
    for k in range(scans):
        scale_P = np.abs(Pk[:, k]).max()
        assert np.max(np.abs(s["covariance"][:, k] - Pk[:, k])) <= 1e-9 * scale_P
    assert np.max(np.abs(s["log_likelihood"][:, 1:] - llk[:, 1:])) <= 1e-9
    assert np.all(np.isnan(s["log_likelihood"][:, 0]))


def test_determinant_lemma_is_the_squared_form():
    """|S| = (|R_{k|k}| / (|R_{k|k−1}| |R_ν|))² (the thesis prints it without the square)."""
    rng = np.random.default_rng(0)
    A = rng.standard_normal((5, 3, 3))
    P = A @ np.swapaxes(A, 1, 2) + 3 * np.eye(3)
    x = rng.standard_normal((5, 3))
    H = rng.standard_normal((2, 3))
    Rm = np.array([[4.0, 1.0], [1.0, 3.0]])
    y = rng.standard_normal((5, 2))
    R, z = srif_from_moments(x, P)
    R = np.linalg.qr(R, mode="r")        # any triangular square root of the same information
    R, z = R, np.einsum("rij,rj->ri", R, x)
    Rv = information_factor(Rm)
    Rp, zp, e, ll = srif_measurement_update(R, z, H, y, Rv)
    nu = y - x @ H.T
    S = H @ P @ H.T + Rm
    det_S = np.linalg.det(S)
    det_sqrt = np.abs(np.linalg.det(Rp) / (np.linalg.det(R) * np.linalg.det(Rv)))
    np.testing.assert_allclose(det_sqrt**2, det_S, rtol=1e-10)
    assert not np.allclose(det_sqrt, det_S, rtol=1e-3)
    np.testing.assert_allclose(e**2, np.einsum("ri,rij,rj->r", nu, np.linalg.inv(S), nu), rtol=1e-10)
    np.testing.assert_allclose(ll, gaussian_log_likelihood(nu, np.broadcast_to(S, (5, 2, 2))), rtol=1e-10, atol=1e-12)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), T=st.floats(0.01, 2.0), log_q=st.floats(-2, 4), log_r=st.floats(-1, 4),
       order=st.sampled_from([2, 3]))
def test_srif_matches_kalman_on_random_well_conditioned_problems(seed, T, log_q, log_r, order):
    rng = np.random.default_rng(seed)
    if order == 2:
        F = np.array([[1.0, T], [0.0, 1.0]])
        G = np.array([[T * T / 2], [T]])
    else:
        F, G = ca_model(T)
    n = order
    q = np.array([[10.0**log_q]])
    H = np.zeros((1, n))
    H[0, 0] = 1.0
    R = np.array([[10.0**log_r]])
    A = rng.standard_normal((2, n, n))
    P0 = A @ np.swapaxes(A, 1, 2) + np.eye(n)
    x0 = rng.standard_normal((2, n))
    y = rng.standard_normal((2, 12, 1)) * np.sqrt(R[0, 0]) + np.arange(12)[None, :, None]
    s = srif_filter(x0, P0, F, G, q, H, y, R)
    xk, Pk, llk = kalman_reference(x0, P0, F, G @ q @ G.T, H, y, R)
    for k in range(12):
        sx = 1.0 + np.abs(xk[:, k]).max()
        sP = np.abs(Pk[:, k]).max()
        assert np.max(np.abs(s["state"][:, k] - xk[:, k])) <= 1e-9 * sx
        assert np.max(np.abs(s["covariance"][:, k] - Pk[:, k])) <= 1e-9 * sP
    assert np.max(np.abs(s["log_likelihood"][:, 1:] - llk[:, 1:])) <= 1e-8


def test_single_precision_huge_prior_tiny_noise_kf_goes_indefinite_srif_stays_pd():
    """P₀ = 1e10 I, R = 1e-6, float32: the Kalman covariance (foundation kf_predict/kf_update,
    stored in float32 between steps) acquires negative eigenvalues and its state drifts by several
    reference standard deviations; the float32 SRIF's factor keeps a positive diagonal (so
    P = R⁻¹R⁻ᵀ is positive definite by construction) and its state and covariance stay close to
    the float64 reference."""
    rng = np.random.default_rng(0)
    T = 0.05
    F, G = ca_model(T)
    q = np.array([[1.0]])
    H = np.array([[1.0, 0.0, 0.0]])
    R = np.array([[1e-6]])
    runs, scans = 1, 100
    y = rng.standard_normal((runs, scans, 1)) * 1e-3 + np.linspace(0, 5, scans)[None, :, None]
    x0 = np.zeros((runs, 3))
    P0 = 1e10 * np.eye(3)
    ref = srif_filter(x0, P0, F, G, q, H, y, R)
    # the float64 reference is itself consistent with the float64 Kalman filter here
    xk64, Pk64, _ = kalman_reference(x0, P0, F, G @ q @ G.T, H, y, R)
    sd = np.sqrt(np.diagonal(ref["covariance"], axis1=-2, axis2=-1))
    assert np.max(np.abs(xk64 - ref["state"]) / sd) < 1e-2

    f32 = np.float32
    s32 = srif_filter(*(a.astype(f32) for a in (x0, P0, F, G, q, H, y, R)))
    assert s32["R"].dtype == f32 and s32["state"].dtype == f32
    xk, Pk, _ = kalman_reference(x0, P0, F, G @ q @ G.T, H, y, R, dtype=f32, likelihood=False)
    assert Pk.dtype == f32

    kf_min_eig = np.array([np.linalg.eigvalsh(Pk[0, k].astype(float))[0] for k in range(scans)])
    assert (kf_min_eig < 0).any(), "the single-precision Kalman covariance should lose positive definiteness"
    kf_err = np.abs(xk - ref["state"]) / sd
    assert np.nanmax(kf_err) > 1.0

    diag = np.diagonal(s32["R"], axis1=-2, axis2=-1)
    assert np.all(np.isfinite(diag)) and np.all(diag > 0)
    for k in range(scans):
        Rk = s32["R"][0, k].astype(float)
        S = np.linalg.solve(Rk, np.eye(3))
        P = S @ S.T
        assert np.linalg.eigvalsh(P)[0] > 0
        Pref = ref["covariance"][0, k]
        np.testing.assert_allclose(np.diag(P), np.diag(Pref), rtol=1e-3)
    srif_err = np.abs(s32["state"] - ref["state"]) / sd
    assert np.max(srif_err) < 0.05


def test_moment_round_trip_and_time_update_against_kalman_prediction():
    rng = np.random.default_rng(1)
    F, G = ca_model(0.1)
    A = rng.standard_normal((4, 3, 3))
    P = A @ np.swapaxes(A, 1, 2) + np.eye(3)
    x = rng.standard_normal((4, 3))
    R, z = srif_from_moments(x, P)
    x2, P2 = srif_moments(R, z)
    np.testing.assert_allclose(x2, x, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(P2, P, rtol=1e-12, atol=1e-12)
    q = np.array([[5.0]])
    Rp, zp = srif_time_update(R, z, F, G, information_factor(q))   # R Φ⁻¹ by a solve with Φᵀ
    assert np.allclose(np.tril(Rp, -1), 0.0) and np.all(np.diagonal(Rp, axis1=1, axis2=2) >= 0)
    xp, Pp = srif_moments(Rp, zp)
    xk, Pk = kf_predict(x, P, F, G @ q @ G.T)
    np.testing.assert_allclose(xp, xk, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(Pp, Pk, rtol=1e-10, atol=1e-10)


@pytest.mark.parametrize("bad", [np.array([[0.0]]), np.array([[-1.0]]), np.array([[np.nan]]),
                                 np.array([[1.0, 2.0], [2.0, 1.0]])])
def test_measurement_covariance_not_positive_definite_is_a_clear_error(bad):
    with pytest.raises(InputError, match="positive definite|NaN"):
        information_factor(bad, "measurement-noise covariance R")


def test_singular_transition_is_a_clear_error():
    F = np.array([[1.0, 0.05, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 0.0]])
    _, G = ca_model(0.05)
    with pytest.raises(InputError, match="singular"):
        srif_filter(np.zeros((1, 3)), np.eye(3), F, G, np.eye(1), np.array([[1.0, 0, 0]]),
                    np.zeros((1, 5, 1)), np.eye(1))
