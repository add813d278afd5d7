"""TDOA/FDOA simulator: moving sensors, one (moving) emitter, measurements per epoch, truth.

Kim et al. (2013): the measurement model of eqs. 1–5
(:func:`trackreplay.cores.localisation.tdoa_fdoa_model.measurement_model`) plus Gaussian noise of
σ_TDOA and σ_FDOA, in the paper's simulated experiments (Tables 1–3, Fig. 7); see
``docs/papers/tdoa-fdoa.md``. Presets:

* geometries (paper's Tables 2–3): ``line`` (−3000, 0), (0, 0), (3000, 0) m and ``triangle``
  (−3000, 0), (0, 5120), (3000, 0) m, every sensor moving at (300, 0) m/s;
* emitters (Table 1): 1 = (−5000, 15000) m, 2 = (0, 15000) m, 3 = (5000, 15000) m, all moving
  at (200, 0) m/s.

Any sensor set (``sensor_positions_m = "x,y; x,y; …"``, ``sensor_velocities_mps``), emitter
(``emitter_position_m = "x,y"``, ``emitter_velocity_mps``), pair list (``pairs = "0-1,2-3"``,
sensors numbered from 0, no common reference needed; ``all`` = every pair), σ_TDOA, σ_FDOA and
carrier f₀ (default 1 GHz, the paper gives none) are parameters.

One *epoch* (a scan in the data contract) is one snapshot of measurements. Sensors and emitter
move at constant velocity between epochs (``epoch_interval_s``; 0 repeats one instant);
``noise_scales`` multiplies both σ per epoch (one value for all epochs, or one per epoch: the
paper's Fig. 7 noise study, where the geometry stays put and only the noise changes).

Initial guess (the paper: "truth plus Gaussian noise of 1 % MSE"): read here as
θ̂₀ᵢ = θᵢ + nᵢ, nᵢ ~ N(0, m·θᵢ²) with m = ``initial_relative_mse`` = 0.01 per component, i.e. a
10 % relative standard deviation (a component whose true value is 0, such as ẏ, starts exact).
It is written to ``/emitter/prior`` as a simulated coarse prior fix, so the estimator never
reads the truth channel.

Random numbers are drawn in a fixed order and shape (measurement noise, then prior noise), so a
seed fixes every byte and data sets that differ in one parameter share their noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trackreplay.errors import InputError, check_all, require_finite_params
from trackreplay.cores.localisation.tdoa_fdoa_model import all_pairs, measurement_model
from trackreplay.vocabulary import CHANNELS
from trackreplay.recorders.simulated import SimulatedData

MEASUREMENTS_TOPIC = CHANNELS["emitter_measurements"]
SENSORS_TOPIC = CHANNELS["emitter_sensors"]
PRIOR_TOPIC = CHANNELS["emitter_prior"]
TRUTH_TOPIC = CHANNELS["emitter_truth"]

GEOMETRIES = {
    "line": (((-3000.0, 0.0), (0.0, 0.0), (3000.0, 0.0)), ((300.0, 0.0),) * 3),
    "triangle": (((-3000.0, 0.0), (0.0, 5120.0), (3000.0, 0.0)), ((300.0, 0.0),) * 3),
}
EMITTERS = {
    1: ((-5000.0, 15000.0), (200.0, 0.0)),
    2: ((0.0, 15000.0), (200.0, 0.0)),
    3: ((5000.0, 15000.0), (200.0, 0.0)),
}
#: An emitter closer than this to a sensor makes r_i = 0 and the model undefined.
MIN_SENSOR_DISTANCE_M = 1e-3


@dataclass
class EmitterScenario:
    """A resolved scenario: arrays ready for the model (epoch axis first)."""

    times: np.ndarray            # (E,)
    sensor_pos: np.ndarray       # (E, M, 2)
    sensor_vel: np.ndarray       # (E, M, 2)
    emitter: np.ndarray          # (E, 4)
    pairs: np.ndarray            # (N, 2)
    carrier_hz: float
    sigma: np.ndarray            # (E, 2N): σ_TDOA (s) for the N TDOAs, then σ_FDOA (Hz)

    @property
    def n_pairs(self) -> int:
        return len(self.pairs)


def _parse_points(key: str, text: str, expect: int | None = None) -> np.ndarray:
    try:
        pts = [[float(v) for v in item.split(",")] for item in text.replace(" ", "").split(";") if item]
    except ValueError:
        raise InputError(f"parameter {key!r}: cannot read {text!r} as 'x,y; x,y; …' numbers") from None
    if not pts or any(len(p) != 2 for p in pts):
        raise InputError(f"parameter {key!r}: expected 'x,y' pairs separated by ';', got {text!r}")
    arr = np.array(pts, float)
    if expect is not None and len(arr) != expect:
        raise InputError(f"parameter {key!r} lists {len(arr)} point(s), expected {expect}")
    if not np.all(np.isfinite(arr)):
        raise InputError(f"parameter {key!r} must be finite")
    return arr


def parse_pairs(text: str, n_sensors: int) -> np.ndarray:
    """``"0-1,1-2"`` (or ``"all"``) → (N, 2) int array, checked against ``n_sensors``."""
    if text.strip().lower() == "all":
        return all_pairs(n_sensors)
    out, seen = [], set()
    for item in text.replace(" ", "").split(","):
        if not item:
            continue
        try:
            i, j = (int(v) for v in item.split("-"))
        except ValueError:
            raise InputError(f"parameter 'pairs': cannot read {item!r} as 'i-j' (sensors numbered from 0)") from None
        if not (0 <= i < n_sensors and 0 <= j < n_sensors):
            raise InputError(f"parameter 'pairs': {item} names a sensor outside 0..{n_sensors - 1}")
        if i == j:
            raise InputError(f"parameter 'pairs': {item} pairs a sensor with itself")
        if frozenset((i, j)) in seen:
            raise InputError(f"parameter 'pairs': {item} repeats a pair")
        seen.add(frozenset((i, j)))
        out.append((i, j))
    if not out:
        raise InputError("parameter 'pairs' lists no pair")
    return np.array(out, dtype=np.int64)


def parse_scales(text: str, n_epochs: int) -> np.ndarray:
    try:
        scales = np.array([float(v) for v in str(text).replace(" ", "").split(",") if v], float)
    except ValueError:
        raise InputError(f"parameter 'noise_scales': cannot read {text!r} as comma-separated numbers") from None
    if scales.size == 0 or not np.all(np.isfinite(scales)) or np.any(scales <= 0):
        raise InputError("parameter 'noise_scales' must list positive numbers")
    if scales.size == 1:
        return np.full(n_epochs, scales[0])
    if scales.size != n_epochs:
        raise InputError(f"parameter 'noise_scales' lists {scales.size} values: give one, or one per epoch "
                         f"(n_epochs = {n_epochs})")
    return scales


def resolve(p: dict) -> EmitterScenario:
    """Presets and overrides → arrays, with every check the simulator needs."""
    if p["geometry"] not in GEOMETRIES:
        raise InputError(f"unknown geometry {p['geometry']!r} (presets: {', '.join(GEOMETRIES)}; "
                         "or give sensor_positions_m)")
    if p["emitter"] not in EMITTERS:
        raise InputError(f"unknown emitter {p['emitter']!r} (Table 1 presets: 1, 2, 3; "
                         "or give emitter_position_m)")
    pos0, vel0 = (np.array(a, float) for a in GEOMETRIES[p["geometry"]])
    if p["sensor_positions_m"]:
        pos0 = _parse_points("sensor_positions_m", p["sensor_positions_m"])
        if not p["sensor_velocities_mps"] and len(pos0) != len(vel0):
            raise InputError(f"sensor_positions_m lists {len(pos0)} sensors: give sensor_velocities_mps too")
    if p["sensor_velocities_mps"]:
        vel0 = _parse_points("sensor_velocities_mps", p["sensor_velocities_mps"], len(pos0))
    if len(pos0) < 2:
        raise InputError("at least two sensors are needed")
    e_pos, e_vel = (np.array(a, float) for a in EMITTERS[p["emitter"]])
    if p["emitter_position_m"]:
        e_pos = _parse_points("emitter_position_m", p["emitter_position_m"], 1)[0]
    if p["emitter_velocity_mps"]:
        e_vel = _parse_points("emitter_velocity_mps", p["emitter_velocity_mps"], 1)[0]
    pairs = parse_pairs(p["pairs"], len(pos0))
    checks = [
        (p["sigma_tdoa_s"] > 0, "sigma_tdoa_s must be > 0"),
        (p["sigma_fdoa_hz"] > 0, "sigma_fdoa_hz must be > 0"),
        (p["carrier_hz"] > 0, "carrier_hz must be > 0"),
        (p["n_epochs"] >= 1, "n_epochs must be ≥ 1"),
        (p["epoch_interval_s"] >= 0, "epoch_interval_s must be ≥ 0"),
        (p["initial_relative_mse"] >= 0, "initial_relative_mse must be ≥ 0"),
    ]
    check_all(checks)
    require_finite_params(p)
    for a in range(len(pos0)):
        for b in range(a + 1, len(pos0)):
            if np.all(pos0[a] == pos0[b]) and np.all(vel0[a] == vel0[b]):
                raise InputError(f"sensors {a} and {b} coincide")
    n_epochs = int(p["n_epochs"])
    scales = parse_scales(p["noise_scales"], n_epochs)
    times = np.arange(n_epochs) * float(p["epoch_interval_s"])
    sensor_pos = pos0[None] + times[:, None, None] * vel0[None]
    sensor_vel = np.broadcast_to(vel0, sensor_pos.shape).copy()
    emitter = np.concatenate([e_pos[None] + times[:, None] * e_vel[None], np.broadcast_to(e_vel, (n_epochs, 2))], axis=1)
    dist = np.linalg.norm(emitter[:, None, :2] - sensor_pos, axis=-1)
    if dist.min() < MIN_SENSOR_DISTANCE_M:
        e, i = np.unravel_index(np.argmin(dist), dist.shape)
        raise InputError(f"the emitter coincides with sensor {i} at epoch {e} (range {dist[e, i]:.3g} m): "
                         "TDOA/FDOA are undefined there")
    n = len(pairs)
    sigma = np.concatenate([np.full((n_epochs, n), p["sigma_tdoa_s"]), np.full((n_epochs, n), p["sigma_fdoa_hz"])], axis=1)
    sigma = sigma * scales[:, None]
    return EmitterScenario(times, sensor_pos, sensor_vel, emitter, pairs, float(p["carrier_hz"]), sigma)


def validate(p: dict) -> None:
    """Reject parameter sets the simulator cannot honour (before any work starts)."""
    resolve(p)
    if p["initial_guess"] not in ("prior", "grid"):
        raise InputError("initial_guess must be 'prior' (the recorded coarse fix) or 'grid' (coarse grid search)")
    if p["iterations"] < 1:
        raise InputError("iterations must be ≥ 1")
    if p["step_tolerance_sigma"] < 0:
        raise InputError("step_tolerance_sigma must be ≥ 0")
    if p["grid_step_m"] <= 0 or p["grid_extent_m"] <= 0:
        raise InputError("grid_step_m and grid_extent_m must be > 0")
    if p["divergence_range_m"] <= 0:
        raise InputError("divergence_range_m must be > 0")


def simulate(p: dict, runs: int, seed: int) -> SimulatedData:
    """Simulate ``runs`` Monte Carlo runs of the scenario ``p``.

    Returns
    -------
    SimulatedData
        ``/emitter/measurements`` (``tdoa_s``, ``fdoa_hz``, ``sigma_tdoa_s``,
        ``sigma_fdoa_hz`` per pair, ``pairs`` (N, 2), ``carrier_hz``), ``/emitter/sensors``
        (``position_m``, ``velocity_mps`` (M, 2)), ``/emitter/prior`` (``state``, ``std``)
        and ``/emitter/truth`` (``state`` = [x, y, ẋ, ẏ]) per run and epoch.
    """
    validate(p)
    sc = resolve(p)
    rng = np.random.default_rng(seed)
    E, n = len(sc.times), sc.n_pairs
    meas_noise = rng.standard_normal((runs, E, 2 * n))
    prior_noise = rng.standard_normal((runs, E, 4))
    clean = measurement_model(sc.emitter, sc.sensor_pos, sc.sensor_vel, sc.pairs, sc.carrier_hz, jacobian=False)
    measured = clean[None] + sc.sigma[None] * meas_noise
    prior_std = np.sqrt(p["initial_relative_mse"]) * np.abs(sc.emitter)
    prior = sc.emitter[None] + prior_std[None] * prior_noise

    def per_run(a):
        return np.broadcast_to(a, (runs, *a.shape))

    return SimulatedData(
        times=sc.times,
        fixed={
            MEASUREMENTS_TOPIC: {
                "tdoa_s": measured[..., :n], "fdoa_hz": measured[..., n:],
                "sigma_tdoa_s": per_run(sc.sigma[:, :n]), "sigma_fdoa_hz": per_run(sc.sigma[:, n:]),
                "pairs": per_run(np.broadcast_to(sc.pairs.astype(np.int32), (E, n, 2))),
                "carrier_hz": np.full((runs, E), sc.carrier_hz),
            },
            SENSORS_TOPIC: {"position_m": per_run(sc.sensor_pos), "velocity_mps": per_run(sc.sensor_vel)},
            PRIOR_TOPIC: {"state": prior, "std": per_run(prior_std)},
            TRUTH_TOPIC: {"state": per_run(sc.emitter)},
        },
    )
