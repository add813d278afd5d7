"""The square-root information filter (SRIF; Bierman 1977, as in Kwon 1997 ch. IV.2).

Kwon (1997), ch. IV.2–IV.3, the square-root information filter (thesis eqs. 4.2.3–4.2.4,
4.2.18–4.2.22, 4.3.5–4.3.13); see ``docs/papers/colored.md``. The filter carries ``(R, z)`` with
``P⁻¹ = Rᵀ R`` and ``x = R⁻¹ z``. With ``Q⁻¹ = R_wᵀ R_w`` and ``R⁻¹ = R_νᵀ R_ν``:

* time update (4.2.18 / 4.3.5): an orthogonal triangularisation (Householder QR) of
  ``[[R_w, 0, R_w w̄], [−R Φ⁻¹ Ψ, R Φ⁻¹, z]]`` leaves ``[0, R_{k|k−1}, z_{k|k−1}]`` in its
  last n rows; ``R Φ⁻¹`` comes from a solve with ``Φᵀ`` (Φ⁻¹ is never formed);
* measurement update (4.2.21 / 4.3.9): triangularising ``[[R_{k|k−1}, z_{k|k−1}],
  [R_ν Ĥ, R_ν y_k]]`` gives ``[[R_{k|k}, z_{k|k}], [0, e_k]]``;
* likelihood (4.3.11–4.3.13): ``eᵀe`` is the innovation's normalised square and, by the
  matrix determinant lemma, ``|S_k| = (|R_{k|k}| / (|R_{k|k−1}| |R_ν|))²``. The thesis prints
  eq. 4.3.12 without the square, which is ``√|S|``; the tests check the squared form against
  the Kalman filter's ``S``.

The recursion has two forms in this one module: :func:`srif_predict_update` (time update and
measurement update as two QRs, the runs first; :func:`srif_filter` carries ``(R, z)`` through a
record with it) and :func:`stacked_srif_step` (both updates as one Householder triangularisation,
every model and run at once with the runs last, entry by entry: what the IMM's SRIF models
(:mod:`trackreplay.cores.filters.imm`) run from their mixed moments). The tests check they agree.

No covariance is formed and no matrix is inverted inside the recursion: symmetry and positive
definiteness of ``P = R⁻¹ R⁻ᵀ`` hold by construction, which is what keeps the SRIF usable in
single precision or with a huge initial covariance and a tiny R, where the Kalman filter's
covariance goes indefinite (tests/test_colored_srif.py shows both).

Every function works on stacks: leading axes are Monte Carlo runs (numpy's ``linalg.qr`` and
``solve`` are batched), so a whole study advances one scan per call. Triangular factors are
returned with a non-negative diagonal (rows of ``[R | z]`` flipped as needed), which makes
them unique and comparable (``R_{k|k}`` is then the transposed Cholesky factor of ``P⁻¹``).
Arrays keep the caller's floating-point type.
"""

from __future__ import annotations

import numpy as np

from trackreplay.batched_linalg import back_substitute, cholesky_lower, forward_substitute, householder_triangularise
from trackreplay.cores.filters.decorrelation import transition_inverse_check
from trackreplay.errors import InputError

LOG_2PI = float(np.log(2.0 * np.pi))


def _eye(n: int, like: np.ndarray) -> np.ndarray:
    return np.eye(n, dtype=like.dtype)


def _positive_diagonal(R: np.ndarray, z: np.ndarray):
    """Flip rows of ``[R | z]`` so that ``diag(R) ≥ 0`` (an orthogonal change, nothing else)."""
    s = np.where(np.diagonal(R, axis1=-2, axis2=-1) < 0, -1.0, 1.0).astype(R.dtype)
    return R * s[..., :, None], z * s


def information_factor(C, name: str = "covariance") -> np.ndarray:
    """Square-root information factor ``F`` of a covariance: ``Fᵀ F = C⁻¹``.

    ``F = L⁻¹`` with ``C = L Lᵀ`` (lower triangular, so ``F`` is lower triangular too), from a
    Cholesky factorisation and a triangular solve.

    Parameters
    ----------
    C : array_like (..., m, m)
        Symmetric positive definite.
    name : str
        What ``C`` is, for the error message.

    Raises
    ------
    InputError
        If ``C`` is not positive definite (or not finite).
    """
    C = np.asarray(C)
    if not np.all(np.isfinite(C)):
        raise InputError(f"{name} holds NaN/Inf")
    try:
        L = np.linalg.cholesky(C)
    except np.linalg.LinAlgError:
        raise InputError(f"{name} is not positive definite") from None
    return np.linalg.solve(L, np.broadcast_to(_eye(C.shape[-1], L), L.shape))


def srif_from_moments(x: np.ndarray, P: np.ndarray):
    """``(R, z)`` of a Gaussian ``N(x, P)``: ``R = L⁻¹`` (``P = L Lᵀ``), ``z = R x`` (one solve)."""
    n = x.shape[-1]
    L = np.linalg.cholesky(P)
    rhs = np.concatenate([np.broadcast_to(_eye(n, L), L.shape), x[..., None]], axis=-1)
    sol = np.linalg.solve(L, rhs)
    return sol[..., :n], sol[..., n]


def srif_moments(R: np.ndarray, z: np.ndarray):
    """``x = R⁻¹ z`` and ``P = R⁻¹ R⁻ᵀ`` (4.2.7, 4.2.22) from one solve with ``[I | z]``."""
    n = z.shape[-1]
    rhs = np.concatenate([np.broadcast_to(_eye(n, R), R.shape), z[..., None]], axis=-1)
    sol = np.linalg.solve(R, rhs)
    S = sol[..., :n]
    return sol[..., n], S @ np.swapaxes(S, -1, -2)


def times_transition_inverse(R: np.ndarray, Phi: np.ndarray) -> np.ndarray:
    """``R Φ⁻¹`` as ``(Φ⁻ᵀ Rᵀ)ᵀ``: a solve with ``Φᵀ``, no inverse.

    ``R`` is ``(..., *B, n, n)`` for ``Φ`` of shape ``(*B, n, n)`` (``B`` empty for a shared Φ,
    the model axis for an IMM group): the rows of every leading index are stacked into one
    right-hand side, so each Φ is factorised once per call rather than once per run. Other
    shapes fall back to a broadcast solve.
    """
    n = Phi.shape[-1]
    k = Phi.ndim - 2
    B = Phi.shape[:-2]
    PhiT = np.swapaxes(Phi, -1, -2)
    if R.shape[R.ndim - 2 - k:-2] != B:
        return np.swapaxes(np.linalg.solve(PhiT, np.swapaxes(R, -1, -2)), -1, -2)
    rows = np.moveaxis(R.reshape((-1,) + B + (n, n)), 0, k).reshape(B + (-1, n))  # (*B, L·n, n)
    X = np.swapaxes(np.linalg.solve(PhiT, np.swapaxes(rows, -1, -2)), -1, -2)
    return np.moveaxis(X.reshape(B + (-1, n, n)), k, 0).reshape(R.shape)


def srif_time_update(R: np.ndarray, z: np.ndarray, Phi: np.ndarray, Psi: np.ndarray,
                     Rw: np.ndarray, w_mean: np.ndarray | None = None):
    """SRIF time update (eq. 4.2.18 / 4.3.5) by one batched QR.

    Parameters
    ----------
    R : ndarray (..., n, n)
        Information square root at k−1 (any square root; need not be triangular).
    z : ndarray (..., n)
    Phi : ndarray (n, n) or (..., n, n)
        State transition Φ (non-singular; ``R Φ⁻¹`` is computed by a solve).
    Psi : ndarray (n, p) or (..., n, p)
        Process-noise gain Ψ.
    Rw : ndarray (p, p)
        Information square root of the process noise, ``Q⁻¹ = R_wᵀ R_w``.
    w_mean : ndarray (p,), optional
        Process-noise mean ``w̄`` (zero by default).

    Returns
    -------
    R_pred : ndarray (..., n, n)
        Upper triangular, non-negative diagonal.
    z_pred : ndarray (..., n)
    """
    n = R.shape[-1]
    p = Rw.shape[-1]
    batch = R.shape[:-2]
    R_Phi_inv = times_transition_inverse(R, Phi)
    M = np.zeros(batch + (p + n, p + n + 1), dtype=R.dtype)
    M[..., :p, :p] = Rw
    if w_mean is not None:
        M[..., :p, -1] = Rw @ w_mean
    M[..., p:, :p] = -(R_Phi_inv @ Psi)
    M[..., p:, p:p + n] = R_Phi_inv
    M[..., p:, -1] = z
    T = np.linalg.qr(M, mode="r")
    return _positive_diagonal(T[..., p:, p:p + n], T[..., p:, -1])


def srif_measurement_update(R: np.ndarray, z: np.ndarray, H: np.ndarray, y: np.ndarray,
                            Rv: np.ndarray):
    """SRIF measurement update (eq. 4.2.21 / 4.3.9) and the likelihood terms (4.3.11–4.3.13).

    Parameters
    ----------
    R : ndarray (..., n, n)
        Predicted information square root, triangular (as :func:`srif_time_update` returns).
    z : ndarray (..., n)
    H : ndarray (m, n) or (..., m, n)
        Measurement matrix (``Ĥ`` for decorrelated measurements).
    y : ndarray (..., m)
    Rv : ndarray (m, m) or (..., m, m)
        Triangular information square root of the measurement noise (:func:`information_factor`).

    Returns
    -------
    R_post : ndarray (..., n, n)
        Upper triangular, non-negative diagonal.
    z_post : ndarray (..., n)
    residual_norm : ndarray (...)
        ``‖e_k‖`` (``‖e‖² = νᵀ S⁻¹ ν``; QR fixes e only up to an orthogonal change, so its norm
        is what it determines).
    log_likelihood : ndarray (...)
        ``log N(ν; 0, S) = −½ (‖e‖² + log|S| + m log 2π)`` with
        ``log|S| = 2 (log|R_{k|k}| − log|R_{k|k−1}| − log|R_ν|)``.
    """
    n = R.shape[-1]
    m = y.shape[-1]
    batch = np.broadcast_shapes(R.shape[:-2], y.shape[:-1])
    M = np.zeros(batch + (n + m, n + 1), dtype=R.dtype)
    M[..., :n, :n] = R
    M[..., :n, n] = z
    M[..., n:, :n] = Rv @ H
    M[..., n:, n] = np.einsum("...ij,...j->...i", Rv, y)
    T = np.linalg.qr(M, mode="r")
    R_post, z_post = _positive_diagonal(T[..., :n, :n], T[..., :n, n])
    residual = np.abs(T[..., n, n])

    def logdet(A):
        return np.sum(np.log(np.abs(np.diagonal(A, axis1=-2, axis2=-1))), axis=-1)

    log_det_S = 2.0 * (logdet(R_post) - logdet(R) - logdet(Rv))
    log_likelihood = -0.5 * (residual * residual + log_det_S + m * LOG_2PI)
    return R_post, z_post, residual, log_likelihood


def srif_predict_update(R: np.ndarray, z: np.ndarray, Phi: np.ndarray, Psi: np.ndarray, Rw: np.ndarray,
                        H: np.ndarray, y: np.ndarray, Rv: np.ndarray, w_mean: np.ndarray | None = None):
    """One scan of the SRIF recursion: :func:`srif_time_update` then :func:`srif_measurement_update`.

    Parameters
    ----------
    R, z : ndarray (..., n, n), (..., n)
        Information square root and vector at k−1.
    Phi, Psi, Rw, w_mean
        As in :func:`srif_time_update`.
    H, y, Rv
        As in :func:`srif_measurement_update`.

    Returns
    -------
    R_post, z_post, residual_norm, log_likelihood
        As :func:`srif_measurement_update` returns them.
    """
    R, z = srif_time_update(R, z, Phi, Psi, Rw, w_mean)
    return srif_measurement_update(R, z, H, y, Rv)


def srif_filter(x0, P0, Phi, Psi, q, H, y, meas_cov, start: int = 1):
    """Run the SRIF over a whole record, every run at once (carries ``(R, z)`` throughout).

    A driver of :func:`srif_predict_update`: validates the model once, then one call per scan.

    Parameters
    ----------
    x0 : ndarray (runs, n)
    P0 : ndarray (runs, n, n) or (n, n)
    Phi : ndarray (n, n)
        Non-singular (an :class:`~trackreplay.errors.InputError` otherwise).
    Psi : ndarray (n, p)
    q : ndarray (p, p)
        Process-noise covariance (positive definite: the SRIF needs ``Q⁻¹``).
    H : ndarray (m, n) or (runs, scans, m, n)
    y : ndarray (runs, scans, m)
        Measurements (scans before ``start`` are not used).
    meas_cov : ndarray (m, m) or (runs, scans, m, m)
    start : int
        First scan with a measurement update (scan ``start − 1`` holds ``x0, P0``).

    Returns
    -------
    dict
        ``state`` (runs, scans, n), ``covariance`` (runs, scans, n, n), ``log_likelihood`` and
        ``residual_norm`` (runs, scans; NaN before ``start``), ``R`` (runs, scans, n, n)
        information square roots.
    """
    dtype = np.asarray(y).dtype if np.asarray(y).dtype.kind == "f" else np.float64
    y = np.asarray(y, dtype=dtype)
    runs, scans, m = y.shape
    transition_inverse_check(Phi, "Phi", "the SRIF time update")
    Phi = np.asarray(Phi, dtype=dtype)
    n = Phi.shape[0]
    Psi = np.asarray(Psi, dtype=dtype)
    Rw = information_factor(np.asarray(q, dtype=dtype), "process-noise covariance Q")
    H = np.asarray(H, dtype=dtype)
    meas_cov = np.asarray(meas_cov, dtype=dtype)
    Rv_all = information_factor(meas_cov, "measurement-noise covariance R")
    P0 = np.broadcast_to(np.asarray(P0, dtype=dtype), (runs, n, n))
    R, z = srif_from_moments(np.asarray(x0, dtype=dtype), P0)
    out = {"state": np.full((runs, scans, n), np.nan, dtype), "covariance": np.full((runs, scans, n, n), np.nan, dtype),
           "R": np.full((runs, scans, n, n), np.nan, dtype),
           "log_likelihood": np.full((runs, scans), np.nan, dtype), "residual_norm": np.full((runs, scans), np.nan, dtype)}
    first = max(start - 1, 0)
    out["state"][:, first], out["covariance"][:, first] = srif_moments(R, z)
    out["R"][:, first] = R
    for k in range(start, scans):
        Hk = H if H.ndim == 2 else H[:, k]
        Rv = Rv_all if Rv_all.ndim == 2 else Rv_all[:, k]
        R, z, e, ll = srif_predict_update(R, z, Phi, Psi, Rw, Hk, y[:, k], Rv)
        out["state"][:, k], out["covariance"][:, k] = srif_moments(R, z)
        out["R"][:, k] = R
        out["log_likelihood"][:, k] = ll
        out["residual_norm"][:, k] = e
    return out


_sum = np.add.reduce   # ndarray.sum's Python wrapper costs more than the sum of a few small arrays


def stacked_srif_step(st, x, P, y, H, Rv, log_det_Rv):
    """The SRIF recursion on a stack of models with the runs on the last axis, from the mixed
    moments (Kwon 1997, 4.3.5–4.3.13 from 4.3.6–4.3.7): the IMM's model-matched SRIF step. It
    is :func:`srif_predict_update` with the two QRs done as one triangularisation (below); the
    tests check the two agree. ``st`` carries the stack's constants as the IMM lays them out
    (``p``, ``Rw``, ``C`` = ``[−Φ⁻¹Ψ | Φ⁻¹]``, the masks of a decoupled component, ``fill_*``,
    ``log_det_Phi_over_Rw``; :class:`trackreplay.cores.filters.imm.ModelFilter`).

    From ``P = L Lᵀ`` the information square root is ``R = L⁻¹`` and ``z = L⁻¹ x``, so the time
    update's rows ``[−R Φ⁻¹ Ψ, R Φ⁻¹, z]`` are one forward substitution with ``L`` on the
    constant ``[−Φ⁻¹Ψ | Φ⁻¹]`` and ``x``. The measurement rows ``[0, R_ν Ĥ, R_ν y]`` are stacked
    under them and the whole array is triangularised by one sequence of Householder reflections
    (4.2.18 and 4.2.21 at once). That is the same factorisation as the two QRs in turn: the
    reflections of the noise columns leave the measurement rows alone (their entries there are
    zero), and after them the rows of ``[R⁻, z⁻]`` and of the measurement are what the second QR
    would triangularise; the triangular factor is unique up to the signs of its rows. So rows
    ``p…`` hold ``[R, z]`` and the row below them the residual ``e``.

    Likelihood (4.3.11–4.3.13): ``|S| = (|R| / (|R⁻| |R_ν|))²`` with ``|R⁻|`` from the
    determinant of the time-update array, ``|R_w| / (|L| |Φ|)``, divided by the product of the
    first ``p`` diagonal entries of the result. Moments from one back substitution with
    ``[I | z]`` (4.2.7, 4.2.22). Signs of rows are left as the reflections give them: the moments,
    ``‖e‖`` and ``|R|`` do not depend on them.

    ``Rv`` (m, m, 1 or runs) is the measurement noise's information factor and ``log_det_Rv``
    ``log|R_ν|`` (scalar or runs).

    Returns
    -------
    x, P, log Λ (G, runs), ‖e‖² (G, runs)
    """
    G, N, R = x.shape
    m = y.shape[0]
    p = st.p
    L = cholesky_lower(P * st.mask + st.dummy)
    A = np.zeros((G, p + N + m, p + N + 1, R))
    A[:, :p, :p] = st.Rw
    B = A[:, p:p + N]
    B[:, :, :p + N] = st.C
    B[:, :, -1] = x * st.vmask
    forward_substitute(L, B, out=B)
    if m == 1:
        A[:, p + N, p:p + N] = Rv[0, 0] * H[:, 0]
        A[:, p + N, -1] = Rv[0, 0] * y[0]
    else:
        A[:, p + N:, p:p + N] = _sum((Rv[None, :, :, None] * H[:, None]), 2)
        A[:, p + N:, -1] = _sum(Rv * y[None], 1)
    householder_triangularise(A, p + N)
    e2 = _sum(A[:, p + N:, -1] ** 2, 1)
    log_det_T = _sum(np.log(np.abs(np.diagonal(A[:, :p + N, :p + N], axis1=1, axis2=2))), -1)
    log_det_L = _sum(np.log(np.diagonal(L, axis1=1, axis2=2)), -1)
    log_det_S = 2.0 * (log_det_T + log_det_L + st.log_det_Phi_over_Rw - log_det_Rv)
    ll = -0.5 * (e2 + log_det_S + m * LOG_2PI)
    rhs = np.empty((G, N, N + 1, R))
    rhs[:, :, :N] = np.eye(N)[:, :, None]
    rhs[:, :, N] = A[:, p:p + N, -1]
    sol = back_substitute(A[:, p:p + N, p:p + N], rhs, out=rhs)
    Sinv = sol[:, :, :N]                                       # R⁻¹: P = R⁻¹ R⁻ᵀ
    P_post = _sum(Sinv[:, :, None] * Sinv[:, None], 3)
    x_post = sol[:, :, N]
    if st.decoupled:
        x_post = x_post * st.vmask + st.fill_mean
        P_post = P_post * st.mask + st.fill_cov
    return x_post, P_post, ll, e2
