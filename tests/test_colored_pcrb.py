"""The posterior Cramér–Rao bound of the colored-noise scenario: against Gaussian conditioning
on the whole measurement history (an independent computation), attained by the exact filter
of the truth's own model on simulated data, and never beaten by the built-in trackers."""

from __future__ import annotations

import numpy as np
import polars as pl
import pytest

from trackreplay.cores.filters.kalman import kf_predict, kf_update
from trackreplay.replay import replay
from trackreplay.trackers.colored import colored_noise_pcrb
from trackreplay.recorders.scenarios import load_scenario
from trackreplay.recorders.simulated import record


def conditioned_covariance(alpha, T: float, q: float, R: float, k: int) -> np.ndarray:
    """Cov([p_k, v_k] | x_0, z_0..z_k) from the joint Gaussian of the noises, by conditioning.

    Every quantity is a linear map of the independent noises (w_1..w_k, ν_0, η_1..η_k), so
    the joint covariance is ``A Aᵀ`` with A built scan by scan; the posterior covariance is
    ``Σ_xx − Σ_xz Σ_zz⁻¹ Σ_zx`` (one solve)."""
    n_noise = 2 * k + 1                                  # w_1..w_k, ν_0, η_1..η_k
    x_map = np.zeros((2, n_noise))                       # x_j − E x_j as a map of the noises
    nu_map = np.zeros(n_noise)
    nu_map[k] = np.sqrt(R)
    rows = [x_map[0] + nu_map]                            # z_0
    Phi, psi = np.array([[1.0, T], [0.0, 1.0]]), np.array([T**2 / 2, T])
    for j in range(1, k + 1):
        x_map = Phi @ x_map
        x_map[:, j - 1] += psi * np.sqrt(q)
        nu_map = alpha[j] * nu_map
        nu_map[k + j] = np.sqrt((1 - alpha[j] ** 2) * R)
        rows.append(x_map[0] + nu_map)
    Z = np.array(rows)
    S_xx, S_xz, S_zz = x_map @ x_map.T, x_map @ Z.T, Z @ Z.T
    return S_xx - S_xz @ np.linalg.solve(S_zz, S_xz.T)


def test_bound_equals_gaussian_conditioning_on_the_whole_history():
    rng = np.random.default_rng(3)
    K, T, q, R = 14, 0.05, 50.0, 100.0
    alpha = rng.uniform(0.3, 0.95, K)
    bound = colored_noise_pcrb(alpha[None, :], np.arange(K) * T, q, R)
    for k in (1, 2, 5, K - 1):
        np.testing.assert_allclose(bound[k], conditioned_covariance(alpha, T, q, R, k), rtol=1e-7, atol=1e-12)


@pytest.fixture(scope="module")
def short_imm(tmp_path_factory):
    path = tmp_path_factory.mktemp("pcrb") / "imm.mcap"
    scenario = load_scenario("colored-imm").with_overrides(
        {"n_samples": 240, "manoeuvre_first_sample": 80, "manoeuvre_last_sample": 160})
    record(path, scenario, runs=200, seed=11)
    return path


def test_the_exact_filter_of_the_truths_model_attains_the_bound(short_imm):
    """A Kalman filter on [p, v, ν] with the known input has the bound as its mean squared error,
    within Monte Carlo error (200 runs × 240 scans)."""
    from trackreplay.contract import read_dataset

    ds = read_dataset(short_imm)
    truth = ds.channels["/colored/truth"]
    state, alpha = truth.grid("state"), truth.grid("alpha")[..., 0]
    z = ds.channels["/colored/measurements"].grid("position_m")[..., 0]
    times = ds.channels["/colored/measurements"].times()
    p = ds.scenario["params"]
    q, R, T = float(p["process_noise_variance"]), float(p["measurement_variance_m2"]), float(times[1] - times[0])
    runs, K = z.shape
    x = np.zeros((runs, 3))
    x[:, :2] = state[:, 0, :2]
    P = np.zeros((runs, 3, 3))
    P[:, 2, 2] = R
    H, Rz = np.array([[1.0, 0.0, 1.0]]), np.zeros((1, 1))
    squared = np.empty((runs, K))
    for k in range(K):
        if k:
            F = np.array([[1.0, T, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 0.0]])
            F = np.broadcast_to(F, (runs, 3, 3)).copy()
            F[:, 2, 2] = alpha[:, k]
            psi = np.array([T**2 / 2, T, 0.0])
            Q = np.zeros((runs, 3, 3))
            Q[:, :2, :2] = q * np.outer(psi, psi)[:2, :2]
            Q[:, 2, 2] = (1 - alpha[:, k] ** 2) * R
            x, P = kf_predict(x, P, F, Q)
            x[:, :2] += psi[:2] * state[:, k - 1, 2][:, None]     # the known input u_{k−1}
        x, P, *_ = kf_update(x, P, z[:, k, None], H, Rz)
        squared[:, k] = (x[:, 0] - state[:, k, 0]) ** 2
    bound = colored_noise_pcrb(alpha, times, q, R)[:, 0, 0]
    late = slice(20, None)
    mse, b = squared[:, late].mean(), bound[late].mean()
    # the time-averaged MSE over runs × scans; scans are correlated, so judge by the spread of
    # per-run averages (independent runs)
    per_run = squared[:, late].mean(axis=1)
    se = per_run.std(ddof=1) / np.sqrt(runs)
    assert abs(mse - b) < 3 * se, (mse, b, se)


def test_no_built_in_tracker_beats_the_bound(short_imm):
    s = replay(short_imm).summary
    eff = s.filter((pl.col("metric") == "position_efficiency") & (pl.col("scope") == "overall"))
    assert set(eff["tracker"]) >= {"kf", "kf_dp", "imm", "mimm_k", "pimm"}
    # efficiency above 1 would be an error below the bound, beyond Monte Carlo error
    assert (eff["ci_low"] < 1.0).all() and (eff["value"] > 0).all()
