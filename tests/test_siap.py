"""SIAP measures (evaluators/siap.py): equal to Stone Soup's SIAPMetrics on the same tracks, each
definition by hand on tiny cases, and the differences kept on purpose."""

from __future__ import annotations

from datetime import datetime, timedelta

import numpy as np
import pytest
from stonesoup.dataassociator.tracktotrack import TrackToTruth
from stonesoup.measures import Euclidean
from stonesoup.metricgenerator.manager import MultiManager
from stonesoup.metricgenerator.tracktotruthmetrics import SIAPMetrics
from stonesoup.types.groundtruth import GroundTruthPath, GroundTruthState
from stonesoup.types.state import State
from stonesoup.types.track import Track

from trackreplay.evaluators.assignment_metrics import scan_matches
from trackreplay.evaluators.siap import MEASURES, pooled_siap, siap, siap_sums

NAN = np.nan
T0 = datetime(2026, 1, 1)
TITLES = {"completeness": "SIAP Completeness", "ambiguity": "SIAP Ambiguity",
          "spuriousness": "SIAP Spuriousness", "position_accuracy": "SIAP Position Accuracy",
          "velocity_accuracy": "SIAP Velocity Accuracy",
          "track_number_change_rate": "SIAP Rate of Track Number Change",
          "longest_track_segment": "SIAP Longest Track Segment"}


# ---------------------------------------------------------------- Stone Soup on our arrays
def stone_soup_siap(tracks, truths, track_ids, truth_ids, times, gate, runs=None):
    """Stone Soup's SIAPMetrics of the runs ``runs`` (default all) pooled: every run gets its own
    stretch of time (runs never overlap), so its sums over timestamps are the sums over runs.
    States are [x, y, vx, vy]."""
    runs = range(tracks.shape[0]) if runs is None else runs
    span = float(times[-1] - times[0]) + 1000.0
    truth_paths, track_list = [], []
    for n, r in enumerate(runs):
        stamp = lambda k: T0 + timedelta(seconds=n * span + float(times[k]))  # noqa: E731
        for objects, ids, kind in ((truths[r], truth_ids[r], "truth"), (tracks[r], track_ids[r], "track")):
            states = {}
            for k in range(objects.shape[0]):
                for s in range(objects.shape[1]):
                    if ids[k, s] >= 0 and np.isfinite(objects[k, s]).all():
                        states.setdefault(int(ids[k, s]), []).append((k, objects[k, s]))
            for ident, seq in states.items():
                if kind == "truth":
                    truth_paths.append(GroundTruthPath([GroundTruthState(v.reshape(-1, 1), timestamp=stamp(k))
                                                        for k, v in seq]))
                else:
                    track_list.append(Track([State(v.reshape(-1, 1), timestamp=stamp(k)) for k, v in seq]))
    generator = SIAPMetrics(position_measure=Euclidean((0, 1)), velocity_measure=Euclidean((2, 3)))
    associator = TrackToTruth(association_threshold=gate, consec_pairs_confirm=1, consec_misses_end=1,
                              measure=Euclidean((0, 1)))
    manager = MultiManager([generator], associator)
    manager.add_data({"tracks": track_list, "groundtruth_paths": truth_paths})
    metrics = manager.generate_metrics()["siap_generator"]
    return {key: float(metrics[title].value) for key, title in TITLES.items()}


def ours(tracks, truths, track_ids, truth_ids, times, gate, runs=None):
    sums = siap_sums(tracks[..., :2], truths[..., :2], gate, times, track_ids, truth_ids,
                     track_velocities=tracks[..., 2:], truth_velocities=truths[..., 2:])
    return pooled_siap(sums, runs)


# ---------------------------------------------------------------- synthetic scenes
def scene(seed, R=4, K=30, n_targets=6, gate=50.0, clutter=3, duplicates=2, switches=1, dt=2.0):
    """Targets born and dying (lives ≥ 4 scans) far apart (> 4 gates), a track on each from a
    scan or two after birth (noise ≪ gate; lost and restarted with a new identity now and then),
    duplicate tracks on some targets, clutter tracks far from every target and identity switches
    (two tracks exchange targets). Every association lasts ≥ 2 scans (Stone Soup cannot hold a
    single-scan one). Returns tracks (R, K, S, 4), truths (R, K, T, 4), their ids, times."""
    rng = np.random.default_rng(seed)
    times = np.round(dt * np.arange(K) + rng.uniform(0, 0.5, K).cumsum(), 3)   # whole microseconds
    S, T = n_targets + duplicates + clutter + 4, n_targets
    tracks = np.full((R, K, S, 4), NAN)
    truths = np.full((R, K, T, 4), NAN)
    track_ids = np.full((R, K, S), -1)
    truth_ids = np.full((R, K, T), -1)
    for r in range(R):
        next_id = 100
        lives = []
        for t in range(T):
            birth = int(rng.integers(0, K // 3))
            death = int(rng.integers(birth + 4, K + 1))
            start = np.array([1000.0 * t, 1000.0 * (t % 2)]) + rng.uniform(-50, 50, 2)
            vel = rng.uniform(-5, 5, 2)
            for k in range(birth, death):
                truths[r, k, t] = np.r_[start + vel * (times[k] - times[birth]), vel]
                truth_ids[r, k, t] = 10 * t + 3
            lives.append((birth, death))
        noisy = lambda r, k, t: truths[r, k, t] + np.r_[rng.normal(0, 5, 2), rng.normal(0, 1, 2)]  # noqa: E731
        for t, (birth, death) in enumerate(lives):
            first = birth + int(rng.integers(0, 3))
            last = death - int(rng.integers(0, 2))        # exclusive
            cut = int(rng.integers(first + 2, last - 1)) if last - first >= 7 and rng.random() < 0.4 else None
            pieces = [(first, last)] if cut is None else [(first, cut), (cut + 2, last)]
            for a, b in pieces:
                if b - a < 2:
                    continue
                for k in range(a, b):
                    tracks[r, k, t] = noisy(r, k, t)
                    track_ids[r, k, t] = next_id
                next_id += 1
        for n in range(duplicates):                       # a second track on a target for a while
            t = int(rng.integers(0, T))
            birth, death = lives[t]
            if death - birth < 5:
                continue
            a = int(rng.integers(birth, death - 3))
            b = int(rng.integers(a + 2, death + 1))
            for k in range(a, b):
                tracks[r, k, T + n] = noisy(r, k, t)
                track_ids[r, k, T + n] = next_id
            next_id += 1
        for n in range(clutter):                          # false tracks far from every target
            a = int(rng.integers(0, K - 2))
            b = int(rng.integers(a + 1, K + 1))
            for k in range(a, b):
                tracks[r, k, T + duplicates + n] = np.r_[rng.uniform(-5e4, -1e4, 2), rng.normal(0, 5, 2)]
                track_ids[r, k, T + duplicates + n] = next_id
            next_id += 1
        for _ in range(switches):                         # two tracks exchange targets from scan m on
            t1, t2 = rng.choice(T, 2, replace=False)
            both = [k for k in range(2, K - 2) if (track_ids[r, k - 2:k + 2, [t1, t2]] >= 0).all()]
            if both:
                m = both[len(both) // 2]
                ids1, ids2 = track_ids[r, m:, t1].copy(), track_ids[r, m:, t2].copy()
                same1, same2 = ids1 == track_ids[r, m - 1, t1], ids2 == track_ids[r, m - 1, t2]
                track_ids[r, m:, t1] = np.where(same1, track_ids[r, m - 1, t2], ids1)
                track_ids[r, m:, t2] = np.where(same2, track_ids[r, m - 1, t1], ids2)
    return tracks, truths, track_ids, truth_ids, times


@pytest.mark.parametrize("seed", [1, 2, 3, 4])
def test_equal_to_stone_soup(seed):
    """Pooled over all runs and over a subset of runs: Stone Soup's SIAPMetrics on the same tracks
    (TrackToTruth associating each track with its nearest truth within the gate at every scan)."""
    gate = 50.0
    tracks, truths, track_ids, truth_ids, times = scene(seed, gate=gate)
    for runs in (None, [0, 2]):
        theirs = stone_soup_siap(tracks, truths, track_ids, truth_ids, times, gate, runs)
        mine = ours(tracks, truths, track_ids, truth_ids, times, gate, runs)
        for key in MEASURES:
            assert mine[key] == pytest.approx(theirs[key], rel=1e-9, abs=1e-12), (seed, runs, key)
    # the scenes hold what SIAP is about
    m = ours(tracks, truths, track_ids, truth_ids, times, gate)
    assert m["ambiguity"] > 1 and 0 < m["spuriousness"] < 1 and m["track_number_change_rate"] > 0
    assert 0 < m["completeness"] < 1 and 0 < m["longest_track_segment"] < 1


# ---------------------------------------------------------------- definitions by hand
def tiny():
    """One run, 5 scans 1 s apart (times 0, 1, 3, 4, 6), two targets (ids 7, 8), three tracks.

    target 7 at x = 0 on scans 0–4; target 8 at x = 100 on scans 1–3.
    track 1 on 7 (error 1) at scans 0–2; track 2 on 7 (error 2) at scans 2–4 (a duplicate at 2);
    track 3 on 8 (error 3) at scans 1–2, then at x = 1000 (clutter) at 3."""
    times = np.array([0.0, 1.0, 3.0, 4.0, 6.0])
    truths = np.full((1, 5, 2, 2), NAN)
    truth_ids = np.full((1, 5, 2), -1)
    truths[0, :, 0] = [0.0, 0.0]
    truth_ids[0, :, 0] = 7
    truths[0, 1:4, 1] = [100.0, 0.0]
    truth_ids[0, 1:4, 1] = 8
    tracks = np.full((1, 5, 3, 2), NAN)
    ids = np.full((1, 5, 3), -1)
    tracks[0, 0:3, 0] = [1.0, 0.0]
    ids[0, 0:3, 0] = 1
    tracks[0, 2:5, 1] = [0.0, 2.0]
    ids[0, 2:5, 1] = 2
    tracks[0, 1:3, 2] = [100.0, 3.0]
    tracks[0, 3, 2] = [1000.0, 0.0]
    ids[0, 1:4, 2] = 3
    return tracks, truths, ids, truth_ids, times


def test_definitions_by_hand():
    tracks, truths, ids, truth_ids, times = tiny()
    s = siap_sums(tracks, truths, 10.0, times, ids, truth_ids)
    # J: 1, 2, 2, 2, 1 = 8; JT: 1, 2, 2, 1, 1 = 7; N: 1, 2, 3, 2, 1 = 9; NA: 1, 2, 3, 1, 1 = 8
    assert [s[k][0] for k in ("truths", "tracked_truths", "tracks", "associated_tracks")] == [8, 7, 9, 8]
    # errors: track 1 three times 1, track 2 three times 2, track 3 twice 3
    assert s["position_error_sum"][0] == 3 * 1 + 3 * 2 + 2 * 3
    # target 7: segments track 1 [0, 2] (3 s), track 2 [2, 4] (3 s): NU 2, TT 6 s, TL 3 s, T 6 s
    # target 8: segment track 3 [1, 2] (2 s): NU 1, TT 2 s, TL 2 s, T 3 s
    assert s["track_number_changes"][0] == 1
    assert s["time_tracked"][0] == 6 + 2
    assert s["longest_segment_time"][0] == 3 + 2
    assert s["truth_lifetime"][0] == 6 + 3
    m = pooled_siap(s)
    assert m["completeness"] == 7 / 8 and m["ambiguity"] == 8 / 7 and m["spuriousness"] == 1 / 9
    assert m["position_accuracy"] == 15 / 8
    assert m["track_number_change_rate"] == 1 / 8 and m["longest_track_segment"] == 5 / 9
    # and Stone Soup says the same (with zero velocities)
    pad = lambda a: np.concatenate([a, np.zeros(a.shape)], axis=-1)  # noqa: E731
    theirs = stone_soup_siap(pad(tracks), pad(truths), ids, truth_ids, times, 10.0)
    for key in MEASURES:
        assert m.get(key, 0.0) == pytest.approx(theirs[key]) or key == "velocity_accuracy"


def test_empty_conventions():
    """Stone Soup's values where a ratio has nothing to count: ambiguity 1, the rest 0."""
    tracks = np.full((2, 3, 1, 2), NAN)
    truths = np.zeros((2, 3, 1, 2))
    m = siap(tracks, truths, 5.0)
    assert m["completeness"] == 0 and m["ambiguity"] == 1 and m["spuriousness"] == 0
    assert m["position_accuracy"] == 0 and m["track_number_change_rate"] == 0 and m["longest_track_segment"] == 0
    m = siap(np.ones((1, 3, 1, 2)), np.full((1, 3, 1, 2), NAN), 5.0)
    assert m["spuriousness"] == 1 and m["completeness"] == 0 and m["longest_track_segment"] == 0


def test_pooled_is_sum_over_runs_not_mean():
    """A subset of runs pools its sums: a run with many targets weighs more."""
    tracks, truths, ids, truth_ids, times = scene(5, R=3)
    s = siap_sums(tracks[..., :2], truths[..., :2], 50.0, times, ids, truth_ids)
    whole = pooled_siap(s)
    by_hand = s["tracked_truths"].sum() / s["truths"].sum()
    assert whole["completeness"] == pytest.approx(by_hand)
    alone = siap(tracks[1:2, ..., :2], truths[1:2, ..., :2], 50.0, times, ids[1:2], truth_ids[1:2])
    assert pooled_siap(s, [1]) == pytest.approx(alone, nan_ok=True)


def test_nearest_truth_not_one_to_one():
    """Two tracks on one target: SIAP associates both (ambiguity 2), where the one-to-one
    assignment of the CLEAR measures matches one and calls the other a false positive."""
    truths = np.array([[[[0.0, 0.0]], [[1.0, 0.0]]]])                # (1, 2, 1, 2)
    tracks = np.array([[[[0.5, 0.0], [0.0, 1.0]], [[1.5, 0.0], [1.0, 1.0]]]])
    m = siap(tracks, truths, 5.0)
    assert m["ambiguity"] == 2 and m["spuriousness"] == 0
    match, _ = scan_matches(tracks, truths, 5.0)
    assert (match >= 0).sum() == 2                                   # one track per scan


def test_fewest_tracks_differs_from_stone_soup_walk():
    """On purpose unlike Stone Soup 1.9: NU_j is the fewest segments covering the tracked scans.
    Stone Soup's walk lands on scan 3, where the only segment holding it (track 2, scans 1–3)
    ends, and stops there: it never counts track 3 (scans 5–6), NU 2 instead of 3."""
    times = np.arange(7.0)
    truths = np.zeros((1, 7, 1, 4))
    truth_ids = np.zeros((1, 7, 1), int)
    tracks = np.full((1, 7, 3, 4), NAN)
    ids = np.full((1, 7, 3), -1)
    for slot, (a, b) in enumerate([(0, 3), (1, 4), (5, 7)]):
        tracks[0, a:b, slot] = [1.0, 0.0, 0.0, 0.0]
        ids[0, a:b, slot] = slot + 1
    mine = ours(tracks, truths, ids, truth_ids, times, 5.0)
    theirs = stone_soup_siap(tracks, truths, ids, truth_ids, times, 5.0)
    s = siap_sums(tracks[..., :2], truths[..., :2], 5.0, times, ids, truth_ids)
    assert s["track_number_changes"][0] == 2 and s["time_tracked"][0] == 4  # 0–2, 1–3, 5–6
    assert mine["track_number_change_rate"] == 2 / 4
    assert theirs["track_number_change_rate"] == 1 / 4
    for key in set(MEASURES) - {"track_number_change_rate"}:
        assert mine[key] == pytest.approx(theirs[key])


def test_single_scan_association_counts():
    """On purpose unlike Stone Soup 1.9, which cannot hold an association of one scan (its
    TimeRange refuses start = end): a track near a target at one scan is associated there."""
    truths = np.zeros((1, 3, 1, 4))
    tracks = np.full((1, 3, 1, 4), NAN)
    tracks[0, :, 0] = [[1.0, 0, 0, 0], [500.0, 0, 0, 0], [1.0, 0, 0, 0]]
    ids = np.ones((1, 3, 1), int)
    m = ours(tracks, truths, ids, np.zeros((1, 3, 1), int), np.arange(3.0), 5.0)
    assert m["completeness"] == 2 / 3 and m["spuriousness"] == 1 / 3
    assert m["longest_track_segment"] == 0 and m["track_number_change_rate"] == 0  # NU 2, TT 0
    with pytest.raises(ValueError):
        stone_soup_siap(tracks, truths, ids, np.zeros((1, 3, 1), int), np.arange(3.0), 5.0)


def test_angles_wrap():
    truths = np.full((1, 2, 1, 1), np.pi - 0.01)
    tracks = np.full((1, 2, 1, 1), -np.pi + 0.01)
    m = siap(tracks, truths, 0.05, angular=True)
    assert m["completeness"] == 1 and m["position_accuracy"] == pytest.approx(0.02)


def test_standard_table_rows():
    """evaluate_standard reports the pooled measures over all runs, velocity accuracy in m/s from
    the radar layout [x, y, vx, vy], each with a grouped-jackknife interval around the value."""
    from trackreplay.evaluators.standard import evaluate_standard, position_space

    tracks, truths, ids, truth_ids, times = scene(6, R=12, K=20)
    space = position_space({"ospa_cutoff_m": 1000.0, "assignment_gate_m": 40.0, "ospa_order": 2,
                            "siap_gate_m": 50.0}, (0, 1, 2, 3), (0, 1))
    assert space.velocity_components == (2, 3) and space.siap_gate == 50.0
    out = {"state": tracks, "flags": np.zeros(ids.shape, np.uint32), "track_id": ids}
    _, summary = evaluate_standard(times, {"t": out}, truths, space, truth_ids=truth_ids)
    row = {m: (v, lo, hi) for m, v, lo, hi in summary.select("metric", "value", "ci_low", "ci_high").iter_rows()}
    expected = ours(tracks, truths, ids, truth_ids, times, 50.0)
    names = {"completeness": "siap_completeness", "ambiguity": "siap_ambiguity",
             "spuriousness": "siap_spuriousness", "position_accuracy": "siap_position_accuracy_m",
             "velocity_accuracy": "siap_velocity_accuracy_m/s",
             "track_number_change_rate": "siap_track_number_change_rate",
             "longest_track_segment": "siap_longest_track_segment"}
    for key, metric in names.items():
        value, lo, hi = row[metric]
        assert value == pytest.approx(expected[key]) and lo <= value <= hi, metric
    # a bearing space has no velocity row, and its accuracy is in degrees
    from trackreplay.evaluators.standard import bearing_space
    bearing = bearing_space({"ospa_cutoff_deg": 10.0, "assignment_gate_deg": 5.0, "ospa_order": 2})
    angles = np.deg2rad(np.array([[[0.0], [1.0]], [[2.0], [3.0]]]))[None]          # (1, 2, 2, 1)
    truth = np.deg2rad(np.array([[[0.5]], [[2.5]]]))[None]                          # (1, 2, 1, 1)
    _, summary = evaluate_standard(np.arange(2.0), {"b": {"state": angles, "flags": np.zeros((1, 2, 2), np.uint32)}},
                                   truth, bearing)
    metrics = dict(summary.select("metric", "value").iter_rows())
    assert "siap_velocity_accuracy_deg/s" not in metrics
    assert metrics["siap_position_accuracy_deg"] == pytest.approx(0.5)
    assert metrics["siap_ambiguity"] == 2


def test_silent_scans_keep_the_segment():
    """On purpose unlike Stone Soup 1.9: a track silent at scan 2 and back on its target keeps
    its segment (LS 1, no track number change) but is associated only where it reports
    (completeness 4/5); Stone Soup counts it at scan 2 and then cannot find its state there."""
    truths = np.zeros((1, 5, 1, 4))
    tracks = np.zeros((1, 5, 1, 4))
    tracks[0, :, 0, 0] = 1.0
    tracks[0, 2] = NAN
    ids, truth_ids = np.ones((1, 5, 1), int), np.zeros((1, 5, 1), int)
    m = ours(tracks, truths, ids, truth_ids, np.arange(5.0), 5.0)
    assert m["completeness"] == 4 / 5 and m["longest_track_segment"] == 1 and m["track_number_change_rate"] == 0
    with pytest.raises(IndexError):
        stone_soup_siap(tracks, truths, ids, truth_ids, np.arange(5.0), 5.0)
