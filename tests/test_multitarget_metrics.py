"""Multi-target measures against their anchors: HOTA, CLEAR MOT and the identity measures against
TrackEval, GOSPA (with its per-scan switching term) against Stone Soup, and the assignment-based
measures against brute force on tiny cases.

The synthetic data sets have births, deaths, missed scans, false tracks (clutter), identity
switches and swaps, and truth and track slots that are reused by different identities. TrackEval
is fed our point tracks through its metric classes' ``eval_sequence`` with a similarity matrix
per scan (one Monte Carlo run is one of its sequences); Stone Soup through
``GOSPAMetric.compute_over_time``. See docs/evaluation.md.
"""

from __future__ import annotations

import datetime
from itertools import permutations

import numpy as np
import pytest
import trackeval
from stonesoup.metricgenerator.ospametric import GOSPAMetric
from stonesoup.types.state import State

from trackreplay.evaluators.assignment_metrics import assignment_metrics, scan_matches
from trackreplay.evaluators.hota import HOTA_ALPHAS, hota_sums, point_similarity, pooled_hota
from trackreplay.evaluators.set_distances import gospa, gospa_switching, pairwise_distance

# ------------------------------------------------------------------ synthetic multi-target data


def synthetic(seed, runs=4, scans=60, targets=8, clutter=0.3, area=400.0, sigma=8.0, swap_rate=0.03, miss=0.1):
    """Tracks (R, K, S, 2), track_ids, truths (R, K, T, 2), truth_ids of targets moving at constant
    velocity, born and dying at random scans, tracked with a one-scan lag by noisy tracks that miss
    scans, swap targets, take new identities (fragments) and are joined by short-lived false
    tracks. Every scan puts its elements in random slots, so slots are reused by different
    identities and an identity wanders between slots. A target parked far away is never tracked
    and a false track parked elsewhere never matches, so that no scan is without truth or tracks
    (TrackEval treats such scans differently: see the tests of the differences below)."""
    rng = np.random.default_rng(seed)
    per_run, T, S = [], 0, 0
    for r in range(runs):
        birth = rng.integers(0, scans // 2, targets)
        death = np.minimum(scans, birth + rng.integers(scans // 4, scans, targets))
        start, velocity = rng.uniform(0, area, (targets, 2)), rng.normal(0, area / scans, (targets, 2))
        position = start[None] + np.arange(scans)[:, None, None] * velocity[None]
        alive = (np.arange(scans)[:, None] >= birth) & (np.arange(scans)[:, None] < death)
        track_of = np.arange(targets) + 1000 * (r + 1)
        next_id = int(track_of.max()) + 1
        false_tracks, history = [], []
        for k in range(scans):
            if rng.random() < swap_rate:                      # two tracks swap their targets
                a, b = rng.choice(targets, 2, replace=False)
                track_of[[a, b]] = track_of[[b, a]]
            if rng.random() < swap_rate:                      # a track restarts with a new identity
                track_of[rng.integers(targets)] = next_id
                next_id += 1
            truth = [(i, position[k, i]) for i in range(targets) if alive[k, i]] + [(99, np.array([5e4, 5e4]))]
            track = [(int(track_of[i]), position[k, i] + rng.normal(0, sigma, 2)) for i in range(targets)
                     if alive[k, i] and k > birth[i] and rng.random() > miss] + [(1, np.array([-5e4, -5e4]))]
            if rng.random() < clutter:
                false_tracks.append([next_id, rng.uniform(0, area, 2), int(rng.integers(1, 6))])
                next_id += 1
            for f in false_tracks:
                if f[2] > 0:
                    track.append((f[0], f[1] + rng.normal(0, 2.0, 2)))
                    f[2] -= 1
            history.append((truth, track))
            T, S = max(T, len(truth)), max(S, len(track))
        per_run.append(history)
    T, S = T + 1, S + 1                                       # a spare slot, so slots move around
    truths, truth_ids = np.full((runs, scans, T, 2), np.nan), np.full((runs, scans, T), -1)
    tracks, track_ids = np.full((runs, scans, S, 2), np.nan), np.full((runs, scans, S), -1)
    for r, history in enumerate(per_run):
        for k, (truth, track) in enumerate(history):
            for slot, (i, p) in zip(rng.permutation(T), truth):
                truths[r, k, slot], truth_ids[r, k, slot] = p, i
            for slot, (i, p) in zip(rng.permutation(S), track):
                tracks[r, k, slot], track_ids[r, k, slot] = p, i
    return tracks, track_ids, truths, truth_ids


DATA_SETS = {
    "sparse": dict(seed=1),
    "dense-swaps": dict(seed=2, area=200.0, swap_rate=0.08, clutter=0.5),
    "many-targets": dict(seed=3, runs=3, scans=80, targets=14, sigma=12.0, miss=0.2),
}


@pytest.fixture(scope="module", params=list(DATA_SETS), ids=list(DATA_SETS))
def data(request):
    return synthetic(**DATA_SETS[request.param])


def test_the_data_sets_reuse_slots_and_move_identities_between_slots(data):
    _, track_ids, _, truth_ids = data
    for ids in (truth_ids, track_ids):
        R, K, n = ids.shape
        slot_holds = [len(set(ids[r, :, j][ids[r, :, j] >= 0])) for r in range(R) for j in range(n)]
        assert max(slot_holds) >= 2                           # a slot held different identities
        moved = [len(set(np.nonzero(ids[r] == i)[1])) for r in range(R) for i in np.unique(ids[r][ids[r] >= 0])]
        assert max(moved) >= 2                                # an identity sat in different slots


# ------------------------------------------------------------------ TrackEval adapters


def trackeval_sequence(tracks, track_ids, truths, truth_ids, similarity):
    """One run as TrackEval's per-sequence data dict, with ``similarity(distances)`` as the
    similarity matrix of every scan (rows truths, columns tracks)."""
    K = tracks.shape[0]
    on_truth, on_track = truth_ids >= 0, track_ids >= 0
    truth_uniq, track_uniq = np.unique(truth_ids[on_truth]), np.unique(track_ids[on_track])
    data = {"gt_ids": [], "tracker_ids": [], "similarity_scores": [], "num_timesteps": K,
            "num_gt_ids": truth_uniq.size, "num_tracker_ids": track_uniq.size,
            "num_gt_dets": int(on_truth.sum()), "num_tracker_dets": int(on_track.sum())}
    for k in range(K):
        g, t = np.flatnonzero(on_truth[k]), np.flatnonzero(on_track[k])
        data["gt_ids"].append(np.searchsorted(truth_uniq, truth_ids[k, g]))
        data["tracker_ids"].append(np.searchsorted(track_uniq, track_ids[k, t]))
        data["similarity_scores"].append(similarity(pairwise_distance(truths[k, g], tracks[k, t])))
    return data


def trackeval_runs(metric, data, similarity):
    tracks, track_ids, truths, truth_ids = data
    return {r: metric.eval_sequence(trackeval_sequence(tracks[r], track_ids[r], truths[r], truth_ids[r], similarity))
            for r in range(tracks.shape[0])}


GATE = 40.0
# our CLEAR matching maximises Σ (1 − (d/gate)²) over the pairs closer than the gate (see
# evaluators/assignment_metrics.py), so TrackEval's CLEAR gets that similarity and a threshold just
# above 0; its Identity counts a pair at similarity ≥ 0.5, which 1 − d/(2·gate) puts at the gate
CLEAR_SIMILARITY = lambda d: np.maximum(0.0, 1.0 - (d / GATE) ** 2)  # noqa: E731
IDENTITY_SIMILARITY = lambda d: 1.0 - d / (2 * GATE)  # noqa: E731
CLEAR = trackeval.metrics.CLEAR({"THRESHOLD": 1e-9, "PRINT_CONFIG": False})
IDENTITY = trackeval.metrics.Identity({"THRESHOLD": 0.5, "PRINT_CONFIG": False})
HOTA_D0 = 50.0

# ------------------------------------------------------------------ HOTA against TrackEval


def test_hota_equals_trackeval_per_run_and_pooled_over_runs(data):
    tracks, track_ids, truths, truth_ids = data
    metric = trackeval.metrics.HOTA()
    theirs = trackeval_runs(metric, data, lambda d: point_similarity(d, HOTA_D0))
    sums = hota_sums(tracks, truths, HOTA_D0, track_ids, truth_ids)
    names = {"hota": "HOTA", "deta": "DetA", "assa": "AssA", "loca": "LocA", "detre": "DetRe", "detpr": "DetPr",
             "assre": "AssRe", "asspr": "AssPr"}
    for r, res in theirs.items():
        ours = pooled_hota(sums, runs=[r])
        for mine, name in names.items():
            np.testing.assert_allclose(ours[f"{mine}_alpha"], res[name], rtol=1e-12, atol=1e-12, err_msg=name)
        np.testing.assert_array_equal(sums["tp"][r], res["HOTA_TP"])
        np.testing.assert_array_equal(sums["fn"][r], res["HOTA_FN"])
        np.testing.assert_array_equal(sums["fp"][r], res["HOTA_FP"])
    # pooled over runs: TrackEval's combination of sequences, also for a subset of the runs (the
    # regrouping behind the Monte Carlo intervals)
    for runs in (list(theirs), list(theirs)[::2]):
        combined = metric.combine_sequences({r: theirs[r] for r in runs})
        ours = pooled_hota(sums, runs=runs)
        for mine, name in names.items():
            assert ours[mine] == pytest.approx(float(np.mean(combined[name])), rel=1e-12, abs=1e-12), name


def test_hota_thresholds_are_trackevals():
    np.testing.assert_array_equal(HOTA_ALPHAS, trackeval.metrics.HOTA().array_labels)


# ------------------------------------------------------------------ CLEAR and identity against TrackEval


def test_clear_and_identity_equal_trackeval_per_run_and_pooled(data):
    tracks, track_ids, truths, truth_ids = data
    ours = assignment_metrics(tracks, truths, GATE, track_ids, truth_ids=truth_ids)     # TrackEval's convention
    match, distance = scan_matches(tracks, truths, GATE, track_ids=track_ids, truth_ids=truth_ids)
    clear = trackeval_runs(CLEAR, data, CLEAR_SIMILARITY)
    ident = trackeval_runs(IDENTITY, data, IDENTITY_SIMILARITY)
    pairs = {"matches": "CLR_TP", "misses": "CLR_FN", "false_positives": "CLR_FP", "id_switches": "IDSW",
             "mostly_tracked": "MT", "partially_tracked": "PT", "mostly_lost": "ML", "track_breaks": "Frag"}
    for r in clear:
        for mine, name in pairs.items():
            assert ours[mine][r] == clear[r][name], (r, name)
        assert ours["mota"][r] == pytest.approx(clear[r]["MOTA"], rel=1e-12)
        # TrackEval's MOTP is the mean similarity of the matches: with this similarity it is
        # 1 − mean(d²)/gate² over our matches; ours is the mean distance of the same matches
        d = distance[r][match[r] >= 0]
        assert clear[r]["MOTP"] == pytest.approx(1 - np.mean(d ** 2) / GATE ** 2, rel=1e-12)
        assert ours["motp"][r] == pytest.approx(np.mean(d), rel=1e-12)
        for mine, name in {"idtp": "IDTP", "idfp": "IDFP", "idfn": "IDFN"}.items():
            assert ours[mine][r] == ident[r][name], (r, name)
        for mine, name in {"idf1": "IDF1", "idp": "IDP", "idr": "IDR"}.items():
            assert ours[mine][r] == pytest.approx(ident[r][name], rel=1e-12), (r, name)
    pooled = CLEAR.combine_sequences(clear)
    total = lambda key: ours[key].sum()  # noqa: E731
    assert 1 - (total("misses") + total("false_positives") + total("id_switches")) / total("presences") == \
        pytest.approx(pooled["MOTA"], rel=1e-12)
    pooled_id = IDENTITY.combine_sequences(ident)
    assert 2 * total("idtp") / (2 * total("idtp") + total("idfp") + total("idfn")) == pytest.approx(pooled_id["IDF1"])


# ------------------------------------------------------------------ GOSPA against Stone Soup


def stone_soup_gospa(tracks, track_ids, truths, truth_ids, c, p, gamma):
    """Stone Soup's GOSPA values per scan of one run: {scan: value dict}."""
    t0 = datetime.datetime(2020, 1, 1)
    measured, measured_ids, true, true_ids = [], [], [], []
    for k in range(tracks.shape[0]):
        when = t0 + datetime.timedelta(seconds=k)
        for j in np.flatnonzero(track_ids[k] >= 0):
            measured.append(State(tracks[k, j][:, None], timestamp=when))
            measured_ids.append(int(track_ids[k, j]))
        for j in np.flatnonzero(truth_ids[k] >= 0):
            true.append(State(truths[k, j][:, None], timestamp=when))
            true_ids.append(int(truth_ids[k, j]))
    metric = GOSPAMetric(c=c, p=p, switching_penalty=gamma)
    values = metric.compute_over_time(measured, measured_ids, true, true_ids).value
    return {int((m.timestamp - t0).total_seconds()): m.value for m in values}


@pytest.mark.parametrize("p", [1, 2])
def test_gospa_and_its_parts_equal_stone_soup(data, p):
    tracks, track_ids, truths, truth_ids = data
    c = 30.0
    ours = gospa_switching(tracks, truths, c, p, 0.0, track_ids, truth_ids)
    plain = gospa(tracks, truths, c, p)
    for r in range(tracks.shape[0]):
        theirs = stone_soup_gospa(tracks[r], track_ids[r], truths[r], truth_ids[r], c, p, 0.0)
        for k, v in theirs.items():
            assert ours["gospa"][r, k] == pytest.approx(v["distance"], rel=1e-9, abs=1e-9)
            assert plain["gospa"][r, k] == pytest.approx(v["distance"], rel=1e-9, abs=1e-9)
            # Stone Soup gives the parts as their share of GOSPA^p
            assert ours["localisation"][r, k] ** p == pytest.approx(v["localisation"], rel=1e-9, abs=1e-9)
            assert ours["missed"][r, k] * c ** p / 2 == pytest.approx(v["missed"], rel=1e-9, abs=1e-9)
            assert ours["false"][r, k] * c ** p / 2 == pytest.approx(v["false"], rel=1e-9, abs=1e-9)


def test_switching_per_truth_equals_stone_soup(data):
    tracks, track_ids, truths, truth_ids = data
    c, gamma = 30.0, 20.0
    ours = gospa_switching(tracks, truths, c, 2, gamma, track_ids, truth_ids, per="truth")
    assert ours["half_switches"].sum() > 10
    for r in range(tracks.shape[0]):
        theirs = stone_soup_gospa(tracks[r], track_ids[r], truths[r], truth_ids[r], c, 2, gamma)
        for k, v in theirs.items():
            assert ours["switching"][r, k] == pytest.approx(v["switching"], rel=1e-9, abs=1e-9), k
            assert ours["gospa_switching"][r, k] == pytest.approx(v["distance"], rel=1e-9, abs=1e-9), k


# ------------------------------------------------------------------ brute force on tiny cases


def _partial_matchings(m, n):
    """Every partial one-to-one matching of m rows and n columns, as lists of (row, col)."""
    out = []
    for size in range(min(m, n) + 1):
        for rows in permutations(range(m), size):
            if list(rows) != sorted(rows):
                continue
            for cols in permutations(range(n), size):
                out.append(list(zip(rows, cols)))
    return out


def _tiny(rng, runs, scans, T, S, spread=3.0):
    truths = rng.uniform(0, spread, (runs, scans, T, 2))
    tracks = truths[:, :, rng.permutation(T)[:S] if S <= T else rng.integers(0, T, S)] + rng.normal(0, 0.6, (runs, scans, S, 2))
    truths[rng.random((runs, scans, T)) < 0.2] = np.nan
    tracks[rng.random((runs, scans, S)) < 0.2] = np.nan
    return tracks, truths


def test_each_scans_matching_is_the_best_partial_matching_by_brute_force():
    rng = np.random.default_rng(11)
    tracks, truths = _tiny(rng, 30, 1, 3, 4)
    gate = 1.0
    match, dist = scan_matches(tracks, truths, gate, keep_previous=False)
    for r in range(30):
        X, Y = truths[r, 0], tracks[r, 0]
        d = pairwise_distance(X, Y)
        ok = np.isfinite(d) & (d < gate)
        best = max(sum(gate ** 2 - d[i, j] ** 2 for i, j in pairs)
                   for pairs in _partial_matchings(*d.shape) if all(ok[i, j] for i, j in pairs))
        ours = sum(gate ** 2 - dist[r, 0, i] ** 2 for i in range(3) if match[r, 0, i] >= 0)
        assert ours == pytest.approx(best, rel=1e-12, abs=1e-12)


def _reference_keep_previous(tracks, truths, gate):
    """Scan by scan, in plain Python: keep each target's previous track while within the gate,
    then the best partial matching of the rest by enumeration."""
    K, T, S = truths.shape[0], truths.shape[1], tracks.shape[1]
    match = -np.ones((K, T), int)
    for k in range(K):
        d = pairwise_distance(truths[k], tracks[k])
        ok = np.isfinite(d) & (d < gate)
        kept = {t: match[k - 1, t] for t in range(T) if k and match[k - 1, t] >= 0 and ok[t, match[k - 1, t]]}
        free_t = [t for t in range(T) if t not in kept]
        free_s = [s for s in range(S) if s not in kept.values()]
        best, best_pairs = -1.0, []
        for pairs in _partial_matchings(len(free_t), len(free_s)):
            pairs = [(free_t[i], free_s[j]) for i, j in pairs]
            if all(ok[t, s] for t, s in pairs):
                value = sum(gate ** 2 - d[t, s] ** 2 for t, s in pairs)
                if value > best + 1e-12:
                    best, best_pairs = value, pairs
        for t, s in list(kept.items()) + best_pairs:
            match[k, t] = s
    return match


def test_keeping_previous_matches_equals_the_plain_rule_by_brute_force():
    rng = np.random.default_rng(12)
    tracks, truths = _tiny(rng, 20, 6, 3, 3, spread=1.5)
    match, _ = scan_matches(tracks, truths, 1.0, keep_previous=True)
    for r in range(20):
        np.testing.assert_array_equal(match[r], _reference_keep_previous(tracks[r], truths[r], 1.0))


def test_idtp_is_the_best_identity_pairing_by_brute_force():
    rng = np.random.default_rng(13)
    R, K = 10, 5
    tracks, truths = _tiny(rng, R, K, 3, 3, spread=1.5)
    # identities unique within a scan, in random slots
    truth_ids = np.where(np.isfinite(truths[..., 0]), np.argsort(rng.random((R, K, 3)), axis=-1), -1)
    track_ids = np.where(np.isfinite(tracks[..., 0]), np.argsort(rng.random((R, K, 3)), axis=-1) + 10, -1)
    a = assignment_metrics(tracks, truths, 1.0, track_ids, truth_ids=truth_ids)
    for r in range(R):
        d = pairwise_distance(truths[r], tracks[r])                      # (K, T, S)
        close = np.isfinite(d) & (d < 1.0)
        gids, tids = np.unique(truth_ids[r][truth_ids[r] >= 0]), np.unique(track_ids[r][track_ids[r] >= 0])
        w = {(g, h): int(np.sum(close & (truth_ids[r][:, :, None] == g) & (track_ids[r][:, None, :] == h)))
             for g in gids for h in tids}
        best = max(sum(w[gids[i], tids[j]] for i, j in pairs) for pairs in _partial_matchings(gids.size, tids.size))
        assert a["idtp"][r] == best


def _reference_hota(tracks, truths, track_ids, truth_ids, d0):
    """HOTA of one run from the paper's definitions, with each scan's assignment found by
    enumerating every partial matching (Luiten et al. 2021, eqs. 5–12 and 18)."""
    K = truths.shape[0]
    sims, present = [], []
    for k in range(K):
        g, t = np.flatnonzero(truth_ids[k] >= 0), np.flatnonzero(track_ids[k] >= 0)
        sims.append(point_similarity(pairwise_distance(truths[k, g], tracks[k, t]), d0))
        present.append((truth_ids[k, g], track_ids[k, t]))
    n_g, n_h, soft = {}, {}, {}
    for (gi, ti), s in zip(present, sims):
        for a in gi:
            n_g[a] = n_g.get(a, 0) + 1
        for b in ti:
            n_h[b] = n_h.get(b, 0) + 1
        for i, a in enumerate(gi):
            for j, b in enumerate(ti):
                den = s[i].sum() + s[:, j].sum() - s[i, j]
                soft[a, b] = soft.get((a, b), 0.0) + (s[i, j] / den if den > 0 else 0.0)
    A = {key: v / (n_g[key[0]] + n_h[key[1]] - v) for key, v in soft.items()}
    chosen = []
    for (gi, ti), s in zip(present, sims):
        best, best_pairs = -1.0, []
        for pairs in _partial_matchings(len(gi), len(ti)):
            value = sum(A[gi[i], ti[j]] * s[i, j] for i, j in pairs)
            if value > best + 1e-12:
                best, best_pairs = value, pairs
        chosen.append([(gi[i], ti[j], s[i, j]) for i, j in best_pairs])
    total_g, total_h = sum(n_g.values()), sum(n_h.values())
    hota, deta, assa = [], [], []
    for alpha in HOTA_ALPHAS:
        tps = [(a, b, s) for scan in chosen for a, b, s in scan if s >= alpha - np.finfo(float).eps]
        tp = len(tps)
        tpa = {}
        for a, b, _ in tps:
            tpa[a, b] = tpa.get((a, b), 0) + 1
        ass = sum(tpa[a, b] / (n_g[a] + n_h[b] - tpa[a, b]) for a, b, _ in tps) / max(tp, 1)
        det = tp / (total_g + total_h - tp)
        deta.append(det)
        assa.append(ass)
        hota.append(np.sqrt(det * ass))
    return np.mean(hota), np.mean(deta), np.mean(assa)


def test_hota_equals_the_papers_definitions_with_brute_force_assignment():
    rng = np.random.default_rng(14)
    R, K = 6, 8
    tracks, truths = _tiny(rng, R, K, 3, 4, spread=2.0)
    truth_ids = np.where(np.isfinite(truths[..., 0]), np.argsort(rng.random((R, K, 3)), axis=-1), -1)
    track_ids = np.where(np.isfinite(tracks[..., 0]), np.argsort(rng.random((R, K, 4)), axis=-1) + 7, -1)
    sums = hota_sums(tracks, truths, 1.5, track_ids, truth_ids)
    for r in range(R):
        ours = pooled_hota(sums, runs=[r])
        ref = _reference_hota(tracks[r], truths[r], track_ids[r], truth_ids[r], 1.5)
        assert (ours["hota"], ours["deta"], ours["assa"]) == pytest.approx(ref, rel=1e-12, abs=1e-12)


def test_half_switches_on_a_hand_built_history():
    """One track identity (7) over six scans: unassigned (converging), on target 1, on target 2
    (a switch: 2 halves), unassigned (1 half), absent (nothing), on target 2 (1 half)."""
    far = [np.nan, np.nan]
    truth = np.array([[0.0, 0.0], [100.0, 0.0]])                     # targets 1 and 2, fixed
    at = {None: [50.0, 50.0], 1: [0.5, 0.0], 2: [100.5, 0.0], "gone": far}
    states = [None, 1, 2, None, "gone", 2]
    tracks = np.array([[at[s]] for s in states])[None]                 # (1, 6, 1, 2)
    track_ids = np.where(np.isfinite(tracks[..., 0]), 7, -1)
    truths = np.broadcast_to(truth, (1, 6, 2, 2))
    truth_ids = np.broadcast_to(np.array([1, 2]), (1, 6, 2))
    c, gamma = 10.0, 4.0
    out = gospa_switching(tracks, truths, c, 2, gamma, track_ids, truth_ids, per="track")
    np.testing.assert_array_equal(out["half_switches"][0], [0, 0, 2, 1, 0, 1])
    np.testing.assert_allclose(out["switching"][0] ** 2, gamma ** 2 / 2 * np.array([0, 0, 2, 1, 0, 1]))
    np.testing.assert_allclose(out["gospa_switching"][0] ** 2, out["gospa"][0] ** 2 + out["switching"][0] ** 2)
    assert gospa_switching(tracks, truths, c, 2, None, track_ids, truth_ids)["switching"][0, 2] == pytest.approx(c)


# ------------------------------------------------------------------ the defaults and the differences


def test_without_truth_ids_the_slot_metrics_are_unchanged_and_equal_the_identity_path(data):
    # no truth_ids: earlier releases' per-scan convention on slots; the same histories given as
    # identities (truth slot t is identity t) through the per-identity code give the same counts
    tracks, track_ids, truths, _ = data
    slot = assignment_metrics(tracks, truths, GATE, track_ids)
    ids = np.where(np.isfinite(truths[..., 0]), np.arange(truths.shape[2]), -1)
    general = assignment_metrics(tracks, truths, GATE, track_ids, truth_ids=ids, convention="per-scan")
    assert slot.keys() == general.keys()
    for key in slot:
        np.testing.assert_array_equal(slot[key], general[key], err_msg=key)


def _crossing():
    """Two targets on parallel lines 1 apart; track 0 follows target 0 but drifts to within the
    gate of both; at scan 2 it is closer to target 1's line while still within the gate of its
    own target."""
    truths = np.array([[[0.0, 0.0], [0.0, 1.0]]] * 4)[None]
    tracks = np.array([[[0.0, 0.1], [0.0, 0.9]], [[0.0, 0.2], [0.0, 0.8]],
                       [[0.0, 0.7], [0.0, 0.3]], [[0.0, 0.1], [0.0, 0.9]]])[None]
    return tracks, truths


def test_trackeval_convention_keeps_matches_where_the_per_scan_one_switches():
    # at scan 2 the tracks sit on the wrong side but within the gate of their own targets:
    # TrackEval keeps the previous matches (no switch); each scan's own assignment swaps them
    # and back (4 switches). Without truth_ids the per-scan rule stays the default.
    tracks, truths = _crossing()
    ids = np.broadcast_to(np.arange(2), (1, 4, 2))
    per_scan = assignment_metrics(tracks, truths, 1.0)
    trackeval_rule = assignment_metrics(tracks, truths, 1.0, truth_ids=ids)
    assert per_scan["id_switches"][0] == 4 and trackeval_rule["id_switches"][0] == 0
    theirs = CLEAR.eval_sequence(trackeval_sequence(tracks[0], ids[0], truths[0], ids[0],
                                                    lambda d: np.maximum(0.0, 1.0 - d ** 2)))
    assert theirs["IDSW"] == 0


def test_mostly_tracked_at_exactly_80_percent_differs_between_the_conventions():
    truths = np.zeros((1, 5, 1, 1))
    tracks = np.zeros((1, 5, 1, 1))
    tracks[0, 4] = np.nan                                               # matched 4 of 5 scans
    ids = np.zeros((1, 5, 1), int)
    assert assignment_metrics(tracks, truths, 1.0)["mostly_tracked"][0] == 1          # ≥ 80 %
    assert assignment_metrics(tracks, truths, 1.0, truth_ids=ids)["mostly_tracked"][0] == 0  # > 80 %
    theirs = CLEAR.eval_sequence(trackeval_sequence(tracks[0], np.where(np.isfinite(tracks[0, ..., 0]), 0, -1),
                                                    truths[0], ids[0], lambda d: np.maximum(0.0, 1.0 - d ** 2)))
    assert theirs["MT"] == 0 and theirs["PT"] == 1


def test_a_scan_without_tracks_is_a_gap_for_us_not_for_trackeval():
    # TrackEval skips a scan without tracks (or without truth) before it forgets the previous
    # matches, so the target matched before and after it is not fragmented there; for us the
    # target went unmatched at that scan, so its matching resumes: one fragmentation
    truths = np.zeros((1, 3, 1, 1))
    tracks = np.zeros((1, 3, 1, 1))
    tracks[0, 1] = np.nan
    ids = np.zeros((1, 3, 1), int)
    ours = assignment_metrics(tracks, truths, 1.0, truth_ids=ids)
    theirs = CLEAR.eval_sequence(trackeval_sequence(tracks[0], np.where(np.isfinite(tracks[0, ..., 0]), 0, -1),
                                                    truths[0], ids[0], lambda d: np.maximum(0.0, 1.0 - d ** 2)))
    assert ours["track_breaks"][0] == 1 and theirs["Frag"] == 0
    assert ours["misses"][0] == theirs["CLR_FN"] == 1


def test_a_scan_without_tracks_leaves_truths_unassigned_for_us_not_for_stone_soup():
    # Stone Soup records no assignment for the truths of a scan without tracks, so a target
    # tracked before and after by the same track switches nothing; for us it went unassigned
    # and came back: two half switches
    truths = np.zeros((1, 3, 1, 2))
    tracks = np.zeros((1, 3, 1, 2))
    tracks[0, 1] = np.nan
    ids = np.zeros((1, 3, 1), int)
    track_ids = np.where(np.isfinite(tracks[..., 0]), 5, -1)
    ours = gospa_switching(tracks, truths, 1.0, 2, 1.0, track_ids, ids, per="truth")
    theirs = stone_soup_gospa(tracks[0], track_ids[0], truths[0], ids[0], 1.0, 2, 1.0)
    assert ours["half_switches"][0].tolist() == [0, 1, 1]
    assert [theirs[k]["switching"] for k in range(3)] == [0, 0, 0]


def test_switching_per_track_and_per_truth_differ_when_one_track_serves_two_targets():
    # track 5 on target 1, then target 2 (target 1 left without a track): per track one switch
    # (2 halves); per truth target 1 goes assigned → unassigned (1 half) and target 2
    # unassigned → assigned at its first assignment (nothing)
    truths = np.broadcast_to(np.array([[0.0, 0.0], [100.0, 0.0]]), (1, 2, 2, 2))
    tracks = np.array([[[0.0, 0.0]], [[100.0, 0.0]]])[None]
    ids, track_ids = np.broadcast_to(np.array([1, 2]), (1, 2, 2)), np.full((1, 2, 1), 5)
    assert gospa_switching(tracks, truths, 10.0, 2, 1.0, track_ids, ids, per="track")["half_switches"].sum() == 2
    assert gospa_switching(tracks, truths, 10.0, 2, 1.0, track_ids, ids, per="truth")["half_switches"].sum() == 1


# ------------------------------------------------------------------ the fast forms equal the plain ones


def test_hota_sparse_form_equals_the_plain_one(data):
    tracks, track_ids, truths, truth_ids = data
    for ids in ((track_ids, truth_ids), (None, None)):
        plain = hota_sums(tracks, truths, HOTA_D0, *ids, method="plain")
        sparse = hota_sums(tracks, truths, HOTA_D0, *ids, method="sparse")
        for key in ("tp", "fn", "fp", "loc_sum", "ass_sum", "ass_re_sum", "ass_pr_sum"):
            np.testing.assert_allclose(sparse[key], plain[key], rtol=1e-12, atol=1e-12, err_msg=key)


def test_close_pairs_and_edge_matching_equal_the_dense_assignment():
    from trackreplay.evaluators.set_distances import assign_edges, close_pairs, optimal_assignment

    rng = np.random.default_rng(15)
    for m, n in ((3, 9), (12, 12), (20, 7)):
        X, Y = rng.uniform(0, 10, (60, m, 2)), rng.uniform(0, 10, (60, n, 2))
        X[rng.random((60, m)) < 0.2] = np.nan
        Y[rng.random((60, n)) < 0.2] = np.nan
        c = 2.5
        p, i, j, d = close_pairs(X, Y, c)
        D = pairwise_distance(X, Y)
        expected = np.nonzero(D < c)
        for got, want in zip((p, i, j), expected):
            np.testing.assert_array_equal(got, want)
        np.testing.assert_array_equal(d, D[expected])
        w = c ** 2 - d ** 2
        chosen = assign_edges(p, i, j, w, m, n)
        vx, vy = np.isfinite(X[..., 0]), np.isfinite(Y[..., 0])
        total, _ = optimal_assignment(np.minimum(np.where(np.isfinite(D), D, c), c) ** 2, vx, vy, unmatched=c ** 2)
        gain = np.bincount(p[chosen], weights=w[chosen], minlength=60)
        np.testing.assert_allclose(np.maximum(vx.sum(1), vy.sum(1)) * c ** 2 - gain, total, rtol=1e-12)
        for side in (i, j):                                              # one-to-one
            assert len(set(zip(p[chosen], side[chosen]))) == chosen.sum()


def test_gospa_switching_parts_on_large_sets_equal_gospa(data):
    # beyond the brute-force size gospa_switching assigns on the pairs closer than c alone
    tracks, track_ids, truths, truth_ids = data
    assert max(tracks.shape[2], truths.shape[2]) > 6
    for p in (1, 2):
        ours = gospa_switching(tracks, truths, 30.0, p, 0.0, track_ids, truth_ids)
        dense = gospa(tracks, truths, 30.0, p)
        for key in ("gospa", "localisation", "missed", "false", "ospa", "assigned"):
            np.testing.assert_allclose(ours[key], dense[key], rtol=1e-9, atol=1e-9, err_msg=key)
        np.testing.assert_array_equal(ours["gospa_switching"], ours["gospa"])     # γ = 0
