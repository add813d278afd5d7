"""Ryu, Lee & Lee (2001): multi-target bearing tracking from array snapshots with the angular
innovation; Ryu et al. (1999) for the least-squares innovation it replaces.

The paper's section III.2, steps 1–5, eqs. (14)–(22); see ``docs/papers/array.md``.
Two trackers of the family ``array`` share one pipeline and differ only in how the
angular innovation is computed (:mod:`trackreplay.cores.array.angular_innovation`):

``proposed``  the paper's closed form (eqs. (7), (11)–(13));
``ryu``       Ryu et al. (1999)'s (2N+1)-unknown least squares (eq. (6) of the 1999 paper).

Scan 0 is the paper's k = −1, scan 1 is k = 0, tracking starts at scan 2 (k = 1):

1. **Start-up** (step 1): MUSIC on scans 0 and 1 (:mod:`trackreplay.cores.array.music`). The number
   of targets N is the source count (MDL or AIC) of scan 1, or the design's fixed ``n_sources``;
   N peaks are picked in both scans and associated by nearest angle (for two sorted sets of N
   angles, pairing by rank is the nearest-angle assignment). Per target
   ``x(0|0) = [θ̂(0), (θ̂(0) − θ̂(−1))/T]``,
   ``P(0|0) = [[σ_z², σ_z²/T], [σ_z²/T, 2σ_z²/T²]]`` (the two-point difference; the paper prints
   σ_z²/T²).
2. **Subspace**: PAST (Yang 1995, :mod:`trackreplay.cores.array.past_subspace`) initialised from the
   EVD of scan 0 and run over every snapshot of scans 1, 2, …; W(k) is its state at the end of
   scan k. The per-scan batch EVD is computed alongside as the reference (``subspace_error_rad``
   = largest principal angle between the two) and can replace PAST (``subspace_tracker=batch``).
3. **Kalman filter** per target, constant angular velocity, ``F = [[1, T], [0, 1]]``,
   ``Q = q [[T³/3, T²/2], [T²/2, T]]``, ``H = [1, 0]``, variance σ_z² (eqs. (14)–(22),
   :mod:`trackreplay.cores.filters.kalman`); the update uses the angular innovation δθ(k) from W(k)
   and the prediction θ̂(k|k−1) in place of z − Hx. A non-finite innovation (prediction at
   end-fire) leaves the track coasting (flag ``COASTED``). With ``align_subspace_instant`` (a
   converted recording records it) W(k) is taken for the scene at the instant its weights
   describe, δ_k from the scan's time stamp
   (:func:`trackreplay.cores.array.past_subspace.subspace_instant_offset`): ``H = [1, δ_k]`` and the
   innovation is taken about θ̂ + δ_k θ̂̇, so a source moving at a constant rate is not trailed.

The N of each run comes from its own start-up, so runs are processed in groups of equal N, each
group in one vectorised pass (no loop per run). Track slots are padded to the largest N (flag
``NO_TRACK``, state NaN).

Outputs (vocabulary of :data:`trackreplay.vocabulary.OUTPUTS`, T track slots):
``state`` (R, K, T, 2) ``[θ, θ̇]`` in rad and rad/s (scan 0 has no rate: ``NOT_ESTIMATED``),
``covariance`` (R, K, T, 2, 2) from scan 1 on, ``innovation`` (R, K, T, 1) the angular innovation
δθ, ``innovation_covariance`` (R, K, T, 1, 1), ``gain`` (R, K, T, 2, 1), ``flags`` (R, K, T)
(``INITIALISING`` on scans 0 and 1, ``COASTED``, ``NO_TRACK``), ``track_id`` (R, K, T): the
slots are fixed (one per target found at start-up, in angle order) and never restarted, so slot
j holds track j wherever it holds a track and −1 elsewhere. The paper's extras:
``predicted_rad`` (R, K, T) θ̂(k|k−1); ``n_tracks``, ``source_count`` (R, K) the run's N and
its MDL/AIC count at scan 1; ``subspace_error_rad`` (R, K); and the cost of each scan's
innovation step (section IV): ``innovation_flops_model`` (the paper's analytic model),
``innovation_flops_counted`` (what our kernel executes, steering vectors excluded) and
``steering_flops_counted`` (R, K), NaN where no innovation is computed.

The start-up and the subspace sequence do not depend on the innovation strategy: both trackers
of one replay compute them once (:func:`shared_front_end`, a memo keyed on the read-only
snapshot array the stage decodes); the numbers are the same either way.
"""

from __future__ import annotations

import dataclasses
import weakref
from dataclasses import dataclass

import numpy as np

from trackreplay import vocabulary as vocab
from trackreplay.batched_linalg import over_blocks
from trackreplay.cores.array.angular_innovation import INNOVATIONS, _counted_flops_memo
from trackreplay.cores.array.flop_counts import ANALYTIC
from trackreplay.cores.array.music import angle_grid, eigen_decomposition, music_spectrum, pick_peaks, sample_covariance, source_count
from trackreplay.cores.array.past_subspace import (batch_signal_subspace, initial_state, largest_principal_angle, past_scans,
                                                subspace_instant_offset)
from trackreplay.cores.association.track_management import EndingRule, TrackLife
from trackreplay.cores.filters.kalman import apply_gain, continuous_white_noise_model, kalman_gain, kf_predict, two_point_start
from trackreplay.errors import InputError
from trackreplay.trackers.interface import ArraySnapshots, Param, Tracker

STARTUP_SCANS = 2
# runs per block of the batch EVD and the subspace error (memory and speed, not results): at 16
# runs a block's covariances and eigenvectors (< 8 MB) reuse the memory of the block before; fresh
# memory of 64-run blocks cost a quarter of the EVD's time in page faults
FRONT_END_BLOCK_RUNS = 16
INNOVATION_BLOCK_RUNS = 256  # runs per call of the innovation kernel (speed, not results)
PAST_BLOCK_RUNS = 256  # runs per PAST pass: fewer calls per run, arrays still in the L2 cache (speed, not results)
SUBSPACES = ("past", "batch")
CRITERIA = ("mdl", "aic")


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
    max_coasted_scans : int
        A track whose innovation is undefined (its prediction beyond the field) this many scans
        in a row is deleted; 0: never. A track whose bearing leaves the field
        (:attr:`field_rad`) is always deleted
        (:mod:`trackreplay.cores.association.track_management`).
    align_subspace_instant : bool
        Measure each scan's bearing at the instant its subspace describes
        (:func:`trackreplay.cores.array.past_subspace.subspace_instant_offset`: PAST's memory reaches
        back 0.59 T before the scan's time stamp at β = 0.97), not at the time stamp. False (the
        default) is the paper as printed, whose tracks trail a moving source by θ̇ times that
        offset; a converted WAV recording records True (``recorders/array_wav.py``).
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
    max_coasted_scans: int = 3
    align_subspace_instant: bool = False

    @property
    def field_rad(self) -> float:
        """Half-width of the field free of grating lobes: |θ| < arcsin(λ/d − 1) above d = λ/2,
        the whole half-plane (π/2) at or below it."""
        return float(np.arcsin(min(1.0, 1.0 / self.spacing_wavelengths - 1.0)))

    def model(self):
        """``F, Q, H, R`` of the constant-angular-velocity filter."""
        F, Q = continuous_white_noise_model(self.scan_period_s, self.process_noise_q, 2)
        H = np.array([[1.0, 0.0]])
        R = np.array([[self.innovation_variance]])
        return F, Q, H, R

    def front_end_key(self) -> tuple:
        """The values the start-up and the subspace sequence depend on."""
        return (self.spacing_wavelengths, self.forgetting, self.source_count, self.n_sources, self.grid_step_rad,
                self.subspace)


# --------------------------------------------------------------------------- step 1: start-up


@dataclass
class StartUp:
    """MUSIC start-up of every run (step 1)."""

    n_tracks: np.ndarray  # (B,)
    theta_minus1: np.ndarray  # (B, Nmax), ascending, NaN padded
    theta_0: np.ndarray  # (B, Nmax)
    source_counts: np.ndarray  # (B, 2) estimated counts at scans 0 and 1


def start_up(snapshots: np.ndarray, design: SubspaceTrackerDesign, evd=None) -> StartUp:
    """Step 1: source count and angles from MUSIC at k = −1 and k = 0 (scans 0, 1).

    ``evd``: the ``(values, vectors)`` of those scans' sample covariances when the caller has
    them already (:func:`front_end` shares them with the subspaces of scans 0 and 1).
    """
    grid = angle_grid(design.grid_step_rad)
    first = snapshots[:, :STARTUP_SCANS]
    values, vectors = eigen_decomposition(sample_covariance(first)) if evd is None else evd
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


# --------------------------------------------------------------------------- step 2: subspace


def _batch_subspaces(X: np.ndarray, sel: np.ndarray, n: int, past: np.ndarray, sub_err: np.ndarray,
                     batch: np.ndarray | None = None) -> None:
    """The batch EVD of every tracked scan (scan ≥ 2) of a group of runs and the largest
    principal angle between it and PAST's W (``subspace_error_rad``, written into ``sub_err``).

    :data:`FRONT_END_BLOCK_RUNS` runs at a time, in double precision: the covariances and full
    eigenvector stacks stay a few MB at any number of runs (every run is its own problem, so the
    blocks give the same numbers as one batch). With ``batch`` given (``subspace="batch"``)
    the leading eigenvectors are also written there, for the filters to track. The blocks are
    independent (each writes its own rows): a replay runs them on its cores at once
    (:func:`trackreplay.batched_linalg.over_blocks`, the same bits).
    """
    def one_block(first: int) -> None:
        rows = sel[first:first + FRONT_END_BLOCK_RUNS]
        part = slice(first, first + len(rows))
        block = _runs(X, rows)[:, STARTUP_SCANS:].astype(complex)
        vectors = batch_signal_subspace(block, n)[0]
        if batch is not None:
            batch[part, STARTUP_SCANS:] = vectors
        sub_err[rows, STARTUP_SCANS:] = largest_principal_angle(past[part, STARTUP_SCANS:], vectors,
                                                                b_orthonormal=True)

    over_blocks(one_block, range(0, len(sel), FRONT_END_BLOCK_RUNS))


@dataclass
class FrontEnd:
    """What both innovation strategies share: the start-up and, per group of runs with the same
    N, the subspace sequence the filters use."""

    start: StartUp
    groups: list  # [(run indices, N, subspaces (B_n, K, M, N))]
    subspace_error: np.ndarray  # (B, K) largest principal angle, PAST vs batch EVD
    n_sensors: int


def _runs(X: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """``X[rows]``, as a view when the rows are consecutive (the usual case: one N for all runs),
    so that nothing is copied before the per-scan conversions."""
    if rows.size and rows[-1] - rows[0] == rows.size - 1:
        return X[rows[0]:rows[-1] + 1]
    return X[rows]


def _leading(values: np.ndarray, vectors: np.ndarray, n: int):
    """The ``n`` leading eigenpairs, largest first, as copies (the full stacks can be freed)."""
    return (np.ascontiguousarray(vectors[..., ::-1][..., :n]), np.ascontiguousarray(values[..., ::-1][..., :n]))


def front_end(snapshots: np.ndarray, design: SubspaceTrackerDesign) -> FrontEnd:
    """Steps 1–2 for every run: start-up, then PAST (or batch EVD) per group of equal N.

    Each scan's sample covariance is decomposed once: scans 0 and 1 serve both the start-up
    and the subspaces; PAST runs from scan 0's EVD over :data:`PAST_BLOCK_RUNS` runs at a time,
    then the batch EVD of the other scans gives the subspace error (:func:`_batch_subspaces`;
    with ``subspace="batch"`` also the subspaces the filters track).
    """
    if design.subspace not in SUBSPACES:
        raise ValueError(f"unknown subspace tracker {design.subspace!r} (have: {', '.join(SUBSPACES)})")
    X = np.asarray(snapshots)
    B, K, M = X.shape[:3]
    head = X[:, :STARTUP_SCANS].astype(complex, copy=False)
    head_values, head_vectors = eigen_decomposition(sample_covariance(head))
    init = start_up(head, design, (head_values, head_vectors))
    sub_err = np.full((B, K), np.nan)
    fe = FrontEnd(init, [], sub_err, M)
    for n in np.unique(init.n_tracks):
        if n == 0:
            continue
        n = int(n)
        sel = np.flatnonzero(init.n_tracks == n)
        head_batch, head_lam = _leading(head_values[sel], head_vectors[sel], n)
        past = np.empty((len(sel), K, M, n), dtype=complex)
        batch = np.empty_like(past) if design.subspace == "batch" else None
        past[:, 0], P = initial_state(head_batch[:, 0], head_lam[:, 0], design.forgetting)
        if batch is not None:
            batch[:, :STARTUP_SCANS] = head_batch
        # every run of a block in one PAST pass: the work per snapshot is a handful of
        # element-wise operations, whose cost per call is amortised over the block's runs; the
        # blocks are independent (a replay runs them on its cores at once, the same bits)
        def past_block(first: int, sel=sel, past=past, P=P) -> None:
            rows = sel[first:first + PAST_BLOCK_RUNS]
            part = slice(first, first + len(rows))
            past[part, 1:], _ = past_scans(past[part, 0], P[part], _runs(X, rows)[:, 1:], design.forgetting)

        over_blocks(past_block, range(0, len(sel), PAST_BLOCK_RUNS))
        sub_err[sel, :STARTUP_SCANS] = largest_principal_angle(past[:, :STARTUP_SCANS], head_batch,
                                                               b_orthonormal=True)
        _batch_subspaces(X, sel, n, past, sub_err, batch)
        fe.groups.append((sel, n, past if batch is None else batch))
    return fe


# the last front end computed, as one tuple (weak reference to its snapshots, key, value): a tuple
# is read and replaced whole, so no lock is needed (a second thread at worst recomputes one)
_MEMO = [None]


def _forget(ref) -> None:
    memo = _MEMO[0]
    if memo is not None and memo[0] is ref:
        _MEMO[0] = None


def shared_front_end(snapshots: np.ndarray, design: SubspaceTrackerDesign) -> FrontEnd:
    """:func:`front_end`, computed once for consecutive trackers on the same snapshots.

    Only a read-only array is remembered (the stage decodes one; its values cannot change
    between two trackers), by a weak reference: the memo dies with the array.
    """
    key = design.front_end_key()
    if not isinstance(snapshots, np.ndarray) or snapshots.flags.writeable:
        return front_end(snapshots, design)
    memo = _MEMO[0]
    if memo is not None and memo[0]() is snapshots and memo[1] == key:
        return memo[2]
    value = front_end(snapshots, design)
    _MEMO[0] = (weakref.ref(snapshots, _forget), key, value)
    return value


# --------------------------------------------------------------------------- steps 3–5: filters


def _innovation_in_blocks(innovation_fn, W: np.ndarray, theta_pred: np.ndarray, spacing_wavelengths: float):
    """``innovation_fn(W, θ̂, d/λ)`` over :data:`INNOVATION_BLOCK_RUNS` runs at a time.

    Every run is its own problem (the same numbers as one call); the kernels' temporaries (Ryu's
    (2M × (2N+1)) matrix per target, the M × M projectors) then stay in cache and in reused
    memory: over 1,000 runs at once they were fresh pages at every scan. A replay runs the
    blocks on its cores at once (:func:`trackreplay.batched_linalg.over_blocks`, the same bits).
    """
    if len(W) <= INNOVATION_BLOCK_RUNS:
        return innovation_fn(W, theta_pred, spacing_wavelengths)
    out = np.empty(theta_pred.shape)

    def one_block(first: int) -> None:
        part = slice(first, first + INNOVATION_BLOCK_RUNS)
        out[part] = innovation_fn(W[part], theta_pred[part], spacing_wavelengths)

    over_blocks(one_block, range(0, len(W), INNOVATION_BLOCK_RUNS))
    return out


def _track_group(subspaces, theta_minus1, theta_0, design: SubspaceTrackerDesign, strategy: str,
                 instant_offset_s: np.ndarray | None = None) -> dict:
    """Steps 3–5 for a group of runs with the same number of tracks ``n`` (outputs (B, K, n, ...)).

    ``instant_offset_s`` (K,) δ_k: scan k's subspace describes the scene δ_k after its time
    stamp, so the bearing it gives is θ + δ_k θ̇ (``H = [1, δ_k]``), and the angular innovation
    is taken about that prediction; None is the paper's ``H = [1, 0]``.
    """
    B, K, M, n = subspaces.shape
    F, Q, H, R = design.model()
    innovation_fn = INNOVATIONS[strategy]
    x, P = two_point_start(theta_minus1, theta_0, design.scan_period_s, np.sqrt(design.innovation_variance))  # (B, n, 2)
    nan = np.nan
    out = {
        "state": np.full((B, K, n, 2), nan), "covariance": np.full((B, K, n, 2, 2), nan),
        "innovation": np.full((B, K, n, 1), nan), "innovation_covariance": np.full((B, K, n, 1, 1), nan),
        "gain": np.full((B, K, n, 2, 1), nan), "predicted_rad": np.full((B, K, n), nan),
        "flags": np.zeros((B, K, n), np.uint16),
    }
    out["state"][:, 0, :, 0] = theta_minus1  # k = −1: an angle, no rate yet
    out["state"][:, 1] = x
    out["covariance"][:, 1] = P
    out["flags"][:, :STARTUP_SCANS] = vocab.INITIALISING
    out["flags"][:, 0] |= vocab.NOT_ESTIMATED
    # MUSIC's start-up is the confirmation; a track ends when its bearing leaves the field
    field = design.field_rad
    life = TrackLife((B, n), ending=EndingRule(field=(-field, field), max_coasted_scans=design.max_coasted_scans))
    life.start(np.ones((B, n), bool), confirmed=True)
    for k in range(STARTUP_SCANS, K):
        x, P = kf_predict(x, P, F, Q)
        out["predicted_rad"][:, k] = x[..., 0]
        measured_at = x[..., 0]
        if instant_offset_s is not None:
            H = np.array([[1.0, float(instant_offset_s[k])]])
            measured_at = x[..., 0] + instant_offset_s[k] * x[..., 1]
        dtheta = _innovation_in_blocks(innovation_fn, subspaces[:, k], measured_at, design.spacing_wavelengths)
        gain, S = kalman_gain(P, H, R)
        ok = np.isfinite(dtheta)
        x_new, P_new = apply_gain(x, P, gain, np.where(ok, dtheta, 0.0)[..., None], H, R)
        x = np.where(ok[..., None], x_new, x)
        P = np.where(ok[..., None, None], P_new, P)
        out["state"][:, k] = x
        out["covariance"][:, k] = P
        out["innovation"][:, k, :, 0] = dtheta
        out["innovation_covariance"][:, k] = S
        out["gain"][:, k] = gain
        _, ending = life.step(ok, x[..., 0])
        flags = np.where(ok, 0, vocab.COASTED).astype(np.uint16)
        gone = ~life.alive
        if gone.any():  # ended here (DELETED) or before: an ended track's prediction runs on, unreported
            flags = np.where(ending, vocab.NO_TRACK | vocab.DELETED, np.where(gone, vocab.NO_TRACK, flags))
            for key in ("state", "covariance", "innovation", "innovation_covariance", "gain", "predicted_rad"):
                out[key][:, k][gone] = np.nan
        out["flags"][:, k] = flags
    return out


def innovation_flops(strategy: str, n_sensors: int, n_targets: int) -> dict:
    """Cost of one scan's innovation for N targets and M sensors (the paper's section IV).

    Returns ``model`` (the paper's analytic count), ``counted`` (what our kernel executes,
    steering vectors excluded: both strategies build the same â, b̂ and the paper does not count
    them), ``steering`` (those steering vectors) and ``steps`` (counted FLOPs per step).
    """
    steps = _counted_flops_memo(strategy, n_sensors, n_targets)  # counted_flops, once per shape
    return {"model": int(ANALYTIC[strategy](n_sensors, n_targets)),
            "counted": int(sum(v for k, v in steps.items() if k != "steering")),
            "steering": int(steps["steering"]), "steps": steps}


def track_bearings(snapshots: np.ndarray, design: SubspaceTrackerDesign, strategy: str = "proposed") -> dict:
    """Run the whole tracker with one innovation strategy over all Monte Carlo runs.

    Parameters
    ----------
    snapshots : ndarray, complex, shape (B, K, M, Ns)
        Snapshot blocks per run and scan (complex, finite, N ≤ M − 1, Ns ≥ N).
    design : SubspaceTrackerDesign
    strategy : str
        Innovation strategy, a key of :data:`trackreplay.cores.array.angular_innovation.INNOVATIONS`.

    Returns
    -------
    dict of ndarray
        The outputs listed in the module docstring, each ``(B, K, ...)``.
    """
    if strategy not in INNOVATIONS:
        raise ValueError(f"unknown innovation strategy {strategy!r} (have: {', '.join(INNOVATIONS)})")
    shape = np.shape(snapshots)
    if len(shape) != 4:
        raise ValueError(f"snapshots must be (runs, scans, sensors, snapshots), got shape {shape}")
    B, K, M, Ns = shape
    if design.n_sources > min(M - 1, Ns):
        raise ValueError(f"n_sources = {design.n_sources} exceeds M − 1 = {M - 1} or Ns = {Ns}")
    fe = shared_front_end(snapshots, design)
    # one slot at least: where no run found a source the outputs hold one empty (NO_TRACK) slot,
    # which every reader takes, rather than none
    width = max(fe.start.theta_0.shape[1], 1)
    nan = np.nan
    whole = len(fe.groups) == 1 and len(fe.groups[0][0]) == B and fe.groups[0][1] == width
    out = {} if whole else {  # one group of every run and all slots: its arrays are the outputs
        "state": np.full((B, K, width, 2), nan), "covariance": np.full((B, K, width, 2, 2), nan),
        "innovation": np.full((B, K, width, 1), nan), "innovation_covariance": np.full((B, K, width, 1, 1), nan),
        "gain": np.full((B, K, width, 2, 1), nan), "predicted_rad": np.full((B, K, width), nan),
        "flags": np.full((B, K, width), vocab.NO_TRACK, np.uint16),
    }
    flops = {key: np.full((B, K), nan) for key in ("innovation_flops_model", "innovation_flops_counted",
                                                   "steering_flops_counted")}
    offset = (subspace_instant_offset(design.subspace, design.forgetting, design.scan_period_s, Ns, K)
              if design.align_subspace_instant else None)
    for sel, n, subspaces in fe.groups:
        part = _track_group(subspaces, fe.start.theta_minus1[sel, :n], fe.start.theta_0[sel, :n], design, strategy,
                            offset)
        if whole:
            out = part
        else:
            for key, value in part.items():
                out[key][sel, :, :n] = value
        cost = innovation_flops(strategy, M, n)
        for key, name in (("innovation_flops_model", "model"), ("innovation_flops_counted", "counted"),
                          ("steering_flops_counted", "steering")):
            flops[key][sel, STARTUP_SCANS:] = cost[name]
    out.update(flops)
    # fixed slots, never restarted: slot j is track j wherever it holds one (flags without NO_TRACK)
    held = (out["flags"].astype(np.int64) & vocab.NO_TRACK) == 0
    out["track_id"] = np.where(held, np.arange(width, dtype=np.int64), np.int64(-1))
    out["n_tracks"] = np.broadcast_to(fe.start.n_tracks[:, None], (B, K)).astype(np.int32)
    out["source_count"] = np.broadcast_to(fe.start.source_counts[:, 1][:, None], (B, K)).astype(np.int32)
    out["subspace_error_rad"] = fe.subspace_error.copy()
    return out


def music_waterfall(snapshots: np.ndarray, n_sources, spacing_wavelengths: float, grid_step_rad: float):
    """MUSIC spectrum of every scan of one run ``(K, M, Ns)`` → ``(grid (G,), spectrum (K, G))``."""
    grid = angle_grid(grid_step_rad)
    _, vectors = eigen_decomposition(sample_covariance(np.asarray(snapshots).astype(complex, copy=False)))
    return grid, music_spectrum(vectors, np.maximum(n_sources, 1), grid, spacing_wavelengths)


# --------------------------------------------------------------------------- the trackers

#: the finest MUSIC start-up grid (0.001°: 180,001 angles; the start-up's bearing then stands far
#: below any array's resolution)
MIN_MUSIC_GRID_STEP_DEG = 1e-3


PARAMS = (
    Param("scan_period_s", None, "s", "scan period T of the constant-angular-velocity model", low=0.0),
    Param("process_noise_q_deg2", None, "deg²/s³", "q of Q = q [[T³/3, T²/2], [T²/2, T]] (paper: \"q = 1°\")",
          low=0.0),
    Param("innovation_variance_deg2", None, "deg²", "σ_z², variance of the angular innovation (paper: \"4°\")",
          low=0.0),
    Param("past_forgetting", None, "", "PAST forgetting factor β per snapshot, 0 < β ≤ 1"),
    Param("source_count_criterion", None, "", "source count at start-up: mdl | aic"),
    Param("n_sources", None, "", "number of targets; 0 estimates it at start-up (≤ M − 1)", low=0, closed=True),
    Param("music_grid_step_deg", None, "deg", "MUSIC angle grid step at start-up (≥ 0.001°: a finer grid holds "
          "more than 180,000 angles a scan, memory without a finer start)", low=MIN_MUSIC_GRID_STEP_DEG, closed=True),
    Param("subspace_tracker", None, "", "past (the paper) | batch (per-scan EVD, reference)"),
    Param("max_coasted_scans", 3, "scans", "a track without a usable innovation this many scans in a row is deleted "
          "(0: never; a track whose bearing leaves the field is always deleted)", low=-1),
    Param("align_subspace_instant", False, "", "measure each bearing at the instant the scan's subspace describes "
          "(PAST's memory reaches back before the scan's time stamp); false: the paper as printed (a WAV "
          "recording's conversion records true)"),
)


def check_design(design: dict) -> None:
    """Refuse choices the tracker does not know, and a forgetting factor outside (0, 1] (open at one
    end only, which a :class:`Param`'s bounds do not say) (:class:`InputError`, one line); the other
    numbers' ranges are their Params', checked when the tracker is built."""
    crit = str(design["source_count_criterion"]).lower()
    if crit not in CRITERIA:
        raise InputError(f"source_count_criterion must be mdl or aic, got {crit!r}")
    if design["subspace_tracker"] not in SUBSPACES:
        raise InputError(f"subspace_tracker must be one of {', '.join(SUBSPACES)}, got {design['subspace_tracker']!r}")
    if not 0 < design["past_forgetting"] <= 1:
        raise InputError("past_forgetting must be in (0, 1]")


class _AngularInnovationTracker(Tracker):
    """MUSIC start-up → PAST → per-target Kalman filters with one angular-innovation strategy
    (the class's ``name``, a key of :data:`trackreplay.cores.array.angular_innovation.INNOVATIONS`)."""

    family = "array"
    form = "batch"
    params = PARAMS

    def __init__(self, **design):
        super().__init__(**design)
        check_design(self.design)
        deg2 = np.deg2rad(1.0) ** 2
        self.tracker_design = SubspaceTrackerDesign(
            scan_period_s=float(self.scan_period_s), process_noise_q=float(self.process_noise_q_deg2) * deg2,
            innovation_variance=float(self.innovation_variance_deg2) * deg2, forgetting=float(self.past_forgetting),
            source_count=str(self.source_count_criterion).lower(), n_sources=int(self.n_sources),
            grid_step_rad=np.deg2rad(float(self.music_grid_step_deg)), subspace=str(self.subspace_tracker),
            max_coasted_scans=int(self.max_coasted_scans), align_subspace_instant=bool(self.align_subspace_instant))

    def track(self, snapshots: ArraySnapshots) -> dict:
        design = dataclasses.replace(self.tracker_design, spacing_wavelengths=float(snapshots.spacing_wavelengths))
        return track_bearings(snapshots.snapshots, design, self.name)

    @classmethod
    def innovation_flops(cls, n_sensors: int, n_targets: int) -> dict:
        """FLOPs of this tracker's innovation for one scan (see :func:`innovation_flops`)."""
        return innovation_flops(cls.name, n_sensors, n_targets)


class Proposed(_AngularInnovationTracker):
    """The closed-form angular innovation (Ryu, Lee & Lee 2001, eqs. (7), (11)–(13))."""

    name = "proposed"
    label = "proposed"


class Ryu(_AngularInnovationTracker):
    """Ryu et al. (1999)'s (2N+1)-dimensional least-squares innovation (the paper's reference)."""

    name = "ryu"
    label = "Ryu 1999"


TRACKERS = (Proposed, Ryu)
