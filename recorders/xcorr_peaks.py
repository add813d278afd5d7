"""Cross-correlation peaks from the paper's stochastic model: per-scan peak lists plus truth.

Park, Ryu & Lee (1994), the stochastic model and the experiments (see ``docs/papers/xcorr.md``).
Each scan of each run yields a set of peaks ``(z_p, z_a)`` (bearing in radians, amplitude):

* one true peak per target, detected with probability ``P_D`` and not during a data-loss
  stretch; position ``N(θ_t, σ_p²)``, amplitude ``N(ẑ_a, σ_a²)`` truncated at 0 (amplitudes
  of a correlator's positive peaks are never negative; the mass below 0 is < 1e-3 for the
  paper's strengths);
* clutter: a Poisson point process over the sensor's field ``[field_min, field_max]`` whose
  density is ``λ_bg = background_clutter_per_gate / V`` everywhere and ``λ_t =
  <role>_clutter_per_gate / V`` within half a gate of target t's true bearing (the larger of
  the two where they overlap). So the clutter count in a gate of width V around a target is
  Poisson with mean ``λV`` of its role (strong 2, weak 3), away from targets Poisson(2), as in
  the paper's table; positions are uniform; amplitudes are one-sided exponential ``α e^{−α z}``.

Geometry (bearing–time plane with 1° ≙ 1 s, centred on ``center_bearing_deg``). The targets
come in pairs, each pair the paper's two targets; ``n_targets`` (default 2, the paper's) lays
⌈n/2⌉ pairs side by side, pair j (targets 2j, 2j+1) centred ``(j − (P−1)/2)·pair_spacing_deg``
from ``center_bearing_deg`` (P pairs); with an odd count the last pair has only its first
target (for one target: a single straight track through the centre). Target t's strength role
is the ``roles`` pattern cycled (:mod:`trackreplay.trackers.xcorr_peak_roles`).

* ``crossing``: targets move at ``±tan(ψ/2)`` °/s and cross at mid-run with angle ψ
  (``crossing_angle_deg``); the run starts and ends with the targets ``end_separation_deg``
  apart, so it lasts ``end_separation / tan(ψ/2)`` seconds (small angles mean long runs:
  the time the targets share a gate grows as 1/tan(ψ/2) whatever the run length).
* ``maneuver``: the targets approach each other at ``approach_rate_deg_per_s`` each, turn
  away with a constant bearing acceleration over ``turn_duration_s`` and reach their minimum
  separation ``min_distance_deg`` (L) at mid-run.

Data-loss stretches: per target a two-state Markov chain enters a loss with probability
``data_loss_probability`` per scan and leaves it with probability ``1 / data_loss_mean_scans``.
The first two scans always carry every true peak: they are the two-point track start
(paper: P(0|0) = [[σ_p², σ_p²], [σ_p², 2σ_p²]] is the covariance of that start with T = 1 s).

Random numbers are drawn in a fixed order (true-peak noise, amplitudes, detections, losses,
clutter counts, clutter positions, acceptance, clutter amplitudes), so a seed fixes every byte.
Peaks of a scan are sorted by bearing, as a correlator lists them by lag.
"""

from __future__ import annotations

import numpy as np
from scipy.special import ndtr, ndtri

from trackreplay.errors import InputError, check_all, require_finite_params
from trackreplay.trackers.xcorr_peak_roles import track_roles
from trackreplay.vocabulary import CHANNELS
from trackreplay.recorders.simulated import SimulatedData

PEAKS_TOPIC = CHANNELS["xcorr_peaks"]
TRUTH_TOPIC = CHANNELS["xcorr_truth"]
ORIGIN_CLUTTER = -1
ROLES = ("strong", "weak")
GEOMETRIES = ("crossing", "maneuver")
MAX_SCANS = 20000
#: clutter peaks a scan the simulator draws at the most (expected, over the whole field)
MAX_CLUTTER_PER_SCAN = 10_000
MAX_TARGETS = 100
DEFAULT_N_TARGETS = 2  # the paper's pair; data sets recorded before n_targets existed hold two
DEFAULT_PAIR_SPACING_DEG = 20.0


def role_model(p: dict, role: str) -> dict:
    """The stochastic model of one track role (strong / weak), in SI units (radians)."""
    return {
        "clutter_per_gate": float(p[f"{role}_clutter_per_gate"]),
        "amplitude_mean": float(p[f"{role}_amplitude_mean"]),
        "amplitude_std": float(p[f"{role}_amplitude_std"]),
        "sigma_p_rad": float(np.deg2rad(p[f"{role}_sigma_p_deg"])),
    }


def _duration_s(p: dict) -> float:
    sep = float(p["end_separation_deg"])
    if p["geometry"] == "crossing":
        return sep / np.tan(np.deg2rad(p["crossing_angle_deg"]) / 2)
    rate, tau, L = float(p["approach_rate_deg_per_s"]), float(p["turn_duration_s"]), float(p["min_distance_deg"])
    half_gap = (sep - L) / (2 * rate)  # h(u) = half_gap, h as in _turn_profile
    u = half_gap + tau / 4 if half_gap >= tau / 4 else np.sqrt(half_gap * tau)
    return 2 * u


def _turn_profile(u: np.ndarray, tau: float) -> np.ndarray:
    """|u| with the corner rounded over |u| < τ/2 by a parabola (continuous rate: a turn)."""
    a = np.abs(u)
    if tau <= 0:
        return a
    return np.where(a <= tau / 2, u * u / tau, a - tau / 4)


def n_targets(p: dict) -> int:
    """Targets of the scenario (``n_targets``; 2, the paper's pair, where a record lacks it)."""
    return int(p.get("n_targets", DEFAULT_N_TARGETS))


def pair_centres_deg(p: dict) -> np.ndarray:
    """Bearing (deg) of the centre of each pair of targets: ⌈n/2⌉ pairs spaced
    ``pair_spacing_deg`` apart around ``center_bearing_deg`` (one pair: the centre itself)."""
    pairs = (n_targets(p) + 1) // 2
    spacing = float(p.get("pair_spacing_deg", DEFAULT_PAIR_SPACING_DEG))
    return float(p["center_bearing_deg"]) + (np.arange(pairs) - (pairs - 1) / 2) * spacing


def target_bearings(p: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Scan times and the targets' true bearings and bearing rates.

    Returns
    -------
    times : ndarray (scans,)
    bearing_rad, rate_radps : ndarray (scans, n_targets)
        Targets 2j and 2j+1 are pair j (:func:`pair_centres_deg`), moving as the paper's two.
    """
    T = float(p["scan_period_s"])
    n = int(np.floor(_duration_s(p) / T + 1e-9)) + 1
    times = np.arange(n) * T
    u = times - times[-1] / 2  # closest approach at mid-run
    bearings, rates = [], []
    for centre in pair_centres_deg(p):
        centre = float(centre)
        if p["geometry"] == "crossing":
            rate = np.tan(np.deg2rad(p["crossing_angle_deg"]) / 2)
            bearings += [centre + rate * u, centre - rate * u]
            rates += [np.full(n, rate), np.full(n, -rate)]
        else:
            rate, tau, L = float(p["approach_rate_deg_per_s"]), float(p["turn_duration_s"]), float(p["min_distance_deg"])
            h = rate * _turn_profile(u, tau)
            dh = rate * (np.clip(2 * u / tau, -1, 1) if tau > 0 else np.sign(u))
            bearings += [centre + L / 2 + h, centre - L / 2 - h]
            rates += [dh, -dh]
    N = n_targets(p)
    b = np.stack(bearings[:N], axis=1)
    r = np.stack(rates[:N], axis=1)
    return times, np.deg2rad(b), np.deg2rad(r)


def validate(p: dict) -> None:
    """Reject parameter sets the simulator cannot honour (before any work starts)."""
    if p.get("geometry") not in GEOMETRIES:
        raise InputError(f"geometry must be one of {', '.join(GEOMETRIES)} (got {p.get('geometry')!r})")
    require_finite_params(p)
    track_roles(p)
    N = p.get("n_targets", DEFAULT_N_TARGETS)
    check_all([(isinstance(N, (int, np.integer)) and not isinstance(N, bool) and 1 <= N <= MAX_TARGETS,
                f"n_targets must be a whole number in 1…{MAX_TARGETS} (got {N!r})"),
               (N <= 2 or float(p.get("pair_spacing_deg", DEFAULT_PAIR_SPACING_DEG)) > 0,
                "pair_spacing_deg must be > 0 (the bearing between neighbouring pairs of targets)")])
    checks = [
        (p["scan_period_s"] > 0, "scan_period_s must be > 0"),
        (p["gate_deg"] > 0, "gate_deg must be > 0"),
        (0 <= p["field_min_deg"] < p["field_max_deg"] <= 180,
         "the field must satisfy 0 ≤ field_min_deg < field_max_deg ≤ 180 (θ = arccos(C·D/d))"),
        (0 < p["detection_probability"] <= 1, "detection_probability must be in (0, 1]"),
        (0 <= p["data_loss_probability"] < 1, "data_loss_probability must be in [0, 1)"),
        (p["data_loss_mean_scans"] >= 1, "data_loss_mean_scans must be ≥ 1"),
        (p["background_clutter_per_gate"] >= 0, "background_clutter_per_gate must be ≥ 0"),
        (p["clutter_alpha"] > 0, "clutter_alpha must be > 0 (mean clutter amplitude 1/α)"),
        (p["end_separation_deg"] > 0, "end_separation_deg must be > 0"),
    ]
    for role in ROLES:
        checks += [
            (p[f"{role}_clutter_per_gate"] >= 0, f"{role}_clutter_per_gate must be ≥ 0"),
            (p[f"{role}_amplitude_mean"] > 0, f"{role}_amplitude_mean must be > 0"),
            (p[f"{role}_amplitude_std"] > 0, f"{role}_amplitude_std must be > 0"),
            (p[f"{role}_sigma_p_deg"] > 0, f"{role}_sigma_p_deg must be > 0"),
        ]
    if p["geometry"] == "crossing":
        checks.append((0 < p["crossing_angle_deg"] < 180, "crossing_angle_deg must be in (0, 180)"))
    else:
        checks += [
            (0 <= p["min_distance_deg"] < p["end_separation_deg"],
             "min_distance_deg must be in [0, end_separation_deg)"),
            (p["approach_rate_deg_per_s"] > 0, "approach_rate_deg_per_s must be > 0"),
            (p["turn_duration_s"] >= 0, "turn_duration_s must be ≥ 0"),
        ]
    check_all(checks)
    # clutter is drawn per scan at the highest density over the whole field: a tiny gate or a huge
    # count per gate asks for more peaks than any correlator reports (and than memory holds)
    densest = max([p["background_clutter_per_gate"]] + [p[f"{role}_clutter_per_gate"] for role in ROLES])
    expected = densest / np.deg2rad(p["gate_deg"]) * np.deg2rad(p["field_max_deg"] - p["field_min_deg"])
    check_all([(expected <= MAX_CLUTTER_PER_SCAN,
                f"the clutter density (clutter per gate {densest:g} over a gate of {p['gate_deg']:g}°) gives "
                f"{expected:.3g} clutter peaks a scan over the field; at most {MAX_CLUTTER_PER_SCAN:,} are "
                "simulated (raise gate_deg or lower the clutter per gate)")])
    n = _duration_s(p) / p["scan_period_s"] + 1
    if n > MAX_SCANS:
        raise InputError(f"the geometry needs {n:.0f} scans (> {MAX_SCANS}); use a larger angle/rate "
                         "or a smaller end_separation_deg")
    if n < 3:
        raise InputError("the geometry lasts fewer than 3 scans; use a larger end_separation_deg")
    _, b, _ = target_bearings(p)
    lo, hi = np.deg2rad(p["field_min_deg"]), np.deg2rad(p["field_max_deg"])
    if b.min() < lo or b.max() > hi:
        more = "" if N <= 2 else ", pair_spacing_deg or n_targets"
        raise InputError(f"the targets leave the field [{p['field_min_deg']}, {p['field_max_deg']}]°; "
                         f"widen the field or reduce end_separation_deg{more}")


def _truncated_normal(u: np.ndarray, mean, std) -> np.ndarray:
    """Inverse-CDF draw of N(mean, std²) truncated to [0, ∞) from uniforms ``u``."""
    lo = ndtr(-np.asarray(mean) / np.asarray(std))
    return mean + std * ndtri(lo + u * (1.0 - lo))


def data_loss_mask(enter_u: np.ndarray, stay_u: np.ndarray, p_enter: float, mean_scans: float) -> np.ndarray:
    """Loss stretches ``(runs, scans, targets)`` from two fixed uniform draws (Markov chain)."""
    lost = np.zeros(enter_u.shape, bool)
    p_stay = 1.0 - 1.0 / mean_scans
    for k in range(2, enter_u.shape[1]):
        lost[:, k] = np.where(lost[:, k - 1], stay_u[:, k] < p_stay, enter_u[:, k] < p_enter)
    return lost


def clutter_density(bearing: np.ndarray, target_bearing: np.ndarray, gate: float,
                    background: float, per_target: np.ndarray) -> np.ndarray:
    """Clutter density (per rad) at ``bearing`` (…,) given the targets' bearings (…, T)."""
    inside = np.abs(bearing[..., None] - target_bearing) <= gate / 2
    return np.maximum(background, np.max(np.where(inside, per_target, 0.0), axis=-1))


def pack_peaks(run: np.ndarray, scan: np.ndarray, arrays: dict, runs: int, scans: int):
    """Flat peaks (one entry per peak) → padded ``(runs, scans, width)`` arrays sorted by bearing.

    Returns ``(padded arrays, counts)``; padding is NaN (−1 for integer arrays).
    """
    key = run * scans + scan
    order = np.lexsort((arrays["bearing_rad"], key))
    key = key[order]
    counts = np.bincount(key, minlength=runs * scans).reshape(runs, scans)
    starts = np.concatenate([[0], np.cumsum(counts.ravel())[:-1]])
    slot = np.arange(key.size) - starts[key]
    width = int(counts.max()) if counts.size else 0
    out = {}
    for name, a in arrays.items():
        fill = -1 if a.dtype.kind == "i" else np.nan
        padded = np.full((runs, scans, width), fill, dtype=a.dtype)
        padded.reshape(runs * scans, width)[key, slot] = a[order]
        out[name] = padded
    return out, counts


def simulate(p: dict, runs: int, seed: int) -> SimulatedData:
    """Simulate ``runs`` Monte Carlo runs of the scenario ``p``.

    Returns
    -------
    SimulatedData
        ``/xcorr/peaks`` (ragged ``bearing_rad``, ``amplitude``, ``origin``: the target index
        or −1 for clutter) and ``/xcorr/truth`` (``bearing_rad``, ``bearing_rate_radps``,
        ``detected``, ``strength`` per target) on a common scan-time axis.
    """
    validate(p)
    rng = np.random.default_rng(seed)
    times, bearing, rate = target_bearings(p)
    K, T = bearing.shape
    models = [role_model(p, role) for role in track_roles(p, T)]
    gate = np.deg2rad(p["gate_deg"])
    lo, hi = np.deg2rad(p["field_min_deg"]), np.deg2rad(p["field_max_deg"])
    sigma_p = np.array([m["sigma_p_rad"] for m in models])
    amp_mean = np.array([m["amplitude_mean"] for m in models])
    amp_std = np.array([m["amplitude_std"] for m in models])

    pos_noise = rng.standard_normal((runs, K, T))
    amp_u = rng.random((runs, K, T))
    det_u = rng.random((runs, K, T))
    enter_u = rng.random((runs, K, T))
    stay_u = rng.random((runs, K, T))

    lost = data_loss_mask(enter_u, stay_u, p["data_loss_probability"], p["data_loss_mean_scans"])
    detected = (det_u < p["detection_probability"]) & ~lost
    detected[:, :2] = True
    true_bearing = bearing[None] + sigma_p * pos_noise
    detected &= (true_bearing >= lo) & (true_bearing <= hi)
    true_amp = _truncated_normal(amp_u, amp_mean, amp_std)

    background = p["background_clutter_per_gate"] / gate
    per_target = np.array([m["clutter_per_gate"] for m in models]) / gate
    lam_max = max(background, float(per_target.max()))
    n_clutter = rng.poisson(lam_max * (hi - lo), size=(runs, K))
    total = int(n_clutter.sum())
    c_bearing = lo + (hi - lo) * rng.random(total)
    accept_u = rng.random(total)
    c_amp = rng.standard_exponential(total) / p["clutter_alpha"]
    c_run, c_scan = np.divmod(np.repeat(np.arange(runs * K), n_clutter.ravel()), K)
    density = clutter_density(c_bearing, bearing[c_scan], gate, background, per_target)
    keep = accept_u * lam_max < density

    r_idx, k_idx, t_idx = np.nonzero(detected)
    flat = {
        "bearing_rad": np.concatenate([true_bearing[r_idx, k_idx, t_idx], c_bearing[keep]]),
        "amplitude": np.concatenate([true_amp[r_idx, k_idx, t_idx], c_amp[keep]]),
        "origin": np.concatenate([t_idx, np.full(int(keep.sum()), ORIGIN_CLUTTER)]).astype(np.int32),
    }
    padded, counts = pack_peaks(np.concatenate([r_idx, c_run[keep]]), np.concatenate([k_idx, c_scan[keep]]),
                                flat, runs, K)
    truth = {
        "bearing_rad": np.broadcast_to(bearing, (runs, K, T)).copy(),
        "bearing_rate_radps": np.broadcast_to(rate, (runs, K, T)).copy(),
        "detected": detected,
        "strength": np.broadcast_to(amp_mean, (runs, K, T)).copy(),
    }
    return SimulatedData(times=times, fixed={TRUTH_TOPIC: truth}, ragged={PEAKS_TOPIC: (padded, counts)})
