"""The multi-target radar trackers (GNN, JPDA) and the pieces they are made of: the generalised
JPDA core against a brute-force enumeration of joint events, the per-track filter against the
plain Kalman filter, the clustering against transitive closure, and tracking that finds every
target of a clean scene without an identity switch."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from trackreplay.cores.association.gnn import gnn_assignment
from trackreplay.cores.association._jpda_fast import joint_association_probabilities
from trackreplay.cores.association.jpda import (
    association_marginals,
    cluster_tracks,
    gaussian_likelihood_ratio,
    pda_update,
    pda_update_gaussian,
)
from trackreplay.cores.filters.kalman import kalman_gain, kf_update
from trackreplay.cores.filters.track_filter import PolarConstantVelocityEKF, squared_distances, wrap_angle


def _closure_labels(gated):
    """The clusters by transitive closure of the tracks-share-a-peak relation (the definition)."""
    R, T, _ = gated.shape
    out = np.zeros((R, T), np.int64)
    for r in range(R):
        share = (gated[r].astype(int) @ gated[r].T.astype(int) > 0) | np.eye(T, dtype=bool)
        reach = share.copy()
        for _ in range(T):
            reach = (reach.astype(int) @ share.astype(int)) > 0
        out[r] = np.argmax(reach, axis=1)
    return out


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 3), st.integers(1, 9), st.integers(0, 7), st.floats(0.05, 0.6), st.integers(0, 2**31))
def test_clusters_are_the_transitive_closure(R, T, m, density, seed):
    gated = np.random.default_rng(seed).random((R, T, m)) < density
    assert np.array_equal(cluster_tracks(gated), _closure_labels(gated))


def _brute_force_marginals(ratio, miss):
    """β by enumerating every joint event (each track one plot or none, each plot at most one
    track), the definition of the JPDA marginals."""
    s, m = ratio.shape
    beta, beta0, total = np.zeros((s, m)), np.zeros(s), 0.0
    for choice in itertools.product(range(-1, m), repeat=s):
        used = [c for c in choice if c >= 0]
        if len(used) != len(set(used)):
            continue
        w = np.prod([ratio[t, c] if c >= 0 else miss[t] for t, c in enumerate(choice)])
        total += w
        for t, c in enumerate(choice):
            if c >= 0:
                beta[t, c] += w
            else:
                beta0[t] += w
    return beta / total, beta0 / total


def _radar_scene(seed, tracks, plots):
    """Predicted radar tracks close together and plots around them, as the JPDA sees them."""
    rng = np.random.default_rng(seed)
    f = PolarConstantVelocityEKF(1.0, 20.0, np.deg2rad(0.2), 100.0)
    x = np.zeros((1, tracks, 4))
    x[..., 0] = 20e3 + rng.normal(0, 60, tracks)
    x[..., 1] = 10e3 + rng.normal(0, 60, tracks)
    P = np.broadcast_to(np.diag([900.0, 900.0, 100.0, 100.0]), (1, tracks, 4, 4)).copy()
    z_pred, H, S = f.predict_measurement(x, P)
    z = z_pred[:, rng.integers(0, tracks, plots)] + rng.normal(0, 1, (1, plots, 2)) * [40.0, np.deg2rad(0.3)]
    nu = f.innovations(z, z_pred)
    d2 = squared_distances(nu, S)
    return f, x, P, H, S, nu, d2


@pytest.mark.parametrize("seed", range(6))
def test_radar_jpda_marginals_match_brute_force(seed):
    f, x, P, H, S, nu, d2 = _radar_scene(seed, tracks=3 + seed % 2, plots=4)
    gated = d2 <= 16.0
    det = np.linalg.det(S)
    ratio = gaussian_likelihood_ratio(d2, det, 0.9, 1e-4)
    miss = np.full(gated.shape[:-1], 1 - 0.9 * 0.9997)
    beta, beta0, split = joint_association_probabilities(ratio, miss, gated, x[..., 0], 12)
    exact_beta, exact_beta0 = _brute_force_marginals(np.where(gated, ratio, 0.0)[0], miss[0])
    assert not split.any()
    np.testing.assert_allclose(beta[0], exact_beta, rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(beta0[0], exact_beta0, rtol=1e-10, atol=1e-14)


@pytest.mark.parametrize("seed", range(4))
def test_bearing_jpda_marginals_match_brute_force(seed):
    rng = np.random.default_rng(seed)
    ratio = rng.gamma(1.0, 2.0, (1, 4, 5)) * (rng.random((1, 4, 5)) < 0.7)
    miss = rng.uniform(0.05, 0.5, (1, 4))
    beta, beta0 = association_marginals(ratio, miss)
    exact_beta, exact_beta0 = _brute_force_marginals(ratio[0], miss[0])
    np.testing.assert_allclose(beta[0], exact_beta, rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(beta0[0], exact_beta0, rtol=1e-10, atol=1e-14)


def test_general_pda_update_is_the_bearing_one_in_one_dimension():
    rng = np.random.default_rng(3)
    B, W = 7, 5
    A = rng.normal(size=(B, 2, 2))
    P = A @ np.swapaxes(A, -1, -2) + np.eye(2)
    x = rng.normal(size=(B, 2))
    H = np.array([[1.0, 0.0]])
    R = np.full((B, 1, 1), 0.3)
    K, S = kalman_gain(P, H, R)
    nu = rng.normal(size=(B, W))
    gated = rng.random((B, W)) < 0.7
    beta = rng.random((B, W)) * gated
    beta0 = rng.random(B)
    total = beta.sum(axis=1) + beta0
    beta, beta0 = beta / total[:, None], beta0 / total
    x1, P1, nu1 = pda_update(x, P.reshape(B, 4), K[..., 0], S[:, 0, 0], nu, gated, beta, beta0)
    x2, P2, nu2 = pda_update_gaussian(x, P, K, S, nu[..., None], gated, beta, beta0)
    np.testing.assert_allclose(x2, x1, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(P2.reshape(B, 4), P1, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(nu2[..., 0], nu1, rtol=1e-12, atol=1e-12)


def test_pda_update_with_one_certain_plot_is_the_kalman_update():
    f, x, P, H, S, nu, d2 = _radar_scene(1, tracks=2, plots=3)
    K, _ = kalman_gain(P, H, f.measurement_covariance())
    beta = np.zeros(d2.shape)
    beta[0, 0, 1] = beta[0, 1, 2] = 1.0
    x_pda, P_pda, _ = pda_update_gaussian(x, P, K, S, nu, np.ones(d2.shape, bool), beta, np.zeros((1, 2)))
    x_kf, P_kf, _ = f.update(x, P, H, S, np.stack([nu[0, 0, 1], nu[0, 1, 2]])[None])
    np.testing.assert_allclose(x_pda, x_kf, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(P_pda, P_kf, rtol=1e-9, atol=1e-9)


def test_ekf_update_is_the_one_kalman_update_on_the_linearised_model():
    f, x, P, H, S, nu, _ = _radar_scene(2, tracks=3, plots=3)
    picked = nu[:, :, 0]
    x_post, P_post, _ = f.update(x, P, H, S, picked)
    z = picked + np.einsum("...ij,...j->...i", H, x)  # the linear model's measurement
    x_ref, P_ref, _, S_ref, _ = kf_update(x, P, z, H, f.measurement_covariance())
    np.testing.assert_allclose(S, S_ref, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(x_post, x_ref, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(P_post, P_ref, rtol=1e-9, atol=1e-9)


@settings(max_examples=80, deadline=None)
@given(T=st.integers(1, 5), W=st.integers(0, 5), seed=st.integers(0, 2**31))
@pytest.mark.parametrize("sparse", [True, False])
def test_gnn_assignment_is_the_cheapest_gated_assignment(T, W, seed, sparse):
    rng = np.random.default_rng(seed)
    cost = rng.uniform(0, 10, (1, T, W))
    gated = rng.random((1, T, W)) < 0.6
    miss = rng.uniform(2, 8, (1, T))
    plot = gnn_assignment(cost, gated, miss, sparse=sparse)[0]
    assert len(set(plot[plot >= 0])) == (plot >= 0).sum()
    assert all(gated[0, t, p] for t, p in enumerate(plot) if p >= 0)

    def total(choice):
        return sum(cost[0, t, c] if c >= 0 else miss[0, t] for t, c in enumerate(choice))

    best = min(total(c) for c in itertools.product(range(-1, W), repeat=T)
               if len({x for x in c if x >= 0}) == sum(x >= 0 for x in c)
               and all(x < 0 or gated[0, t, x] for t, x in enumerate(c)))
    assert total(plot) == pytest.approx(best, rel=1e-12, abs=1e-12)


def test_ukf_measurement_prediction_tends_to_the_ekf_one_as_the_covariance_shrinks():
    from trackreplay.cores.filters.track_filter import PolarConstantVelocityUKF

    f, x, P, H, S, nu, _ = _radar_scene(4, tracks=3, plots=1)
    u = PolarConstantVelocityUKF(1.0, 20.0, np.deg2rad(0.2), 100.0)
    R = f.measurement_covariance()
    for scale, tol in ((1.0, 1e-3), (1e-4, 1e-6)):
        z_e, H_e, S_e = f.predict_measurement(x, scale * P)
        z_u, H_u, S_u = u.predict_measurement(x, scale * P)
        np.testing.assert_allclose(z_u[..., 0], z_e[..., 0], rtol=tol)
        np.testing.assert_allclose(z_u[..., 1], z_e[..., 1], rtol=tol, atol=tol * 1e-3)
        # the spread part of S (S − R) agrees with the linearisation's to the same order, entry by
        # entry relative to its diagonal (range and bearing differ by ten orders of magnitude)
        spread_u, spread_e = S_u - R, S_e - R
        d = np.sqrt(np.einsum("...ii->...i", spread_e))
        norm = d[..., :, None] * d[..., None, :]
        np.testing.assert_allclose(spread_u / norm, spread_e / norm, rtol=0, atol=tol * 10)


def test_ukf_sigma_points_carry_the_mean_and_covariance_exactly_through_a_linear_map():
    """On an (almost) linear stretch of the measurement function the unscented transform is exact:
    a target far out, a tiny covariance — the UKF's statistical linearisation is then the Jacobian."""
    from trackreplay.cores.filters.track_filter import PolarConstantVelocityUKF

    u = PolarConstantVelocityUKF(1.0, 20.0, np.deg2rad(0.2), 100.0)
    f = PolarConstantVelocityEKF(1.0, 20.0, np.deg2rad(0.2), 100.0)
    x = np.array([[[3e6, 4e6, 10.0, -5.0]]])
    P = np.diag([1.0, 2.0, 0.5, 0.5])[None, None]
    _, H_u, _ = u.predict_measurement(x, P)
    _, H_e, _ = f.predict_measurement(x, P)
    np.testing.assert_allclose(H_u, H_e, rtol=1e-5, atol=1e-15)


def test_squared_distances_written_out_equal_the_general_contraction():
    from trackreplay.cores.filters.track_filter import _squared_distance_2x2

    _, _, _, _, S, nu, _ = _radar_scene(5, tracks=6, plots=9)
    general = np.einsum("...wi,...ij,...wj->...w", nu, np.linalg.inv(S), nu)
    np.testing.assert_allclose(_squared_distance_2x2(nu, S[..., None, :, :]), general, rtol=1e-9)


def test_innovation_bearings_are_wrapped_as_wrap_angle_does():
    from trackreplay.cores.filters.track_filter import wrap_angle

    f = PolarConstantVelocityEKF(1.0, 20.0, np.deg2rad(0.2), 100.0)
    rng = np.random.default_rng(8)
    z = np.stack([rng.uniform(1e3, 5e4, (1, 40)), rng.uniform(-np.pi, np.pi, (1, 40))], axis=-1)
    z[0, :4, 1] = [np.pi, -np.pi, np.pi - 1e-12, -np.pi + 1e-12]
    z_pred = np.stack([rng.uniform(1e3, 5e4, (1, 30)), rng.uniform(-np.pi, np.pi, (1, 30))], axis=-1)
    z_pred[0, :2, 1] = [np.pi, -np.pi]
    nu = f.innovations(z, z_pred)
    expected = wrap_angle(z[..., None, :, 1] - z_pred[..., :, None, 1])
    np.testing.assert_allclose(nu[..., 1], expected, rtol=0, atol=1e-12)
    assert np.all(nu[..., 1] >= -np.pi) and np.all(nu[..., 1] < np.pi)


@pytest.mark.parametrize("seed", range(3))
def test_clustered_marginals_equal_the_joint_recursion_over_every_track_and_peak(seed):
    """The clustered path's fast forms (a lone track in closed form; each cluster on its own
    peaks) against the plain recursion over all tracks and all peaks of the scan at once."""
    rng = np.random.default_rng(seed)
    R, T, m = 4, 8, 14
    ratio = rng.exponential(1.0, (R, T, m))
    gated = rng.random((R, T, m)) < 0.12               # sparse: singletons, pairs, a few larger clusters
    miss = rng.uniform(0.05, 1.0, (R, T))
    beta, beta0, split = joint_association_probabilities(ratio, miss, gated, rng.random((R, T)), 12, clustering=True)
    plain, plain0 = association_marginals(np.where(gated, ratio, 0.0), miss)
    assert not split.any()
    np.testing.assert_allclose(beta, plain, rtol=1e-10, atol=1e-13)
    np.testing.assert_allclose(beta0, plain0, rtol=1e-10, atol=1e-13)


class _Cartesian(PolarConstantVelocityEKF):
    """The same filter with its windows along range, a component that does not wrap."""

    window_component = 0
    window_period = None


@settings(max_examples=80, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), runs=st.integers(1, 4), tracks=st.integers(0, 12),
       plots=st.integers(0, 30), spread_rad=st.sampled_from([1e-4, 0.05, 1.0, 3.0, 10.0]),
       near_the_cut=st.booleans(), cartesian=st.booleans())
def test_gating_through_windows_gives_every_pair_the_definition_gives(seed, runs, tracks, plots, spread_rad,
                                                                     near_the_cut, cartesian):
    """The coarse windows (sorted plots, a binary search per track, wrapping at ±π) find exactly
    the pairs of every track against every plot, in the same order, with the same d²; gates
    from slivers to wider than the circle, bearings on both sides of ±π, empty slots and padding."""
    from trackreplay.cores.association.gating import gate_pairs

    rng = np.random.default_rng(seed)
    f = (_Cartesian if cartesian else PolarConstantVelocityEKF)(1.0, 20.0, np.deg2rad(0.2), 100.0)
    centre = np.pi if near_the_cut else 0.0
    z = np.stack([rng.uniform(1e3, 3e3, (runs, plots)),
                  wrap_angle(centre + rng.uniform(-0.2, 0.2, (runs, plots)))], axis=-1)
    valid = rng.random((runs, plots)) < 0.8
    z = np.where(valid[..., None], z, np.nan)
    z_pred = np.stack([rng.uniform(1e3, 3e3, (runs, tracks)),
                       wrap_angle(centre + rng.uniform(-0.2, 0.2, (runs, tracks)))], axis=-1)
    sd = np.stack([rng.uniform(10, 800, (runs, tracks)), rng.uniform(0.1, 1.0, (runs, tracks)) * spread_rad],
                  axis=-1)
    rho = rng.uniform(-0.9, 0.9, (runs, tracks))
    S = np.empty((runs, tracks, 2, 2))
    S[..., 0, 0], S[..., 1, 1] = sd[..., 0] ** 2, sd[..., 1] ** 2
    S[..., 0, 1] = S[..., 1, 0] = rho * sd[..., 0] * sd[..., 1]
    live = rng.random((runs, tracks)) < 0.85
    plain = gate_pairs(f, z, valid, z_pred, S, 16.0, live, windows=False)
    fast = gate_pairs(f, z, valid, z_pred, S, 16.0, live, windows=True)
    np.testing.assert_array_equal(fast.plot, plain.plot)
    np.testing.assert_array_equal(fast.squared_distance, plain.squared_distance)
    np.testing.assert_array_equal(fast.innovation, plain.innovation)
    assert fast.plots == plain.plots == plots


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), runs=st.integers(1, 4), tracks=st.integers(1, 10), peaks=st.integers(0, 14),
       density=st.sampled_from([0.05, 0.15, 0.4]), max_cluster=st.integers(2, 12))
def test_jpda_from_pairs_equals_the_dense_layout(seed, runs, tracks, peaks, density, max_cluster):
    """The pair-driven JPDA (sparse components, each group on its own peaks) gives the β, β₀ and
    cut flags of the dense ``(R, T, m)`` clustered path, clusters cut or whole."""
    from trackreplay.cores.association._jpda_fast import pair_association_probabilities

    rng = np.random.default_rng(seed)
    ratio = rng.exponential(1.0, (runs, tracks, peaks))
    gated = rng.random((runs, tracks, peaks)) < density
    miss = rng.uniform(0.05, 1.0, (runs, tracks))
    bearing = rng.random((runs, tracks))
    beta, beta0, split = joint_association_probabilities(ratio, miss, gated, bearing, max_cluster, clustering=True)
    run, trk, peak = np.nonzero(gated)
    b, b0, cut = pair_association_probabilities(ratio[run, trk, peak], run * tracks + trk, run * peaks + peak,
                                                miss.ravel(), bearing.ravel(), max_cluster)
    np.testing.assert_allclose(b, beta[run, trk, peak], rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(b0.reshape(runs, tracks), beta0, rtol=1e-12, atol=1e-15)
    np.testing.assert_array_equal(cut.reshape(runs, tracks), split)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), runs=st.integers(1, 5), tracks=st.integers(0, 12), plots=st.integers(0, 12),
       density=st.sampled_from([0.05, 0.2, 0.6]))
def test_gnn_assignment_on_the_gated_pairs_equals_one_dense_problem_per_run(seed, runs, tracks, plots, density):
    """The sparse form (lone pairs settled at once, the rest one matching over every run) picks
    what linear_sum_assignment on each run's full matrix picks (costs of either sign)."""
    rng = np.random.default_rng(seed)
    cost = rng.uniform(-5, 10, (runs, tracks, plots))
    gated = rng.random((runs, tracks, plots)) < density
    miss = rng.uniform(-2, 8, (runs, tracks))
    np.testing.assert_array_equal(gnn_assignment(cost, gated, miss, sparse=True),
                                  gnn_assignment(cost, gated, miss, sparse=False))
    # the rest as one sparse matching (what many runs' scans take) rather than a dense matrix
    from trackreplay.cores.association.gnn import pair_assignment

    b, t, w = np.nonzero(gated)
    chosen = pair_assignment(cost[b, t, w], b * tracks + t, b * plots + w, miss.ravel(), dense_entries=0)
    # plot numbers far apart (renumbered densely inside) choose the same pairs
    np.testing.assert_array_equal(pair_assignment(cost[b, t, w], b * tracks + t, (b * plots + w) * 100_003 + 7,
                                                  miss.ravel(), dense_entries=0), chosen)
    sparse_plot = np.full((runs, tracks), -1)
    sparse_plot[b[chosen], t[chosen]] = w[chosen]
    np.testing.assert_array_equal(sparse_plot, gnn_assignment(cost, gated, miss, sparse=False))


def test_covariance_prediction_as_one_product_equals_F_P_Ft():
    from trackreplay.cores.filters.track_filter import _congruence, _cv_model

    rng = np.random.default_rng(3)
    F, _ = _cv_model(0.7, 5.0)
    A = rng.normal(size=(3, 7, 4, 4))
    P = A @ np.swapaxes(A, -1, -2)
    np.testing.assert_allclose(_congruence(F, P), F @ P @ F.T, rtol=1e-13, atol=1e-13)


@pytest.mark.parametrize("name", ["gnn", "jpda_mt"])
def test_bearings_given_over_zero_to_two_pi_track_as_the_same_plots_in_minus_pi_to_pi(name):
    """A recording may give bearings over [0, 2π), or a turn beyond: the trackers see the same
    plots and give the same tracks as with bearings in [−π, π)."""
    from trackreplay.trackers.interface import RadarPlots
    from trackreplay.trackers.radar_multi_target import TRACKERS
    from trackreplay.recorders.radar_multi import simulate
    from trackreplay.recorders.scenarios import load_scenario
    from trackreplay import vocabulary as vocab

    params = dict(load_scenario("radar-multi").params, n_scans=25, sector_half_width_deg=180.0)
    data = simulate(params, 2, 5)
    values, counts = data.ragged[vocab.CHANNELS["radar_plots"]]
    rng, brg = values["range_m"], values["bearing_rad"]
    times = data.times_s if hasattr(data, "times_s") else np.arange(counts.shape[1]) * params["scan_period_s"]
    tracker = {c.name: c for c in TRACKERS}[name](sigma_range_m=params["sigma_range_m"],
                                                   sigma_bearing_deg=params["sigma_bearing_deg"],
                                                   clutter_per_scan=params["clutter_per_scan"],
                                                   sector_half_width_deg=180.0)
    plain = tracker.track(RadarPlots(range_m=rng, bearing_rad=brg, counts=counts, times_s=times))
    turned = np.where(brg < 0, brg + 2 * np.pi, brg + 4 * np.pi * (brg > 1.0))  # over [0, 2π) and turns beyond
    assert (turned < 0).sum() == 0 and (turned > 4 * np.pi).any()
    other = tracker.track(RadarPlots(range_m=rng, bearing_rad=turned, counts=counts, times_s=times))
    np.testing.assert_array_equal(other["track_id"], plain["track_id"])
    np.testing.assert_allclose(other["state"], plain["state"], rtol=1e-9, atol=1e-6)


def test_innovation_covariance_written_out_equals_H_P_Ht_plus_R():
    from trackreplay.cores.filters.track_filter import _position_innovation_covariance

    rng = np.random.default_rng(5)
    A = rng.normal(size=(3, 6, 4, 4))
    P = A @ np.swapaxes(A, -1, -2)
    H = np.zeros((3, 6, 2, 4))
    H[..., :2] = rng.normal(size=(3, 6, 2, 2))
    R = np.array([[400.0, 0.0], [0.0, 1e-5]])
    expected = H @ P @ np.swapaxes(H, -1, -2) + R
    np.testing.assert_allclose(_position_innovation_covariance(H, P, R), 0.5 * (expected + np.swapaxes(expected, -1, -2)),
                               rtol=1e-12, atol=1e-12)


def test_gain_from_a_given_two_by_two_S_equals_the_batched_solve():
    rng = np.random.default_rng(6)
    A = rng.normal(size=(5, 4, 4))
    P = A @ np.swapaxes(A, -1, -2)
    H = rng.normal(size=(5, 2, 4))
    R = np.diag([400.0, 1e-5])
    K_solve, S = kalman_gain(P, H, R)
    K_given, _ = kalman_gain(P, H, R, S)
    np.testing.assert_allclose(K_given, K_solve, rtol=1e-10, atol=1e-14)


def test_joseph_products_contracted_equal_the_matmul_form():
    from trackreplay.cores.filters._kalman_fast import _joseph_terms_contracted

    rng = np.random.default_rng(7)
    A, P = rng.normal(size=(600, 4, 4)), rng.normal(size=(600, 4, 4))
    K, R = rng.normal(size=(600, 4, 2)), np.diag([400.0, 1e-5])
    np.testing.assert_allclose(_joseph_terms_contracted(A, P, K, R),
                               A @ P @ np.swapaxes(A, -1, -2) + K @ R @ np.swapaxes(K, -1, -2), rtol=1e-13, atol=1e-12)


def test_covariance_prediction_of_a_slot_window_per_run_equals_F_P_Ft():
    """The tracker predicts a window of every run's slots, a view that is not contiguous; the
    product keeps the runs as a batch axis (one small BLAS call per run: one call over every
    run's tracks woke OpenBLAS's threads) and equals F P Fᵀ to rounding, run by run."""
    from trackreplay.cores.filters.track_filter import _congruence, _cv_model

    rng = np.random.default_rng(4)
    F, _ = _cv_model(1.0, 1.0)
    A = rng.normal(size=(5, 40, 4, 4))
    P = (A @ np.swapaxes(A, -1, -2))[:, :23]
    got = _congruence(F, P)
    assert got.shape == P.shape
    np.testing.assert_allclose(got, F @ P @ F.T, rtol=1e-13, atol=1e-13)
    np.testing.assert_array_equal(got[2], _congruence(F, P[2]))


def test_cheapest_pair_of_each_track_by_runs_of_tracks_equals_the_sorted_form():
    """pair_assignment's tracks alone take their cheapest pair: pairs given by track take one
    minimum per track, others a stable sort; the same pairs, ties going to the first in order."""
    from trackreplay.cores.association.gnn import _cheapest_of_each_track

    rng = np.random.default_rng(5)
    track = np.sort(rng.integers(0, 60, 400))
    cost = rng.integers(0, 6, 400).astype(float)  # many ties
    pairs = np.flatnonzero(rng.random(400) < 0.7)
    by_runs = _cheapest_of_each_track(pairs, cost, track)
    # the tracks in another order, each track's pairs keeping theirs: the sorted form
    order = np.argsort(rng.random(60)[track], kind="stable")
    inverse = np.argsort(order)
    assert not (np.diff(track[order]) >= 0).all()
    sorted_form = _cheapest_of_each_track(np.sort(inverse[pairs]), cost[order], track[order])
    np.testing.assert_array_equal(np.sort(order[sorted_form]), by_runs)
    assert _cheapest_of_each_track(np.array([], np.int64), cost, track).size == 0
