"""The fast forms of :mod:`trackreplay.evaluators.set_distances`: private, each the same values as
the plain form it stands for, and tested against it. The plain module imports this one; this one
imports only the pieces both share (:mod:`trackreplay.evaluators.set_distances_shared`).

* :func:`_every_permutation`: the brute-force assignment of small sets, every permutation of
  many problems at once along a prefix tree (:func:`~trackreplay.evaluators.set_distances.optimal_assignment`);
* :func:`_sparse_assignment`: the assignment from the pairs closer than the cut-off alone, for
  sets larger than ``BRUTE_FORCE_MAX`` (GOSPA from those pairs,
  :func:`~trackreplay.evaluators.set_distances._gospa_sparse`, is built on the plain
  ``close_pairs`` and ``assign_edges`` and lives beside them);
* :func:`_gospa_switching_single`: :func:`~trackreplay.evaluators.set_distances.gospa_switching` of
  one track and one target a run (Rahmathullah, García-Fernández & Svensson 2017), from the one
  distance per scan;
* :func:`_close_pairs_windowed`: :func:`~trackreplay.evaluators.set_distances.close_pairs` from a
  window along one component (the plain form, every pair, is
  :func:`~trackreplay.evaluators.set_distances_shared._close_pairs_dense`);
* :func:`_identity_pairs_dense`, :func:`_global_identities_sorted` and
  :func:`_bipartite_components`: the bookkeeping of identities and of the assignment's graph.

See ``docs/evaluation.md`` and ``docs/benchmarks.md``.
"""

from __future__ import annotations

from functools import lru_cache
from itertools import permutations

import numpy as np

from trackreplay.batched_linalg import all_finite
# the pieces the plain forms share with these (this module imports nothing of the plain one)
from trackreplay.evaluators.set_distances_shared import (BRUTE_FORCE_MAX, SinglePair, _add_square, _close_pairs_dense,
                                                         _compact, single_pair_distance, single_pair_view)

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


def _sparse_assignment(cost, pair, n_rows, n_cols, unmatched):
    """:func:`optimal_assignment` beyond the brute-force size when no pair costs more than
    ``unmatched``.

    Then the padded problem is a maximum-weight matching: with ``u`` pairs cheaper than
    ``unmatched`` (the *edges*) in an assignment, the total is
    ``max(m′, n′)·unmatched − Σ_edges (unmatched − cost)`` (m′, n′ present rows and columns),
    because every present element not on an edge pairs with padding or with another such
    element at ``unmatched`` per pair. So elements without an edge play no part, and an edge
    whose row and column have no other edge is in every optimal assignment (exchanging it for
    any other partners costs more). What is left, usually little where targets are apart, is
    solved by trying every permutation (:func:`_every_permutation`, all problems at once) when
    it has at most ``BRUTE_FORCE_MAX`` rows and columns, else by
    ``scipy.optimize.linear_sum_assignment``. Rows that end on no edge get −1 (their partner
    would cost ``unmatched``, the cut-off, which every caller reads as unmatched).
    """
    from scipy.optimize import linear_sum_assignment

    lead, (m, n) = cost.shape[:-2], cost.shape[-2:]
    cost = cost.reshape((-1, m, n))
    edge = pair.reshape((-1, m, n)) & (cost < unmatched)
    weight = np.where(edge, unmatched - cost, 0.0)
    row_edges, col_edges = edge.sum(axis=2), edge.sum(axis=1)
    alone = edge & (row_edges[:, :, None] == 1) & (col_edges[:, None, :] == 1)
    alone_row = alone.any(axis=2)
    match = np.where(alone_row, alone.argmax(axis=2), -1)
    gain = np.where(alone, weight, 0.0).sum(axis=(1, 2))
    rest_rows = (row_edges > 0) & ~alone_row
    rest_cols = (col_edges > 0) & ~alone.any(axis=1)
    n_rest = np.maximum(rest_rows.sum(axis=1), rest_cols.sum(axis=1))
    small = np.flatnonzero((n_rest > 0) & (n_rest <= BRUTE_FORCE_MAX))
    if small.size:
        # the left-over rows and columns first (stable order), cut to the largest left-over size
        size = int(n_rest[small].max())
        rows = np.argsort(~rest_rows[small], axis=1, kind="stable")[:, :size]
        cols = np.argsort(~rest_cols[small], axis=1, kind="stable")[:, :size]
        sub = np.zeros((small.size, size, size))
        w = weight[small[:, None, None], rows[:, :, None], cols[:, None, :]]
        ok = (np.take_along_axis(rest_rows[small], rows, axis=1)[:, :, None]
              & np.take_along_axis(rest_cols[small], cols, axis=1)[:, None, :])
        sub[:, :rows.shape[1], :cols.shape[1]] = np.where(ok, w, 0.0)
        total, perm = _every_permutation(-sub)
        gain[small] -= total
        r_in = np.arange(rows.shape[1])
        c_in = perm[:, :rows.shape[1]]
        chosen = (c_in < cols.shape[1]) & (np.take_along_axis(sub[:, :rows.shape[1]], c_in[..., None], axis=2)[..., 0] > 0)
        b_i, r_i = np.nonzero(chosen)
        match[small[b_i], rows[b_i, r_in[r_i]]] = cols[b_i, c_in[b_i, r_i]]
    for b in np.flatnonzero(n_rest > BRUTE_FORCE_MAX):
        rows, cols = np.flatnonzero(rest_rows[b]), np.flatnonzero(rest_cols[b])
        w = weight[b][rows][:, cols]
        r, c = linear_sum_assignment(w, maximize=True)
        used = w[r, c] > 0
        match[b, rows[r[used]]] = cols[c[used]]
        gain[b] += w[r[used], c[used]].sum()
    total = np.maximum(n_rows, n_cols).reshape(-1) * unmatched - gain
    return total.reshape(lead), match.reshape(lead + (m,))


def _gospa_switching_single(tracks, truths, cutoff: float, order: float = 2.0, switch_penalty: float | None = None,
                            track_ids=None, truth_ids=None, angular: bool = False, per: str = "track",
                            view: SinglePair | None = None) -> dict:
    """:func:`gospa_switching` of sets of one track and one target slot ``(R, K, 1, d)`` whose
    identities are one per run (:func:`one_identity_per_run`, both sides), from the distance
    of the one pair per (run, scan) (``view``, :func:`single_pair_view` of the same sets, when
    already found): the assignment is the pair when both are present and closer than c, and an
    identity's state changes between assigned and unassigned only, one half switch each
    time. The same arithmetic as the one-element assignment, so the same values."""
    if per not in ("track", "truth"):
        raise ValueError(f"per must be 'track' or 'truth', not {per!r}")
    gamma = float(cutoff if switch_penalty is None else switch_penalty)
    X, Y = np.asarray(tracks, float), np.asarray(truths, float)
    if view is None:
        view = single_pair_view(X, Y, track_ids, truth_ids, angular)
    # GOSPA takes track − target: the view's distance (target − track) is the same number, but a
    # wrapped angle may round apart
    d = single_pair_distance(X, Y, angular) if angular else view.distance
    # GOSPA counts every finite element, whatever its identity
    vx, vy = view.track_finite, view.truth_finite
    both = vx & vy
    either = vx | vy
    cp = cutoff ** order
    # the one-element assignment's total: the pair's capped cost, c^p with one element, 0 with none
    total = np.where(both, np.minimum(np.where(both, d, 0.0), cutoff) ** order, np.where(either, cp, 0.0))
    close = both & (d < cutoff)
    m_count, n_count = vx.astype(np.int64), vy.astype(np.int64)
    assigned = close.astype(np.int64)
    loc = np.where(close, d ** order, 0.0)
    # |m − n| is 1 where one element is alone, else 0 (a bool times a float: the same numbers)
    g = np.maximum(total - cp / 2 * (vx != vy), 0.0) ** (1 / order)
    # max(m, n) is 1 wherever either is present, and total / 1 is total
    ospa = np.where(either, total ** (1 / order), 0.0)
    parts = {"gospa": g, "localisation": loc ** (1 / order), "missed": n_count - assigned,
             "false": m_count - assigned, "ospa": ospa, "assigned": assigned}
    # the followed identity's presences; its state is assigned or not (one partner per run)
    present = view.track_present if per == "track" else view.truth_present
    half = _single_half_switches(present, close & present)
    term = gamma ** order / 2 * half
    parts["half_switches"] = half
    parts["switching"] = term ** (1 / order)
    parts["gospa_switching"] = (g ** order + term) ** (1 / order)
    return parts


def scan_index_type(K: int):
    """The smallest signed integer type that holds a scan index −1…K (a quarter or less of
    int64's bytes for the scan accumulations of the single-target forms)."""
    return next(t for t in (np.int8, np.int16, np.int32, np.int64) if K < np.iinfo(t).max)


def scans_where(mask, fill: int):
    """``np.where(mask, scans, fill)`` for a mask (R, K) over scans 0…K−1 and ``fill`` −1 or K,
    in :func:`scan_index_type`: by arithmetic (``mask · (scan + 1) − 1``, ``K − mask · (K −
    scan)``), as a broadcast ``np.where`` of small integers costs some twenty times as much."""
    K = mask.shape[-1]
    kind = scan_index_type(K)
    scans = np.arange(K, dtype=kind)
    if fill == -1:
        out = np.multiply(mask, scans + kind(1), dtype=kind)
        out -= kind(1)
    elif fill == K:
        out = np.multiply(mask, kind(K) - scans, dtype=kind)
        np.subtract(kind(K), out, out=out)
    else:
        raise ValueError(f"fill must be -1 or K = {K}, not {fill}")
    return out


def or_accumulate(mask, axis: int = 1):
    """``np.logical_or.accumulate(mask, axis)`` of a bool array, as the running maximum of its
    bytes (0 or 1), which numpy computes at a fraction of the cost."""
    return np.maximum.accumulate(np.asarray(mask, bool).view(np.uint8), axis=axis).view(bool)


def _single_half_switches(present, assigned) -> np.ndarray:
    """Half switches (R, K) of one identity per run present at ``present`` (R, K) and assigned
    at ``assigned``: a change of state between consecutive presences, from its first
    assignment on, charged at the later one (:func:`gospa_switching`)."""
    R, K = present.shape
    # the latest presence at or before each scan, and the latest assigned one: the state at the
    # latest presence is "assigned" when the two are the same scan
    latest = np.maximum.accumulate(scans_where(present, -1), axis=1)
    latest_assigned = np.maximum.accumulate(scans_where(present & assigned, -1), axis=1)
    out = np.zeros((R, K), np.int64)
    # from the second scan on, against the latest presence before it (k − 1's latest at or before)
    now, before = (slice(None), slice(1, None)), (slice(None), slice(None, -1))
    change = present[now] & (latest[before] >= 0) & (assigned[now] != (latest_assigned[before] == latest[before]))
    # … from the identity's first assignment on (any assignment before the scan)
    change &= or_accumulate(assigned)[before]
    out[now] = change
    return out


def _global_identities_sorted(value, present, low, span):
    """:func:`global_identities` by sorting the (run, identity) keys: any range of identities."""
    r, k, j = np.nonzero(present)
    key = r.astype(np.int64) * span + (value[r, k, j] - low)
    out = np.full(present.shape, -1, np.int64)
    uniq, inverse = np.unique(key, return_inverse=True)
    out[r, k, j] = inverse
    return out, uniq.size, uniq // span


def _close_pairs_windowed(X, Y, radius: float, angular: bool = False):
    """:func:`close_pairs` from the rows of ``Y`` within a window along one component.

    A pair closer than ``radius`` is closer than ``radius`` along every component, so the rows
    of ``Y`` are sorted along one (the one they spread most along: fewest candidates) and each
    row of ``X`` takes those of its problem within ``radius`` of it there, by binary search;
    only these candidates get a distance, summed component by component with the very
    operations of :func:`_close_pairs_dense` and kept by the same two tests, so the pairs and
    the distances are bit for bit the same. Problems go through in blocks of
    :data:`WINDOW_BLOCK_ROWS` rows (see :func:`_window_block`).
    """
    P, m, n = X.shape[0], X.shape[1], Y.shape[1]
    d = min(X.shape[-1], Y.shape[-1])
    X, Y = X[..., :d], Y[..., :d]
    step = max(1, WINDOW_BLOCK_ROWS // max(m, n, 1))
    parts = []
    for a in range(0, P, step):
        p, i, j, dist = _window_block(X[a:a + step], Y[a:a + step], radius, angular)
        parts.append((p + a, i, j, dist))
    if not parts:
        return _no_pairs()
    return tuple(np.concatenate(column) for column in zip(*parts))


#: rows of a block of problems of :func:`_close_pairs_windowed`: its keys stay exact to far
#: below the window's margin
WINDOW_BLOCK_ROWS = 1 << 18
#: candidate pairs :func:`_window_block` measures at once (8 MB an array)
WINDOW_CANDIDATES = 1 << 20


def _window_block(X, Y, radius, angular):
    """:func:`_close_pairs_windowed` on one block of problems (P, m, d), (P, n, d).

    All problems share one sorted order: the key of a row is ``problem · spacing + position``
    along the window's component, and the spacing leaves more than a window between two
    problems. The window is widened by a margin far above the rounding of the keys and of the
    differences (2⁻³⁰ of the largest key against 2⁻⁵³), so it holds every pair the exact test
    keeps. On a circle the positions are first brought to [−π, π) and every row of ``Y`` also
    stands one turn below and one above (three copies), so a window near ±π reaches across;
    the window, shorter than a turn, holds one copy of a row at most.
    """
    P, m, n = X.shape[0], X.shape[1], Y.shape[1]
    d = X.shape[-1]
    x_present, y_present = all_finite(X), all_finite(Y)
    x_at_rows = np.flatnonzero(x_present)
    y_at_rows = np.flatnonzero(y_present)
    if x_at_rows.size == 0 or y_at_rows.size == 0:
        return _no_pairs()
    px, ix = np.divmod(x_at_rows, m)
    py, jy = np.divmod(y_at_rows, n)
    xs = X.reshape(-1, d)[x_at_rows].T.copy()                      # present rows, a component each
    ys = Y.reshape(-1, d)[y_at_rows].T.copy()
    turn = 2 * np.pi
    if angular:
        x_at = np.mod(xs[0] + np.pi, turn) - np.pi
        y_once = np.mod(ys[0] + np.pi, turn) - np.pi
        y_at = np.concatenate([y_once - turn, y_once, y_once + turn])
        y_row, y_problem = np.tile(np.arange(py.size), 3), np.tile(py, 3)
        # the reduction to [−π, π) rounds relative to the raw angles
        raw = max(float(np.max(np.abs(xs[0]))), float(np.max(np.abs(ys[0])))) + turn
    else:
        axis = int(np.argmax([np.ptp(v) for v in ys]))
        x_at, y_at = xs[axis], ys[axis]
        y_row, y_problem = np.arange(py.size), py
        raw = 0.0
    low = min(float(x_at.min()), float(y_at.min()))
    extent = max(float(x_at.max()), float(y_at.max())) - low
    spacing = 2 * (extent + 2 * radius)
    margin = 2.0 ** -30 * (P * spacing + radius) + 2.0 ** -40 * raw
    width = radius + margin
    if margin >= extent + 3 * radius or (angular and width >= np.pi):
        # a margin too wide for the spacing or a window as long as a turn: every pair instead
        return _close_pairs_dense(X, Y, radius, angular)
    y_key = y_problem * spacing + (y_at - low)
    x_key = px * spacing + (x_at - low)
    copies = y_at.size // max(py.size, 1)
    if angular:
        by_key = _order_within_problems(y_at, y_problem, np.concatenate([jy + c * n for c in range(copies)]),
                                        copies * n, P)
        start = np.searchsorted(y_key[by_key], x_key - width, side="left")
        count = np.searchsorted(y_key[by_key], x_key + width, side="right") - start
    else:
        # both sides in (problem, position) order, each problem's rows sorted on their own; the
        # window's ends are searched for in increasing order, which numpy's binary search walks
        # about twice as fast as the rows' own order (each x row's window is the same whatever
        # the order of the searches, and so is the set of rows in it whatever the order of equal
        # keys)
        by_key = _rows_by_position(Y[..., axis], y_present)
        x_order = _rows_by_position(X[..., axis], x_present)
        y_key = y_key[by_key]
        queries = x_key[x_order]
        start, count = np.empty(px.size, np.int64), np.empty(px.size, np.int64)
        start[x_order] = np.searchsorted(y_key, queries - width, side="left")
        count[x_order] = np.searchsorted(y_key, queries + width, side="right")
        count -= start
    # the rows of X in pieces of about WINDOW_CANDIDATES candidates: the memory stays bounded
    # however wide the windows are against the spread of the rows
    ends = np.cumsum(count)
    cuts = np.unique(np.r_[0, np.searchsorted(ends, np.arange(WINDOW_CANDIDATES, ends[-1], WINDOW_CANDIDATES)),
                           px.size])
    wide = radius * radius * (1 + 8 * np.finfo(float).eps)
    found, distances = [], []
    for lo, hi in zip(cuts[:-1], cuts[1:]):
        piece = count[lo:hi]
        total = int(piece.sum())
        if total == 0:
            continue
        # the candidates: each row of X with every row of Y in its window
        row = np.repeat(np.arange(lo, hi), piece)
        at = np.arange(total) + np.repeat(start[lo:hi] - (np.cumsum(piece) - piece), piece)
        other = y_row[by_key[at]]
        # the squared distance a component at a time, as _close_pairs_dense sums it
        t = np.zeros(total)
        for xc, yc in zip(xs, ys):
            _add_square(t, xc[row] - yc[other], angular)
        near = np.flatnonzero(t < wide)
        dist = np.sqrt(t[near])
        keep = dist < radius
        near, dist = near[keep], dist[keep]
        found.append((px[row[near]] * m + ix[row[near]]) * n + jy[other[near]])
        distances.append(dist)
    if not found:
        return _no_pairs()
    flat, dist = np.concatenate(found), np.concatenate(distances)
    # in (problem, i) order already, each row's pairs by position along the window: a stable
    # sort (a merge of sorted runs) puts them in j order
    by = np.argsort(flat, kind="stable")
    flat, dist = flat[by], dist[by]
    p, ij = np.divmod(flat, m * n)
    i, j = np.divmod(ij, n)
    return p, i, j, dist
#: keys of one block of runs there (32 MB of counts)
DENSE_PAIRS_BLOCK = 1 << 22


def _identity_pairs_dense(first, local, run, first_start, per_run):
    """:func:`identity_pairs` of events in run order: each block of runs' pairs counted with one
    ``bincount`` over the block's (first, local second) keys, whose nonzero entries are the
    pairs, in order."""
    R = first_start.size - 1
    cuts, keys = [0], 0
    for r, n in enumerate((np.diff(first_start) * per_run).tolist()):
        # blocks of whole runs, each within DENSE_PAIRS_BLOCK keys (or one run)
        if keys + n > DENSE_PAIRS_BLOCK and r > cuts[-1]:
            cuts.append(r)
            keys = 0
        keys += n
    cuts.append(R)
    event_cuts = np.searchsorted(run, cuts)
    pair_first, pair_local, counts = [], [], []
    inverse = np.empty(run.size, np.int64)
    found = 0
    for (a, b), (ea, eb) in zip(zip(cuts[:-1], cuts[1:]), zip(event_cuts[:-1], event_cuts[1:])):
        base = int(first_start[a])
        key = (first[ea:eb] - base) * per_run + local[ea:eb]
        count = np.bincount(key, minlength=(int(first_start[b]) - base) * per_run)
        at = np.flatnonzero(count != 0)          # the bytes of a mask scan faster than the counts
        number = np.empty(count.size, np.int64)        # each key's pair: the rank of its entry
        number[at] = np.arange(found, found + at.size)
        inverse[ea:eb] = number[key]
        pair_first.append(at // per_run + base)
        pair_local.append(at % per_run)
        counts.append(count[at])
        found += at.size
    return np.concatenate(pair_first), np.concatenate(pair_local), inverse, np.concatenate(counts)


def _rows_by_position(position, present) -> np.ndarray:
    """The present rows of a block (``position`` (P, m) along the window's component, ``present``
    (P, m)), numbered 0… in (problem, row) order, listed in the order of (problem, position):
    :func:`_order_within_problems` of rows that each keep their own column, from one short sort
    per problem straight on the block."""
    P, m = present.shape
    order = np.argsort(np.where(present, position, np.inf), axis=1)
    order += (np.arange(P) * m)[:, None]
    flat = order.reshape(-1)
    number = np.cumsum(present.reshape(-1)) - 1                    # each present row's number
    return number[flat[present.reshape(-1)[flat]]]


def _order_within_problems(position, problem, column, columns: int, P: int) -> np.ndarray:
    """The entries (``position`` in ``problem`` 0…P−1, each at its own ``column`` < ``columns``
    of its problem) in the order of (problem, position): what ``argsort`` of
    ``problem · spacing + position`` gives, up to the order of equal keys, from one short sort
    per problem on a (P, columns) table instead of one sort of every entry."""
    table = np.full((P, columns), np.inf)
    table[problem, column] = position
    entry = np.full((P, columns), -1, np.int64)
    entry[problem, column] = np.arange(position.size)
    ordered = np.take_along_axis(entry, np.argsort(table, axis=1), axis=1).reshape(-1)
    return ordered[ordered >= 0]


def _no_pairs():
    """:func:`close_pairs`'s answer when no pair is close."""
    empty = np.zeros(0, np.intp)
    return empty, empty.copy(), empty.copy(), np.zeros(0)


#: edges up to which :func:`_bipartite_components` labels by propagation (beyond: scipy's search,
#: whose fixed cost per call is above a small graph's whole work)
PROPAGATION_MAX_EDGES = 1 << 12
#: rounds of propagation before it leaves a long chain to scipy
PROPAGATION_ROUNDS = 24


def _bipartite_components(r_node, c_node, n_rows: int, n_cols: int):
    """Connected components of the graph of rows 0…n_rows−1 and columns 0…n_cols−1 joined by the
    edges (``r_node``, ``c_node``): their number and each node's (rows first, then columns),
    numbered in the order of their smallest node.

    A small graph is labelled by propagating the smallest node number along the edges, each
    round followed by one pointer jump (label of the label), until nothing changes: a few
    rounds where the components are a handful of nodes, as here. A larger one, or one that
    has not settled after :data:`PROPAGATION_ROUNDS` rounds, goes to
    ``scipy.sparse.csgraph.connected_components``; the partition is the same either way, and
    the numbering (by smallest node) too.
    """
    nodes = n_rows + n_cols
    a, b = np.asarray(r_node), n_rows + np.asarray(c_node)
    if a.size <= PROPAGATION_MAX_EDGES:
        label = np.arange(nodes)
        for _ in range(PROPAGATION_ROUNDS):
            low = np.minimum(label[a], label[b])
            new = label.copy()
            np.minimum.at(new, a, low)
            np.minimum.at(new, b, low)
            new = new[new]
            if np.array_equal(new, label):
                return _numbered(label, nodes)
            label = new
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    graph = coo_matrix((np.ones(a.size, bool), (a, b)), shape=(nodes, nodes))
    n_comp, label = connected_components(graph, directed=False)
    label = label.astype(np.int64, copy=False)
    if nodes and label[0] == 0 and np.all(np.diff(np.maximum.accumulate(label)) <= 1):
        return n_comp, label         # already numbered by smallest node (each first seen in node order)
    # numbered as the search met them: renumbered by their smallest node
    smallest = np.full(n_comp, nodes, np.int64)
    np.minimum.at(smallest, label, np.arange(nodes))
    return _numbered(smallest[label], nodes)


def _numbered(label, n: int):
    """Labels (values below n) renumbered 0… in increasing order: their count and the labels."""
    number, count = _compact(label, n)
    return count, number
