"""One IMM core for models of different state sizes (Kwon 1997 ch. IV.3, V.3)."""

from __future__ import annotations

import numpy as np
import polars as pl
import pytest

from trackreplay import vocabulary as vocab
from trackreplay.errors import InputError
from trackreplay.cores.filters.imm import MeasurementStream, ModelFilter, MotionModel, imm_filter, kinematic_model, single_model_filter
from trackreplay.cores.filters.srif import srif_filter
from trackreplay.recorders.colored_noise import simulate
from trackreplay.recorders.scenarios import load_scenario

T = 0.05
TRANSITION = np.array([[0.99, 0.01, 0.00], [0.33, 0.34, 0.33], [0.00, 0.01, 0.99]])


def small_record(runs=3, scans=300, seed=0):
    p = dict(load_scenario("colored-imm").params)
    p.update(n_samples=scans, manoeuvre_first_sample=100, manoeuvre_last_sample=200)
    d = simulate(p, runs, seed)
    return (d.fixed[vocab.CHANNELS["colored_measurements"]]["position_m"],
            d.fixed[vocab.CHANNELS["colored_truth"]]["state"], p)


def textbook_kf(x0, P0, F, Q, z, R, alpha=None, var=None):
    """A per-run loop written out from the textbook formulas (independent of trackreplay.cores.filters.kalman);
    with alpha/var it filters the decorrelated measurement y_k = z_k − α z_{k−1}, Ĥ = H − α H F⁻¹."""
    runs, scans, _ = z.shape
    n = F.shape[0]
    H = np.zeros((1, n))
    H[0, 0] = 1.0
    Finv = np.linalg.inv(F)
    xs = np.full((runs, scans, n), np.nan)
    for r in range(runs):
        x, P = x0[r].copy(), P0.copy()
        xs[r, 0] = x
        for k in range(1, scans):
            x = F @ x
            P = F @ P @ F.T + Q
            if alpha is None:
                y, h, rr = z[r, k], H, R
            else:
                y, h, rr = z[r, k] - alpha[r, k] * z[r, k - 1], H - alpha[r, k] * H @ Finv, var[r, k]
            S = (h @ P @ h.T)[0, 0] + rr
            K = (P @ h.T)[:, 0] / S
            x = x + K * (y[0] - (h @ x)[0])
            A = np.eye(n) - np.outer(K, h[0])
            P = A @ P @ A.T + rr * np.outer(K, K)
            xs[r, k] = x
    return xs


def test_single_kf_model_equals_that_models_filter_plain_and_decorrelated():
    z, truth, p = small_record()
    model = kinematic_model("ca", 3, T, 1.0, noise="increment")
    P0 = 100 * np.eye(3)
    R = np.array([[100.0]])
    out = single_model_filter(ModelFilter(model), truth[:, 0], P0, MeasurementStream(z, R))
    ref = textbook_kf(truth[:, 0], P0, model.F, model.Q, z, 100.0)
    assert np.max(np.abs(out["state"] - ref)) < 1e-9 * np.abs(ref).max()
    assert np.all(out["model_probabilities"][:, :, 0] == 1.0)
    rng = np.random.default_rng(1)
    alpha = np.clip(0.8 + 0.05 * rng.standard_normal(z.shape), -0.9, 0.9)
    var = 36.0 + rng.random(z.shape)
    out = single_model_filter(ModelFilter(model), truth[:, 0], P0, MeasurementStream(z, R, True, alpha, var))
    ref = textbook_kf(truth[:, 0], P0, model.F, model.Q, z, 100.0, alpha[..., 0], var[..., 0])
    assert np.max(np.abs(out["state"] - ref)) < 1e-9 * np.abs(ref).max()


def test_single_srif_model_equals_the_srif_and_imm_matches_kf_with_srif_models():
    z, truth, _ = small_record()
    model = kinematic_model("ca", 3, T, 400.0)
    P0 = 100 * np.eye(3)
    R = np.array([[100.0]])
    out = single_model_filter(ModelFilter(model, "srif"), truth[:, 0], P0, MeasurementStream(z, R))
    ref = srif_filter(truth[:, 0], P0, model.F, model.G, model.q, model.H, z, R)
    assert np.max(np.abs(out["state"] - ref["state"])) < 1e-9 * np.abs(ref["state"]).max()
    np.testing.assert_allclose(out["covariance"], ref["covariance"], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(out["log_likelihood"][:, 1:, 0], ref["log_likelihood"][:, 1:], rtol=1e-9)
    # the full mixed-size IMM with SRIF models equals the one with Kalman models to rounding error
    models = [kinematic_model("cv", 2, T, 50.0), kinematic_model("a", 3, T, 6400.0), kinematic_model("b", 3, T, 16.0)]
    kf = imm_filter([ModelFilter(m) for m in models], TRANSITION, truth[:, 0], P0, MeasurementStream(z, R))
    sr = imm_filter([ModelFilter(m, "srif") for m in models], TRANSITION, truth[:, 0], P0, MeasurementStream(z, R))
    assert np.max(np.abs(kf["state"] - sr["state"])) < 1e-8 * np.abs(kf["state"]).max()
    assert np.max(np.abs(kf["model_probabilities"] - sr["model_probabilities"])) < 1e-8


def equal_size_imm_reference(z, x0, P0, R, q_cv, q_a, q_b, acc_var):
    """Textbook IMM with three 3-state models, the CV model embedded as a 3-state model whose
    acceleration row/column of Φ are zero and whose process noise puts acc_var on the
    acceleration (a per-run loop with explicit formulas: an independent computation)."""
    F3 = np.array([[1.0, T, T * T / 2], [0.0, 1.0, T], [0.0, 0.0, 1.0]])
    Fcv = np.array([[1.0, T, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 0.0]])
    gcv = np.array([T * T / 2, T, 0.0])
    gca = np.array([T**3 / 6, T * T / 2, T])
    Qcv = q_cv * np.outer(gcv, gcv)
    Qcv[2, 2] = acc_var
    Fs = [Fcv, F3, F3]
    Qs = [Qcv, q_a * np.outer(gca, gca), q_b * np.outer(gca, gca)]
    H = np.array([1.0, 0.0, 0.0])
    runs, scans, _ = z.shape
    out = np.full((runs, scans, 3), np.nan)
    mus = np.full((runs, scans, 3), np.nan)
    for r in range(runs):
        xs = [x0[r].copy() for _ in range(3)]
        Ps = [P0.copy() for _ in range(3)]
        mu = np.full(3, 1 / 3)
        for k in range(1, scans):
            cbar = TRANSITION.T @ mu
            w = TRANSITION * mu[:, None] / cbar[None, :]
            lik = np.empty(3)
            new_x, new_P = [], []
            for j in range(3):
                xm = sum(w[i, j] * xs[i] for i in range(3))
                Pm = sum(w[i, j] * (Ps[i] + np.outer(xs[i] - xm, xs[i] - xm)) for i in range(3))
                x = Fs[j] @ xm
                P = Fs[j] @ Pm @ Fs[j].T + Qs[j]
                S = H @ P @ H + R
                nu = z[r, k, 0] - H @ x
                K = P @ H / S
                x = x + K * nu
                A = np.eye(3) - np.outer(K, H)
                P = A @ P @ A.T + R * np.outer(K, K)
                lik[j] = np.exp(-0.5 * nu * nu / S) / np.sqrt(2 * np.pi * S)
                new_x.append(x)
                new_P.append(P)
            xs, Ps = new_x, new_P
            mu = cbar * lik / np.sum(cbar * lik)
            out[r, k] = sum(mu[j] * xs[j] for j in range(3))
            mus[r, k] = mu
    return out, mus


def test_mixed_size_imm_equals_equal_size_imm_with_the_stated_embedding():
    z, truth, _ = small_record(runs=2, scans=250, seed=3)
    P0 = 100 * np.eye(3)
    models = [kinematic_model("cv", 2, T, 50.0), kinematic_model("a", 3, T, 6400.0), kinematic_model("b", 3, T, 16.0)]
    ours = imm_filter([ModelFilter(m) for m in models], TRANSITION, truth[:, 0], P0, MeasurementStream(z, [[100.0]]))
    ref, mu_ref = equal_size_imm_reference(z, truth[:, 0], P0, 100.0, 50.0, 6400.0, 16.0, acc_var=50.0)
    assert np.max(np.abs(ours["state"][:, 1:] - ref[:, 1:])) < 1e-8 * np.abs(ref[:, 1:]).max()
    assert np.max(np.abs(ours["model_probabilities"][:, 1:] - mu_ref[:, 1:])) < 1e-9
    # and the embedding variance matters: a different fill gives a different IMM
    ref2, _ = equal_size_imm_reference(z, truth[:, 0], P0, 100.0, 50.0, 6400.0, 16.0, acc_var=5000.0)
    assert np.max(np.abs(ours["state"][:, 1:] - ref2[:, 1:])) > 1e-3


@pytest.fixture(scope="module")
def thesis_experiment(tmp_path_factory):
    """The thesis's IMM comparison: 50 runs of colored-imm through the real recorder and replay."""
    from trackreplay.replay import replay
    from trackreplay.recorders.simulated import record

    path = tmp_path_factory.mktemp("colored") / "imm50.mcap"
    record(path, load_scenario("colored-imm"), runs=50, seed=2024)
    return replay(path, trackers=["imm", "mimm_k", "pimm"])


def metric(res, tracker, name, scope="overall"):
    s = res.summary
    v = s.filter((pl.col("tracker") == tracker) & (pl.col("metric") == name) & (pl.col("scope") == scope))["value"]
    assert len(v) == 1, (tracker, name, scope)
    return float(v[0])


def test_ca_models_dominate_in_the_manoeuvre_and_cv_outside(thesis_experiment):
    res = thesis_experiment
    for t in ("imm", "mimm_k", "pimm"):
        ca = metric(res, t, "prob_ca_transition", "manoeuvre") + metric(res, t, "prob_ca_steady", "manoeuvre")
        cv_in = metric(res, t, "prob_cv", "manoeuvre")
        cv_out = metric(res, t, "prob_cv", "constant_velocity")
        assert ca > 0.5 > cv_in, (t, ca, cv_in)
        assert cv_out > 0.5, (t, cv_out)
        # per scan: well inside the manoeuvre the CA models hold most of the probability
        part = res.per_scan.filter((pl.col("tracker") == t) & pl.col("scan").is_between(500, 800))
        assert (part["prob_ca_transition"] + part["prob_ca_steady"]).min() > 0.5


def test_decorrelating_imms_beat_the_standard_imm_in_velocity_and_acceleration(thesis_experiment):
    res = thesis_experiment
    for t in ("mimm_k", "pimm"):
        for m in ("rmse_velocity_mps", "rmse_acceleration_mps2"):
            assert metric(res, t, m) < metric(res, "imm", m), (t, m)


def test_pimm_equals_mimm_k(thesis_experiment):
    """The SRIF is algebraically the Kalman filter: PIMM ≈ MIMM_K in position (and everywhere)."""
    res = thesis_experiment
    for m in ("rmse_position_m", "rmse_velocity_mps", "rmse_acceleration_mps2"):
        a, b = metric(res, "pimm", m), metric(res, "mimm_k", m)
        assert abs(a - b) <= 1e-6 * b
    tracks = res.results["colored"]["tracks"]
    assert np.max(np.abs(tracks["pimm"]["state"][..., 0] - tracks["mimm_k"]["state"][..., 0])) < 1e-6


def test_before_the_estimator_is_warm_the_decorrelating_imm_is_the_plain_one(thesis_experiment):
    tracks = thesis_experiment.results["colored"]["tracks"]
    warm = tracks["ar_estimator"]["warm"][0].astype(bool)
    first_warm = int(np.argmax(warm))
    a, b = tracks["mimm_k"]["state"][:, :first_warm], tracks["imm"]["state"][:, :first_warm]
    assert np.max(np.abs(a - b)) == 0.0
    assert np.all((tracks["mimm_k"]["flags"][:, :first_warm] & vocab.NOT_WARM) > 0)
    assert not np.any(tracks["mimm_k"]["flags"][:, first_warm:] & vocab.NOT_WARM)


# --------------------------------------------------------------------------- bad input


@pytest.mark.parametrize("bad", [[[0.9, 0.2, 0.0], [0.33, 0.34, 0.33], [0.0, 0.01, 0.99]],
                                 [[0.99, 0.01], [0.01, 0.99]],
                                 [[1.1, -0.1, 0.0], [0.33, 0.34, 0.33], [0.0, 0.01, 0.99]],
                                 [[0.99, 0.01, 0.0], [0.5, 0.5, 0.0], [0.0, 1.0, 0.0]]])
def test_bad_transition_matrix_is_a_clear_error(bad):
    z, truth, _ = small_record(runs=1, scans=10)
    models = [kinematic_model("cv", 2, T, 50.0), kinematic_model("a", 3, T, 6400.0), kinematic_model("b", 3, T, 16.0)]
    with pytest.raises(InputError, match="transition matrix"):
        imm_filter([ModelFilter(m) for m in models], bad, truth[:, 0], np.eye(3), MeasurementStream(z, [[100.0]]))


def test_singular_phi_is_a_clear_error():
    F = np.array([[1.0, T], [0.0, 0.0]])
    with pytest.raises(InputError, match="singular"):
        MotionModel("broken", F, np.array([[T * T / 2], [T]]), np.eye(1), np.array([[1.0, 0.0]]),
                    np.array([0, 1]), np.zeros(3), np.zeros((3, 3)))


@pytest.mark.parametrize("R", [[[0.0]], [[-4.0]], [[np.nan]]])
def test_measurement_covariance_not_positive_definite_is_a_clear_error(R):
    z, _, _ = small_record(runs=1, scans=10)
    with pytest.raises(InputError, match="R"):
        MeasurementStream(z, R)


def test_nan_measurement_is_a_clear_error():
    z, _, _ = small_record(runs=1, scans=10)
    z[0, 5, 0] = np.nan
    with pytest.raises(InputError, match="NaN"):
        MeasurementStream(z, [[100.0]])
