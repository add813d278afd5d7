"""Multi-target radar simulator: births, deaths, turns, missed detections and clutter.

A Stone Soup / MATLAB style multi-target scenario (``data/scenarios/radar-multi.toml``). Radar at
the origin, bearing counter-clockwise from +x (x = r cos θ, y = r sin θ); the surveillance region
is the range/bearing sector ``min_range_m ≤ r ≤ max_range_m``, ``|θ| ≤ sector_half_width_deg``.

Targets
    A Poisson number (mean ``initial_targets_mean``) at scan 0 and a Poisson number of births at
    every later scan (mean ``birth_rate_per_scan``), each uniform over the region's area, with a
    speed uniform in [``min_speed_mps``, ``max_speed_mps``] and a uniform heading. A target alive
    at scan k is alive at k + 1 with probability ``survival_probability`` (its lifetime is drawn
    at birth: geometric), and dies when it leaves the region. Identities are 0, 1, 2, … in order
    of birth within a run, never reused.
Motion
    Nearly constant velocity: per axis ``[p, v]`` moves by ``F = [[1, T], [0, 1]]`` plus white
    noise ``Q = q [[T³/3, T²/2], [T²/2, T]]`` (q = ``process_noise_m2ps3``, the exact
    discretisation of white acceleration of spectral density q). A fraction ``turning_fraction``
    of the targets (each with that probability) fly a coordinated turn instead, with a constant
    turn rate ω uniform in ±``max_turn_rate_degps``: the exact CT transition
    (:func:`coordinated_turn`), plus the same noise Q.
Plots
    Each alive target is detected with probability ``detection_probability``; range and bearing
    get Gaussian noise (``sigma_range_m``, ``sigma_bearing_deg``); a bearing is wrapped to
    (−π, π] and a range is its absolute value. Clutter: a Poisson number per scan (mean
    ``clutter_per_scan``) uniform in range and in bearing over the region, so constant density
    in measurement space (:func:`clutter_density_per_m_rad`) and ∝ 1/r per unit area
    (:func:`clutter_density_per_m2`). The plots of a scan are in random order; ``origin`` is the
    identity of the target a plot came from, −1 for clutter.

Random numbers come from five independent streams of the seed (births, motion, plots, clutter,
plot order), each drawn in a fixed order, so a seed fixes every byte, and changing a plot or
clutter parameter keeps the same targets (common random numbers): P_D compares the same
uniforms, σ scales the same normals, the clutter leaves the targets' plots as they were.
"""

from __future__ import annotations

import numpy as np

from trackreplay import vocabulary as vocab
from trackreplay.errors import check_all, require_finite_params
from trackreplay.recorders.simulated import SimulatedData

PLOTS_TOPIC = vocab.CHANNELS["radar_plots"]
TRUTH_TOPIC = vocab.CHANNELS["radar_truth"]
ORIGIN_CLUTTER = -1
MAX_MEAN_COUNT = 1e4  # per scan: targets at scan 0, births, clutter (beyond is a typo, not a scenario)


def validate(p: dict) -> None:
    """Reject parameter sets the simulator cannot honour (before any work starts)."""
    require_finite_params(p)
    checks = [
        (p["scan_period_s"] > 0, "scan_period_s must be > 0"),
        (p["n_scans"] >= 1, "n_scans must be ≥ 1"),
        (0 <= p["min_range_m"] < p["max_range_m"], "the region must satisfy 0 ≤ min_range_m < max_range_m"),
        (0 < p["sector_half_width_deg"] <= 180, "sector_half_width_deg must be in (0, 180]"),
        (0 <= p["initial_targets_mean"] <= MAX_MEAN_COUNT, f"initial_targets_mean must be in [0, {MAX_MEAN_COUNT:g}]"),
        (0 <= p["birth_rate_per_scan"] <= MAX_MEAN_COUNT, f"birth_rate_per_scan must be in [0, {MAX_MEAN_COUNT:g}]"),
        (0 < p["survival_probability"] <= 1, "survival_probability must be in (0, 1]"),
        (0 <= p["min_speed_mps"] <= p["max_speed_mps"], "speeds must satisfy 0 ≤ min_speed_mps ≤ max_speed_mps"),
        (p["process_noise_m2ps3"] >= 0, "process_noise_m2ps3 must be ≥ 0"),
        (0 <= p["turning_fraction"] <= 1, "turning_fraction must be in [0, 1]"),
        (0 <= p["max_turn_rate_degps"] <= 180, "max_turn_rate_degps must be in [0, 180]"),
        (0 < p["detection_probability"] <= 1, "detection_probability must be in (0, 1]"),
        (p["sigma_range_m"] > 0, "sigma_range_m must be > 0"),
        (0 < p["sigma_bearing_deg"] < 23,
         "sigma_bearing_deg must be in (0, 23) (linearised conversion needs σ_θ < 0.4 rad)"),
        (0 <= p["clutter_per_scan"] <= MAX_MEAN_COUNT, f"clutter_per_scan must be in [0, {MAX_MEAN_COUNT:g}]"),
    ]
    check_all(checks)


# --------------------------------------------------------------------------- region and clutter


def region_area_m2(p: dict) -> float:
    """Area of the surveillance sector: ``Δθ/2 · (r_max² − r_min²)`` with ``Δθ = 2·half width``."""
    half = np.deg2rad(p["sector_half_width_deg"])
    return float(half * (p["max_range_m"] ** 2 - p["min_range_m"] ** 2))


def clutter_density_per_m_rad(p: dict) -> float:
    """Clutter density in measurement space, per metre of range and radian of bearing:
    ``λ / (Δr · Δθ)`` (λ = ``clutter_per_scan``), the same everywhere in the region."""
    width = p["max_range_m"] - p["min_range_m"]
    return float(p["clutter_per_scan"] / (width * 2 * np.deg2rad(p["sector_half_width_deg"])))


def clutter_density_per_m2(p: dict, range_m=None):
    """Clutter density per unit area (per m² per scan).

    Clutter is uniform in range and bearing, so per unit area it falls as 1/r: at range r it is
    ``λ / (Δr · Δθ · r)`` (:func:`clutter_density_per_m_rad` over r, the Jacobian of
    x = r cos θ, y = r sin θ). Without ``range_m``, its mean over the region, ``λ / A``
    (:func:`region_area_m2`): the one number of a tracker that assumes uniform clutter in x/y,
    exact at ``r = (r_min + r_max)/2``.
    """
    if range_m is None:
        return float(p["clutter_per_scan"] / region_area_m2(p))
    return clutter_density_per_m_rad(p) / np.asarray(range_m, dtype=float)


def in_region(x: np.ndarray, p: dict) -> np.ndarray:
    """Whether states ``(..., ≥2)`` lie inside the sector (edges included)."""
    r = np.hypot(x[..., 0], x[..., 1])
    theta = np.arctan2(x[..., 1], x[..., 0])
    return (r >= p["min_range_m"]) & (r <= p["max_range_m"]) & (np.abs(theta) <= np.deg2rad(p["sector_half_width_deg"]))


def wrap_angle(a: np.ndarray) -> np.ndarray:
    """Angles to (−π, π]; values already there are returned unchanged (bit for bit)."""
    a = np.asarray(a, dtype=float)
    out = (a > np.pi) | (a <= -np.pi)
    return np.where(out, np.pi - np.mod(np.pi - a, 2 * np.pi), a)


# --------------------------------------------------------------------------- motion


def coordinated_turn(x: np.ndarray, omega_radps: np.ndarray, T: float) -> np.ndarray:
    """Exact coordinated-turn transition of states ``[x, y, vx, vy]`` ``(n, 4)`` over ``T``.

    ``p' = p + [[s, −c], [c, s]] v`` and ``v' = R(ωT) v`` with ``s = sin(ωT)/ω`` and
    ``c = (1 − cos ωT)/ω``, written with ``sinc`` so that ω = 0 is the constant-velocity
    transition exactly (s = T, c = 0, R = I).
    """
    w = np.asarray(omega_radps, dtype=float)
    wT = w * T
    s = T * np.sinc(wT / np.pi)                        # sin(ωT)/ω
    c = T * np.sin(wT / 2) * np.sinc(wT / (2 * np.pi))  # (1 − cos ωT)/ω = 2 sin²(ωT/2)/ω
    cos, sin = np.cos(wT), np.sin(wT)
    vx, vy = x[:, 2], x[:, 3]
    out = np.empty_like(x)
    out[:, 0] = x[:, 0] + s * vx - c * vy
    out[:, 1] = x[:, 1] + c * vx + s * vy
    out[:, 2] = cos * vx - sin * vy
    out[:, 3] = sin * vx + cos * vy
    return out


def process_noise_covariance(q: float, T: float) -> np.ndarray:
    """``Q`` ``(4, 4)`` of state ``[x, y, vx, vy]``: ``q [[T³/3, T²/2], [T²/2, T]]`` per axis."""
    return np.kron(q * np.array([[T**3 / 3, T**2 / 2], [T**2 / 2, T]]), np.eye(2))


def _process_noise(z: np.ndarray, q: float, T: float) -> np.ndarray:
    """Noise ``(n, 4)`` of covariance :func:`process_noise_covariance` from normals ``z`` ``(n, 2, 2)``
    (axis 1: x/y, axis 2: the two factors of the per-axis Cholesky factor)."""
    sq = np.sqrt(q)
    pos = sq * np.sqrt(T**3 / 3) * z[:, :, 0]
    vel = sq * np.sqrt(T) * (np.sqrt(3) / 2 * z[:, :, 0] + 0.5 * z[:, :, 1])
    return np.concatenate([pos, vel], axis=1)


# --------------------------------------------------------------------------- simulation


def _pack(key: np.ndarray, arrays: dict, n_frames: int, shape: tuple) -> tuple[dict, np.ndarray]:
    """Rows sorted by frame ``key`` → padded ``(runs, scans, width, ...)`` arrays and counts."""
    counts = np.bincount(key, minlength=n_frames)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    slot = np.arange(key.size) - starts[key]
    width = int(counts.max()) if counts.size else 0
    out = {}
    for name, a in arrays.items():
        padded = np.zeros((n_frames, width) + a.shape[1:], dtype=a.dtype)
        if a.dtype.kind == "f":
            padded.fill(np.nan)
        padded[key, slot] = a
        out[name] = padded.reshape(shape + (width,) + a.shape[1:])
    return out, counts.reshape(shape)


def _births(rng, p: dict, runs: int, K: int):
    """Every target of every run: run, scan of birth, identity, state at birth, turn rate and
    number of scans it survives (geometric)."""
    n0 = rng.poisson(p["initial_targets_mean"], runs)
    nb = rng.poisson(p["birth_rate_per_scan"], (runs, K - 1))
    born = np.concatenate([n0[:, None], nb], axis=1)  # (runs, K): targets born at scan k
    frame = np.repeat(np.arange(runs * K), born.ravel())
    run, scan = np.divmod(frame, K)
    per_run = born.sum(axis=1)
    first = np.concatenate([[0], np.cumsum(per_run)[:-1]])
    ident = np.arange(frame.size) - first[run]
    u = rng.random((frame.size, 7))

    r_lo, r_hi = float(p["min_range_m"]), float(p["max_range_m"])
    half = np.deg2rad(p["sector_half_width_deg"])
    r = np.sqrt(r_lo**2 + u[:, 0] * (r_hi**2 - r_lo**2))  # uniform over the area
    theta = half * (2 * u[:, 1] - 1)
    speed = p["min_speed_mps"] + u[:, 2] * (p["max_speed_mps"] - p["min_speed_mps"])
    heading = 2 * np.pi * u[:, 3]
    state = np.stack([r * np.cos(theta), r * np.sin(theta), speed * np.cos(heading), speed * np.sin(heading)], axis=1)
    turning = u[:, 4] < p["turning_fraction"]
    omega = np.where(turning, np.deg2rad(p["max_turn_rate_degps"]) * (2 * u[:, 5] - 1), 0.0)
    ps = float(p["survival_probability"])
    if ps < 1:
        survives = np.floor(np.log1p(-u[:, 6]) / np.log(ps))  # P(survives ≥ j scans) = p_s^j
    else:
        survives = np.full(frame.size, np.inf)
    return run, scan, ident, state, omega, survives


def _trajectories(rng, p: dict, scan0: np.ndarray, state0: np.ndarray, omega: np.ndarray,
                  survives: np.ndarray, K: int):
    """Flight of every target, all targets at once by age: rows (target index, age, state) of
    every scan at which a target is alive."""
    T, q = float(p["scan_period_s"]), float(p["process_noise_m2ps3"])
    active = np.arange(scan0.size)
    x = state0
    rows, ages, states = [], [], []
    for age in range(K):
        rows.append(active)
        ages.append(np.full(active.size, age))
        states.append(x)
        go_on = (survives[active] > age) & (scan0[active] + age + 1 < K)
        active, x = active[go_on], x[go_on]
        if active.size == 0:
            break
        x = coordinated_turn(x, omega[active], T) + _process_noise(rng.standard_normal((active.size, 2, 2)), q, T)
        inside = in_region(x, p)
        active, x = active[inside], x[inside]
    return np.concatenate(rows), np.concatenate(ages), np.concatenate(states)


def simulate(p: dict, runs: int, seed: int) -> SimulatedData:
    """Simulate ``runs`` Monte Carlo runs of the scenario ``p``.

    Returns
    -------
    SimulatedData
        ``/radar/plots``: ragged ``range_m``, ``bearing_rad`` and ``origin`` (target identity,
        −1 for clutter) per run and scan, in random order; ``/radar/truth``: ragged ``state``
        ``[x, y, vx, vy]`` and ``target_id`` of the targets alive at the scan, ordered by
        identity (zero rows when none is).
    """
    validate(p)
    K, T = int(p["n_scans"]), float(p["scan_period_s"])
    births_rng, motion_rng, plots_rng, clutter_rng, order_rng = (
        np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(5))
    times = np.arange(K) * T

    # truth: one row per (target, scan alive), ordered by run, scan, identity
    run, scan0, ident, state0, omega, survives = _births(births_rng, p, runs, K)
    target, age, state = _trajectories(motion_rng, p, scan0, state0, omega, survives, K)
    frame = run[target] * K + scan0[target] + age
    order = np.lexsort((target, frame))  # identities grow with the target index within a run
    frame, target, state = frame[order], target[order], state[order]
    truth, truth_counts = _pack(frame, {"state": state, "target_id": ident[target].astype(np.int64)},
                                runs * K, (runs, K))

    # the targets' plots: one detection draw and two normals per truth row
    detect_u = plots_rng.random(frame.size)
    noise = plots_rng.standard_normal((frame.size, 2))
    true_range = np.hypot(state[:, 0], state[:, 1])
    true_bearing = np.arctan2(state[:, 1], state[:, 0])
    det = detect_u < p["detection_probability"]
    det_range = np.abs(true_range + p["sigma_range_m"] * noise[:, 0])[det]
    det_bearing = wrap_angle(true_bearing + np.deg2rad(p["sigma_bearing_deg"]) * noise[:, 1])[det]

    # clutter: Poisson per (run, scan), uniform in range and bearing
    n_clutter = clutter_rng.poisson(p["clutter_per_scan"], (runs, K))
    u = clutter_rng.random((int(n_clutter.sum()), 2))
    half = np.deg2rad(p["sector_half_width_deg"])
    c_range = p["min_range_m"] + u[:, 0] * (p["max_range_m"] - p["min_range_m"])
    c_bearing = wrap_angle(half * (2 * u[:, 1] - 1))
    c_frame = np.repeat(np.arange(runs * K), n_clutter.ravel())

    key = np.concatenate([frame[det], c_frame])
    shuffle = order_rng.random(key.size)
    order = np.lexsort((shuffle, key))
    flat = {
        "range_m": np.concatenate([det_range, c_range])[order],
        "bearing_rad": np.concatenate([det_bearing, c_bearing])[order],
        "origin": np.concatenate([ident[target][det], np.full(c_range.size, ORIGIN_CLUTTER)]).astype(np.int64)[order],
    }
    plots, plot_counts = _pack(key[order], flat, runs * K, (runs, K))
    return SimulatedData(times=times, ragged={PLOTS_TOPIC: (plots, plot_counts), TRUTH_TOPIC: (truth, truth_counts)})
