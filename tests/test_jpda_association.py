"""JPDA joint-event probabilities: exact against brute-force enumeration, β sums to one,
clustering changes nothing, an isolated track is textbook PDA, bounded cost past the limits."""

import itertools
import time
import tracemalloc

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from trackreplay import vocabulary as vocab
from trackreplay.cores.association._jpda_fast import association_marginals_fast, joint_association_probabilities
from trackreplay.cores.association.jpda import (STRATEGIES, BearingTrackerDesign, amplitude_likelihood_ratio,
                           association_marginals, cluster_tracks, position_likelihood_ratio, update_strength,
                           window_gate_probability)
from trackreplay.cores.association.jpda_tracking import ScanPeaks, track_bearing_peaks
from trackreplay.cores.filters.kalman import two_point_start


def brute_force(ratio, miss, gated):
    """Enumerate every feasible joint event (each track one gated peak or none, no peak twice)."""
    T, m = ratio.shape
    beta, beta0, Z = np.zeros((T, m)), np.zeros(T), 0.0
    options = [[-1] + [j for j in range(m) if gated[t, j]] for t in range(T)]
    for event in itertools.product(*options):
        used = [j for j in event if j >= 0]
        if len(used) != len(set(used)):
            continue
        w = np.prod([miss[t] if j < 0 else ratio[t, j] for t, j in enumerate(event)])
        Z += w
        for t, j in enumerate(event):
            if j < 0:
                beta0[t] += w
            else:
                beta[t, j] += w
    return beta / Z, beta0 / Z


@st.composite
def cases(draw, max_tracks=5, max_peaks=6):
    T = draw(st.integers(1, max_tracks))
    m = draw(st.integers(0, max_peaks))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    # ratios over 8 orders of magnitude: the recursion must not lose precision to scaling
    ratio = rng.exponential(1.0, (T, m)) * 10.0 ** rng.uniform(-4, 4, (T, m))
    gated = rng.random((T, m)) < draw(st.floats(0.2, 1.0))
    miss = rng.uniform(1e-3, 1.0, T)
    return ratio, miss, gated


@settings(max_examples=150, deadline=None)
@given(cases())
def test_joint_event_probabilities_equal_brute_force(case):
    ratio, miss, gated = case
    expect_beta, expect_beta0 = brute_force(ratio, miss, gated)
    for clustering in (True, False):
        beta, beta0, split = joint_association_probabilities(ratio[None], miss[None], gated[None],
                                                             np.arange(len(miss))[None] * 1.0, 12, clustering)
        assert np.max(np.abs(beta[0] - expect_beta), initial=0) <= 1e-12
        assert np.max(np.abs(beta0[0] - expect_beta0)) <= 1e-12
        assert not split.any()


@settings(max_examples=60, deadline=None)
@given(cases(max_tracks=7, max_peaks=9))
def test_beta_sums_to_one_and_vanishes_outside_the_gate(case):
    ratio, miss, gated = case
    beta, beta0, _ = joint_association_probabilities(ratio[None], miss[None], gated[None], np.zeros((1, len(miss))))
    assert np.allclose(beta0[0] + beta[0].sum(axis=1), 1.0, rtol=0, atol=1e-12)
    assert np.all(beta[0][~gated] == 0) and np.all(beta >= 0) and np.all(beta0 >= 0)
    # a peak is used at most once over all events: Σ_t β_j^t ≤ 1
    assert np.all(beta[0].sum(axis=0) <= 1 + 1e-12)


def test_both_recursion_forms_agree_for_larger_clusters():
    """The transfer-matrix form (≤ 6 tracks, the fast form) and the state-by-state form (the plain
    one) are one recursion."""
    rng = np.random.default_rng(1)
    ratio = rng.exponential(1.0, (3, 8, 10))
    miss = rng.uniform(0.05, 1, (3, 8))
    ref_beta, ref_beta0 = association_marginals(ratio, miss)  # 8 tracks: loop form
    for r in range(3):
        bf_beta, bf_beta0 = brute_force(ratio[r, :5, :6], miss[r, :5], np.ones((5, 6), bool))
        for form in (association_marginals, association_marginals_fast):  # track by track, matrix form
            b, b0 = form(ratio[r:r + 1, :5, :6], miss[r:r + 1, :5])
            assert np.max(np.abs(b[0] - bf_beta)) < 1e-12 and np.max(np.abs(b0[0] - bf_beta0)) < 1e-12
    assert np.allclose(ref_beta0 + ref_beta.sum(-1), 1.0, atol=1e-12)


def test_batched_runs_equal_one_run_at_a_time_and_peak_order_does_not_matter():
    rng = np.random.default_rng(2)
    R, T, m = 20, 4, 12  # m > 8 also exercises the per-run compression of gated peaks
    ratio = rng.exponential(1.0, (R, T, m))
    gated = rng.random((R, T, m)) < 0.3
    miss = rng.uniform(0.05, 1, (R, T))
    bearing = rng.random((R, T))
    beta, beta0, _ = joint_association_probabilities(ratio, miss, gated, bearing, clustering=True)
    perm = rng.permutation(m)
    pb, pb0, _ = joint_association_probabilities(ratio[..., perm], miss, gated[..., perm], bearing)
    for r in range(R):
        b, b0, _ = joint_association_probabilities(ratio[r:r + 1], miss[r:r + 1], gated[r:r + 1], bearing[r:r + 1])
        assert np.max(np.abs(b[0] - beta[r])) < 1e-13 and np.max(np.abs(b0[0] - beta0[r])) < 1e-13
    assert np.max(np.abs(pb - beta[..., perm])) < 1e-13 and np.max(np.abs(pb0 - beta0)) < 1e-13


def test_clusters_are_connected_components_of_shared_peaks():
    gated = np.zeros((1, 5, 4), bool)
    gated[0, 0, 0] = gated[0, 1, 0] = True  # 0–1 share peak 0
    gated[0, 1, 1] = gated[0, 2, 1] = True  # 1–2 share peak 1 (0–2 linked through 1)
    gated[0, 3, 2] = True  # 3 alone; 4 has nothing
    assert cluster_tracks(gated)[0].tolist() == [0, 0, 0, 3, 4]


def test_clusters_beyond_the_exact_limit_are_cut_flagged_and_stay_bounded():
    rng = np.random.default_rng(3)
    T, m = 16, 40
    ratio = rng.exponential(1.0, (2, T, m))
    gated = np.ones((2, T, m), bool)  # one cluster of 16 tracks in both runs
    miss = rng.uniform(0.1, 1, (2, T))
    t0 = time.perf_counter()
    beta, beta0, split = joint_association_probabilities(ratio, miss, gated, rng.random((2, T)), max_cluster_tracks=6)
    assert time.perf_counter() - t0 < 5.0
    assert split.all()
    assert np.allclose(beta0 + beta.sum(-1), 1.0, atol=1e-12)
    # within a cut group the weights are exact for that group alone
    exact, exact0, split2 = joint_association_probabilities(ratio, miss, gated, rng.random((2, T)), max_cluster_tracks=16)
    assert not split2.any() and np.allclose(exact0 + exact.sum(-1), 1.0, atol=1e-12)


# --------------------------------------------------------------------------- PDA reduction


def textbook_pda(z_scans, x, P, F, Q, sigma_p, pd, lam, gate):
    """Bar-Shalom & Tse PDA for one track, scalar formulas written out independently.

    β_j = e_j / (b + Σ e), β_0 = b / (b + Σ e), e_j = exp(−ν_j²/2S),
    b = λ √(2π S) (1 − P_D P_G) / P_D.
    """
    xs = []
    for z in z_scans:
        x = F @ x
        P = F @ P @ F.T + Q
        S = P[0, 0] + sigma_p**2
        K = P[:, 0] / S
        nu = z - x[0]
        nu = nu[np.abs(nu) <= gate / 2]
        PG = float(window_gate_probability(np.array(S), gate))
        e = np.exp(-nu**2 / (2 * S))
        b = lam * np.sqrt(2 * np.pi * S) * (1 - pd * PG) / pd
        beta = e / (b + e.sum())
        beta0 = b / (b + e.sum())
        nu_bar = np.sum(beta * nu)
        x = x + K * nu_bar
        Pc = P - np.outer(K, K) * S
        P = beta0 * P + (1 - beta0) * Pc + np.outer(K, K) * (np.sum(beta * nu**2) - nu_bar**2)
        xs.append(x.copy())
    return np.array(xs)


def _design(T, **kw):
    base = dict(scan_period_s=1.0, gate_rad=np.deg2rad(10.0), q_rad2=0.1 * np.deg2rad(1) ** 2,
                amplitude_threshold=0.0, detection_probability=0.9, clutter_per_gate=2.0, clutter_alpha=4e-4,
                sigma_p_rad=np.full(T, np.deg2rad(1.3)), strength=np.full(T, 21000.0), sigma_a=np.full(T, 2500.0))
    base.update(kw)
    return BearingTrackerDesign(**base)


def _scans(z_lists, amp=20000.0):
    w = max(1, max(len(z) for z in z_lists))
    out = []
    for z in z_lists:
        b = np.zeros((1, w))
        v = np.zeros((1, w), bool)
        b[0, : len(z)] = z
        v[0, : len(z)] = True
        out.append(ScanPeaks(b, np.full((1, w), amp), v))
    return out


def test_isolated_track_reduces_exactly_to_pda():
    rng = np.random.default_rng(4)
    d = _design(1)
    K = 60
    truth = np.deg2rad(90) + np.deg2rad(0.2) * np.arange(K)
    z_lists = [np.sort(np.r_[truth[k] + d.sigma_p_rad[0] * rng.standard_normal(),
                             truth[k] + np.deg2rad(rng.uniform(-8, 8, rng.poisson(2)))]) for k in range(K)]
    x0, P0 = two_point_start(np.array([[truth[0]]]), np.array([[truth[0]]]), 1.0, d.sigma_p_rad)
    x0[..., 1] = np.deg2rad(0.2)
    out = track_bearing_peaks(_scans(z_lists), x0, P0, d, STRATEGIES["jpda"], start_scan=0)
    from trackreplay.cores.association.jpda import bearing_motion_model

    F, Q = bearing_motion_model(1.0, d.q_rad2)
    expect = textbook_pda(z_lists[1:], x0[0, 0], P0[0, 0], F, Q, d.sigma_p_rad[0], 0.9, d.clutter_density, d.gate_rad)
    assert np.max(np.abs(out["state"][0, 1:, 0] - expect)) < 1e-12


def test_two_tracks_with_disjoint_gates_are_two_independent_pdas():
    rng = np.random.default_rng(5)
    d2, d1 = _design(2), _design(1)
    K = 40
    truth = np.deg2rad(np.stack([75 + 0.1 * np.arange(K), 105 - 0.1 * np.arange(K)], 1))
    z = [np.sort(np.r_[truth[k] + d2.sigma_p_rad * rng.standard_normal(2),
                       np.deg2rad(rng.uniform(60, 120, rng.poisson(9)))]) for k in range(K)]
    x0 = np.stack([truth[0], np.deg2rad([0.1, -0.1])], -1)[None]
    _, P0 = two_point_start(truth[0][None], truth[0][None], 1.0, d2.sigma_p_rad)
    both = track_bearing_peaks(_scans(z), x0, P0, d2, STRATEGIES["jpda"], 0)
    assert np.min(np.abs(np.diff(both["gate_center"][0, 1:], axis=1))) > d2.gate_rad  # gates never overlap
    for t in range(2):
        alone = track_bearing_peaks(_scans(z), x0[:, t:t + 1], P0[:, t:t + 1], d1, STRATEGIES["jpda"], 0)
        assert np.max(np.abs(both["state"][0, 1:, t] - alone["state"][0, 1:, 0])) < 1e-12


# --------------------------------------------------------------------------- amplitude term


def test_amplitude_term_is_a_pluggable_factor_of_the_same_core():
    """JPDA_A's β equal the JPDA core's β fed with ratio × amplitude term (and P_D × survival)."""
    rng = np.random.default_rng(6)
    R, T, m = 5, 2, 7
    nu = np.deg2rad(rng.uniform(-5, 5, (R, T, m)))
    S = np.deg2rad(1.5) ** 2 * np.ones((R, T))
    amp = rng.uniform(5000, 30000, (R, m))
    strength = np.array([21000.0, 12000.0])
    sigma_a = np.array([2500.0, 3500.0])
    amp_ratio, survive = amplitude_likelihood_ratio(amp, np.broadcast_to(strength, (R, T)),
                                                    np.broadcast_to(sigma_a, (R, T)), 4e-4, 5000.0)
    # independent: scipy densities, truncated above the threshold
    from scipy import stats

    tn = stats.norm(strength[None, :, None], sigma_a[None, :, None])
    f_true = tn.pdf(amp[:, None, :]) / tn.sf(5000.0)
    f_clutter = stats.expon(loc=5000.0, scale=1 / 4e-4).pdf(amp[:, None, :])
    assert np.allclose(amp_ratio, f_true / f_clutter, rtol=1e-10)
    assert np.allclose(survive, tn.sf(5000.0)[..., 0])
    # a constant amplitude term only rescales λ: β unchanged versus JPDA with λ / c
    ratio = position_likelihood_ratio(nu, S, 0.9, 1.0)
    gated = np.ones((R, T, m), bool)
    b1, b01, _ = joint_association_probabilities(ratio * 3.7, np.full((R, T), 0.1), gated, np.zeros((R, T)))
    b2, b02, _ = joint_association_probabilities(position_likelihood_ratio(nu, S, 0.9, 1 / 3.7),
                                                 np.full((R, T), 0.1), gated, np.zeros((R, T)))
    assert np.allclose(b1, b2, atol=1e-14) and np.allclose(b01, b02, atol=1e-14)


def test_amplitude_tracking_follows_equation_9():
    s = np.array([[15000.0, 15000.0]])
    amp = np.array([[20000.0, 9000.0, 30000.0]])
    gated = np.array([[[True, True, False], [False, False, False]]])
    new = update_strength(s, amp, gated)
    assert new[0, 0] == pytest.approx(0.7 * 15000 + 0.3 * 20000)
    assert new[0, 1] == 15000.0  # empty gate: unchanged


# --------------------------------------------------------------------------- bounded cost


def test_hundreds_of_peaks_per_scan_stay_bounded_in_time_and_memory():
    rng = np.random.default_rng(7)
    R, K, T, m = 20, 40, 2, 600
    d = _design(T)
    bearing = np.deg2rad(rng.uniform(0, 180, (R, K, m)))
    scans = [ScanPeaks(bearing[:, k], rng.exponential(2500, (R, m)), np.ones((R, m), bool)) for k in range(K)]
    x0 = np.broadcast_to(np.deg2rad([[[88, 0.1], [92, -0.1]]]), (R, T, 2)).copy()
    _, P0 = two_point_start(x0[..., 0], x0[..., 0], 1.0, d.sigma_p_rad)
    tracemalloc.start()
    t0 = time.perf_counter()
    out = track_bearing_peaks(scans, x0, P0, d, STRATEGIES["jpda_a"], 0)
    elapsed = time.perf_counter() - t0
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert out["n_gated"][:, 1:].mean() > 20  # ~33 peaks in each 10° gate
    assert elapsed < 10.0, elapsed
    assert peak < 200e6, peak
    assert np.all(np.isfinite(out["state"][:, 1:]))
    assert np.allclose(out["beta0"][:, 1:] + np.nansum(np.nan_to_num(out["beta_top"][:, 1:]), -1) <= 1 + 1e-9, True)


def test_past_the_exact_cluster_limit_the_filter_flags_and_continues():
    rng = np.random.default_rng(8)
    T, K = 6, 12
    d = _design(T, max_cluster_tracks=3)
    base = np.deg2rad(90 + np.arange(T) * 0.8)
    z = [np.sort(base + np.deg2rad(1.3) * rng.standard_normal(T)) for _ in range(K)]
    x0 = np.stack([base, np.zeros(T)], -1)[None]
    _, P0 = two_point_start(base[None], base[None], 1.0, d.sigma_p_rad)
    out = track_bearing_peaks(_scans(z), x0, P0, d, STRATEGIES["jpda"], 0)
    assert np.all(out["flags"][0, 1:] & vocab.CLUSTER_SPLIT)
    assert np.all(np.isfinite(out["state"][0, 1:]))
