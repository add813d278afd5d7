"""Global nearest neighbour association: one optimal one-to-one assignment of tracks to plots per
scan, inside the tracks' gates, with "not detected" as an option for every track.

Blackman & Popoli (1999), ch. 6: the assignment minimises the summed cost of the pairs it makes
plus the cost of leaving the other tracks without a plot. With the cost of a pair its squared
Mahalanobis distance ``νᵀ S⁻¹ ν`` and the cost of a miss the gate ``G``, a track takes a plot
only when doing so lowers the total, and never a plot outside its gate. The problem is solved
with :func:`scipy.optimize.linear_sum_assignment` on the tracks × (plots + one "miss" column
per track) matrix (docs/trackers.md, "Multi-target trackers").
"""

from __future__ import annotations

import numpy as np

# scipy.optimize and scipy.sparse.csgraph are imported where a contested scan needs them: the
# trackers' module is imported by every replay of the family (the registry lists its trackers),
# and scipy.optimize alone costs 0.14 s of CPU (beyond the import floor) in a 10-run replay
# that never calls it (issue 27).


def gnn_assignment(cost, gated, miss_cost, sparse: bool = True):
    """The GNN assignment of one scan, for every leading batch element (e.g. every run).

    Parameters
    ----------
    cost : ndarray (..., T, W)
        Cost of giving plot w to track t (any value where not gated).
    gated : ndarray of bool (..., T, W)
        Pairs allowed (plot inside the track's gate).
    miss_cost : float or ndarray (..., T)
        Cost of track t taking no plot.
    sparse : bool
        Solve every batch element at once on the gated pairs alone
        (:func:`_gnn_assignment_sparse`, the same assignment); False solves each batch element
        with :func:`scipy.optimize.linear_sum_assignment` on its tracks × (plots + misses)
        matrix, as written below.

    Returns
    -------
    plot : ndarray of int (..., T)
        The plot each track takes, −1 for none.
    """
    cost = np.asarray(cost, float)
    gated = np.asarray(gated, bool)
    lead, (T, W) = cost.shape[:-2], cost.shape[-2:]
    miss = np.broadcast_to(np.asarray(miss_cost, float), lead + (T,))
    if T == 0 or W == 0:
        return np.full(lead + (T,), -1, np.int64)
    if sparse:
        return _gnn_assignment_sparse(cost.reshape(-1, T, W), gated.reshape(-1, T, W), miss.reshape(-1, T)).reshape(
            lead + (T,))
    from scipy.optimize import linear_sum_assignment

    plot = np.full(lead + (T,), -1, np.int64)
    flat_plot = plot.reshape(-1, T)
    for b, (c, g, m) in enumerate(zip(cost.reshape(-1, T, W), gated.reshape(-1, T, W), miss.reshape(-1, T))):
        big = np.full((T, W + T), np.inf)
        big[:, :W] = np.where(g, c, np.inf)
        big[np.arange(T), W + np.arange(T)] = m
        r, k = linear_sum_assignment(big)
        real = k < W
        flat_plot[b, r[real]] = k[real]
    return plot


def _gnn_assignment_sparse(cost, gated, miss):
    """:func:`gnn_assignment` of ``(B, T, W)`` problems through their gated pairs only
    (:func:`pair_assignment`, the batch axis folded into the track and plot indices)."""
    B, T, W = cost.shape
    plot = np.full((B, T), -1, np.int64)
    b, t, w = np.nonzero(gated)
    chosen = pair_assignment(cost[b, t, w], b * T + t, b * W + w, miss.reshape(-1))
    plot[b[chosen], t[chosen]] = w[chosen]
    return plot


#: the rest of a scan's assignment goes to a dense linear_sum_assignment up to this many matrix
#: entries (its fixed cost is lower than building a sparse graph), to the sparse matching beyond
DENSE_MATCHING_ENTRIES = 1 << 16


def _cheapest_of_each_track(pairs, cost, track):
    """Of the ``pairs`` (indices), each track's cheapest, the first in order among equal costs.

    Pairs given by track (a tracker's, from :func:`numpy.nonzero`) take one minimum per run of
    equal tracks (:func:`numpy.minimum.reduceat`); others are sorted by track and cost, a stable
    sort (tests/test_multitarget_trackers.py holds the two equal)."""
    if not pairs.size:
        return pairs
    t, c = track[pairs], cost[pairs]
    new_track = np.r_[True, t[1:] != t[:-1]]
    if (t[1:] >= t[:-1]).all() and not np.isnan(c).any():
        starts = np.flatnonzero(new_track)
        lowest = np.minimum.reduceat(c, starts)
        at_lowest = np.flatnonzero(c == np.repeat(lowest, np.diff(np.append(starts, c.size))))
        group = np.cumsum(new_track)[at_lowest]
        return pairs[at_lowest[np.r_[True, group[1:] != group[:-1]]]]
    pairs = pairs[np.lexsort((c, t))]
    return pairs[np.r_[True, track[pairs][1:] != track[pairs][:-1]]]


def pair_assignment(cost, track, plot, miss, dense_entries: int = DENSE_MATCHING_ENTRIES):
    """The GNN assignment from the gated track–plot pairs alone.

    A track none of whose gated plots another track gates is a problem of its own: it takes its
    cheapest plot when cheaper than a miss. The other tracks form one sparse bipartite graph (their gated
    pairs, plus one "miss" column per track) whose minimum-weight matching of every track
    (:func:`scipy.sparse.csgraph.min_weight_full_bipartite_matching`) is the assignment; separate
    problems (runs) share no vertex, so one matching solves them all. Costs are shifted per track
    to be positive (a sparse graph has no zero-weight edge); a constant added to all of one
    track's options changes no optimum, as the track takes exactly one of them. A small rest
    (one run's crossings) is solved as a dense matrix instead, which costs less to set up.

    Parameters
    ----------
    cost : ndarray (E,)
        Cost of each gated pair.
    track : ndarray of int (E,)
        Its track, 0 … N − 1.
    plot : ndarray of int (E,)
        Its plot (any non-negative integers; a plot shared by tracks has one number).
    miss : ndarray (N,)
        Cost of each track taking no plot.
    dense_entries : int
        Largest tracks × (plots + misses) matrix of the rest solved densely
        (:func:`scipy.optimize.linear_sum_assignment`); the same assignment either way.

    Returns
    -------
    chosen : ndarray of bool (E,)
        The pairs of the assignment.
    """
    cost, track, plot = np.asarray(cost, float), np.asarray(track, np.int64), np.asarray(plot, np.int64)
    chosen = np.zeros(cost.size, bool)
    if cost.size == 0:
        return chosen
    if plot.max() >= 4 * plot.size + 1024:  # sparse numbers: made dense for the counts below
        _, plot = np.unique(plot, return_inverse=True)
        plot = plot.ravel()
    # a track none of whose plots another track gates is a problem of its own: its cheapest plot,
    # if cheaper than a miss (a track in clutter, away from the other tracks)
    shared_plot = np.bincount(plot)[plot] > 1
    alone = np.bincount(track, weights=shared_plot)[track] == 0
    first = _cheapest_of_each_track(np.flatnonzero(alone), cost, track)
    chosen[first] = cost[first] < miss[track[first]]
    rest = np.flatnonzero(~alone)
    if rest.size == 0:
        return chosen
    rows, row = np.unique(track[rest], return_inverse=True)
    cols, col = np.unique(plot[rest], return_inverse=True)
    n, row, col, c = rows.size, row.ravel(), col.ravel(), cost[rest]
    row_miss = miss[rows]
    if n * (cols.size + n) <= dense_entries:
        big = np.full((n, cols.size + n), np.inf)
        big[row, col] = c
        big[np.arange(n), cols.size + np.arange(n)] = row_miss
        from scipy.optimize import linear_sum_assignment
        r, k = linear_sum_assignment(big)
    else:
        from scipy.sparse import csr_matrix
        from scipy.sparse.csgraph import min_weight_full_bipartite_matching
        low = row_miss.copy()
        np.minimum.at(low, row, c)
        shift = 1.0 - low
        graph = csr_matrix((np.concatenate([c + shift[row], row_miss + shift]),
                            (np.concatenate([row, np.arange(n)]), np.concatenate([col, cols.size + np.arange(n)]))),
                           shape=(n, cols.size + n))
        r, k = min_weight_full_bipartite_matching(graph)
    real = k < cols.size
    # the edge of each matched (row, column): rows of a matching are distinct, so one per row
    match_col = np.full(n, -1, np.int64)
    match_col[r[real]] = k[real]
    mine = match_col[row] == col
    chosen[rest[mine]] = True
    return chosen
