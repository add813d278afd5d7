"""Uniform-linear-array snapshot simulator: N far-field moving targets, complex M × Ns per scan.

Ryu, Lee & Lee (2001), signal model (eqs. (1)–(5)) and simulation set-up (section V); see
``docs/papers/array.md``.

    r(t) = Σₙ sₙ(t) a(θₙ) + n(t),   a(θ) = [1, γ, …, γ^(M−1)]ᵀ,  γ = exp(j 2π (d/λ) sin θ)

* Source signals sₙ are circular complex Gaussian, independent across targets and snapshots,
  power σ²·10^(SNRₙ/10) (per-element SNR); sensor noise is circular complex Gaussian with
  variance σ², white across sensors. ``d/λ`` is recorded in the metadata (the scenario's
  ``spacing_wavelengths``).
* **Motion within an interval**: targets are stationary during the Ns snapshots of scan k
  (angle = trajectory at t_k = k·T), as the paper treats them; the truth of scan k is that angle.
  Trajectories are piecewise linear through knots (a change of slope is a manoeuvre).
* **Several SNRs in one file**: ``snr_db`` is a list; the file holds runs × len(snr_db) Monte
  Carlo runs, run index = SNR index · runs + run. The same random draws are used at every SNR
  (common random numbers), scaled by each SNR's amplitude, so SNR comparisons are paired.
* Random numbers are drawn in a fixed order and shape (source signals, then noise), so a seed
  fixes every byte.
* **Any number of targets** N = ``n_targets`` (1 … M − 1). ``layout = "table"`` (the default,
  the paper's scene) takes the first N rows of ``trajectories_deg``; ``layout = "spread"`` lays
  N targets out evenly in sin θ over ±``spread_deg`` (the ULA resolves equally well everywhere
  in sin θ) at scan 0, every one drifting at ``spread_rate_deg_per_s`` (the same rate, so they
  never cross): a well-separated scene of any size.

Channels: ``/array/snapshots`` {``snapshots`` (M, Ns) complex} and ``/array/truth``
{``angle_rad`` (N,), ``snr_db`` (run's nominal SNR), ``target_snr_db`` (N,)}.
"""

from __future__ import annotations

import numpy as np

from trackreplay import vocabulary as vocab
from trackreplay.errors import InputError, check_all, require_finite_params
from trackreplay.cores.array.linear_array import steering_vectors
from trackreplay.recorders.simulated import SimulatedData

SNAPSHOTS_TOPIC = vocab.CHANNELS["array_snapshots"]
TRUTH_TOPIC = vocab.CHANNELS["array_truth"]
SNAPSHOT_DTYPES = {"complex64": np.complex64, "complex128": np.complex128}
LAYOUTS = ("table", "spread")


def float_list(key: str, value) -> list[float]:
    """A list parameter from TOML (a list) or the command line (``"0,5,10"``)."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return [float(value)]
    if isinstance(value, str):
        parts = [p for p in value.replace(";", ",").split(",") if p.strip()]
    else:
        parts = list(value)
    try:
        out = [float(p) for p in parts]
    except (TypeError, ValueError):
        raise InputError(f"parameter {key!r}: expected numbers separated by commas, got {value!r}") from None
    if not out:
        raise InputError(f"parameter {key!r} is empty")
    return out


def trajectory_table(value) -> np.ndarray:
    """``trajectories_deg``: rows of knot angles, from a TOML list of lists or
    ``"a,b,c; d,e,f"`` on the command line."""
    if isinstance(value, str):
        rows = [r for r in value.split(";") if r.strip()]
        table = [float_list("trajectories_deg", r) for r in rows]
    else:
        table = [float_list("trajectories_deg", r) for r in value]
    if not table or len({len(r) for r in table}) != 1:
        raise InputError("parameter 'trajectories_deg': every target needs one angle per knot")
    return np.array(table, dtype=float)


def layout(p: dict) -> str:
    """How the targets move: ``table`` (rows of ``trajectories_deg``; data sets recorded before
    ``layout`` existed) or ``spread``."""
    return str(p.get("layout", "table"))


def spread_angles_deg(p: dict, times: np.ndarray) -> np.ndarray:
    """Angles (deg) ``(K, N)`` of the ``spread`` layout: N targets evenly spaced in sin θ over
    ±``spread_deg`` at scan 0 (one target: broadside), each moving at ``spread_rate_deg_per_s``."""
    N = int(p["n_targets"])
    limit = np.sin(np.deg2rad(float(p.get("spread_deg", 60.0))))
    start = np.rad2deg(np.arcsin(np.linspace(-limit, limit, N) if N > 1 else np.zeros(1)))
    return start[None, :] + float(p.get("spread_rate_deg_per_s", 0.0)) * np.asarray(times, float)[:, None]


def validate(p: dict) -> None:
    """Reject parameter sets the simulator cannot honour (before any work starts)."""
    M, N, Ns = int(p["n_sensors"]), int(p["n_targets"]), int(p["snapshots_per_scan"])
    knots = np.array(float_list("knot_times_s", p["knot_times_s"]))
    table = trajectory_table(p["trajectories_deg"])
    offsets = float_list("target_snr_offset_db", p["target_snr_offset_db"])
    snrs = float_list("snr_db", p["snr_db"])
    spread = layout(p) == "spread"
    if layout(p) not in LAYOUTS:
        raise InputError(f"layout must be one of {', '.join(LAYOUTS)} (got {layout(p)!r})")
    if len(offsets) < N:  # targets beyond the list get 0 dB (target_offsets_db)
        offsets = offsets + [0.0] * (N - len(offsets))
    checks = [
        (M >= 2, "n_sensors must be ≥ 2"),
        (N >= 1, "n_targets must be ≥ 1"),
        (N <= M - 1, f"n_targets = {N} must be ≤ n_sensors − 1 = {M - 1} (the noise subspace must not be empty)"),
        (Ns >= N, f"snapshots_per_scan = {Ns} is fewer than the {N} targets (rank-deficient covariance)"),
        (spread or table.shape[0] >= N, f"trajectories_deg has {table.shape[0]} target(s), n_targets asks for {N}: "
                                        "add rows, or --set layout=spread for any number of targets"),
        (0 < p["spacing_wavelengths"] <= 0.5, "spacing_wavelengths must be in (0, 0.5] (no grating lobes)"),
        (p["noise_variance"] > 0, "noise_variance must be > 0"),
        (p["scan_period_s"] > 0, "scan_period_s must be > 0"),
        (int(p["n_scans"]) >= 3, "n_scans must be ≥ 3 (two start-up scans, then tracking)"),
        (table.shape[1] == knots.size, f"trajectories_deg rows need {knots.size} angles (one per knot time)"),
        (knots.size >= 1 and knots[0] == 0 and np.all(np.diff(knots) > 0), "knot_times_s must start at 0 and increase"),
        (np.all(np.abs(table) < 90), "trajectory angles must lie in (−90°, 90°)"),
        (p["snapshot_dtype"] in SNAPSHOT_DTYPES, f"snapshot_dtype must be one of {', '.join(SNAPSHOT_DTYPES)}"),
        (all(np.isfinite(snrs)) and all(np.isfinite(offsets)) and np.all(np.isfinite(table)), "SNRs and angles must be finite"),
    ]
    if spread:
        checks.append((0 <= float(p.get("spread_deg", 60.0)) < 90, "spread_deg must be in [0, 90)"))
    check_all(checks)
    require_finite_params(p)
    if spread:
        _, theta = truth_angles(p)
        if np.any(np.abs(theta) >= np.pi / 2):
            raise InputError("the spread targets drift beyond ±90° within the run; reduce spread_deg, "
                             "spread_rate_deg_per_s or n_scans")


def target_offsets_db(p: dict) -> np.ndarray:
    """``target_snr_offset_db`` of the N targets; targets beyond its values get 0 dB."""
    N = int(p["n_targets"])
    given = float_list("target_snr_offset_db", p["target_snr_offset_db"])[:N]
    return np.array(given + [0.0] * (N - len(given)))


def truth_angles(p: dict) -> tuple[np.ndarray, np.ndarray]:
    """Scan times ``(K,)`` and true angles ``(K, N)`` in radians."""
    K, T, N = int(p["n_scans"]), float(p["scan_period_s"]), int(p["n_targets"])
    times = np.arange(K) * T
    if layout(p) == "spread":
        return times, np.deg2rad(spread_angles_deg(p, times))
    knots = np.array(float_list("knot_times_s", p["knot_times_s"]))
    table = trajectory_table(p["trajectories_deg"])[:N]
    angles = np.stack([np.interp(times, knots, row) for row in table], axis=-1)
    return times, np.deg2rad(angles)


def simulate(p: dict, runs: int, seed: int) -> SimulatedData:
    """Simulate ``runs`` Monte Carlo runs at every SNR of ``p["snr_db"]``.

    Returns
    -------
    SimulatedData
        ``/array/snapshots`` and ``/array/truth`` with ``runs · len(snr_db)`` runs.
    """
    validate(p)
    M, N, Ns, K = int(p["n_sensors"]), int(p["n_targets"]), int(p["snapshots_per_scan"]), int(p["n_scans"])
    snrs = np.array(float_list("snr_db", p["snr_db"]))
    offsets = target_offsets_db(p)
    sigma2 = float(p["noise_variance"])
    times, theta = truth_angles(p)
    rng = np.random.default_rng(seed)
    half = np.sqrt(0.5)
    signals = (rng.standard_normal((runs, K, N, Ns)) + 1j * rng.standard_normal((runs, K, N, Ns))) * half
    noise = (rng.standard_normal((runs, K, M, Ns)) + 1j * rng.standard_normal((runs, K, M, Ns))) * (half * np.sqrt(sigma2))
    A = steering_vectors(theta, M, p["spacing_wavelengths"])  # (K, M, N)
    target_snr = snrs[:, None] + offsets[None, :]  # (S, N)
    amplitude = np.sqrt(sigma2 * 10.0 ** (target_snr / 10.0))
    dtype = SNAPSHOT_DTYPES[p["snapshot_dtype"]]
    S = len(snrs)
    snaps = np.empty((S * runs, K, M, Ns), dtype=dtype)
    for i in range(S):  # one block per SNR (the run axis is SNR-major)
        scaled = (A * amplitude[i])[None] @ signals
        snaps[i * runs:(i + 1) * runs] = scaled + noise
    truth = {
        "angle_rad": np.broadcast_to(theta, (S * runs, K, N)).copy(),
        "snr_db": np.repeat(snrs, runs)[:, None].repeat(K, axis=1),
        "target_snr_db": np.broadcast_to(np.repeat(target_snr, runs, axis=0)[:, None, :], (S * runs, K, N)).copy(),
    }
    return SimulatedData(times=times, fixed={SNAPSHOTS_TOPIC: {"snapshots": snaps}, TRUTH_TOPIC: truth})
