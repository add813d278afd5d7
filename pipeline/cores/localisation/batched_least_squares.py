"""Whitened, column-scaled linear least squares for a stack of small problems at once.

The TDOA/FDOA Gauss-Newton step and Cramér-Rao bound (Kim et al. 2013, eqs. 16 and 18; see
``docs/papers/tdoa-fdoa.md``: δ = (HᵀΨ⁻¹H)⁻¹HᵀΨ⁻¹(u − g), I = HᵀΨ⁻¹H) both need the same
linear algebra on thousands of tall, thin (m × q, q ≤ 4) matrices whose columns mix metres and
metres per second. Forming HᵀΨ⁻¹H and inverting it squares a condition number that the mixed
units already make large, so instead:

1. the caller whitens rows (divides each row by its σ, i.e. Ψ^{-1/2} for a diagonal Ψ);
2. each column is divided by its norm (unit-free columns, which makes the condition number an
   honest measure of how well the geometry separates the unknowns; :func:`column_scale`);
3. Householder QR reduces every matrix of the stack;
4. R y = Qᵀb is solved by back-substitution (:func:`back_substitute`); the step in the
   original units is y / scale.

Two forms of step 3. :func:`householder_qr` loops over the q ≤ 4 columns, each step
vectorised over the stack (the CRLB path, :func:`information_covariance`).
:func:`solve_augmented` (the Gauss-Newton path, :func:`scaled_least_squares`) keeps the stack
axis last and hands the augmented matrices [A | b] to LAPACK's stacked ``geqrf`` through
:func:`numpy.linalg.qr` in one call: a Gauss-Newton iteration on a single run then costs a few
dozen array calls instead of a few hundred, and on 500 runs the LAPACK loop over matrices is
still no slower than the column loop (≈ 250 µs against ≈ 300 µs per 500 augmented 6 × 5
matrices on the reference machine). A stack of one (a single recording) calls the same LAPACK
routine through ``scipy.linalg.lapack.dgeqrf``, without the stacked call's set-up (≈ 1 µs
against ≈ 6 µs per 6 × 5 matrix), and gets the same bits.

The inverse of R (needed for a covariance, never for a step) is again a back-substitution.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg.lapack import dgeqrf as _dgeqrf

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


def _back_substitute_rows(Rt: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Solve R x = y in place, the stack axis last: ``Rt`` (q, ≥ q, B) with R in its upper
    triangle (anything below it is ignored), ``x`` (q, B) or (q, k, B) holding y on entry.

    Column-oriented: once x_i is known its contribution R[:i, i] x_i is removed from the rows
    above, so each of the q steps is two array operations over the whole stack, on rows that
    are contiguous in the stack axis (no per-matrix LAPACK call, whose fixed cost dominates
    4 × 4 systems).
    """
    if x.ndim == 3:  # several right-hand sides: R's entries broadcast along them
        Rt = Rt[:, :, None, :]
    i = x.shape[0] - 1
    x[i] /= Rt[i, i]
    while i:
        x[:i] -= Rt[:i, i] * x[i]
        i -= 1
        x[i] /= Rt[i, i]
    return x


def back_substitute(R: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Solve R x = y for a stack of upper-triangular R (B, q, q); y (B, q) or (B, q, k)."""
    x = np.moveaxis(np.array(y, dtype=float, copy=True), 0, -1).copy()  # stack axis last
    _back_substitute_rows(R.transpose(1, 2, 0), x)
    return np.moveaxis(x, -1, 0)


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


_DIAGONAL = np.arange(16)  # index of the diagonal of the triangular factors (q ≤ 16), built once
_IDENTITY = {q: np.eye(q)[:, :, None] for q in range(17)}  # (q, q, 1): broadcast along a stack


def _geqrf_rows(M: np.ndarray, q: int) -> np.ndarray:
    """LAPACK ``geqrf`` of every (m, q + 1) matrix of ``M`` (stack last), returned as the top
    q rows of the factored matrices, (q, q + 1, B): R in the upper triangle, Q₁ᵀb last.

    A stack goes to the stacked :func:`numpy.linalg.qr` (``mode="raw"``); a single matrix goes
    to ``scipy.linalg.lapack.dgeqrf`` directly (≈ 1 µs against ≈ 6 µs for the stacked call's
    checks and set-up, paid at every iteration of a one-run Gauss-Newton). Both run the same
    LAPACK routine on the same matrix, so a run's factor is the same alone as in a stack
    (``tests/test_tdoa_speed_paths.py`` checks it to the bit).
    """
    if M.shape[2] == 1:
        factored, _, _, info = _dgeqrf(M[:, :, 0])
        if info:  # only for an invalid argument, which the shapes rule out
            raise ValueError(f"geqrf failed (info {info})")
        return factored[:q, :, None]
    # raw mode hands back the factored (B, m, q + 1) matrices transposed: swap to rows k,
    # columns j, stack last
    return np.ascontiguousarray(np.linalg.qr(M.transpose(2, 0, 1), mode="raw")[0][:, :, :q].transpose(2, 1, 0))


def _factor(M: np.ndarray, zero_rtol: float, rank_rtol: float):
    """Column scaling, QR and rank test of :func:`solve_augmented`.

    Returns the factor ``Rt`` (q, q + 1, B: R in the upper triangle, Q₁ᵀb in the last
    column, rows k and columns j with the stack last), ``scale`` (q, B), the rank-deficiency
    mask (B,), whether any member is deficient, and ‖b‖² (B,).
    """
    q = M.shape[1] - 1
    A = M[:, :q]
    # sums of squares of every column, b's included (‖b‖² is the cost): the reduction runs over
    # the leading axis, so it adds the rows in order whatever B is (a run's answer must not
    # depend on the rest of the stack; q + 1 ≥ 2 keeps the rows from being the inner loop)
    squares = np.add.reduce(M * M, axis=0)
    norms = np.sqrt(squares[:q])
    # a column is zero unless above the threshold: an infinite norm (overflow) makes the
    # threshold infinite and every column of that member zero, so that it is rank deficient
    used = norms > zero_rtol * np.maximum.reduce(norms, axis=0)
    scale = np.where(used, norms, 1.0)
    A /= scale
    Rt = _geqrf_rows(M, q)
    # a zero column counts as a zero on the diagonal (M is finite, so R is); the diagonal is
    # a (B, q) view, and a minimum or maximum is exact in any order
    d = np.abs(Rt.diagonal(axis1=0, axis2=1)) * used.T
    bad = np.minimum.reduce(d, axis=1) <= rank_rtol * np.maximum.reduce(d, axis=1)
    return Rt, scale, bad, bool(np.logical_or.reduce(bad)), squares[q]


def _step(Rt: np.ndarray, scale: np.ndarray, bad: np.ndarray, bad_any: bool):
    """x = R⁻¹ Q₁ᵀb / scale (q, B; NaN where ``bad``) and ‖Q₁ᵀb‖ (B,) from :func:`_factor`."""
    q = Rt.shape[0]
    Qtb = Rt[:, q]
    x = Qtb.copy()
    if bad_any:  # the identity in their place keeps the back-substitution free of 0/0
        R = Rt.copy()
        R[:, :q, bad] = _IDENTITY[q]
        _back_substitute_rows(R, x)
        x[:, bad] = np.nan
    else:
        _back_substitute_rows(Rt, x)
    x /= scale
    # q < 8 terms: numpy adds them in order in any loop layout, so again B plays no part
    return x, np.sqrt(np.add.reduce(Qtb * Qtb, axis=0))


def solve_augmented(M: np.ndarray, zero_rtol: float = ZERO_COLUMN_RTOL,
                    rank_rtol: float = RANK_RTOL) -> LeastSquaresSolution:
    """min ‖A x − b‖ for a stack given as augmented matrices [A | b], stack axis last.

    The whitened, column-scaled Householder QR of the module, in as few array calls as
    possible, because a single Gauss-Newton run pays every call's fixed cost at each iteration
    (``docs/papers/tdoa-fdoa.md``, "Speed"):

    * the stack axis is last, so every elementwise step (column norms, scaling, rank test,
      back-substitution) runs over long contiguous rows rather than tiny trailing axes;
    * LAPACK's ``geqrf`` (through the stacked :func:`numpy.linalg.qr`, ``mode="raw"``) reduces
      [A/scale | b] in one call: R is the leading q × q triangle and Q₁ᵀb the top of the last
      column, so Qᵀ is never formed nor applied separately;
    * R y = Q₁ᵀb by back-substitution over the whole stack; rank-deficient members get the
      identity there (no 0/0) and NaN in ``x``.

    Every member is solved on its own (LAPACK factors the matrices one by one, the other
    steps are elementwise over the stack), so a member's answer does not depend on the rest
    of the stack, to the last bit.

    Parameters
    ----------
    M : ndarray (m, q + 1, B), m ≥ q, finite
        Whitened design matrices with the whitened right-hand side as the last column. The
        first q columns are divided by their norms in place.
    zero_rtol, rank_rtol : float
        As :data:`ZERO_COLUMN_RTOL` and :data:`RANK_RTOL`.

    Returns
    -------
    LeastSquaresSolution
    """
    m, n, _ = M.shape
    if m < n - 1:
        raise ValueError(f"least squares needs m ≥ q, got {m} × {n - 1}")
    Rt, scale, bad, bad_any, _ = _factor(M, zero_rtol, rank_rtol)
    x, norm = _step(Rt, scale, bad, bad_any)
    return LeastSquaresSolution(x.T, norm, bad, np.triu(Rt[:, :-1].transpose(2, 0, 1)), scale.T)


def scaled_least_squares(A: np.ndarray, b: np.ndarray) -> LeastSquaresSolution:
    """Solve min ‖A x − b‖ per stack member via column scaling and Householder QR.

    Parameters
    ----------
    A : ndarray (B, m, q)
        Whitened design matrices (rows already divided by their σ), finite.
    b : ndarray (B, m)
        Whitened right-hand sides, finite.
    """
    A = np.asarray(A, float)
    B, m, q = A.shape
    M = np.empty((m, q + 1, B))
    M[:, :q] = A.transpose(1, 2, 0)
    M[:, q] = np.asarray(b, float).T
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        return solve_augmented(M)


def _covariance_rows(Rt: np.ndarray, scale: np.ndarray, bad: np.ndarray, bad_any: bool) -> np.ndarray:
    """D⁻¹ R⁻¹ R⁻ᵀ D⁻¹ (B, q, q) from ``Rt`` (q, ≥ q, B; R in the upper triangle) and
    ``scale`` (q, B); NaN where ``bad`` (whose R is replaced by the identity first)."""
    q, B = scale.shape
    Rinv = np.repeat(_IDENTITY[q], B, axis=2)  # rows of R⁻¹, stack last; the identity on entry
    if bad_any:
        Rt = Rt.copy()
        Rt[:, :q, bad] = _IDENTITY[q]
    _back_substitute_rows(Rt, Rinv)
    Rinv /= scale[:, None, :]  # D⁻¹ R⁻¹
    # Σ_k over q < 8 terms, in order whatever the layout (see _factor)
    cov = np.add.reduce(Rinv[:, None] * Rinv[None, :], axis=2).transpose(2, 0, 1)
    if bad_any:
        cov[bad] = np.nan
    return cov


def covariance_from_factor(R: np.ndarray, scale: np.ndarray, bad: np.ndarray | None = None) -> np.ndarray:
    """(AᵀA)⁻¹ from the QR factor of the column-scaled A: D⁻¹ R⁻¹ R⁻ᵀ D⁻¹ (NaN where singular).

    Only the upper triangle of ``R`` (B, q, q) is read. R⁻¹ is a back-substitution against the
    identity (R being triangular, this is no general inverse); members with a zero on the
    diagonal or flagged ``bad`` get the identity in place of R (no 0/0) and NaN in the result.
    """
    q = R.shape[-1]
    Rt = R.transpose(1, 2, 0)
    singular = ~(np.abs(Rt[_DIAGONAL[:q], _DIAGONAL[:q]]).min(axis=0) > 0.0)
    if bad is not None:
        singular |= bad
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        return _covariance_rows(Rt, scale.T, singular, bool(singular.any()))


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
