"""Kalata gains, the approximate update and the stability clamp, against independent computations."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.linalg import solve_discrete_are

from trackreplay.cores.filters.alpha_beta_gains import (
    approximate_gains,
    clamp_to_stability,
    kalata_gain_slopes,
    kalata_gains,
    startup_gains,
    steady_state_covariance,
    tracking_index,
)


def dare_gains(sigma_v, T, sigma_w):
    """Steady-state Kalman gain and updated covariance of the 1-D white-acceleration model."""
    F = np.array([[1.0, T], [0.0, 1.0]])
    G = np.array([[T * T / 2], [T]])
    Q = sigma_v**2 * G @ G.T
    H = np.array([[1.0, 0.0]])
    R = np.array([[sigma_w**2]])
    P = solve_discrete_are(F.T, H.T, Q, R)  # predicted covariance
    S = H @ P @ H.T + R
    K = np.linalg.solve(S, H @ P).T
    P_upd = (np.eye(2) - K @ H) @ P
    return K[0, 0], K[1, 0] * T, P_upd


@pytest.mark.parametrize("sigma_w", [20.0, 100.0, 150.0, 400.0, 2000.0])
@pytest.mark.parametrize("T", [1.0, 5.0])
def test_kalata_gains_equal_steady_state_kalman_gains(sigma_w, T):
    sigma_v = 0.98
    alpha, beta = kalata_gains(tracking_index(sigma_v, T, sigma_w))
    a_ref, b_ref, _ = dare_gains(sigma_v, T, sigma_w)
    assert abs(alpha - a_ref) <= 1e-9
    assert abs(beta - b_ref) <= 1e-9


@pytest.mark.parametrize("sigma_w", [30.0, 150.0, 900.0])
def test_steady_state_covariance_equals_riccati_solution(sigma_w):
    T, sigma_v = 5.0, 0.98
    alpha, beta = kalata_gains(tracking_index(sigma_v, T, sigma_w))
    _, _, P_ref = dare_gains(sigma_v, T, sigma_w)
    P = steady_state_covariance(alpha, beta, T, sigma_w)
    np.testing.assert_allclose(P, P_ref, rtol=1e-8)


def test_slopes_match_central_differences():
    lam = np.geomspace(1e-3, 10, 25)
    h = 1e-6 * lam
    a_p, b_p = kalata_gains(lam + h)
    a_m, b_m = kalata_gains(lam - h)
    m_a, m_b = kalata_gain_slopes(lam)
    np.testing.assert_allclose(m_a, (a_p - a_m) / (2 * h), rtol=1e-6)
    np.testing.assert_allclose(m_b, (b_p - b_m) / (2 * h), rtol=1e-6)


@settings(max_examples=60, deadline=None)
@given(lam_bar=st.floats(0.005, 2.0), rel=st.floats(0.05, 0.3), sign=st.sampled_from([-1.0, 1.0]))
def test_approximate_gain_error_is_second_order(lam_bar, rel, sign):
    """Halving Δλ divides the approximation error by ≈ 4 (error ∝ Δλ²)."""
    errs = []
    for d in (rel * lam_bar, rel * lam_bar / 2):
        lam = lam_bar + sign * d
        a_apx, b_apx = approximate_gains(lam, lam_bar)
        a_ex, b_ex = kalata_gains(lam)
        errs.append((abs(a_apx - a_ex), abs(b_apx - b_ex)))
    for k in range(2):
        ratio = errs[0][k] / errs[1][k]
        assert 3.0 < ratio < 5.5, (k, ratio)


def test_approximate_gains_exact_at_nominal():
    lam_bar = 0.16
    np.testing.assert_array_equal(approximate_gains(lam_bar, lam_bar), kalata_gains(lam_bar))


@settings(max_examples=200, deadline=None)
@given(alpha=st.floats(-5, 5), beta=st.floats(-5, 10))
def test_clamp_lands_inside_stability_region(alpha, beta):
    a, b, clamped = clamp_to_stability(alpha, beta)
    assert 0 < a < 1 and 0 < b < 4 - 2 * a
    inside = 0 < alpha < 1 and 0 < beta < 4 - 2 * alpha
    if not inside:
        assert clamped
    if not clamped:
        assert (a, b) == (alpha, beta)


def test_clamp_leaves_interior_untouched_and_flags_outside():
    a, b, c = clamp_to_stability(np.array([0.5, 1.4, 0.6]), np.array([0.3, 0.2, 3.5]))
    np.testing.assert_array_equal(c, [False, True, True])
    assert a[0] == 0.5 and b[0] == 0.3


def test_startup_gains_start_at_two_point_fit_and_decay():
    a, b = startup_gains(np.arange(2, 50))
    assert a[0] == 1.0 and b[0] == 1.0
    assert np.all(np.diff(a) < 0) and np.all(np.diff(b) < 0)
