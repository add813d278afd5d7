"""The fast forms of the JPDA core (:mod:`trackreplay.cores.association.jpda`), each the same
numbers as the plain form it stands for, for fewer array operations.

:mod:`~trackreplay.cores.association.jpda` keeps the forms a reader holds against the papers
(Fortmann, Bar-Shalom & Scheffe 1983; Park, Ryu & Lee 1994, eqs. A.1–A.7;
``docs/papers/xcorr.md``): the exact marginals of eq. A.6 by the recursion over track
sets (:func:`~trackreplay.cores.association.jpda.association_marginals`), the clusters
(:func:`~trackreplay.cores.association.jpda.cluster_tracks`) and the PDA update of eq. A.7. This
module imports that one, never the other way; the filter's scan loop
(:func:`trackreplay.cores.association.jpda_tracking.track_bearing_peaks`) calls the forms here.
Each with the test that holds it to its plain form:

* :func:`association_marginals_fast`, :func:`_transfer_matrix_recursion`: association_marginals'
  recursion as one matrix product per peak, for clusters of up to ``MATRIX_FORM_TRACKS`` tracks
  (tests/test_jpda_fast_forms.py);
* :func:`joint_association_probabilities`: the β of every run, per cluster of tracks sharing
  peaks or in one recursion over all tracks, whichever costs less, clusters larger than
  ``max_cluster_tracks`` cut (tests/test_multitarget_trackers.py against association_marginals,
  tests/test_jpda_association.py against enumeration);
* :func:`pair_marginals`: association_marginals of one or two tracks in closed form
  (tests/test_jpda_pair_marginals.py);
* :func:`_lone_track_marginals`: association_marginals of one track (tests/test_jpda_fast_forms.py);
* :func:`_clustered_marginals`, :func:`_cluster_marginals_on_own_peaks`: association_marginals of
  all of a run's tracks at once, solved per cluster of tracks sharing peaks, each on its own peaks
  (tests/test_jpda_association.py against enumeration, tests/test_jpda_fast_forms.py);
* :func:`pair_association_probabilities`: joint_association_probabilities from the gated
  track–peak pairs alone (tests/test_multitarget_trackers.py);
* :class:`_TopWeights`: the largest β of each track and scan, sorted in blocks of scans rather
  than scan by scan (tests/test_jpda_fast_forms.py).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

# the plain forms these stand for (this module imports that one, never the other way)
from trackreplay.cores.association import jpda as _plain

MATRIX_FORM_TRACKS = 6  # clusters up to this size use the transfer-matrix form (≤ 64×64)
JOINT_WITHOUT_CLUSTERING = 4  # up to this many tracks the joint recursion beats clustering bookkeeping
COMPRESS_PEAKS = 8  # with more peaks per scan, drop the ones outside every gate first


def association_marginals_fast(ratio: np.ndarray, miss: np.ndarray):
    """:func:`~trackreplay.cores.association.jpda.association_marginals`, clusters of up to
    ``MATRIX_FORM_TRACKS`` tracks by :func:`_transfer_matrix_recursion` (one batched matrix
    product per peak, the same β to rounding, tests/test_jpda_fast_forms.py), larger ones by the
    plain function itself."""
    B, s, m = ratio.shape
    if B == 0 or s == 0 or s > MATRIX_FORM_TRACKS:
        return _plain.association_marginals(ratio, miss)
    n_states = 1 << s
    chunk = max(1, _plain.MEMORY_BUDGET_FLOATS // ((m + 1) * n_states * n_states))
    if B > chunk:
        beta, beta0 = np.zeros((B, s, m)), np.ones((B, s))
        for lo in range(0, B, chunk):
            beta[lo:lo + chunk], beta0[lo:lo + chunk] = association_marginals_fast(ratio[lo:lo + chunk],
                                                                                   miss[lo:lo + chunk])
        return beta, beta0
    r, F, back, end, bits = _plain._recursion_tables(ratio, miss)
    return _plain._normalised(_transfer_matrix_recursion(r, F, back), F, back, end, bits)


def _transfer_matrix_recursion(r, F, back):
    """The forward–backward recursion of
    :func:`~trackreplay.cores.association.jpda.association_marginals` in matrix form, for small
    clusters: peak j is the transfer matrix ``M_j = I + Σ_t r[t, j] E_t`` over the 2^s track sets
    (``E_t`` adds track t), ``F_j = F_{j−1} M_j`` and ``B_{j−1} = M_j B_j``, one batched product
    per peak.

    Parameters
    ----------
    r : ndarray (B, s, m)
        Scaled likelihood ratios.
    F, back : ndarray (m + 1, B, 2^s)
        The forward and backward tables, with ``F[0]`` and ``back[m]`` set; filled here.

    Returns
    -------
    ndarray (B, s, m)
        The unnormalised ``β[t, j] = r[t, j] Σ_{A ∌ t} F_{j−1}(A) B_j(A ∪ {t})``.
    """
    B, s, m = r.shape
    n_states = 1 << s
    E = _adders(s)  # (s, states, states)
    M = np.einsum("btj,tik->jbik", r, E)
    M += np.eye(n_states)
    # forward rows F_j = F_{j−1} M_j and backward rows B_{j−1}ᵀ = B_jᵀ M_jᵀ in one product per step
    both = np.concatenate([M, np.swapaxes(M[::-1], -1, -2)], axis=1)  # (m, 2B, n, n)
    rows = np.concatenate([F[0], back[m]])[:, None, :]
    for j in range(m):
        rows = np.matmul(rows, both[j])
        F[j + 1], back[m - 1 - j] = rows[:B, 0], rows[B:, 0]
    added = np.einsum("tik,jbk->jbti", E, back[1:])  # B_j(A ∪ {t}) for A ∌ t, else 0
    return r * np.einsum("jbi,jbti->btj", F[:m], added)


@lru_cache(maxsize=None)
def _adders(s: int) -> np.ndarray:
    """``E[t, A, A ∪ {t}] = 1`` for every track set A without t."""
    n = 1 << s
    E = np.zeros((s, n, n))
    for t in range(s):
        A = np.flatnonzero(~_plain._state_bits(s)[:, t])
        E[t, A, A | (1 << t)] = 1.0
    return E


def pair_marginals(weights: np.ndarray) -> np.ndarray:
    """Exact JPDA marginals (eq. A.6) of clusters of one or two tracks, in closed form.

    With two tracks a joint event has both tracks missed, one on peak j and the other missed,
    or the two on different peaks i ≠ j. Summing the other track's options for each choice of
    track 1 gives ``β_j^1 ∝ r_1j (m_2 + Σ_{k≠j} r_2k)`` and ``β_0^1 ∝ m_1 (m_2 + Σ_k r_2k)``
    (likewise for track 2), and the normaliser is the sum of track 1's numerators, which counts
    every event once. Only sums and products of non-negative terms appear: the leave-one-out
    sums come from one product with a 0/1 matrix rather than from ``Σ − r``, so a dominant
    peak shared by both tracks costs no precision. One track's event weights are its own row.
    The result equals :func:`~trackreplay.cores.association.jpda.association_marginals` for a few array operations, whatever the
    number of peaks (Fortmann, Bar-Shalom & Scheffe 1983; ``docs/papers/xcorr.md``).

    Parameters
    ----------
    weights : ndarray (B, s, m + 1), s = 1 or 2
        Per track the likelihood ratios of the m peaks (0 where not gated) and, last, the
        miss weight ``1 − P_D P_G``. Overwritten (scaled).

    Returns
    -------
    ndarray (B, s, m + 1)
        ``β_j^t`` in the first m columns, ``β_0^t`` last. A batch element whose events all
        weigh 0 gets β = 0 and β₀ = 1, as in :func:`~trackreplay.cores.association.jpda.association_marginals`.
    """
    B, s, n = weights.shape
    # Scaling a track's row scales every event alike, so β is unchanged; with every factor
    # ≤ 1 no product overflows. The tiny floor keeps an all-zero row at zero instead of 0/0.
    weights /= np.maximum.reduce(weights, axis=2, keepdims=True, initial=_TINY)
    if s == 1:
        num = weights
    else:
        num = weights * (weights @ _others(n))[:, ::-1]
    Z = num[:, 0].sum(axis=1)
    if not (Z > 0).all():
        ok = Z > 0
        num = np.where(ok[:, None, None], num / np.where(ok, Z, 1.0)[:, None, None], 0.0)
        num[..., -1] = np.where(ok[:, None], num[..., -1], 1.0)
        return num
    num /= Z[:, None, None]
    return num


_TINY = 1e-300


@lru_cache(maxsize=None)
def _others(n: int) -> np.ndarray:
    """``(n, n)`` 0/1 matrix: column j < n − 1 sums every entry but j (the other track's
    options when this track takes peak j), the last column sums all (this track missed)."""
    J = 1.0 - np.eye(n)
    J[-1, -1] = 1.0
    return J


def _lone_track_marginals(ratio, miss):
    """:func:`~trackreplay.cores.association.jpda.association_marginals` of clusters of one track ``(B, 1, m)``, without the
    recursion: ``β_j = r_j / (miss + Σ r)``, ``β₀ = miss / (miss + Σ r)``."""
    Z = miss + ratio.sum(axis=-1)
    ok = Z > 0
    Zs = np.where(ok, Z, 1.0)
    return np.where(ok[..., None], ratio / Zs[..., None], 0.0), np.where(ok, miss / Zs, 1.0)


def _cut_clusters(cluster, max_cluster_tracks: int):
    """Groups of at most ``max_cluster_tracks`` tracks from tracks sorted by ``cluster`` (and,
    within one, in the order a cut follows): ``too_big`` marks the tracks of a cluster that had
    to be cut, ``new_group`` the first track of every group."""
    new_cluster = np.r_[True, cluster[1:] != cluster[:-1]]
    cluster_start = np.flatnonzero(new_cluster)
    cluster_id = np.cumsum(new_cluster) - 1
    cluster_size = np.diff(np.r_[cluster_start, cluster.size])
    rank = np.arange(cluster.size) - cluster_start[cluster_id]
    too_big = cluster_size[cluster_id] > max_cluster_tracks
    return too_big, new_cluster | (too_big & (rank % max_cluster_tracks == 0))


def _clustered_marginals(r, miss, gated, predicted_bearing, max_cluster_tracks, split):
    """Cluster per run, cut clusters larger than the limit, batch equal sizes across runs."""
    R, T, m = r.shape
    labels = _plain.cluster_tracks(gated) if T > 1 else np.zeros((R, 1), np.int64)
    key = (labels + T * np.arange(R)[:, None]).ravel()
    order = np.lexsort((predicted_bearing.ravel(), key))
    too_big, new_group = _cut_clusters(key[order], max_cluster_tracks)
    split.ravel()[order[too_big]] = True
    group_start = np.flatnonzero(new_group)
    group_size = np.diff(np.r_[group_start, key.size])
    beta = np.zeros((R, T, m))
    beta0 = np.ones((R, T))
    for s in np.unique(group_size):
        first = group_start[group_size == s]
        flat = order[first[:, None] + np.arange(s)]  # (batch, s) flat (run, track) indices
        run, trk = np.divmod(flat, T)
        if s == 1:
            bb, b0 = _lone_track_marginals(r[run, trk], miss[run, trk])
        else:
            bb, b0 = _cluster_marginals_on_own_peaks(r[run, trk], miss[run, trk])
        beta[run, trk] = bb
        beta0[run, trk] = b0
    return beta, beta0


def _cluster_marginals_on_own_peaks(r, miss):
    """:func:`~trackreplay.cores.association.jpda.association_marginals` of a batch of clusters ``r`` (B, s, m), each solved on the
    peaks its own tracks gate: a peak no track of a cluster gates has ratio 0 for all of them and
    multiplies every joint event by 1, so dropping it leaves β exact, and the recursion's cost,
    linear in the peaks, falls from a scan's to a cluster's (hundreds of clutter plots a scan)."""
    own = (r > 0).any(axis=1)                                               # (B, m)
    width = int(own.sum(axis=1).max(initial=0))
    if width == r.shape[2]:
        return association_marginals_fast(r, miss)
    cols = np.argsort(~own, axis=1, kind="stable")[:, :width]              # each cluster's peaks first
    b, b0 = association_marginals_fast(np.take_along_axis(r, cols[:, None, :], axis=2), miss)
    beta = np.zeros(r.shape)
    np.put_along_axis(beta, np.broadcast_to(cols[:, None, :], b.shape), b, axis=2)
    return beta, b0


def joint_association_probabilities(ratio: np.ndarray, miss: np.ndarray, gated: np.ndarray,
                                    predicted_bearing: np.ndarray, max_cluster_tracks: int = 12,
                                    clustering: bool | None = None):
    """β for every run: cluster, batch clusters by size, run the exact recursion.

    The joint-event sum factorises over clusters, so solving each cluster alone is exact.
    With few tracks (≤ ``JOINT_WITHOUT_CLUSTERING``) one recursion over all of them costs less
    than the clustering bookkeeping and gives the same β (``clustering=None`` picks that
    automatically; tests compare both paths).

    Parameters
    ----------
    ratio : ndarray (R, T, m)
        Likelihood ratios (any value where not gated; masked here).
    miss : ndarray (R, T)
    gated : ndarray of bool (R, T, m)
    predicted_bearing : ndarray (R, T)
        Orders the tracks of a cluster that has to be cut.
    max_cluster_tracks : int
        Largest cluster solved exactly as a whole.
    clustering : bool, optional
        Force (True) or skip (False) clustering; default: automatic.

    Returns
    -------
    beta : ndarray (R, T, m)
    beta0 : ndarray (R, T)
    split : ndarray of bool (R, T)
        Tracks whose cluster was cut (their β are approximate).
    """
    R, T, m = ratio.shape
    split = np.zeros((R, T), bool)
    if R == 0 or T == 0:
        return np.zeros((R, T, m)), np.ones((R, T)), split
    r = np.where(gated, ratio, 0.0)
    cols = None
    somewhere = gated.any(axis=(0, 1))
    if not somewhere.all():  # peaks outside every gate of every run are clutter for sure
        full = np.zeros((R, T, m))
        b, b0, split = joint_association_probabilities(ratio[..., somewhere], miss, gated[..., somewhere],
                                                       predicted_bearing, max_cluster_tracks, clustering)
        full[..., somewhere] = b
        return full, b0, split
    g = gated
    if m > COMPRESS_PEAKS:
        # Only peaks inside some gate matter: move them to the front and drop the rest, so
        # hundreds of peaks in a scan cost what the few gated ones cost.
        any_gate = gated.any(axis=1)
        width = int(any_gate.sum(axis=1).max())
        if width < m:  # (with every peak in some gate of every run there is nothing to drop)
            cols = np.argsort(~any_gate, axis=1, kind="stable")[:, :width]
            g = np.take_along_axis(gated, cols[:, None, :], axis=2)
            r = np.take_along_axis(r, cols[:, None, :], axis=2)
    if clustering is None:
        clustering = T > min(JOINT_WITHOUT_CLUSTERING, max_cluster_tracks)
    if not clustering and T <= max_cluster_tracks:
        b_c, beta0 = association_marginals_fast(r, miss)
    else:
        b_c, beta0 = _clustered_marginals(r, miss, g, predicted_bearing, max_cluster_tracks, split)
    if cols is None:
        return b_c, beta0, split
    beta = np.zeros((R, T, m))
    np.put_along_axis(beta, np.broadcast_to(cols[:, None, :], b_c.shape), b_c, axis=2)
    return beta, beta0, split


def pair_association_probabilities(ratio, track, peak, miss, predicted_bearing, max_cluster_tracks: int = 12):
    """:func:`~trackreplay.cores.association.jpda.joint_association_probabilities` from the gated track–peak pairs alone.

    Many tracks, peaks and runs make the dense ``(R, T, m)`` layout mostly empty: each track
    gates a few of a scan's peaks. Here only the gated pairs are given; tracks and peaks carry
    global indices (fold a run axis in: ``run · T + track``). Clusters are the connected
    components of the tracks-share-a-peak graph (:func:`scipy.sparse.csgraph.connected_components`),
    cut as :func:`~trackreplay.cores.association.jpda.joint_association_probabilities` cuts them (in ``predicted_bearing`` order, at
    most ``max_cluster_tracks`` tracks a group, flagged), and each group is solved by the same
    recursion (:func:`~trackreplay.cores.association.jpda.association_marginals`) on its own peaks, all groups of one size in one
    batch. tests/test_multitarget_trackers.py holds the two equal.

    Parameters
    ----------
    ratio : ndarray (E,)
        Likelihood ratio of each gated pair.
    track, peak : ndarray of int (E,)
        The pair's track (0 … N − 1) and peak (any non-negative integers).
    miss : ndarray (N,)
    predicted_bearing : ndarray (N,)
        Orders the tracks of a cluster that has to be cut.
    max_cluster_tracks : int

    Returns
    -------
    beta : ndarray (E,)
        β of each pair.
    beta0 : ndarray (N,)
    split : ndarray of bool (N,)
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    N = miss.shape[0]
    beta, beta0, split = np.zeros(ratio.shape), np.ones(N), np.zeros(N, bool)
    if ratio.size == 0:
        return beta, beta0, split
    peaks, peak_local = np.unique(peak, return_inverse=True)
    peak_local = peak_local.ravel()
    # tracks are nodes 0 … N − 1, peaks N … N + M − 1; an edge per gated pair
    M = peaks.size
    graph = coo_matrix((np.ones(ratio.size), (track, N + peak_local)), shape=(N + M, N + M))
    _, label = connected_components(graph, directed=False)
    tracks = np.unique(track)
    # order the tracks of each cluster as the dense form does: by predicted bearing, then index
    order = tracks[np.lexsort((tracks, predicted_bearing[tracks], label[tracks]))]
    too_big, new_group = _cut_clusters(label[order], max_cluster_tracks)
    split[order[too_big]] = True
    group_start = np.flatnonzero(new_group)
    group_size = np.diff(np.r_[group_start, order.size])
    group_of = np.empty(N, np.int64)
    group_of[order] = np.cumsum(new_group) - 1
    slot_in_group = np.empty(N, np.int64)
    slot_in_group[order] = np.arange(order.size) - group_start[group_of[order]]
    # each group's own peaks, in peak order, numbered from 0
    g = group_of[track]
    by = np.lexsort((peak_local, g))
    first_of_peak = np.r_[True, (g[by][1:] != g[by][:-1]) | (peak_local[by][1:] != peak_local[by][:-1])]
    peak_number = np.cumsum(first_of_peak) - 1
    group_first_peak = np.zeros(group_start.size, np.int64)
    starts = np.r_[True, g[by][1:] != g[by][:-1]]
    group_first_peak[g[by][starts]] = peak_number[starts]
    column = np.empty(ratio.size, np.int64)
    column[by] = peak_number - group_first_peak[g[by]]
    width = np.zeros(group_start.size, np.int64)
    np.maximum.at(width, g, column + 1)
    for s in np.unique(group_size):
        groups = np.flatnonzero(group_size == s)
        index = np.full(group_start.size, -1, np.int64)
        index[groups] = np.arange(groups.size)
        w = int(width[groups].max())
        mine = index[g] >= 0
        r = np.zeros((groups.size, s, w))
        r[index[g[mine]], slot_in_group[track[mine]], column[mine]] = ratio[mine]
        members = order[group_start[groups][:, None] + np.arange(s)]      # (batch, s) tracks
        mm = miss[members]
        bb, b0 = _lone_track_marginals(r, mm) if s == 1 else association_marginals_fast(r, mm)
        beta[mine] = bb[index[g[mine]], slot_in_group[track[mine]], column[mine]]
        beta0[members] = b0
    return beta, beta0, split


class _TopWeights:
    """The ``TOP_WEIGHTS`` largest β of each track and scan and their peak indices.

    Only the outputs need them, so the per-scan β are kept and sorted in blocks of many scans
    (one sort per block instead of one per scan); a block is laid out padded to its widest scan
    and sorted once it would exceed ``MEMORY_BUDGET_FLOATS``.
    """

    def __init__(self, R: int, T: int):
        self.R, self.T = R, T
        self.pending, self.width, self.done = [], 0, []

    def add(self, beta: np.ndarray) -> None:
        self.pending.append(beta)
        self.width = max(self.width, beta.shape[2])
        if len(self.pending) * self.R * self.T * self.width > _plain.MEMORY_BUDGET_FLOATS:
            self._sort()

    def _sort(self) -> None:
        n, width = len(self.pending), self.width
        block = np.zeros((n, self.R, self.T, max(width, 1)))
        for j, beta in enumerate(self.pending):
            block[j, ..., :beta.shape[2]] = beta
        # stable: equal weights keep peak order; padding (0) sorts after every positive weight
        index = np.argsort(-block, axis=3, kind="stable")[..., :_plain.TOP_WEIGHTS]
        w = np.take_along_axis(block, index, axis=3)
        # with fewer than TOP_WEIGHTS peaks in every scan of the block the last columns stay empty
        index, w = index[..., :min(width, _plain.TOP_WEIGHTS)], w[..., :min(width, _plain.TOP_WEIGHTS)]
        self.done.append((np.where(w > 0, w, np.nan), np.where(w > 0, index, -1)))
        self.pending, self.width = [], 0

    def store(self, top: np.ndarray, index: np.ndarray) -> None:
        """Write into ``(R, scans, T, TOP_WEIGHTS)`` views of the outputs (NaN / −1 beyond)."""
        if self.pending:
            self._sort()
        lo = 0
        for w, ix in self.done:
            hi = lo + w.shape[0]
            top[:, lo:hi, :, :w.shape[3]] = w.swapaxes(0, 1)
            index[:, lo:hi, :, :w.shape[3]] = ix.swapaxes(0, 1)
            lo = hi

