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
  (:func:`~trackreplay.cores.association._jpda_fast.pair_marginals`: the same marginals in closed form, a few array operations per scan);
* clusters of more than ``max_cluster_tracks`` tracks (default 12, i.e. 4096 states per peak)
  are cut, in bearing order, into groups of at most that many tracks, each solved exactly but
  blind to the others (a peak may then be shared across a cut): approximate, and flagged with
  ``CLUSTER_SPLIT`` (:data:`trackreplay.vocabulary.FLAGS`). Peaks cost linear time and the recursion is run in batches of
  bounded memory, so hundreds of peaks per scan stay cheap;
* PDA update per track (eq. A.7): combined innovation, covariance with the spread term;
* optional amplitude tracking (eq. 9): ``ẑ_a(k) = 0.7 ẑ_a(k−1) + 0.3 max_j z_a`` over the
  peaks in the track's gate (unchanged when the gate is empty).

This module holds the plain forms, the ones to hold against the papers, and imports nothing of
the fast ones. The fast forms (the transfer-matrix recursion, the closed form of one or two
tracks, the β of every run by clusters, the pair-driven JPDA of many tracks, the outputs' top
weights) live in :mod:`trackreplay.cores.association._jpda_fast`, which imports this module and
is tested equal to it; the filter's scan loop, which calls them,
is :func:`trackreplay.cores.association.jpda_tracking.track_bearing_peaks`.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.special import erf, ndtr

from trackreplay.cores.filters.kalman import continuous_white_noise_model
from trackreplay.cores.association.track_management import ConfirmationRule, EndingRule

MEMORY_BUDGET_FLOATS = 1 << 22  # forward table of one recursion batch (32 MB)
TOP_WEIGHTS = 3  # the largest β of each track and scan kept in the outputs


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
    track t), ``F_j = F_{j−1} M_j`` and ``B_{j−1} = M_j B_j``. Here the 2^s states are updated
    track by track; the matrix form, one batched product per peak, is the fast form
    (:func:`~trackreplay.cores.association._jpda_fast.association_marginals_fast`, the same β to
    rounding, tests/test_jpda_fast_forms.py).

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
    chunk = max(1, MEMORY_BUDGET_FLOATS // ((m + 1) * (1 << s)))
    if B > chunk:
        beta, beta0 = np.zeros((B, s, m)), np.ones((B, s))
        for lo in range(0, B, chunk):
            beta[lo:lo + chunk], beta0[lo:lo + chunk] = association_marginals(ratio[lo:lo + chunk], miss[lo:lo + chunk])
        return beta, beta0
    r, F, back, end, bits = _recursion_tables(ratio, miss)
    # the recursion as written above, track by track over the 2^s states
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
    return _normalised(beta, F, back, end, bits)


def _recursion_tables(ratio, miss):
    """The start of :func:`association_marginals`' recursion (shared with its matrix form in
    :mod:`trackreplay.cores.association._jpda_fast`): the scaled ratios ``r``, the forward and
    backward tables with ``F[0]`` and ``back[m]`` set, the weight ``end`` of the tracks left
    unassigned missing, and the track-set bits."""
    B, s, m = ratio.shape
    n_states = 1 << s
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
    return r, F, back, end, bits


def _normalised(beta, F, back, end, bits):
    """β and β₀ of the filled tables, divided by the total weight ``Z`` (β = 0, β₀ = 1 where no
    event has weight)."""
    m = F.shape[0] - 1
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
