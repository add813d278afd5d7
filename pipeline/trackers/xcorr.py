"""Park, Ryu & Lee (1994): JPDA and amplitude-aided JPDA_A for bearing tracks of
cross-correlation peaks (see ``docs/papers/xcorr.md``).

Each scan a correlator lists peaks ``(z_p, z_a)``: bearing and amplitude. Every track is a
``[θ, θ̇]`` filter (rad, rad/s) with the continuous white-noise acceleration model of eq. 8b;
the peaks in each track's gate are weighted by the exact JPDA marginals β (appendix eqs.
A.1–A.6) and combined by the PDA update (eq. A.7). JPDA_A multiplies each peak's likelihood
ratio by the ratio of its amplitude's density as a true peak to that as clutter (eq. A.5); with
``amplitude_tracking`` the expected amplitude ẑ_a follows eq. 9. The numerics are the one
core :mod:`trackreplay.cores.association.jpda`; this module picks its design values, starts the
tracks and exposes the two variants as trackers:

``jpda``    position likelihoods only (Fortmann, Bar-Shalom & Scheffe 1983);
``jpda_a``  position and amplitude likelihoods (the paper's proposal).

Track start (design ``track_start``):

``truth``      the true bearing and bearing rate at scan 0 (``measurements.truth_bearing_rad``,
               ``measurements.truth_rate_radps``) with the covariance P(0|0) of eq. 8c; the
               default, because the paper's Fig. 8 measures association, not track initiation.
               Needs ground truth, so it is for simulated and labelled data only.
``two-point``  two-point differencing of the labelled true peaks (``origin``) of scans 0 and 1,
               whose covariance *is* eq. 8c; filtering starts at scan 2.
``peaks``      a one-point start from unlabelled peaks, as a recording has them: the ``n``
               strongest peaks above the amplitude threshold at scan 0 (the strongest to the
               role with the largest expected amplitude), zero rate with the prior
               ``start_rate_sigma_deg_s``; filtering starts at scan 1
               (:func:`strongest_start_peaks`, :func:`one_point_start`). A slot without a
               peak to start from stays empty.
``auto``       ``truth`` when the data have it, else ``peaks`` (the default).

A track started from peaks is tentative (``INITIALISING``) until ``confirm_hits`` of its first
``confirm_window`` scans had a peak in its gate, and is deleted if it cannot get there; every
track ends when it leaves the field by more than half a gate or coasts ``max_coasted_scans``
scans in a row (:mod:`trackreplay.cores.association.track_management`).

Any number of tracks T (the targets of the data); their strength roles are the design's
``roles`` pattern (or ``pair``'s) cycled over them (:mod:`trackreplay.trackers.xcorr_peak_roles`).

Outputs (:data:`trackreplay.vocabulary.OUTPUTS`): ``state`` (R, K, T, 2), ``covariance``,
``track_id`` (R, K, T: slot j is track j wherever it holds one, −1 elsewhere; a slot is never
restarted),
``flags`` (``NO_TRACK | INITIALISING`` before the start scan, whose state is NaN;
``INITIALISING`` at the start scan, which holds the start values; then ``COASTED`` where no
peak fell in the gate and ``CLUSTER_SPLIT`` where a cluster was cut), ``innovation`` (the
combined innovation ν̄), ``innovation_covariance``, ``gain``, and the paper's diagnostics
``beta0``, ``beta_top``, ``beta_index``, ``strength``, ``n_gated``, ``gate_center``.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from trackreplay import vocabulary as vocab
from trackreplay.cores.association.jpda import STRATEGIES, BearingTrackerDesign
from trackreplay.cores.association.jpda_tracking import scans_from_padded, track_bearing_peaks
from trackreplay.cores.association.track_management import ConfirmationRule, EndingRule
from trackreplay.cores.filters.kalman import two_point_start
from trackreplay.errors import InputError, check_all
from trackreplay.trackers.interface import BearingPeaks, Param, Tracker
from trackreplay.trackers.xcorr_peak_roles import roles_for, track_roles

PEAKS = vocab.CHANNELS["xcorr_peaks"]
TRUTH = vocab.CHANNELS["xcorr_truth"]
TRACK_STARTS = ("auto", "truth", "two-point", "peaks")

PARAMS = (
    Param("scan_period_s", None, "s", "scan period T of the motion model (eq. 8b)"),
    Param("gate_deg", None, "deg", "gate width V: a window |ν| ≤ V/2 around each predicted bearing"),
    Param("q_deg2", None, "deg²/s³", "spectral density q of the bearing acceleration (eq. 8b)"),
    Param("amplitude_threshold", None, "", "peaks below this amplitude are discarded before association"),
    Param("design_detection_probability", None, "", "P_D the filters assume"),
    Param("design_clutter_per_gate", None, "", "clutter count λV per gate the filters assume (before the threshold)"),
    Param("clutter_alpha", None, "1/amplitude", "α of the clutter amplitude density α e^{−α z_a}"),
    Param("pair", None, "", "roles of the targets in order: strong-weak | strong-strong | weak-weak (cycled over "
          "more targets; used where roles is 'pair')"),
    Param("roles", "pair", "", "strength roles cycled over the tracks, strong/weak joined by '-' (strong-weak-weak: "
          "track t takes the (t mod 3)-th); pair: pair's"),
    Param("strong_sigma_p_deg", None, "deg", "bearing noise σ_p of a strong track's true peak"),
    Param("strong_amplitude_mean", None, "", "expected amplitude ẑ_a of a strong track's true peak"),
    Param("strong_amplitude_std", None, "", "amplitude spread σ_a of a strong track's true peak"),
    Param("weak_sigma_p_deg", None, "deg", "bearing noise σ_p of a weak track's true peak"),
    Param("weak_amplitude_mean", None, "", "expected amplitude ẑ_a of a weak track's true peak"),
    Param("weak_amplitude_std", None, "", "amplitude spread σ_a of a weak track's true peak"),
    Param("amplitude_tracking", None, "", "track ẑ_a by eq. 9 instead of using the roles' values"),
    Param("initial_strength", None, "", "ẑ_a at the track start when amplitude_tracking is on"),
    Param("tracked_amplitude_std", None, "", "σ_a when amplitude_tracking is on"),
    Param("max_cluster_tracks", None, "", "largest cluster whose joint events are computed exactly"),
    Param("track_start", None, "", "auto (truth if the data have it, else peaks) | truth (true state at scan 0) | "
          "two-point (labelled peaks of scans 0, 1) | peaks (the strongest unlabelled peaks of scan 0, one-point)"),
    Param("max_coasted_scans", 0, "scans", "a track coasting this many scans in a row ends (0: never; a track "
          "leaving the field by more than half a gate always ends)", low=-1),
    Param("start_rate_sigma_deg_s", 0.5, "deg/s", "prior standard deviation of the bearing rate of a track started "
          "from one peak (track_start=peaks): about the largest rate a target is expected to have", low=0.0),
    Param("confirm_hits", 3, "scans", "M of M-of-N confirmation: a track started from peaks is tentative until M of "
          "its first N scans (the start's own scans included) had a peak in its gate; a truth start is confirmed; "
          "0: no confirmation", low=-1),
    Param("confirm_window", 4, "scans", "N of M-of-N confirmation (a tentative track that cannot reach M hits "
          "within N scans is deleted)", low=-1),
)


def design_from(params: dict, params_spec=PARAMS) -> dict:
    """The design values of ``params_spec`` from a scenario's ``params``, a parameter the scenario
    does not name taking its own default."""
    return {p.name: params[p.name] if p.name in params or p.default is None else p.default for p in params_spec}


def core_design(design: dict, n_tracks: int) -> BearingTrackerDesign:
    """The core's design (SI units, radians, one σ_p, ẑ_a, σ_a per track from its role).

    Parameters
    ----------
    design : dict
        Values of :data:`PARAMS` by name (degrees in the ``_deg`` ones).
    n_tracks : int
        Targets in the data; the roles pattern (``roles``, else ``pair``) is cycled over them.

    Raises
    ------
    InputError
        An unknown role or a design value out of range.
    """
    roles = roles_for(design, n_tracks)
    per = lambda key: np.array([float(design[f"{r}_{key}"]) for r in roles])
    check_design(design)
    return BearingTrackerDesign(
        scan_period_s=float(design["scan_period_s"]), gate_rad=float(np.deg2rad(design["gate_deg"])),
        q_rad2=float(design["q_deg2"]) * np.deg2rad(1.0) ** 2,
        amplitude_threshold=float(design["amplitude_threshold"]),
        detection_probability=float(design["design_detection_probability"]),
        clutter_per_gate=float(design["design_clutter_per_gate"]), clutter_alpha=float(design["clutter_alpha"]),
        sigma_p_rad=np.deg2rad(per("sigma_p_deg")), strength=per("amplitude_mean"), sigma_a=per("amplitude_std"),
        amplitude_tracking=bool(design["amplitude_tracking"]), initial_strength=float(design["initial_strength"]),
        tracked_sigma_a=float(design["tracked_amplitude_std"]), max_cluster_tracks=int(design["max_cluster_tracks"]))


def check_design(design: dict) -> None:
    """Range checks of the design values that do not depend on the data (first failure raised)."""
    roles = sorted(set(track_roles(design)))  # also refuses a bad roles / pair value
    role_values = [float(design[f"{r}_{k}"]) for r in roles for k in ("sigma_p_deg", "amplitude_std")]
    check_all([(design["gate_deg"] > 0, "gate_deg must be > 0"), (design["q_deg2"] >= 0, "q_deg2 must be ≥ 0"),
               (0 < design["design_detection_probability"] <= 1, "design_detection_probability must be in (0, 1]"),
               (design["design_clutter_per_gate"] > 0, "design_clutter_per_gate must be > 0"),
               (design["clutter_alpha"] > 0, "clutter_alpha must be > 0"),
               (design["max_cluster_tracks"] >= 1, "max_cluster_tracks must be ≥ 1"),
               (all(v > 0 for v in role_values), "σ_p and σ_a of every role must be > 0"),
               (design.get("confirm_hits", 0) <= max(design.get("confirm_window", 0), 0) or not design.get("confirm_hits"),
                "confirm_hits (M) must be ≤ confirm_window (N)"),
               (design["track_start"] in TRACK_STARTS,
                f"track_start must be one of {', '.join(TRACK_STARTS)} (got {design['track_start']!r})")])


def labelled_start_peaks(bearing: np.ndarray, origin: np.ndarray, counts: np.ndarray,
                         n_tracks: int) -> tuple[np.ndarray, np.ndarray]:
    """Bearings ``(R, T)`` of the labelled true peaks of scans 0 and 1 (the two-point start).

    Parameters
    ----------
    bearing, origin : ndarray (R, K, W)
        Padded peaks and their labels (target index, −1 for clutter or unknown).
    counts : ndarray (R, K)
        Real peaks per scan.

    Raises
    ------
    InputError
        A run whose scan 0 or 1 has no peak labelled with some target.
    """
    R = bearing.shape[0]
    z = np.full((2, R, n_tracks), np.nan)
    for k in range(min(2, bearing.shape[1])):
        valid = np.arange(bearing.shape[2])[None, :] < counts[:, k, None]
        o = origin[:, k]
        r, j = np.nonzero(valid & (o >= 0) & (o < n_tracks))
        z[k, r, o[r, j]] = bearing[r, k, j]
    missing = ~np.isfinite(z)
    if missing.any():
        k, r, t = (int(v[0]) for v in np.nonzero(missing))
        raise InputError(f"{PEAKS}: no labelled true peak (origin = {t}) at scan {k} of run {r}; tracks start "
                         "from the labelled true peaks of scans 0 and 1")
    return z[0], z[1]


def strongest_start_peaks(bearing: np.ndarray, amplitude: np.ndarray, counts: np.ndarray, strength: np.ndarray,
                          threshold: float) -> np.ndarray:
    """Bearings ``(R, T)`` of scan 0 for a one-point start from unlabelled peaks.

    The ``T`` strongest peaks above ``threshold`` go to the tracks in decreasing order of their
    expected amplitude ``strength`` (T,). A run whose scan 0 holds fewer peaks starts only as
    many tracks (the strongest roles first); the other slots get NaN and stay empty
    (``NO_TRACK``): a recording's first scan may miss a target, and that must not fail the replay.
    """
    R, W = bearing.shape[0], bearing.shape[2]
    T = len(strength)
    slots = np.arange(W)[None, :]
    # every run at once, padded to T slots so a scan with fewer peaks than tracks leaves the rest unstarted
    width = max(W, T)
    a0 = np.full((R, width), -np.inf)
    a0[:, :W] = np.where((slots < counts[:, 0, None]) & (amplitude[:, 0] >= threshold), amplitude[:, 0], -np.inf)
    b0 = np.full((R, width), np.nan)
    b0[:, :W] = bearing[:, 0]
    strongest = np.argsort(-a0, axis=1, kind="stable")[:, :T]
    found = np.isfinite(np.take_along_axis(a0, strongest, axis=1))
    z0 = np.empty((R, T))
    z0[:, np.argsort(-np.asarray(strength), kind="stable")] = np.where(found, np.take_along_axis(b0, strongest, axis=1),
                                                                       np.nan)
    return z0


def one_point_start(z0: np.ndarray, sigma_p_rad, rate_sigma_radps: float):
    """State ``[z₀, 0]`` and covariance ``diag(σ_p², σ_θ̇²)`` of a track started from one peak.

    The rate is unknown, and the prior ``σ_θ̇`` (the design's largest plausible bearing rate)
    lets the next scans' peaks, weighted by JPDA, estimate it. A two-point difference instead
    gives the rate an error of √2 σ_p / T, about 1.8°/s with σ_p = 1.3° and T = 1 s: far more
    than the targets' own rates, and the window gate then loses them (docs/papers/xcorr.md).
    """
    x0 = np.stack([z0, np.zeros_like(z0)], axis=-1)
    P0 = np.zeros(z0.shape + (2, 2))
    P0[..., 0, 0] = np.broadcast_to(np.asarray(sigma_p_rad, float) ** 2, z0.shape)
    P0[..., 1, 1] = rate_sigma_radps ** 2
    return x0, P0


def resolved_start(m: BearingPeaks, track_start: str) -> str:
    """``auto`` resolved for these data: the truth when they have it, else the unlabelled peaks
    (labels are for judging; a recording has none)."""
    if track_start != "auto":
        return track_start
    if m.truth_bearing_rad is not None and m.truth_rate_radps is not None:
        return "truth"
    return "peaks"


def start_tracks(m: BearingPeaks, track_start: str, d: BearingTrackerDesign, rate_sigma_radps: float):
    """Initial states ``(R, T, 2)``, covariances ``(R, T, 2, 2)`` and the scan they belong to.

    ``two-point``: eq. 8c from the labelled peaks of scans 0 and 1 (start scan 1). ``peaks``: a
    one-point start (:func:`one_point_start`) from the strongest unlabelled peaks of scan 0
    (:func:`strongest_start_peaks`, start scan 0). ``truth``: the
    true state of scan 0 with the covariance of eq. 8c around it (start scan 0). ``auto``:
    :func:`resolved_start`.
    """
    track_start = resolved_start(m, track_start)
    if track_start == "peaks":
        z0 = strongest_start_peaks(m.bearing_rad, m.amplitude, m.counts, d.strength, d.amplitude_threshold)
        x0, P0 = one_point_start(z0, d.sigma_p_rad, rate_sigma_radps)
        return x0, P0, 0
    if track_start == "two-point":
        z0, z1 = labelled_start_peaks(m.bearing_rad, m.origin, m.counts, m.n_targets)
        x0, P0 = two_point_start(z0, z1, d.scan_period_s, d.sigma_p_rad)
        return x0, P0, 1
    b, rate = m.truth_bearing_rad, m.truth_rate_radps
    if b is None or rate is None:
        raise InputError(f"track_start='truth' needs {TRUTH} (bearing_rad, bearing_rate_radps); "
                         "use --set track_start=auto (or peaks) for data without truth")
    if b.shape != rate.shape or b.shape[2] != m.n_targets:
        raise InputError(f"truth bearings {b.shape} and rates {rate.shape} must both be (runs, scans, "
                         f"{m.n_targets} targets)")
    x0 = np.stack([b[:, 0], rate[:, 0]], axis=-1)
    _, P0 = two_point_start(b[:, 0], b[:, 0], d.scan_period_s, d.sigma_p_rad)
    return x0, P0, 0


class _JpdaTracker(Tracker):
    """One variant of :data:`trackreplay.cores.association.jpda.STRATEGIES` (see the module docstring)."""

    family = "xcorr"
    form = "batch"
    params = PARAMS

    def __init__(self, **design):
        super().__init__(**design)
        check_design(self.design)

    def track(self, peaks: BearingPeaks) -> dict:
        d = core_design(self.design, peaks.n_targets)
        d = replace(d, ending=EndingRule(field=tuple(peaks.field_rad), margin=d.gate_rad / 2,
                                         max_coasted_scans=int(self.max_coasted_scans)))
        x0, P0, start = start_tracks(peaks, self.track_start, d, float(np.deg2rad(self.start_rate_sigma_deg_s)))
        if resolved_start(peaks, self.track_start) != "truth":  # from measurements: tentative until M-of-N
            d = replace(d, confirmation=ConfirmationRule(int(self.confirm_hits), int(self.confirm_window)))
        scans = scans_from_padded(peaks.bearing_rad, peaks.amplitude, peaks.counts)
        out = track_bearing_peaks(scans, x0, P0, d, STRATEGIES[self.name], start)
        out["track_id"] = slot_track_ids(out["flags"])
        return out


def slot_track_ids(flags: np.ndarray) -> np.ndarray:
    """``track_id`` (R, K, T) of trackers with fixed slots: slot j holds track j wherever it holds a
    track (flags without ``NO_TRACK``), −1 elsewhere. A slot is never restarted after its track
    ends, so identity j is one track for the whole run."""
    flags = np.asarray(flags)
    held = (flags.astype(np.int64) & vocab.NO_TRACK) == 0
    return np.where(held, np.arange(flags.shape[-1], dtype=np.int64), np.int64(-1))


class JPDA(_JpdaTracker):
    """JPDA on peak positions alone (Fortmann, Bar-Shalom & Scheffe 1983; Park et al. 1994's reference)."""

    name = "jpda"
    label = "JPDA"


class JPDA_A(_JpdaTracker):
    """Amplitude-aided JPDA: position and amplitude likelihoods (Park, Ryu & Lee 1994, eq. A.5)."""

    name = "jpda_a"
    label = "JPDA_A"


TRACKERS = (JPDA, JPDA_A)
