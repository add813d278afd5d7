"""Track-to-truth assignment metrics over whole runs: CLEAR MOT, identity F1, track quality.

At every scan the tracks are assigned to the true targets by the minimum-cost assignment of
:mod:`evaluators.set_distances` with cost ``min(d, gate)``; a pair closer than the **gate** is a
match. From the matches, per run:

* CLEAR MOT (Bernardin & Stiefelhagen 2008): misses (true targets without a match), false
  positives (tracks without a match), identity switches (a target matched to a different track
  identity than at its previous match), MOTA = 1 − (misses + false positives + switches) /
  target presences, MOTP = mean distance of the matches;
* track quality (Li, Huang & Nevatia's MT/PT/ML convention): a target is *mostly tracked* when
  matched in ≥ 80 % of the scans it exists, *mostly lost* when in < 20 %, else *partially
  tracked*; *track breaks* (fragmentations) count the times a target's matching resumes after a
  gap; a *false track* is a track identity never matched to any target;
* identity F1 (Ristani et al. 2016): the one-to-one pairing of target and track identities that
  maximises the scans they are matched within the gate (IDTP), with
  IDF1 = 2 IDTP / (2 IDTP + IDFP + IDFN).

See ``docs/evaluation.md``.
"""

from __future__ import annotations

import numpy as np

from evaluators.set_distances import BRUTE_FORCE_MAX, optimal_assignment, pairwise_distance
from pipeline.batched_linalg import all_finite

MOSTLY_TRACKED = 0.8
MOSTLY_LOST = 0.2


def slot_identities(tracks) -> np.ndarray:
    """Track identities when a tracker keeps a fixed slot per track: slot j is track j."""
    present = all_finite(np.asarray(tracks, float))
    ids = np.broadcast_to(np.arange(present.shape[-1]), present.shape)
    return np.where(present, ids, -1)


def scan_matches(tracks, truths, gate: float, angular: bool = False):
    """Per-scan matches of tracks to targets.

    Parameters
    ----------
    tracks : ndarray (R, K, S, d), NaN rows absent
    truths : ndarray (R, K, T, d), NaN rows absent
    gate : float
        Largest distance of a match (the family's units).

    Returns
    -------
    match : ndarray of int (R, K, T)
        Slot of the track matched to each target, -1 for none.
    distance : ndarray (R, K, T)
        Distance to the matched track (NaN when unmatched).
    """
    X, Y = np.asarray(truths, float), np.asarray(tracks, float)
    vx, vy = all_finite(X), all_finite(Y)
    d = pairwise_distance(np.where(vx[..., None], X, 0.0), np.where(vy[..., None], Y, 0.0), angular)
    # squared capped distances: in one dimension (bearings) two tracks on the same side of two
    # targets tie in the sum of distances, so the last bit of a state would pick the match;
    # the sum of squares has no such tie
    _, match = optimal_assignment(np.minimum(d, gate) ** 2, vx, vy, unmatched=gate ** 2)
    dist = np.where(match >= 0, np.take_along_axis(d, np.maximum(match, 0)[..., None], axis=-1)[..., 0], np.nan)
    ok = (match >= 0) & (dist < gate)
    return np.where(ok, match, -1), np.where(ok, dist, np.nan)


def assignment_metrics(tracks, truths, gate: float, track_ids=None, angular: bool = False, matches=None) -> dict:
    """Per-run CLEAR MOT, IDF1 and track-quality counts (arrays of shape (R,)).

    Parameters
    ----------
    tracks : ndarray (R, K, S, d)
    truths : ndarray (R, K, T, d)
    gate : float
    track_ids : ndarray of int (R, K, S), optional
        Track identity per slot (−1 empty); default: each slot is one track for the whole run.
    matches : tuple, optional
        ``(match, distance)`` of :func:`scan_matches` on the same sets, when already computed.

    Returns
    -------
    dict of ndarray (R,)
        ``targets``, ``presences`` (target-scans), ``matches``, ``misses``, ``false_positives``,
        ``id_switches``, ``track_breaks``, ``mostly_tracked``, ``partially_tracked``,
        ``mostly_lost``, ``false_tracks``, ``distance_sum``, ``idtp``, ``idfp``, ``idfn``; and the
        ratios ``mota``, ``motp``, ``idf1`` per run.
    """
    tracks, truths = np.asarray(tracks, float), np.asarray(truths, float)
    ids = slot_identities(tracks) if track_ids is None else np.asarray(track_ids)
    match, dist = scan_matches(tracks, truths, gate, angular) if matches is None else matches
    R, K, T = match.shape
    present = all_finite(truths)                                   # (R, K, T)
    track_present = ids >= 0                                       # (R, K, S)
    matched = match >= 0
    matched_id = np.where(matched, np.take_along_axis(ids, np.maximum(match, 0), axis=-1), -1)

    # identity switches: compare each match's identity with the target's previous matched identity
    k_idx = np.where(matched, np.arange(K)[None, :, None], -1)
    last_k = np.maximum.accumulate(k_idx, axis=1)                  # latest scan ≤ k with a match
    prev_k = np.concatenate([np.full((R, 1, T), -1), last_k[:, :-1]], axis=1)
    prev_id = np.where(prev_k >= 0, np.take_along_axis(matched_id, np.maximum(prev_k, 0), axis=1), -1)
    switches = matched & (prev_id >= 0) & (matched_id != prev_id)
    # breaks: matched now, not matched at the previous scan, matched at some earlier scan
    prev_matched = np.concatenate([np.zeros((R, 1, T), bool), matched[:, :-1]], axis=1)
    breaks = matched & ~prev_matched & (prev_k >= 0)

    presences = present.sum(axis=1)                                # (R, T)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = matched.sum(axis=1) / presences
    exists = presences > 0
    out = {
        "targets": exists.sum(axis=1),
        "presences": present.sum(axis=(1, 2)),
        "matches": matched.sum(axis=(1, 2)),
        "misses": (present & ~matched).sum(axis=(1, 2)),
        "false_positives": track_present.sum(axis=(1, 2)) - matched.sum(axis=(1, 2)),
        "id_switches": switches.sum(axis=(1, 2)),
        "track_breaks": breaks.sum(axis=(1, 2)),
        "mostly_tracked": (exists & (ratio >= MOSTLY_TRACKED)).sum(axis=1),
        "mostly_lost": (exists & (ratio < MOSTLY_LOST)).sum(axis=1),
        "distance_sum": np.nansum(dist, axis=(1, 2)),
    }
    out["partially_tracked"] = out["targets"] - out["mostly_tracked"] - out["mostly_lost"]
    out.update(_identity_counts(ids, matched_id, present, track_present))
    with np.errstate(invalid="ignore", divide="ignore"):
        out["mota"] = 1 - (out["misses"] + out["false_positives"] + out["id_switches"]) / out["presences"]
        out["motp"] = out["distance_sum"] / out["matches"]
        out["idf1"] = 2 * out["idtp"] / (2 * out["idtp"] + out["idfp"] + out["idfn"])
    return out


def _identity_counts(ids, matched_id, present, track_present) -> dict:
    """IDTP/IDFP/IDFN per run and the false tracks (identities never matched)."""
    R = ids.shape[0]
    T = matched_id.shape[-1]
    top = int(ids.max()) if ids.size else -1
    if top < BRUTE_FORCE_MAX and T <= BRUTE_FORCE_MAX:
        # few identities (e.g. the track slots themselves): every run's assignment in one call
        U = max(top + 1, 1)
        weight = np.zeros((R, T, U), np.int64)
        r_i, k_i, t_i = np.nonzero(matched_id >= 0)
        np.add.at(weight, (r_i, t_i, matched_id[r_i, k_i, t_i]), 1)
        seen = np.zeros((R, U), bool)
        r_s, *_rest, = np.nonzero(ids >= 0)
        seen[r_s, ids[ids >= 0]] = True
        total, _ = optimal_assignment(-weight.astype(float), np.ones((R, T), bool), seen)
        idtp = (-total).round().astype(np.int64)
        false_tracks = np.sum(seen & (weight.sum(axis=1) == 0), axis=1)
        return {"idtp": idtp, "idfp": track_present.sum(axis=(1, 2)) - idtp, "idfn": present.sum(axis=(1, 2)) - idtp,
                "false_tracks": false_tracks}
    from scipy.optimize import linear_sum_assignment  # imported where needed: 0.25 s

    idtp, false_tracks = np.zeros(R, np.int64), np.zeros(R, np.int64)
    for r in range(R):  # one assignment per run between target and track identities
        uniq = np.unique(ids[r][ids[r] >= 0])
        if uniq.size == 0:
            continue
        T = matched_id.shape[-1]
        col = np.searchsorted(uniq, np.maximum(matched_id[r], uniq[0]))
        weight = np.zeros((T, uniq.size), np.int64)
        ok = matched_id[r] >= 0
        np.add.at(weight, (np.broadcast_to(np.arange(T), ok.shape)[ok], col[ok]), 1)
        rows, cols = linear_sum_assignment(-weight)
        idtp[r] = weight[rows, cols].sum()
        false_tracks[r] = int(np.sum(weight.sum(axis=0) == 0))
    return {"idtp": idtp, "idfp": track_present.sum(axis=(1, 2)) - idtp, "idfn": present.sum(axis=(1, 2)) - idtp,
            "false_tracks": false_tracks}
