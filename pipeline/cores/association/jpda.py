"""JPDA and amplitude-aided JPDA_A for bearing tracks of cross-correlation peaks.

Park, Ryu & Lee (1994), appendix eqs. A.1–A.7, with the JPDA of Fortmann, Bar-Shalom & Scheffe
(1983); see ``docs/papers/xcorr.md``. The trackers that call this core are in
:mod:`trackreplay.trackers.xcorr`. One core, batched over a leading Monte Carlo run axis:

* motion: state ``[θ, θ̇]`` (rad, rad/s), continuous white-noise acceleration
  ``Q' = q [[T³/3, T²/2], [T²/2, T]]`` (eq. 8b), two-point start ``P(0|0) = [[σ², σ²/T],
  [σ²/T, 2σ²/T²]]`` (eq. 8c with T = 1); the model from :mod:`trackreplay.cores.filters.kalman`,
  predict and gain written out for this two-state, one-measurement case (one run costs the
  number of array operations per scan, not their arithmetic);
* gating: a window of width V (``|ν| ≤ V/2``) around each predicted bearing, after the
  amplitude threshold; ``P_G = erf(V / (2√(2S)))``;
* event likelihoods (eq. A.5) as per-pair *likelihood ratios* against clutter: a peak j
  assigned to track t contributes ``r_tj = P_D N(ν_tj; 0, S_t) / λ`` times, for JPDA_A, the
  pluggable amplitude term ``N(z_a; ẑ_a, σ_a²) / (α e^{−α z_a})`` (both densities conditioned
  on ``z_a ≥`` threshold); a missed track contributes ``1 − P_D P_G``; clutter peaks contribute
  1 (their ``λ V⁻¹ α e^{−α z_a}`` factor is common to all events and cancels);
* exact marginals β_j^t (eq. A.6) without enumerating joint events: a forward–backward
  recursion over the peaks whose state is the *set of tracks already assigned* (an
  EHM-style net, transposed: nodes keyed by used tracks instead of used measurements). Cost
  O(m · s · 2^s) for s tracks and m peaks of a cluster, i.e. linear in the number of peaks;
  the number of joint events it sums is exponential in both;
* track clustering: tracks sharing a gated peak, transitively, form a cluster; clusters are
  solved independently (exact, since the joint-event sum factorises over clusters) and all
  clusters of the same size across runs go through one batched recursion; with at most
  ``JOINT_WITHOUT_CLUSTERING`` tracks one recursion over all of them gives the same β for less
  bookkeeping, and peaks outside every gate are dropped first; one or two tracks need neither
  (:func:`pair_marginals`: the same marginals in closed form, a few array operations per scan);
* clusters of more than ``max_cluster_tracks`` tracks (default 12, i.e. 4096 states per peak)
  are cut, in bearing order, into groups of at most that many tracks, each solved exactly but
  blind to the others (a peak may then be shared across a cut): approximate, and flagged with
  ``CLUSTER_SPLIT`` (:data:`trackreplay.vocabulary.FLAGS`). Peaks cost linear time and the recursion is run in batches of
  bounded memory, so hundreds of peaks per scan stay cheap;
* PDA update per track (eq. A.7): combined innovation, covariance with the spread term;
* optional amplitude tracking (eq. 9): ``ẑ_a(k) = 0.7 ẑ_a(k−1) + 0.3 max_j z_a`` over the
  peaks in the track's gate (unchanged when the gate is empty).

This module holds the plain forms, the ones to hold against the papers; the fast forms they
choose between (the closed form of one or two tracks, the clustering, the transfer-matrix
recursion, the pair-driven JPDA of many tracks, the outputs' top weights) live in
:mod:`trackreplay.cores.association._jpda_fast`, each tested equal to the plain one. Its
length (about 640 lines) is the filter's scan loop, :func:`track_bearing_peaks`, written out
for the two-state bearing filter in one function, so that a reader follows a scan from
prediction to output without leaving it.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.special import erf, ndtr

from trackreplay import vocabulary as vocab
from trackreplay.cores.filters.kalman import continuous_white_noise_model
from trackreplay.cores.association.track_management import ConfirmationRule, EndingRule, TrackLife
# the fast forms, each tested equal to the plain one it stands for (see the module docstring);
# pair_marginals and pair_association_probabilities are public names of this module as well
from trackreplay.cores.association._jpda_fast import (  # noqa: F401
    _clustered_marginals,
    _TopWeights,
    _transfer_matrix_recursion,
    pair_association_probabilities,
    pair_marginals,
)

# Flag bits of the one table (trackreplay.vocabulary.FLAGS), as this core uses them:
FLAG_NO_TRACK = vocab.NO_TRACK            # before the track start scan: no state yet
FLAG_INITIALISING = vocab.INITIALISING    # up to and including the start scan: start values, not filtered
FLAG_COASTED = vocab.COASTED              # no peak in the gate: the state is the prediction
FLAG_DELETED = vocab.DELETED              # the track ended at this scan (track_management); NO_TRACK after
FLAG_CLUSTER_SPLIT = vocab.CLUSTER_SPLIT  # the track's cluster exceeded max_cluster_tracks (approximate β)
MEMORY_BUDGET_FLOATS = 1 << 22  # forward table of one recursion batch (32 MB)
TOP_WEIGHTS = 3
MATRIX_FORM_TRACKS = 6  # clusters up to this size use the transfer-matrix form (≤ 64×64)
JOINT_WITHOUT_CLUSTERING = 4  # up to this many tracks the joint recursion beats clustering bookkeeping
COMPRESS_PEAKS = 8  # with more peaks per scan, drop the ones outside every gate first
CLOSED_FORM_TRACKS = 2  # up to this many tracks the scan loop uses pair_marginals (0: never)


# --------------------------------------------------------------------------- design


@dataclass(frozen=True)
class AssociationStrategy:
    """A named variant of the one JPDA core: which likelihood terms enter the events."""

    name: str
    amplitude: bool


STRATEGIES = {
    "jpda": AssociationStrategy("jpda", amplitude=False),
    "jpda_a": AssociationStrategy("jpda_a", amplitude=True),
}


@dataclass(frozen=True)
class BearingTrackerDesign:
    """Filter parameters (SI units, radians). Per-track arrays have one entry per track."""

    scan_period_s: float
    gate_rad: float
    q_rad2: float  # spectral density of the bearing acceleration, rad²/s³
    amplitude_threshold: float
    detection_probability: float
    clutter_per_gate: float  # λV before the threshold
    clutter_alpha: float
    sigma_p_rad: np.ndarray
    strength: np.ndarray
    sigma_a: np.ndarray
    amplitude_tracking: bool = False
    initial_strength: float = 15000.0
    tracked_sigma_a: float = 3500.0
    max_cluster_tracks: int = 12
    ending: EndingRule = EndingRule()  # when a track ends (trackreplay.cores.association.track_management)
    confirmation: ConfirmationRule = ConfirmationRule()  # M-of-N; the default confirms at the start

    @property
    def clutter_density(self) -> float:
        """λ of peaks above the threshold, per radian (exponential amplitudes: e^{−ατ} survive)."""
        return self.clutter_per_gate / self.gate_rad * np.exp(-self.clutter_alpha * self.amplitude_threshold)


def bearing_motion_model(dt: float, q: float):
    """``F = [[1, T], [0, 1]]`` and the continuous white-noise acceleration ``Q`` (eq. 8b):
    :func:`trackreplay.cores.filters.kalman.continuous_white_noise_model` of order 2."""
    return continuous_white_noise_model(dt, q, 2)


# --------------------------------------------------------------------------- likelihood terms


def window_gate_probability(S: np.ndarray, gate: float) -> np.ndarray:
    """P_G of a window ``|ν| ≤ V/2`` for a Gaussian innovation of variance S."""
    return erf(gate / (2.0 * np.sqrt(2.0 * S)))


def position_likelihood_ratio(innovation: np.ndarray, S: np.ndarray, detection_probability,
                              clutter_density: float) -> np.ndarray:
    """``P_D N(ν; 0, S) / λ`` per track and peak; ``innovation`` (…, T, m), ``S`` (…, T)."""
    S = S[..., None]
    pdf = np.exp(-0.5 * innovation * innovation / S) / np.sqrt(2.0 * np.pi * S)
    return np.asarray(detection_probability)[..., None] * pdf / clutter_density


def amplitude_likelihood_ratio(amplitude: np.ndarray, strength: np.ndarray, sigma_a: np.ndarray,
                               alpha: float, threshold: float):
    """The JPDA_A term: true-peak over clutter amplitude density, both above the threshold.

    ``N(z_a; ẑ_a, σ_a²)/Φ((ẑ_a − τ)/σ_a)`` over ``α e^{−α (z_a − τ)}``, computed in logs so
    that strong peaks far in the exponential's tail stay finite.

    Returns
    -------
    ratio : ndarray (…, T, m)
    detection_factor : ndarray (…, T)
        ``Φ((ẑ_a − τ)/σ_a)``: the chance that a true peak clears the threshold.
    """
    strength = np.asarray(strength, float)[..., None]
    sigma_a = np.asarray(sigma_a, float)[..., None]
    z = amplitude[..., None, :]
    survive = ndtr((strength - threshold) / sigma_a)
    log_true = (-0.5 * ((z - strength) / sigma_a) ** 2 - np.log(np.sqrt(2 * np.pi) * sigma_a)
                - np.log(np.maximum(survive, 1e-300)))
    log_clutter = np.log(alpha) - alpha * (z - threshold)
    with np.errstate(over="ignore"):
        ratio = np.exp(np.minimum(log_true - log_clutter, 700.0))
    return ratio, survive[..., 0]


# --------------------------------------------------------------------------- joint events


def association_marginals(ratio: np.ndarray, miss: np.ndarray):
    """Exact JPDA marginals of one batch of clusters of the same size (eq. A.6).

    Every joint event assigns each track either one peak or none, each peak to at most one
    track; its weight is ``Π_{t→j} ratio[t, j] · Π_{t missed} miss[t]``. The sum over events is
    built peak by peak: ``F_j(A)`` is the weight of all ways to assign peaks 1…j to exactly the
    track set A, ``B_j(A)`` the weight of all completions with peaks j+1…m given A, so
    ``β[t, j] = ratio[t, j] Σ_{A ∌ t} F_{j−1}(A) B_j(A ∪ {t}) / Z``. In matrix form peak j is a
    transfer matrix ``M_j = I + Σ_t ratio[t, j] E_t`` over the 2^s track sets (``E_t`` adds
    track t), ``F_j = F_{j−1} M_j`` and ``B_{j−1} = M_j B_j``; small clusters use that form
    (one batched product per peak), larger ones update the 2^s states track by track.

    Parameters
    ----------
    ratio : ndarray (B, s, m)
        Likelihood ratio of peak j against clutter for track t (0 where not gated).
    miss : ndarray (B, s)
        Weight of the track having no peak (``1 − P_D P_G``).

    Returns
    -------
    beta : ndarray (B, s, m)
        ``β_j^t``.
    beta0 : ndarray (B, s)
        ``β_0^t`` (no peak from track t); ``beta0 + beta.sum(-1) == 1``.
    """
    B, s, m = ratio.shape
    if B == 0 or s == 0:
        return np.zeros((B, s, m)), np.ones((B, s))
    n_states = 1 << s
    chunk = max(1, MEMORY_BUDGET_FLOATS // ((m + 1) * n_states * (n_states if s <= MATRIX_FORM_TRACKS else 1)))
    if B > chunk:
        beta, beta0 = np.zeros((B, s, m)), np.ones((B, s))
        for lo in range(0, B, chunk):
            beta[lo:lo + chunk], beta0[lo:lo + chunk] = association_marginals(ratio[lo:lo + chunk], miss[lo:lo + chunk])
        return beta, beta0
    # Scaling a track's row (its ratios and its miss weight) by one constant scales every
    # event by the same factor, so β is unchanged; with all factors ≤ 1 nothing overflows.
    scale = np.maximum(miss, ratio.max(axis=2, initial=0.0))
    scale = np.where(scale > 0, scale, 1.0)
    r = ratio / scale[..., None]
    m0 = miss / scale
    bits = _state_bits(s)  # (states, s)
    end = np.prod(np.where(bits[None], 1.0, m0[:, None, :]), axis=2)  # tracks left unassigned miss
    F = np.empty((m + 1, B, n_states))
    back = np.empty((m + 1, B, n_states))
    F[0] = 0.0
    F[0, :, 0] = 1.0
    back[m] = end
    if s <= MATRIX_FORM_TRACKS:  # the same recursion, one batched matrix product per peak
        beta = _transfer_matrix_recursion(r, F, back)
    else:  # the recursion as written above, track by track over the 2^s states
        with_t = [np.flatnonzero(bits[:, t]) for t in range(s)]
        without_t = [w ^ (1 << t) for t, w in enumerate(with_t)]
        for j in range(m):
            F[j + 1] = F[j]
            for t in range(s):
                F[j + 1][:, with_t[t]] += F[j][:, without_t[t]] * r[:, t, j, None]
        beta = np.empty((B, s, m))
        for j in range(m - 1, -1, -1):
            back[j] = back[j + 1]
            for t in range(s):
                beta[:, t, j] = r[:, t, j] * np.einsum("bi,bi->b", F[j][:, without_t[t]], back[j + 1][:, with_t[t]])
                back[j][:, without_t[t]] += r[:, t, j, None] * back[j + 1][:, with_t[t]]
    Z = back[0][:, 0]
    beta0 = np.einsum("bi,is->bs", F[m] * end, ~bits)
    ok = Z > 0
    Zs = np.where(ok, Z, 1.0)
    beta = np.where(ok[:, None, None], beta / Zs[:, None, None], 0.0)
    beta0 = np.where(ok[:, None], beta0 / Zs[:, None], 1.0)
    return beta, beta0


@lru_cache(maxsize=None)
def _state_bits(s: int) -> np.ndarray:
    """``bits[A, t]``: whether track t is in the track set with index A (a bitmask)."""
    return ((np.arange(1 << s)[:, None] >> np.arange(s)) & 1).astype(bool)


def cluster_tracks(gated: np.ndarray) -> np.ndarray:
    """Connected components of the tracks-share-a-gated-peak graph.

    Every track starts with its own index as label; a peak takes the smallest label of the tracks
    gating it, a track the smallest label of its peaks (and its own), until nothing changes: the
    labels spread along the graph one track-peak-track step per round, so the rounds are as many as
    the longest chain of tracks sharing peaks (one or two in practice), each a few array passes
    over every run at once.

    Parameters
    ----------
    gated : ndarray of bool (R, T, m)

    Returns
    -------
    labels : ndarray of int (R, T)
        The smallest track index of each track's cluster.
    """
    R, T, m = gated.shape
    labels = np.broadcast_to(np.arange(T), (R, T)).copy()
    if m == 0 or T < 2:
        return labels
    no_label = T  # larger than every track index
    while True:
        peak_label = np.where(gated, labels[:, :, None], no_label).min(axis=1)           # (R, m)
        spread = np.minimum(labels, np.where(gated, peak_label[:, None, :], no_label).min(axis=2))
        if np.array_equal(spread, labels):
            return labels
        labels = spread


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
        b_c, beta0 = association_marginals(r, miss)
    else:
        b_c, beta0 = _clustered_marginals(r, miss, g, predicted_bearing, max_cluster_tracks, split)
    if cols is None:
        return b_c, beta0, split
    beta = np.zeros((R, T, m))
    np.put_along_axis(beta, np.broadcast_to(cols[:, None, :], b_c.shape), b_c, axis=2)
    return beta, beta0, split


# --------------------------------------------------------------------------- state update


def pda_update(x, P4, gain, S, innovation, gated, beta, beta0):
    """PDA combination of the per-peak updates (eq. A.7) for the two-component bearing state.

    ``x⁺ = x + K ν̄`` with ``ν̄ = Σ β_j ν_j``; ``P⁺ = P − (1 − β₀) K S Kᵀ + K (Σ β_j ν_j² − ν̄²) Kᵀ``
    (the Kalman gain ``K = P⁻Hᵀ/S`` with ``H = [1, 0]``).

    Parameters
    ----------
    x : (…, 2)
    P4 : (…, 4)
        The predicted covariance, row-major (the loop keeps it so: ``F P Fᵀ`` is one product).
    gain : (…, 2), S : (…,)
        Kalman gain and innovation variance.
    innovation : (…, m), gated : (…, m) bool
        Per-peak innovations (ungated entries may hold padding; their β is 0).
    beta : (…, m), beta0 : (…,)

    Returns
    -------
    x_post : (…, 2)
    P4_post : (…, 4)
    nu_bar : (…,)
        The combined innovation ν̄ (0 when no peak has weight).
    """
    nu = np.where(gated, innovation, 0.0)
    weighted = beta * nu
    nu_bar = weighted.sum(axis=-1)
    weighted *= nu
    spread = weighted.sum(axis=-1) - nu_bar * nu_bar
    x_post = x + gain * nu_bar[..., None]
    w = spread - (1.0 - beta0) * S
    P4_post = P4 + w[..., None] * (gain[..., :, None] * gain[..., None, :]).reshape(P4.shape)
    return x_post, P4_post, nu_bar


def gaussian_likelihood_ratio(squared_distance, det_S, detection_probability, clutter_density):
    """``P_D N(ν; 0, S) / λ`` per track and plot from the squared Mahalanobis distance
    ``d² = νᵀ S⁻¹ ν`` ``(..., T, W)`` and ``|S|`` ``(..., T)`` of an m = 2 measurement (the radar's
    range and bearing; λ in plots per unit of measurement space, e.g. per metre and radian).
    The event weights of eq. A.5 in any dimension; :func:`position_likelihood_ratio` is the
    bearing (m = 1) case."""
    pdf = np.exp(-0.5 * squared_distance) / (2.0 * np.pi * np.sqrt(det_S))[..., None]
    return detection_probability * pdf / clutter_density


def pda_update_gaussian(x, P, gain, S, innovation, gated, beta, beta0):
    """PDA combination of the per-plot updates (the PDAF update of Bar-Shalom, Willett & Tian 2011; the
    bearing paper's eq. A.7) for any state and measurement size.

    ``x⁺ = x + K ν̄`` with ``ν̄ = Σ_j β_j ν_j``;
    ``P⁺ = P − (1 − β₀) K S Kᵀ + K (Σ_j β_j ν_j ν_jᵀ − ν̄ ν̄ᵀ) Kᵀ``: with probability β₀ the
    prediction stands, otherwise the Kalman posterior ``P − K S Kᵀ``, plus the spread of the
    innovations. :func:`pda_update` is the same formula for the two-state bearing filter.

    Parameters
    ----------
    x : (…, n), P : (…, n, n)
        Predicted state and covariance.
    gain : (…, n, m), S : (…, m, m)
        Kalman gain and innovation covariance.
    innovation : (…, W, m), gated : (…, W) bool
        Per-plot innovations (ungated entries may hold anything; their β is 0).
    beta : (…, W), beta0 : (…,)

    Returns
    -------
    x_post : (…, n)
    P_post : (…, n, n)
    nu_bar : (…, m)
    """
    nu = np.where(gated[..., None], innovation, 0.0)
    weighted = beta[..., None] * nu
    nu_bar = weighted.sum(axis=-2)
    spread = np.einsum("...wi,...wj->...ij", weighted, nu) - nu_bar[..., :, None] * nu_bar[..., None, :]
    spread -= (1.0 - beta0)[..., None, None] * S
    x_post = x + np.einsum("...ij,...j->...i", gain, nu_bar)
    P_post = P + gain @ spread @ np.swapaxes(gain, -1, -2)
    return x_post, 0.5 * (P_post + np.swapaxes(P_post, -1, -2)), nu_bar


def update_strength(strength: np.ndarray, amplitude: np.ndarray, gated: np.ndarray) -> np.ndarray:
    """Eq. 9: ``0.7 ẑ_a(k−1) + 0.3 max_j z_a`` over gated peaks; unchanged with an empty gate."""
    peak = np.max(np.where(gated, amplitude[..., None, :], -np.inf), axis=-1)
    return np.where(np.isfinite(peak), 0.7 * strength + 0.3 * peak, strength)


# --------------------------------------------------------------------------- the filter


@dataclass
class ScanPeaks:
    """The peaks of one scan for every run, padded: ``(R, m)`` arrays, ``valid`` marks real ones."""

    bearing: np.ndarray
    amplitude: np.ndarray
    valid: np.ndarray


def scans_from_padded(bearing: np.ndarray, amplitude: np.ndarray, counts: np.ndarray) -> list[ScanPeaks]:
    """``(R, K, W)`` padded arrays + counts → one :class:`ScanPeaks` per scan, trimmed per scan."""
    out = []
    W = bearing.shape[2]
    for k in range(bearing.shape[1]):
        w = int(counts[:, k].max()) if counts.size else 0
        valid = np.arange(min(w, W))[None, :] < counts[:, k, None]
        out.append(ScanPeaks(np.where(valid, bearing[:, k, :w], 0.0), np.where(valid, amplitude[:, k, :w], 0.0), valid))
    return out


def track_bearing_peaks(scans: list[ScanPeaks], x0: np.ndarray, P0: np.ndarray, design: BearingTrackerDesign,
                        strategy: AssociationStrategy, start_scan: int = 1) -> dict:
    """Run JPDA / JPDA_A over all scans for all runs at once.

    Parameters
    ----------
    scans : list of ScanPeaks
        One entry per scan, ``(R, m_k)`` arrays (bearing in rad).
    x0, P0 : ndarray (R, T, 2), (R, T, 2, 2)
        Track states at ``start_scan``; filtering starts at the next scan.
    design : BearingTrackerDesign
    strategy : AssociationStrategy

    Returns
    -------
    dict of ndarray with a leading ``(R, K, T)``, in the output vocabulary
    (:data:`trackreplay.vocabulary.OUTPUTS`):
        ``state`` (…, 2) and ``covariance`` (…, 2, 2): NaN before ``start_scan``, the start
        values at ``start_scan``, the PDA posterior after; ``flags`` (uint16):
        ``NO_TRACK | INITIALISING`` before ``start_scan``, ``INITIALISING`` at it and while
        the track is tentative (``design.confirmation``), then ``COASTED`` where no peak fell in
        the gate and ``CLUSTER_SPLIT`` where the track's cluster was cut; ``NO_TRACK | DELETED``
        (state NaN) at the scan a track ends (``design.ending`` or a failed confirmation), and
        ``NO_TRACK`` after it (:mod:`trackreplay.cores.association.track_management`); ``innovation`` (…, 1): the combined innovation ν̄ = Σ β_j ν_j of
        eq. A.7 (NaN where coasted, before and at the start); ``innovation_covariance``
        (…, 1, 1): S = H P⁻ Hᵀ + σ_p²; ``gain`` (…, 2, 1): the Kalman gain applied to ν̄.
        Paper-specific extras: ``beta0``, ``beta_top`` / ``beta_index`` (…, 3: the largest
        peak weights and their index in the scan's peak list, −1 for none), ``strength``
        (ẑ_a used), ``n_gated``, ``gate_center`` (predicted bearing).
    """
    K = len(scans)
    R, T, _ = x0.shape
    F, Q = continuous_white_noise_model(design.scan_period_s, design.q_rad2, 2)  # eq. 8b
    # F, Q, H = [1, 0] and σ_p² never change, and the state has two components, so the filter is
    # written out for that case (the same algebra as trackreplay.cores.filters.kalman, fewer array
    # operations per scan, which is what one run costs): P is kept as its row-major 4-vector,
    # F P Fᵀ is one product with F ⊗ F, S = p₀₀ + σ_p² and the gain is [p₀₀, p₀₁] / S.
    FF = np.kron(F, F).T
    Ft = F.T
    Q4 = Q.ravel()
    r_meas = np.broadcast_to(np.asarray(design.sigma_p_rad, float) ** 2, (R, T))
    out = {
        "state": np.full((R, K, T, 2), np.nan), "covariance": np.full((R, K, T, 2, 2), np.nan),
        "beta0": np.full((R, K, T), np.nan), "beta_top": np.full((R, K, T, TOP_WEIGHTS), np.nan),
        "beta_index": np.full((R, K, T, TOP_WEIGHTS), -1, np.int32), "strength": np.full((R, K, T), np.nan),
        "n_gated": np.zeros((R, K, T), np.int32), "gate_center": np.full((R, K, T), np.nan),
        "flags": np.zeros((R, K, T), np.uint16), "innovation": np.full((R, K, T, 1), np.nan),
        "innovation_covariance": np.full((R, K, T, 1, 1), np.nan), "gain": np.full((R, K, T, 2, 1), np.nan),
    }
    out["flags"][:, :start_scan] = FLAG_NO_TRACK | FLAG_INITIALISING
    x, P = np.array(x0, float), np.array(P0, float)
    # a slot without a start (NaN: no peak to start it from) stays empty the whole run; it
    # carries a finite placeholder so the arithmetic stays finite, and takes no peak
    started = np.isfinite(x).all(axis=-1) & np.isfinite(P).all(axis=(-2, -1))
    if not started.all():
        x = np.where(started[..., None], x, 0.0)
        P = np.where(started[..., None, None], P, np.eye(2))
    out["flags"][:, start_scan] = np.where(started, FLAG_INITIALISING, FLAG_NO_TRACK)
    out["state"][:, start_scan] = np.where(started[..., None], x, np.nan)
    out["covariance"][:, start_scan] = np.where(started[..., None, None], P, np.nan)
    P4 = (0.5 * (P + np.swapaxes(P, -1, -2))).reshape(R, T, 4)
    if design.amplitude_tracking:
        strength = np.full((R, T), float(design.initial_strength))
        sigma_a = np.full((R, T), float(design.tracked_sigma_a))
    else:
        strength = np.broadcast_to(np.asarray(design.strength, float), (R, T)).copy()
        sigma_a = np.broadcast_to(np.asarray(design.sigma_a, float), (R, T)).copy()
    out["strength"][:, start_scan] = strength
    half_gate = design.gate_rad / 2
    threshold = design.amplitude_threshold
    pd = design.detection_probability
    # the start's own measurements count towards M-of-N: scans 0 … start_scan
    life = TrackLife((R, T), design.confirmation, design.ending)
    life.start(started, hits=start_scan + 1, scans=start_scan + 1)
    # no track starts inside the loop, so a life that cannot change now never will: skip its step
    settled = life.settled
    slots_started = None if started.all() else started[..., None]
    # two tracks (or one) need no clustering and no recursion: closed-form marginals
    pair = T <= min(CLOSED_FORM_TRACKS, 2) and (T == 1 or design.max_cluster_tracks >= 2)
    n = max(K - start_scan - 1, 0)
    # per-scan results, scan first so each store is one contiguous write; laid out after the loop
    xs, Ps, gains = np.empty((n, R, T, 2)), np.empty((n, R, T, 4)), np.empty((n, R, T, 2))
    centers, beta0s, nu_bars, Ss = (np.empty((n, R, T)) for _ in range(4))
    n_gated_k = np.empty((n, R, T), np.int32)
    strengths = np.empty((n, R, T)) if design.amplitude_tracking else None
    splits = None if pair else np.zeros((n, R, T), bool)
    if not settled:
        alives, endings, tentatives = (np.empty((n, R, T), bool) for _ in range(3))
    top = _TopWeights(R, T)
    for i, k in enumerate(range(start_scan + 1, K)):
        sp = scans[k]
        m = sp.bearing.shape[1]
        x = x @ Ft
        P4 = P4 @ FF
        P4 += Q4
        S = P4[..., 0] + r_meas
        gain = P4[..., :2] / S[..., None]
        center = x[..., 0]
        nu = sp.bearing[:, None, :] - center[..., None]  # (R, T, m)
        gated = np.abs(nu) <= half_gate
        gated &= (sp.valid & (sp.amplitude >= threshold))[:, None, :]
        # an ended track keeps predicting (finite, harmless) but takes no peak and is not output
        if not settled:
            gated &= life.alive[..., None]
        elif slots_started is not None:
            gated &= slots_started
        # likelihood ratios of the m peaks and, last, the miss weight 1 − P_D P_G of each track
        pd_k = pd
        if strategy.amplitude:
            amp_ratio, survive = amplitude_likelihood_ratio(sp.amplitude, strength, sigma_a, design.clutter_alpha,
                                                            threshold)
            pd_k = pd * survive
        weights = np.empty((R, T, m + 1))
        ratio = weights[..., :m]
        ratio[...] = position_likelihood_ratio(nu, S, pd_k, design.clutter_density)
        if strategy.amplitude:
            ratio *= amp_ratio
        np.copyto(ratio, 0.0, where=~gated)
        miss = 1.0 - pd_k * window_gate_probability(S, design.gate_rad)
        if pair:
            weights[..., m] = miss
            marginals = pair_marginals(weights)
            beta, beta0 = marginals[..., :m], marginals[..., m]
        else:
            beta, beta0, splits[i] = joint_association_probabilities(ratio, miss, gated, center,
                                                                     design.max_cluster_tracks)
        x, P4, nu_bar = pda_update(x, P4, gain, S, nu, gated, beta, beta0)  # eq. A.7
        if design.amplitude_tracking:
            strength = update_strength(strength, sp.amplitude, gated)
            strengths[i] = strength
        n_gated = gated.sum(axis=2)
        if not settled:
            tentatives[i], endings[i] = life.step(n_gated > 0, x[..., 0])
            alives[i] = life.alive
        xs[i], Ps[i], gains[i] = x, P4, gain
        centers[i], beta0s[i], nu_bars[i], Ss[i], n_gated_k[i] = center, beta0, nu_bar, S, n_gated
        top.add(beta)
    if n == 0:
        return out
    after = slice(start_scan + 1, K)
    coasted = n_gated_k == 0
    flags = coasted * np.uint16(FLAG_COASTED)
    if splits is not None:
        flags |= splits * np.uint16(FLAG_CLUSTER_SPLIT)
    if settled:
        gone = np.broadcast_to(~life.alive, (n, R, T))
    else:
        flags |= tentatives * np.uint16(FLAG_INITIALISING)
        gone = ~alives
    # ended at this scan (DELETED), before, or never started: no state, nothing associated
    if gone.any():
        flags = np.where(gone, np.uint16(FLAG_NO_TRACK), flags)
        if not settled:
            flags = np.where(endings, np.uint16(FLAG_NO_TRACK | FLAG_DELETED), flags)
        for a in (xs, Ps, gains, Ss):
            a[gone] = np.nan
        nu_bars[gone] = np.nan
    nu_bars[coasted] = np.nan
    # symmetric to rounding already; exactly so, as the general filter returns it
    Ps = Ps.reshape(n, R, T, 2, 2)
    Ps = 0.5 * (Ps + np.swapaxes(Ps, -1, -2))
    out["flags"][:, after] = flags.swapaxes(0, 1)
    out["state"][:, after] = xs.swapaxes(0, 1)
    out["covariance"][:, after] = Ps.swapaxes(0, 1)
    out["gain"][:, after, :, :, 0] = gains.swapaxes(0, 1)
    out["innovation_covariance"][:, after, :, 0, 0] = Ss.swapaxes(0, 1)
    out["innovation"][:, after, :, 0] = nu_bars.swapaxes(0, 1)
    out["beta0"][:, after] = beta0s.swapaxes(0, 1)
    out["gate_center"][:, after] = centers.swapaxes(0, 1)
    out["n_gated"][:, after] = n_gated_k.swapaxes(0, 1)
    out["strength"][:, after] = strength[:, None] if strengths is None else strengths.swapaxes(0, 1)
    top.store(out["beta_top"][:, after], out["beta_index"][:, after])
    return out
