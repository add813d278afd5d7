"""Per-target and per-track tables: the first thing to read when a run went wrong.

From the same per-scan matches the assignment measures use (:func:`evaluators.assignment_metrics.scan_matches`,
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

from evaluators.assignment_metrics import scan_matches

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
    """
    times = np.asarray(times, float)
    match, dist = scan_matches(positions, truths, gate, angular, track_ids, truth_ids)
    matched_id = np.where(match >= 0, np.take_along_axis(track_ids, np.maximum(match, 0), axis=-1), -1)
    target_rows, track_rows = [], []
    R = positions.shape[0]
    for r in range(R):
        # ---- targets: every (scan, slot) of an identity, in scan order
        k, t = np.nonzero(truth_ids[r] >= 0)
        who = truth_ids[r][k, t]
        order = np.lexsort((k, who))
        k, t, who = k[order], t[order], who[order]
        for ident in np.unique(who):
            sel = who == ident
            ks, ts = k[sel], t[sel]
            got = matched_id[r][ks, ts]
            hit = got >= 0
            seq = got[hit]
            d = dist[r][ks, ts][hit]
            target_rows.append({
                "tracker": name, "run": r, "target_id": int(ident), "first_s": float(times[ks[0]]),
                "last_s": float(times[ks[-1]]),
                "first_tracked_s": float(times[ks[hit][0]]) if hit.any() else None,
                "last_tracked_s": float(times[ks[hit][-1]]) if hit.any() else None,
                "tracked_fraction": float(hit.mean()), "tracks": int(np.unique(seq).size),
                "switches": int(np.count_nonzero(seq[1:] != seq[:-1])),
                "rmse": float(np.sqrt(np.mean(d * d))) if d.size else None})
        # ---- tracks: every (scan, slot) of an identity; the target matched to it there
        k, s = np.nonzero(track_ids[r] >= 0)
        tid = track_ids[r][k, s]
        followed = np.full(k.size, -1, np.int64)
        km, tm = np.nonzero(match[r] >= 0)
        owner = {(int(a), int(match[r][a, b])): int(truth_ids[r][a, b]) for a, b in zip(km, tm)}
        for i, (a, b) in enumerate(zip(k, s)):
            followed[i] = owner.get((int(a), int(b)), -1)
        order = np.lexsort((k, tid))
        k, s, tid, followed = k[order], s[order], tid[order], followed[order]
        for ident in np.unique(tid):
            sel = tid == ident
            ks, fs = k[sel], followed[sel]
            on = fs[fs >= 0]
            values, counts = np.unique(on, return_counts=True)
            best = int(values[np.argmax(counts)]) if values.size else -1
            row_nis = None
            if nis is not None:
                v = nis[r][ks, s[sel]]
                v = v[np.isfinite(v)]
                row_nis = float(v.mean()) if v.size else None
            track_rows.append({
                "tracker": name, "run": r, "track_id": int(ident), "first_s": float(times[ks[0]]),
                "last_s": float(times[ks[-1]]), "scans": int(ks.size), "target_id": best,
                "matched_fraction": float(counts.max() / ks.size) if values.size else 0.0, "mean_nis": row_nis})
    return pl.DataFrame(target_rows, schema=TARGET_SCHEMA), pl.DataFrame(track_rows, schema=TRACK_SCHEMA)


#: runs the tables cover (the first ones): a table of every target of 10,000 Monte Carlo runs is
#: more than anyone reads, and costs a Python pass per run
LIFE_TABLE_RUNS = 100


def tables_for(times, tracks: dict, truth, truth_ids, space, innovations: dict | None = None,
               runs: int = LIFE_TABLE_RUNS):
    """:func:`life_tables` of every tracker of ``tracks`` (the output vocabulary) on the first
    ``runs`` runs, in the standard measures' space (:class:`evaluators.standard.EvaluationSpace`)."""
    from evaluators.standard import NOT_A_TRACK, as_slots_with_ids

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
