"""Posterior Cramér–Rao bound (PCRB) by the Tichavský, Muravchik & Nehorai (1998) recursion.

For a state ``x_{k+1} = F x_k + w_k`` (w ~ N(0, Q)) observed through ``z_k = h(x_k) + v_k``
(v ~ N(0, R)), the Fisher information of the posterior obeys (their eq. 21 with additive
Gaussian noise)

    J_{k+1} = (Q + F J_k⁻¹ Fᵀ)⁻¹ + E[H_{k+1}ᵀ R⁻¹ H_{k+1}],

with ``H`` the Jacobian of ``h`` at the true state and the expectation over the true
trajectories (here: the Monte Carlo runs). In covariance form, with ``A = Q + F P_k Fᵀ`` and
``M = E[Hᵀ R⁻¹ H]``, the bound is ``P_{k+1} = (A⁻¹ + M)⁻¹ = (I + A M)⁻¹ A``: one linear solve per
scan, no inverse, and ``Q = 0`` (deterministic motion) is allowed. For a linear-Gaussian model the
bound equals the Kalman filter's covariance. See ``docs/evaluation.md``.

:func:`linear_gaussian_bound` is that covariance computed in gain form, for models whose
measurements carry no noise of their own (``R`` singular or zero, e.g. a state augmented with a
coloured measurement noise), where the information form above has no ``R⁻¹``.
"""

from __future__ import annotations

import math

import numpy as np

from trackreplay.cores.filters._kalman_fast import joseph_covariance_fast
from trackreplay.cores.filters.kalman import MATRIX_FROM_COMPONENTS, kalman_gain


def pcrb_recursion(P0, F, Q, information) -> np.ndarray:
    """Bound covariances ``P_k`` for k = 0..K−1 from ``P_0``.

    Parameters
    ----------
    P0 : ndarray (n, n)
        Bound at the first scan (e.g. the covariance of the initialisation at the truth).
    F, Q : ndarray (K, n, n) or (n, n)
        Transition into scan k and its process noise (entry 0 unused).
    information : ndarray (K, n, n)
        ``E[H_kᵀ R_k⁻¹ H_k]`` per scan (entry 0 unused); zero where a scan has no measurement.

    Returns
    -------
    ndarray (K, n, n)
        NaN from the first scan whose information cannot be represented (non-finite, or a
        singular ``I + A M``) on.
    """
    M = np.asarray(information, float)
    K, n = M.shape[0], M.shape[-1]
    F = np.broadcast_to(np.asarray(F, float), (K, n, n))
    Q = np.broadcast_to(np.asarray(Q, float), (K, n, n))
    out = np.empty((K, n, n))
    out[0] = P0
    eye = np.eye(n)
    for k in range(1, K):
        A = F[k] @ out[k - 1] @ F[k].T + Q[k]
        B = eye + A @ M[k]
        if not (np.all(np.isfinite(A)) and np.all(np.isfinite(B))):
            out[k:] = np.nan  # information that cannot be represented (e.g. a truth at the sensor)
            break
        try:
            P = np.linalg.solve(B, A)
        except np.linalg.LinAlgError:
            out[k:] = np.nan  # no bound from here on rather than a wrong one
            break
        out[k] = 0.5 * (P + P.T)  # symmetric to rounding
    return out


def _cv_position_pcrb_recursion(P0, dt, sigma_v: float, position_information) -> np.ndarray:
    """:func:`pcrb_recursion` for the 2-D constant-velocity model (state ``[x, y, ẋ, ẏ]``, white
    acceleration of std ``sigma_v``, intervals ``dt`` ``(K,)``, entry 0 unused) observed in
    position only (``position_information`` ``(K, 2, 2)``: the non-zero block of ``M``): a fast
    form for long recordings, equal to it to rounding (tests/test_long_recording.py).

    With ``A = [[A_p, A_c], [A_cᵀ, A_v]]`` in (position, velocity) blocks and ``M`` zero beside
    its position block ``M_p``, ``(I + A M)⁻¹ A`` is ``P_p = E A_p``, ``P_c = E A_c``,
    ``P_v = A_v − A_cᵀ M_p P_c`` with ``E = (I + A_p M_p)⁻¹`` (2 × 2); each scan is then some
    hundred operations on Python floats instead of 4 × 4 products and a solve, which costs a
    hundred times more per scan on a recording of one run. ``A`` is formed as
    :func:`trackreplay.cores.filters.kalman.cv_predict_components` forms it.
    """
    K = len(dt)
    out = np.full((K, 4, 4), np.nan)
    out[0] = P0
    P = np.asarray(P0, float)
    a00, a01, a11 = P[0, 0], P[0, 1], P[1, 1]
    b00, b01, b10, b11 = P[0, 2], P[0, 3], P[1, 2], P[1, 3]
    c00, c01, c11 = P[2, 2], P[2, 3], P[3, 3]
    a00, a01, a11, b00, b01, b10, b11, c00, c01, c11 = (float(v) for v in (a00, a01, a11, b00, b01, b10, b11,
                                                                          c00, c01, c11))
    q = sigma_v * sigma_v
    info = np.asarray(position_information, float)
    rows = []
    for d, m00, m01, m10, m11 in zip(np.asarray(dt, float)[1:].tolist(), *info[1:].reshape(-1, 4).T.tolist()):
        m01 = 0.5 * (m01 + m10)
        q4, q3, q2 = q * d**4 / 4, q * d**3 / 2, q * d * d
        d2 = d * d
        a00, a01, a11, b00, b01, b10, b11, c00, c11 = (
            a00 + 2 * d * b00 + d2 * c00 + q4, a01 + d * (b01 + b10) + d2 * c01, a11 + 2 * d * b11 + d2 * c11 + q4,
            b00 + d * c00 + q3, b01 + d * c01, b10 + d * c01, b11 + d * c11 + q3, c00 + q2, c11 + q2)
        # I + A_p M_p and its inverse E
        e00, e01 = 1.0 + a00 * m00 + a01 * m01, a00 * m01 + a01 * m11
        e10, e11 = a01 * m00 + a11 * m01, 1.0 + a01 * m01 + a11 * m11
        det = e00 * e11 - e01 * e10
        if not (det != 0.0 and math.isfinite(det) and math.isfinite(a00 + a01 + a11 + b00 + b01 + b10 + b11
                                                                     + c00 + c01 + c11)):
            break  # no bound from here on rather than a wrong one (as pcrb_recursion)
        i00, i01, i10, i11 = e11 / det, -e01 / det, -e10 / det, e00 / det
        # P_p = E A_p, P_c = E A_c
        p00, p01 = i00 * a00 + i01 * a01, i00 * a01 + i01 * a11
        p10, p11 = i10 * a00 + i11 * a01, i10 * a01 + i11 * a11
        x00, x01 = i00 * b00 + i01 * b10, i00 * b01 + i01 * b11
        x10, x11 = i10 * b00 + i11 * b10, i10 * b01 + i11 * b11
        # A_cᵀ M_p, then P_v = A_v − A_cᵀ M_p P_c and the lower block A_cᵀ − A_cᵀ M_p P_p
        n00, n01 = b00 * m00 + b10 * m01, b00 * m01 + b10 * m11
        n10, n11 = b01 * m00 + b11 * m01, b01 * m01 + b11 * m11
        v00 = c00 - (n00 * x00 + n01 * x10)
        v01 = c01 - (n00 * x01 + n01 * x11)
        v10 = c01 - (n10 * x00 + n11 * x10)
        v11 = c11 - (n10 * x01 + n11 * x11)
        l00 = b00 - (n00 * p00 + n01 * p10)
        l01 = b10 - (n00 * p01 + n01 * p11)
        l10 = b01 - (n10 * p00 + n11 * p10)
        l11 = b11 - (n10 * p01 + n11 * p11)
        # symmetric to rounding, as pcrb_recursion makes it
        a00, a01, a11 = p00, 0.5 * (p01 + p10), p11
        b00, b01, b10, b11 = 0.5 * (x00 + l00), 0.5 * (x01 + l10), 0.5 * (x10 + l01), 0.5 * (x11 + l11)
        c00, c01, c11 = v00, 0.5 * (v01 + v10), v11
        rows.append((a00, a01, a11, b00, b01, b10, b11, c00, c01, c11))
    if rows:
        c = np.array(rows).T
        n = len(rows)
        out[1:1 + n] = np.moveaxis(c[MATRIX_FROM_COMPONENTS], 0, -1).reshape(n, 4, 4)
    return out


def linear_gaussian_bound(P0, F, Q, H, R) -> np.ndarray:
    """PCRB of a linear-Gaussian model: the Kalman filter's covariance, batched.

    For ``x_k = F_k x_{k−1} + w_k`` (w ~ N(0, Q_k)) and ``z_k = H x_k + v_k`` (v ~ N(0, R)) the
    posterior is Gaussian and its covariance, the Riccati recursion, attains the bound
    (Tichavský et al. 1998, §IV). The gain form needs ``S = H P Hᵀ + R`` to be positive
    definite, not ``R``: a measurement that is exact given an augmented state is allowed.

    Parameters
    ----------
    P0 : ndarray (..., n, n)
        Prior covariance at scan 0, before its measurement.
    F, Q : ndarray (K, ..., n, n)
        Transition into scan k and its process noise (entry 0 unused).
    H : ndarray (m, n)
    R : ndarray (m, m)

    Returns
    -------
    ndarray (K, ..., n, n)
        The bound after each scan's measurement.
    """
    F, Q = np.asarray(F, float), np.asarray(Q, float)
    H, R = np.asarray(H, float), np.asarray(R, float)
    P = np.asarray(P0, float)
    out = np.empty((F.shape[0],) + P.shape)
    for k in range(F.shape[0]):
        if k:
            P = F[k] @ out[k - 1] @ np.swapaxes(F[k], -1, -2) + Q[k]
        K, _ = kalman_gain(P, H, R)
        out[k] = joseph_covariance_fast(P, K, H, R)
    return out


def polar_position_information(truth_xy, sigma_range_m: float, sigma_bearing_rad: float) -> np.ndarray:
    """The position block of :func:`polar_information`, ``(..., 2, 2)``: the only non-zero one
    (a radar Monte Carlo set's average needs no more than this, a fifth of the full matrices)."""
    xy = np.asarray(truth_xy, float)
    r = np.hypot(xy[..., 0], xy[..., 1])
    u0, u1 = xy[..., 0] / r, xy[..., 1] / r
    # u uᵀ/σ_r² + t tᵀ/(r² σ_θ²) with t = (−u₁, u₀), entry by entry: t₀t₀ = u₁u₁, t₁t₁ = u₀u₀ and
    # t₀t₁ = −u₀u₁ exactly (a sign changes no rounding), so each entry is the whole-matrix
    # expression's value to the bit, without its 2 × 2 temporaries (tests/test_evaluation_speed_paths.py)
    range_var, cross_var = sigma_range_m**2, r * r * sigma_bearing_rad**2
    out = np.empty(r.shape + (2, 2))
    out[..., 0, 0] = u0 * u0 / range_var + u1 * u1 / cross_var
    out[..., 1, 1] = u1 * u1 / range_var + u0 * u0 / cross_var
    both = u0 * u1
    out[..., 0, 1] = both / range_var - both / cross_var
    out[..., 1, 0] = out[..., 0, 1]
    return out


def polar_information(truth_xy, sigma_range_m: float, sigma_bearing_rad: float) -> np.ndarray:
    """``Hᵀ R⁻¹ H`` of a range–bearing plot of a CV state ``[x, y, ẋ, ẏ]`` at the true position.

    Parameters
    ----------
    truth_xy : ndarray (..., 2)
    sigma_range_m, sigma_bearing_rad : float

    Returns
    -------
    ndarray (..., 4, 4)
        Only the position block is non-zero: ``u uᵀ/σ_r² + t tᵀ/(r² σ_θ²)`` with u the unit
        line of sight and t its normal (bearing measured from x towards y;
        :func:`polar_position_information`).
    """
    block = polar_position_information(truth_xy, sigma_range_m, sigma_bearing_rad)
    out = np.zeros(block.shape[:-2] + (4, 4))
    out[..., :2, :2] = block
    return out
