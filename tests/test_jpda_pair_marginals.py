"""The closed-form marginals of one- and two-track clusters (``pair_marginals``) against the
general recursion and brute-force enumeration, including the extremes the recursion's scaling
exists for; and the scan loop's fast path against the general association path."""

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from trackreplay.cores.association._jpda_fast import pair_marginals
from trackreplay.cores.association.jpda import STRATEGIES, BearingTrackerDesign, association_marginals
from trackreplay.cores.association.jpda_tracking import ScanPeaks, track_bearing_peaks
from trackreplay.cores.association.track_management import ConfirmationRule, EndingRule, TrackLife
from trackreplay.cores.filters.kalman import two_point_start


def _closed_form(ratio, miss, gated):
    """β, β₀ from ``pair_marginals`` for (B, s, m) inputs."""
    m = ratio.shape[2]
    w = np.concatenate([np.where(gated, ratio, 0.0), miss[..., None]], axis=2)
    out = pair_marginals(w)
    return out[..., :m], out[..., m]


@st.composite
def pairs(draw):
    s = draw(st.integers(1, 2))
    m = draw(st.integers(0, 7))
    B = draw(st.integers(1, 4))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    # up to 600 orders of magnitude: products of two such ratios overflow without scaling
    span = draw(st.sampled_from([4.0, 40.0, 300.0]))
    ratio = rng.exponential(1.0, (B, s, m)) * 10.0 ** rng.uniform(-span, span, (B, s, m))
    gated = rng.random((B, s, m)) < draw(st.floats(0.2, 1.0))
    miss = rng.uniform(1e-3, 1.0, (B, s)) * 10.0 ** rng.uniform(-span / 4, 0, (B, s))
    return ratio, miss, gated


@settings(max_examples=300, deadline=None)
@given(pairs())
def test_closed_form_equals_the_recursion(case):
    ratio, miss, gated = case
    beta, beta0 = _closed_form(ratio, miss, gated)
    expect, expect0 = association_marginals(np.where(gated, ratio, 0.0), miss)
    assert np.all(np.isfinite(beta)) and np.all(np.isfinite(beta0))
    assert np.max(np.abs(beta - expect), initial=0) <= 1e-12
    assert np.max(np.abs(beta0 - expect0)) <= 1e-12
    assert np.allclose(beta0 + beta.sum(-1), 1.0, rtol=0, atol=1e-12)


def test_a_dominant_peak_shared_by_both_tracks_keeps_full_precision():
    """Both tracks want peak 0 far more than anything else: ``Σ − r`` would cancel to 0."""
    ratio = np.array([[[1e300, 1.0], [1e300, 1e-3]]])
    miss = np.array([[1e-2, 1e-2]])
    beta, beta0 = _closed_form(ratio, miss, np.ones_like(ratio, bool))
    expect, expect0 = association_marginals(ratio, miss)
    assert np.allclose(beta, expect, rtol=1e-12, atol=0) and np.allclose(beta0, expect0, rtol=1e-12, atol=0)


def test_no_feasible_event_gives_no_association():
    """P_D = P_G = 1 (miss weight 0) and an empty gate: every event weighs 0, as in the recursion."""
    ratio = np.array([[[2.0, 0.0], [0.0, 0.0]], [[0.0, 0.0], [0.0, 0.0]]])
    miss = np.array([[0.0, 0.0], [0.0, 0.5]])
    beta, beta0 = _closed_form(ratio, miss, ratio > 0)
    expect, expect0 = association_marginals(ratio, miss)
    assert np.array_equal(beta, expect) and np.array_equal(beta0, expect0)
    assert np.all(beta0 == 1.0) and np.all(beta == 0.0)


def _design(T, **kw):
    base = dict(scan_period_s=1.0, gate_rad=np.deg2rad(10.0), q_rad2=0.1 * np.deg2rad(1) ** 2,
                amplitude_threshold=3000.0, detection_probability=0.9, clutter_per_gate=2.0, clutter_alpha=4e-4,
                sigma_p_rad=np.full(T, np.deg2rad(1.3)), strength=np.array([21000.0, 12000.0])[:T],
                sigma_a=np.array([2500.0, 3500.0])[:T])
    base.update(kw)
    return BearingTrackerDesign(**base)


@pytest.mark.parametrize("strategy", ["jpda", "jpda_a"])
@pytest.mark.parametrize("life", ["none", "rules"])
def test_the_two_track_fast_path_equals_the_general_association(strategy, life, monkeypatch):
    """Forcing two tracks through clustering and the recursion changes nothing beyond rounding."""
    rng = np.random.default_rng(11)
    R, K, T = 6, 40, 2
    truth = np.deg2rad(np.stack([88 + 0.05 * np.arange(K), 92 - 0.05 * np.arange(K)], 1))
    bearings, amps = [], []
    for k in range(K):
        b = np.c_[truth[k] + np.deg2rad(1.3) * rng.standard_normal((R, 2)), np.deg2rad(rng.uniform(80, 100, (R, 4)))]
        bearings.append(b)
        amps.append(np.c_[rng.normal([21000, 12000], [2500, 3500], (R, 2)), rng.exponential(2500, (R, 4)) + 3000])
    counts = rng.integers(0, 7, (R, K))
    scans = [ScanPeaks(b, a, np.arange(6)[None] < counts[:, k, None]) for k, (b, a) in enumerate(zip(bearings, amps))]
    d = _design(T)
    if life == "rules":
        d = replace(d, ending=EndingRule(field=(np.deg2rad(80), np.deg2rad(100)), margin=d.gate_rad / 2,
                                         max_coasted_scans=3), confirmation=ConfirmationRule(3, 5),
                    amplitude_tracking=True)
    x0 = np.broadcast_to(np.stack([truth[0], np.deg2rad([0.05, -0.05])], -1), (R, T, 2)).copy()
    x0[0, 1] = np.nan  # one slot never starts
    _, P0 = two_point_start(x0[..., 0], x0[..., 0], 1.0, d.sigma_p_rad)
    fast = track_bearing_peaks(scans, x0, P0, d, STRATEGIES[strategy], 0)
    import trackreplay.cores.association._jpda_fast as fast_forms
    import trackreplay.cores.association.jpda_tracking as loop

    monkeypatch.setattr(loop, "CLOSED_FORM_TRACKS", 0)
    general = fast_forms.joint_association_probabilities
    for clustering in (True, False):
        # (the general function calls itself by name in its own module: the forced choice reaches
        # that call too)
        forced = lambda r, mi, g, c, limit=12, _=None, forced=clustering: general(r, mi, g, c, limit, forced)
        monkeypatch.setattr(loop, "joint_association_probabilities", forced)
        monkeypatch.setattr(fast_forms, "joint_association_probabilities", forced)
        _same(fast, track_bearing_peaks(scans, x0, P0, d, STRATEGIES[strategy], 0))


def _same(fast, slow):
    assert fast.keys() == slow.keys()
    for key in fast:
        a, b = fast[key], slow[key]
        assert a.dtype == b.dtype and a.shape == b.shape, key
        if a.dtype.kind == "f":
            assert np.array_equal(np.isnan(a), np.isnan(b)), key
            assert np.allclose(a, b, rtol=1e-9, atol=1e-12, equal_nan=True), key
        else:
            assert np.array_equal(a, b), key


def test_a_settled_life_skips_nothing_that_matters():
    """``settled``: no rule and nothing tentative; ``step`` then ends and confirms nothing."""
    life = TrackLife((3,))
    life.start(np.array([True, True, False]), hits=2, scans=2)
    assert life.settled
    tentative, ending = life.step(np.array([False, True, False]), np.zeros(3))
    assert not tentative.any() and not ending.any() and list(life.coasting) == [1, 0, 1]
    assert not TrackLife((2,), ending=EndingRule(max_coasted_scans=2)).settled
    tentative_life = TrackLife((2,), ConfirmationRule(3, 5))
    tentative_life.start(np.array([True, False]), hits=2, scans=2)
    assert not tentative_life.settled
