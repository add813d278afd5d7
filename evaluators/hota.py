"""HOTA for point targets: detection, association and localisation accuracy over Monte Carlo runs.

HOTA (Luiten, Ošep, Dendorfer, Torr, Geiger, Leal-Taixé & Leibe 2021, *IJCV* 129, §5) scores a
tracker at each localisation threshold α = 0.05, 0.10, …, 0.95 from a similarity ``S ∈ [0, 1]``
between a track and a target. For points we use ``S = max(0, 1 − d/d₀)`` with ``d₀`` a design
value (the distance at which a track stops resembling the target; ``hota_distance_m`` of a family).

Per run (the paper's "sequence"):

1. every pair of truth identity *g* and track identity *h* gets a global alignment score
   ``A(g, h) = Σ_k Ŝ_k / (n_g + n_h − Σ_k Ŝ_k)``, where ``n_g``, ``n_h`` count the scans the
   identities are present and ``Ŝ_k = S / (Σ_row S + Σ_col S − S)`` is scan k's similarity
   normalised within its matrix (TrackEval's soft count of potential matches);
2. at each scan the pairs are assigned optimally on ``A · S`` (eq. 18's objective), once for all α;
3. for each α the assigned pairs with ``S ≥ α`` are true positives (TP); the targets left are
   misses (FN), the tracks left false positives (FP);
4. ``DetA_α = |TP| / (|TP| + |FN| + |FP|)`` (eq. 5), ``AssA_α = (1/|TP|) Σ_{c∈TP} A(c)`` with
   ``A(c) = |TPA(c)| / (|TPA(c)| + |FNA(c)| + |FPA(c)|)`` (eqs. 6–9, counted per identity pair),
   ``HOTA_α = √(DetA_α · AssA_α)`` (eq. 10) and ``LocA_α = (1/|TP|) Σ_{c∈TP} S(c)`` (eq. 12);
5. HOTA, DetA, AssA, LocA are the means over the 19 values of α (eq. 11).

Over Monte Carlo runs nothing is averaged per run: TP, FN, FP, the association sums and the
similarity sums of every α are **summed over runs** and the ratios formed from the totals (so
AssA and LocA are weighted by |TP|, as TrackEval combines sequences). :func:`hota_sums` returns
those per-run sums, so :func:`pooled_hota` gives the value of any subset of runs (Monte Carlo
intervals by regrouping runs, :mod:`trackreplay.evaluators.confidence`).

At an α without a single TP, AssA_α = 0 and LocA_α = 1: TrackEval's conventions, kept so that the
averages over α agree with it. See ``docs/evaluation.md`` (section *HOTA*).
"""

from __future__ import annotations

import numpy as np

from trackreplay.evaluators.set_distances import (absent_as_nan, assign_edges, close_pairs, global_identities, identity_pairs,
                                      optimal_assignment, pairs_within, pairwise_distance)
from trackreplay.evaluators.set_distances_shared import SinglePair, single_pair_view
from trackreplay.batched_linalg import all_finite

#: the localisation thresholds α, built as TrackEval builds them (so every bit of α agrees)
HOTA_ALPHAS = np.arange(0.05, 0.99, 0.05)
_EPS = np.finfo(float).eps
SUM_KEYS = ("tp", "fn", "fp", "loc_sum", "ass_sum", "ass_re_sum", "ass_pr_sum")
#: from this many track–target pairs over all scans and runs on, :func:`hota_sums` takes the
#: vectorised form (the plain one is the reference it is tested against)
SPARSE_FROM_PAIRS = 1 << 16


def point_similarity(distance, distance_scale: float):
    """``max(0, 1 − d/d₀)``: 1 on the target, 0 from ``d₀`` on (Luiten et al. 2021, §5)."""
    return np.maximum(0.0, 1.0 - np.asarray(distance, float) / float(distance_scale))


def hota_sums(tracks, truths, distance_scale: float, track_ids=None, truth_ids=None, angular: bool = False,
              alphas=HOTA_ALPHAS, method: str = "auto", pairs=None) -> dict:
    """Per-run sums from which HOTA and its parts are formed for any set of runs.

    Parameters
    ----------
    tracks : ndarray (R, K, S, d)
        Track positions; NaN rows are absent.
    truths : ndarray (R, K, T, d)
        True positions in the same space; NaN rows are absent.
    distance_scale : float
        ``d₀`` (> 0) of the similarity :func:`point_similarity`, in the units of the space.
    track_ids : ndarray of int (R, K, S), optional
        Track identity per slot (−1 empty); default: the slot.
    truth_ids : ndarray of int (R, K, T), optional
        Target identity per slot (−1 empty); default: the slot. Identities are unique within a scan.
    angular : bool
        The components are angles (radians): differences wrap.
    alphas : ndarray (A,)
        Localisation thresholds.
    method : {"auto", "plain", "sparse"}
        ``"plain"``: run by run on dense similarity matrices, the definitions as written;
        ``"sparse"``: all runs at once on the pairs with S > 0 only (the same sums up to
        rounding, tested); ``"auto"``: sparse from :data:`SPARSE_FROM_PAIRS` pairs on.
    pairs : tuple, optional
        :func:`trackreplay.evaluators.assignment_metrics.gated_pairs` of the same sets at a gate of at
        least ``distance_scale`` (those closer than ``d₀`` are kept), when already found: the
        sparse form starts from them instead of searching again.

    Returns
    -------
    dict of ndarray (R, A)
        ``tp``, ``fn``, ``fp`` (counts), ``loc_sum`` (Σ S over the TPs), ``ass_sum`` (Σ A(c) over
        the TPs), ``ass_re_sum`` and ``ass_pr_sum`` (the same for association recall and
        precision); and ``alphas`` (A,).
    """
    tracks, truths = np.asarray(tracks, float), np.asarray(truths, float)
    alphas = np.asarray(alphas, float)
    R = tracks.shape[0]
    if method == "sparse" or (method == "auto" and truths[..., 0].size * tracks.shape[2] >= SPARSE_FROM_PAIRS):
        out = _sums_sparse(tracks, truths, float(distance_scale), track_ids, truth_ids, angular, alphas, pairs)
        out["alphas"] = alphas
        return out
    out = {key: np.zeros((R, alphas.size)) for key in SUM_KEYS}
    for r in range(R):
        one = _one_run(tracks[r], truths[r], float(distance_scale), None if track_ids is None else track_ids[r],
                       None if truth_ids is None else truth_ids[r], angular, alphas)
        for key in SUM_KEYS:
            out[key][r] = one[key]
    out["alphas"] = alphas
    return out


def _compact(ids, present):
    """Identities (K, n) as 0…U−1 (−1 absent) and U."""
    uniq = np.unique(ids[present])
    return np.where(present, np.searchsorted(uniq, np.where(present, ids, uniq[0] if uniq.size else 0)), -1), uniq.size


def _one_run(tracks, truths, d0, track_ids, truth_ids, angular, alphas) -> dict:
    """The sums of :func:`hota_sums` for one run (tracks (K, S, d), truths (K, T, d))."""
    vy = all_finite(tracks)
    vx = all_finite(truths)
    gid_raw = np.broadcast_to(np.arange(vx.shape[-1]), vx.shape) if truth_ids is None else np.asarray(truth_ids)
    tid_raw = np.broadcast_to(np.arange(vy.shape[-1]), vy.shape) if track_ids is None else np.asarray(track_ids)
    vx, vy = vx & (gid_raw >= 0), vy & (tid_raw >= 0)
    gid, n_truth_ids = _compact(gid_raw, vx)
    tid, n_track_ids = _compact(tid_raw, vy)
    A = alphas.size
    n_truth, n_track = int(vx.sum()), int(vy.sum())
    if n_truth == 0 or n_track == 0:
        zeros = np.zeros(A)
        return {"tp": zeros, "fn": np.full(A, n_truth), "fp": np.full(A, n_track), "loc_sum": zeros,
                "ass_sum": zeros, "ass_re_sum": zeros, "ass_pr_sum": zeros}
    pair = vx[:, :, None] & vy[:, None, :]                                          # (K, T, S)
    d = pairwise_distance(np.where(vx[..., None], truths, 0.0), np.where(vy[..., None], tracks, 0.0), angular)
    sim = np.where(pair, point_similarity(d, d0), 0.0)

    # 1. global alignment score between identities, from each scan's normalised similarity
    denom = sim.sum(axis=1, keepdims=True) + sim.sum(axis=2, keepdims=True) - sim
    soft = np.where(denom > _EPS, sim / np.where(denom > _EPS, denom, 1.0), 0.0)
    key = gid[:, :, None] * n_track_ids + tid[:, None, :]                          # (K, T, S)
    potential = np.bincount(key[pair], weights=soft[pair], minlength=n_truth_ids * n_track_ids)
    potential = potential.reshape(n_truth_ids, n_track_ids)
    truth_count = np.bincount(gid[vx], minlength=n_truth_ids).astype(float)[:, None]
    track_count = np.bincount(tid[vy], minlength=n_track_ids).astype(float)[None, :]
    alignment = potential / (truth_count + track_count - potential)

    # 2. one assignment per scan maximising Σ A·S (the same for every α)
    score = np.where(pair, alignment[np.maximum(gid, 0)[:, :, None], np.maximum(tid, 0)[:, None, :]] * sim, 0.0)
    _, match = optimal_assignment(-score, vx, vy, unmatched=0.0)                   # (K, T)
    k_m, t_m = np.nonzero(match >= 0)
    s_m = match[k_m, t_m]
    sim_m = sim[k_m, t_m, s_m]
    key_m = key[k_m, t_m, s_m]

    # 3.–4. per α: TPs, and per identity pair the TPA count that gives A(c)
    out = {k: np.zeros(A) for k in SUM_KEYS}
    for a, alpha in enumerate(alphas):
        tp = sim_m >= alpha - _EPS
        n_tp = int(tp.sum())
        out["tp"][a], out["fn"][a], out["fp"][a] = n_tp, n_truth - n_tp, n_track - n_tp
        if n_tp == 0:
            continue
        out["loc_sum"][a] = sim_m[tp].sum()
        tpa = np.bincount(key_m[tp], minlength=n_truth_ids * n_track_ids).reshape(n_truth_ids, n_track_ids)
        # Σ_c A(c) over the TPs = Σ over identity pairs of |TPA| · A(pair)
        out["ass_sum"][a] = np.sum(tpa * (tpa / np.maximum(1.0, truth_count + track_count - tpa)))
        out["ass_re_sum"][a] = np.sum(tpa * (tpa / np.maximum(1.0, truth_count)))
        out["ass_pr_sum"][a] = np.sum(tpa * (tpa / np.maximum(1.0, track_count)))
    return out


def _sums_sparse(tracks, truths, d0, track_ids, truth_ids, angular, alphas, pairs=None) -> dict:
    """:func:`hota_sums` for all runs at once from the pairs with S > 0 (d < d₀) alone."""
    R, K, T = truths.shape[:3]
    S = tracks.shape[2]
    truth_id = np.broadcast_to(np.arange(T), (R, K, T)) if truth_ids is None else np.asarray(truth_ids)
    track_id = np.broadcast_to(np.arange(S), (R, K, S)) if track_ids is None else np.asarray(track_ids)
    vx = all_finite(truths) & (truth_id >= 0)
    vy = all_finite(tracks) & (track_id >= 0)
    g_id, n_g, g_run = global_identities(truth_id, vx)
    h_id, n_h, h_run = global_identities(track_id, vy)
    truth_count = np.bincount(g_id[vx], minlength=n_g).astype(float)
    track_count = np.bincount(h_id[vy], minlength=n_h).astype(float)
    n_truth, n_track = vx.sum(axis=(1, 2)), vy.sum(axis=(1, 2))
    if pairs is None:
        pairs = close_pairs(absent_as_nan(truths, vx).reshape(R * K, T, -1),
                            absent_as_nan(tracks, vy).reshape(R * K, S, -1), d0, angular)
    p, i, j, d = pairs_within(pairs, d0)
    sim = point_similarity(d, d0)
    # 1. global alignment from each scan's normalised similarity
    row_sum = np.bincount(p * T + i, weights=sim, minlength=R * K * T)
    col_sum = np.bincount(p * S + j, weights=sim, minlength=R * K * S)
    denom = row_sum[p * T + i] + col_sum[p * S + j] - sim
    soft = np.where(denom > _EPS, sim / np.where(denom > _EPS, denom, 1.0), 0.0)
    g, h = g_id.reshape(-1)[p * T + i], h_id.reshape(-1)[p * S + j]
    pair_g, pair_h, pair, _ = identity_pairs(g, h, g_run, h_run)
    potential = np.bincount(pair, weights=soft, minlength=pair_g.size)
    alignment = potential / (truth_count[pair_g] + track_count[pair_h] - potential)
    # 2. every scan's assignment on A·S
    chosen = assign_edges(p, i, j, alignment[pair] * sim, T, S)
    sim_c, run_c, pair_c = sim[chosen], p[chosen] // K, pair[chosen]
    pair_run = g_run[pair_g]
    # a TP at α is one at every smaller α: count each by the number of α it passes, then add up
    level = _alpha_levels(alphas, sim_c)
    A = alphas.size

    def over_alphas(group, n_groups, weights=None):
        """Σ over the TPs of each group at each α (n_groups, A)."""
        h = np.bincount(group * (A + 1) + level, weights, minlength=n_groups * (A + 1)).reshape(n_groups, A + 1)
        return np.cumsum(h[:, ::-1], axis=1)[:, ::-1][:, 1:]

    n_tp = over_alphas(run_c, R)
    tpa = over_alphas(pair_c, pair_g.size).astype(float)                      # (pairs, A)
    g_count, h_count = truth_count[pair_g][:, None], track_count[pair_h][:, None]
    per_run = lambda v: np.stack([np.bincount(pair_run, v[:, a], minlength=R) for a in range(A)], axis=1)  # noqa: E731
    out = {"tp": n_tp.astype(float), "fn": (n_truth[:, None] - n_tp).astype(float),
           "fp": (n_track[:, None] - n_tp).astype(float), "loc_sum": over_alphas(run_c, R, sim_c),
           "ass_sum": per_run(tpa * (tpa / np.maximum(1.0, g_count + h_count - tpa))),
           "ass_re_sum": per_run(tpa * (tpa / np.maximum(1.0, g_count))),
           "ass_pr_sum": per_run(tpa * (tpa / np.maximum(1.0, h_count)))}
    return out


def _sums_single(tracks, truths, d0, track_ids=None, truth_ids=None, angular=False, alphas=HOTA_ALPHAS,
                 view: SinglePair | None = None) -> dict:
    """:func:`hota_sums` of sets of one track and one target slot ``(R, K, 1, d)`` whose
    identities are one per run (:func:`trackreplay.evaluators.set_distances.one_identity_per_run`), from
    the distance of the one pair per (run, scan) (``view``,
    :func:`trackreplay.evaluators.set_distances_shared.single_pair_view` of the same sets, when already
    found).

    With one pair a scan, a scan's normalised similarity is 1 wherever S > ε (S / (S + S − S)),
    so the alignment of a run's one identity pair is its count of such scans over
    ``n_g + n_h −`` that count, and each scan's assignment takes the pair whenever A·S > 0.
    The sums are then added as :func:`_sums_sparse` adds them (the same order), so the values
    are the same.
    """
    alphas, d0 = np.asarray(alphas, float), float(d0)
    if view is None:
        view = single_pair_view(tracks, truths, track_ids, truth_ids, angular)
    vx, vy, d = view.truth_present, view.track_present, view.distance
    R, K = vx.shape
    close = vx & vy & (d < d0)
    sim = np.where(close, point_similarity(np.where(close, d, 0.0), d0), 0.0)
    n_truth, n_track = vx.sum(axis=1), vy.sum(axis=1)
    potential = (close & (sim > _EPS)).sum(axis=1).astype(float)
    alignment = potential / np.maximum(n_truth + n_track - potential, 1.0)
    # the pair's weight A·S in the scan's assignment: taken when positive
    chosen = close & (alignment[:, None] * sim > 0)
    A = alphas.size
    # each scan's bin (run, the number of α its TP passes), found once for the counts and the
    # sums; a scan without a TP goes to its run's bin 0, which counts no α and is dropped, so
    # the TPs' bins get the very additions, in the same order, as from the TPs alone
    key = _alpha_levels(alphas, sim) * chosen                     # 0 where no TP
    key += (np.arange(R) * (A + 1))[:, None]
    key = key.reshape(-1)
    sim_c = np.where(chosen, sim, 0.0).reshape(-1)

    def over_alphas(weights=None):
        """Σ over each run's TPs at each α (R, A)."""
        h = np.bincount(key, weights, minlength=R * (A + 1)).reshape(R, A + 1)
        return np.cumsum(h[:, ::-1], axis=1)[:, ::-1][:, 1:]

    n_tp = over_alphas()
    tpa = n_tp.astype(float)
    g_count, h_count = n_truth[:, None].astype(float), n_track[:, None].astype(float)
    return {"tp": n_tp.astype(float), "fn": (n_truth[:, None] - n_tp).astype(float),
            "fp": (n_track[:, None] - n_tp).astype(float), "loc_sum": over_alphas(sim_c),
            "ass_sum": tpa * (tpa / np.maximum(1.0, g_count + h_count - tpa)),
            "ass_re_sum": tpa * (tpa / np.maximum(1.0, g_count)),
            "ass_pr_sum": tpa * (tpa / np.maximum(1.0, h_count)), "alphas": alphas}


def _alpha_levels(alphas, similarity):
    """``np.searchsorted(alphas − ε, similarity, side="right")``, the number of thresholds each
    similarity passes, for increasing thresholds about evenly spaced (HOTA's α): a first guess
    from the spacing, then moved a step down or up by the exact comparisons while any is off
    (one round for :data:`HOTA_ALPHAS`, where a binary search of 19 values per similarity
    costs several times as much). Anything else goes to ``searchsorted`` itself."""
    edges = np.asarray(alphas, float) - _EPS
    A = edges.size
    if (A < 2 or not np.all(np.isfinite(edges)) or not np.all(np.diff(edges) > 0)
            or not np.all(np.isfinite(similarity))):
        return np.searchsorted(edges, similarity, side="right")
    guess = (similarity - edges[0]) * ((A - 1) / (edges[-1] - edges[0]))
    guess += 1.0
    np.floor(guess, out=guess)
    np.clip(guess, 0, A, out=guess)
    level = guess.astype(np.intp)
    # the level passes edges[level − 1] and not edges[level] (−∞ and +∞ beyond the ends)
    passed = np.r_[-np.inf, edges]
    next_edge = np.r_[edges, np.inf]
    for _ in range(A + 1):
        down = similarity < passed[level]
        up = similarity >= next_edge[level]
        if not (down.any() or up.any()):
            break
        level -= down
        level += up
    return level


def pooled_hota(sums: dict, runs=None) -> dict:
    """HOTA and its parts of the runs ``runs`` (default: all) from :func:`hota_sums`.

    The counts and sums are added over the runs first and the ratios formed from the totals;
    never an average of per-run HOTA.

    Returns
    -------
    dict
        Floats ``hota``, ``deta``, ``assa``, ``loca``, ``detre``, ``detpr``, ``assre``,
        ``asspr`` (each the mean over α), and the same per α as arrays (A,) under
        ``<name>_alpha``.
    """
    pick = slice(None) if runs is None else np.asarray(runs)
    total = {key: np.asarray(sums[key])[pick].sum(axis=0) for key in SUM_KEYS}
    tp, fn, fp = total["tp"], total["fn"], total["fp"]
    per_alpha = {
        "deta": tp / np.maximum(1.0, tp + fn + fp),
        "detre": tp / np.maximum(1.0, tp + fn),
        "detpr": tp / np.maximum(1.0, tp + fp),
        "assa": total["ass_sum"] / np.maximum(1.0, tp),
        "assre": total["ass_re_sum"] / np.maximum(1.0, tp),
        "asspr": total["ass_pr_sum"] / np.maximum(1.0, tp),
        # 1 at an α without TP (TrackEval's convention)
        "loca": np.maximum(1e-10, total["loc_sum"]) / np.maximum(1e-10, tp),
    }
    per_alpha["hota"] = np.sqrt(per_alpha["deta"] * per_alpha["assa"])
    out = {name: float(np.mean(v)) for name, v in per_alpha.items()}
    out.update({f"{name}_alpha": v for name, v in per_alpha.items()})
    return out


def hota(tracks, truths, distance_scale: float, track_ids=None, truth_ids=None, angular: bool = False) -> dict:
    """HOTA, DetA, AssA, LocA (and recall/precision parts) pooled over all runs: :func:`pooled_hota`
    of :func:`hota_sums`."""
    return pooled_hota(hota_sums(tracks, truths, distance_scale, track_ids, truth_ids, angular))
