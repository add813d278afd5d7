"""Track-while-scan radar simulator: one target, plots (range, bearing) per scan, plus truth.

Kim & Lee (2006), the paper's simulation (``docs/papers/radar.md``). Radar at the origin, bearing
counter-clockwise from +x. Random numbers are drawn in a fixed order and shape whatever the
parameters (process noise, range noise, bearing noise, detection draws), so two data sets that
differ in one parameter share their noise (common random numbers) and a seed fixes every byte.
"""

from __future__ import annotations

import numpy as np

from trackreplay import vocabulary as vocab
from trackreplay.errors import check_all, require_finite_params
from trackreplay.recorders.simulated import SimulatedData

PLOTS_TOPIC = vocab.CHANNELS["radar_plots"]
TRUTH_TOPIC = vocab.CHANNELS["radar_truth"]


def validate(p: dict) -> None:
    """Reject parameter sets the simulator cannot honour (before any work starts)."""
    checks = [
        (p["scan_period_s"] > 0, "scan_period_s must be > 0"),
        (p["n_scans"] >= 3, "n_scans must be ≥ 3 (two plots start a track)"),
        (p["sigma_range_m"] > 0, "sigma_range_m must be > 0"),
        (0 < p["sigma_bearing_deg"] < 23, "sigma_bearing_deg must be in (0, 23) (linearised conversion needs σ_θ < 0.4 rad)"),
        (p["truth_process_noise_mps2"] >= 0, "truth_process_noise_mps2 must be ≥ 0"),
        (0 < p["detection_probability"] <= 1, "detection_probability must be in (0, 1]"),
        (p["design_sigma_v_mps2"] > 0, "design_sigma_v_mps2 must be > 0"),
        (p["nominal_cross_range_m"] > 0, "nominal_cross_range_m must be > 0"),
    ]
    check_all(checks)
    require_finite_params(p)


def simulate(p: dict, runs: int, seed: int) -> SimulatedData:
    """Simulate ``runs`` Monte Carlo runs of the scenario ``p``.

    Returns
    -------
    SimulatedData
        ``/radar/plots`` (ragged ``range_m``, ``bearing_rad``) and ``/radar/truth``
        (``state`` = [x, y, ẋ, ẏ]) on a common scan-time axis.
    """
    validate(p)
    rng = np.random.default_rng(seed)
    K = int(p["n_scans"])
    T = float(p["scan_period_s"])
    times = np.arange(K) * T
    accel = rng.standard_normal((runs, K, 2)) * p["truth_process_noise_mps2"]
    range_noise = rng.standard_normal((runs, K)) * p["sigma_range_m"]
    bearing_noise = rng.standard_normal((runs, K)) * np.deg2rad(p["sigma_bearing_deg"])
    detected = rng.random((runs, K)) < p["detection_probability"]

    state = np.empty((runs, K, 4))
    state[:, 0] = [p["start_x_m"], p["start_y_m"], p["velocity_x_mps"], p["velocity_y_mps"]]
    for k in range(1, K):
        pos, vel = state[:, k - 1, :2], state[:, k - 1, 2:]
        a = accel[:, k]
        state[:, k, :2] = pos + T * vel + 0.5 * T * T * a
        state[:, k, 2:] = vel + T * a
    true_range = np.hypot(state[..., 0], state[..., 1])
    true_bearing = np.arctan2(state[..., 1], state[..., 0])
    meas_range = np.abs(true_range + range_noise)
    meas_bearing = np.angle(np.exp(1j * (true_bearing + bearing_noise)))
    counts = detected.astype(np.int64)
    return SimulatedData(
        times=times,
        fixed={TRUTH_TOPIC: {"state": state}},
        ragged={PLOTS_TOPIC: ({"range_m": meas_range[..., None], "bearing_rad": meas_bearing[..., None]}, counts)},
    )
