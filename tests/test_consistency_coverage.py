"""The consistency bounds and the rate intervals hold their stated 95 % coverage.

Independent data sets of a correctly modelled linear Kalman filter (2-D constant velocity,
position measurements, model matched, from a wide initial covariance: a transient phase, then
the steady state) are simulated with numpy alone; their NEES and NIS go through the project's
own functions (:func:`trackreplay.evaluators.consistency.normalised_squared`,
:func:`trackreplay.evaluators.consistency.consistency_summary`), and the bounds the tables print must contain
the truth (the "consistent" verdict must hold) in 95 % of the data sets, up to what a binomial
count of data sets allows. The rate intervals are checked the same way on Bernoulli data sets,
through :func:`trackreplay.evaluators.confidence.summary_intervals`, the path every family table takes.

``benchmarks/coverage_consistency.py`` runs the same study on more data sets and prints the
figures quoted in ``docs/evaluation.md``.
"""

from __future__ import annotations

import numpy as np
import polars as pl
from scipy.stats import binom

from trackreplay.evaluators.confidence import summary_intervals
from trackreplay.evaluators.consistency import average_bounds, consistency_summary, normalised_squared

NOMINAL = 0.95
#: a count of data sets outside the central 99.8 % of Binomial(D, 0.95) fails: with the few
#: checks of this file, a correct interval fails one of them by chance about once in a hundred runs
TAIL = 0.001


def kalman_data_sets(rng, sets: int, runs: int, scans: int, dt: float = 1.0, q: float = 0.01, r: float = 10.0,
                     sigma0=(100.0, 10.0)):
    """NEES (sets, runs, scans) of the 4-state and NIS of the 2-component innovation of a Kalman
    filter whose model is the truth's: constant velocity in x and y driven by continuous white
    acceleration of spectral density ``q`` (m²/s³), positions measured with σ = ``r`` m every
    ``dt`` s, the first estimate drawn from N(truth, diag(σ_p², σ_v²)²) (``sigma0``) which is also
    its covariance. The gains do not depend on the data, so one Riccati recursion serves every
    run; truth, measurements and estimates are simulated for every run."""
    F1 = np.array([[1.0, dt], [0.0, 1.0]])
    Q1 = q * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
    F, Q = np.kron(np.eye(2), F1), np.kron(np.eye(2), Q1)
    H = np.kron(np.eye(2), np.array([[1.0, 0.0]]))
    R = r**2 * np.eye(2)
    P0 = np.diag([sigma0[0] ** 2, sigma0[1] ** 2] * 2)
    P, covariances, innovation_covariances, gains = P0, [], [], []
    for _ in range(scans):
        Pp = F @ P @ F.T + Q
        S = H @ Pp @ H.T + R
        K = np.linalg.solve(S, H @ Pp).T
        A = np.eye(4) - K @ H
        P = A @ Pp @ A.T + K @ R @ K.T                     # Joseph form
        covariances.append(P)
        innovation_covariances.append(S)
        gains.append(K)
    Lq, Lr, L0 = np.linalg.cholesky(Q), np.linalg.cholesky(R), np.linalg.cholesky(P0)
    shape = (sets, runs)
    x = rng.normal(size=shape + (4,)) * [1000.0, 10.0, 1000.0, 10.0]
    estimate = x + rng.normal(size=shape + (4,)) @ L0.T
    error = np.empty(shape + (scans, 4))
    innovation = np.empty(shape + (scans, 2))
    for k in range(scans):
        x = x @ F.T + rng.normal(size=shape + (4,)) @ Lq.T
        z = x @ H.T + rng.normal(size=shape + (2,)) @ Lr.T
        predicted = estimate @ F.T
        innovation[..., k, :] = z - predicted @ H.T
        estimate = predicted + innovation[..., k, :] @ gains[k].T
        error[..., k, :] = estimate - x
    nees = normalised_squared(error, np.array(covariances))
    nis = normalised_squared(innovation, np.array(innovation_covariances))
    return nees, nis


def consistency_coverage(seed: int, sets: int, runs: int, scans: int, batch: int = 100, **model) -> dict:
    """Over ``sets`` data sets: how many the printed NEES and NIS time-average bounds call
    consistent, how many the former χ² bound of the NEES time average did, and how many Wilson
    intervals of the ANEES / ANIS inside fraction contain 0.95."""
    rng = np.random.default_rng(seed)
    hits = {"nees": 0, "nis": 0, "nees_chi2_all_values": 0, "anees_inside": 0, "anis_inside": 0}
    done = 0
    while done < sets:
        n = min(batch, sets - done)
        nees, nis = kalman_data_sets(rng, n, runs, scans, **model)
        for d in range(n):
            c = consistency_summary(nees[d], 4)
            i = consistency_summary(nis[d], 2, white=True)
            lo, hi = average_bounds(4, runs * scans)
            hits["nees"] += c["time_low"] <= c["time_average"] <= c["time_high"]
            hits["nis"] += i["time_low"] <= i["time_average"] <= i["time_high"]
            hits["nees_chi2_all_values"] += lo <= c["time_average"] <= hi
            hits["anees_inside"] += c["inside_low"] <= NOMINAL <= c["inside_high"]
            hits["anis_inside"] += i["inside_low"] <= NOMINAL <= i["inside_high"]
        done += n
    return hits


def acceptance(sets: int, tail: float = TAIL) -> tuple[int, int]:
    """The counts of data sets inside that a 95 % interval gives with probability 1 − 2·tail."""
    return int(binom.ppf(tail, sets, NOMINAL)), int(binom.isf(tail, sets, NOMINAL))


def rate_data_set(rng, runs: int, p: float, cells: int = 10, correlation: float = 0.3):
    """One outcome per run (Bernoulli p) and ``cells`` outcomes per run that share a run-level
    probability drawn from a Beta of mean p and intra-run correlation ``correlation``."""
    outcome = rng.random(runs) < p
    a, b = p * (1 - correlation) / correlation, (1 - p) * (1 - correlation) / correlation
    cell = rng.random((runs, cells)) < rng.beta(a, b, runs)[:, None]
    return {"outcome": outcome, "cells": cell}


def _score_rates(data):
    return None, pl.DataFrame({"tracker": ["t", "t"], "metric": ["loss_rate", "converged_fraction"],
                               "scope": ["overall", "overall"],
                               "value": [float(np.mean(data["outcome"])), float(np.mean(data["cells"]))]})


def rate_coverage(seed: int, sets: int, runs: int, p: float) -> dict:
    """Coverage of p by the table's intervals of a one-outcome-per-run rate (``loss_rate``) and
    of a pooled rate (``converged_fraction``), and whether any interval left [0, 1] or missed
    its own value."""
    rng = np.random.default_rng(seed)
    hits, bad = np.zeros(2, int), 0
    for _ in range(sets):
        _, table = summary_intervals(_score_rates, rate_data_set(rng, runs, p), runs)
        lo, hi, v = (table[c].to_numpy().astype(float) for c in ("ci_low", "ci_high", "value"))
        hits += (lo <= p) & (p <= hi)
        bad += bool(np.any(lo < 0) or np.any(hi > 1) or np.any(v < lo) or np.any(v > hi))
    return {"run": int(hits[0]), "pooled": int(hits[1]), "outside_or_missing_value": bad}


# ---------------------------------------------------------------------------------------------


SETS = 1500


def test_nees_and_nis_time_average_bounds_hold_their_coverage():
    # 1500 data sets of 60 runs × 100 scans: the transient from the wide start, then the steady
    # state, where the NEES is correlated from scan to scan (lag-1 correlation about 0.85)
    hits = consistency_coverage(seed=2026, sets=SETS, runs=60, scans=100)
    low, high = acceptance(SETS)
    assert low <= hits["nees"] <= high, (hits, low, high)
    assert low <= hits["nis"] <= high, (hits, low, high)
    # the χ² bound of all N·K values, which counts correlated values as independent, fails it
    assert hits["nees_chi2_all_values"] < 0.8 * SETS, hits
    # the Wilson intervals of the fraction of scans inside: at least nominal (the NEES one counts
    # effective scans and may be conservative), and not vacuous
    assert low <= hits["anis_inside"] <= high, (hits, low, high)
    assert low <= hits["anees_inside"] <= 0.995 * SETS, (hits, low)


def test_a_wrong_covariance_is_found_inconsistent_by_the_time_average_bounds():
    rng = np.random.default_rng(7)
    nees, nis = kalman_data_sets(rng, 1, 60, 100)
    for scale, side in ((0.5, "high"), (2.0, "low")):
        c = consistency_summary(nees[0] / scale, 4)
        i = consistency_summary(nis[0] / scale, 2, white=True)
        for s in (c, i):
            assert (s["time_average"] > s["time_high"]) if side == "high" else (s["time_average"] < s["time_low"])
    # the NEES bounds hold n and mirror the time average's own interval over runs (the verdict is
    # the same read either way)
    c = consistency_summary(nees[0], 4)
    assert c["time_low"] < 4 < c["time_high"]
    assert np.isclose(c["time_low"] - 4, c["time_average"] - c["time_ci_high"])
    assert np.isclose(c["time_high"] - 4, c["time_average"] - c["time_ci_low"])


RATE_SETS = 500


def test_rate_intervals_hold_their_coverage_inside_zero_one():
    low, high = acceptance(RATE_SETS)
    for runs, p in ((200, 0.01), (200, 0.5), (60, 0.5)):
        r = rate_coverage(seed=int(1000 * p) + runs, sets=RATE_SETS, runs=runs, p=p)
        assert r["outside_or_missing_value"] == 0, (runs, p, r)
        assert low <= r["run"] <= high, (runs, p, r, low, high)
        # the pooled rate's Korn–Graubard interval may be conservative at small p, never short
        assert r["pooled"] >= low, (runs, p, r, low)
        if p == 0.5:
            assert r["pooled"] <= high, (runs, p, r, high)


def test_a_rare_loss_gets_an_interval_inside_zero_one():
    # the review's example: a loss rate of 0.01 (2 of 200 runs), whose t interval over groups
    # of runs was [−0.013, 0.033]
    outcome = np.zeros(200, bool)
    outcome[[3, 150]] = True
    data = {"outcome": outcome, "cells": np.zeros((200, 10), bool)}
    _, table = summary_intervals(_score_rates, data, 200)
    loss = table.filter(pl.col("metric") == "loss_rate").row(0, named=True)
    assert 0 < loss["ci_low"] < 0.01 < loss["ci_high"] < 0.04
    never = table.filter(pl.col("metric") == "converged_fraction").row(0, named=True)
    # no success in any run: the interval starts at 0 and counts the 200 runs, not 2000 cells
    assert never["ci_low"] == 0 and 0.01 < never["ci_high"] < 0.03
