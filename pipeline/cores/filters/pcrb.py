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

import numpy as np


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
    from pipeline.cores.filters.kalman import joseph_covariance, kalman_gain

    F, Q = np.asarray(F, float), np.asarray(Q, float)
    H, R = np.asarray(H, float), np.asarray(R, float)
    P = np.asarray(P0, float)
    out = np.empty((F.shape[0],) + P.shape)
    for k in range(F.shape[0]):
        if k:
            P = F[k] @ out[k - 1] @ np.swapaxes(F[k], -1, -2) + Q[k]
        K, _ = kalman_gain(P, H, R)
        out[k] = joseph_covariance(P, K, H, R)
    return out


def polar_position_information(truth_xy, sigma_range_m: float, sigma_bearing_rad: float) -> np.ndarray:
    """The position block of :func:`polar_information`, ``(..., 2, 2)``: the only non-zero one
    (a radar Monte Carlo set's average needs no more than this, a fifth of the full matrices)."""
    xy = np.asarray(truth_xy, float)
    r = np.hypot(xy[..., 0], xy[..., 1])
    u = xy / r[..., None]
    t = np.stack([-u[..., 1], u[..., 0]], axis=-1)
    return (u[..., :, None] * u[..., None, :]) / sigma_range_m**2 \
        + (t[..., :, None] * t[..., None, :]) / (r[..., None, None] ** 2 * sigma_bearing_rad**2)


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
