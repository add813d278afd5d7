"""The array front end's fast paths give the numbers of the plain definitions they replace.

PAST over many scans in one pass (:func:`past_scans`) against the textbook recursion of Yang
(1995) run one snapshot at a time; the largest principal angle against the SVD definition of
:func:`principal_angles` (small, medium and near-90° angles); and the front end of Ryu, Lee &
Lee (2001)'s trackers (shared start-up EVD, PAST blocks, batch EVD and subspace error in
blocks) against the same steps written out per scan, for any block size and for groups
of runs that are not consecutive.
"""

import numpy as np
import pytest

from trackreplay.cores.array.linear_array import steering_vectors
from trackreplay.cores.array.music import eigen_decomposition, sample_covariance
from trackreplay.cores.array.past_subspace import (
    batch_signal_subspace,
    initial_state,
    largest_principal_angle,
    past_scans,
    past_update,
    principal_angles,
)
from trackreplay.trackers import array as ab

M = 8


def scene(rng, runs, scans, n_snapshots, theta=(-0.4, 0.1, 0.5), snr_db=10.0):
    A = steering_vectors(np.asarray(theta), M, 0.5)
    N = A.shape[-1]
    shape = (runs, scans)
    S = rng.standard_normal(shape + (N, n_snapshots)) + 1j * rng.standard_normal(shape + (N, n_snapshots))
    noise = rng.standard_normal(shape + (M, n_snapshots)) + 1j * rng.standard_normal(shape + (M, n_snapshots))
    return (A @ S) * np.sqrt(0.5 * 10 ** (snr_db / 10)) + np.sqrt(0.5) * noise


def textbook_past(W, P, X, beta):
    """Yang (1995)'s recursion, one run and one snapshot at a time, as the module docstring writes it."""
    W, P = W.copy(), P.copy()
    for x in X.T:
        y = np.conj(W.T) @ x
        h = P @ y
        g = h / (beta + np.real(np.vdot(y, h)))
        P = (P - np.outer(g, np.conj(h))) / beta
        P = 0.5 * (P + np.conj(P.T))
        e = x - W @ y
        W = W + np.outer(e, np.conj(g))
    return W, P


def test_past_over_scans_is_the_recursion_snapshot_by_snapshot():
    rng = np.random.default_rng(0)
    X = scene(rng, 3, 4, 6)
    basis, values = batch_signal_subspace(X[:, 0], 3)
    W0, P0 = initial_state(basis, values, 0.97)
    Ws, P = past_scans(W0, P0, X.astype(np.complex64), 0.97)  # single precision in: converted scan by scan
    X64 = X.astype(np.complex64).astype(complex)
    for r in range(3):
        W, Pr = W0[r], P0[r]
        for k in range(4):
            W, Pr = textbook_past(W, Pr, X64[r, k], 0.97)
            np.testing.assert_allclose(Ws[r, k], W, rtol=0, atol=1e-12)
        np.testing.assert_allclose(P[r], Pr, rtol=1e-12, atol=0)
    # one scan at a time through past_update: the same bits as the many-scan pass
    W, Pk = W0, P0
    for k in range(4):
        W, Pk = past_update(W, Pk, X64[:, k], 0.97)
        np.testing.assert_array_equal(W, Ws[:, k])
    np.testing.assert_array_equal(Pk, P)


@pytest.mark.parametrize("angle", [1e-7, 1e-3, 0.3, 0.785, 0.8, 1.2, 1.5707])
def test_largest_principal_angle_is_the_last_principal_angle(angle):
    rng = np.random.default_rng(1)
    e = np.eye(6, dtype=complex)
    rotated = np.stack([e[:, 0], np.cos(0.1) * e[:, 1] + np.sin(0.1) * e[:, 3],
                        np.cos(angle) * e[:, 2] + np.sin(angle) * e[:, 4]], axis=1)
    Q = np.linalg.qr(rng.standard_normal((6, 6)) + 1j * rng.standard_normal((6, 6)))[0]
    A, B = Q @ e[:, :3] * (2 - 1j), Q @ rotated  # A not orthonormal, B orthonormal
    expected = principal_angles(A, B)[-1]
    assert np.isclose(expected, max(angle, 0.1), rtol=1e-9)
    for b_orthonormal in (False, True):
        got = largest_principal_angle(A, B, b_orthonormal=b_orthonormal)
        assert np.ndim(got) == 0 and np.isclose(got, expected, rtol=1e-9, atol=0)


def test_largest_principal_angle_batched_matches_the_svd_definition():
    rng = np.random.default_rng(2)
    A = rng.standard_normal((4, 5, 7, 3)) + 1j * rng.standard_normal((4, 5, 7, 3))
    scale = np.logspace(-6, 1, 20).reshape(4, 5, 1, 1)  # from nearly equal spans to unrelated ones
    B = A + scale * (rng.standard_normal((4, 5, 7, 3)) + 1j * rng.standard_normal((4, 5, 7, 3)))
    expected = principal_angles(A, B)[..., -1]
    assert (expected > np.pi / 4).any() and (expected < np.pi / 4).any()  # both branches
    np.testing.assert_allclose(largest_principal_angle(A, B), expected, rtol=1e-12)


def reference_front_end(X, design):
    """Steps 1–2 written out per scan: start-up, then per run group a batch EVD and PAST per scan."""
    head = X[:, :2].astype(complex)
    init = ab.start_up(head, design)
    B, K = X.shape[:2]
    sub_err = np.full((B, K), np.nan)
    groups = {}
    for n in np.unique(init.n_tracks):
        if n == 0:
            continue
        sel = np.flatnonzero(init.n_tracks == n)
        Xs = X[sel].astype(complex)
        batch, values = batch_signal_subspace(Xs, int(n))
        past = np.empty_like(batch)
        past[:, 0], P = initial_state(batch[:, 0], values[:, 0], design.forgetting)
        for k in range(1, K):
            past[:, k], P = past_update(past[:, k - 1], P, Xs[:, k], design.forgetting)
        sub_err[sel] = principal_angles(past, batch)[..., -1]
        groups[int(n)] = (sel, past, batch)
    return init, groups, sub_err


@pytest.mark.parametrize("subspace", ["past", "batch"])
def test_the_front_end_is_its_steps_per_scan_for_any_block_size(monkeypatch, subspace):
    rng = np.random.default_rng(3)
    X = scene(rng, 7, 5, 12)
    X[[1, 4]] = scene(rng, 2, 5, 12, theta=(-0.2, 0.3))  # runs 1 and 4: two sources, not consecutive
    X = X.astype(np.complex64)
    X.flags.writeable = False
    design = ab.SubspaceTrackerDesign(subspace=subspace, grid_step_rad=np.deg2rad(0.5))
    init, groups, sub_err = reference_front_end(X, design)
    assert 2 in groups and len(groups) >= 2  # two groups, one of them not consecutive runs
    for past_block, evd_block in ((256, 64), (3, 2), (1, 1)):
        monkeypatch.setattr(ab, "PAST_BLOCK_RUNS", past_block)
        monkeypatch.setattr(ab, "FRONT_END_BLOCK_RUNS", evd_block)
        fe = ab.front_end(X, design)
        np.testing.assert_array_equal(fe.start.n_tracks, init.n_tracks)
        np.testing.assert_array_equal(fe.start.theta_0, init.theta_0)
        np.testing.assert_array_equal(fe.start.theta_minus1, init.theta_minus1)
        np.testing.assert_allclose(fe.subspace_error[:, 1:], sub_err[:, 1:], rtol=1e-9)
        np.testing.assert_allclose(fe.subspace_error[:, 0], 0.0, atol=1e-12)  # PAST starts on scan 0's EVD
        for sel, n, subspaces in fe.groups:
            ref_sel, past, batch = groups[n]
            np.testing.assert_array_equal(sel, ref_sel)
            np.testing.assert_array_equal(subspaces, past if subspace == "past" else batch)


def test_a_failure_in_the_batch_evd_reaches_the_caller(monkeypatch):
    rng = np.random.default_rng(4)
    X = scene(rng, 2, 4, 12)

    def broken(*args, **kwargs):
        raise np.linalg.LinAlgError("no convergence")

    monkeypatch.setattr(ab, "batch_signal_subspace", broken)
    for subspace in ("past", "batch"):
        design = ab.SubspaceTrackerDesign(grid_step_rad=np.deg2rad(0.5), subspace=subspace)
        with pytest.raises(np.linalg.LinAlgError, match="no convergence"):
            ab.front_end(X, design)


def test_the_start_up_reuses_the_evd_it_is_given():
    rng = np.random.default_rng(5)
    head = scene(rng, 3, 2, 12)
    design = ab.SubspaceTrackerDesign(grid_step_rad=np.deg2rad(0.5))
    evd = eigen_decomposition(sample_covariance(head))
    a, b = ab.start_up(head, design), ab.start_up(head, design, evd)
    for key in ("n_tracks", "theta_minus1", "theta_0", "source_counts"):
        np.testing.assert_array_equal(getattr(a, key), getattr(b, key))


def test_the_memo_keeps_no_snapshots_alive_and_another_data_set_replaces_it():
    """The memo holds no reference to the snapshots, so it dies with them; a
    second data set then replaces the memo (in a thread with a deadline: a lock held while the
    first array's weak-reference callback runs would hang)."""
    import gc
    import threading
    import weakref

    rng = np.random.default_rng(6)
    design = ab.SubspaceTrackerDesign(grid_step_rad=np.deg2rad(0.5))
    first = scene(rng, 3, 5, 12).astype(np.complex64)
    first.flags.writeable = False
    ab.track_bearings(first, design, "proposed")
    gone = weakref.ref(first)
    del first
    gc.collect()
    assert gone() is None
    for _ in range(2):  # each replaces the memo of the one before, whose array is then freed
        X = scene(rng, 3, 5, 12).astype(np.complex64)
        X.flags.writeable = False
        worker = threading.Thread(target=ab.track_bearings, args=(X, design, "ryu"), daemon=True)
        worker.start()
        worker.join(timeout=60)
        assert not worker.is_alive()
        del X
