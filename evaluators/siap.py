"""SIAP measures: completeness, ambiguity, spuriousness, accuracy and continuity over Monte Carlo runs.

The Single Integrated Air Picture attribute measures (Votruba et al., *SIAP Metrics
Implementation*, SIAP Task Force, 2001), in the form of Stone Soup's ``SIAPMetrics``
(``stonesoup/metricgenerator/tracktotruthmetrics.py``). Every sum runs over the scans t of a run:

* completeness ``C = Σ JT(t) / Σ J(t)``: J the targets present, JT those with at least one
  associated track (0 when no target is present);
* ambiguity ``A = Σ NA(t) / Σ JT(t)``: NA the associated tracks (1 when no target is tracked);
* spuriousness ``S = Σ (N(t) − NA(t)) / Σ N(t)``: N the reported tracks (0 without tracks);
* positional (velocity) accuracy ``PA = Σ_t Σ_assoc d / Σ NA(t)``: the mean distance of the
  associated track-target pairs in position (velocity) over every scan, i.e. the sum of the
  per-scan sums over the sum of the per-scan counts (0 without associations);
* rate of track number change ``R = Σ_j (NU_j − 1) / Σ_j TT_j`` over targets j with NU_j > 0:
  NU_j the fewest association segments that cover every scan at which j is tracked, TT_j the
  time (s) between consecutive presences of j that one segment spans (0 when nothing is tracked);
* longest track segment ``LS = Σ_j TL_j / Σ_j T_j``: TL_j the duration (s) of j's longest
  association segment, T_j the time from j's first to last presence (0 when every T_j is 0).

**Association** (Stone Soup's ``TrackToTruth`` with ``consec_pairs_confirm=1`` and
``consec_misses_end=1``): at every scan each reported track is associated with the nearest
present target closer than the gate (``siap_gate_m``/``_deg``, default the assignment gate).
Several tracks may share a target, which is what ambiguity counts; the one-to-one assignment of
:mod:`trackreplay.evaluators.assignment_metrics` would keep A at 1. An *association segment* is a maximal run
of a track's reports (consecutive scans at which it reports) associated with the same target;
its duration is the time from its first to its last scan.

Over Monte Carlo runs nothing is averaged per run: :func:`siap_sums` returns per-run sums and
:func:`pooled_siap` forms the ratios from the totals of any subset of runs (intervals by
re-grouping runs, :mod:`trackreplay.evaluators.confidence`).

Where this differs from Stone Soup 1.9 on purpose (``docs/evaluation.md``, section *SIAP*):

* a segment of a single scan counts (duration 0); Stone Soup cannot build its time range
  (``TimeRange`` refuses start = end) and fails;
* NU_j is the fewest segments covering the tracked scans. Stone Soup's greedy walk stops at a scan
  where the segment it picks ends (having arrived there inside it), so it misses later segments;
* with angles the differences wrap (Stone Soup's Euclidean measure does not).
"""

from __future__ import annotations

import numpy as np

from trackreplay.evaluators.set_distances import close_pairs, global_identities, stable_order
from trackreplay.evaluators.set_distances_fast import scan_index_type, scans_where
from trackreplay.evaluators.set_distances_shared import SinglePair, single_pair_view
from trackreplay.batched_linalg import all_finite

SUM_KEYS = ("truths", "tracked_truths", "tracks", "associated_tracks", "position_error_sum",
            "velocity_error_sum", "track_number_changes", "time_tracked", "longest_segment_time",
            "truth_lifetime")
#: the pooled measures of :func:`pooled_siap`
MEASURES = ("completeness", "ambiguity", "spuriousness", "position_accuracy", "velocity_accuracy",
            "track_number_change_rate", "longest_track_segment")


def siap_associations(tracks, truths, gate: float, track_ids=None, truth_ids=None, angular: bool = False,
                      pairs=None):
    """Each reported track's target at every scan: the nearest present target closer than ``gate``.

    ``pairs``, when given, are :func:`trackreplay.evaluators.assignment_metrics.gated_pairs` of the same
    sets at the same gate (the pairs this search starts from), found once for several measures.

    Returns
    -------
    target : ndarray of int (R, K, S)
        Truth slot associated with each track slot, −1 for none (or no track).
    distance : ndarray (R, K, S)
        Its distance (NaN for none).
    """
    tracks, truths = np.asarray(tracks, float), np.asarray(truths, float)
    R, K, S = tracks.shape[:3]
    T = truths.shape[2]
    vy = all_finite(tracks) & (_ids(track_ids, (R, K, S)) >= 0)
    vx = all_finite(truths) & (_ids(truth_ids, (R, K, T)) >= 0)
    if pairs is None:
        X = np.where(vx[..., None], truths, np.nan).reshape(R * K, T, -1)
        Y = np.where(vy[..., None], tracks, np.nan).reshape(R * K, S, -1)
        pairs = close_pairs(X, Y, gate, angular)
    p, i, j, d = pairs
    keep = d < gate
    p, i, j, d = p[keep], i[keep], j[keep], d[keep]
    # the nearest target of every track (the first of equal distances, by slot): the pairs come
    # sorted by (problem, i, j), a stable sort on (problem, j) keeps i in order
    key = p.astype(np.int64) * S + j
    order = np.argsort(key, kind="stable")
    key, i, d = key[order], i[order], d[order]
    start = np.flatnonzero(np.r_[True, key[1:] != key[:-1]]) if key.size else np.zeros(0, np.intp)
    group = np.cumsum(np.r_[False, key[1:] != key[:-1]]) if key.size else np.zeros(0, np.intp)
    nearest = d == np.minimum.reduceat(d, start)[group] if key.size else np.zeros(0, bool)
    at = np.flatnonzero(nearest)
    first = at[np.r_[True, group[at][1:] != group[at][:-1]]] if at.size else at
    target = np.full(R * K * S, -1, np.intp)
    distance = np.full(R * K * S, np.nan)
    target[key[first]] = i[first]
    distance[key[first]] = d[first]
    return target.reshape(R, K, S), distance.reshape(R, K, S)


def _ids(ids, shape):
    """Identities per slot, the slot index by default."""
    return np.broadcast_to(np.arange(shape[-1]), shape) if ids is None else np.asarray(ids).astype(np.int64)


def siap_sums(tracks, truths, gate: float, times=None, track_ids=None, truth_ids=None, angular: bool = False,
              track_velocities=None, truth_velocities=None, pairs=None) -> dict:
    """Per-run sums from which the SIAP measures of any set of runs are formed.

    Parameters
    ----------
    tracks : ndarray (R, K, S, d)
        Track positions, NaN rows where a slot reports no track.
    truths : ndarray (R, K, T, d)
        True positions, NaN rows absent.
    gate : float
        A track is associated with its nearest target closer than ``gate``.
    times : ndarray (K,), optional
        Scan times (s); default 0, 1, …, K − 1.
    track_ids, truth_ids : ndarray of int (R, K, S) / (R, K, T), optional
        Identities (−1 empty; unique within a scan); default: the slot.
    angular : bool
        The components are angles (differences wrap).
    track_velocities, truth_velocities : ndarray (R, K, S, v) / (R, K, T, v), optional
        Velocities for the velocity accuracy; without them ``velocity_error_sum`` is NaN.
    pairs : tuple, optional
        :func:`trackreplay.evaluators.assignment_metrics.gated_pairs` of the same sets at ``gate``, when
        already found.

    Returns
    -------
    dict of ndarray (R,)
        The :data:`SUM_KEYS`: ``truths`` Σ J, ``tracked_truths`` Σ JT, ``tracks`` Σ N,
        ``associated_tracks`` Σ NA, ``position_error_sum`` and ``velocity_error_sum`` (the
        distances of the associated pairs), ``track_number_changes`` Σ (NU_j − 1),
        ``time_tracked`` Σ TT_j, ``longest_segment_time`` Σ TL_j, ``truth_lifetime`` Σ T_j.
    """
    tracks, truths = np.asarray(tracks, float), np.asarray(truths, float)
    R, K, S = tracks.shape[:3]
    T = truths.shape[2]
    times = np.arange(K, dtype=float) if times is None else np.asarray(times, float)
    tid, gid = _ids(track_ids, (R, K, S)), _ids(truth_ids, (R, K, T))
    vy = all_finite(tracks) & (tid >= 0)
    vx = all_finite(truths) & (gid >= 0)
    target, distance = siap_associations(tracks, truths, gate, tid, gid, angular, pairs)
    target = np.where(vy, target, -1)
    associated = target >= 0
    out = {key: np.zeros(R) for key in SUM_KEYS}
    out["truths"] = vx.sum(axis=(1, 2)).astype(float)
    out["tracks"] = vy.sum(axis=(1, 2)).astype(float)
    out["associated_tracks"] = associated.sum(axis=(1, 2)).astype(float)
    out["position_error_sum"] = np.where(associated, distance, 0.0).sum(axis=(1, 2))
    ra, ka, sa = np.nonzero(associated)
    ia = target[ra, ka, sa]
    tracked = np.zeros((R, K, T), bool)
    tracked[ra, ka, ia] = True
    out["tracked_truths"] = tracked.sum(axis=(1, 2)).astype(float)
    if track_velocities is None or truth_velocities is None:
        out["velocity_error_sum"] = np.full(R, np.nan)
    else:
        dv = np.asarray(track_velocities, float)[ra, ka, sa] - np.asarray(truth_velocities, float)[ra, ka, ia]
        out["velocity_error_sum"] = np.bincount(ra, np.sqrt(np.sum(dv * dv, axis=-1)), minlength=R)

    # ---- continuity: association segments per target
    g_num, n_g, g_run = global_identities(gid, vx)                 # targets numbered over runs
    h_num, n_h, _ = global_identities(tid, vy)
    r, k, s = np.nonzero(vy)                                         # every report, in (run, scan) order
    h = h_num[r, k, s]
    slot = target[r, k, s]
    g = np.where(slot >= 0, g_num[r, k, np.maximum(slot, 0)], -1)
    order = stable_order(h, n_h)                                    # each track's reports in scan order
    r, k, h, g, slot = r[order], k[order], h[order], g[order], slot[order]
    start = np.ones(h.size, bool)
    start[1:] = (h[1:] != h[:-1]) | (g[1:] != g[:-1])
    first_event = np.flatnonzero(start)
    last_event = np.append(first_event[1:] - 1, h.size - 1).astype(np.int64)[:first_event.size]
    keep = g[first_event] >= 0
    seg_g = g[first_event][keep]
    seg_run = r[first_event][keep]
    seg_k0, seg_k1 = k[first_event][keep], k[last_event][keep]
    seg_i0, seg_i1 = slot[first_event][keep], slot[last_event][keep]

    # every target's presences in scan order, and each presence's position in its target's list
    pr, pk, pi = np.nonzero(vx)
    pg = g_num[pr, pk, pi]
    order = stable_order(pg, n_g)
    pr, pk, pg = pr[order], pk[order], pg[order]
    n_pres = np.bincount(pg, minlength=n_g)
    offset = np.concatenate([[0], np.cumsum(n_pres)[:-1]]).astype(np.int64)
    position = np.full((R, K, T), -1, np.int64)
    position[pr, pk, pi[order]] = np.arange(pg.size) - offset[pg]
    # a segment's ends are presences of its target
    seg_p0, seg_p1 = position[seg_run, seg_k0, seg_i0], position[seg_run, seg_k1, seg_i1]

    # T_j: first to last presence
    if n_g:
        first_scan = pk[offset]
        last_scan = pk[offset + n_pres - 1]
        out["truth_lifetime"] = np.bincount(g_run, times[last_scan] - times[first_scan], minlength=R)
    # TL_j: the longest segment
    seg_time = times[seg_k1] - times[seg_k0]
    longest = np.zeros(n_g)
    np.maximum.at(longest, seg_g, seg_time)
    out["longest_segment_time"] = np.bincount(g_run, longest, minlength=R) if n_g else np.zeros(R)
    # TT_j: the gaps between consecutive presences that one segment spans
    cover = np.zeros(pg.size + 1, np.int64)
    np.add.at(cover, offset[seg_g] + seg_p0, 1)
    np.add.at(cover, offset[seg_g] + seg_p1, -1)
    covered = np.cumsum(cover)[:-1] > 0                             # presence q → q + 1 spanned
    nxt = np.arange(pg.size) + 1
    inside = np.zeros(pg.size, bool)
    inside[:-1] = pg[1:] == pg[:-1]
    gap = np.where(inside, times[pk[np.minimum(nxt, pg.size - 1)]] - times[pk], 0.0)
    out["time_tracked"] = np.bincount(pr[covered & inside], gap[covered & inside], minlength=R)
    # NU_j: the fewest segments covering the tracked presences (greedy on the latest end)
    changes = np.zeros(n_g)
    by_g = stable_order(seg_g, n_g)
    bounds = np.searchsorted(seg_g[by_g], np.arange(n_g + 1))
    for target_number in np.flatnonzero(bounds[1:] > bounds[:-1]):
        b = by_g[bounds[target_number]:bounds[target_number + 1]]
        changes[target_number] = _fewest_segments(seg_p0[b], seg_p1[b]) - 1
    out["track_number_changes"] = np.bincount(g_run, changes, minlength=R) if n_g else np.zeros(R)
    return out


def _sums_single(tracks, truths, gate: float, times=None, track_ids=None, truth_ids=None, angular: bool = False,
                 track_velocities=None, truth_velocities=None, view: SinglePair | None = None) -> dict:
    """:func:`siap_sums` of sets of one track and one target slot ``(R, K, 1, d)`` whose
    identities are one per run (:func:`trackreplay.evaluators.set_distances.one_identity_per_run`), from
    per-scan arrays (``view``: :func:`trackreplay.evaluators.set_distances_shared.single_pair_view` of the
    same sets, when already found).

    The track is associated wherever both are present and closer than the gate. Its
    association segments are the stretches of associated reports between two reports that are
    not associated; they are disjoint, so the fewest that cover the tracked presences are all
    of them (NU = their number); a gap between two consecutive presences of the target is
    spanned when both ends lie in one segment. The sums are added in the order
    :func:`siap_sums` adds them.
    """
    if view is None:
        view = single_pair_view(tracks, truths, track_ids, truth_ids, angular)
    vx, vy, d = view.truth_present, view.track_present, view.distance
    R, K = vx.shape
    times = np.arange(K, dtype=float) if times is None else np.asarray(times, float)
    associated = vx & vy & (d < gate)
    out = {key: np.zeros(R) for key in SUM_KEYS}
    out["truths"] = vx.sum(axis=1).astype(float)
    out["tracks"] = vy.sum(axis=1).astype(float)
    out["associated_tracks"] = associated.sum(axis=1).astype(float)
    out["tracked_truths"] = out["associated_tracks"].copy()
    out["position_error_sum"] = np.where(associated, d, 0.0)[:, :, None].sum(axis=(1, 2))
    if track_velocities is None or truth_velocities is None:
        out["velocity_error_sum"] = np.full(R, np.nan)
    else:
        # the speed error at every scan, a component at a time (0 + a² + b², the bits of the
        # sum over the components), then added where associated
        tv, gv = np.asarray(track_velocities, float)[:, :, 0], np.asarray(truth_velocities, float)[:, :, 0]
        # laid out as the velocities are (a tracker's buffer and the recorded truth hold the runs
        # fastest): the differences then read both along the runs
        runs_fastest = abs(tv.strides[0]) < abs(tv.strides[1])
        speed_error, part = ((np.zeros((K, R)).T, np.empty((K, R)).T) if runs_fastest
                             else (np.zeros((R, K)), np.empty((R, K))))
        with np.errstate(invalid="ignore", over="ignore"):
            if tv.shape[-1] >= 8:           # numpy sums 8 or more components pairwise: as siap_sums does
                np.sum((tv - gv) ** 2, axis=-1, out=speed_error)
            for c in range(tv.shape[-1] if tv.shape[-1] < 8 else 0):
                np.subtract(tv[..., c], gv[..., c], out=part)
                np.multiply(part, part, out=part)
                speed_error += part
            np.sqrt(speed_error, out=speed_error)
        out["velocity_error_sum"] = _add_over_scans(speed_error, associated)
    small = scan_index_type(K)
    last = (slice(None), slice(-1, None))
    now, before = (slice(None), slice(1, None)), (slice(None), slice(None, -1))   # a scan and the one before
    # whether the track's latest report at or before each scan (its earliest at or after) is
    # associated: the latest associated report is the latest report
    latest = np.maximum.accumulate(scans_where(vy, -1), axis=1)
    latest_associated = np.maximum.accumulate(scans_where(associated, -1), axis=1) == latest
    latest_associated &= latest >= 0
    earliest = np.minimum.accumulate(scans_where(vy, K)[:, ::-1], axis=1)[:, ::-1]
    earliest_associated = np.minimum.accumulate(scans_where(associated, K)[:, ::-1], axis=1)[:, ::-1] == earliest
    earliest_associated &= earliest < K
    # a segment starts at an associated report whose previous report is not associated (or none),
    # and ends at one whose next report is not
    starts = associated.copy()
    starts[now] &= ~latest_associated[before]
    ends = associated.copy()
    ends[before] &= ~earliest_associated[now]
    # the gap from a presence of the target to its next one lies in one segment when the latest
    # report up to the first and the earliest report after it are associated and no report falls
    # between the two presences (one there would be unassociated: the target is absent); the
    # last scan has no next presence
    presence_after = np.minimum.accumulate(scans_where(vx, K)[:, ::-1], axis=1)[:, ::-1]
    next_presence = np.empty((R, K), small)
    next_presence[before] = presence_after[now]
    next_presence[last] = K
    covered = vx & latest_associated
    covered[last] = False
    covered[before] &= earliest_associated[now] & (earliest[now] >= next_presence[before]) & (next_presence[before] < K)
    np.minimum(next_presence, K - 1, out=next_presence)            # a scan index wherever it is read
    out["time_tracked"] = _add_over_scans(times[next_presence] - times, covered)
    # T_j and TL_j; a run without the target adds nothing
    exists = vx.any(axis=1)
    first = np.argmax(vx, axis=1)
    final = K - 1 - np.argmax(vx[:, ::-1], axis=1)
    out["truth_lifetime"] = np.where(exists, times[final] - times[first], 0.0)
    re, ke = np.nonzero(ends)
    start_scan = np.maximum.accumulate(scans_where(starts, -1), axis=1)
    longest = np.zeros(R)
    np.maximum.at(longest, re, times[ke] - times[start_scan[re, ke]])
    out["longest_segment_time"] = longest
    n_segments = starts.sum(axis=1)
    out["track_number_changes"] = np.maximum(n_segments - 1, 0).astype(float)
    return out


def _add_over_scans(values, where):
    """``Σ_k values[r, k]`` over the scans k where ``where`` (R, K) holds, added scan after scan
    from 0: the bits of ``np.bincount(run, values[where])`` over the (run, scan) pairs in order,
    without gathering them (adding +0.0 where ``where`` is false leaves every sum as it is: a
    sum started at +0.0 is never −0.0)."""
    # a scan's values (R,) at a time: the transposed selection, which numpy lays out with the runs
    # contiguous (whatever the layout, the additions are the loop's, in scan order)
    picked = np.where(where.T, values.T, 0.0)
    total = np.zeros(where.shape[0])
    for column in picked:
        total += column
    return total


def _fewest_segments(p0, p1) -> int:
    """Fewest of the segments [p0, p1] (positions in a target's presences) that cover every
    position some segment covers: from the first uncovered position, take the segment holding
    it that ends last, continue after its end."""
    n = 0
    p = int(p0.min())
    last = int(p1.max())
    while p <= last:
        holding = (p0 <= p) & (p1 >= p)
        if holding.any():
            n += 1
            p = int(p1[holding].max()) + 1
        else:
            later = p0 > p
            if not later.any():
                break
            p = int(p0[later].min())
    return n


def pooled_siap(sums: dict, runs=None) -> dict:
    """The SIAP measures of the runs ``runs`` (default: all) from :func:`siap_sums`: the sums are
    added over the runs first and the ratios formed from the totals, with Stone Soup's values
    where a ratio has nothing to count (C, S, PA, VA, R, LS 0; A 1)."""
    pick = slice(None) if runs is None else np.asarray(runs)
    t = {key: float(np.asarray(sums[key])[pick].sum()) for key in SUM_KEYS}
    ratio = lambda a, b, empty: a / b if b != 0 else empty  # noqa: E731
    return {
        "completeness": ratio(t["tracked_truths"], t["truths"], 0.0),
        "ambiguity": ratio(t["associated_tracks"], t["tracked_truths"], 1.0),
        "spuriousness": ratio(t["tracks"] - t["associated_tracks"], t["tracks"], 0.0),
        "position_accuracy": ratio(t["position_error_sum"], t["associated_tracks"], 0.0),
        "velocity_accuracy": ratio(t["velocity_error_sum"], t["associated_tracks"], 0.0),
        "track_number_change_rate": ratio(t["track_number_changes"], t["time_tracked"], 0.0),
        "longest_track_segment": ratio(t["longest_segment_time"], t["truth_lifetime"], 0.0),
    }


def siap(tracks, truths, gate: float, times=None, track_ids=None, truth_ids=None, angular: bool = False,
         track_velocities=None, truth_velocities=None) -> dict:
    """The SIAP measures pooled over all runs: :func:`pooled_siap` of :func:`siap_sums`."""
    return pooled_siap(siap_sums(tracks, truths, gate, times, track_ids, truth_ids, angular, track_velocities,
                                 truth_velocities))
