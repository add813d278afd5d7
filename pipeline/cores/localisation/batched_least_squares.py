"""Whitened, column-scaled linear least squares for a stack of small problems at once.

The TDOA/FDOA Gauss-Newton step and Cramér-Rao bound (Kim et al. 2013, eqs. 16 and 18; see
``docs/papers/tdoa-fdoa.md``: δ = (HᵀΨ⁻¹H)⁻¹HᵀΨ⁻¹(u − g), I = HᵀΨ⁻¹H) both need the same
linear algebra on thousands of tall, thin (m × q, q ≤ 4) matrices whose columns mix metres and
metres per second. Forming HᵀΨ⁻¹H and inverting it squares a condition number that the mixed
units already make large, so instead:

1. the caller whitens rows (divides each row by its σ, i.e. Ψ^{-1/2} for a diagonal Ψ);
2. :func:`column_scale` divides each column by its norm (unit-free columns, which makes the
   condition number an honest measure of how well the geometry separates the unknowns);
3. :func:`householder_qr` reduces every matrix in the stack at once: a Python loop over the
   q ≤ 4 columns, each step vectorised over the whole stack (numpy's stacked ``linalg.qr``
   loops over matrices in C but pays a LAPACK call per matrix; this is ~3× faster here);
4. :func:`back_substitute` solves R y = Qᵀb; the step in the original units is y / scale.

The inverse of R (needed for a covariance, never for a step) is again a back-substitution.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Columns whose norm is below this fraction of the largest column are treated as zero
#: (the geometry gives no information on that unknown, e.g. an emitter on the sensors' line).
ZERO_COLUMN_RTOL = 1e-10
#: Below this ratio of the smallest to the largest |R_kk| the scaled problem is called rank
#: deficient (a variance ratio of 1e20: numerically meaningless, not merely a poor geometry).
RANK_RTOL = 1e-10


def column_scale(A: np.ndarray, zero_rtol: float = ZERO_COLUMN_RTOL) -> tuple[np.ndarray, np.ndarray]:
    """Column norms of a stack of matrices, with a flag for columns that are (numerically) zero.

    Parameters
    ----------
    A : ndarray (..., m, q)

    Returns
    -------
    scale : ndarray (..., q)
        Column norms; 1 where the column is zero (so dividing by it is harmless).
    zero : ndarray of bool (..., q)
        Columns below ``zero_rtol`` times the largest column norm (or not finite).
    """
    norms = np.sqrt(np.einsum("...ij,...ij->...j", A, A))
    largest = np.max(np.where(np.isfinite(norms), norms, 0.0), axis=-1, keepdims=True)
    zero = ~np.isfinite(norms) | (norms <= zero_rtol * largest) | (largest == 0)
    return np.where(zero, 1.0, norms), zero


def householder_qr(A: np.ndarray, b: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """Householder QR of every matrix of a stack, applying Qᵀ to right-hand sides as it goes.

    Parameters
    ----------
    A : ndarray (B, m, q) with m ≥ q
    b : ndarray (B, m) or (B, m, k), optional

    Returns
    -------
    R : ndarray (B, q, q)
        Upper triangular factor.
    Qtb : ndarray like ``b``, or None
        Qᵀb; its first q rows are the projected right-hand side, the rest the residual.
    """
    A = np.array(A, dtype=float, copy=True)
    _, m, q = A.shape
    if m < q:
        raise ValueError(f"householder_qr needs m ≥ q, got {m} × {q}")
    vec = b is not None and b.ndim == 2
    Qtb = None if b is None else np.array(b[..., None] if vec else b, dtype=float, copy=True)
    for k in range(q):
        x = A[:, k:, k]
        norm_x = np.sqrt(np.einsum("bi,bi->b", x, x))
        alpha = -np.where(x[:, 0] >= 0, 1.0, -1.0) * norm_x
        v = x.copy()
        v[:, 0] -= alpha
        vv = np.einsum("bi,bi->b", v, v)
        tau = np.where(vv > 0, 2.0 / np.where(vv > 0, vv, 1.0), 0.0)
        w = np.einsum("bi,bij->bj", v, A[:, k:, k:]) * tau[:, None]
        A[:, k:, k:] -= v[:, :, None] * w[:, None, :]
        if Qtb is not None:
            wb = np.einsum("bi,bij->bj", v, Qtb[:, k:]) * tau[:, None]
            Qtb[:, k:] -= v[:, :, None] * wb[:, None, :]
    R = np.triu(A[:, :q, :])
    if Qtb is not None and vec:
        Qtb = Qtb[..., 0]
    return R, Qtb


def back_substitute(R: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Solve R x = y for a stack of upper-triangular R (B, q, q); y (B, q) or (B, q, k)."""
    vec = y.ndim == 2
    Y = y[..., None] if vec else y
    q = R.shape[-1]
    x = np.empty(Y.shape, dtype=float)
    for i in range(q - 1, -1, -1):
        acc = Y[:, i] - np.einsum("bj,bjk->bk", R[:, i, i + 1:], x[:, i + 1:])
        x[:, i] = acc / R[:, i, i][:, None]
    return x[..., 0] if vec else x


def rank_deficient(R: np.ndarray, zero_columns: np.ndarray | None = None, rtol: float = RANK_RTOL) -> np.ndarray:
    """Stacks whose (column-scaled) triangular factor is numerically singular."""
    d = np.abs(np.diagonal(R, axis1=-2, axis2=-1))
    bad = ~np.all(np.isfinite(d), axis=-1) | (d.min(axis=-1) <= rtol * d.max(axis=-1))
    if zero_columns is not None:
        bad |= zero_columns.any(axis=-1)
    return bad


@dataclass
class LeastSquaresSolution:
    """Solution of min ‖A x − b‖ for every stack member (whitened units).

    Attributes
    ----------
    x : ndarray (B, q)
        Solution in the original column units (NaN where rank deficient).
    projected_norm : ndarray (B,)
        ‖Q₁ᵀ b‖ = ‖A x‖: for a Gauss-Newton step, the step's length in standard deviations
        (its Mahalanobis length under the local Fisher information).
    rank_deficient : ndarray of bool (B,)
    R : ndarray (B, q, q)
        Triangular factor of the column-scaled A.
    scale : ndarray (B, q)
        Column norms of A.
    """

    x: np.ndarray
    projected_norm: np.ndarray
    rank_deficient: np.ndarray
    R: np.ndarray
    scale: np.ndarray


def scaled_least_squares(A: np.ndarray, b: np.ndarray) -> LeastSquaresSolution:
    """Solve min ‖A x − b‖ per stack member via column scaling and Householder QR.

    Parameters
    ----------
    A : ndarray (B, m, q)
        Whitened design matrices (rows already divided by their σ).
    b : ndarray (B, m)
        Whitened right-hand sides.
    """
    scale, zero = column_scale(A)
    R, Qtb = householder_qr(A / scale[:, None, :], b)
    q = A.shape[-1]
    bad = rank_deficient(R, zero)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        y = back_substitute(R, Qtb[:, :q])
    x = np.where(bad[:, None], np.nan, y / scale)
    return LeastSquaresSolution(x, np.sqrt(np.sum(Qtb[:, :q] ** 2, axis=-1)), bad, R, scale)


def covariance_from_factor(R: np.ndarray, scale: np.ndarray, bad: np.ndarray | None = None) -> np.ndarray:
    """(AᵀA)⁻¹ from the QR factor of the column-scaled A: D⁻¹ R⁻¹ R⁻ᵀ D⁻¹ (NaN where singular)."""
    q = R.shape[-1]
    eye = np.broadcast_to(np.eye(q), R.shape)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        Rinv = back_substitute(R, eye)
        cov = np.einsum("bik,bjk->bij", Rinv, Rinv) / (scale[:, :, None] * scale[:, None, :])
    if bad is not None:
        cov[bad] = np.nan
    return cov


def information_covariance(A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(AᵀA)⁻¹ for a stack of whitened Jacobians A (..., m, q), without forming AᵀA.

    Returns
    -------
    cov : ndarray (..., q, q)
        NaN where the information matrix is singular.
    singular : ndarray of bool (...)
    """
    lead = A.shape[:-2]
    m, q = A.shape[-2:]
    if m < q:  # fewer equations than unknowns: singular whatever the geometry
        return np.full((*lead, q, q), np.nan), np.ones(lead, bool)
    flat = A.reshape(-1, m, q)
    scale, zero = column_scale(flat)
    R, _ = householder_qr(flat / scale[:, None, :])
    bad = rank_deficient(R, zero)
    cov = covariance_from_factor(R, scale, bad)
    return cov.reshape(*lead, *cov.shape[-2:]), bad.reshape(lead)
