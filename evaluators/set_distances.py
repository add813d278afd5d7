"""OSPA and GOSPA between the set of track estimates and the set of true targets, per scan.

* OSPA (Schuhmacher, Vo & Vo 2008): for |X| = m ≤ n = |Y|,
  ``d = ((1/n)(min_π Σ_i min(d(x_i, y_π(i)), c)^p + c^p (n − m)))^(1/p)``.
* GOSPA with α = 2 (Rahmathullah, García-Fernández & Svensson 2017, eq. 2 and Prop. 1):
  ``d = (min_γ Σ_{(i,j)∈γ} d(x_i, y_j)^p + (c^p/2)(|X| + |Y| − 2|γ|))^(1/p)`` over partial
  assignments γ; it splits into localisation, missed-target and false-track parts.

Both reduce to one assignment on the cost ``min(d, c)^p``: a pair at or beyond the cut-off ``c``
costs as much as leaving both unassigned. Sets are padded arrays with NaN rows for absent
elements, so whole data sets are scored at once: small sets (≤ ``BRUTE_FORCE_MAX`` elements on
the larger side) by evaluating every permutation in one numpy expression, larger ones with
``scipy.optimize.linear_sum_assignment`` per scan. See ``docs/evaluation.md``.
"""

from __future__ import annotations

from functools import lru_cache
from itertools import permutations

import numpy as np

from pipeline.batched_linalg import all_finite, sum_squares

BRUTE_FORCE_MAX = 6  # 6! = 720 permutations per scan, evaluated together
BRUTE_FORCE_BLOCK_SUMS = 1 << 17  # permutation sums per block of problems: 1 MiB, in the cache


@lru_cache(maxsize=None)
def _perms(n: int) -> np.ndarray:
    return np.array(list(permutations(range(n))), dtype=np.intp).reshape(-1, n)


@lru_cache(maxsize=None)
def _prefix_tree(n: int) -> tuple:
    """The permutations of ``range(n)`` as a tree of prefixes: per row k, the parent of every
    prefix of length k + 1 among those of length k and the column it adds. Prefixes are listed
    in lexicographic order, so the leaves are :func:`_perms`'s rows in its order."""
    levels, prefixes = [], [()]
    for _ in range(n):
        parent, column, grown = [], [], []
        for i, prefix in enumerate(prefixes):
            for j in range(n):
                if j not in prefix:
                    parent.append(i)
                    column.append(j)
                    grown.append(prefix + (j,))
        levels.append((np.array(parent, dtype=np.intp), np.array(column, dtype=np.intp)))
        prefixes = grown
    return tuple(levels)


def _every_permutation(full: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Minimum total and its permutation of every ``(size, size)`` problem in ``full`` (B, size,
    size), trying all permutations.

    The totals are summed row by row along the prefix tree, so each prefix sum is shared by
    every permutation that extends it (1,956 additions per problem at size 6 instead of
    4,320) and each total is ``((c₀ + c₁) + c₂) + …`` in row order, bit for bit the sum of
    the permutation's costs; among equal totals the first permutation in lexicographic order
    wins. Problems go through in blocks of :data:`BRUTE_FORCE_BLOCK_SUMS` sums (182 problems
    at size 6), problems last, so that every gather along the tree copies whole rows and the
    sums stay in the cache whatever the number of scans and runs.
    """
    size = full.shape[-1]
    levels, perms = _prefix_tree(size), _perms(size)
    total = np.empty(full.shape[0])
    best = np.empty(full.shape[0], dtype=np.intp)
    step = max(1, BRUTE_FORCE_BLOCK_SUMS // len(perms))
    for start in range(0, full.shape[0], step):
        block = np.ascontiguousarray(full[start:start + step].transpose(1, 2, 0))  # (size, size, b)
        sums = block[0, levels[0][1]]
        for row, (parent, column) in enumerate(levels[1:], start=1):
            sums = sums[parent] + block[row, column]
        choice = np.argmin(sums, axis=0)
        part = slice(start, start + block.shape[-1])
        best[part] = choice
        total[part] = sums[choice, np.arange(block.shape[-1])]
    return total, perms[best]


def pairwise_distance(tracks, truths, angular: bool = False) -> np.ndarray:
    """Euclidean distances ``(..., m, n)`` between padded sets ``(..., m, d)`` and ``(..., n, d)``.

    With ``angular`` the components are angles and differences wrap to (−π, π].
    """
    diff = np.asarray(tracks, float)[..., :, None, :] - np.asarray(truths, float)[..., None, :, :]
    if angular:
        diff = (diff + np.pi) % (2 * np.pi) - np.pi
    return np.sqrt(sum_squares(diff))


def optimal_assignment(cost: np.ndarray, valid_rows: np.ndarray, valid_cols: np.ndarray, unmatched: float = 0.0):
    """Minimum-cost assignment for every leading index of ``cost`` (..., m, n).

    Absent rows/columns (padding) pair with each other for nothing; a present element left
    with padding costs ``unmatched``.

    Returns
    -------
    total : ndarray (...)
        The minimum total cost.
    match : ndarray of int (..., m)
        Column assigned to each row, -1 for none or an invalid partner.
    """
    cost = np.asarray(cost, float)
    lead, (m, n) = cost.shape[:-2], cost.shape[-2:]
    size = max(m, n)
    rows_present = np.zeros(lead + (size,), bool)
    rows_present[..., :m] = valid_rows
    cols_present = np.zeros(lead + (size,), bool)
    cols_present[..., :n] = valid_cols
    full = np.where(rows_present[..., :, None] != cols_present[..., None, :], float(unmatched), 0.0)
    both = rows_present[..., :, None] & cols_present[..., None, :]
    full[..., :m, :n] = np.where(both[..., :m, :n], cost, full[..., :m, :n])
    match = np.full(lead + (m,), -1, dtype=np.intp)
    if size == 0:
        return np.zeros(lead), match
    if size == 1:
        # one element a side (a single-track family): the one assignment there is, no search
        total, cols = full[..., 0, 0], np.zeros(lead + (1,), dtype=np.intp)[..., :m]
    elif size <= BRUTE_FORCE_MAX:
        total, cols = _every_permutation(full.reshape(-1, size, size))
        total, cols = total.reshape(lead), cols.reshape(lead + (size,))[..., :m]
    else:
        from scipy.optimize import linear_sum_assignment

        flat = full.reshape(-1, size, size)
        cols = np.empty((flat.shape[0], size), dtype=np.intp)
        total = np.empty(flat.shape[0])
        for i, c in enumerate(flat):
            r, col = linear_sum_assignment(c)
            cols[i, r] = col
            total[i] = c[r, col].sum()
        cols, total = cols.reshape(lead + (size,))[..., :m], total.reshape(lead)
    # a row's partner is real when its column is a present element (not padding, not a dummy column)
    keep = valid_rows & np.take_along_axis(cols_present, cols, axis=-1)
    match = np.where(keep, cols, -1)
    return total, match


def gospa(tracks, truths, cutoff: float, order: float = 2.0, angular: bool = False) -> dict:
    """GOSPA (α = 2) and its parts for padded sets, vectorised over the leading axes.

    Parameters
    ----------
    tracks : ndarray (..., m, d)
        Track estimates; rows with NaN are absent.
    truths : ndarray (..., n, d)
        True target states in the same space; rows with NaN are absent.
    cutoff : float
        ``c`` (> 0), in the units of the space.
    order : float
        ``p`` ≥ 1.
    angular : bool
        The components are angles (radians): differences wrap.

    Returns
    -------
    dict of ndarray (...)
        ``gospa``, ``localisation`` (Σ d^p over assigned pairs closer than c, to the power 1/p),
        ``missed`` and ``false`` (counts), ``ospa``, and ``assigned`` (pairs closer than c).
    """
    X, Y = np.asarray(tracks, float), np.asarray(truths, float)
    vx, vy = all_finite(X), all_finite(Y)
    d = pairwise_distance(np.where(vx[..., None], X, 0.0), np.where(vy[..., None], Y, 0.0), angular)
    cost = np.minimum(d, cutoff) ** order
    cp = cutoff ** order
    total, match = optimal_assignment(cost, vx, vy, unmatched=cp)
    m_count, n_count = vx.sum(axis=-1), vy.sum(axis=-1)
    matched_d = np.where(match >= 0, np.take_along_axis(d, np.maximum(match, 0)[..., None], axis=-1)[..., 0], np.inf)
    close = (match >= 0) & (matched_d < cutoff)
    assigned = close.sum(axis=-1)
    loc = np.where(close, matched_d ** order, 0.0).sum(axis=-1)
    # total = Σ min(d, c)^p over the optimal pairs + c^p per element of the larger set left over.
    # A pair at or beyond c costs c^p, as much as leaving both unassigned (c^p/2 each) in GOSPA,
    # so GOSPA^p = total − (c^p/2)·||X| − |Y|| and OSPA^p = total / max(|X|, |Y|).
    excess = np.abs(m_count - n_count)
    g = np.maximum(total - cp / 2 * excess, 0.0) ** (1 / order)
    big = np.maximum(m_count, n_count)
    ospa = np.where(big > 0, (total / np.maximum(big, 1)) ** (1 / order), 0.0)
    return {"gospa": g, "localisation": loc ** (1 / order), "missed": n_count - assigned,
            "false": m_count - assigned, "ospa": ospa, "assigned": assigned}
