"""One long recording, fast (issue 27): every fast form equal to the plain form it stands for.

The radar trackers take stretches of steady scans as blocks (``track_plots(scan_blocks=True)``,
the default) and the CV Kalman kernel has scan-axis fast forms; each is held here to the plain
scan-by-scan form, bit for bit, on plots that reach every branch: misses (coasting, deletion,
restarts), tentative tracks, start-up gains, clamped approximate gains and floored variances
next to the radar, one run (Python floats) and many (arrays).
"""

from types import SimpleNamespace

import numpy as np
import pytest

from trackreplay import vocabulary as vocab
from trackreplay.cores.filters import _kalman_fast, kalman
from trackreplay.trackers import radar_tws as rt

BASE = dict(scan_period_s=5.0, design_sigma_v_mps2=0.98, sigma_range_m=100.0, sigma_bearing_deg=1.0,
            nominal_cross_range_m=150.0, startup_gains=True)


def _plots(n_runs, n_scans, seed, detection=0.9, pass_distance_m=3000.0, sigma_range_m=100.0):
    """Plots of a straight-line target passing ``pass_distance_m`` from the radar (jittered scan
    times, misses with probability 1 − ``detection``): (range, bearing, counts, times)."""
    rng = np.random.default_rng(seed)
    times = np.cumsum(np.r_[0.0, 5.0 + rng.uniform(-0.05, 0.05, n_scans - 1)])
    t = times - times[n_scans // 2]
    x = 20.0 * t[None, :] + rng.normal(0, 50, (n_runs, 1))
    y = pass_distance_m + 0.0 * t[None, :] + rng.normal(0, 5, (n_runs, 1))
    r = np.hypot(x, y) + rng.normal(0, sigma_range_m, x.shape)
    b = np.arctan2(y, x) + rng.normal(0, np.deg2rad(1.0), x.shape)
    counts = (rng.random((n_runs, n_scans)) < detection).astype(np.int64)
    r = np.where(counts > 0, np.abs(r), np.nan)[..., None]
    b = np.where(counts > 0, b, np.nan)[..., None]
    return r, b, counts, times


def _both(plots, strategy, **design):
    tracker = next(c for c in rt.TRACKERS if c.name == strategy)(**{**BASE, **design})
    args = (*plots, tracker.tracker_design, rt.STRATEGIES[strategy])
    return rt.track_plots(*args, scan_blocks=True), rt.track_plots(*args, scan_blocks=False)


def _assert_same(fast, plain):
    assert fast.keys() == plain.keys()
    for name in plain:
        assert fast[name].dtype == plain[name].dtype, name
        np.testing.assert_array_equal(fast[name], plain[name], err_msg=name)


@pytest.mark.parametrize("strategy", ["fixed", "approximate", "exact", "kalman"])
@pytest.mark.parametrize("n_runs", [1, 3, 9])
def test_scan_blocks_equal_the_scan_loop_bit_for_bit(strategy, n_runs):
    plots = _plots(n_runs, 160, seed=n_runs, detection=0.93)
    fast, plain = _both(plots, strategy)
    _assert_same(fast, plain)
    # the blocks did run: most scans of one run lie in stretches with a plot in every scan
    if n_runs == 1:
        assert (rt._steady_stretches(plots[2]) >= rt.MIN_BLOCK_SCANS).sum() > 60


@pytest.mark.parametrize("strategy", ["fixed", "approximate", "exact", "kalman"])
def test_scan_blocks_with_clamps_floors_and_other_designs(strategy):
    # a pass 2 m from the radar: approximate gains clamp, the cross-range variance is floored
    plots = _plots(2, 120, seed=7, detection=1.0, pass_distance_m=2.0)
    fast, plain = _both(plots, strategy)
    _assert_same(fast, plain)
    if strategy == "approximate":
        assert (plain["flags"] & vocab.CLAMPED).any()
    assert (plain["flags"] & vocab.FLOORED).any()
    # no start-up gains, immediate confirmation, deletion after two coasted scans
    plots = _plots(1, 200, seed=8, detection=0.7)
    _assert_same(*_both(plots, strategy, startup_gains=False, confirm_hits=0, max_coasted_scans=2))
    assert (_both(plots, strategy, max_coasted_scans=2)[1]["flags"] & vocab.DELETED).any()


def test_blocks_of_many_runs_are_cut_to_bound_memory(monkeypatch):
    monkeypatch.setattr(rt, "BLOCK_RUN_SCANS", 40)  # blocks of max(4, 40 // 6) = 6 scans
    plots = _plots(6, 90, seed=3, detection=1.0)
    _assert_same(*_both(plots, "kalman"))
    _assert_same(*_both(plots, "approximate"))


@pytest.mark.parametrize("strategy", ["fixed", "approximate", "exact", "kalman"])
def test_steady_scans_of_many_runs_equal_the_scan_loop_bit_for_bit(monkeypatch, strategy):
    # beyond BLOCK_MAX_RUNS the Kalman strategy takes steady stretches scan by scan
    # (_steady_kalman_scans), cut at SCANS_RUN_SCANS; the α-β ones keep the loop
    monkeypatch.setattr(rt, "BLOCK_MAX_RUNS", 4)
    monkeypatch.setattr(rt, "SCANS_RUN_SCANS", 70)  # stretches of max(4, 70 // runs) scans
    taken = []
    real = rt._steady_kalman_scans
    monkeypatch.setattr(rt, "_steady_kalman_scans",
                        lambda first, stop, *a: taken.append(stop - first) or real(first, stop, *a))
    for plots in (_plots(7, 120, seed=5, detection=0.998), _plots(9, 80, seed=7, detection=1.0, pass_distance_m=2.0)):
        _assert_same(*_both(plots, strategy))
        _assert_same(*_both(plots, strategy, startup_gains=False, confirm_hits=0, max_coasted_scans=2))
    if strategy == "kalman":
        assert sum(taken) > 100 and max(taken) == 10
    else:
        assert not taken


def test_covariances_a_stretch_found_safe_are_not_checked_again(monkeypatch):
    """_steady_kalman_scans checks its covariances' pivots while they are in the cache and marks a
    stretch that passes; track_plots' last check then takes the other scans only. With a floor
    that some stretches pass and others do not (the relative pivots here are 0.39-0.64, most
    above 0.57; 40 of the 120 scans are found safe), both forms repair and flag the same
    covariances."""
    from trackreplay.trackers import _radar_tws_blocks

    floor = 0.57
    monkeypatch.setattr(rt, "BLOCK_MAX_RUNS", 4)
    monkeypatch.setattr(_radar_tws_blocks, "PIVOT_FLOOR", floor)
    checked = []

    def cv_floor_components(c, live):
        fixed, repaired = kalman.cv_floor_components(c, live, floor=floor)
        checked.append((c.shape[1], int(repaired.sum())))
        return fixed, repaired

    monkeypatch.setattr(rt, "cv_floor_components", cv_floor_components)
    plots = _plots(7, 120, seed=5, detection=0.998)
    fast, plain = _both(plots, "kalman")
    _assert_same(fast, plain)
    (fast_scans, fast_repaired), (plain_scans, plain_repaired) = checked
    assert plain_scans == 120 and 0 < fast_scans < 100
    assert fast_repaired == plain_repaired > 10


def test_steady_scans_of_a_few_hundred_runs_equal_the_scan_loop_bit_for_bit():
    plots = _plots(rt.BLOCK_MAX_RUNS + 44, 40, seed=9, detection=1.0)
    _assert_same(*_both(plots, "kalman"))


@pytest.mark.parametrize("n_runs, detection", [(1, 0.97), (6, 0.97), (300, 0.97), (300, 1.0)])
def test_every_output_entry_is_written(monkeypatch, n_runs, detection):
    """The outputs are allocated unfilled (the loop fills its scans with NaN, the blocks and the
    many-run stretches write all of theirs): with allocations that start as garbage, the outputs
    do not change."""
    plots = _plots(n_runs, 90, seed=n_runs, detection=detection)
    clean = _both(plots, "kalman", max_coasted_scans=2)
    garbage = SimpleNamespace(**{**vars(np), "empty": lambda shape, dtype=float: np.full(shape, 7.25, dtype)})
    monkeypatch.setattr(rt, "np", garbage)
    for a, b in zip(_both(plots, "kalman", max_coasted_scans=2), clean):
        _assert_same(a, b)


def _random_components(rng, n_runs):
    A = rng.normal(size=(n_runs, 4, 4))
    P = A @ np.swapaxes(A, 1, 2) * 100.0 + np.eye(4) * 50.0
    return kalman.matrix_to_components(P)


@pytest.mark.parametrize("scalar_runs", [0, 8])
def test_kalman_scan_axis_forms_equal_the_kernel_scan_by_scan(scalar_runs):
    rng = np.random.default_rng(11)
    n_runs, L, sigma_v = 3, 50, 0.7
    dt = 5.0 + rng.uniform(-0.1, 0.1, L)
    c0 = _random_components(rng, n_runs)
    x0 = rng.normal(size=(4, n_runs)) * 1e3
    along, cross = rng.uniform(1e2, 1e4, (L, n_runs)), rng.uniform(1e2, 1e5, (L, n_runs))
    theta = rng.uniform(-np.pi, np.pi, (L, n_runs))
    r_cov = (along * np.cos(theta) ** 2 + cross * np.sin(theta) ** 2, (along - cross) * np.cos(theta) * np.sin(theta),
             along * np.sin(theta) ** 2 + cross * np.cos(theta) ** 2)
    zx, zy = rng.normal(size=(L, n_runs)) * 1e3, rng.normal(size=(L, n_runs)) * 1e3
    gains, posts = _kalman_fast._cv_position_filter_covariances(c0, r_cov, dt, sigma_v, scalar_runs=scalar_runs)
    states = _kalman_fast._cv_states_with_gains(x0, gains, zx, zy, dt, scalar_runs=scalar_runs)
    x, c = x0, c0
    for j in range(L):
        xp, cp = kalman.cv_predict_components(x, c, float(dt[j]), sigma_v)
        g, c = kalman.cv_position_update_components(cp, r_cov[0][j], r_cov[1][j], r_cov[2][j])
        x = kalman.cv_apply_gain_components(xp, g, np.stack([zx[j] - xp[0], zy[j] - xp[1]]))
        np.testing.assert_array_equal(gains[:, j], g)
        np.testing.assert_array_equal(posts[:, j], c)
        np.testing.assert_array_equal(states[:, j], x)
    # the predictions of many scans in one call
    x_prev = np.concatenate([x0[:, None], states[:, :-1]], axis=1)
    c_prev = np.concatenate([c0[:, None], posts[:, :-1]], axis=1)
    xp_all, cp_all = _kalman_fast._cv_predict_components_scans(x_prev, c_prev, dt, sigma_v)
    for j in range(L):
        xp, cp = kalman.cv_predict_components(x_prev[:, j], c_prev[:, j], float(dt[j]), sigma_v)
        np.testing.assert_array_equal(xp_all[:, j], xp)
        np.testing.assert_array_equal(cp_all[:, j], cp)


@pytest.mark.parametrize("n_runs", [1, 7, 500])
def test_kalman_scan_of_many_runs_equals_the_kernel_to_the_bit(n_runs):
    """_cv_position_scan_rows (one scan of many runs fused) against cv_predict_components, then
    cv_position_update_components, then cv_apply_gain_components, scan after scan."""
    rng = np.random.default_rng(n_runs)
    L, sigma_v = 30, 0.9
    dt = 5.0 + rng.uniform(-0.1, 0.1, L)
    c0 = _random_components(rng, n_runs)
    x0 = rng.normal(size=(4, n_runs)) * 1e3
    along, cross = rng.uniform(1e2, 1e4, (L, n_runs)), rng.uniform(1e-2, 1e6, (L, n_runs))
    theta = rng.uniform(-np.pi, np.pi, (L, n_runs))
    r = np.stack([along * np.cos(theta) ** 2 + cross * np.sin(theta) ** 2,
                  (along - cross) * np.cos(theta) * np.sin(theta),
                  along * np.sin(theta) ** 2 + cross * np.cos(theta) ** 2], axis=1)
    z = rng.normal(size=(L, 2, n_runs)) * 1e3
    x, c, xf, cf = x0, c0, x0, c0
    for j in range(L):
        xp, cp = kalman.cv_predict_components(x, c, float(dt[j]), sigma_v)
        g, c = kalman.cv_position_update_components(cp, *r[j])
        nu = np.stack([z[j, 0] - xp[0], z[j, 1] - xp[1]])
        x = kalman.cv_apply_gain_components(xp, g, nu)
        outs = x_out, nu_out, s_out, g_out, c_out = (np.empty((4, n_runs)), np.empty((2, n_runs)),
                                                     np.empty((3, n_runs)), np.empty((8, n_runs)),
                                                     np.empty((10, n_runs)))
        _kalman_fast._cv_position_scan_rows(xf, cf, float(dt[j]), sigma_v, z[j], r[j], *outs)
        for got, want in ((x_out, x), (nu_out, nu), (s_out, cp[:3] + r[j]), (g_out, g), (c_out, c)):
            np.testing.assert_array_equal(got, want)
        xf, cf = x_out, c_out


@pytest.mark.parametrize("sigma_v", [0.0, 2.0])
def test_cv_position_pcrb_equals_the_general_recursion(sigma_v):
    from trackreplay.cores.filters.pcrb import _cv_position_pcrb_recursion, pcrb_recursion, polar_position_information

    rng = np.random.default_rng(5)
    K = 120
    times = np.cumsum(np.r_[0.0, 5.0 + rng.uniform(-0.2, 0.2, K - 1)])
    xy = np.stack([np.linspace(-8e3, 9e3, K), np.linspace(6e3, 2e3, K)], axis=-1)
    info = polar_position_information(xy, 100.0, np.deg2rad(1.0))
    info[rng.random(K) < 0.2] = 0.0  # scans without a plot in any run
    full = np.zeros((K, 4, 4))
    full[:, :2, :2] = info
    dt = np.diff(times, prepend=np.nan)
    F, Q = kalman.white_acceleration_model(np.nan_to_num(dt, nan=1.0), sigma_v)
    P0 = kalman.components_to_matrix(_random_components(rng, 1))[0]
    expected = pcrb_recursion(P0, F, Q, full)
    got = _cv_position_pcrb_recursion(P0, dt, sigma_v, info)
    np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-9 * np.abs(expected).max())
    # a scan whose information cannot be represented ends the bound in both
    info[60] = np.inf
    full[60, :2, :2] = np.inf
    with np.errstate(invalid="ignore"):
        expected = pcrb_recursion(P0, F, Q, full)
    got = _cv_position_pcrb_recursion(P0, dt, sigma_v, info)
    assert np.isnan(got[60:]).all() and np.isnan(expected[60:]).all()
    np.testing.assert_allclose(got[:60], expected[:60], rtol=1e-9, atol=1e-9 * np.abs(expected[:60]).max())


# --------------------------------------------------------------------------- long recordings on disk


def _same_channels(a, b):
    """Every frame's run, scan and time, and every array's grid or ragged view, identical."""
    assert list(a.channels) == list(b.channels)
    for topic in a.channels:
        x, y = a.channel(topic), b.channel(topic)
        for attr in ("run", "scan", "time_s"):
            np.testing.assert_array_equal(getattr(x, attr), getattr(y, attr), err_msg=f"{topic} {attr}")
        assert list(x.arrays) == list(y.arrays)
        for name in x.arrays:
            u, v = (x.ragged(name), y.ragged(name)) if topic.endswith("plots") else ((x.grid(name),), (y.grid(name),))
            for p, q in zip(u, v):
                assert p.dtype == q.dtype and p.shape == q.shape and p.tobytes() == q.tobytes(), (topic, name)


@pytest.mark.parametrize("runs", [1, 3])
def test_a_long_recording_groups_scans_and_reads_as_one_message_per_scan(tmp_path, runs):
    from trackreplay.contract import CONTRACT_V1, GROUP_MIN_SCANS, read_dataset, rewrite_dataset, scans_per_message
    from trackreplay.recorders.scenarios import load_scenario
    from trackreplay.recorders.simulated import record

    n_scans = GROUP_MIN_SCANS + 52
    scenario = load_scenario("radar-tws").with_overrides({"n_scans": n_scans, "detection_probability": 0.9})
    messages = record(tmp_path / "long.mcap", scenario, runs, seed=4)
    group = scans_per_message(runs, n_scans)
    assert group > 1 and messages == 2 * -(-n_scans // group)  # two channels, a message per group
    record(tmp_path / "v1.mcap", scenario, runs, seed=4, contract=CONTRACT_V1)  # one message per run and scan
    grouped, plain = read_dataset(tmp_path / "long.mcap"), read_dataset(tmp_path / "v1.mcap")
    _same_channels(grouped, plain)
    # and back through the frame-by-frame path every converter uses
    rewrite_dataset(tmp_path / "long.mcap", tmp_path / "again.mcap", contract=CONTRACT_V1)
    _same_channels(read_dataset(tmp_path / "again.mcap"), plain)


@pytest.mark.parametrize("runs, extra", [(1, 1), (5, 700)])  # (1, 1): the last message holds one scan
def test_replay_outputs_of_a_long_recording_group_scans(tmp_path, runs, extra):
    from trackreplay.contract import GROUP_MIN_SCANS, read_dataset, scans_per_message, write_dataset

    rng = np.random.default_rng(2)
    n_scans = GROUP_MIN_SCANS + extra
    A = rng.normal(size=(runs, n_scans, 4, 4))
    arrays = {"state": rng.normal(size=(runs, n_scans, 4)), "covariance": A @ np.swapaxes(A, -1, -2),
              "flags": rng.integers(0, 9, size=(runs, n_scans)).astype(np.uint32),
              "strided": rng.normal(size=(n_scans, runs, 2)).transpose(1, 0, 2)}
    times = np.cumsum(rng.uniform(4.9, 5.1, n_scans))
    with write_dataset(tmp_path / "out.mcap", pack_symmetric=True) as w:
        w.write_grid("/tracks/radar/x", times, arrays)
    assert w.messages == -(-n_scans // scans_per_message(runs, n_scans))
    got = read_dataset(tmp_path / "out.mcap").channel("/tracks/radar/x")
    assert (got.n_runs, got.n_scans) == (runs, n_scans)
    np.testing.assert_array_equal(got.times(), times)
    for name, a in arrays.items():
        np.testing.assert_array_equal(got.grid(name), a, err_msg=name)


def test_a_group_that_does_not_hold_the_same_runs_in_each_scan_is_refused(tmp_path):
    from trackreplay.contract import Scan, read_dataset, write_dataset
    from trackreplay.errors import InputError

    with write_dataset(tmp_path / "bad.mcap", group_scans=True) as w:
        msg = Scan(scan=0, time_s=0.0, frame_count=5, scan_count=2)  # 5 frames cannot be 2 scans alike
        msg.times_s = np.zeros(5).tobytes()
        msg.columns.add(name="state", dtype="<f8", values=np.zeros((5, 4)).tobytes()).shape.extend([4])
        w._add_message("/radar/truth", 0.0, msg.SerializeToString())
    with pytest.raises(InputError, match="same runs in each"):
        read_dataset(tmp_path / "bad.mcap")
