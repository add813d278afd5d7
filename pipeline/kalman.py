"""The one Kalman filter: predict and update, batched over any leading axes.

Shapes: state ``x`` is ``(..., n)``, covariance ``P`` is ``(..., n, n)``; model matrices may be
shared ``(n, n)`` or batched ``(..., n, n)``. Every Monte Carlo run of a data set goes through
one call, so a study costs one pass over the scans, not one Python loop per run.
"""

from __future__ import annotations

import numpy as np


def kf_predict(x: np.ndarray, P: np.ndarray, F: np.ndarray, Q: np.ndarray):
    """Time update ``x⁻ = F x``, ``P⁻ = F P Fᵀ + Q``.

    Returns
    -------
    x_pred, P_pred : ndarray
    """
    x_pred = np.einsum("...ij,...j->...i", F, x)
    P_pred = F @ P @ np.swapaxes(F, -1, -2) + Q
    return x_pred, 0.5 * (P_pred + np.swapaxes(P_pred, -1, -2))


def kalman_gain(P: np.ndarray, H: np.ndarray, R: np.ndarray):
    """Gain ``K = P Hᵀ S⁻¹`` and innovation covariance ``S = H P Hᵀ + R``.

    ``S`` is symmetric, so ``Kᵀ = S⁻¹ (H P)`` comes from one batched solve (no inverse).
    """
    HP = H @ P
    S = HP @ np.swapaxes(H, -1, -2) + R
    K = np.swapaxes(np.linalg.solve(S, HP), -1, -2)
    return K, S


def apply_gain(x: np.ndarray, P: np.ndarray, K: np.ndarray, innovation: np.ndarray,
               H: np.ndarray, R: np.ndarray | None):
    """Measurement update with a given gain (optimal or not).

    The Joseph form ``(I − KH) P (I − KH)ᵀ + K R Kᵀ`` keeps ``P`` symmetric positive
    semi-definite for any gain, which matters for the suboptimal α-β gains.
    If ``R`` is None only the state is updated and ``P`` is returned unchanged.
    """
    x_post = x + np.einsum("...ij,...j->...i", K, innovation)
    if R is None:
        return x_post, P
    n = P.shape[-1]
    A = np.eye(n) - K @ H
    P_post = A @ P @ np.swapaxes(A, -1, -2) + K @ R @ np.swapaxes(K, -1, -2)
    return x_post, 0.5 * (P_post + np.swapaxes(P_post, -1, -2))


def gaussian_log_likelihood(innovation: np.ndarray, S: np.ndarray) -> np.ndarray:
    """``log N(ν; 0, S)`` per batch element, through a Cholesky factor of ``S``."""
    L = np.linalg.cholesky(S)
    w = np.linalg.solve(L, innovation[..., None])[..., 0]
    m = innovation.shape[-1]
    logdet = 2.0 * np.sum(np.log(np.diagonal(L, axis1=-2, axis2=-1)), axis=-1)
    return -0.5 * (np.sum(w * w, axis=-1) + logdet + m * np.log(2.0 * np.pi))


def kf_update(x: np.ndarray, P: np.ndarray, z: np.ndarray, H: np.ndarray, R: np.ndarray):
    """Optimal measurement update.

    Returns
    -------
    x_post, P_post, innovation, S, K
    """
    innovation = z - np.einsum("...ij,...j->...i", H, x)
    K, S = kalman_gain(P, H, R)
    x_post, P_post = apply_gain(x, P, K, innovation, H, R)
    return x_post, P_post, innovation, S, K


def white_acceleration_model(dt: float | np.ndarray, sigma_v: float, axes: int = 2):
    """Constant-velocity model with piecewise-constant white acceleration (per axis).

    State order ``[x, y, …, ẋ, ẏ, …]``: positions first, then velocities.

    Returns
    -------
    F, Q : ndarray
        ``(..., 2·axes, 2·axes)``, batched if ``dt`` is an array.
    """
    dt = np.asarray(dt, dtype=float)
    I = np.eye(axes)
    Z = np.zeros((axes, axes))
    F = np.block([[I, Z], [Z, I]]) + np.kron(np.array([[0.0, 1.0], [0.0, 0.0]]), I) * dt[..., None, None]
    g = np.stack(np.broadcast_arrays(0.5 * dt**2, dt), axis=-1)  # (..., 2)
    q1 = sigma_v**2 * g[..., :, None] * g[..., None, :]  # (..., 2, 2) per-axis block
    Q = np.einsum("...ab,ij->...aibj", q1, I).reshape(*dt.shape, 2 * axes, 2 * axes)
    return F, Q
