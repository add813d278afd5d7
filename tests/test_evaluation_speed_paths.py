"""The evaluators' fast paths give the numbers of the plain computations they replace.

* group estimates from per-group totals (:func:`trackreplay.evaluators.confidence.group_totals`) against
  re-scoring every group of runs, for the radar family's table and for time averages;
* whitening in blocks along the axis the covariances lie fastest in, and the NEES summed
  block by block, against whitening matrix by matrix;
* the standard measures in blocks of runs against one block;
* the component-wise sums and checks against numpy's reductions, and the one-element
  assignment against the permutation search;
* the single-target forms (one target and one track identity a run) against the general
  GOSPA, matching, CLEAR/identity, HOTA and SIAP, and the HOTA/SIAP intervals from group
  totals against the jackknife that re-pools the runs.
"""

from __future__ import annotations

import numpy as np
import polars as pl
import pytest

from trackreplay.evaluators import consistency, radar, standard
from trackreplay.evaluators.confidence import (RANDOM_GROUPS_MIN_RUNS, group_totals, jackknife, ratio_jackknife, run_groups,
                                   summary_intervals)
from trackreplay.evaluators.set_distances import optimal_assignment
from trackreplay.evaluators.set_distances_fast import _every_permutation
from trackreplay.batched_linalg import all_finite, sum_squares, whiten
from trackreplay.vocabulary import CLAMPED, COASTED, INITIALISING, NO_TRACK

RTOL = 1e-12


@pytest.mark.parametrize("runs,groups", [(40, 10), (37, 10), (5, 10), (203, 20)])
@pytest.mark.parametrize("left_out", [False, True])
def test_group_totals_are_the_sums_over_each_group(runs, groups, left_out):
    values = np.random.default_rng(runs).normal(size=(runs, 3, 2))
    parts = run_groups(runs, groups)
    totals = group_totals(values, len(parts), left_out)
    for g, part in enumerate(parts):
        kept = np.setdiff1d(np.arange(runs), part) if left_out else part
        np.testing.assert_allclose(totals[g], values[kept].sum(axis=0), rtol=RTOL, atol=1e-12)


def test_ratio_jackknife_is_the_jackknife_of_the_mean():
    rng = np.random.default_rng(3)
    values = rng.chisquare(2, size=(57, 9))
    values[rng.random(values.shape) < 0.2] = np.nan   # missing scans count for nothing
    values[4] = np.nan                                 # nor does a run without any
    finite = np.isfinite(values)
    sums, counts = np.where(finite, values, 0.0).sum(axis=1), finite.sum(axis=1)
    fast = ratio_jackknife(sums, counts, groups=10)
    plain = jackknife(lambda idx: np.nanmean(values[idx]), 57, groups=10)
    np.testing.assert_allclose(np.array(fast, float), np.array(plain, float), rtol=1e-11)


# ------------------------------------------------------------------ the radar family's groups


def _radar_outputs(runs: int, scans: int = 12, seed: int = 5):
    """Outputs of two radar trackers in the vocabulary with every case the scores tell apart:
    start-up and empty scans, clamped and coasted scans, missing plots and a NaN state."""
    rng = np.random.default_rng(seed)
    truth = rng.normal(scale=1e3, size=(runs, scans, 4))
    measured = truth[..., :2] + rng.normal(scale=50.0, size=(runs, scans, 2))
    measured[rng.random((runs, scans)) < 0.1] = np.nan
    tracks = {}
    for name in ("a", "b"):
        flags = np.zeros((runs, scans), np.uint16)
        flags[:, :2] = INITIALISING
        flags[rng.random((runs, scans)) < 0.05] |= NO_TRACK
        flags[rng.random((runs, scans)) < 0.1] |= CLAMPED
        flags[rng.random((runs, scans)) < 0.1] |= COASTED
        state = truth + rng.normal(scale=30.0, size=truth.shape)
        state[0, 5] = np.nan
        out = {"state": state, "flags": flags, "alpha": rng.random((runs, scans, 2)),
               "beta": rng.random((runs, scans, 2)), "lambda_cross": rng.random((runs, scans))}
        if name == "a":   # one tracker reports the plot it used and its innovation, the other not
            out["measurement"] = measured + rng.normal(scale=5.0, size=measured.shape)
            out["innovation"] = rng.normal(scale=20.0, size=(runs, scans, 2))
        tracks[name] = out
    # about half the scans above the nominal cross-range error, one scan covered by no run
    cross = rng.uniform(0.5, 1.5, size=(runs, scans))
    cross[:, 3] = np.nan
    pcrb = rng.uniform(10.0, 100.0, size=scans)
    pcrb[-1] = np.nan
    return np.arange(scans, dtype=float), tracks, measured, truth, cross, pcrb


def _assert_same_table(fast: pl.DataFrame, plain: pl.DataFrame, rtol=RTOL):
    assert fast.select("tracker", "metric", "scope").equals(plain.select("tracker", "metric", "scope"))
    np.testing.assert_allclose(fast["value"].to_numpy().astype(float), plain["value"].to_numpy().astype(float),
                               rtol=rtol, atol=1e-300)


@pytest.mark.parametrize("left_out", [False, True], ids=["alone", "left-out"])
def test_radar_group_summaries_are_the_scores_of_the_groups(left_out):
    times, tracks, measured, truth, cross, pcrb = _radar_outputs(43)
    per_scan, summary, groups = radar.evaluate(times, tracks, measured, truth, cross, 1.0, pcrb,
                                                   groups=10, left_out=left_out)
    plain_scan, plain = radar.evaluate(times, tracks, measured, truth, cross, 1.0, pcrb)
    _assert_same_table(summary, plain)
    assert per_scan.columns == plain_scan.columns
    for c in per_scan.columns[3:]:
        np.testing.assert_allclose(per_scan[c].to_numpy().astype(float), plain_scan[c].to_numpy().astype(float),
                                   rtol=RTOL)
    for part, table in zip(run_groups(43, 10), groups):
        runs = np.setdiff1d(np.arange(43), part) if left_out else part
        sub = {n: {k: v[runs] for k, v in o.items()} for n, o in tracks.items()}
        _, expected = radar.evaluate(times, sub, measured[runs], truth[runs], cross[runs], 1.0, pcrb)
        _assert_same_table(table, expected)


@pytest.mark.parametrize("runs", [60, 240], ids=["jackknife", "random-groups"])
def test_summary_intervals_from_group_totals_match_rescoring(runs):
    assert (runs >= RANDOM_GROUPS_MIN_RUNS) == (runs == 240)
    times, tracks, measured, truth, cross, pcrb = _radar_outputs(runs, seed=runs)
    data = {"tracks": tracks, "reference": {"measured": measured, "truth": truth, "cross": cross}}

    def score(d, groups=None, left_out=False):
        r = d["reference"]
        return radar.evaluate(times, d["tracks"], r["measured"], r["truth"], r["cross"], 1.0, pcrb,
                                  groups=groups, left_out=left_out)

    _, fast = summary_intervals(score, data, runs, score_groups=score)
    _, plain = summary_intervals(score, data, runs)
    _assert_same_table(fast, plain)
    for c in ("se", "ci_low", "ci_high"):
        x, y = fast[c].to_numpy().astype(float), plain[c].to_numpy().astype(float)
        assert np.array_equal(np.isnan(x), np.isnan(y)), c
        # an interval's spread is a difference of estimates: it keeps their rounding, not their size
        np.testing.assert_allclose(x, y, rtol=1e-9, atol=1e-12 * np.nanmax(np.abs(plain["value"].to_numpy())))


def test_a_scorer_without_group_totals_falls_back_to_rescoring():
    err = np.random.default_rng(2).normal(size=(30, 4))
    score = lambda d: (None, pl.DataFrame({"tracker": ["t"], "metric": ["m"], "scope": ["overall"],  # noqa: E731
                                           "value": [float(np.mean(d["err"] ** 2))]}))
    _, plain = summary_intervals(score, {"err": err}, 30)
    _, fallback = summary_intervals(score, {"err": err}, 30, score_groups=lambda *a: None)
    assert plain.equals(fallback)


# ------------------------------------------------------------------ whitening and the standard measures


def _covariances(lead, n, rng, runs_fastest=True):
    A = rng.normal(size=lead + (n, n))
    P = A @ np.swapaxes(A, -1, -2) + 0.5 * np.eye(n)
    if not runs_fastest:
        return P
    # a tracker's buffer: the matrix entries slowest, the runs fastest, seen as (R, K, n, n)
    buffer = np.ascontiguousarray(np.moveaxis(P, (0, 1), (-1, -2)))   # (n, n, K, R)
    return np.moveaxis(buffer, (-1, -2), (0, 1))


@pytest.mark.parametrize("runs_fastest", [True, False])
def test_whitening_in_blocks_is_whitening_matrix_by_matrix(monkeypatch, runs_fastest):
    rng = np.random.default_rng(8)
    P = _covariances((23, 7), 3, rng, runs_fastest)
    e = rng.normal(size=(23, 7, 3))
    e[2, 3] = np.nan
    P[4, 1] = -np.eye(3)                                       # not positive definite: NaN
    monkeypatch.setattr(consistency, "WHITEN_BLOCK", 10)       # many blocks, one not full
    w = consistency.whitened(e, P)
    expected = whiten(e.reshape(-1, 3), np.ascontiguousarray(P).reshape(-1, 3, 3)).reshape(e.shape)
    np.testing.assert_array_equal(w, expected)
    nees = consistency.normalised_squared(e, P)
    np.testing.assert_array_equal(nees, sum_squares(expected))
    assert np.isnan(nees[2, 3]) and np.isnan(nees[4, 1])
    assert np.isfinite(np.delete(nees.ravel(), [2 * 7 + 3, 4 * 7 + 1])).all()



def _bits(a):
    """The bytes of a float array (NaNs compared by their bits, not as equal by position)."""
    return np.ascontiguousarray(a, float).view(np.int64)


@pytest.mark.parametrize("n", [1, 2, 3, 4, 6])
@pytest.mark.parametrize("runs_fastest", [True, False])
def test_whitening_entry_by_entry_is_whiten_then_sum_squares(n, runs_fastest):
    """_whitened_entries (the whitening the evaluators use) gives the bits of whiten and
    sum_squares, NaN payloads included, on every layout and at the edges its checks read from
    the sum: missing errors and covariances, matrices that are not positive definite, an
    infinite pivot (w finite, yet NaN), an infinite error, and a sum that overflows (kept)."""
    from trackreplay.batched_linalg import _whitened_entries

    rng = np.random.default_rng(20 + n)
    lead = (13, 9)
    P = _covariances(lead, n, rng, runs_fastest)
    e = rng.normal(size=lead + (n,))
    e[2, 3] = np.nan
    P[0, 0] = np.nan
    P[4, 1] = -np.eye(n)
    P[5, 2] = np.zeros((n, n))                                  # zero pivot: 0/0 and x/0
    P[6, 3, n - 1, n - 1] = np.inf                              # infinite last pivot: w finite there
    e[7, 4, 0] = np.inf
    e[8, 5, 0] = 1e200                                          # its square overflows: the sum is inf
    plain_w = whiten(e.reshape(-1, n), np.ascontiguousarray(P).reshape(-1, n, n))
    plain = sum_squares(plain_w)
    w = np.empty(lead + (n,))
    fast = _whitened_entries(e, P, w)
    np.testing.assert_array_equal(_bits(fast).ravel(), _bits(plain))
    np.testing.assert_array_equal(_bits(w).reshape(-1, n), _bits(plain_w))
    assert np.isinf(fast[8, 5]) and np.isnan(fast[[0, 2, 4, 5, 6, 7], [0, 3, 1, 2, 3, 4]]).all()
    # without infinities the checks are read from the sum alone: the same bits
    P[6, 3], e[7, 4, 0], e[8, 5, 0] = np.eye(n), 0.0, 0.0
    expected = sum_squares(whiten(e.reshape(-1, n), np.ascontiguousarray(P).reshape(-1, n, n)))
    np.testing.assert_array_equal(_bits(_whitened_entries(e, P)).ravel(), _bits(expected))
    assert not np.isinf(expected).any() and np.isnan(expected).sum() >= 4


def test_whitened_innovations_are_whitening_and_its_sum_of_squares():
    """whitened_innovations gives w and its NIS from one pass: whitened's w, sum_squares(w)."""
    rng = np.random.default_rng(31)
    R, K, m = 11, 6, 2
    S = _covariances((R, K), m, rng, runs_fastest=False)
    nu = rng.normal(size=(R, K, m))
    nu[3, 2] = np.nan
    S[1, 4] = -np.eye(m)
    w, nis = consistency.whitened_innovations({"innovation": nu, "innovation_covariance": S})
    expected = whiten(nu.reshape(-1, m), S.reshape(-1, m, m)).reshape(R, K, 1, m)
    np.testing.assert_array_equal(_bits(w), _bits(expected))
    np.testing.assert_array_equal(_bits(nis), _bits(sum_squares(expected)))
    assert w.flags.c_contiguous and nis.shape == (R, K, 1)

def test_the_standard_measures_in_blocks_of_runs_are_those_of_one_block(monkeypatch):
    rng = np.random.default_rng(11)
    R, K = 37, 9
    truth = rng.normal(scale=100.0, size=(R, K, 4))
    out = {"state": truth + rng.normal(scale=20.0, size=(R, K, 4)),
           "covariance": _covariances((R, K), 4, rng) * 400.0,
           "flags": np.where(rng.random((R, K)) < 0.1, NO_TRACK, 0).astype(np.uint16),
           "innovation": rng.normal(size=(R, K, 2)), "innovation_covariance": _covariances((R, K), 2, rng)}
    space = standard.EvaluationSpace(truth_components=(0, 1, 2, 3), position_components=(0, 1), angular=False,
                                     cutoff=60.0, gate=40.0)
    one_scan, one = standard.evaluate_standard(np.arange(K, dtype=float), {"t": out}, truth, space)
    monkeypatch.setattr(standard, "SET_BLOCK", 4 * K)          # blocks of 4 runs, the last of 1
    monkeypatch.setattr(standard, "NEES_BLOCK", 2 * R * 4)      # the NEES two scans at a time, the last one
    blocks_scan, blocks = standard.evaluate_standard(np.arange(K, dtype=float), {"t": out}, truth, space)
    assert one.equals(blocks) and one_scan.equals(blocks_scan)


@pytest.mark.parametrize("block", [1, 23, 5 * 23])
def test_the_radar_pcrb_in_blocks_of_scans_is_the_bound_of_one_block(monkeypatch, block):
    """radar_pcrb averages the plots' information over runs a few scans at a time; the mean over
    runs adds in the same order whatever the block, so the bound is the same to the bit."""
    from trackreplay.trackers import radar_tws as tracker

    rng = np.random.default_rng(12)
    R, K = 23, 11
    truth = np.empty((R, K, 4))
    truth[..., :2] = rng.uniform(5e3, 5e4, (R, 1, 2)) + np.arange(K)[None, :, None] * rng.normal(0, 50, (R, 1, 2))
    truth[..., 2:] = rng.normal(0, 50, (R, K, 2))
    detected = rng.random((R, K)) > 0.2
    args = (truth, 5.0 * np.arange(K), 0.5, 30.0, np.deg2rad(0.8))
    whole = tracker.radar_pcrb(*args, detected=detected)
    monkeypatch.setattr(tracker, "PCRB_BLOCK", block)
    assert np.array_equal(tracker.radar_pcrb(*args, detected=detected), whole, equal_nan=True)
    assert np.isfinite(whole[1:]).all()


# ------------------------------------------------------------------ small helpers


def test_component_sums_and_checks_match_numpy():
    rng = np.random.default_rng(4)
    a = rng.normal(size=(50, 6, 4))
    a[3, 2, 1] = np.nan
    a[7, 0, 3] = np.inf
    np.testing.assert_allclose(sum_squares(a), np.sum(a * a, axis=-1), rtol=1e-15)
    np.testing.assert_array_equal(all_finite(a), np.isfinite(a).all(axis=-1))
    assert all_finite(np.zeros((3, 0))).all() and sum_squares(np.zeros((3, 0))).tolist() == [0.0] * 3


def test_the_one_element_assignment_is_the_permutation_search():
    rng = np.random.default_rng(6)
    cost = rng.random((40, 1, 1))
    rows, cols = rng.random((40, 1)) < 0.8, rng.random((40, 1)) < 0.8
    total, match = optimal_assignment(cost, rows, cols, unmatched=0.7)
    full = np.where(rows[:, :, None] & cols[:, None, :], cost, np.where(rows[:, :, None] != cols[:, None, :], 0.7, 0.0))
    ref_total, ref_cols = _every_permutation(full)
    np.testing.assert_array_equal(total, ref_total)
    np.testing.assert_array_equal(match, np.where(rows & cols, ref_cols, -1))


def test_jackknife_leaves_out_each_group_in_run_order():
    seen = []
    jackknife(lambda idx: seen.append(idx.copy()) or float(len(idx)), 23, groups=5)
    assert np.array_equal(seen[0], np.arange(23))
    for part, idx in zip(run_groups(23, 5), seen[1:]):
        assert np.array_equal(idx, np.setdiff1d(np.arange(23), part))



# ------------------------------------------------------------------ one target and one track a run


def _one_pair_sets(seed: int, runs: int = 6, scans: int = 30, angular: bool = False, with_ids: bool = True):
    """One truth slot and one track slot per (run, scan), both missing at random, the track near
    the gate; the identities one per run (drawn per run) or the slots'. Bearings are wrapped
    anywhere in three turns."""
    rng = np.random.default_rng(seed)
    d = 1 if angular else 2
    truth = rng.normal(scale=3.0, size=(runs, scans, 1, d))
    track = truth + rng.normal(scale=rng.uniform(0.2, 3.0), size=truth.shape)
    if angular:
        truth = truth % (2 * np.pi)
        track = track % (2 * np.pi) + 2 * np.pi * rng.integers(-1, 2, size=track.shape)
    truth[rng.random((runs, scans)) < rng.uniform(0.0, 0.4)] = np.nan
    track[rng.random((runs, scans)) < rng.uniform(0.0, 0.4)] = np.nan
    truth_ids = track_ids = None
    if with_ids:
        truth_ids = np.where(np.isfinite(truth[..., 0]), rng.integers(0, 5, size=(runs, 1, 1)), -1)
        track_ids = np.where(np.isfinite(track[..., 0]), rng.integers(0, 9, size=(runs, 1, 1)), -1)
    times = np.cumsum(rng.uniform(0.5, 2.0, size=scans))
    truth_velocity = rng.normal(size=(runs, scans, 1, 2))
    track_velocity = truth_velocity + rng.normal(size=truth_velocity.shape)
    return track, truth, track_ids, truth_ids, times, track_velocity, truth_velocity


def _assert_same_values(fast: dict, plain: dict, rtol: float = 0.0):
    assert set(fast) >= set(plain) - {"alphas"}
    for key in plain:
        if key != "alphas":
            if rtol:
                np.testing.assert_allclose(np.asarray(fast[key], float), np.asarray(plain[key], float), rtol=rtol,
                                           atol=1e-12, err_msg=key)
            else:
                np.testing.assert_array_equal(fast[key], plain[key], err_msg=key)


@pytest.mark.parametrize("seed", range(24))
def test_the_single_target_forms_are_the_general_measures(seed):
    """With one target and one track identity a run in one slot each, GOSPA with switching, the
    matches, CLEAR MOT and identity measures (both conventions), HOTA's sums and SIAP's sums of
    the single-target forms are those of the general forms, bit for bit (HOTA's plain form
    adds in another order: to rounding)."""
    from trackreplay.evaluators import assignment_metrics as am, hota, siap
    from trackreplay.evaluators import set_distances as sd, set_distances_fast as sd_fast

    angular = seed % 4 == 0
    X, Y, track_ids, truth_ids, times, track_v, truth_v = _one_pair_sets(seed, angular=angular, with_ids=seed % 3 > 0)
    assert sd.one_identity_per_run(track_ids, all_finite(X)) and sd.one_identity_per_run(truth_ids, all_finite(Y))
    for per in ("track", "truth"):
        _assert_same_values(sd_fast._gospa_switching_single(X, Y, 2.0, 2.0, 1.5, track_ids, truth_ids, angular, per=per),
                            sd.gospa_switching(X, Y, 2.0, 2.0, 1.5, track_ids, truth_ids, angular, per=per))
    for convention in ("trackeval", "per-scan"):
        fast = am._single_target_matches(X, Y, 2.0, angular, track_ids, truth_ids)
        plain = am.scan_matches(X, Y, 2.0, angular, track_ids, truth_ids, keep_previous=convention == "trackeval")
        np.testing.assert_array_equal(fast[0], plain[0])
        np.testing.assert_array_equal(fast[1], plain[1])
        _assert_same_values(am._single_target_metrics(X, Y, 2.0, track_ids, angular, truth_ids=truth_ids,
                                                      convention=convention),
                            am.assignment_metrics(X, Y, 2.0, track_ids, angular, truth_ids=truth_ids,
                                                  convention=convention))
    single = hota._sums_single(X, Y, 2.5, track_ids, truth_ids, angular)
    _assert_same_values(single, hota.hota_sums(X, Y, 2.5, track_ids, truth_ids, angular, method="sparse"))
    _assert_same_values(single, hota.hota_sums(X, Y, 2.5, track_ids, truth_ids, angular, method="plain"), rtol=1e-12)
    _assert_same_values(siap._sums_single(X, Y, 2.0, times, track_ids, truth_ids, angular, track_v, truth_v),
                        siap.siap_sums(X, Y, 2.0, times, track_ids, truth_ids, angular, track_v, truth_v))


@pytest.mark.parametrize("seed", range(12))
def test_the_single_target_forms_from_a_shared_view_are_those_without(seed):
    """The presences and the one distance found once (single_pair_view) and handed to every
    single-target form give the values each form finds on its own, bit for bit, also where the
    sets, identities and velocities hold the runs fastest in memory (as a tracker's buffers and
    the recorded truth do) against the same values in C order; the view's arrays are C-ordered
    whatever the inputs' layout (the layout decides how numpy adds along the scans)."""
    from trackreplay.evaluators import assignment_metrics as am, hota, siap
    from trackreplay.evaluators import set_distances_fast as sd_fast
    from trackreplay.evaluators.set_distances_shared import single_pair_distance, single_pair_view

    angular = seed % 4 == 0
    plain = _one_pair_sets(seed, angular=angular, with_ids=seed % 3 > 0)
    X, Y, track_ids, truth_ids, times, track_v, truth_v = plain
    if seed % 4 < 2:   # runs fastest in memory, as the trackers' buffers and the recorded truth are
        X, track_v = (np.ascontiguousarray(a.transpose(3, 2, 1, 0)).transpose(3, 2, 1, 0) for a in (X, track_v))
        Y, truth_v = (np.ascontiguousarray(a.transpose(1, 0, 2, 3)).transpose(1, 0, 2, 3) for a in (Y, truth_v))
        assert X.strides[0] == Y.strides[3] == 8 and Y.strides[0] < Y.strides[1]
        track_ids, truth_ids = (None if a is None else np.asfortranarray(a) for a in (track_ids, truth_ids))
    cX, cY, c_track_ids, c_truth_ids, _, c_track_v, c_truth_v = plain        # C-ordered
    view = single_pair_view(X, Y, track_ids, truth_ids, angular)
    for part in view:
        if part is not None:
            assert part.flags.c_contiguous and part.shape == X.shape[:2]
    np.testing.assert_array_equal(view.distance, single_pair_distance(cY, cX, angular))
    np.testing.assert_array_equal(view.track_present, all_finite(cX)[:, :, 0] & (True if track_ids is None
                                                                                 else c_track_ids[:, :, 0] >= 0))
    for per in ("track", "truth"):
        _assert_same_values(sd_fast._gospa_switching_single(X, Y, 2.0, 2.0, 1.5, track_ids, truth_ids, angular, per=per,
                                                            view=view),
                            sd_fast._gospa_switching_single(cX, cY, 2.0, 2.0, 1.5, c_track_ids, c_truth_ids, angular,
                                                            per=per))
    matches = am._single_target_matches(X, Y, 2.0, angular, track_ids, truth_ids, view=view)
    for shared, own in zip(matches, am._single_target_matches(cX, cY, 2.0, angular, c_track_ids, c_truth_ids)):
        np.testing.assert_array_equal(shared, own)
    _assert_same_values(am._single_target_metrics(X, Y, 2.0, track_ids, angular, matches=matches, truth_ids=truth_ids,
                                                  view=view),
                        am._single_target_metrics(cX, cY, 2.0, c_track_ids, angular, truth_ids=c_truth_ids))
    _assert_same_values(hota._sums_single(X, Y, 2.5, track_ids, truth_ids, angular, view=view),
                        hota._sums_single(cX, cY, 2.5, c_track_ids, c_truth_ids, angular))
    _assert_same_values(siap._sums_single(X, Y, 2.0, times, track_ids, truth_ids, angular, track_v, truth_v, view=view),
                        siap._sums_single(cX, cY, 2.0, times, c_track_ids, c_truth_ids, angular, c_track_v, c_truth_v))


@pytest.mark.parametrize("alphas", ["hota", "uneven", "one", "descending"])
def test_alpha_levels_are_the_binary_search(alphas):
    """HOTA's levels (thresholds passed) from the spacing are searchsorted's, at and around every
    threshold to the last bit, outside [0, 1] and with infinities and NaN."""
    from trackreplay.evaluators.hota import _EPS, HOTA_ALPHAS, _alpha_levels

    alphas = {"hota": HOTA_ALPHAS, "uneven": np.array([0.1, 0.15, 0.5, 0.51, 0.9]), "one": np.array([0.5]),
              "descending": np.array([0.5, 0.2])}[alphas]
    rng = np.random.default_rng(3)
    edges = alphas - _EPS
    near = np.concatenate([edges, np.nextafter(edges, -1.0), np.nextafter(edges, 2.0), alphas])
    sims = np.concatenate([rng.random(5000), near, [0.0, 1.0, -0.3, 1.7]])
    expected = np.searchsorted(edges, sims, side="right") if np.all(np.diff(edges) > 0) else None
    if expected is not None:
        np.testing.assert_array_equal(_alpha_levels(alphas, sims), expected)
    with_odd = np.concatenate([sims, [np.nan, np.inf, -np.inf]])
    np.testing.assert_array_equal(_alpha_levels(alphas, with_odd), np.searchsorted(edges, with_odd, side="right"))


def test_sums_added_scan_by_scan_are_the_bincount():
    """SIAP's per-run sums over the picked scans, added scan after scan over a dense array, are
    the bincount over the picked (run, scan) pairs to the bit, with NaN, infinities and
    negative values among them."""
    from trackreplay.evaluators.siap import _add_over_scans

    rng = np.random.default_rng(8)
    values = rng.normal(scale=10.0, size=(50, 37)) ** 3
    values[rng.random(values.shape) < 0.02] = np.nan
    values[0, 3], values[1, 4] = np.inf, -np.inf
    where = rng.random(values.shape) < 0.6
    r, k = np.nonzero(where)
    np.testing.assert_array_equal(_add_over_scans(values, where), np.bincount(r, values[r, k], minlength=50))


@pytest.mark.parametrize("K", [1, 2, 64, 126, 127, 300])
def test_scan_indices_by_arithmetic_are_the_where(K):
    """The scan indices where a mask holds (−1 or K elsewhere) by arithmetic in the smallest
    integer type are np.where's, and the running "or" of a mask by its bytes is numpy's, at the
    edges of the int8 range and beyond it."""
    from trackreplay.evaluators.set_distances_fast import or_accumulate, scan_index_type, scans_where

    mask = np.random.default_rng(K).random((9, K)) < 0.4
    mask[0], mask[1] = False, True
    scans = np.arange(K)
    for fill in (-1, K):
        got = scans_where(mask, fill)
        assert got.dtype == scan_index_type(K) and np.iinfo(got.dtype).max > K
        np.testing.assert_array_equal(got, np.where(mask, scans, fill))
    with pytest.raises(ValueError):
        scans_where(mask, 0)
    np.testing.assert_array_equal(or_accumulate(mask), np.logical_or.accumulate(mask, axis=1))
    np.testing.assert_array_equal(or_accumulate(mask[:, ::-1]), np.logical_or.accumulate(mask[:, ::-1], axis=1))


def test_one_identity_per_run_tells_the_single_target_case():
    from trackreplay.evaluators.set_distances import one_identity_per_run

    present = np.array([[True, False, True], [False, False, False]])[..., None]
    assert one_identity_per_run(None, present)
    assert one_identity_per_run(np.where(present, 7, -1), present)
    present[1, 1, 0] = True
    assert one_identity_per_run(np.where(present, np.array([4, 9])[:, None, None], -1), present)  # one a run
    two = np.where(present, 4, -1)
    two[0, 2, 0] = 5                                       # a second identity in run 0
    assert not one_identity_per_run(two, present)
    hidden = np.where(present, 4, -1)
    hidden[0, 2, 0] = -1                                   # present without an identity
    assert not one_identity_per_run(hidden, present)


@pytest.mark.parametrize("with_ids", [False, True])
def test_the_standard_measures_of_one_target_take_the_single_target_forms(monkeypatch, with_ids):
    """evaluate_standard on single-target outputs: its tables equal those of the general forms
    (the single-target case switched off), to rounding in the intervals' sums."""
    rng = np.random.default_rng(21 + with_ids)
    R, K = 41, 17
    truth = rng.normal(scale=100.0, size=(R, K, 1, 4))
    truth[rng.random((R, K)) < 0.1] = np.nan
    out = {"state": truth[:, :, 0] + rng.normal(scale=30.0, size=(R, K, 4)),
           "covariance": _covariances((R, K), 4, rng) * 900.0,
           "flags": np.where(rng.random((R, K)) < 0.15, NO_TRACK, 0).astype(np.uint16),
           "innovation": rng.normal(size=(R, K, 2)), "innovation_covariance": _covariances((R, K), 2, rng)}
    truth_ids = np.where(np.isfinite(truth[..., 0]), 3, -1) if with_ids else None
    space = standard.EvaluationSpace(truth_components=(0, 1, 2, 3), position_components=(0, 1), angular=False,
                                     cutoff=80.0, gate=60.0, velocity_components=(2, 3))
    calls = []
    single = standard.hota_module._sums_single
    monkeypatch.setattr(standard.hota_module, "_sums_single", lambda *a, **k: calls.append(1) or single(*a, **k))
    fast_scan, fast = standard.evaluate_standard(np.arange(K, dtype=float), {"t": out}, truth, space,
                                                 truth_ids=truth_ids)
    assert calls, "the single-target forms were not taken"
    monkeypatch.setattr(standard, "one_identity_per_run", lambda ids, present: False)
    plain_scan, plain = standard.evaluate_standard(np.arange(K, dtype=float), {"t": out}, truth, space,
                                                   truth_ids=truth_ids)
    assert len(calls) == 1
    assert fast_scan.equals(plain_scan)
    assert fast.select("tracker", "metric", "scope").equals(plain.select("tracker", "metric", "scope"))
    for column in ("value", "se", "ci_low", "ci_high"):
        np.testing.assert_allclose(fast[column].to_numpy().astype(float), plain[column].to_numpy().astype(float),
                                   rtol=1e-9, atol=1e-12, err_msg=column)


@pytest.mark.parametrize("runs", [1, 2, 7, 53])
def test_pooled_jackknife_from_group_totals_is_the_jackknife(runs):
    from trackreplay.evaluators.hota import SUM_KEYS, pooled_hota

    rng = np.random.default_rng(runs)
    sums = {key: rng.integers(0, 50, size=(runs, 19)).astype(float) for key in SUM_KEYS}
    sums["loc_sum"] = sums["tp"] * rng.uniform(0.3, 1.0, size=(runs, 19))
    statistic = lambda s, idx: [pooled_hota(s, idx)[k] for k in ("hota", "deta", "assa", "loca")]  # noqa: E731
    fast = standard._pooled_jackknife(statistic, sums, SUM_KEYS, runs, 10)
    plain = jackknife(lambda idx: statistic(sums, idx), runs, 10)
    np.testing.assert_allclose(np.array(fast, float), np.array(plain, float), rtol=1e-12, atol=1e-15)


# ------------------------------------------------------------------ the 10,000-run radar replay's memory


@pytest.mark.parametrize("lead,n", [((23, 7), 4), ((23, 7, 1), 4), ((5, 3, 2), 2), ((40,), 3)])
def test_the_nees_on_the_buffer_is_the_nees_of_whitening(monkeypatch, lead, n):
    """normalised_squared on covariances whose matrices lie runs fastest (a tracker's buffer)
    factors views of the buffer; matrix by matrix (a C-order copy) gives the same bits."""
    rng = np.random.default_rng(len(lead) * 10 + n)
    A = rng.normal(size=lead + (n, n))
    P = A @ np.swapaxes(A, -1, -2) + 0.5 * np.eye(n)
    buffer = np.ascontiguousarray(np.moveaxis(P, 0, -1))           # (..., n, n, R): the runs fastest
    runs_fastest = np.moveaxis(buffer, -1, 0)
    e = rng.normal(size=lead + (n,))
    missing, indefinite = tuple(min(1, s - 1) for s in lead), (2,) + (0,) * (len(lead) - 1)
    e[missing] = np.nan
    runs_fastest[indefinite] = -np.eye(n)                          # not positive definite: NaN
    plain = consistency._whitened(e, np.ascontiguousarray(runs_fastest), squared=True)
    assert consistency._stack_axis(runs_fastest, lead) == 0
    monkeypatch.setattr(consistency, "WHITEN_BLOCK", 7)            # many blocks, one not full
    fast = consistency.normalised_squared(e, runs_fastest)
    np.testing.assert_array_equal(fast, plain)
    assert np.isnan(fast[missing]) and np.isnan(fast[indefinite])


@pytest.mark.parametrize("rows", [1, 3, 1 << 20])
def test_effective_scans_a_few_runs_transforms_at_a_time_are_those_of_the_block(monkeypatch, rows):
    rng = np.random.default_rng(rows)
    nx = rng.chisquare(4, size=(300, 33)) + np.cumsum(rng.normal(size=(300, 33)), axis=1) ** 2
    nx[:, :2] = np.nan
    nx[rng.random(nx.shape) < 0.05] = np.nan
    whole = [consistency.effective_scans(v, max_block=1 << 12) for v in (nx, np.nan_to_num(nx, nan=1.0))]
    monkeypatch.setattr(consistency, "FFT_ROWS", rows * 64)        # FFT length 64: `rows` runs at a time
    assert [consistency.effective_scans(v, max_block=1 << 12) for v in (nx, np.nan_to_num(nx, nan=1.0))] == whole


@pytest.mark.parametrize("max_block", [1 << 12, 1 << 20])
def test_effective_scans_one_transform_of_the_pairs_when_every_run_misses_the_same_scans(monkeypatch, max_block):
    # every run misses the same (start-up) scans: the pairs come from one run's transform,
    # added once per run; the value must be the one of a transform per run, to the bit
    rng = np.random.default_rng(max_block)
    nx = rng.chisquare(4, size=(700, 40)) + np.cumsum(rng.normal(size=(700, 40)), axis=1) ** 2
    nx[:, :2] = np.nan
    taken = []
    monkeypatch.setattr(consistency, "FFT_ROWS", 5 * 128)          # FFT length 128: 5 runs at a time
    same_rows = consistency._same_rows
    monkeypatch.setattr(consistency, "_same_rows", lambda m: taken.append(same_rows(m)) or taken[-1])
    shortcut = consistency.effective_scans(nx, max_block=max_block)   # blocks of 32 runs, or all of them
    assert taken == [True]
    monkeypatch.setattr(consistency, "_same_rows", lambda m: False)
    assert consistency.effective_scans(nx, max_block=max_block) == shortcut
    assert 1 < shortcut < 38


@pytest.mark.parametrize("block", [1, 4, 7, 50])
def test_scan_means_added_a_block_of_runs_at_a_time_are_nanmeans(block):
    from trackreplay.evaluators.tracking_metrics import nanmean

    rng = np.random.default_rng(block)
    values = rng.standard_cauchy(size=(50, 9))
    counts = rng.integers(0, 3, size=(50, 9))
    with_nan = values.copy()
    with_nan[rng.random(values.shape) < 0.2] = np.nan
    with_nan[:, 4] = np.nan                                        # a scan no run covers: NaN
    for whole in (values, counts, with_nan):
        means = standard._ScanMeans()
        for start in range(0, 50, block):
            means.add(whole[start:start + block])
        np.testing.assert_array_equal(means.mean(), nanmean(whole.astype(float), axis=0))


@pytest.mark.parametrize("axis", [0, 1, None, (1, 2)])
@pytest.mark.parametrize("order", ["C", "F"])
def test_nanmean_is_numpys_nanmean_to_the_bit(axis, order):
    """tracking_metrics.nanmean finds the NaNs once and follows np.nanmean's steps: the same
    bits on either layout, all-NaN slices NaN (without a warning)."""
    import warnings

    from trackreplay.evaluators.tracking_metrics import nanmean

    rng = np.random.default_rng(5)
    a = np.asarray(rng.normal(size=(40, 9, 3)), order=order)
    a[a > 1.0] = np.nan
    a[:, 2] = np.nan
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        expected = np.nanmean(a, axis=axis)
    got = nanmean(a, axis=axis)
    assert type(got) is type(expected)
    np.testing.assert_array_equal(_bits(got), _bits(expected))
    np.testing.assert_array_equal(_bits(nanmean(np.nan_to_num(a), axis=axis)), _bits(np.mean(np.nan_to_num(a), axis=axis)))


@pytest.mark.parametrize("block", [1 << 14, 7 * 3])
def test_squared_error_is_the_sum_of_squares_component_by_component(monkeypatch, block):
    """squared_error squares each difference where it is made, a block of runs at a time: the
    bits of the plain loop ``total = 0; total += (e_i − t_i)²``, NaN passing through,
    broadcast truth included."""
    from trackreplay.evaluators import tracking_metrics
    from trackreplay.evaluators.tracking_metrics import squared_error

    monkeypatch.setattr(tracking_metrics, "SQUARED_ERROR_BLOCK", block)    # or 3 runs a block

    rng = np.random.default_rng(6)
    e = np.moveaxis(rng.normal(size=(4, 30, 7)), 0, -1)          # a buffer's layout: components slowest
    t = rng.normal(size=(30, 7, 4))
    e[3, 2, 1] = np.nan
    for a, b in ((e, t), (e[..., :2], t[..., :2]), (e[..., 2:], 0.0), (e[..., :1], t[..., :1])):
        a, b = np.broadcast_arrays(a, np.asarray(b, float))
        plain = np.zeros(a.shape[:-1])
        for i in range(a.shape[-1]):
            plain += (a[..., i] - b[..., i]) * (a[..., i] - b[..., i])
        got = squared_error(a, b)
        np.testing.assert_array_equal(_bits(got), _bits(plain))
        assert got.flags.c_contiguous                           # the layout the sums over runs read
    assert squared_error(np.zeros((3, 2, 0)), 0.0).shape == (3, 2)
    assert squared_error(np.array([3.0, 4.0]), 0.0) == 25.0


def test_whiteness_from_the_nis_is_the_whiteness_of_the_innovations():
    """The standard measures' whiteness reads presence and ‖w‖² from the NIS whitening gave:
    the bits of innovation_whiteness on the same innovations (missing and indefinite ones too)."""
    rng = np.random.default_rng(32)
    R, K, m = 17, 12, 2
    S = _covariances((R, K), m, rng)
    nu = rng.normal(size=(R, K, m)) + 0.3 * np.cumsum(rng.normal(size=(R, K, m)), axis=1)
    nu[:, :2] = np.nan
    nu[4, 7, 1] = np.nan
    S[6, 5] = -np.eye(m)
    w, nis = consistency.whitened_innovations({"innovation": nu, "innovation_covariance": S})
    plain = consistency.innovation_whiteness(nu, S)
    fast = consistency._whiteness_of_whitened(w[:, :, 0], nis[:, :, 0])
    np.testing.assert_array_equal(_bits(fast["rho"]), _bits(plain["rho"]))
    np.testing.assert_array_equal(fast["bound"], plain["bound"])
    # the products of every lag in one buffer: the sums of the products numpy makes lag by lag
    w0 = np.where(all_finite(w[:, :, 0])[..., None], w[:, :, 0], 0.0)
    power, present = sum_squares(w0), all_finite(w[:, :, 0])
    for i, j in enumerate(plain["lags"]):
        both = present[:, :-j] & present[:, j:]
        rho = np.sum(w0[:, :-j] * w0[:, j:]) / np.sqrt(np.sum(power[:, :-j], where=both) *
                                                      np.sum(power[:, j:], where=both))
        assert _bits(np.array([rho])) == _bits(plain["rho"][i:i + 1])
    assert fast["outside"] == plain["outside"] and np.isfinite(fast["rho"]).all()


@pytest.mark.parametrize("left_out", [False, True], ids=["alone", "left-out"])
def test_radar_group_records_are_the_rows_of_the_group_tables(left_out):
    """The radar groups' summaries as records hold every row of their tables, value for value,
    and summary_intervals gives the same table from either."""
    times, tracks, measured, truth, cross, pcrb = _radar_outputs(43)
    args = (times, tracks, measured, truth, cross, 1.0, pcrb)
    _, summary, tables = radar.evaluate(*args, groups=10, left_out=left_out)
    _, summary_r, records = radar.evaluate(*args, groups=10, left_out=left_out, records=True)
    assert summary.equals(summary_r) and len(records) == len(tables) == 10
    for table, rows in zip(tables, records):
        expected = {(t, m, s): v for t, m, s, v in table.iter_rows()}
        got = {(t, m, s): v for t, m, s, v in rows}
        assert len(got) == len(rows) == table.height and got.keys() == expected.keys()
        assert all(_bits(np.array([got[k]])) == _bits(np.array([expected[k]])) for k in got)
    data = {"tracks": tracks}
    score = lambda d, groups=None, left_out=False, records=False: radar.evaluate(  # noqa: E731
        times, d["tracks"], measured, truth, cross, 1.0, pcrb, groups=groups, left_out=left_out, records=records)
    _, from_tables = summary_intervals(score, data, 43, score_groups=score)
    _, from_records = summary_intervals(score, data, 43, score_groups=lambda d, g, lo: score(d, g, lo, True))
    assert from_tables.equals(from_records)


def test_the_truths_single_target_case_found_once_is_the_one_found_per_tracker():
    """truth_one_identity_per_run tells the truth's half of the single-target case, and the
    standard measures given it are those that find it themselves."""
    rng = np.random.default_rng(13)
    R, K = 9, 7
    truth = rng.normal(scale=100.0, size=(R, K, 4))
    out = {"state": truth + rng.normal(scale=20.0, size=(R, K, 4)), "flags": np.zeros((R, K), np.uint16),
           "covariance": _covariances((R, K), 4, rng) * 400.0}
    space = standard.EvaluationSpace(truth_components=(0, 1, 2, 3), position_components=(0, 1), angular=False,
                                     cutoff=60.0, gate=40.0)
    ids = np.zeros((R, K), np.int64)
    assert standard.truth_one_identity_per_run(truth, space, ids)
    two = ids.copy()
    two[3, 4:] = 1                                              # a run whose target changes identity
    assert not standard.truth_one_identity_per_run(truth, space, two)
    assert not standard.truth_one_identity_per_run(np.stack([truth, truth], axis=2), space)
    for truth_ids in (ids, two):
        found = standard.evaluate_standard(np.arange(K, dtype=float), {"t": out}, truth, space, truth_ids=truth_ids)
        given = standard.evaluate_standard(np.arange(K, dtype=float), {"t": out}, truth, space, truth_ids=truth_ids,
                                           truth_single=standard.truth_one_identity_per_run(truth, space, truth_ids))
        assert found[0].equals(given[0]) and found[1].equals(given[1])


def test_polar_position_information_entry_by_entry_is_the_matrix_expression():
    """The radar PCRB's information, written entry by entry, is u uᵀ/σ_r² + t tᵀ/(r² σ_θ²) as
    whole matrices give it, to the bit (a target at the origin and a missing one too)."""
    from trackreplay.cores.filters.pcrb import polar_position_information

    rng = np.random.default_rng(14)
    xy = rng.uniform(-5e4, 5e4, size=(40, 7, 2))
    xy[0, 0], xy[1, 1, 0] = 0.0, np.nan
    sigma_r, sigma_b = 30.0, np.deg2rad(0.8)
    r = np.hypot(xy[..., 0], xy[..., 1])
    with np.errstate(invalid="ignore", divide="ignore"):
        u = xy / r[..., None]
        t = np.stack([-u[..., 1], u[..., 0]], axis=-1)
        plain = (u[..., :, None] * u[..., None, :]) / sigma_r**2 \
            + (t[..., :, None] * t[..., None, :]) / (r[..., None, None] ** 2 * sigma_b**2)
        fast = polar_position_information(xy, sigma_r, sigma_b)
    np.testing.assert_array_equal(_bits(fast), _bits(plain))
    assert np.isfinite(fast[2:]).all() and np.isnan(fast[0, 0]).all()


@pytest.mark.parametrize("dtype", [np.uint8, np.int16, np.uint16, np.uint32, np.int64, np.float64])
def test_flags_tested_in_their_own_type_are_those_of_an_int64_copy(dtype):
    from trackreplay.vocabulary import DELETED

    rng = np.random.default_rng(15)
    info = np.iinfo(dtype) if np.dtype(dtype).kind in "iu" else None
    high = min(info.max, 1 << 20) if info is not None else 1 << 20
    flags = rng.integers(info.min if info is not None else 0, high, size=(20, 6, 1), endpoint=True).astype(dtype)
    bits = NO_TRACK | DELETED | INITIALISING
    expected = (flags.astype(np.int64) & bits) > 0
    np.testing.assert_array_equal(standard._any_flag(flags, bits), expected)
    assert expected.any() and not expected.all()


def test_consistency_summary_reads_the_finite_values_once():
    """consistency_summary finds where the values are finite once for its counts, its time
    average's interval and its effective number of scans: those of the public functions."""
    rng = np.random.default_rng(16)
    nx = rng.chisquare(4, size=(60, 25)) + np.cumsum(rng.normal(size=(60, 25)), axis=1) ** 2
    nx[:, :2] = np.nan
    nx[5, 7] = np.inf
    c = consistency.consistency_summary(nx, 4, white=False)
    mean, se, low, high, _ = consistency.run_mean_interval(nx)
    assert (c["time_average"], c["time_se"], c["time_ci_high"]) == (mean, se, high)
    assert c["inside_trials"] == min(float(c["scans"]), consistency.effective_scans(nx)) < c["scans"]


@pytest.mark.parametrize("runs,groups,block", [(43, 10, 64), (43, 10, 1 << 14), (7, 10, 64), (100, 10, 30),
                                               (37, 1, 50)])
def test_radar_sums_in_blocks_of_runs_are_the_group_totals(runs, groups, block):
    """A radar tracker's per-group sums taken a block of runs at a time (the runs left over
    last, fewer runs than groups too) are those of the whole (runs, scans) arrays, to the bit."""
    times, tracks, measured, truth, cross, pcrb = _radar_outputs(runs)
    for out in tracks.values():
        for with_truth in (truth, None):
            plain = radar._tracker_sums(out, measured, with_truth, lambda a: group_totals(a, groups))
            fast = radar._tracker_sums_in_blocks(out, measured, with_truth, groups, block)
            assert plain.keys() == fast.keys()
            for key in plain:
                pair = (plain[key], fast[key]) if isinstance(plain[key], tuple) else ((plain[key],), (fast[key],))
                for p, f in zip(*pair):
                    np.testing.assert_array_equal(_bits(f), _bits(p), err_msg=key)
