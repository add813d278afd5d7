"""Signal-subspace tracking by PAST (Yang 1995), with the batch EVD as its reference.

Yang (1995), "Projection approximation subspace tracking", the ref. [9] of Ryu, Lee & Lee (2001);
see ``docs/papers/array-bearing.md``.
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

from pipeline.cores.array.music import eigen_decomposition, sample_covariance


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
    beta = float(forgetting)
    inv_beta = 1.0 / beta
    # runs-last layout: every step is a few contiguous element-wise passes over all runs
    # (faster than batched matmuls of 15 × 5 matrices)
    W = np.ascontiguousarray(np.moveaxis(np.asarray(W, dtype=complex), 0, -1))  # (M, N, B)
    P = np.ascontiguousarray(np.moveaxis(np.asarray(P, dtype=complex), 0, -1))  # (N, N, B)
    X = np.ascontiguousarray(np.moveaxis(np.asarray(snapshots).astype(complex, copy=False), -1, 0))  # (Ns, B, M)
    for x in X:
        x = x.T  # (M, B)
        y = np.sum(W.conj() * x[:, None, :], axis=0)  # Wᴴx, (N, B)
        h = np.sum(P * y[None, :, :], axis=1)  # P y
        g = h / (beta + np.sum(y.real * h.real + y.imag * h.imag, axis=0))  # yᴴh is real (P Hermitian)
        P = (P - g[:, None, :] * h.conj()[None, :, :]) * inv_beta
        P = 0.5 * (P + P.conj().transpose(1, 0, 2))  # Tri{·}: the Hermitian part
        e = x - np.sum(W * y[None, :, :], axis=1)
        W = W + e[:, None, :] * g.conj()[None, :, :]
    return np.moveaxis(W, -1, 0), np.moveaxis(P, -1, 0)


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


def largest_principal_angle(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """The subspace error used in the reports: the largest principal angle (rad)."""
    return principal_angles(A, B)[..., -1]
