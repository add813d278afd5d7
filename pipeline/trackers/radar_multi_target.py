"""Multi-target radar trackers: global nearest neighbour (GNN) and JPDA over range-bearing plots.

Tracks are born, confirmed, coasted and deleted among clutter, any number at a time. One scan
loop (:func:`track_multi_target`) serves both; what differs is a small **association strategy**:

``gnn``      one optimal one-to-one assignment of tracks to plots per scan inside the χ² gates,
             "not detected" an option for every track (Blackman & Popoli 1999, ch. 6;
             :func:`trackreplay.cores.association.gnn.pair_assignment`); a Kalman update with the
             assigned plot.
``jpda_mt``  joint probabilistic data association (Fortmann, Bar-Shalom & Scheffe 1983): the
             marginal association probabilities of every confirmed track and gated plot from the
             project's one JPDA core (:func:`trackreplay.cores.association._jpda_fast.pair_association_probabilities`:
             exact per cluster of tracks sharing plots, from the gated pairs), then the PDA update
             (:func:`trackreplay.cores.association.jpda.pda_update_gaussian`); tentative tracks take,
             by nearest neighbour, only plots outside every confirmed gate (a separate initiator).

Both see a scan as the track–plot pairs inside the gates
(:func:`trackreplay.cores.association.gating.gate_pairs`), never as a dense track × plot matrix:
hundreds of tracks meet hundreds of plots in a busy scan, yet each gates a few, and every run of
a Monte Carlo set is one more block of the same sparse problem.

Each track is filtered by a **per-track filter** object
(:class:`trackreplay.cores.filters.track_filter.PolarConstantVelocityEKF`: nearly-constant-velocity
motion, range-bearing EKF), which owns prediction, predicted measurement, innovation covariance
and update; the gate is the χ² quantile of the innovation's two degrees of freedom.

Track life is the shared mechanism of :mod:`trackreplay.cores.association.track_management`: a plot
that no track claimed (GNN: not assigned; JPDA: inside no confirmed gate and not taken by a
tentative track) starts a tentative track
(``INITIALISING``) at the plot with a zero-mean velocity prior; it is confirmed when
``confirm_hits`` of its first ``confirm_window`` scans had a plot in its gate, and deleted
(``DELETED | NO_TRACK``) after ``max_coasted_scans`` scans in a row without one, or at once when it
can no longer be confirmed. Every track has an identity (``track_id``) never reused within a run;
tracks live in **slots** (the output's track axis), and a slot freed at scan k can hold a new
track from scan k + 1 on. See docs/trackers.md, "Multi-target trackers".
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trackreplay import vocabulary as vocab
from trackreplay.cores.association.gating import GatedPairs, gate_pairs
from trackreplay.cores.association.gnn import pair_assignment
from trackreplay.cores.association._jpda_fast import pair_association_probabilities
from trackreplay.cores.association.jpda import gaussian_likelihood_ratio, pda_update_gaussian
from trackreplay.cores.association.track_management import ConfirmationRule, EndingRule, TrackLife
from trackreplay.cores.filters.kalman import kalman_gain
from trackreplay.cores.filters.track_filter import (
    PolarConstantVelocityEKF,
    PolarConstantVelocityUKF,
    TrackFilter,
    wrap_angle,
)
from trackreplay.trackers.interface import Param, Tracker

#: smallest clutter density (plots per metre and radian) the JPDA weighs plots against: a
#: scenario without clutter still has a finite likelihood ratio
MIN_CLUTTER_DENSITY = 1e-12
#: slots a run's track arrays start with; they double when the tracks alive outgrow them
INITIAL_SLOTS = 8


@dataclass(frozen=True)
class MultiTargetDesign:
    """Design of a multi-target tracker (SI units, radians).

    Attributes
    ----------
    track_filter : TrackFilter
        The per-track filter.
    detection_probability : float
        P_D of a target per scan.
    clutter_density : float
        Clutter plots per unit of measurement space (per metre of range and radian of bearing).
    gate_chi2 : float
        A plot is in a track's gate when ``νᵀ S⁻¹ ν`` is at most this.
    gate_probability : float
        P_G: the chance that a target's own plot falls inside the gate.
    confirmation, ending : ConfirmationRule, EndingRule
        Track management (M-of-N confirmation; deletion after coasting).
    max_cluster_tracks : int
        Largest cluster of tracks the JPDA solves exactly as a whole (bigger ones are cut and
        flagged ``CLUSTER_SPLIT``).
    """

    track_filter: TrackFilter
    detection_probability: float
    clutter_density: float
    gate_chi2: float
    gate_probability: float
    confirmation: ConfirmationRule
    ending: EndingRule
    max_cluster_tracks: int = 12


# --------------------------------------------------------------------------- association strategies


@dataclass(frozen=True)
class ScanAssociation:
    """What an association strategy returns for one scan.

    ``x``, ``P``: posterior of every slot (prediction where coasted; a strategy updates the
    prediction arrays it is given in place, they are the loop's own); ``hit`` (R, S): a plot was
    used; ``claimed`` (R, W): plots a track took (the rest may start tracks); ``innovation``
    (R, S, m) and ``innovation_covariance`` (R, S, m, m) of the update, NaN where none or where
    it is not a single plot's (the JPDA's combined innovation is not Gaussian with covariance
    S); ``flags`` (R, S) extra flag bits."""

    x: np.ndarray
    P: np.ndarray
    hit: np.ndarray
    claimed: np.ndarray
    innovation: np.ndarray | None
    innovation_covariance: np.ndarray | None
    flags: np.ndarray


def _det(S):
    """``|S|`` of every track's innovation covariance (1 where not positive: an empty slot)."""
    if S.shape[-1] == 2:
        det = S[..., 0, 0] * S[..., 1, 1] - S[..., 0, 1] * S[..., 0, 1]
    else:
        det = np.linalg.det(S)
    return np.where(det > 0, det, 1.0)


class GlobalNearestNeighbour:
    """GNN: the assignment minimising Σ νᵀS⁻¹ν + ln|S| over the pairs it makes plus, for a track
    left without a plot, the gate plus ln|S| (so a pair is taken only inside the gate)."""

    name = "gnn"
    reports_innovation = True

    def associate(self, design: MultiTargetDesign, x, P, H, S, pairs: GatedPairs, tentative) -> ScanAssociation:
        return _nearest_neighbour_update(design, x, P, H, S, pairs, pairs.inside)


def _nearest_neighbour_update(design: MultiTargetDesign, x, P, H, S, pairs: GatedPairs, usable) -> ScanAssociation:
    """The GNN assignment of the ``usable`` pairs and the Kalman update of the tracks that took a plot."""
    f = design.track_filter
    R, slots = x.shape[:2]
    n, m = x.shape[-1], f.measurement_size
    # every (run, slot) as one flat track index and every pair as one flat index: gathers along one
    # axis cost a fraction of indexing by (run, slot, k) arrays, for the same elements in the same order
    x, P = np.ascontiguousarray(x), np.ascontiguousarray(P)   # (views unless they were not already)
    log_det = np.log(_det(S)).reshape(-1)
    pair = np.flatnonzero(usable)
    track = pair // usable.shape[-1]                           # run · slots + slot
    run = track // slots
    plot = pairs.plot.reshape(-1)[pair]
    # the run axis folded into the track and plot indices: one problem, runs never sharing a plot
    chosen = pair_assignment(pairs.squared_distance.reshape(-1)[pair] + log_det[track], track,
                             run * pairs.plots + plot, design.gate_chi2 + log_det)
    pair, track, run, plot = pair[chosen], track[chosen], run[chosen], plot[chosen]
    hit = np.zeros(R * slots, bool)
    hit[track] = True
    hit = hit.reshape(R, slots)
    claimed = np.zeros(R * pairs.plots, bool)
    claimed[run * pairs.plots + plot] = True
    claimed = claimed.reshape(R, pairs.plots)
    innovation = np.full(x.shape[:-1] + (m,), np.nan)
    if track.size == 0:  # every track coasts
        return ScanAssociation(x, P, hit, claimed, innovation, np.full(S.shape, np.nan), np.zeros(hit.shape, np.uint32))
    picked = pairs.innovation.reshape(-1, m)[pair]              # (hits, m): each hit track's plot
    # the update of the tracks that took a plot only (the others coast on their prediction)
    x_flat, P_flat = x.reshape(-1, n), P.reshape(-1, n, n)
    x_upd, P_upd, _ = f.update(x_flat[track], P_flat[track], H.reshape(-1, m, n)[track], S.reshape(-1, m, m)[track],
                               picked)
    x_flat[track], P_flat[track] = x_upd, P_upd  # in place: the loop's own prediction arrays
    innovation.reshape(-1, m)[track] = picked
    covariance = np.where(hit[..., None, None], S, np.nan)
    return ScanAssociation(x, P, hit, claimed, innovation, covariance, np.zeros(hit.shape, np.uint32))


class JointProbabilistic:
    """JPDA: marginal association probabilities per cluster from the one JPDA core, PDA update,
    for the confirmed tracks; tentative ones by nearest neighbour on the plots left over."""

    name = "jpda_mt"
    reports_innovation = False

    def associate(self, design: MultiTargetDesign, x, P, H, S, pairs: GatedPairs, tentative) -> ScanAssociation:
        # Confirmed tracks share the plots in their gates by JPDA; tentative tracks (hypotheses
        # from plots no track claimed, most of them clutter) take, by nearest neighbour, only
        # plots outside every confirmed gate, as a separate initiator would: they never pull a
        # confirmed track's probabilities, and clusters stay the size of real crossings.
        step = self._jpda(design, x, P, H, S, pairs, pairs.inside & ~tentative[..., None])
        free = ~step.claimed[np.arange(x.shape[0])[:, None, None], np.maximum(pairs.plot, 0)]
        starting = pairs.inside & tentative[..., None] & free
        if not starting.any():
            return step
        nn = _nearest_neighbour_update(design, step.x, step.P, H, S, pairs, starting)
        return ScanAssociation(nn.x, nn.P, step.hit | nn.hit, step.claimed | nn.claimed, None, None, step.flags)

    def _jpda(self, design: MultiTargetDesign, x, P, H, S, pairs: GatedPairs, usable) -> ScanAssociation:
        """JPDA marginals of the ``usable`` pairs and the PDA update of their tracks."""
        f = design.track_filter
        R, slots = x.shape[:2]
        ratio = gaussian_likelihood_ratio(pairs.squared_distance, _det(S),
                                          design.detection_probability, design.clutter_density)
        run, slot, k = np.nonzero(usable)
        plot = pairs.plot[run, slot, k]
        # the run axis folded into the track and plot indices: one problem, runs never sharing a plot
        beta_flat, beta0_flat, split_flat = pair_association_probabilities(
            ratio[run, slot, k], run * slots + slot, run * pairs.plots + plot,
            np.full(R * slots, 1.0 - design.detection_probability * design.gate_probability),
            # the order in which a cluster too large to solve whole is cut: around the radar, by bearing
            np.arctan2(x[..., 1], x[..., 0]).ravel(), design.max_cluster_tracks)
        beta = np.zeros(usable.shape)
        beta[run, slot, k] = beta_flat
        beta0 = beta0_flat.reshape(R, slots)
        # every track with a plot in its gate takes the PDA update (weighted by its β); for its
        # life, a hit only when a plot is more likely than not its own: a lost track whose gate
        # has grown over clutter keeps coasting towards deletion instead of living on clutter
        in_gate = usable.any(axis=-1)
        hit = in_gate & (beta0 < 0.5)
        claimed = np.zeros((R, pairs.plots), bool)
        claimed[run, plot] = True
        flags = np.where(split_flat.reshape(R, slots), vocab.CLUSTER_SPLIT, 0).astype(np.uint32)
        if not in_gate.any():
            return ScanAssociation(x, P, hit, claimed, None, None, flags)
        run, slot = np.nonzero(in_gate)
        K, _ = kalman_gain(P[run, slot], H[run, slot], f.measurement_covariance(x), S[run, slot])
        x_upd, P_upd, _ = pda_update_gaussian(x[run, slot], P[run, slot], K, S[run, slot],
                                              pairs.innovation[run, slot], usable[run, slot], beta[run, slot],
                                              beta0[run, slot])
        x[run, slot], P[run, slot] = x_upd, P_upd  # in place: the loop's own prediction arrays
        return ScanAssociation(x, P, hit, claimed, None, None, flags)


ASSOCIATIONS = {a.name: a for a in (GlobalNearestNeighbour(), JointProbabilistic())}


# --------------------------------------------------------------------------- the scan loop


class _Slots:
    """The tracks of every run in slots: states, covariances, identities and their life."""

    def __init__(self, runs: int, design: MultiTargetDesign):
        n = design.track_filter.state_size
        self.x = np.zeros((runs, 0, n))
        self.P = np.zeros((runs, 0, n, n))
        self.ids = np.zeros((runs, 0), np.int64)
        self.next_id = np.zeros(runs, np.int64)
        self.life = TrackLife((runs, 0), design.confirmation, design.ending)
        self.grow(INITIAL_SLOTS)

    @property
    def count(self) -> int:
        return self.ids.shape[1]

    def grow(self, slots: int) -> None:
        """Room for at least ``slots`` tracks per run (empty slots added at the end)."""
        extra = slots - self.count
        if extra <= 0:
            return
        R, n = self.x.shape[0], self.x.shape[-1]
        # an empty slot holds a harmless state (1 m along x, unit covariance) so that the
        # filter's arithmetic on it stays finite; it is never reported
        self.x = np.concatenate([self.x, np.broadcast_to(np.eye(n)[0], (R, extra, n))], axis=1)
        self.P = np.concatenate([self.P, np.broadcast_to(np.eye(n), (R, extra, n, n))], axis=1)
        self.ids = np.concatenate([self.ids, np.full((R, extra), -1, np.int64)], axis=1)
        self.life.resize(self.count)

    def start(self, runs, z, track_filter: TrackFilter, free) -> np.ndarray:
        """Start one track per row of ``runs`` (sorted) from plot ``z`` in a free slot of its run.
        Returns the slots' mask ``(R, S)``."""
        R = self.x.shape[0]
        born = np.bincount(runs, minlength=R)
        need = int((born - free.sum(axis=1)).max(initial=0))
        if need > 0:
            self.grow(max(2 * self.count, self.count + need))
            free = np.concatenate([free, np.ones((R, self.count - free.shape[1]), bool)], axis=1)
        first = np.cumsum(born) - born
        rank = np.arange(runs.size) - first[runs]
        # the rank-th free slot of each run, lowest first: the free slots in run-major order
        _, free_slot = np.nonzero(free)
        first_free = np.cumsum(free.sum(axis=1)) - free.sum(axis=1)
        slots = free_slot[first_free[runs] + rank]
        x0, P0 = track_filter.start(z)
        self.x[runs, slots] = x0
        self.P[runs, slots] = P0
        self.ids[runs, slots] = self.next_id[runs] + rank
        self.next_id += born
        where = np.zeros(self.ids.shape, bool)
        where[runs, slots] = True
        self.life.start(where, hits=1, scans=1)
        return where


def track_multi_target(range_m, bearing_rad, counts, times, design: MultiTargetDesign, association) -> dict:
    """Track any number of targets through every scan of every run.

    Parameters
    ----------
    range_m, bearing_rad : ndarray (R, K, W)
        Plots, NaN-padded beyond ``counts``.
    counts : ndarray of int (R, K)
    times : ndarray (K,)
        Scan times (s), increasing.
    design : MultiTargetDesign
    association : GlobalNearestNeighbour or JointProbabilistic

    Returns
    -------
    dict
        ``state`` (R, K, S, 4), ``covariance`` (R, K, S, 4, 4), ``flags`` (R, K, S) uint32,
        ``track_id`` (R, K, S) (−1 in empty slots), and for the GNN ``innovation`` (R, K, S, 2)
        and ``innovation_covariance`` (R, K, S, 2, 2), with S the most slots any scan needed.
    """
    f = design.track_filter
    R, K = counts.shape
    history = _History(R, K, f.state_size)
    bearing_rad = wrap_angle(bearing_rad)  # a recording's bearings may run over [0, 2π) or beyond
    slots = _Slots(R, design)
    scans = []
    for k in range(K):
        w = int(counts[:, k].max(initial=0))
        z = np.stack([range_m[:, k, :w], bearing_rad[:, k, :w]], axis=-1)
        valid = np.arange(w) < counts[:, k, None]
        alive = slots.life.alive.copy()
        flags = np.zeros(alive.shape, np.uint32)
        innovation = covariance = None
        claimed = np.zeros((R, w), bool)
        ending = np.zeros(alive.shape, bool)
        if alive.any():
            # new tracks take the lowest free slots, so the live ones sit below the highest one
            # alive: the filter works on those, not on every slot a busier scan once needed
            top = int(np.flatnonzero(alive.any(axis=0))[-1]) + 1
            live = alive[:, :top]
            x, P = f.predict(slots.x[:, :top], slots.P[:, :top], float(times[k] - times[k - 1]))
            z_pred, H, S = f.predict_measurement(x, P)
            pairs = gate_pairs(f, z, valid, z_pred, S, design.gate_chi2, live)
            step = association.associate(design, x, P, H, S, pairs, slots.life.tentative[:, :top])
            # every slot below top takes its prediction or posterior: an empty one is never read
            # before a new track's start writes it
            slots.x[:, :top], slots.P[:, :top] = step.x, step.P
            hit = _pad(step.hit & live, alive.shape[1], False)
            flags |= _pad(np.where(live, step.flags, 0).astype(np.uint32), alive.shape[1], 0)
            claimed = step.claimed
            innovation = None if step.innovation is None else _pad(step.innovation, alive.shape[1], np.nan)
            covariance = None if step.innovation_covariance is None else _pad(step.innovation_covariance,
                                                                               alive.shape[1], np.nan)
            position_variance = slots.P[..., 0, 0] + slots.P[..., 1, 1]
            tentative, ending = slots.life.step(hit, slots.x[..., 0], position_variance)
            flags |= np.where(alive & ~hit & ~ending, vocab.COASTED, 0).astype(np.uint32)
        # plots no track claimed start tentative tracks, in slots free before this scan
        run, plot = np.nonzero(valid & ~claimed)
        free = ~alive
        if run.size:
            slots.start(run, z[run, plot], f, free)
        S_now = slots.count
        flags = _pad(flags, S_now, vocab.NO_TRACK)
        ending = _pad(ending, S_now, False)
        live = slots.life.alive
        flags |= np.where(live & slots.life.tentative, vocab.INITIALISING, 0).astype(np.uint32)
        flags |= np.where(~live, vocab.NO_TRACK, 0).astype(np.uint32)
        flags |= np.where(ending, vocab.DELETED, 0).astype(np.uint32)
        history.record(k, slots.x, slots.P)
        scans.append({
            "flags": flags,
            "track_id": np.where(live, slots.ids, -1),
            **({"innovation": _pad(innovation, S_now, np.nan),
                "innovation_covariance": _pad(covariance, S_now, np.nan)}
               if association.reports_innovation and innovation is not None else {}),
        })
        slots.ids = np.where(ending, -1, slots.ids)
    out = _stack_scans(scans, slots.count, association.reports_innovation)
    # the states and covariances of slots holding no track at a scan (recorded as they stood,
    # or never written) are NaN
    out["state"], out["covariance"] = history.state[:, :, :slots.count], history.covariance[:, :, :slots.count]
    empty = out["track_id"] < 0
    np.copyto(out["state"], np.nan, where=empty[..., None])
    np.copyto(out["covariance"], np.nan, where=empty[..., None, None])
    return out


class _History:
    """Every scan's slot states and covariances as they stand, written straight into
    ``(R, K, S, ...)`` buffers whose slot axis grows with the tracker's (doubling, as the slots
    do): one copy per scan, no stacking at the end. Entries a scan did not write belong to
    slots that held no track then; the caller sets them to NaN."""

    def __init__(self, runs: int, scans: int, n: int):
        self.state = np.empty((runs, scans, 0, n))
        self.covariance = np.empty((runs, scans, 0, n, n))

    def record(self, k: int, x, P) -> None:
        S = x.shape[1]
        if S > self.state.shape[2]:
            grown = max(S, 2 * self.state.shape[2])
            for name in ("state", "covariance"):
                old = getattr(self, name)
                new = np.empty(old.shape[:2] + (grown,) + old.shape[3:])
                # only the scans recorded so far: the rest of the old buffer was never written
                # (copying it all touched every page of both buffers, a sixth of the GNN's time
                # at 100 runs)
                new[:, :k, :old.shape[2]] = old[:, :k]
                setattr(self, name, new)
        self.state[:, k, :S] = x
        self.covariance[:, k, :S] = P


def _pad(a, slots: int, fill):
    """``a`` (R, S, ...) with slots added up to ``slots``, holding ``fill``."""
    if a is None or a.shape[1] >= slots:
        return a
    pad = np.full((a.shape[0], slots - a.shape[1]) + a.shape[2:], fill, dtype=a.dtype)
    return np.concatenate([a, pad], axis=1)


def _stack_scans(scans: list, slots: int, innovations: bool) -> dict:
    """Per-scan outputs of different slot counts as ``(R, K, S, ...)`` arrays."""
    R = scans[0]["flags"].shape[0] if scans else 0
    fills = {"flags": vocab.NO_TRACK, "track_id": -1, "innovation": np.nan, "innovation_covariance": np.nan}
    out = {}
    for key, fill in fills.items():
        if key.startswith("innovation") and not innovations:
            continue
        first = next((scan[key] for scan in scans if scan.get(key) is not None), None)
        tail = first.shape[2:] if first is not None else ((2,) if key == "innovation" else (2, 2))
        dtype = first.dtype if first is not None else float
        out[key] = np.full((R, len(scans), slots) + tail, fill, dtype)
        for k, scan in enumerate(scans):
            a = scan.get(key)
            if a is not None:  # (None: a scan before any track, nothing updated)
                out[key][:, k, :a.shape[1]] = a
    return out


# --------------------------------------------------------------------------- trackers


PARAMS = (
    Param("sigma_range_m", None, "m", "plot range noise the filter assumes"),
    Param("sigma_bearing_deg", None, "deg", "plot bearing noise the filter assumes"),
    Param("design_process_noise_m2ps3", 40.0, "m²/s³", "spectral density q of the white acceleration per axis "
          "the filters assume (above the truth's own where targets turn)", low=0.0),
    Param("detection_probability", 0.9, "", "P_D: chance that a target gives a plot in a scan", low=0.0, high=1.0001),
    Param("clutter_per_scan", 0.0, "plots", "mean number of clutter plots a scan over the surveillance region",
          low=-1e-12),
    Param("min_range_m", 1000.0, "m", "surveillance region: nearest range (clutter density)", low=-1e-12),
    Param("max_range_m", 50000.0, "m", "surveillance region: farthest range (clutter density)", low=0.0),
    Param("sector_half_width_deg", 60.0, "deg", "surveillance region: half width of the bearing sector", low=0.0,
          high=180.0001),
    Param("association_gate_probability", 0.9997, "", "P_G of the multi-target trackers' χ² gate (2 degrees of "
          "freedom): the chance that a target's own plot falls inside it", low=0.0, high=1.0),
    Param("initial_speed_sigma_mps", 150.0, "m/s", "velocity prior of a track started from one plot (std per axis)",
          low=0.0),
    Param("confirm_hits", 3, "scans", "M of M-of-N confirmation: a track is tentative until M of its first N "
          "scans (its start included) had a plot"),
    Param("confirm_window", 4, "scans", "N of M-of-N confirmation (a tentative track that cannot reach M is deleted)"),
    Param("max_coasted_scans", 5, "scans", "a track that coasts this many scans in a row is deleted"),
)


def clutter_density(design: dict) -> float:
    """Clutter plots per metre of range and radian of bearing: the mean count a scan spread
    uniformly over the region's range and bearing extent (the measurement space the filter
    weighs plots in)."""
    extent = (float(design["max_range_m"]) - float(design["min_range_m"])) * 2.0 * np.deg2rad(
        float(design["sector_half_width_deg"]))
    return max(float(design["clutter_per_scan"]) / max(extent, 1e-300), MIN_CLUTTER_DENSITY)


class _MultiTargetTracker(Tracker):
    """A multi-target radar tracker: :func:`track_multi_target` with one association strategy
    and one per-track filter class."""

    family = "radar"
    targets = "many"
    params = PARAMS
    association = ""                         # a key of ASSOCIATIONS
    track_filter = PolarConstantVelocityEKF  # the per-track filter class

    def __init__(self, **design):
        super().__init__(**design)
        from trackreplay.errors import InputError

        if int(self.confirm_hits) < 1 or int(self.confirm_window) < int(self.confirm_hits):
            raise InputError(f"{self.name}: confirmation needs 1 ≤ confirm_hits ≤ confirm_window (got "
                             f"{self.confirm_hits} of {self.confirm_window})")
        if float(self.max_range_m) <= float(self.min_range_m):
            raise InputError(f"{self.name}: max_range_m ({self.max_range_m:g}) must exceed min_range_m "
                             f"({self.min_range_m:g})")
        p_gate = float(self.association_gate_probability)
        self.tracker_design = MultiTargetDesign(
            track_filter=self.track_filter(
                process_noise_m2ps3=float(self.design_process_noise_m2ps3), sigma_range_m=float(self.sigma_range_m),
                sigma_bearing_rad=float(np.deg2rad(self.sigma_bearing_deg)),
                initial_speed_sigma_mps=float(self.initial_speed_sigma_mps)),
            detection_probability=min(float(self.detection_probability), 1.0),
            clutter_density=clutter_density(self.design),
            gate_chi2=float(-2.0 * np.log1p(-p_gate)),  # χ² quantile of 2 degrees of freedom
            gate_probability=p_gate,
            confirmation=ConfirmationRule(int(self.confirm_hits), int(self.confirm_window)),
            ending=EndingRule(max_coasted_scans=int(self.max_coasted_scans)))

    def track(self, plots):
        return track_multi_target(plots.range_m, plots.bearing_rad, plots.counts, plots.times_s,
                                  self.tracker_design, ASSOCIATIONS[self.association])


class GnnTracker(_MultiTargetTracker):
    """Global nearest neighbour: an optimal one-to-one assignment per scan, EKF per track."""

    name = "gnn"
    label = "GNN"
    association = "gnn"


class JpdaTracker(_MultiTargetTracker):
    """JPDA: exact marginal association probabilities per cluster, PDA update, EKF per track."""

    name = "jpda_mt"
    label = "JPDA"
    association = "jpda_mt"


class UkfGnnTracker(_MultiTargetTracker):
    """GNN with an unscented Kalman filter per track: the per-track filter is the only change
    (:class:`~trackreplay.cores.filters.track_filter.PolarConstantVelocityUKF`); the loop is the same."""

    name = "ukf"
    label = "UKF (GNN)"
    association = "gnn"
    track_filter = PolarConstantVelocityUKF
    # the GNN again with another filter: on a radar's long-range plots it follows the EKF GNN
    # closely, so a replay runs it when named (--trackers gnn,jpda_mt,ukf), not by default
    runs_by_default = False


TRACKERS = (GnnTracker, JpdaTracker, UkfGnnTracker)
