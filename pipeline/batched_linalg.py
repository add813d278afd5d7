"""Cholesky factors and whitening of many small matrices at once, element by element.

Tracking states and measurements are small (n ≤ 10 or so) and come in stacks of millions: one per
run, scan and track. LAPACK called per matrix spends most of its time on the call; here each
entry of the factor is one vectorised operation over the whole stack, a few dozen operations in
all, and a matrix that is missing or not positive definite simply comes out NaN. Numpy only, no
I/O: the trackers' output checks (``pipeline.trackers.interface``) and the evaluators' NEES/NIS
(``evaluators.consistency``) share it (``docs/evaluation.md``).
"""

from __future__ import annotations

import numpy as np


def cholesky_columns(P):
    """The lower Cholesky factor of a stack of symmetric matrices, entry by entry.

    Parameters
    ----------
    P : ndarray (N, n, n)
        Only the lower triangle is read.

    Returns
    -------
    L : list of list of ndarray (N,)
        ``L[i][j]`` (j ≤ i) the factor's entries.
    pivot : ndarray (N, n)
        The squared diagonal before its square root (``L[i][i]²``): a matrix is positive definite
        exactly where every pivot is > 0 (NaN where it is missing).
    """
    n = P.shape[-1]
    L = [[None] * n for _ in range(n)]
    pivot = np.empty(P.shape[:1] + (n,))
    with np.errstate(invalid="ignore", divide="ignore"):
        for i in range(n):
            for j in range(i + 1):
                acc = P[:, i, j].copy()
                for k in range(j):
                    acc -= L[i][k] * L[j][k]
                if j < i:
                    L[i][j] = acc / L[j][j]
                else:
                    pivot[:, i] = acc
                    L[i][i] = np.sqrt(acc)
    return L, pivot


def whiten(e, P):
    """``w = L⁻¹ e`` with ``P = L Lᵀ`` for stacks ``e`` (N, n) and ``P`` (N, n, n), so that
    ``eᵀ P⁻¹ e = ‖w‖²``; NaN rows where ``e`` or ``P`` is missing or ``P`` is not positive
    definite."""
    L, pivot = cholesky_columns(P)
    n = e.shape[-1]
    w = np.empty(e.shape)
    with np.errstate(invalid="ignore", divide="ignore"):
        for i in range(n):
            acc = e[:, i].copy()
            for k in range(i):
                acc -= L[i][k] * w[:, k]
            w[:, i] = acc / L[i][i]
    bad = ~(pivot > 0).all(axis=-1) | ~np.isfinite(w).all(axis=-1)
    w[bad] = np.nan
    return w
