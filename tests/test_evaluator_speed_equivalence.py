"""The evaluators' fast forms give bit for bit what the plain forms they replace give.

* :func:`trackreplay.evaluators.set_distances.close_pairs` through its window along one component
  (:func:`~trackreplay.evaluators.set_distances_fast._close_pairs_windowed`) against every pair of every problem
  (:func:`~trackreplay.evaluators.set_distances._close_pairs_dense`): the same pairs in the same order and
  the same distances, with absent rows, empty sets, pairs at the radius to the last bit,
  bearings wrapping at ±π and many problems in several blocks;
* :func:`trackreplay.evaluators.life_tables.life_tables`, grouped with sorts and counts, against the
  per-identity loop it replaced (kept below as the reference);
* the identity helpers of :mod:`trackreplay.evaluators.set_distances` (numbering, radix orders, pair
  counts, components by propagation) against numpy's and scipy's own.
"""

from __future__ import annotations

import numpy as np
import polars as pl
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from trackreplay.evaluators import set_distances, set_distances_fast
from trackreplay.evaluators.assignment_metrics import scan_matches
from trackreplay.evaluators.life_tables import TARGET_SCHEMA, TRACK_SCHEMA, life_tables
from trackreplay.evaluators.set_distances import _close_pairs_dense, close_pairs, pairwise_distance
from trackreplay.evaluators.set_distances_fast import _close_pairs_windowed

# ------------------------------------------------------------------ close pairs


def assert_same_pairs(got, want):
    """Same problems, rows and distances, in the same order, to the bit and the dtype."""
    assert len(got) == len(want) == 4
    for g, w, name in zip(got, want, ("problem", "i", "j", "distance")):
        assert g.dtype == w.dtype and g.shape == w.shape, name
        assert g.tobytes() == w.tobytes(), name


def padded_sets(seed, problems, m, n, d, scale, absent, lattice, angular):
    """``X`` (P, m, d) and ``Y`` (P, n, d) with NaN rows (absent) and, on a lattice, many pairs
    exactly at integer distances (3-4-5 triangles) so that the radius test is met with equality;
    bearings gather near ±π, some a turn or two away from (−π, π]."""
    rng = np.random.default_rng(seed)
    if angular:
        def draw(shape):
            near_edge = np.pi - rng.uniform(0, 0.2, shape)
            value = np.where(rng.random(shape) < 0.5, near_edge * rng.choice([-1.0, 1.0], shape),
                             rng.uniform(-np.pi, np.pi, shape))
            return value + 2 * np.pi * rng.integers(-2, 3, shape) * (rng.random(shape) < 0.2)
    elif lattice:
        def draw(shape):
            return rng.integers(-6, 7, shape).astype(float) * scale
    else:
        def draw(shape):
            return rng.uniform(-1, 1, shape) * scale
    X, Y = draw((problems, m, d)), draw((problems, n, d))
    X[rng.random((problems, m)) < absent] = np.nan
    Y[rng.random((problems, n)) < absent] = np.nan
    # a single NaN component makes a row absent too
    if m and problems:
        X[rng.random((problems, m)) < absent / 2, rng.integers(0, d)] = np.nan
    return X, Y


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**16), problems=st.integers(0, 40), m=st.integers(0, 12), n=st.integers(0, 12),
       d=st.integers(1, 3), scale=st.sampled_from([1e-3, 1.0, 7.0, 1e5]), absent=st.sampled_from([0.0, 0.3, 1.0]),
       lattice=st.booleans(), radius=st.sampled_from([0.5, 1.0, 5.0, 5.000000000000001, 4.999999999999999, 30.0]))
def test_windowed_close_pairs_equal_every_pair(seed, problems, m, n, d, scale, absent, lattice, radius):
    X, Y = padded_sets(seed, problems, m, n, d, scale, absent, lattice, angular=False)
    r = radius * scale
    want = _close_pairs_dense(X, Y, r)
    assert_same_pairs(_close_pairs_windowed(X, Y, r), want)
    assert_same_pairs(close_pairs(X, Y, r), want)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**16), problems=st.integers(0, 40), m=st.integers(0, 12), n=st.integers(0, 12),
       d=st.integers(1, 2), absent=st.sampled_from([0.0, 0.3]),
       radius=st.sampled_from([1e-3, 0.05, 0.3, 1.0, 2.5, 2.999]))
def test_windowed_close_pairs_on_bearings_equal_every_pair(seed, problems, m, n, d, absent, radius):
    # bearings near ±π are close across the wrap; raw angles a turn away are the same bearing
    X, Y = padded_sets(seed, problems, m, n, d, 1.0, absent, False, angular=True)
    want = _close_pairs_dense(X, Y, radius, angular=True)
    assert_same_pairs(_close_pairs_windowed(X, Y, radius, angular=True), want)
    assert_same_pairs(close_pairs(X, Y, radius, angular=True), want)


def test_close_pairs_across_the_wrap_are_found():
    X = np.array([[[np.pi - 0.01]], [[-np.pi + 0.002]], [[3 * np.pi - 0.01]]])
    Y = np.array([[[-np.pi + 0.01]], [[np.pi - 0.003]], [[-np.pi + 0.01]]])
    p, i, j, d = close_pairs(X, Y, 0.03, angular=True)
    np.testing.assert_array_equal(p, [0, 1, 2])
    np.testing.assert_array_equal(d, pairwise_distance(X, Y, angular=True)[p, i, j])


@pytest.mark.parametrize("block_rows,candidates", [(40, 1 << 20), (1 << 18, 7), (40, 50)])
def test_windowed_close_pairs_in_many_blocks(monkeypatch, block_rows, candidates):
    # blocks of a few problems each, and their candidates in pieces: the problems' offsets and
    # the joined order are right
    X, Y = padded_sets(7, 300, 9, 11, 2, 10.0, 0.2, False, angular=False)
    want = _close_pairs_dense(X, Y, 3.0)
    Xa, Ya = padded_sets(8, 300, 9, 11, 1, 1.0, 0.2, False, angular=True)
    want_angular = _close_pairs_dense(Xa, Ya, 0.2, angular=True)
    monkeypatch.setattr(set_distances_fast, "WINDOW_BLOCK_ROWS", block_rows)
    monkeypatch.setattr(set_distances_fast, "WINDOW_CANDIDATES", candidates)
    assert_same_pairs(_close_pairs_windowed(X, Y, 3.0), want)
    assert_same_pairs(_close_pairs_windowed(Xa, Ya, 0.2, angular=True), want_angular)


def test_windowed_close_pairs_on_many_problems_equal_every_pair():
    # many scans of many targets and tracks, mostly far apart: the case the window is for
    rng = np.random.default_rng(3)
    truth = rng.uniform(0, 5e4, (500, 60, 2))
    X = truth + rng.normal(scale=300.0, size=truth.shape)
    X = np.concatenate([X, rng.uniform(0, 5e4, (500, 40, 2))], axis=1)
    X[rng.random(X.shape[:2]) < 0.3] = np.nan
    for radius in (500.0, 1000.0):
        want = _close_pairs_dense(X, truth, radius)
        assert want[0].size > 1000
        assert_same_pairs(close_pairs(X, truth, radius), want)
        np.testing.assert_array_equal(want[3], pairwise_distance(X, truth)[want[:3]])


@pytest.mark.parametrize("radius", [0.0, -1.0, np.inf, np.nan, 1e-200, 1e-160, 3.0, 4.0, 10.0])
@pytest.mark.parametrize("angular", [False, True])
def test_close_pairs_at_odd_radii_equal_every_pair(radius, angular):
    X, Y = padded_sets(11, 20, 7, 8, 1, 1.0, 0.2, False, angular)
    X[0, :3] = Y[0, :3]                                   # pairs at distance 0
    X[1, 0] = Y[1, 0] + 1e-170 if np.isfinite(Y[1, 0, 0]) else X[1, 0]
    assert_same_pairs(close_pairs(X, Y, radius, angular), _close_pairs_dense(X, Y, radius, angular))


@pytest.mark.parametrize("shape", [((0, 3, 2), (0, 4, 2)), ((5, 0, 2), (5, 4, 2)), ((5, 3, 2), (5, 0, 2)),
                                   ((5, 3, 0), (5, 4, 0))])
def test_close_pairs_of_empty_sets(shape):
    X, Y = np.zeros(shape[0]), np.ones(shape[1])
    for radius in (0.5, 2.0):
        assert_same_pairs(close_pairs(X, Y, radius), _close_pairs_dense(X, Y, radius))


def test_close_pairs_when_every_row_is_absent():
    X, Y = np.full((4, 3, 2), np.nan), np.zeros((4, 5, 2))
    assert_same_pairs(close_pairs(X, Y, 1.0), _close_pairs_dense(X, Y, 1.0))
    assert_same_pairs(close_pairs(Y, X, 1.0), _close_pairs_dense(Y, X, 1.0))


def test_windowed_close_pairs_with_huge_raw_bearings_fall_back_to_every_pair():
    # angles 10¹⁵ rad from (−π, π]: the margin of their rounding is wider than the window
    # can hold, and every pair is tried instead
    X, Y = padded_sets(5, 10, 6, 6, 1, 1.0, 0.0, False, angular=True)
    X[:, 0] += 2 * np.pi * 1.6e14
    assert_same_pairs(_close_pairs_windowed(X, Y, 0.5, angular=True), _close_pairs_dense(X, Y, 0.5, angular=True))


# ------------------------------------------------------------------ life tables


def life_tables_reference(name, times, positions, track_ids, truths, truth_ids, gate, angular=False, nis=None):
    """The tables by a loop per run and identity (the form :func:`life_tables` replaced)."""
    times = np.asarray(times, float)
    match, dist = scan_matches(positions, truths, gate, angular, track_ids, truth_ids)
    matched_id = np.where(match >= 0, np.take_along_axis(track_ids, np.maximum(match, 0), axis=-1), -1)
    target_rows, track_rows = [], []
    for r in range(positions.shape[0]):
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


def assert_same_table(got: pl.DataFrame, want: pl.DataFrame):
    """Same schema, rows in the same order, every value to the last bit (nulls where nulls)."""
    assert got.schema == want.schema
    assert got.equals(want, null_equal=True)
    for column in got.columns:
        if got[column].dtype == pl.Float64:
            a, b = got[column].to_numpy(), want[column].to_numpy()
            assert a.tobytes() == b.tobytes(), column
    assert got.write_csv() == want.write_csv()


def many_target_run(seed, runs, scans, targets, tracks, spread, miss, clutter, nis_kind, id_pool):
    """Truths and tracks of a few runs: targets born and dying, identities moving between slots
    and reused, tracks following targets with noise, swapping, dropping out, and clutter."""
    rng = np.random.default_rng(seed)
    T, S = targets, tracks
    walk = np.cumsum(rng.normal(scale=3.0, size=(runs, scans, T, 2)), axis=1)
    truths = rng.uniform(0, spread, (runs, 1, T, 2)) + walk
    alive = rng.random((runs, scans, T)) > 0.2
    truth_ids = np.full((runs, scans, T), -1, np.int64)
    for r in range(runs):
        for k in range(scans):
            truth_ids[r, k] = rng.permutation(max(T, id_pool))[:T]
    truth_ids = np.where(alive, truth_ids, -1)
    truths = np.where(alive[..., None], truths, np.nan)
    positions = np.full((runs, scans, S, 2), np.nan)
    track_ids = np.full((runs, scans, S), -1, np.int64)
    for r in range(runs):
        for k in range(scans):
            slots = rng.permutation(S)
            for t in range(min(T, S)):
                if rng.random() < miss:
                    continue
                positions[r, k, slots[t]] = truths[r, k, t] + rng.normal(scale=spread / 20, size=2)
                track_ids[r, k, slots[t]] = (t + (rng.random() < 0.1)) % (T + 2)
            for slot in slots[min(T, S):]:
                if rng.random() < clutter:
                    positions[r, k, slot] = rng.uniform(0, spread, 2)
                    track_ids[r, k, slot] = T + 2 + rng.integers(0, 4)
    # an identity once per scan (the slots hold different tracks)
    for r in range(runs):
        for k in range(scans):
            ids = track_ids[r, k]
            seen = set()
            for slot in range(S):
                if ids[slot] >= 0 and ids[slot] in seen:
                    ids[slot] = -1
                seen.add(int(ids[slot]))
    positions = np.where((track_ids >= 0)[..., None], positions, np.nan)
    nis = None
    if nis_kind != "none":
        nis = rng.chisquare(2, (runs, scans, S))
        if nis_kind == "gaps":
            nis[rng.random(nis.shape) < 0.4] = np.nan
        if nis_kind == "none-finite":
            nis[:] = np.nan
    times = np.cumsum(rng.uniform(0.5, 2.0, scans))
    return times, positions, track_ids, truths, truth_ids, nis


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**16), runs=st.integers(1, 3), scans=st.integers(1, 40), targets=st.integers(1, 7),
       tracks=st.integers(1, 9), spread=st.sampled_from([50.0, 400.0]), miss=st.sampled_from([0.0, 0.3, 1.0]),
       clutter=st.sampled_from([0.0, 0.5]), nis_kind=st.sampled_from(["none", "full", "gaps", "none-finite"]),
       id_pool=st.integers(1, 12), angular=st.booleans())
def test_life_tables_equal_the_loop_per_identity(seed, runs, scans, targets, tracks, spread, miss, clutter, nis_kind,
                                                  id_pool, angular):
    times, positions, track_ids, truths, truth_ids, nis = many_target_run(
        seed, runs, scans, targets, tracks, spread, miss, clutter, nis_kind, id_pool)
    gate = 30.0
    if angular:
        # bearings: a component a turn wide, wrapping
        positions, truths, gate = positions[..., :1] / spread * 6.0 - 3.0, truths[..., :1] / spread * 6.0 - 3.0, 0.3
    got = life_tables("t", times, positions, track_ids, truths, truth_ids, gate, angular, nis)
    want = life_tables_reference("t", times, positions, track_ids, truths, truth_ids, gate, angular, nis)
    for g, w in zip(got, want):
        assert_same_table(g, w)


def test_life_tables_of_long_histories_equal_the_loop():
    # hundreds of matches per target: the RMSE's mean is numpy's pairwise sum of the stretch
    times, positions, track_ids, truths, truth_ids, nis = many_target_run(4, 2, 700, 5, 8, 400.0, 0.1, 0.5, "gaps", 9)
    got = life_tables("t", times, positions, track_ids, truths, truth_ids, 30.0, False, nis)
    want = life_tables_reference("t", times, positions, track_ids, truths, truth_ids, 30.0, False, nis)
    for g, w in zip(got, want):
        assert_same_table(g, w)


def test_life_tables_without_targets_or_tracks():
    times = np.arange(4.0)
    empty_ids = np.full((2, 4, 3), -1, np.int64)
    positions = np.full((2, 4, 3, 2), np.nan)
    for args in ((positions, empty_ids, positions, empty_ids),):
        got = life_tables("t", times, *args, 10.0)
        want = life_tables_reference("t", times, *args, 10.0)
        for g, w in zip(got, want):
            assert g.height == 0
            assert_same_table(g, w)


# ------------------------------------------------------------------ identity pairing


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**16), runs=st.integers(1, 4), targets=st.integers(0, 12), tracks=st.integers(0, 15),
       density=st.sampled_from([0.05, 0.2, 0.6, 1.0]), top=st.sampled_from([1, 3, 50]))
def test_identity_true_positives_on_the_pairs_equal_the_whole_matrix(seed, runs, targets, tracks, density, top):
    # identities numbered across runs in run order, as global_identities numbers them; counts
    # with ties (top 1: every pair counts the same) and without; runs without any pair
    from trackreplay.evaluators.assignment_metrics import _identity_true_positives, _identity_true_positives_dense

    rng = np.random.default_rng(seed)
    n_targets = rng.integers(0, targets + 1, runs)
    n_tracks = rng.integers(0, tracks + 1, runs)
    target_run = np.repeat(np.arange(runs), n_targets)
    track_run = np.repeat(np.arange(runs), n_tracks)
    first_target, first_track = np.cumsum(n_targets) - n_targets, np.cumsum(n_tracks) - n_tracks
    pair_run, pair_target, pair_track = [], [], []
    for r in range(runs):
        for a in range(n_targets[r]):
            for b in range(n_tracks[r]):
                if rng.random() < density:
                    pair_run.append(r)
                    pair_target.append(first_target[r] + a)
                    pair_track.append(first_track[r] + b)
    pair_run, pair_target, pair_track = (np.array(v, np.int64) for v in (pair_run, pair_target, pair_track))
    count = rng.integers(1, top + 1, pair_run.size)
    args = (pair_run, pair_target, pair_track, count, target_run, track_run, runs)
    got, want = _identity_true_positives(*args), _identity_true_positives_dense(*args)
    assert got.dtype == want.dtype == np.int64
    np.testing.assert_array_equal(got, want)


# ------------------------------------------------------------------ pairs found once


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**16), runs=st.integers(1, 3), scans=st.integers(1, 30), targets=st.integers(1, 7),
       tracks=st.integers(1, 9), miss=st.sampled_from([0.0, 0.3]), with_ids=st.booleans(), angular=st.booleans())
def test_measures_on_gated_pairs_found_once_equal_their_own(seed, runs, scans, targets, tracks, miss, with_ids,
                                                            angular):
    # the standard measures hand one gated_pairs to the matching, the identity pairing and SIAP
    from trackreplay.evaluators.assignment_metrics import assignment_metrics, gated_pairs
    from trackreplay.evaluators.siap import siap_sums

    times, positions, track_ids, truths, truth_ids, _ = many_target_run(
        seed, runs, scans, targets, tracks, 400.0, miss, 0.5, "none", 9)
    gate = 30.0
    if angular:
        positions, truths, gate = positions[..., :1] / 400.0 * 6.0 - 3.0, truths[..., :1] / 400.0 * 6.0 - 3.0, 0.3
    ids = (track_ids, truth_ids) if with_ids else (None, None)
    pairs = gated_pairs(positions, truths, gate, angular, *ids)
    match = scan_matches(positions, truths, gate, angular, *ids)
    shared = scan_matches(positions, truths, gate, angular, *ids, pairs=pairs)
    for g, w in zip(shared, match):
        assert g.tobytes() == w.tobytes()
    own = assignment_metrics(positions, truths, gate, ids[0], angular, matches=match, truth_ids=ids[1])
    given_pairs = assignment_metrics(positions, truths, gate, ids[0], angular, matches=match, truth_ids=ids[1],
                                     pairs=pairs)
    unmatched = assignment_metrics(positions, truths, gate, ids[0], angular, truth_ids=ids[1], pairs=pairs)
    for key, value in own.items():
        assert given_pairs[key].tobytes() == value.tobytes(), key
        assert unmatched[key].tobytes() == value.tobytes(), key
    siap = siap_sums(positions, truths, gate, times, *ids, angular)
    siap_shared = siap_sums(positions, truths, gate, times, *ids, angular, pairs=pairs)
    for key, value in siap.items():
        assert siap_shared[key].tobytes() == value.tobytes(), key
    # HOTA's sparse form from pairs found out to a wider gate (those within d₀ kept), as
    # evaluate_standard hands them over, and the matching from those within the gate
    from trackreplay.evaluators.hota import hota_sums
    from trackreplay.evaluators.set_distances import pairs_within

    d0 = 1.5 * gate
    wide = gated_pairs(positions, truths, 2.0 * gate, angular, *ids)
    hota = hota_sums(positions, truths, d0, *ids, angular, method="sparse")
    hota_shared = hota_sums(positions, truths, d0, *ids, angular, method="sparse", pairs=wide)
    for key in hota:
        assert hota_shared[key].tobytes() == hota[key].tobytes(), key
    for g, w in zip(pairs_within(wide, gate), pairs):
        assert g.tobytes() == w.tobytes()


# ------------------------------------------------------------------ identity helpers


def _global_identities_by_sorting(ids, present):
    """The numbering of :func:`trackreplay.evaluators.set_distances.global_identities` from ``np.unique``."""
    r, k, j = np.nonzero(present)
    out = np.full(present.shape, -1, np.int64)
    if r.size == 0:
        return out, 0, np.zeros(0, np.int64)
    pairs = np.stack([r, np.asarray(ids)[r, k, j]], axis=1)
    uniq, inverse = np.unique(pairs, axis=0, return_inverse=True)
    out[r, k, j] = inverse.ravel()
    return out, len(uniq), uniq[:, 0]


@settings(max_examples=200, deadline=None)
@given(seed=st.integers(0, 2**16), runs=st.integers(1, 5), scans=st.integers(1, 8), slots=st.integers(1, 5),
       top=st.sampled_from([1, 3, 100, 1 << 30]), density=st.floats(0.0, 1.0))
def test_global_identities_equal_numbering_by_sorting(seed, runs, scans, slots, top, density):
    rng = np.random.default_rng(seed)
    ids = rng.integers(0, top, size=(runs, scans, slots))
    present = rng.random(ids.shape) < density
    got = set_distances.global_identities(ids, present)
    want = _global_identities_by_sorting(ids, present)
    np.testing.assert_array_equal(got[0], want[0])
    assert got[1] == want[1]
    np.testing.assert_array_equal(got[2], want[2])


@pytest.mark.parametrize("top", [1, 7, 1 << 16, (1 << 16) + 1, 1 << 31, 1 << 40])
def test_stable_order_is_numpys_stable_argsort(top):
    keys = np.random.default_rng(top % 97).integers(0, top, size=5000)
    np.testing.assert_array_equal(set_distances.stable_order(keys, top), np.argsort(keys, kind="stable"))


@pytest.mark.parametrize("in_run_order,block", [(False, 1 << 22), (True, 1 << 22), (True, 700)])
def test_identity_pairs_are_the_unique_keys(monkeypatch, in_run_order, block):
    """Counted on dense keys (events in run order; in one block of runs or several) or by
    sorting: the pairs, indices and counts of np.unique."""
    monkeypatch.setattr(set_distances_fast, "DENSE_PAIRS_BLOCK", block)
    monkeypatch.setattr(set_distances, "DENSE_PAIRS_PER_EVENT", 16 if in_run_order else 0)
    rng = np.random.default_rng(8)
    runs, targets, tracks = 6, rng.integers(1, 30, 6), rng.integers(1, 300, 6)
    first_run, second_run = np.repeat(np.arange(runs), targets), np.repeat(np.arange(runs), tracks)
    event_run = rng.integers(0, runs, 4000)
    if in_run_order:
        event_run.sort()
    first = np.cumsum(targets)[event_run] - 1 - rng.integers(0, targets[event_run])
    second = np.cumsum(tracks)[event_run] - 1 - rng.integers(0, tracks[event_run])
    pair_first, pair_second, inverse, count = set_distances.identity_pairs(first, second, first_run, second_run)
    keys, want_inverse, want_count = np.unique(first * tracks.sum() + second, return_inverse=True, return_counts=True)
    np.testing.assert_array_equal(pair_first * tracks.sum() + pair_second, keys)
    np.testing.assert_array_equal(inverse, want_inverse)
    np.testing.assert_array_equal(count, want_count)


@pytest.mark.parametrize("edges,rows,cols,chain", [(0, 3, 3, False), (40, 30, 30, False), (3000, 2000, 2000, False),
                                                   (6000, 3000, 3000, False), (200, 101, 101, True)])
def test_components_by_propagation_are_scipys(monkeypatch, edges, rows, cols, chain):
    """The same partition, numbered by smallest node, as scipy's connected_components: small
    graphs, one over the propagation's edge limit and a chain longer than its rounds."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    rng = np.random.default_rng(edges)
    if chain:   # row i – column i – row i+1 – …: one component as long as the graph, not settled in 2 rounds
        monkeypatch.setattr(set_distances_fast, "PROPAGATION_ROUNDS", 2)
        a = np.concatenate([np.arange(rows - 1), np.arange(1, rows)])
        b = np.concatenate([np.arange(rows - 1), np.arange(rows - 1)])
    else:
        a, b = rng.integers(0, rows, edges), rng.integers(0, cols, edges)
    n, label = set_distances_fast._bipartite_components(a, b, rows, cols)
    graph = coo_matrix((np.ones(a.size, bool), (a, rows + b)), shape=(rows + cols,) * 2)
    want_n, want = connected_components(graph, directed=False)
    assert n == want_n
    # the same partition, numbered in the order of each component's smallest node
    first = np.unique(want, return_index=True)[1]
    renumber = np.empty(want_n, np.int64)
    renumber[np.argsort(first)] = np.arange(want_n)
    np.testing.assert_array_equal(label, renumber[want])


def test_identity_measures_of_runs_without_any_target():
    """No target present anywhere (truth identities given): no presence, every track a false
    positive and a false track, no error (hypothesis found this case)."""
    from trackreplay.evaluators.assignment_metrics import assignment_metrics

    tracks = np.random.default_rng(1).normal(size=(2, 3, 2, 2))
    truths = np.full((2, 3, 1, 2), np.nan)
    track_ids = np.broadcast_to([[0, 1]], (2, 3, 2))
    out = assignment_metrics(tracks, truths, 1.0, track_ids, truth_ids=np.full((2, 3, 1), -1))
    assert out["presences"].tolist() == [0, 0] and out["matches"].tolist() == [0, 0]
    assert out["false_positives"].tolist() == [6, 6] and out["idfp"].tolist() == [6, 6]
    assert out["false_tracks"].tolist() == [2, 2] and out["id_switches"].tolist() == [0, 0]


@pytest.mark.parametrize("seed", range(6))
def test_matching_that_keeps_previous_matches_skips_only_uncontested_scans(seed):
    # scans where no target and no track sits in two gated pairs are matched at once; the loop
    # over every scan (the plain form) gives the same matches and distances, with identities that
    # change slots, absent targets and tracks, and crowded scenes where most scans are contested
    from trackreplay.evaluators import assignment_metrics as am
    from trackreplay.evaluators.set_distances import all_finite

    rng = np.random.default_rng(seed)
    for trial in range(40):
        R, K, T, S = (int(n) for n in (rng.integers(1, 4), rng.integers(1, 30), rng.integers(1, 5), rng.integers(1, 6)))
        X = rng.uniform(0, 10, (R, K, T, 2))
        crowded = trial % 2 == 1
        Y = X[..., :1, :].repeat(S, 2) + rng.normal(0, 1.5, (R, K, S, 2)) if crowded else rng.uniform(0, 10, (R, K, S, 2))
        X[rng.random((R, K, T)) < 0.2] = np.nan
        Y[rng.random((R, K, S)) < 0.3] = np.nan
        order = rng.permutation(T)[None, None, :].repeat(K, 1).repeat(R, 0)
        tid = np.where(all_finite(X), order if trial % 3 == 0 else np.arange(T), -1)
        ids = np.where(all_finite(Y), np.arange(S)[None, None] + (rng.random((R, K, 1)) < 0.2) * 10, -1)
        present, tid = am._truth_identities(X, tid)
        usable = all_finite(Y) & (ids >= 0)
        gate = float(rng.uniform(0.5, 4.0))
        plain = am._matches_keeping_previous_scan_by_scan(X, Y, present, usable, tid, ids, gate, False,
                                                          contested_only=False)
        for fast in (am._matches_keeping_previous_scan_by_scan(X, Y, present, usable, tid, ids, gate, False),
                     am._matches_keeping_previous(X, Y, present, usable, tid, ids, gate, False)):
            assert np.array_equal(fast[0], plain[0]) and np.array_equal(fast[1], plain[1], equal_nan=True), (seed, trial)


@pytest.mark.parametrize("seed", range(8))
def test_matching_that_keeps_previous_matches_visits_contested_pairs_alone(seed):
    # the form that matches uncontested pairs at once and loops over the contested ones, finding
    # each target's slot at the scan before, against the loop over every scan: targets born and
    # dying (new identities), identities moving between slots at every scan, tracks swapping
    # identities and restarting, scans without any target or track, crowded scenes
    from trackreplay.evaluators import assignment_metrics as am
    from trackreplay.evaluators.set_distances import all_finite

    rng = np.random.default_rng(100 + seed)
    for trial in range(25):
        R, K, T, S = (int(n) for n in (rng.integers(1, 4), rng.integers(1, 40), rng.integers(1, 7), rng.integers(1, 8)))
        L = max(T, 1)
        # lanes of targets moving slowly; a lane's target is replaced now and then (a new identity)
        start = rng.uniform(0, 6, (R, 1, L, 2))
        X = start + np.cumsum(rng.normal(0, 0.3, (R, K, L, 2)), axis=1)
        born = np.cumsum(rng.random((R, K, L)) < 0.08, axis=1)
        truth_id = np.arange(L)[None, None, :] + L * born
        alive = rng.random((R, K, L)) > 0.15
        alive[:, rng.random(K) < 0.1] = False                    # scans without any target
        # tracks follow lanes (noisy), swap lanes and restart with new identities; some are false
        lane = rng.integers(0, L, (R, 1, S)).repeat(K, 1)
        swap = rng.random((R, K, S)) < 0.05
        lane = np.where(swap, rng.integers(0, L, (R, K, S)), lane)
        noise = rng.normal(0, 0.8 if trial % 2 else 0.3, (R, K, S, 2))
        Y = np.take_along_axis(X, lane[..., None].repeat(2, -1), axis=2) + noise
        false = rng.random((R, K, S)) < 0.1
        Y[false] = rng.uniform(0, 6, (int(false.sum()), 2))
        track_id = np.arange(S)[None, None, :] + S * np.cumsum(rng.random((R, K, S)) < 0.05, axis=1)
        shown = rng.random((R, K, S)) > 0.2
        shown[:, rng.random(K) < 0.1] = False                    # scans without any track
        # every scan puts its elements in random slots
        for name in ("truth", "track"):
            A, I, on = (X, truth_id, alive) if name == "truth" else (Y, track_id, shown)
            perm = np.argsort(rng.random(I.shape), axis=-1)
            A = np.take_along_axis(A, perm[..., None].repeat(2, -1), axis=2)
            I = np.take_along_axis(I, perm, axis=2)
            on = np.take_along_axis(on, perm, axis=2)
            A = np.where(on[..., None], A, np.nan)
            I = np.where(on, I, -1)
            if name == "truth":
                X, truth_id = A, I
            else:
                Y, track_id = A, I
        present, tid = am._truth_identities(X, truth_id)
        usable = all_finite(Y) & (track_id >= 0)
        gate = float(rng.uniform(0.5, 3.0))
        plain = am._matches_keeping_previous_scan_by_scan(X, Y, present, usable, tid, track_id, gate, False,
                                                          contested_only=False)
        fast = am._matches_keeping_previous(X, Y, present, usable, tid, track_id, gate, False)
        assert np.array_equal(fast[0], plain[0]) and np.array_equal(fast[1], plain[1], equal_nan=True), (seed, trial)


@pytest.mark.parametrize("seed", range(4))
def test_compact_numbering_of_sorted_and_unsorted_keys_is_uniques(seed):
    # the distinct keys numbered in increasing order, whether the keys come sorted (numbered by
    # counting changes) or not (numbered by marking), few or many against the range
    from trackreplay.evaluators.set_distances_shared import _compact

    rng = np.random.default_rng(seed)
    for n, size in ((1000, 10), (1000, 200), (1000, 5000), (50, 3), (7, 1)):
        keys = rng.integers(0, n, size)
        for k in (keys, np.sort(keys)):
            number, count = _compact(k, n)
            uniq, inverse = np.unique(k, return_inverse=True)
            assert count == uniq.size
            np.testing.assert_array_equal(number, inverse)
