"""Signal-subspace tracking by PAST (Yang 1995), with the batch EVD as its reference.

Yang (1995), "Projection approximation subspace tracking", the ref. [9] of Ryu, Lee & Lee (2001);
see ``docs/papers/array.md``.
Per snapshot x, with forgetting factor 0 < β ≤ 1::

    y = Wᴴ x;   h = P y;   g = h / (β + yᴴ h)
    P ← (1/β) · Tri{P − g hᴴ}           (Tri: keep the Hermitian part)
    e = x − W y;   W ← W + e gᴴ

W (M × N) tends to an orthonormal basis of the signal subspace and P to the inverse of the
exponentially weighted correlation of y. The recursion runs over the snapshots in time order and
is vectorised over a leading batch axis (Monte Carlo runs): one pass over the snapshots for all
runs. :func:`initial_state` aligns the tracker with a batch EVD (W = leading eigenvectors,
P = (1 − β) Λ_s⁻¹, the steady-state value of the weighted correlation's inverse), so tracking
starts aligned with the subspace of the first scan.

:func:`batch_signal_subspace` (per-scan EVD of the sample covariance) is the reference PAST is
compared against, through :func:`principal_angles`.
"""

from __future__ import annotations

import numpy as np

from trackreplay.cores.array.music import eigen_decomposition, sample_covariance


def batch_signal_subspace(snapshots: np.ndarray, n_sources: int):
    """Leading ``n_sources`` eigenvectors and eigenvalues of the sample covariance.

    Parameters
    ----------
    snapshots : ndarray, complex, shape (..., M, Ns)
    n_sources : int

    Returns
    -------
    basis : ndarray, complex, shape (..., M, N)
        Orthonormal, eigenvalues descending along the columns.
    values : ndarray, shape (..., N)
    """
    values, vectors = eigen_decomposition(sample_covariance(snapshots))
    # copies of the leading columns, so that the full eigenvector stacks are freed
    return (np.ascontiguousarray(vectors[..., ::-1][..., :n_sources]),
            np.ascontiguousarray(values[..., ::-1][..., :n_sources]))


def initial_state(basis: np.ndarray, values: np.ndarray, forgetting: float):
    """PAST state aligned with an EVD: ``W = basis``, ``P = (1 − β) diag(1/λ)``.

    With β = 1 (no forgetting) ``P = diag(1/λ)/Ns``-like scaling is unknown, so a unit weight
    ``P = diag(1/λ)`` is used.
    """
    scale = (1.0 - forgetting) if forgetting < 1.0 else 1.0
    P = np.zeros(values.shape + values.shape[-1:], dtype=complex)
    idx = np.arange(values.shape[-1])
    P[..., idx, idx] = scale / np.maximum(values, np.finfo(float).tiny)
    return np.array(basis, dtype=complex), P


def past_update(W: np.ndarray, P: np.ndarray, snapshots: np.ndarray, forgetting: float):
    """Run PAST over a block of snapshots in time order.

    Parameters
    ----------
    W : ndarray, complex, shape (B, M, N)
        Current subspace estimates (one per run).
    P : ndarray, complex, shape (B, N, N)
    snapshots : ndarray, complex, shape (B, M, Ns)
    forgetting : float
        β.

    Returns
    -------
    W, P : ndarray
        State after the last snapshot (new arrays; the inputs are not modified).
    """
    X = np.asarray(snapshots)
    Ws, P = past_scans(W, P, X[:, None], forgetting)
    return Ws[:, 0], P


def past_scans(W: np.ndarray, P: np.ndarray, snapshots: np.ndarray, forgetting: float):
    """Run PAST over consecutive scans of snapshots, keeping W at the end of every scan.

    The same recursion as :func:`past_update` over the scans' snapshots in time order (one call
    instead of one per scan: the state stays in its working layout between scans).

    Parameters
    ----------
    W : ndarray, complex, shape (B, M, N)
    P : ndarray, complex, shape (B, N, N)
    snapshots : ndarray, complex, shape (B, K, M, Ns)
        K scans of Ns snapshots per run; read one scan at a time (a complex64 array, or a view
        into a larger one, is converted scan by scan, never as a whole).
    forgetting : float
        β.

    Returns
    -------
    W : ndarray, complex, shape (B, K, M, N)
        The state after the last snapshot of each scan.
    P : ndarray, complex, shape (B, N, N)
        After the last snapshot.
    """
    beta = float(forgetting)
    inv_beta = 1.0 / beta
    B, K, M, Ns = snapshots.shape
    # runs-last layout: every step is a few contiguous element-wise passes over all runs
    # (faster than batched matmuls of 15 × 5 matrices), written into preallocated buffers. The
    # conjugate of W is what is kept: Wᴴx and the rank-one update then need no conjugate of the
    # M × N array (conjugation is exact, so the numbers are those of the plain recursion)
    Wc = np.ascontiguousarray(np.conj(np.moveaxis(np.asarray(W, dtype=complex), 0, -1)))  # (M, N, B)
    P = np.ascontiguousarray(np.moveaxis(np.asarray(P, dtype=complex), 0, -1))  # (N, N, B)
    N = Wc.shape[1]
    big, small, pair = np.empty_like(Wc), np.empty_like(P), np.empty_like(P)
    y, h, g, conj_n = (np.empty((N, B), complex) for _ in range(4))
    e, conj_x = np.empty((M, B), complex), np.empty((M, B), complex)
    real_a, real_b, den = np.empty((N, B)), np.empty((N, B)), np.empty(B)
    out = np.empty((B, K, M, N), complex)
    _sum = np.add.reduce  # np.sum without its Python wrapper (the same reduction): 4 of ~20 calls a snapshot
    for k in range(K):
        X = np.ascontiguousarray(np.asarray(snapshots[:, k]).transpose(2, 1, 0), dtype=complex)  # (Ns, M, B)
        for x in X:
            np.multiply(Wc, x[:, None, :], out=big)
            _sum(big, axis=0, out=y)  # y = Wᴴx
            np.multiply(P, y[None, :, :], out=small)
            _sum(small, axis=1, out=h)  # h = P y
            np.multiply(y.real, h.real, out=real_a)  # yᴴh is real (P Hermitian)
            np.multiply(y.imag, h.imag, out=real_b)
            real_a += real_b
            _sum(real_a, axis=0, out=den)
            den += beta
            np.divide(h, den, out=g)  # g = h / (β + yᴴh)
            np.conjugate(h, out=conj_n)
            np.multiply(g[:, None, :], conj_n[None, :, :], out=small)
            P -= small
            P *= inv_beta  # P ← (P − g hᴴ) / β
            np.conjugate(P.transpose(1, 0, 2), out=pair)
            P += pair
            P *= 0.5  # Tri{·}: the Hermitian part
            np.conjugate(y, out=conj_n)
            np.multiply(Wc, conj_n[None, :, :], out=big)
            _sum(big, axis=1, out=e)
            np.conjugate(x, out=conj_x)
            np.subtract(conj_x, e, out=e)  # conj(e), e = x − W y
            np.multiply(e[:, None, :], g[None, :, :], out=big)
            Wc += big  # conj(W ← W + e gᴴ)
        np.conjugate(Wc.transpose(2, 0, 1), out=out[:, k])
    return out, np.ascontiguousarray(np.moveaxis(P, -1, 0))


def orthonormal_basis(W: np.ndarray) -> np.ndarray:
    """An orthonormal basis of span(W) (reduced QR), batched."""
    q, _ = np.linalg.qr(W)
    return q


def principal_angles(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Principal angles (rad, ascending) between span(A) and span(B), batched.

    Both ``(..., M, N)``. Cosines are the singular values of ``Q_Aᴴ Q_B``, sines those of
    ``(I − Q_A Q_Aᴴ) Q_B``; pairing them through ``arctan2`` keeps small angles accurate
    (an arccos alone loses them below ~1e-8 rad).
    """
    qa, qb = orthonormal_basis(A), orthonormal_basis(B)
    qah = np.conj(np.swapaxes(qa, -1, -2))
    cos = np.linalg.svd(qah @ qb, compute_uv=False)  # descending
    sin = np.sort(np.linalg.svd(qb - qa @ (qah @ qb), compute_uv=False), axis=-1)  # ascending
    return np.arctan2(sin, cos)


def largest_principal_angle(A: np.ndarray, B: np.ndarray, b_orthonormal: bool = False) -> np.ndarray:
    """The subspace error used in the reports: the largest principal angle (rad), batched.

    The last of :func:`principal_angles` for two subspaces of equal dimension, without the two
    singular value decompositions: its sine is the largest singular value of
    ``(I − Q_A Q_Aᴴ) Q_B``, the square root of the largest eigenvalue of that residual's
    N × N Gram matrix (accurate relative to itself, so small angles keep their digits), and its
    cosine ``√(1 − sin²)``. Above 45° the cosine is the better-conditioned of the two, so there
    it is the smallest singular value of ``Q_Aᴴ Q_B`` as in :func:`principal_angles` (for
    those elements only).

    Parameters
    ----------
    A, B : ndarray, complex, shape (..., M, N)
    b_orthonormal : bool
        B's columns are orthonormal already (e.g. eigenvectors): no QR of B.
    """
    qa = orthonormal_basis(A)
    qb = np.asarray(B) if b_orthonormal else orthonormal_basis(B)
    cross = np.conj(np.swapaxes(qa, -1, -2)) @ qb
    resid = qb - qa @ cross
    sin2 = np.clip(np.linalg.eigvalsh(np.conj(np.swapaxes(resid, -1, -2)) @ resid)[..., -1], 0.0, 1.0)
    cos = np.sqrt(1.0 - sin2)
    wide = sin2 > 0.5
    if np.any(wide):
        cos = np.where(wide, 0.0, cos)  # a new array (also for a single pair)
        cos[wide] = np.linalg.svd(cross[wide], compute_uv=False)[..., -1]
    return np.arctan2(np.sqrt(sin2), cos)


def subspace_instant_offset(subspace: str, forgetting: float, scan_period_s: float, snapshots_per_scan: int,
                            n_scans: int) -> np.ndarray:
    """When, relative to its scan's time stamp, each scan's subspace estimate describes the scene (s).

    A scan's time stamp is the centre of its snapshots, which are ``T / Ns`` apart. The batch
    EVD weighs the scan's snapshots equally: it describes the centre (offset 0). PAST at the end
    of a scan weighs the snapshot i steps before the last by (1 − β) βⁱ (Yang 1995's
    exponentially weighted correlation), and the EVD of scan 0 it starts from (:func:`initial_state`,
    run from scan 1 on) by what is left, β^n after n snapshots. The mean age of the weights is

        m = (1 − β) Σ_{i<n} i βⁱ + βⁿ (n + (Ns − 1)/2),

    which tends to β / (1 − β) snapshots (32.3 at β = 0.97); the scan's centre is
    ``(Ns − 1)/2`` snapshots before its last, so PAST describes the scene
    ``(T / Ns) · (m − (Ns − 1)/2)`` before the time stamp (0.59 T at β = 0.97, Ns = 30, once
    the start is forgotten). A source moving at θ̇ is trailed by θ̇ times that, unless the
    filters measure θ at that instant (``docs/papers/array.md``, "PAST lags"). Scans 0
    and 1 are the start-up's per-scan EVDs (offset 0). Without forgetting (β = 1) the memory
    has no fixed age: 0 throughout.

    Returns
    -------
    ndarray, shape (n_scans,)
        The offset δ of each scan (s, negative: earlier than the time stamp).
    """
    out = np.zeros(int(n_scans))
    if subspace == "batch" or forgetting >= 1.0 or n_scans <= 2:
        return out
    beta, Ns = float(forgetting), int(snapshots_per_scan)
    n = Ns * np.arange(1, int(n_scans))  # snapshots PAST has run over at the end of scans 1, 2, …
    # (1 − β) Σ_{i<n} i βⁱ in closed form: β (1 − βⁿ) / (1 − β) − n βⁿ
    decayed = beta ** n
    mean_age = beta * (1.0 - decayed) / (1.0 - beta) - n * decayed + decayed * (n + (Ns - 1) / 2.0)
    out[1:] = -float(scan_period_s) / Ns * (mean_age - (Ns - 1) / 2.0)
    out[:2] = 0.0  # the start-up's scans: per-scan EVDs
    return out
