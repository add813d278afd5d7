"""Targets seen through position measurements with AR(1) coloured noise (Kwon 1997, ch. II, V).

See ``docs/papers/colored.md``. Measurement per axis ``z_k = p_k + ν_k`` with
``ν_k = α_k ν_{k−1} + η_k``, ``var(η_k) = (1 − α_k²) R`` and ``ν_0 ~ N(0, R)``, so ``var(ν_k) = R``
at every scan even where α changes (eqs. 2.9–2.11). Three trajectories (``trajectory``):

``manoeuvre`` (1-D, scenario ``colored-imm``; thesis ch. V.3)
    ``x_{k+1} = Φ x_k + B u_k + Ψ w_k`` with ``x = [p, v]``, ``B = Ψ = [T²/2, T]``,
    ``w_k ~ N(0, process_noise_variance)``, ``u_k = manoeuvre_acceleration_mps2`` for
    ``manoeuvre_first_sample ≤ k ≤ manoeuvre_last_sample`` (scan index k), else 0.
    α_k = ``alpha_manoeuvre`` on the manoeuvre samples, ``alpha_cv`` elsewhere. The truth's
    acceleration is ``u_k`` (the commanded input; the white process noise is not an acceleration
    any filter can estimate).
``circle`` (2-D, scenario ``colored-circle``; thesis ch. V.2, Fig. 12)
    Uniform circular motion about the origin, radius ``circle_radius_m``, speed ``speed_mps``,
    counter-clockwise from +x; the same α on both axes, independent noise per axis.
``constant-velocity`` (1-D, scenario ``colored-ar``; thesis ch. V.1, Figs. 8–9)
    A non-manoeuvring target; run r has α = ``alpha_values[r mod len(alpha_values)]``, so 250
    runs give 50 per value.

Channels: ``/colored/measurements`` (``position_m``, one per axis) and ``/colored/truth``
(``state`` = [p, v, a] per axis, ``alpha`` and ``noise_m`` = ν per axis). Random numbers are
drawn in a fixed order and shape (process noise, η, ν₀), so a seed fixes every byte and data sets
that differ in one parameter share their noise.
"""

from __future__ import annotations

import numpy as np

from trackreplay import vocabulary as vocab
from trackreplay.errors import InputError, check_all, require_finite_params
from trackreplay.recorders.simulated import SimulatedData

MEASUREMENTS_TOPIC = vocab.CHANNELS["colored_measurements"]
TRUTH_TOPIC = vocab.CHANNELS["colored_truth"]
TRAJECTORIES = ("manoeuvre", "circle", "constant-velocity")


def parse_values(text, name: str) -> np.ndarray:
    """A list of numbers or ``"0.8, 0.4, 0"`` → array; an empty or unreadable list is an :class:`InputError`."""
    items = text if isinstance(text, (list, tuple)) else str(text).replace(";", ",").split(",")
    try:
        values = np.array([float(v) for v in items if str(v).strip()])
    except ValueError:
        raise InputError(f"parameter {name!r}: cannot read {text!r} as a comma-separated list of numbers") from None
    if values.size == 0:
        raise InputError(f"parameter {name!r} is empty")
    return values


def _need(p: dict, *keys) -> None:
    missing = [k for k in keys if k not in p]
    if missing:
        raise InputError(f"trajectory {p.get('trajectory')!r} needs parameter(s) {', '.join(missing)}")


def validate(p: dict) -> None:
    """Reject parameter sets the simulator cannot honour (before any work starts)."""
    traj = p.get("trajectory")
    if traj not in TRAJECTORIES:
        raise InputError(f"trajectory must be one of {', '.join(TRAJECTORIES)}, got {traj!r}")
    _need(p, "sample_period_s", "n_samples", "measurement_variance_m2")
    require_finite_params(p)
    checks = [(p["sample_period_s"] > 0, "sample_period_s must be > 0"),
              (p["n_samples"] >= 4, "n_samples must be ≥ 4 (the AR estimator needs three samples)"),
              (p["measurement_variance_m2"] > 0, "measurement_variance_m2 must be > 0 (R positive definite)")]
    if traj == "manoeuvre":
        _need(p, "start_position_m", "start_velocity_mps", "manoeuvre_acceleration_mps2", "manoeuvre_first_sample",
              "manoeuvre_last_sample", "process_noise_variance", "alpha_cv", "alpha_manoeuvre")
        alphas = [p["alpha_cv"], p["alpha_manoeuvre"]]
        checks += [(p["process_noise_variance"] >= 0, "process_noise_variance must be ≥ 0"),
                   (0 <= p["manoeuvre_first_sample"] <= p["manoeuvre_last_sample"],
                    "need 0 ≤ manoeuvre_first_sample ≤ manoeuvre_last_sample")]
    elif traj == "circle":
        _need(p, "circle_radius_m", "speed_mps", "alpha")
        alphas = [p["alpha"]]
        checks += [(p["circle_radius_m"] > 0, "circle_radius_m must be > 0")]
    else:
        _need(p, "start_position_m", "start_velocity_mps", "alpha_values")
        alphas = list(parse_values(p["alpha_values"], "alpha_values"))
    checks += [(all(-1 < a < 1 for a in alphas), "AR coefficients must lie in (−1, 1) (a stationary AR(1) noise)")]
    check_all(checks)


def _truth(p: dict, runs: int, w: np.ndarray):
    """Truth state (runs, K, 3·axes) and α (runs, K, axes)."""
    K = int(p["n_samples"])
    T = float(p["sample_period_s"])
    k = np.arange(K)
    traj = p["trajectory"]
    if traj == "circle":
        om = p["speed_mps"] / p["circle_radius_m"]
        th = om * T * k
        r = p["circle_radius_m"]
        c, s = np.cos(th), np.sin(th)
        one = np.stack([r * c, -r * om * s, -r * om * om * c, r * s, r * om * c, -r * om * om * s], axis=-1)
        state = np.broadcast_to(one, (runs, K, 6)).copy()
        alpha = np.full((runs, K, 2), float(p["alpha"]))
        return state, alpha
    state = np.zeros((runs, K, 3))
    state[:, 0, 0] = p["start_position_m"]
    state[:, 0, 1] = p["start_velocity_mps"]
    if traj == "manoeuvre":
        on = (k >= p["manoeuvre_first_sample"]) & (k <= p["manoeuvre_last_sample"])
        u = np.where(on, float(p["manoeuvre_acceleration_mps2"]), 0.0)
        accel = u[None, :] + w[..., 0] * np.sqrt(p["process_noise_variance"])
        alpha = np.where(on, p["alpha_manoeuvre"], p["alpha_cv"])[None, :, None].repeat(runs, axis=0)
        state[:, :, 2] = u[None, :]
    else:
        accel = np.zeros((runs, K))
        values = parse_values(p["alpha_values"], "alpha_values")
        alpha = np.broadcast_to(values[np.arange(runs) % values.size][:, None, None], (runs, K, 1)).copy()
    # x_{k+1} = Φ x_k + Ψ a_k with Ψ = [T²/2, T]: closed form through cumulative sums
    dv = T * accel[:, :-1]
    state[:, 1:, 1] = state[:, :1, 1] + np.cumsum(dv, axis=1)
    step = T * state[:, :-1, 1] + 0.5 * T * T * accel[:, :-1]
    state[:, 1:, 0] = state[:, :1, 0] + np.cumsum(step, axis=1)
    return state, alpha


def ar1_noise(alpha: np.ndarray, R: float, eta_std_normal: np.ndarray, nu0_std_normal: np.ndarray) -> np.ndarray:
    """``ν_k = α_k ν_{k−1} + η_k`` with ``var(η_k) = (1 − α_k²) R`` and ``ν_0 ~ N(0, R)``.

    All arrays ``(runs, scans, axes)`` except ``nu0_std_normal`` ``(runs, axes)``; the recursion
    runs along scans, every run and axis at once.
    """
    eta = eta_std_normal * np.sqrt((1.0 - alpha * alpha) * R)
    nu = np.empty_like(eta)
    nu[:, 0] = nu0_std_normal * np.sqrt(R)
    for k in range(1, nu.shape[1]):
        nu[:, k] = alpha[:, k] * nu[:, k - 1] + eta[:, k]
    return nu


def simulate(p: dict, runs: int, seed: int) -> SimulatedData:
    """Simulate ``runs`` Monte Carlo runs of the scenario ``p``.

    Returns
    -------
    SimulatedData
        ``/colored/measurements`` (``position_m``) and ``/colored/truth`` (``state``,
        ``alpha``, ``noise_m``) on a common scan-time axis.
    """
    validate(p)
    axes = 2 if p["trajectory"] == "circle" else 1
    K = int(p["n_samples"])
    rng = np.random.default_rng(seed)
    w = rng.standard_normal((runs, K, axes))
    eta = rng.standard_normal((runs, K, axes))
    nu0 = rng.standard_normal((runs, axes))
    state, alpha = _truth(p, runs, w)
    nu = ar1_noise(alpha, float(p["measurement_variance_m2"]), eta, nu0)
    z = state[..., 0::3] + nu
    times = np.arange(K) * float(p["sample_period_s"])
    return SimulatedData(times=times,
                         fixed={MEASUREMENTS_TOPIC: {"position_m": z},
                                TRUTH_TOPIC: {"state": state, "alpha": alpha, "noise_m": nu}})
