"""Per-target and per-track tables: the first thing to read when a run went wrong.

From the same per-scan matches the assignment measures use (:func:`trackreplay.evaluators.assignment_metrics.scan_matches`,
the gate of the family's evaluation space), one row per true target and one per track, per run:

* **targets** — ``tracker, run, target_id``; ``first_s``/``last_s`` when the target was present;
  ``first_tracked_s``/``last_tracked_s`` when a reported track was matched to it (null if never);
  ``tracked_fraction`` of its scans; ``tracks`` (distinct track identities matched to it);
  ``switches`` (its matched identity changed from one match to the next); ``rmse`` of the matched
  positions (the space's unit);
* **tracks** — ``tracker, run, track_id``; ``first_s``/``last_s`` of the reported track;
  ``scans``; ``target_id`` it followed most (−1 if it never matched a target), with
  ``matched_fraction`` of its scans on that target; ``mean_nis`` of its updates where the tracker
  gives innovations.

Only reported (confirmed) tracks count, as in the standard measures (``docs/evaluation.md``).
"""

from __future__ import annotations

import numpy as np
import polars as pl

from trackreplay.evaluators.assignment_metrics import scan_matches

TARGET_SCHEMA = {"tracker": pl.String, "run": pl.Int64, "target_id": pl.Int64, "first_s": pl.Float64,
                 "last_s": pl.Float64, "first_tracked_s": pl.Float64, "last_tracked_s": pl.Float64,
                 "tracked_fraction": pl.Float64, "tracks": pl.Int64, "switches": pl.Int64, "rmse": pl.Float64}
TRACK_SCHEMA = {"tracker": pl.String, "run": pl.Int64, "track_id": pl.Int64, "first_s": pl.Float64,
                "last_s": pl.Float64, "scans": pl.Int64, "target_id": pl.Int64, "matched_fraction": pl.Float64,
                "mean_nis": pl.Float64}


def life_tables(name: str, times, positions, track_ids, truths, truth_ids, gate: float, angular: bool = False,
                nis=None):
    """The target and track tables of one tracker.

    Parameters
    ----------
    name : str
        The tracker (first column of both tables).
    times : ndarray (K,)
    positions : ndarray (R, K, S, d)
        Reported track positions in the evaluation space, NaN where a slot reports no track.
    track_ids : ndarray of int (R, K, S)
        −1 where a slot reports no track.
    truths : ndarray (R, K, T, d), truth_ids : ndarray of int (R, K, T)
    gate : float
    nis : ndarray (R, K, S), optional
        Normalised innovation squared of each slot's update (NaN where none).

    Returns
    -------
    targets, tracks : polars.DataFrame

    Notes
    -----
    Each identity's history is one stretch of a single sort of every (run, identity, scan), so
    the counts come from group-wise sums rather than a pass per identity; the means are numpy's
    own of each stretch, bit for bit those of a loop per identity (which
    ``tests/test_evaluator_speed_equivalence.py`` keeps as the reference).
    """
    times = np.asarray(times, float)
    track_ids, truth_ids = np.asarray(track_ids), np.asarray(truth_ids)
    match, dist = scan_matches(positions, truths, gate, angular, track_ids, truth_ids)
    matched_id = np.where(match >= 0, np.take_along_axis(track_ids, np.maximum(match, 0), axis=-1), -1)
    targets = _target_rows(name, times, truth_ids, matched_id, dist)
    # the target each reported track slot was matched to at each scan (−1 for none)
    followed = np.full(track_ids.shape, -1, np.int64)
    r, k, t = np.nonzero(match >= 0)
    followed[r, k, match[r, k, t]] = truth_ids[r, k, t]
    tracks = _track_rows(name, times, track_ids, followed, nis)
    return pl.DataFrame(targets, schema=TARGET_SCHEMA), pl.DataFrame(tracks, schema=TRACK_SCHEMA)


def _histories(ids):
    """Every (run, scan, slot) of ``ids`` (R, K, slots) holding an identity (≥ 0), in the order
    (run, identity, scan): each identity's history in one stretch.

    Returns
    -------
    r, k, slot : ndarray of int (E,)
    group : ndarray of int (E,)
        The (run, identity) stretch of each, numbered 0… in order.
    first, last : ndarray of int (G,)
        Where each stretch starts and ends (inclusive).
    """
    r, k, slot = np.nonzero(ids >= 0)
    who = ids[r, k, slot]
    order = np.lexsort((k, who, r))          # stable: an identity twice in a scan keeps slot order
    r, k, slot, who = r[order], k[order], slot[order], who[order]
    new = np.ones(r.size, bool)
    new[1:] = (r[1:] != r[:-1]) | (who[1:] != who[:-1])
    group = np.cumsum(new) - 1
    first = np.flatnonzero(new)
    last = np.append(first[1:], r.size)[:first.size] - 1
    return r, k, slot, group, first, last


def _group_means(values, bounds) -> list:
    """``np.mean`` of each stretch ``values[a:b]`` for ``(a, b)`` in ``bounds`` (None when empty):
    numpy's own pairwise sum of each stretch, so bit for bit the mean of the stretch alone."""
    return [float(np.mean(values[a:b])) if b > a else None for a, b in bounds]


def _target_rows(name, times, truth_ids, matched_id, dist) -> dict:
    """The columns of the targets table: one row per (run, target identity), in that order."""
    r, k, t, group, first, last = _histories(truth_ids)
    got = matched_id[r, k, t]
    hit = got >= 0
    seen = last - first + 1
    hits = np.bincount(group[hit], minlength=first.size)
    # the matched events alone, still in (run, identity, scan) order
    h_group, h_k, h_got = group[hit], k[hit], got[hit]
    h_first = np.searchsorted(h_group, np.arange(first.size), side="left")
    h_end = h_first + hits
    tracked = hits > 0
    # distinct track identities matched to a target, and changes from one match to the next
    same_target = np.zeros(h_group.size, bool)
    same_target[1:] = h_group[1:] == h_group[:-1]
    changed = same_target & (h_got != np.roll(h_got, 1))
    switches = np.bincount(h_group[changed], minlength=first.size)
    pair = np.lexsort((h_got, h_group))
    distinct = np.ones(h_group.size, bool)
    distinct[1:] = (h_group[pair][1:] != h_group[pair][:-1]) | (h_got[pair][1:] != h_got[pair][:-1])
    n_tracks = np.bincount(h_group[pair][distinct], minlength=first.size)
    d = dist[r[hit], h_k, t[hit]]
    squares = d * d
    rmse = [None if m is None else float(np.sqrt(m)) for m in _group_means(squares, zip(h_first, h_end))]
    # the scan of each target's first and last match (any scan where it has none: not shown)
    h_time = times[np.append(h_k, 0)]
    return {
        "tracker": [name] * first.size, "run": r[first].tolist(),
        "target_id": truth_ids[r[first], k[first], t[first]].tolist(),
        "first_s": times[k[first]].tolist(), "last_s": times[k[last]].tolist(),
        "first_tracked_s": _where_present(h_time[h_first], tracked),
        "last_tracked_s": _where_present(h_time[h_end - 1], tracked),
        # hit.mean(): the count of matches over the count of scans, both exact in floats
        "tracked_fraction": (hits / seen).tolist(), "tracks": n_tracks.tolist(), "switches": switches.tolist(),
        "rmse": rmse}


def _track_rows(name, times, track_ids, followed, nis) -> dict:
    """The columns of the tracks table: one row per (run, track identity), in that order."""
    r, k, s, group, first, last = _histories(track_ids)
    scans = last - first + 1
    on = followed[r, k, s]
    # the target each track followed most: the most frequent target of its matches, the
    # smallest identity among equally frequent ones (np.unique's order and argmax's first)
    m_group, m_target = group[on >= 0], on[on >= 0]
    pair = np.lexsort((m_target, m_group))
    m_group, m_target = m_group[pair], m_target[pair]
    start = np.ones(m_group.size, bool)
    start[1:] = (m_group[1:] != m_group[:-1]) | (m_target[1:] != m_target[:-1])
    at = np.flatnonzero(start)
    count = np.diff(np.append(at, m_group.size))
    pair_group, pair_target = m_group[at], m_target[at]
    # per group, the largest count first and the smallest target among equals
    best = np.lexsort((pair_target, -count, pair_group))
    lead = np.ones(best.size, bool)
    lead[1:] = pair_group[best][1:] != pair_group[best][:-1]
    best = best[lead]
    target = np.full(first.size, -1, np.int64)
    top = np.zeros(first.size, np.int64)
    target[pair_group[best]] = pair_target[best]
    top[pair_group[best]] = count[best]
    fraction = np.where(target >= 0, top / scans, 0.0)
    if nis is None:
        mean_nis = [None] * first.size
    else:
        v = np.asarray(nis)[r, k, s]
        finite = np.isfinite(v)
        kept = np.cumsum(np.concatenate([[0], finite]))          # finite values before each event
        mean_nis = _group_means(v[finite], zip(kept[first], kept[last + 1]))
    return {
        "tracker": [name] * first.size, "run": r[first].tolist(),
        "track_id": track_ids[r[first], k[first], s[first]].tolist(),
        "first_s": times[k[first]].tolist(), "last_s": times[k[last]].tolist(), "scans": scans.tolist(),
        "target_id": target.tolist(), "matched_fraction": fraction.tolist(), "mean_nis": mean_nis}


def _where_present(values, present) -> list:
    """``values`` as floats, None where not ``present``."""
    return [float(v) if ok else None for v, ok in zip(values.tolist(), present.tolist())]


#: runs the tables cover (the first ones): a table of every target of 10,000 Monte Carlo runs is
#: more than anyone reads
LIFE_TABLE_RUNS = 100


def tables_for(times, tracks: dict, truth, truth_ids, space, innovations: dict | None = None,
               runs: int = LIFE_TABLE_RUNS):
    """:func:`life_tables` of every tracker of ``tracks`` (the output vocabulary) on the first
    ``runs`` runs, in the standard measures' space (:class:`trackreplay.evaluators.standard.EvaluationSpace`)."""
    from trackreplay.evaluators.standard import NOT_A_TRACK, as_slots_with_ids

    targets, lives = [], []
    truth = np.asarray(truth, float)
    truth = truth if truth.ndim == 4 else truth[:, :, None]
    truth_ids = (np.where(np.isfinite(truth).all(axis=-1), np.arange(truth.shape[2]), -1)
                 if truth_ids is None else np.asarray(truth_ids))
    comps = list(space.truth_components)
    pos = [comps.index(c) for c in space.position_components]
    for name, out in tracks.items():
        if "state" not in out or "flags" not in out:
            continue
        positions, ids = as_slots_with_ids(out, NOT_A_TRACK, space.position_components)
        nis = None
        if innovations is not None and innovations.get(name) is not None:
            nis = innovations[name][1]
            nis = nis if nis.ndim == 3 else nis[:, :, None]
            nis = nis[:runs]
        t, l = life_tables(name, times, positions[:runs], ids[:runs], truth[:runs][..., pos], truth_ids[:runs],
                           space.gate, space.angular, nis)
        targets.append(t)
        lives.append(l)
    if not targets:
        return pl.DataFrame(schema=TARGET_SCHEMA), pl.DataFrame(schema=TRACK_SCHEMA)
    return pl.concat(targets), pl.concat(lives)
