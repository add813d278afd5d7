"""The standard measures: χ² bounds, NEES/NIS consistency, OSPA/GOSPA, assignment metrics and
Monte Carlo intervals, each against an independent computation or a property that could fail."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from trackreplay.evaluators.assignment_metrics import assignment_metrics
from trackreplay.evaluators.confidence import jackknife, mean_interval, rms_interval, wilson_interval
from trackreplay.evaluators.consistency import average_bounds, innovation_whiteness, normalised_squared
from trackreplay.evaluators.set_distances import BRUTE_FORCE_MAX, gospa
from trackreplay.evaluators.standard import EvaluationSpace, evaluate_standard

# ------------------------------------------------------------------ χ² bounds


@pytest.mark.parametrize("dim,count", [(1, 1), (2, 50), (4, 200), (6, 1000)])
def test_average_bounds_match_the_gamma_distribution(dim, count):
    # the mean of N independent χ²_n is Gamma(shape nN/2, scale 2/N): an independent route
    from scipy.stats import gamma

    lo, hi = average_bounds(dim, count)
    ref = gamma.ppf([0.025, 0.975], a=dim * count / 2, scale=2 / count)
    np.testing.assert_allclose([lo, hi], ref, rtol=1e-12)


def test_normalised_squared_matches_the_explicit_form():
    rng = np.random.default_rng(0)
    A = rng.normal(size=(50, 3, 3))
    P = A @ np.swapaxes(A, -1, -2) + 0.1 * np.eye(3)
    e = rng.normal(size=(50, 3))
    ref = np.einsum("ki,kij,kj->k", e, np.linalg.inv(P), e)  # the textbook form, as a check only
    np.testing.assert_allclose(normalised_squared(e, P), ref, rtol=1e-10)


def test_whiteness_bounds_hold_for_white_and_fail_for_correlated_innovations():
    rng = np.random.default_rng(1)
    S = np.broadcast_to(np.eye(2), (400, 60, 2, 2))
    white = rng.normal(size=(400, 60, 2))
    w = innovation_whiteness(white, S, max_lag=5)
    assert w["outside"] <= 1
    ar = np.zeros_like(white)
    for k in range(60):  # AR(1) innovations with coefficient 0.5
        ar[:, k] = white[:, k] + (0.5 * ar[:, k - 1] if k else 0.0)
    assert innovation_whiteness(ar, S, max_lag=5)["rho"][0] > 0.3


# ------------------------------------------------------------------ NEES of the Kalman reference


@pytest.fixture(scope="module")
def model_matched(tmp_path_factory):
    """Radar truth with the filter's own process noise (σ_v = 0.98): the Kalman reference is
    matched to it up to the converted-measurement linearisation."""
    from trackreplay.contract import read_dataset
    from trackreplay.replay import replay
    from trackreplay.recorders.scenarios import load_scenario
    from trackreplay.recorders.simulated import record

    path = tmp_path_factory.mktemp("nees") / "matched.mcap"
    sc = load_scenario("radar-tws").with_overrides({"truth_process_noise_mps2": 0.98})
    record(path, sc, runs=300, seed=3)
    ds = read_dataset(path)
    res = replay(path, trackers=["kalman"], dataset=ds)
    return res.results["radar"], ds.channel("/radar/truth").grid("state")


SPACE = EvaluationSpace((0, 1, 2, 3), (0, 1), False, cutoff=1000.0, gate=1000.0)


def _metric(summary, tracker, metric):
    row = summary.filter((summary["tracker"] == tracker) & (summary["metric"] == metric))
    return float(row["value"][0])


def test_kalman_reference_is_consistent_on_model_matched_truth(model_matched):
    result, truth = model_matched
    _, summary = evaluate_standard(result["times"], result["tracks"], truth, SPACE)
    # fraction of scans inside the 95 % bounds, less two binomial standard errors over 63 scans
    floor = 0.95 - 2 * np.sqrt(0.95 * 0.05 / 63)
    assert _metric(summary, "kalman", "anees_inside_fraction") >= floor
    assert _metric(summary, "kalman", "anis_inside_fraction") >= floor
    lo, hi = (_metric(summary, "kalman", f"nees_time_average_{s}") for s in ("low", "high"))
    assert lo <= _metric(summary, "kalman", "nees_time_average") <= hi


@pytest.mark.parametrize("scale,side", [(0.25, "high"), (4.0, "low")])
def test_a_wrong_covariance_falls_outside_on_the_right_side(model_matched, scale, side):
    result, truth = model_matched
    out = dict(result["tracks"]["kalman"])
    out["covariance"] = out["covariance"] * scale
    _, summary = evaluate_standard(result["times"], {"wrong": out}, truth, SPACE)
    nees = _metric(summary, "wrong", "nees_time_average")
    bound = _metric(summary, "wrong", f"nees_time_average_{side}")
    assert (nees > bound) if side == "high" else (nees < bound)
    assert _metric(summary, "wrong", "anees_inside_fraction") < 0.1


# ------------------------------------------------------------------ OSPA / GOSPA


def _brute_gospa(X, Y, c, p):
    """GOSPA (α = 2) by enumerating every partial assignment (the definition itself)."""
    best = np.inf
    for k in range(min(len(X), len(Y)) + 1):
        for rows in itertools.combinations(range(len(X)), k):
            for cols in itertools.permutations(range(len(Y)), k):
                s = sum(np.linalg.norm(X[i] - Y[j]) ** p for i, j in zip(rows, cols))
                best = min(best, s + c**p / 2 * (len(X) + len(Y) - 2 * k))
    return best ** (1 / p)


def _brute_ospa(X, Y, c, p):
    if len(X) > len(Y):
        X, Y = Y, X
    m, n = len(X), len(Y)
    if n == 0:
        return 0.0
    best = min(sum(min(np.linalg.norm(X[i] - Y[j]), c) ** p for i, j in zip(range(m), perm))
               for perm in itertools.permutations(range(n), m))
    return ((best + c**p * (n - m)) / n) ** (1 / p)


def _padded(points, width):
    out = np.full((width, 2), np.nan)
    out[: len(points)] = points
    return out


@pytest.mark.parametrize("seed", range(40))
def test_gospa_and_ospa_match_brute_force(seed):
    rng = np.random.default_rng(seed)
    m, n = rng.integers(0, 5, 2)  # includes no tracks, no targets, more tracks than targets
    X, Y = rng.normal(scale=3, size=(m, 2)), rng.normal(scale=3, size=(n, 2))
    c, p = rng.uniform(0.5, 4), int(rng.integers(1, 4))
    r = gospa(_padded(X, 5)[None], _padded(Y, 6)[None], c, p)
    assert r["gospa"][0] == pytest.approx(_brute_gospa(X, Y, c, p), rel=1e-9, abs=1e-12)
    assert r["ospa"][0] == pytest.approx(_brute_ospa(X, Y, c, p), rel=1e-9, abs=1e-12)
    # the parts add up to GOSPA^p
    parts = r["localisation"][0] ** p + c**p / 2 * (r["missed"][0] + r["false"][0])
    assert parts == pytest.approx(r["gospa"][0] ** p, rel=1e-9, abs=1e-12)


def test_large_sets_use_the_hungarian_algorithm_and_agree():
    from scipy.optimize import linear_sum_assignment

    rng = np.random.default_rng(5)
    n = BRUTE_FORCE_MAX + 3
    X, Y = rng.normal(size=(3, n, 2)), rng.normal(size=(3, n, 2))
    c = 1.5
    r = gospa(X, Y, c, 2)
    for i in range(3):
        d = np.minimum(np.linalg.norm(X[i][:, None] - Y[i][None], axis=-1), c) ** 2
        rows, cols = linear_sum_assignment(d)
        assert r["gospa"][i] == pytest.approx(np.sqrt(d[rows, cols].sum()), rel=1e-12)


@pytest.mark.parametrize("size", range(1, BRUTE_FORCE_MAX + 1))
def test_small_sets_find_the_permutation_every_permutation_sum_finds(size, monkeypatch):
    # independent route: every permutation's costs gathered and summed, the first of the
    # smallest sums in itertools' order; ties (rounded and repeated costs) must go the same way,
    # and problems split over several blocks must not interact
    from trackreplay.evaluators import set_distances_fast

    monkeypatch.setattr(set_distances_fast, "BRUTE_FORCE_BLOCK_SUMS", 1000 * math.factorial(size))
    rng = np.random.default_rng(size)
    costs = rng.random((2500, size, size))
    costs[:800] = np.round(costs[:800] * 3) / 7
    costs[800:1600] = np.where(rng.random((800, size, size)) < 0.5, 0.3, costs[800:1600])
    perms = np.array(list(itertools.permutations(range(size))))
    sums = costs[:, np.arange(size)[None, :], perms].sum(axis=-1)
    first = np.argmin(sums, axis=1)
    total, best = set_distances_fast._every_permutation(costs)
    np.testing.assert_array_equal(total, sums[np.arange(len(costs)), first])
    np.testing.assert_array_equal(best, perms[first])


sets = st.lists(st.tuples(st.floats(-10, 10), st.floats(-10, 10)), max_size=4)


@settings(max_examples=150, deadline=None)
@given(sets, sets, sets)
def test_gospa_is_a_metric(a, b, c_set):
    A, B, C = (_padded(np.array(s).reshape(-1, 2), 4)[None] for s in (a, b, c_set))
    d = lambda x, y: float(gospa(x, y, 3.0, 2)["gospa"][0])  # noqa: E731
    assert d(A, A) == pytest.approx(0.0, abs=1e-9)
    assert d(A, B) == pytest.approx(d(B, A), rel=1e-9, abs=1e-9)
    assert d(A, C) <= d(A, B) + d(B, C) + 1e-9


def test_angular_distances_wrap():
    r = gospa(np.array([[[np.pi - 0.01]]]), np.array([[[-np.pi + 0.01]]]), 1.0, 2, angular=True)
    assert r["gospa"][0] == pytest.approx(0.02, rel=1e-9)


# ------------------------------------------------------------------ assignment metrics


def test_assignment_counts_on_a_hand_built_history():
    """Two targets, three track slots over six scans: slot 0 follows target 0; slot 1 follows
    target 1 for scans 0–2; nothing at scan 3 (a miss); slot 2 takes target 1 at scans 4–5 (a
    break and an identity switch); slot 2's ghost at scan 0 far away (a false positive); and a
    fourth target never tracked (mostly lost)."""
    K = 6
    truth = np.full((1, K, 3, 1), np.nan)
    truth[0, :, 0, 0], truth[0, :, 1, 0], truth[0, :, 2, 0] = 0.0, 10.0, 50.0
    tracks = np.full((1, K, 3, 1), np.nan)
    tracks[0, :, 0, 0] = 0.1
    tracks[0, :3, 1, 0] = 10.1
    tracks[0, 4:, 2, 0] = 10.2
    tracks[0, 0, 2, 0] = 30.0
    m = {k: v[0] for k, v in assignment_metrics(tracks, truth, gate=1.0).items()}
    assert m["matches"] == 11 and m["misses"] == 1 + 6
    assert m["false_positives"] == 1 and m["id_switches"] == 1 and m["track_breaks"] == 1
    assert (m["mostly_tracked"], m["partially_tracked"], m["mostly_lost"]) == (2, 0, 1)
    assert m["false_tracks"] == 0  # slot 2 is matched at scans 4–5
    assert m["mota"] == pytest.approx(1 - (7 + 1 + 1) / 18)
    # identities: target 0 ↔ slot 0 (6 scans), target 1 ↔ slot 1 (3 scans) or slot 2 (2 scans)
    assert m["idtp"] == 9 and m["idfn"] == 18 - 9 and m["idfp"] == 12 - 9


def test_a_track_that_never_meets_a_target_is_a_false_track():
    truth = np.zeros((1, 4, 1, 1))
    tracks = np.full((1, 4, 2, 1), np.nan)
    tracks[0, :, 0, 0] = 0.0
    tracks[0, :, 1, 0] = 100.0
    m = assignment_metrics(tracks, truth, gate=1.0)
    assert m["false_tracks"][0] == 1 and m["idf1"][0] == pytest.approx(2 * 4 / (2 * 4 + 4 + 0))


# ------------------------------------------------------------------ Monte Carlo intervals


def _coverage(trials, make, truth):
    hits = 0
    for i in range(trials):
        lo, hi = make(np.random.default_rng(1000 + i))
        hits += lo <= truth <= hi
    return hits / trials


def _within_mc_error(rate, trials, nominal=0.95):
    return abs(rate - nominal) <= 3 * np.sqrt(nominal * (1 - nominal) / trials)


def test_rms_interval_covers_a_known_rmse_at_its_nominal_rate():
    sigma, runs, trials = 2.0, 40, 600

    def make(rng):  # per-run mean square of 10 scans of 2-D Gaussian errors: true RMSE = σ√2
        err = rng.normal(scale=sigma, size=(runs, 10, 2))
        _, _, lo, hi = rms_interval(np.mean(np.sum(err**2, axis=-1), axis=1))
        return lo, hi

    assert _within_mc_error(_coverage(trials, make, sigma * np.sqrt(2)), trials)


def test_jackknife_interval_covers_a_known_rmse_at_its_nominal_rate():
    sigma, runs, trials = 1.0, 60, 500

    def make(rng):
        sq = np.sum(rng.normal(scale=sigma, size=(runs, 5, 2)) ** 2, axis=-1)
        _, _, lo, hi = jackknife(lambda idx: np.sqrt(np.mean(sq[idx])), runs)
        return lo, hi

    assert _within_mc_error(_coverage(trials, make, sigma * np.sqrt(2)), trials)


@pytest.mark.parametrize("runs", [60, 240], ids=["jackknife", "random-groups"])
def test_summary_intervals_cover_a_known_rmse_at_their_nominal_rate(runs):
    # the path every evaluator's table takes (trackreplay.evaluators.confidence.summary_intervals): grouped
    # jackknife below RANDOM_GROUPS_MIN_RUNS runs, random groups from there on
    import polars as pl

    from trackreplay.evaluators.confidence import RANDOM_GROUPS_MIN_RUNS, summary_intervals

    assert (runs >= RANDOM_GROUPS_MIN_RUNS) == (runs == 240)
    sigma, trials = 1.0, 300

    def make(rng):
        err = rng.normal(scale=sigma, size=(runs, 5, 2))

        def score(data):
            rmse = float(np.sqrt(np.mean(np.sum(data["err"] ** 2, axis=-1))))
            return None, pl.DataFrame({"tracker": ["t"], "metric": ["rmse"], "scope": ["overall"], "value": [rmse]})

        _, table = summary_intervals(score, {"err": err}, runs)
        return table["ci_low"][0], table["ci_high"][0]

    assert _within_mc_error(_coverage(trials, make, sigma * np.sqrt(2)), trials)


def test_mean_and_wilson_intervals_cover_at_their_nominal_rate():
    trials = 800
    rate_mean = _coverage(trials, lambda rng: mean_interval(rng.normal(3.0, 2.0, 30))[2:], 3.0)
    assert _within_mc_error(rate_mean, trials)
    rate_p = _coverage(trials, lambda rng: wilson_interval(rng.binomial(100, 0.9), 100), 0.9)
    assert _within_mc_error(rate_p, trials)


def test_identity_counts_agree_between_the_vectorised_and_the_per_run_paths():
    # few identities take one vectorised assignment; relabelling them beyond the brute-force
    # size sends the same histories through the per-run path: the counts must not change
    from trackreplay.evaluators.assignment_metrics import _identity_counts

    rng = np.random.default_rng(7)
    R, K, T, S = 40, 30, 3, 4
    ids = np.where(rng.random((R, K, S)) < 0.8, rng.integers(0, 5, (R, K, S)), -1)
    matched_id = np.where(rng.random((R, K, T)) < 0.7, rng.integers(0, 5, (R, K, T)), -1)
    present, track_present = rng.random((R, K, T)) < 0.9, ids >= 0
    fast = _identity_counts(ids, matched_id, present, track_present)
    shift = lambda a: np.where(a >= 0, a + 100, -1)
    slow = _identity_counts(shift(ids), shift(matched_id), present, track_present)
    for key in ("idtp", "idfp", "idfn", "false_tracks"):
        np.testing.assert_array_equal(fast[key], slow[key])
