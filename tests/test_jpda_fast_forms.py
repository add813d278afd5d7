"""Every fast form of the JPDA core (``cores/association/_jpda_fast.py``) against the plain form it
stands for (``cores/association/jpda.py``): the transfer-matrix recursion against the
track-by-track one, the lone-track marginals, the clustered marginals and the marginals on each
cluster's own peaks against ``association_marginals`` of all tracks on all peaks, and the top
weights sorted in blocks of scans against a sort of each scan. (The closed form of one or two
tracks is held to the recursion in tests/test_jpda_pair_marginals.py, the pair-driven JPDA to
the dense one in tests/test_multitarget_trackers.py.)"""

import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import trackreplay.cores.association.jpda as plain
from trackreplay.cores.association import _jpda_fast as fast


def _inputs(rng, B, s, m, span=4.0, density=0.6):
    """Ratios over ``2 span`` orders of magnitude (0 where not gated) and miss weights."""
    gated = rng.random((B, s, m)) < density
    ratio = np.where(gated, rng.exponential(1.0, (B, s, m)) * 10.0 ** rng.uniform(-span, span, (B, s, m)), 0.0)
    miss = rng.uniform(1e-3, 1.0, (B, s))
    return ratio, miss, gated


def _close(a, b, atol=1e-12):
    assert a.shape == b.shape
    assert np.max(np.abs(a - b), initial=0.0) <= atol


@settings(max_examples=80, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), B=st.integers(1, 5), s=st.integers(1, fast.MATRIX_FORM_TRACKS),
       m=st.integers(0, 9), span=st.sampled_from([1.0, 4.0, 40.0]))
def test_transfer_matrix_form_equals_the_track_by_track_recursion(seed, B, s, m, span):
    ratio, miss, _ = _inputs(np.random.default_rng(seed), B, s, m, span)
    beta, beta0 = fast.association_marginals_fast(ratio, miss)  # s ≤ MATRIX_FORM_TRACKS: the matrix form
    ref, ref0 = plain.association_marginals(ratio, miss)  # the track-by-track form
    _close(beta, ref)
    _close(beta0, ref0)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), B=st.integers(1, 6), m=st.integers(0, 9))
def test_lone_track_marginals_equal_the_recursion(seed, B, m):
    ratio, miss, _ = _inputs(np.random.default_rng(seed), B, 1, m)
    beta, beta0 = fast._lone_track_marginals(ratio, miss)
    ref, ref0 = plain.association_marginals(ratio, miss)
    _close(beta, ref)
    _close(beta0, ref0)


def test_lone_track_with_no_feasible_event_gives_no_association():
    ratio, miss = np.zeros((2, 1, 3)), np.zeros((2, 1))
    beta, beta0 = fast._lone_track_marginals(ratio, miss)
    ref, ref0 = plain.association_marginals(ratio, miss)
    assert np.array_equal(beta, ref) and np.array_equal(beta0, ref0)


@settings(max_examples=80, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), R=st.integers(1, 4), T=st.integers(1, 8), m=st.integers(0, 12),
       density=st.sampled_from([0.1, 0.3, 0.7]))
def test_clustered_marginals_equal_the_recursion_over_all_tracks(seed, R, T, m, density):
    """Clusters solved alone, each on its own peaks, give the β of one recursion over every track
    and every peak (the joint-event sum factorises over clusters; a peak no track of a cluster
    gates multiplies every event of it by 1)."""
    rng = np.random.default_rng(seed)
    ratio, miss, gated = _inputs(rng, R, T, m, density=density)
    split = np.zeros((R, T), bool)
    beta, beta0 = fast._clustered_marginals(ratio, miss, gated, rng.random((R, T)), 12, split)
    ref, ref0 = plain.association_marginals(ratio, miss)
    assert not split.any()
    _close(beta, ref)
    _close(beta0, ref0)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), B=st.integers(1, 4), s=st.integers(2, 7), m=st.integers(0, 12))
def test_marginals_on_a_clusters_own_peaks_equal_those_on_every_peak(seed, B, s, m):
    ratio, miss, _ = _inputs(np.random.default_rng(seed), B, s, m, density=0.25)
    beta, beta0 = fast._cluster_marginals_on_own_peaks(ratio, miss)
    ref, ref0 = plain.association_marginals(ratio, miss)
    _close(beta, ref)
    _close(beta0, ref0)


def _top_of_each_scan(betas, R, T):
    """The plain form: each scan's β sorted on its own (stable, so equal weights keep peak order)."""
    k = plain.TOP_WEIGHTS
    top, index = np.full((R, len(betas), T, k), np.nan), np.full((R, len(betas), T, k), -1)
    for i, beta in enumerate(betas):
        order = np.argsort(-beta, axis=2, kind="stable")[..., :k]
        w = np.take_along_axis(beta, order, axis=2)
        n = w.shape[2]
        top[:, i, :, :n] = np.where(w > 0, w, np.nan)
        index[:, i, :, :n] = np.where(w > 0, order, -1)
    return top, index


@pytest.mark.parametrize("budget", [1 << 22, 50])  # one block, or a block every few scans
def test_top_weights_in_blocks_equal_a_sort_of_each_scan(budget, monkeypatch):
    rng = np.random.default_rng(5)
    R, T, K = 3, 4, 30
    betas = []
    for _ in range(K):
        m = int(rng.integers(0, 7))
        beta = rng.random((R, T, m)) * (rng.random((R, T, m)) < 0.6)
        beta[..., 1:2] = beta[..., :1]  # ties
        betas.append(beta)
    monkeypatch.setattr(plain, "MEMORY_BUDGET_FLOATS", budget)
    top = fast._TopWeights(R, T)
    for beta in betas:
        top.add(beta)
    got = np.full((R, K, T, plain.TOP_WEIGHTS), np.nan), np.full((R, K, T, plain.TOP_WEIGHTS), -1)
    top.store(*got)
    want = _top_of_each_scan(betas, R, T)
    assert np.array_equal(got[0], want[0], equal_nan=True)
    assert np.array_equal(got[1], want[1])


@pytest.mark.parametrize("first", ["jpda", "_jpda_fast", "jpda_tracking"])
def test_either_module_may_be_imported_first(first):
    """The imports run one way (the loop imports the fast forms, the fast forms the plain ones,
    the plain ones neither): importing any of them first works, and the plain module alone
    loads none of the others."""
    code = (f"import sys, trackreplay.cores.association.{first}; "
            f"assert ('{first}' != 'jpda' or not any(n.endswith(('_jpda_fast', 'jpda_tracking')) for n in sys.modules)); "
            "from trackreplay.cores.association import jpda, _jpda_fast; "
            "import numpy as np; "
            "b, b0 = _jpda_fast._cluster_marginals_on_own_peaks(np.ones((1, 2, 3)), np.ones((1, 2))); "
            "assert abs(b0.sum() + b.sum() - 2) < 1e-12")
    subprocess.run([sys.executable, "-c", code], check=True)
