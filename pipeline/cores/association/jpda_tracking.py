"""The JPDA / JPDA_A bearing filter's scan loop, :func:`track_bearing_peaks` (Park, Ryu & Lee 1994,
appendix eqs. A.1–A.7; Fortmann, Bar-Shalom & Scheffe 1983; ``docs/papers/xcorr.md``).

The loop is the JPDA core's caller that needs speed: it takes the plain forms of
:mod:`trackreplay.cores.association.jpda` (the likelihood ratios, the PDA update of eq. A.7, the
amplitude tracking of eq. 9) and the fast forms of :mod:`trackreplay.cores.association._jpda_fast`
(the β of every run, the closed form of one or two tracks, the outputs' top weights), each tested
equal to its plain form there. It is written out for the two-state bearing filter in one function,
so that a reader follows a scan from prediction to output without leaving it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trackreplay import vocabulary as vocab
from trackreplay.cores.association._jpda_fast import _TopWeights, joint_association_probabilities, pair_marginals
from trackreplay.cores.association.jpda import (
    TOP_WEIGHTS,
    AssociationStrategy,
    BearingTrackerDesign,
    amplitude_likelihood_ratio,
    pda_update,
    position_likelihood_ratio,
    update_strength,
    window_gate_probability,
)
from trackreplay.cores.association.track_management import TrackLife
from trackreplay.cores.filters.kalman import continuous_white_noise_model

# Flag bits of the one table (trackreplay.vocabulary.FLAGS), as this loop sets them:
# vocab.NO_TRACK       before the track start scan: no state yet
# vocab.INITIALISING   up to and including the start scan: start values, not filtered
# vocab.COASTED        no peak in the gate: the state is the prediction
# vocab.DELETED        the track ended at this scan (track_management); NO_TRACK after
# vocab.CLUSTER_SPLIT  the track's cluster exceeded max_cluster_tracks (approximate β)
CLOSED_FORM_TRACKS = 2  # up to this many tracks the scan loop uses pair_marginals (0: never)


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
    out["flags"][:, :start_scan] = vocab.NO_TRACK | vocab.INITIALISING
    x, P = np.array(x0, float), np.array(P0, float)
    # a slot without a start (NaN: no peak to start it from) stays empty the whole run; it
    # carries a finite placeholder so the arithmetic stays finite, and takes no peak
    started = np.isfinite(x).all(axis=-1) & np.isfinite(P).all(axis=(-2, -1))
    if not started.all():
        x = np.where(started[..., None], x, 0.0)
        P = np.where(started[..., None, None], P, np.eye(2))
    out["flags"][:, start_scan] = np.where(started, vocab.INITIALISING, vocab.NO_TRACK)
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
    flags = coasted * np.uint16(vocab.COASTED)
    if splits is not None:
        flags |= splits * np.uint16(vocab.CLUSTER_SPLIT)
    if settled:
        gone = np.broadcast_to(~life.alive, (n, R, T))
    else:
        flags |= tentatives * np.uint16(vocab.INITIALISING)
        gone = ~alives
    # ended at this scan (DELETED), before, or never started: no state, nothing associated
    if gone.any():
        flags = np.where(gone, np.uint16(vocab.NO_TRACK), flags)
        if not settled:
            flags = np.where(endings, np.uint16(vocab.NO_TRACK | vocab.DELETED), flags)
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
