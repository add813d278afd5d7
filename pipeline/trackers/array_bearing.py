"""Multi-target angle tracking from array snapshots: MUSIC start-up → PAST → per-target Kalman
filters fed by the angular innovation (Ryu, Lee & Lee 2001; Ryu et al. 1999).

Spec: ``shared/spec/array-angle-tracking.md`` (paper section III.2, steps 1–5, eqs. (14)–(22)).

Scan 0 is the paper's k = −1, scan 1 is k = 0, tracking starts at scan 2 (k = 1):

1. **Start-up** (step 1): MUSIC on scans 0 and 1 (:mod:`pipeline.cores.array.music`). The number of targets
   N is the source count (MDL or AIC) of scan 1, or the design's fixed ``n_sources``; N peaks
   are picked in both scans and associated by nearest angle (for two sorted sets of N angles,
   pairing by rank is the nearest-angle assignment). Per target
   ``x(0|0) = [θ̂(0), (θ̂(0) − θ̂(−1))/T]``,
   ``P(0|0) = [[σ_z², σ_z²/T], [σ_z²/T, 2σ_z²/T²]]`` (the spec's correction of the printed
   σ_z²/T²).
2. **Subspace**: PAST (:mod:`pipeline.cores.array.past_subspace`) initialised from the EVD of scan 0 and run
   over every snapshot of scans 1, 2, …; W(k) is its state at the end of scan k. The per-scan
   batch EVD is computed alongside as the reference (``subspace_error_rad`` = largest principal
   angle between the two) and can replace PAST (``subspace="batch"``).
3. **Kalman filter** per target, constant angular velocity, ``F = [[1, T], [0, 1]]``,
   ``Q = q [[T³/3, T²/2], [T²/2, T]]``, ``H = [1, 0]``, variance σ_z²
   (:mod:`pipeline.cores.filters.kalman`); the update uses the angular innovation δθ(k) from W(k) and the
   prediction θ̂(k|k−1) (:mod:`pipeline.cores.array.angular_innovation`, strategy ``proposed`` or ``ryu``)
   in place of z − Hx. A non-finite innovation (prediction at end-fire) leaves the track
   coasting and sets :data:`FLAG_COASTED`.

The N of each run comes from its own start-up, so runs are processed in groups of equal N, each
group in one vectorised pass (no loop per run). Outputs are padded to the largest N with NaN.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from pipeline.cores.array.angular_innovation import INNOVATIONS
from pipeline.cores.filters.kalman import apply_gain, continuous_white_noise_model, kalman_gain, kf_predict, two_point_start
from pipeline.cores.array.music import angle_grid, eigen_decomposition, music_spectrum, pick_peaks, sample_covariance, source_count
from pipeline.cores.array.past_subspace import batch_signal_subspace, initial_state, largest_principal_angle, past_update

FLAG_STARTUP = 1
FLAG_COASTED = 2
STARTUP_SCANS = 2
SUBSPACES = ("past", "batch")


@dataclass(frozen=True)
class SubspaceTrackerDesign:
    """Tracker design values (SI units, radians).

    Attributes
    ----------
    spacing_wavelengths : float
        d/λ of the array.
    scan_period_s : float
        T.
    process_noise_q : float
        q of ``Q = q [[T³/3, T²/2], [T²/2, T]]`` (rad²/s³).
    innovation_variance : float
        σ_z² (rad²).
    forgetting : float
        PAST forgetting factor β per snapshot.
    source_count : str
        ``"mdl"`` or ``"aic"``.
    n_sources : int
        Fixed number of targets; 0 estimates it at start-up.
    grid_step_rad : float
        MUSIC grid step.
    subspace : str
        ``"past"`` (the paper) or ``"batch"`` (per-scan EVD, reference).
    """

    spacing_wavelengths: float = 0.5
    scan_period_s: float = 1.0
    process_noise_q: float = np.deg2rad(1.0) ** 2
    innovation_variance: float = 4 * np.deg2rad(1.0) ** 2
    forgetting: float = 0.97
    source_count: str = "mdl"
    n_sources: int = 0
    grid_step_rad: float = np.deg2rad(0.1)
    subspace: str = "past"

    def model(self):
        """``F, Q, H, R`` of the constant-angular-velocity filter."""
        F, Q = continuous_white_noise_model(self.scan_period_s, self.process_noise_q, 2)
        H = np.array([[1.0, 0.0]])
        R = np.array([[self.innovation_variance]])
        return F, Q, H, R


@dataclass
class StartUp:
    """MUSIC start-up of every run (step 1)."""

    n_tracks: np.ndarray  # (B,)
    theta_minus1: np.ndarray  # (B, Nmax), ascending, NaN padded
    theta_0: np.ndarray  # (B, Nmax)
    source_counts: np.ndarray  # (B, 2) estimated counts at scans 0 and 1


def start_up(snapshots: np.ndarray, design: SubspaceTrackerDesign) -> StartUp:
    """Step 1: source count and angles from MUSIC at k = −1 and k = 0 (scans 0, 1)."""
    grid = angle_grid(design.grid_step_rad)
    first = snapshots[:, :STARTUP_SCANS]
    values, vectors = eigen_decomposition(sample_covariance(first))
    counts = source_count(values, snapshots.shape[-1], design.source_count, snapshots.shape[-2] - 1)
    n = counts[:, 1] if design.n_sources == 0 else np.full(snapshots.shape[0], design.n_sources)
    n2 = np.stack([n, n], axis=1)
    angles = pick_peaks(music_spectrum(vectors, np.maximum(n2, 1), grid, design.spacing_wavelengths), grid, n2)
    found = np.sum(np.isfinite(angles[:, 1]), axis=-1)
    n = np.minimum(n, found)  # a spectrum with fewer peaks than sources starts fewer tracks
    width = int(n.max()) if n.size else 0
    th0 = np.full((len(n), width), np.nan)
    thm1 = np.full((len(n), width), np.nan)
    found_before = np.sum(np.isfinite(angles[:, 0]), axis=-1)
    for k in np.unique(n):
        if k == 0:
            continue
        sel = n == k
        th0[sel, :k] = angles[sel, 1, :k]
        # two sorted sets of k angles: pairing by rank is the nearest-angle association (1-D)
        thm1[sel, :k] = angles[sel, 0, :k]
        short = sel & (found_before < k)
        if short.any():  # k = −1 found fewer peaks: each target takes its nearest one
            before = np.where(np.isfinite(angles[short, 0]), angles[short, 0], np.inf)
            dist = np.abs(th0[short, :k, None] - before[:, None, :])
            thm1[short, :k] = np.take_along_axis(before, np.argmin(dist, axis=-1), axis=-1)
    thm1 = np.where(np.isfinite(thm1), thm1, th0)  # no k = −1 peak at all: zero initial rate
    return StartUp(n, thm1, th0, counts)


def subspace_sequence(snapshots: np.ndarray, n: int, design: SubspaceTrackerDesign):
    """PAST and batch-EVD subspaces of every scan for runs sharing the signal dimension ``n``.

    Returns
    -------
    past : ndarray, complex, shape (B, K, M, n)
        PAST's W at the end of each scan (scan 0: the EVD it starts from).
    batch : ndarray, complex, shape (B, K, M, n)
        Leading eigenvectors of each scan's sample covariance.
    """
    B, K, M, _ = snapshots.shape
    batch, values = batch_signal_subspace(snapshots, n)
    past = np.empty_like(batch)
    W, P = initial_state(batch[:, 0], values[:, 0], design.forgetting)
    past[:, 0] = W
    for k in range(1, K):
        W, P = past_update(W, P, snapshots[:, k], design.forgetting)
        past[:, k] = W
    return past, batch


def _track_group(subspaces, theta_minus1, theta_0, design: SubspaceTrackerDesign, strategy: str):
    """Steps 2–5 for a group of runs with the same number of tracks."""
    B, K, M, n = subspaces.shape
    F, Q, H, R = design.model()
    innovation_fn = INNOVATIONS[strategy]
    x, P = two_point_start(theta_minus1, theta_0, design.scan_period_s, np.sqrt(design.innovation_variance))  # (B, n, 2)
    out = {
        "angle_rad": np.full((B, K, n), np.nan), "rate_radps": np.full((B, K, n), np.nan),
        "angle_std_rad": np.full((B, K, n), np.nan), "predicted_rad": np.full((B, K, n), np.nan),
        "innovation_rad": np.full((B, K, n), np.nan), "gain": np.full((B, K, n, 2), np.nan),
        "flags": np.zeros((B, K, n), np.uint8), "innovation_time_s": np.zeros((B, K)),
    }
    out["angle_rad"][:, 0], out["angle_rad"][:, 1] = theta_minus1, theta_0
    out["rate_radps"][:, 1] = x[..., 1]
    out["angle_std_rad"][:, 1] = np.sqrt(P[..., 0, 0])
    out["flags"][:, :STARTUP_SCANS] = FLAG_STARTUP
    for k in range(STARTUP_SCANS, K):
        x, P = kf_predict(x, P, F, Q)
        out["predicted_rad"][:, k] = x[..., 0]
        t0 = time.perf_counter()
        dtheta = innovation_fn(subspaces[:, k], x[..., 0], design.spacing_wavelengths)
        out["innovation_time_s"][:, k] = (time.perf_counter() - t0) / max(B, 1)
        gain, _ = kalman_gain(P, H, R)
        ok = np.isfinite(dtheta)
        x_new, P_new = apply_gain(x, P, gain, np.where(ok, dtheta, 0.0)[..., None], H, R)
        x = np.where(ok[..., None], x_new, x)
        P = np.where(ok[..., None, None], P_new, P)
        out["angle_rad"][:, k] = x[..., 0]
        out["rate_radps"][:, k] = x[..., 1]
        out["angle_std_rad"][:, k] = np.sqrt(P[..., 0, 0])
        out["innovation_rad"][:, k] = dtheta
        out["gain"][:, k] = gain[..., 0]
        out["flags"][:, k] = np.where(ok, 0, FLAG_COASTED)
    return out


def track_bearings(snapshots: np.ndarray, design: SubspaceTrackerDesign, strategies=("proposed", "ryu")):
    """Run the whole tracker over all Monte Carlo runs.

    Parameters
    ----------
    snapshots : ndarray, complex, shape (B, K, M, Ns)
        Snapshot blocks per run and scan (validated by the caller: complex, finite,
        N ≤ M − 1, Ns ≥ N).
    design : SubspaceTrackerDesign
    strategies : sequence of str
        Innovation strategies (keys of :data:`pipeline.cores.array.angular_innovation.INNOVATIONS`).

    Returns
    -------
    dict
        ``strategy -> {array name -> ndarray (B, K, ...)}``: ``angle_rad``, ``rate_radps``,
        ``angle_std_rad``, ``predicted_rad``, ``innovation_rad``, ``gain`` (…, 2),
        ``flags``, ``innovation_time_s`` (per run and scan), ``n_tracks``,
        ``subspace_error_rad`` (PAST vs batch EVD, largest principal angle).
    """
    if design.subspace not in SUBSPACES:
        raise ValueError(f"unknown subspace tracker {design.subspace!r} (have: {', '.join(SUBSPACES)})")
    X = np.asarray(snapshots).astype(complex, copy=False)
    B, K = X.shape[:2]
    init = start_up(X, design)
    width = init.theta_0.shape[1]
    outputs = {s: None for s in strategies}
    sub_err = np.full((B, K), np.nan)
    for n in np.unique(init.n_tracks):
        sel = np.flatnonzero(init.n_tracks == n)
        if n == 0:
            continue
        past, batch = subspace_sequence(X[sel], int(n), design)
        sub_err[sel] = largest_principal_angle(past, batch)
        chosen = past if design.subspace == "past" else batch
        for s in strategies:
            part = _track_group(chosen, init.theta_minus1[sel, :n], init.theta_0[sel, :n], design, s)
            if outputs[s] is None:
                outputs[s] = {k: _empty_like_padded(v, B, width) for k, v in part.items()}
            for k, v in part.items():
                if v.ndim >= 3:
                    outputs[s][k][sel, :, :n] = v
                else:
                    outputs[s][k][sel] = v
    for s in strategies:
        if outputs[s] is None:  # no run found a source
            outputs[s] = {k: _empty_like_padded(v, B, width) for k, v in
                          _track_group(np.zeros((0, K, X.shape[2], 1), complex), np.zeros((0, 1)),
                                       np.zeros((0, 1)), design, s).items()}
        outputs[s]["n_tracks"] = np.broadcast_to(init.n_tracks[:, None], (B, K)).astype(np.int32)
        outputs[s]["subspace_error_rad"] = sub_err
        outputs[s]["source_count"] = np.broadcast_to(init.source_counts[:, 1][:, None], (B, K)).astype(np.int32)
    return outputs


def _empty_like_padded(v, B, width):
    shape = (B, v.shape[1]) + ((width,) + v.shape[3:] if v.ndim >= 3 else ())
    if v.dtype == np.uint8:
        return np.zeros(shape, np.uint8)
    return np.full(shape, np.nan) if v.ndim >= 3 else np.zeros(shape)


def music_waterfall(snapshots: np.ndarray, n_sources: np.ndarray, design: SubspaceTrackerDesign):
    """MUSIC spectrum of every scan of one run ``(K, M, Ns)`` → ``(grid (G,), spectrum (K, G))``."""
    grid = angle_grid(design.grid_step_rad)
    _, vectors = eigen_decomposition(sample_covariance(np.asarray(snapshots).astype(complex, copy=False)))
    return grid, music_spectrum(vectors, np.maximum(n_sources, 1), grid, design.spacing_wavelengths)


TRACKERS = ()  # (being moved onto the tracker interface)
