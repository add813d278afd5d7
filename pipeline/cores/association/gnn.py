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
from scipy.optimize import linear_sum_assignment


def gnn_assignment(cost, gated, miss_cost):
    """The GNN assignment of one scan, for every leading batch element (e.g. every run).

    Parameters
    ----------
    cost : ndarray (..., T, W)
        Cost of giving plot w to track t (any value where not gated).
    gated : ndarray of bool (..., T, W)
        Pairs allowed (plot inside the track's gate).
    miss_cost : float or ndarray (..., T)
        Cost of track t taking no plot.

    Returns
    -------
    plot : ndarray of int (..., T)
        The plot each track takes, −1 for none.
    """
    cost = np.asarray(cost, float)
    gated = np.asarray(gated, bool)
    lead, (T, W) = cost.shape[:-2], cost.shape[-2:]
    miss = np.broadcast_to(np.asarray(miss_cost, float), lead + (T,))
    plot = np.full(lead + (T,), -1, np.int64)
    if T == 0 or W == 0:
        return plot
    flat_cost, flat_gated = cost.reshape(-1, T, W), gated.reshape(-1, T, W)
    flat_miss, flat_plot = miss.reshape(-1, T), plot.reshape(-1, T)
    # a track with one gated plot that no other track gates takes it when cheaper than a miss:
    # no assignment problem to solve (the common case away from crossings and clutter)
    per_track, per_plot = flat_gated.sum(axis=2), flat_gated.sum(axis=1)
    for b in range(flat_cost.shape[0]):
        rows = np.flatnonzero(per_track[b] > 0)
        if rows.size == 0:
            continue
        g = flat_gated[b][rows]
        cols = np.flatnonzero(g.any(axis=0))
        g = g[:, cols]
        c = flat_cost[b][np.ix_(rows, cols)]
        if (per_track[b][rows] == 1).all() and (per_plot[b][cols] == 1).all():
            j = np.argmax(g, axis=1)
            take = c[np.arange(rows.size), j] < flat_miss[b][rows]
            flat_plot[b, rows[take]] = cols[j[take]]
            continue
        n = rows.size
        big = np.full((n, cols.size + n), np.inf)
        big[:, :cols.size] = np.where(g, c, np.inf)
        big[np.arange(n), cols.size + np.arange(n)] = flat_miss[b][rows]
        r, k = linear_sum_assignment(big)
        real = k < cols.size
        flat_plot[b, rows[r[real]]] = cols[k[real]]
    return plot
