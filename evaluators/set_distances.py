"""OSPA and GOSPA between the set of track estimates and the set of true targets, per scan.

* OSPA (Schuhmacher, Vo & Vo 2008): for |X| = m ≤ n = |Y|,
  ``d = ((1/n)(min_π Σ_i min(d(x_i, y_π(i)), c)^p + c^p (n − m)))^(1/p)``.
* GOSPA with α = 2 (Rahmathullah, García-Fernández & Svensson 2017, eq. 2 and Prop. 1):
  ``d = (min_γ Σ_{(i,j)∈γ} d(x_i, y_j)^p + (c^p/2)(|X| + |Y| − 2|γ|))^(1/p)`` over partial
  assignments γ; it splits into localisation, missed-target and false-track parts.
* per-scan switching (:func:`gospa_switching`): GOSPA plus a charge γ^p/2 per half switch of
  the per-scan assignments between scans (in the spirit of trajectory GOSPA, García-Fernández,
  Rahmathullah & Svensson 2020, but not its joint optimisation over scans).

Both reduce to one assignment on the cost ``min(d, c)^p``: a pair at or beyond the cut-off ``c``
costs as much as leaving both unassigned. Sets are padded arrays with NaN rows for absent
elements, so whole data sets are scored at once: small sets (≤ ``BRUTE_FORCE_MAX`` elements on
the larger side) by evaluating every permutation in one numpy expression, larger ones with
``scipy.optimize.linear_sum_assignment`` per scan. See ``docs/evaluation.md``.

This module holds the plain public forms; the fast forms they turn to (every permutation at once,
the sparse assignment, the windowed search for close pairs, the single-target switching GOSPA,
the dense count of identity pairs, connected components by propagation) are in
:mod:`trackreplay.evaluators.set_distances_fast`, each tested against the plain form it stands
for (tests/test_evaluator_speed_equivalence.py, tests/test_evaluation_speed_paths.py).
"""

from __future__ import annotations

import numpy as np

from trackreplay.batched_linalg import all_finite
# the fast forms the plain ones turn to; they import the small shared pieces, never this module
from trackreplay.evaluators import set_distances_fast as _fast
from trackreplay.evaluators.set_distances_shared import BRUTE_FORCE_MAX, _close_pairs_dense, _compact

def pairwise_distance(tracks, truths, angular: bool = False) -> np.ndarray:
    """Euclidean distances ``(..., m, n)`` between padded sets ``(..., m, d)`` and ``(..., n, d)``.

    With ``angular`` the components are angles and differences wrap to (−π, π].
    """
    X, Y = np.asarray(tracks, float), np.asarray(truths, float)
    # a component at a time, left to right (the sum of trackreplay.batched_linalg.sum_squares, bit
    # for bit): no (..., m, n, d) difference array with a short strided last axis
    total = np.zeros(np.broadcast_shapes(X.shape[:-2], Y.shape[:-2]) + (X.shape[-2], Y.shape[-2]))
    for i in range(X.shape[-1]):
        diff = X[..., :, None, i] - Y[..., None, :, i]
        if angular:
            diff = (diff + np.pi) % (2 * np.pi) - np.pi
        total += diff * diff
    return np.sqrt(total, out=total)


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
    if size > BRUTE_FORCE_MAX:
        valid_r = np.broadcast_to(valid_rows, lead + (m,))
        valid_c = np.broadcast_to(valid_cols, lead + (n,))
        pair = valid_r[..., :, None] & valid_c[..., None, :]
        if np.all(np.where(pair, cost, unmatched) <= unmatched):
            # every pair costs at most leaving its two elements unmatched (capped distances,
            # negated similarities): a sparse matching problem, mostly solved without a search
            return _fast._sparse_assignment(cost, pair, valid_r.sum(axis=-1), valid_c.sum(axis=-1), float(unmatched))
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
        total, cols = _fast._every_permutation(full.reshape(-1, size, size))
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
    return _gospa_and_assignment(tracks, truths, cutoff, order, angular)[0]


def _gospa_and_assignment(tracks, truths, cutoff, order, angular):
    """:func:`gospa`'s dict and its assignment: the truth column of each track row (..., m),
    −1 where the track is not assigned to a truth closer than c."""
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
    parts = {"gospa": g, "localisation": loc ** (1 / order), "missed": n_count - assigned,
             "false": m_count - assigned, "ospa": ospa, "assigned": assigned}
    return parts, np.where(close, match, -1)


#: values of the largest (problems, m, n) distance block :func:`gospa_switching` holds at once
def _gospa_sparse(X, Y, cutoff, order, angular):
    """:func:`gospa`'s parts and assignment of every problem (P, m, d), (P, n, d) from the pairs
    closer than c alone (:func:`close_pairs`, :func:`assign_edges`): GOSPA^p is
    ``max(|X|, |Y|)·c^p − Σ (c^p − d^p)`` over the assigned pairs, less ``(c^p/2)·||X| − |Y||``."""
    P, m = X.shape[:2]
    cp = cutoff ** order
    p, i, j, d = close_pairs(X, Y, cutoff, angular)
    dp = d ** order
    chosen = assign_edges(p, i, j, cp - dp, m, Y.shape[1])
    pc = p[chosen]
    m_count, n_count = all_finite(X).sum(axis=-1), all_finite(Y).sum(axis=-1)
    assigned = np.bincount(pc, minlength=P)
    loc = np.bincount(pc, weights=dp[chosen], minlength=P)
    big = np.maximum(m_count, n_count)
    total = big * cp - np.bincount(pc, weights=cp - dp[chosen], minlength=P)
    g = np.maximum(total - cp / 2 * np.abs(m_count - n_count), 0.0) ** (1 / order)
    ospa = np.where(big > 0, (np.maximum(total, 0.0) / np.maximum(big, 1)) ** (1 / order), 0.0)
    match = np.full((P, m), -1, np.intp)
    match[pc, i[chosen]] = j[chosen]
    return {"gospa": g, "localisation": loc ** (1 / order), "missed": n_count - assigned,
            "false": m_count - assigned, "ospa": ospa, "assigned": assigned}, match


SWITCHING_BLOCK = 1 << 20


def gospa_switching(tracks, truths, cutoff: float, order: float = 2.0, switch_penalty: float | None = None,
                    track_ids=None, truth_ids=None, angular: bool = False, per: str = "track") -> dict:
    """Per-scan GOSPA with a switching term computed from the per-scan assignments.

    This is **per-scan switching, not trajectory GOSPA**. Trajectory GOSPA (García-Fernández,
    Rahmathullah & Svensson 2020, *IEEE Trans. Signal Process.* 68, eq. 4) optimises one
    assignment per scan jointly over the whole run with a cost for changing it; here each
    scan keeps GOSPA's own optimal assignment (Rahmathullah, García-Fernández & Svensson 2017)
    and the changes of that assignment between scans are charged afterwards, as Stone Soup's
    ``GOSPAMetric(switching_penalty=γ)`` does.

    **Half switches.** Follow one identity (a track identity with ``per="track"``, a truth
    identity with ``per="truth"``) over the scans at which it is present. At each such scan it
    is either assigned to an identity of the other side (a pair of GOSPA's assignment closer than
    c) or unassigned. From its first assigned scan on, each change of that state between two
    consecutive scans of its presence counts

    * 2 half switches (one switch) when it goes from one assigned identity to another,
    * 1 half switch when it goes from assigned to unassigned or from unassigned to assigned;

    staying the same counts none. The scans before its first assignment count none (a track
    still converging, a target not yet tracked: GOSPA's false and missed parts charge those
    scans already), and neither do the scans it is absent (a gap is not a switch). A change is
    charged at the later of the two scans.

    Per scan, the switching part is ``(γ^p/2)·h`` with ``h`` the half switches charged there,
    and ``gospa_switching = (GOSPA^p + (γ^p/2)·h)^(1/p)``. So a switch costs γ^p, twice the
    γ^p/2 of trajectory GOSPA's s(π^k, π^{k+1}) = 1; a half switch costs γ^p/2 (Stone Soup's
    factor). The default γ = c makes a switch cost as much as one pair at the cut-off.

    Parameters
    ----------
    tracks : ndarray (R, K, m, d)
        Track estimates; rows with NaN are absent.
    truths : ndarray (R, K, n, d)
        True states in the same space; rows with NaN are absent.
    cutoff, order : float
        GOSPA's ``c`` and ``p``.
    switch_penalty : float, optional
        γ (≥ 0), in the units of the space; default ``cutoff``.
    track_ids : ndarray of int (R, K, m), optional
        Track identity per slot (−1 empty); default: the slot.
    truth_ids : ndarray of int (R, K, n), optional
        Target identity per slot (−1 empty); default: the slot. Identities are unique within a scan.
    angular : bool
    per : {"track", "truth"}
        Whose assignment history is followed.

    Returns
    -------
    dict of ndarray (R, K)
        :func:`gospa`'s parts (``gospa``, ``localisation``, ``missed``, ``false``, ``ospa``,
        ``assigned``), ``half_switches``, ``switching`` = ``((γ^p/2)·h)^(1/p)`` and
        ``gospa_switching``.
    """
    if per not in ("track", "truth"):
        raise ValueError(f"per must be 'track' or 'truth', not {per!r}")
    gamma = float(cutoff if switch_penalty is None else switch_penalty)
    X, Y = np.asarray(tracks, float), np.asarray(truths, float)
    R, K, m = X.shape[:3]
    n = Y.shape[2]
    flat = lambda a: a.reshape((R * K,) + a.shape[2:])
    Xf, Yf = flat(X), flat(Y)
    if max(m, n) > BRUTE_FORCE_MAX:
        parts, match = _gospa_sparse(Xf, Yf, cutoff, order, angular)
    else:
        # small sets: :func:`gospa`'s own assignment (bit for bit its values), in blocks of
        # (run, scan) problems (each is its own problem)
        parts, match = None, np.empty((R * K, m), np.intp)
        step = max(1, SWITCHING_BLOCK // max(m * n, 1))
        for a in range(0, R * K, step):
            block = slice(a, a + step)
            p, match[block] = _gospa_and_assignment(Xf[block], Yf[block], cutoff, order, angular)
            if parts is None:
                parts = {key: np.empty((R * K,), v.dtype) for key, v in p.items()}
            for key, v in p.items():
                parts[key][block] = v
    parts = {key: v.reshape(R, K) for key, v in parts.items()}
    match = match.reshape(R, K, m)

    track_id = np.where(all_finite(X), np.arange(m), -1) if track_ids is None else np.asarray(track_ids)
    truth_id = np.where(all_finite(Y), np.arange(n), -1) if truth_ids is None else np.asarray(truth_ids)
    # the identity of the other side assigned to each present element, −1 for none
    if per == "track":
        own, present = track_id, all_finite(X) & (track_id >= 0)
        partner = np.where(match >= 0, np.take_along_axis(truth_id, np.maximum(match, 0), axis=-1), -1)
    else:
        own, present = truth_id, all_finite(Y) & (truth_id >= 0)
        back = np.full((R, K, n), -1, np.intp)
        r_i, k_i, j_i = np.nonzero(match >= 0)
        back[r_i, k_i, match[r_i, k_i, j_i]] = j_i
        partner = np.where(back >= 0, np.take_along_axis(track_id, np.maximum(back, 0), axis=-1), -1)
    half = _half_switches(own, partner, present)
    term = gamma ** order / 2 * half
    parts["half_switches"] = half
    parts["switching"] = term ** (1 / order)
    parts["gospa_switching"] = (parts["gospa"] ** order + term) ** (1 / order)
    return parts


def one_identity_per_run(ids, present) -> bool:
    """Whether every run's identities ``(R, K, 1)`` are one value wherever ``present`` and ≥ 0
    exactly there (None: the slot's own identity, one per run): the case the single-target
    forms (:func:`_gospa_switching_single` and those beside the assignment metrics, HOTA and
    SIAP) take."""
    if ids is None:
        return True
    ids = np.asarray(ids)[:, :, 0]
    present = np.asarray(present)[:, :, 0] if np.ndim(present) == 3 else np.asarray(present)
    if not np.array_equal(ids >= 0, present):
        return False
    low = np.min(np.where(present, ids, np.iinfo(np.int64).max), axis=1, initial=np.iinfo(np.int64).max)
    high = np.max(np.where(present, ids, -1), axis=1, initial=-1)
    return bool(np.all((high == low) | (high < 0)))


def global_identities(ids, present):
    """Identities (R, K, n) numbered 0…N−1 across runs in (run, identity) order (the same
    identity in two runs is two), −1 where not ``present``; N; and the run of each."""
    present = np.asarray(present, bool)
    ids = np.asarray(ids)
    R = present.shape[0]
    if not present.any():
        return np.full(present.shape, -1, np.int64), 0, np.zeros(0, np.int64)
    if ids.dtype != np.int64:
        ids = ids.astype(np.int64)
    top = np.iinfo(np.int64).max
    low = int(np.min(ids, where=present, initial=top))
    span = int(np.max(ids, where=present, initial=low)) - low + 1
    if R * span <= 1 << 26:
        # (run, identity) as one integer, numbered by marking: no list of the present elements;
        # the absent ones all get the key R · span, numbered −1
        key = ids + (np.arange(R, dtype=np.int64) * span - low).reshape((R,) + (1,) * (present.ndim - 1))
        np.copyto(key, R * span, where=~present)
        mark = np.zeros(R * span + 1, bool)
        mark[key] = True
        mark[-1] = False
        marked = np.flatnonzero(mark)
        # each marked key's number, written where it is marked only (the untouched pages of the
        # zeroed table cost nothing, where a running count would write all R · span entries)
        number = np.zeros(R * span + 1, np.int64)
        number[marked] = np.arange(marked.size)
        number[-1] = -1
        return number[key], marked.size, marked // span
    return _fast._global_identities_sorted(np.where(present, ids, 0), present, low, span)


def stable_order(keys, n: int) -> np.ndarray:
    """``np.argsort(keys, kind="stable")`` of integers in [0, n): the same permutation (a stable
    sort has one answer), by numpy's radix sort on 16-bit digits (least significant first)
    where n allows, several times faster than the merge sort it uses on wider integers."""
    keys = np.asarray(keys)
    if n <= 1 << 16:
        return np.argsort(keys.astype(np.uint16), kind="stable")
    if n <= 1 << 32:
        order = np.argsort((keys & 0xFFFF).astype(np.uint16), kind="stable")
        return order[np.argsort((keys[order] >> 16).astype(np.uint16), kind="stable")]
    return np.argsort(keys, kind="stable")


def unique_pairs(first, second, n_second: int):
    """The distinct pairs ``first · n_second + second`` (integers ≥ 0) in increasing order, the
    index of each element's pair and each pair's count: ``np.unique(..., return_inverse=True,
    return_counts=True)`` of those keys, through :func:`stable_order`."""
    key = np.asarray(first, np.int64) * max(n_second, 1) + np.asarray(second, np.int64)
    if key.size == 0:
        return key, np.zeros(0, np.int64), np.zeros(0, np.int64)
    order = stable_order(key, int(key.max()) + 1)
    ordered = key[order]
    new = np.empty(key.size, bool)
    new[0] = True
    np.not_equal(ordered[1:], ordered[:-1], out=new[1:])
    number = np.cumsum(new) - 1
    inverse = np.empty(key.size, np.int64)
    inverse[order] = number
    starts = np.flatnonzero(new)
    return ordered[starts], inverse, np.diff(np.append(starts, key.size))


def _half_switches(own, partner, present) -> np.ndarray:
    """Half switches charged per (run, scan) (R, K) from each present identity's partner
    history (see :func:`gospa_switching`)."""
    R, K = present.shape[:2]
    r, k, j = np.nonzero(present)                                   # in (run, scan) order
    number, _, _ = global_identities(own, present)                  # in (run, identity) order
    ident, state = number[r, k, j], partner[r, k, j]
    order = stable_order(ident, int(ident.max()) + 1 if ident.size else 0)   # scans stay in order
    r, k, ident, state = r[order], k[order], ident[order], state[order]
    same = np.zeros(r.size, bool)
    same[1:] = (r[1:] == r[:-1]) & (ident[1:] == ident[:-1])
    # from the first assigned scan of each identity on
    first = ~same
    group = np.cumsum(first) - 1
    assigned_so_far = np.maximum.accumulate(np.where(state >= 0, np.arange(r.size), -1))
    started_before = np.zeros(r.size, bool)
    started_before[1:] = assigned_so_far[:-1] >= np.flatnonzero(first)[group][1:]
    prev = np.concatenate([[-1], state[:-1]])
    changed = same & started_before & (state != prev)
    halves = np.where(changed, np.where((state >= 0) & (prev >= 0), 2, 1), 0)
    return np.bincount(r * K + k, weights=halves, minlength=R * K).reshape(R, K).astype(np.int64)


def close_pairs(X, Y, radius: float, angular: bool = False):
    """Every pair of present rows of ``X`` (P, m, d) and ``Y`` (P, n, d) of the same problem closer
    than ``radius``; a row with a NaN is absent.

    Targets and tracks are mostly far apart, so the few close pairs carry everything an
    assignment needs (a pair at or beyond the cut-off costs as much as no pair). The pairs are
    those of :func:`_close_pairs_dense`, which tries every pair (the plain form, and the reference
    the fast one is tested against); :func:`_close_pairs_windowed` finds the same pairs from the
    rows within ``radius`` along one component, and is used wherever a window can be set.

    Returns
    -------
    problem, i, j : ndarray of int (E,)
        Problem, row of ``X`` and row of ``Y`` of each close pair, sorted by problem, ``i``, ``j``.
    distance : ndarray (E,)
        Their distances (bit for bit those of :func:`pairwise_distance`).
    """
    X, Y = np.asarray(X, float), np.asarray(Y, float)
    d = min(X.shape[-1], Y.shape[-1])
    # a window needs a finite radius whose square is a normal number (a square of a component
    # then never rounds below it) and a component to slide along; on a circle it must be
    # shorter than a turn, so that a row of Y falls in it once at most
    windowed = (WINDOW_RADIUS_MIN <= radius < np.inf and d > 0
                and (not angular or radius < WINDOW_ANGULAR_MAX))
    return (_fast._close_pairs_windowed if windowed else _close_pairs_dense)(X, Y, radius, angular)


#: the largest radius (radians) :func:`_close_pairs_windowed` takes on a circle: its window
#: (radius and a margin either side) stays shorter than a turn
WINDOW_ANGULAR_MAX = 3.0
#: the smallest radius it takes: below, the square of a difference may underflow
WINDOW_RADIUS_MIN = float(np.sqrt(np.finfo(float).tiny))


def identity_pairs(first, second, first_run, second_run):
    """The distinct (first, second) identity pairs of a list of events, as :func:`unique_pairs`
    of ``first · N₂ + second`` (N₂ the number of second identities) would give them: sorted by
    ``first`` then ``second``, each event's pair and each pair's count.

    Both identities are numbered across runs in run order (:func:`global_identities`) and an
    event pairs identities of one run, so ``second`` is keyed by its number within its run: the
    keys then stay far smaller (fewer radix passes) and sort the same.

    Returns
    -------
    pair_first, pair_second, inverse, count : ndarray of int
    """
    first, second = np.asarray(first, np.int64), np.asarray(second, np.int64)
    second_run = np.asarray(second_run)
    R = int(max(np.max(first_run, initial=-1), np.max(second_run, initial=-1))) + 1
    start = np.searchsorted(second_run, np.arange(R))                # each run's first second identity
    per_run = max(int(np.max(np.diff(np.append(start, second_run.size)), initial=0)), 1)
    first_run = np.asarray(first_run)
    run = first_run[first]
    local = second - start[run]
    first_start = np.searchsorted(first_run, np.arange(R + 1))
    space = int(first_start[-1]) * per_run
    if run.size and space <= DENSE_PAIRS_PER_EVENT * run.size and np.all(run[1:] >= run[:-1]):
        pair_first, pair_local, inverse, count = _fast._identity_pairs_dense(first, local, run, first_start, per_run)
    else:
        keys, inverse, count = unique_pairs(first, local, per_run)
        pair_first, pair_local = keys // per_run, keys % per_run
    return pair_first, pair_local + start[first_run[pair_first]], inverse, count


#: :func:`identity_pairs` counts on dense keys while the key space is at most this many per event
DENSE_PAIRS_PER_EVENT = 16


def absent_as_nan(rows, present):
    """``rows`` (…, d) with NaN where not ``present`` (present rows are finite): the rows
    themselves when every row not present has a NaN first component already (no identity hides
    a finite row, the usual case), else a copy."""
    hidden = ~np.asarray(present)
    hidden &= np.isfinite(rows[..., 0])
    if not hidden.any():
        return rows
    return np.where(present[..., None], rows, np.nan)


def pairs_within(pairs, radius: float):
    """The pairs of :func:`close_pairs` (found at a radius at least ``radius``) closer than
    ``radius``, in their order: the pairs :func:`close_pairs` finds at ``radius`` itself."""
    p, i, j, d = pairs
    keep = d < radius
    if keep.all():                 # found at this radius (HOTA's d₀ as the larger): the pairs themselves
        return p, i, j, d
    return p[keep], i[keep], j[keep], d[keep]


def assign_edges(problem, row, col, weight, n_rows: int, n_cols: int) -> np.ndarray:
    """Maximum-weight one-to-one matching of every problem's edges (weights > 0).

    Each problem is a bipartite graph on ``n_rows`` rows and ``n_cols`` columns given by its edges;
    a matching may leave any row or column out. An edge whose row and column have no other edge
    is in every optimal matching; what is left of a problem is solved by trying every permutation
    (:func:`_every_permutation`, all problems of one size at once) up to ``BRUTE_FORCE_MAX`` rows
    and columns, else by ``scipy.optimize.linear_sum_assignment``.

    Returns
    -------
    chosen : ndarray of bool (E,)
        The edges of the matching.
    """
    problem, row, col = (np.asarray(a, np.int64) for a in (problem, row, col))
    weight = np.asarray(weight, float)
    E = problem.size
    if E == 0:
        return np.zeros(E, bool)
    P = int(problem.max()) + 1
    row_key, col_key = problem * n_rows + row, problem * n_cols + col
    row_deg = np.bincount(row_key, minlength=P * n_rows)
    col_deg = np.bincount(col_key, minlength=P * n_cols)
    alone = (row_deg[row_key] == 1) & (col_deg[col_key] == 1)
    chosen = alone & (weight > 0)
    rest = np.flatnonzero(~alone)
    if rest.size == 0:
        return chosen
    # what is left falls apart into connected components, each its own (mostly small) problem
    r_node, n_row_nodes = _compact(row_key[rest], P * n_rows)
    c_node, n_col_nodes = _compact(col_key[rest], P * n_cols)
    n_comp, label = _fast._bipartite_components(r_node, c_node, n_row_nodes, n_col_nodes)
    prob = label[r_node]
    # the rows and columns of each component, numbered from 0
    r_number, n_r = _rank_within(label[:n_row_nodes], n_comp)
    c_number, n_c = _rank_within(label[n_row_nodes:], n_comp)
    r_local, c_local = r_number[r_node], c_number[c_node]
    size = np.maximum(n_r, n_c)                                   # (components,)
    # the edges left, by the size of their component, then by component: one pass sorts them
    by = np.lexsort((prob, size[prob]))
    edge_size = size[prob[by]]
    sizes = edge_size[np.r_[True, edge_size[1:] != edge_size[:-1]]]      # sorted already
    cuts = np.searchsorted(edge_size, np.append(sizes, edge_size[-1] + 1))
    for s, lo, hi in zip(sizes, cuts[:-1], cuts[1:]):
        e = by[lo:hi]
        if s <= BRUTE_FORCE_MAX:
            # every component of this size at once
            first = np.r_[True, prob[e][1:] != prob[e][:-1]]
            q = np.cumsum(first) - 1
            count = int(q[-1]) + 1
            W = np.zeros((count, s, s))
            index = np.full((count, s, s), -1)
            W[q, r_local[e], c_local[e]] = weight[rest[e]]
            index[q, r_local[e], c_local[e]] = rest[e]
            _, perm = _fast._every_permutation(-W)
            picked = np.take_along_axis(index, perm[..., None], axis=2)[..., 0]
            value = np.take_along_axis(W, perm[..., None], axis=2)[..., 0]
            chosen[picked[(picked >= 0) & (value > 0)]] = True
        else:
            from scipy.optimize import linear_sum_assignment

            starts = np.flatnonzero(np.r_[True, prob[e][1:] != prob[e][:-1]])
            for part in np.split(e, starts[1:]):
                p = prob[part[0]]
                W = np.zeros((n_r[p], n_c[p]))
                index = np.full((n_r[p], n_c[p]), -1)
                W[r_local[part], c_local[part]] = weight[rest[part]]
                index[r_local[part], c_local[part]] = rest[part]
                r, c = linear_sum_assignment(W, maximize=True)
                ok = (index[r, c] >= 0) & (W[r, c] > 0)
                chosen[index[r, c][ok]] = True
    return chosen


def _rank_within(group, n_groups: int):
    """Each element's place (0…) among the elements of its group, and the size of every group."""
    order = np.argsort(group, kind="stable")
    count = np.bincount(group, minlength=n_groups)
    first = np.cumsum(count) - count
    rank = np.empty(group.size, np.int64)
    rank[order] = np.arange(group.size) - first[group[order]]
    return rank, count

