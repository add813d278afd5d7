"""The one Kalman filter: predict and update, batched over any leading axes.

Shapes: state ``x`` is ``(..., n)``, covariance ``P`` is ``(..., n, n)``; model matrices may be
shared ``(n, n)`` or batched ``(..., n, n)``. Every Monte Carlo run of a data set goes through
one call, so a study costs one pass over the scans, not one Python loop per run.
"""

from __future__ import annotations

from math import factorial

import numpy as np

from trackreplay.batched_linalg import cholesky_lower, forward_substitute

LOG_2PI = float(np.log(2.0 * np.pi))
_sum = np.add.reduce   # ndarray.sum's Python wrapper costs more than the sum of a few small arrays


def kf_predict(x: np.ndarray, P: np.ndarray, F: np.ndarray, Q: np.ndarray):
    """Time update ``x⁻ = F x``, ``P⁻ = F P Fᵀ + Q``.

    Returns
    -------
    x_pred, P_pred : ndarray
    """
    x_pred = np.einsum("...ij,...j->...i", F, x)
    P_pred = F @ P @ np.swapaxes(F, -1, -2) + Q
    return x_pred, 0.5 * (P_pred + np.swapaxes(P_pred, -1, -2))


def kalman_gain(P: np.ndarray, H: np.ndarray, R: np.ndarray, S: np.ndarray | None = None):
    """Gain ``K = P Hᵀ S⁻¹`` and innovation covariance ``S = H P Hᵀ + R``.

    ``S`` is symmetric, so ``Kᵀ = S⁻¹ (H P)`` comes from one batched solve (no inverse). A
    caller that already has ``S`` (a multi-target tracker gates with it) passes it; for a
    two-component measurement the solve is then written out with the 2 × 2 inverse, which for
    thousands of tracks costs less than a batched solve's per-matrix calls (equal to rounding;
    tests/test_multitarget_trackers.py).
    """
    HP = H @ P
    if S is None:
        S = HP @ np.swapaxes(H, -1, -2) + R
    elif S.shape[-1] == 2:
        a, b, d = S[..., 0, 0], 0.5 * (S[..., 0, 1] + S[..., 1, 0]), S[..., 1, 1]
        det = a * d - b * b
        # Kᵀ = S⁻¹ (H P), row by row: S⁻¹ = [[d, −b], [−b, a]] / det
        K = np.empty(HP.shape[:-2] + (HP.shape[-1], 2))
        K[..., 0] = (d[..., None] * HP[..., 0, :] - b[..., None] * HP[..., 1, :]) / det[..., None]
        K[..., 1] = (a[..., None] * HP[..., 1, :] - b[..., None] * HP[..., 0, :]) / det[..., None]
        return K, S
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
    return x_post, joseph_covariance(P, K, H, R)


def joseph_covariance(P: np.ndarray, K: np.ndarray, H: np.ndarray, R: np.ndarray):
    """Posterior covariance ``(I − KH) P (I − KH)ᵀ + K R Kᵀ`` of an update with gain ``K``
    (symmetric positive semi-definite for any gain, and for a singular or zero ``R``).

    Stacks of thousands of matrices cost less through its fast form,
    :func:`~trackreplay.cores.filters._kalman_fast.joseph_covariance_fast` (two contractions)."""
    A = np.eye(P.shape[-1]) - K @ H
    P_post = A @ P @ np.swapaxes(A, -1, -2) + K @ R @ np.swapaxes(K, -1, -2)
    return 0.5 * (P_post + np.swapaxes(P_post, -1, -2))


def gaussian_log_likelihood(innovation: np.ndarray, S: np.ndarray, return_parts: bool = False):
    """``log N(ν; 0, S)`` per batch element, through a Cholesky factor of ``S``.

    Parameters
    ----------
    innovation : ndarray (..., m)
    S : ndarray (..., m, m)
        Innovation covariance, symmetric positive definite.
    return_parts : bool
        Also return the two terms the factor gives, so that callers needing the NIS or
        ``log|S|`` do not factorise ``S`` a second time.

    Returns
    -------
    log_likelihood : ndarray (...)
    nis : ndarray (...)
        ``νᵀ S⁻¹ ν`` (only with ``return_parts``).
    log_det : ndarray (...)
        ``log|S|`` (only with ``return_parts``).
    """
    L = np.linalg.cholesky(S)
    w = np.linalg.solve(L, innovation[..., None])[..., 0]
    m = innovation.shape[-1]
    logdet = 2.0 * np.sum(np.log(np.diagonal(L, axis1=-2, axis2=-1)), axis=-1)
    nis = np.sum(w * w, axis=-1)
    ll = -0.5 * (nis + logdet + m * np.log(2.0 * np.pi))
    return (ll, nis, logdet) if return_parts else ll


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
    g = piecewise_white_noise_gain(dt, 2)  # (..., 2): [dt²/2, dt]
    q1 = sigma_v**2 * g[..., :, None] * g[..., None, :]  # (..., 2, 2) per-axis block
    Q = np.einsum("...ab,ij->...aibj", q1, I).reshape(*dt.shape, 2 * axes, 2 * axes)
    return F, Q


def kinematic_transition(T: float, order: int) -> np.ndarray:
    """Transition ``Φ(T)`` of one axis of an ``order``-state kinematic chain ``[p, ṗ, p̈, …]``.

    ``Φ_ij = T^(j−i) / (j−i)!`` for ``j ≥ i``. It is a group in T, so the exact inverse is
    ``Φ(T)⁻¹ = Φ(−T)``: callers that need the inverse evaluate ``kinematic_transition(-T, order)``
    instead of inverting.

    Parameters
    ----------
    T : float
        Sample period (s); negative for the inverse.
    order : int
        Number of states per axis (2: constant velocity, 3: constant acceleration).

    Returns
    -------
    ndarray (order, order)
    """
    F = np.eye(order)
    for k in range(1, order):
        F += np.eye(order, k=k) * (T**k / factorial(k))
    return F


def piecewise_white_noise_gain(T: float | np.ndarray, order: int) -> np.ndarray:
    """Gain ``Ψ = [T^n/n!, …, T²/2, T]`` of a white noise on the highest derivative held constant
    over each sample (the *piecewise-constant* white-noise model, ``Q = q Ψ Ψᵀ``).

    ``order = 2``: white acceleration on ``[p, v]`` (what :func:`white_acceleration_model` uses
    per axis); ``order = 3``: white jerk on ``[p, v, a]``.

    Parameters
    ----------
    T : float or ndarray
        Sample period (s); an array gives a batch.
    order : int
        Number of states per axis.

    Returns
    -------
    ndarray (..., order)
    """
    T = np.asarray(T, dtype=float)
    return np.stack([T**k / factorial(k) for k in range(order, 0, -1)], axis=-1)


def continuous_white_noise_model(T: float, q: float, order: int = 2):
    """One axis of a kinematic chain driven by *continuous-time* white noise of spectral density q
    on its highest derivative (not the piecewise-constant model of :func:`white_acceleration_model`,
    whose ``Q = q Ψ Ψᵀ`` is rank one).

    ``Q = q ∫₀ᵀ Φ(s) e eᵀ Φ(s)ᵀ ds``, i.e. ``Q_ij = q T^(2n−1−i−j) / ((n−1−i)! (n−1−j)! (2n−1−i−j))``;
    for ``order = 2``: ``Q = q [[T³/3, T²/2], [T²/2, T]]``.

    Parameters
    ----------
    T : float
        Sample period (s).
    q : float
        Spectral density (units of the highest derivative² per second).
    order : int
        Number of states per axis.

    Returns
    -------
    F, Q : ndarray (order, order)
    """
    n = order
    M = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            p = 2 * n - 1 - i - j
            M[i, j] = T**p / (factorial(n - 1 - i) * factorial(n - 1 - j) * p)
    return kinematic_transition(T, order), q * M


def two_point_start(z0: np.ndarray, z1: np.ndarray, dt: float, sigma_p: np.ndarray):
    """Two-point track start ``[z₁, (z₁ − z₀)/T]`` from two position measurements one sample apart.

    With independent measurement errors of variance σ²:
    ``P(0|0) = [[σ², σ²/T], [σ²/T, 2σ²/T²]]``.

    Parameters
    ----------
    z0, z1 : ndarray (...)
        Measurements at the previous and the current sample.
    dt : float
        Sample period T (s).
    sigma_p : float or ndarray (...)
        Measurement standard deviation σ.

    Returns
    -------
    x : ndarray (..., 2)
    P : ndarray (..., 2, 2)
    """
    x = np.stack([z1, (z1 - z0) / dt], axis=-1)
    s2 = np.broadcast_to(np.asarray(sigma_p, float) ** 2, x.shape[:-1])
    P = np.stack([np.stack([s2, s2 / dt], -1), np.stack([s2 / dt, 2 * s2 / dt**2], -1)], -2)
    return x, P


# --------------------------------------------------------------------------- CV kernel
# The same filter, specialised to what every TWS tracker here runs: the 2-D constant-velocity
# model with position measurements. With P = [[A, B], [Bᵀ, C]] in 2×2 (position, velocity)
# blocks, F = [[I, dt·I], [0, I]] and H = [I, 0], every product reduces to a handful of
# element-wise operations on the ten distinct covariance entries. They are stored runs-last,
# ``(10, runs)``, so each operation is one contiguous vector operation over all Monte Carlo
# runs: ~20× cheaper than batched 4×4 matrix products for a few hundred runs.
# tests/test_kalman.py checks the kernel against the generic functions above to rounding error.

A00, A01, A11, B00, B01, B10, B11, C00, C01, C11 = range(10)


def matrix_to_components(P):
    """(runs, 4, 4) covariance in state order [x, y, ẋ, ẏ] → (10, runs) components."""
    return np.stack([P[:, 0, 0], P[:, 0, 1], P[:, 1, 1], P[:, 0, 2], P[:, 0, 3], P[:, 1, 2],
                     P[:, 1, 3], P[:, 2, 2], P[:, 2, 3], P[:, 3, 3]])


def components_to_matrix(c):
    """(10, …) components → (…, 4, 4) symmetric covariance."""
    c = np.asarray(c)
    # one gather pass writing the output in order (writing each entry into a preallocated
    # (…, 4, 4) array strides through all of it 16 times: 6× slower at 640,000 matrices)
    return np.moveaxis(c, 0, -1)[..., MATRIX_FROM_COMPONENTS].reshape(c.shape[1:] + (4, 4))


#: The component index of each of the 16 entries of the 4×4 matrix, row by row, in state order
#: [x, y, ẋ, ẏ].
MATRIX_FROM_COMPONENTS = np.array([A00, A01, B00, B01,
                                    A01, A11, B10, B11,
                                    B00, B10, C00, C01,
                                    B01, B11, C01, C11])
#: Where each of the ten components sits among the 16 entries of the matrix, row by row (its
#: first, upper-triangle entry): the components of a ``(16, ...)`` stack of matrix entries.
ENTRY_OF_COMPONENT = tuple(int(np.flatnonzero(MATRIX_FROM_COMPONENTS == k)[0]) for k in range(10))
_IDENTITY_ORDER = tuple(range(10))


def _component_rows(c):
    """How to read the ten components from ``c``: the identity for a ``(10, ...)`` component
    stack, :data:`ENTRY_OF_COMPONENT` for a ``(16, ...)`` stack of row-major matrix entries."""
    if len(c) == 16:
        return ENTRY_OF_COMPONENT
    if len(c) == 10:
        return _IDENTITY_ORDER
    raise ValueError(f"expected 10 covariance components or 16 matrix entries on the first axis, got {len(c)}")


def cv_predict_components(x, c, dt: float, sigma_v: float):
    """Time update of state ``(4, runs)`` and covariance components ``(10, runs)``.

    ``A' = A + dt(B + Bᵀ) + dt² C + q₄ I``, ``B' = B + dt C + q₃ I``, ``C' = C + q₂ I`` with
    ``q₄ = σ_v² dt⁴/4``, ``q₃ = σ_v² dt³/2``, ``q₂ = σ_v² dt²`` (white-acceleration Q).
    """
    q = sigma_v * sigma_v
    return _cv_predict_terms(x, c, dt, q * dt**4 / 4, q * dt**3 / 2, q * dt * dt)


def _cv_predict_terms(x, c, dt, q4, q3, q2):
    """The time update's terms, for a scalar ``dt`` (one scan) or a ``(L, 1)`` column of them
    (many scans at once, :func:`_cv_predict_components_scans`): one written form for both."""
    dt2 = dt * dt
    xp = np.empty_like(x)
    xp[:2] = x[:2] + dt * x[2:]
    xp[2:] = x[2:]
    n = np.empty_like(c)
    n[A00] = c[A00] + 2 * dt * c[B00] + dt2 * c[C00] + q4
    n[A01] = c[A01] + dt * (c[B01] + c[B10]) + dt2 * c[C01]
    n[A11] = c[A11] + 2 * dt * c[B11] + dt2 * c[C11] + q4
    n[B00] = c[B00] + dt * c[C00] + q3
    n[B01] = c[B01] + dt * c[C01]
    n[B10] = c[B10] + dt * c[C01]
    n[B11] = c[B11] + dt * c[C11] + q3
    n[C00] = c[C00] + q2
    n[C01] = c[C01]
    n[C11] = c[C11] + q2
    return xp, n


def cv_position_gain_components(c, r00, r01, r11):
    """Optimal gain of a position measurement with covariance ``[[r00, r01], [r01, r11]]``.

    ``S = A + R`` and ``K = [A; Bᵀ] S⁻¹``; for a 2×2 system Cramer's rule *is* the solve.
    S is bounded below by R, so it is well conditioned.

    Returns
    -------
    gain : ndarray (8, runs)
        ``K_pos`` (00, 01, 10, 11) then ``K_vel`` (00, 01, 10, 11).
    """
    s00, s01, s11 = c[A00] + r00, c[A01] + r01, c[A11] + r11
    inv_det = 1.0 / (s00 * s11 - s01 * s01)
    a00, a01, a11 = c[A00], c[A01], c[A11]
    b00, b01, b10, b11 = c[B00], c[B01], c[B10], c[B11]
    g = np.empty((8,) + s00.shape)
    g[0] = (a00 * s11 - a01 * s01) * inv_det
    g[1] = (a01 * s00 - a00 * s01) * inv_det
    g[2] = (a01 * s11 - a11 * s01) * inv_det
    g[3] = (a11 * s00 - a01 * s01) * inv_det
    g[4] = (b00 * s11 - b10 * s01) * inv_det
    g[5] = (b10 * s00 - b00 * s01) * inv_det
    g[6] = (b01 * s11 - b11 * s01) * inv_det
    g[7] = (b11 * s00 - b01 * s01) * inv_det
    return g


def cv_apply_gain_components(x, gain, innovation):
    """``x + K ν`` for state ``(4, runs)``, gain ``(8, runs)``, innovation ``(2, runs)``."""
    n0, n1 = innovation
    out = np.empty_like(x)
    out[0] = x[0] + gain[0] * n0 + gain[1] * n1
    out[1] = x[1] + gain[2] * n0 + gain[3] * n1
    out[2] = x[2] + gain[4] * n0 + gain[5] * n1
    out[3] = x[3] + gain[6] * n0 + gain[7] * n1
    return out


def cv_posterior_components(c, gain):
    """Covariance after an optimal update: ``P⁺ = P − K H P`` (A − K_pos A, B − K_pos B, C − K_vel B).

    The textbook form: where ``R`` is much smaller than ``A`` in some direction, ``A − K_pos A``
    subtracts nearly equal numbers and can lose definiteness; the filters use
    :func:`cv_position_update_components`, which computes the same covariance without it.
    """
    k00, k01, k10, k11, g00, g01, g10, g11 = gain
    n = np.empty_like(c)
    n[A00] = c[A00] - (k00 * c[A00] + k01 * c[A01])
    n[A01] = c[A01] - (k00 * c[A01] + k01 * c[A11])
    n[A11] = c[A11] - (k10 * c[A01] + k11 * c[A11])
    n[B00] = c[B00] - (k00 * c[B00] + k01 * c[B10])
    n[B01] = c[B01] - (k00 * c[B01] + k01 * c[B11])
    n[B10] = c[B10] - (k10 * c[B00] + k11 * c[B10])
    n[B11] = c[B11] - (k10 * c[B01] + k11 * c[B11])
    n[C00] = c[C00] - (g00 * c[B00] + g01 * c[B10])
    n[C01] = c[C01] - (g00 * c[B01] + g01 * c[B11])
    n[C11] = c[C11] - (g10 * c[B01] + g11 * c[B11])
    return n


def cv_position_update_components(c, r00, r01, r11):
    """Optimal gain and posterior covariance of a position measurement, in one pass.

    The gain is :func:`cv_position_gain_components`'s. The covariance is ``P⁺ = P − K H P`` written
    with ``M = I − K_pos = R S⁻¹`` formed from ``R`` directly::

        A⁺ = M A,   B⁺ = M B,   C⁺ = C − K_vel B

    ``A − K_pos A`` cancels where the measurement is much more precise than the prediction in
    some direction (``K_pos`` → I there); with ``M = R S⁻¹`` the position block keeps its small
    eigenvalue (≈ that of ``R``) to a relative error of about ε·cond(R), whatever the ratio of
    ``R`` to ``A``. The velocity block keeps the textbook form: its cancellation is of relative
    size ≈ 2/λ (λ the tracking index), harmless in the range the trackers allow.

    Returns
    -------
    gain : ndarray (8, runs)
        As :func:`cv_position_gain_components`.
    c_post : ndarray (10, runs)
        Posterior covariance components.

    Its fast form, :func:`~trackreplay.cores.filters._kalman_fast.cv_position_update_components_fast`,
    takes batches of up to a few thousand runs as a dozen calls on stacked rows instead of ninety on
    single rows: the same numbers to the bit (tests/test_kalman.py).
    """
    g = cv_position_gain_components(c, r00, r01, r11)
    a00, a01, a11 = c[A00], c[A01], c[A11]
    b00, b01, b10, b11 = c[B00], c[B01], c[B10], c[B11]
    s00, s01, s11 = a00 + r00, a01 + r01, a11 + r11
    inv_det = 1.0 / (s00 * s11 - s01 * s01)
    m00 = (r00 * s11 - r01 * s01) * inv_det
    m01 = (r01 * s00 - r00 * s01) * inv_det
    m10 = (r01 * s11 - r11 * s01) * inv_det
    m11 = (r11 * s00 - r01 * s01) * inv_det
    n = np.empty_like(c)
    n[A00] = m00 * a00 + m01 * a01
    n[A01] = m00 * a01 + m01 * a11
    n[A11] = m10 * a01 + m11 * a11
    n[B00] = m00 * b00 + m01 * b10
    n[B01] = m00 * b01 + m01 * b11
    n[B10] = m10 * b00 + m11 * b10
    n[B11] = m10 * b01 + m11 * b11
    n[C00] = c[C00] - (g[4] * b00 + g[5] * b10)
    n[C01] = c[C01] - (g[4] * b01 + g[5] * b11)
    n[C11] = c[C11] - (g[6] * b01 + g[7] * b11)
    return g, n


#: Relative pivot ``d_i / P_ii`` below which :func:`cv_floor_components` repairs a covariance.
#: Rounding in a 4×4 Cholesky factorisation perturbs the relative pivots by a few ε ≈ 10⁻¹⁵, so
#: at 10⁻¹² it succeeds with a margin of ~10³. The radar filters reach it only in extreme cases
#: (a track started from a plot micrometres from the radar, fixed gains designed for a nominal
#: error far from the plot's, clamped approximate gains coasting).
PIVOT_FLOOR = 1e-12
#: Smallest eigenvalue, relative to the largest, of the correlation matrix of a repaired covariance.
REPAIR_FLOOR = 1e-9


#: Covariances per block of :func:`cv_relative_pivots`: its two dozen temporaries stay in cache.
PIVOT_BLOCK = 16384


def cv_relative_pivots(c):
    """Smallest LDLᵀ pivot of each covariance ``(10, ...)`` (or its 16 matrix entries, row by
    row, ``(16, ...)``), relative to its diagonal entry.

    ``min_i d_i / P_ii`` in state order [x, y, ẋ, ẏ]; it is at most the smallest eigenvalue of the
    correlation matrix, so a value well above rounding (≳ 10⁻¹⁴) means Cholesky succeeds. NaN
    where an entry is NaN or a pivot is not positive. A stack of more than
    :data:`PIVOT_BLOCK` covariances is taken in blocks along its first axis (every step is
    elementwise, so the result is the same); at 640,000 covariances that is several times faster
    than allocating each temporary at full size.
    """
    c = np.asarray(c)
    if c.ndim < 2 or c[0].size <= PIVOT_BLOCK:
        return _relative_pivots(c)
    per_row = max(1, c[0, 0].size)
    step = max(1, PIVOT_BLOCK // per_row)
    out = np.empty(c.shape[1:])
    for first in range(0, c.shape[1], step):
        out[first:first + step] = _relative_pivots(c[:, first:first + step])
    return out


def _relative_pivots(c):
    """:func:`cv_relative_pivots` of one block."""
    at = _component_rows(c)
    p00, p10, p11 = c[at[A00]], c[at[A01]], c[at[A11]]
    p20, p21, p22 = c[at[B00]], c[at[B10]], c[at[C00]]
    p30, p31, p32, p33 = c[at[B01]], c[at[B11]], c[at[C01]], c[at[C11]]
    with np.errstate(divide="ignore", invalid="ignore"):
        l10 = p10 / p00
        d1 = p11 - l10 * p10
        l20 = p20 / p00
        e21 = p21 - l20 * p10            # d1 · l21
        d2 = p22 - l20 * p20 - e21 * e21 / d1
        l30 = p30 / p00
        e31 = p31 - l30 * p10            # d1 · l31
        e32 = p32 - l30 * p20 - e31 * e21 / d1   # d2 · l32
        d3 = p33 - l30 * p30 - e31 * e31 / d1 - e32 * e32 / d2
        worst = np.minimum(np.minimum(np.sign(p00), d1 / np.abs(p11)), np.minimum(d2 / np.abs(p22), d3 / np.abs(p33)))
    return np.where(worst > 0, worst, np.nan)


def cv_floor_components(c, live, floor: float = PIVOT_FLOOR, repair: float = REPAIR_FLOOR):
    """Repair covariances ``(10, ...)`` (or their matrix entries ``(16, ...)``, see
    :func:`cv_relative_pivots`) that are not safely positive definite.

    Where ``live`` (shape ``...``) and :func:`cv_relative_pivots` is below ``floor`` (or not a
    number), the correlation matrix's eigenvalues are raised to ``repair`` times its largest and
    the covariance rebuilt with the same variances (an eigen-decomposition, of those only). A
    covariance with a non-finite entry is left as it is.

    Returns
    -------
    c : ndarray (10, ...)
        ``c`` itself when nothing needed repair, else a repaired copy.
    floored : ndarray of bool (...)
        True where the covariance was repaired; callers flag those ``FLOORED``.
    """
    pivots = cv_relative_pivots(c)
    floored = live & ~(pivots >= floor)
    if not floored.any():
        return c, floored
    where = np.nonzero(floored)
    entries = len(c) == 16
    P = np.moveaxis(c[(slice(None),) + where], 0, -1).reshape(-1, 4, 4) if entries else \
        components_to_matrix(c[(slice(None),) + where])
    ok = np.isfinite(P).all(axis=(-2, -1))
    floored[where] = ok
    where, P = tuple(w[ok] for w in where), P[ok]
    if not P.size:
        return c, floored
    d = np.sqrt(np.maximum(np.abs(np.diagonal(P, axis1=-2, axis2=-1)), np.finfo(float).tiny))
    corr = P / (d[:, :, None] * d[:, None, :])
    w, V = np.linalg.eigh(0.5 * (corr + np.swapaxes(corr, -1, -2)))
    w = np.maximum(w, repair * w[:, -1:])
    corr = (V * w[:, None, :]) @ np.swapaxes(V, -1, -2)
    P = corr * (d[:, :, None] * d[:, None, :])
    P = 0.5 * (P + np.swapaxes(P, -1, -2))
    out = c.copy()
    out[(slice(None),) + where] = np.moveaxis(P.reshape(-1, 16), -1, 0) if entries else matrix_to_components(P)
    return out, floored


# --------------------------------------------------------------------------- stacks, runs last


def stacked_kf_step(F, Q, fill_mean, x, P, y, H, R_meas):
    """The Kalman filter on a stack of models with the runs on the last axis (Kwon 1997, eqs.
    4.1.1–4.1.5, 4.3.5–4.3.10): the IMM's model-matched step (:mod:`trackreplay.cores.filters.imm`).

    ``F`` (G, N, N) and ``Q`` (G, N, N, 1) are the models' transition and process noise,
    ``fill_mean`` (G, N, 1) or None a constant added to the prediction (see the IMM's fill).

    ``x`` (G, N, runs), ``P`` (G, N, N, runs), ``y`` (m, runs), ``H`` (G, m, N, 1 or runs),
    ``R_meas`` (m, m, 1 or runs). The update is written through the whitened gain: with
    ``S = L Lᵀ``, ``W = L⁻¹ H P⁻`` and ``e = L⁻¹ ν``, ``x = x⁻ + Wᵀ e``, ``P = P⁻ − Wᵀ W``
    (``= P⁻ − K S Kᵀ``, exactly symmetric), ``νᵀ S⁻¹ ν = ‖e‖²`` and ``log|S| = 2 Σ log L_ii``:
    one factorisation gives the gain, the NIS and the likelihood.

    Returns
    -------
    x, P, log Λ (G, runs), NIS (G, runs), ν (G, m, runs), S (G, m, m, runs)
    """
    G, N, R = x.shape
    m = y.shape[0]
    xp = np.matmul(F, x)                                   # one (N × N)(N × runs) product per model
    if fill_mean is not None:
        xp += fill_mean
    # Φ P Φᵀ as two products over the stacked runs: (Φ P) then Φ (Φ P)ᵀ
    FP = np.matmul(F, P.reshape(G, N, N * R)).reshape(G, N, N, R)
    Pp = np.matmul(F, FP.transpose(0, 2, 1, 3).reshape(G, N, N * R)).reshape(G, N, N, R)
    Pp += Q
    Pp += Pp.transpose(0, 2, 1, 3)                            # numpy buffers the overlapping operand
    Pp *= 0.5
    HP = _sum(H[:, :, :, None, :] * Pp[:, None], 2)       # (G, m, N, runs)
    S = _sum(HP[:, :, None] * H[:, None], 3) + R_meas      # (G, m, m, runs)
    nu = y - _sum(H * xp[:, None], 2)                      # (G, m, runs)
    if m == 1:
        d = np.sqrt(S[:, 0, 0])                                 # (G, runs)
        W = HP[:, 0] / d[:, None]
        e = nu[:, 0] / d
        x_post = xp + W * e[:, None]
        P_post = Pp - W[:, :, None] * W[:, None]
        nis = e * e
        log_det = np.log(S[:, 0, 0])
    elif m == 2:
        x_post, P_post, nis, log_det = _whitened_update_2(S, HP, nu, xp, Pp)
    else:
        x_post, P_post, nis, log_det = _whitened_update(S, HP, nu, xp, Pp)
    ll = -0.5 * (nis + log_det + m * LOG_2PI)
    return x_post, P_post, ll, nis, nu, S



def _whitened_update(S, HP, nu, xp, Pp):
    """:func:`stacked_kf_step`'s update through the whitened gain, any measurement size:
    ``L = chol(S)``, ``[W | e] = L⁻¹ [H P⁻ | ν]``, ``x = x⁻ + Wᵀ e``, ``P = P⁻ − Wᵀ W``,
    NIS ``‖e‖²`` and ``log|S| = 2 Σ log L_ii``.

    Returns
    -------
    x, P, NIS (G, runs), log|S| (G, runs)
    """
    N = xp.shape[1]
    L = cholesky_lower(S)
    We = forward_substitute(L, np.concatenate([HP, nu[:, :, None]], axis=2))
    W, e = We[:, :, :N], We[:, :, N]
    x_post = xp + _sum(W * e[:, :, None], 1)
    P_post = Pp - _sum(W[:, :, :, None] * W[:, :, None], 1)
    nis = _sum(e * e, 1)
    log_det = 2.0 * _sum(np.log(np.diagonal(L, axis1=1, axis2=2)), -1)
    return x_post, P_post, nis, log_det


def _whitened_update_2(S, HP, nu, xp, Pp):
    """:func:`stacked_kf_step`'s whitened update for a two-component measurement, written out.

    The same operations, in the same order, as :func:`_whitened_update` (``cholesky_lower``,
    then ``forward_substitute`` on ``[H P⁻ | ν]``, then the sums over the two rows), so the bits
    are the same (tests/test_kalman.py checks it); it skips the loops, the concatenation and the
    one-element sums, which at a few runs cost more than the arithmetic. With
    ``S = L Lᵀ``: ``L₀₀ = √S₀₀``, ``L₁₀ = S₁₀ / L₀₀``, ``L₁₁ = √(S₁₁ − L₁₀²)``; row 0 of
    ``W, e`` is row 0 of ``[H P⁻ | ν]`` over ``L₀₀``, row 1 is (row 1 − ``L₁₀`` row 0) over ``L₁₁``.

    Returns
    -------
    x, P, NIS (G, runs), log|S| (G, runs)
    """
    d0 = np.sqrt(S[:, 0, 0])
    l10 = S[:, 1, 0] / d0
    d1 = np.sqrt(S[:, 1, 1] - l10 * l10)
    W0 = HP[:, 0] / d0[:, None]
    e0 = nu[:, 0] / d0
    W1 = (HP[:, 1] - l10[:, None] * W0) / d1[:, None]
    e1 = (nu[:, 1] - l10 * e0) / d1
    x_post = xp + (W0 * e0[:, None] + W1 * e1[:, None])
    P_post = Pp - (W0[:, :, None] * W0[:, None] + W1[:, :, None] * W1[:, None])
    nis = e0 * e0 + e1 * e1
    log_det = 2.0 * (np.log(d0) + np.log(d1))
    return x_post, P_post, nis, log_det
