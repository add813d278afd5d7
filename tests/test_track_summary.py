"""The track summary (evaluators/track_summary.py): track life read from the flags alone, counted
exactly on hand-made flags; the mean-NIS χ² interval covering a correctly specified Kalman filter
at its nominal rate and rejecting a mis-specified one; and `replay` of data without truth printing
the summary, one line per tracker, for every family, and no error metric."""

from __future__ import annotations


import numpy as np
import polars as pl
import pytest
from click.testing import CliRunner

from trackreplay.evaluators.track_summary import METRICS, mean_nis_bounds, track_life, track_summary
from trackreplay import vocabulary as vocab
from trackreplay.face.cli import main

N, I, C, D = vocab.NO_TRACK, vocab.INITIALISING, vocab.COASTED, vocab.DELETED


def _values(summary: pl.DataFrame, tracker: str = "t") -> dict:
    part = summary.filter(pl.col("tracker") == tracker)
    return dict(zip(part["metric"], part["value"]))


def _outputs(flags, **extra) -> dict:
    flags = np.asarray(flags, np.uint16)
    return {"state": np.zeros(flags.shape + (2,)), "flags": flags, **extra}


# --------------------------------------------------------------------------- hand-made flags

# one run, two slots, ten scans (slot × scan):
#   slot 0: empty, tentative 2 scans, confirmed, deleted at scan 5 (held), empty, a second track
#           tentative one scan, confirmed, open at the end
#   slot 1: confirmed from scan 0, coasts, deleted at scan 3; the deletion repeated on the empty
#           scans after it (counted once); a track at 6–7 that ends without DELETED; one at 9, open
SLOTS = np.array([[N, I, I, 0, 0, D, N, I, 0, 0],
                  [0, 0, C, D | C, N | D, N | D, 0, 0, N, 0]]).T[None]       # (1, 10, 2)
TIMES = 2.0 * np.arange(10)


def test_track_life_counts_starts_confirmations_deletions_and_open_tracks_exactly():
    life = track_life(SLOTS)
    assert np.argwhere(life["start"][0]).tolist() == [[0, 1], [1, 0], [6, 1], [7, 0], [9, 1]]
    assert np.argwhere(life["confirm"][0]).tolist() == [[0, 1], [3, 0], [6, 1], [8, 0], [9, 1]]
    assert np.argwhere(life["deleted"][0]).tolist() == [[3, 1], [5, 0]]
    assert np.argwhere(life["open"][0]).tolist() == [[9, 0], [9, 1]]
    assert np.argwhere(life["unflagged"][0]).tolist() == [[7, 1]]
    s = _values(track_summary(TIMES, {"t": _outputs(SLOTS)}))
    assert (s["tracks_started_per_run"], s["tracks_confirmed_per_run"], s["tracks_deleted_per_run"],
            s["tracks_open_per_run"], s["tracks_ended_unflagged_per_run"]) == (5, 5, 2, 2, 1)
    # lifetimes 5, 3 (slot 0) and 4, 2, 1 scans (slot 1); 2 s per scan
    assert s["track_lifetime_scans"] == 3 and s["track_lifetime_s"] == 4.0
    assert s["track_lifetime_scans_iqr"] == 2.0 and s["track_lifetime_s_iqr"] == 4.0
    assert s["scans_to_confirmation"] == pytest.approx((2 + 1 + 0 + 0 + 0) / 5)
    assert "mean_nis" not in s  # no innovations: nothing pretended


def test_per_run_means_have_student_t_intervals_and_single_track_families_one_slot_per_run():
    # flags (R, K): run 0 holds one track deleted at scan 2 and a second one open; run 1 one track
    flags = np.array([[I, 0, D, N, I, I, 0],
                      [N, N, I, 0, 0, 0, 0]])
    summary = track_summary(np.arange(7.0), {"t": _outputs(flags)})
    row = summary.filter(pl.col("metric") == "tracks_started_per_run").row(0, named=True)
    assert row["value"] == 1.5 and row["se"] == pytest.approx(0.5)  # per run 2 and 1
    assert row["ci_low"] < 1.0 < 2.0 < row["ci_high"]
    s = _values(summary)
    assert (s["tracks_confirmed_per_run"], s["tracks_deleted_per_run"], s["tracks_open_per_run"]) == (1.5, 0.5, 1.0)
    assert s["scans_to_confirmation"] == pytest.approx((1 + 2 + 1) / 3)
    assert sorted(track_life(flags)["first"][track_life(flags)["last"]].tolist()) == [0, 2, 4]


def test_a_new_identity_in_a_slot_starts_a_new_track_and_a_track_never_initialising_is_confirmed_at_its_start():
    flags = np.zeros((1, 6, 1), np.uint16)
    ids = np.array([7, 7, 7, 9, 9, 9])[None, :, None]
    s = _values(track_summary(np.arange(6.0), {"t": _outputs(flags, track_id=ids)}))
    assert (s["tracks_started_per_run"], s["tracks_confirmed_per_run"], s["tracks_ended_unflagged_per_run"],
            s["tracks_open_per_run"], s["scans_to_confirmation"], s["track_lifetime_scans"]) == (2, 2, 1, 1, 0, 3)
    # the same slot without identities: one track for the whole run
    s = _values(track_summary(np.arange(6.0), {"t": _outputs(flags)}))
    assert (s["tracks_started_per_run"], s["track_lifetime_scans"], s["track_lifetime_s"]) == (1, 6, 5.0)


def test_estimator_side_outputs_are_left_out_and_every_name_is_declared():
    flags = np.zeros((3, 4), np.uint16)
    summary = track_summary(np.arange(4.0), {"t": _outputs(flags), "side": {"flags": flags}})
    assert summary["tracker"].unique().to_list() == ["t"]
    assert set(summary["metric"]) <= set(METRICS) and (summary["scope"] == "overall").all()


# --------------------------------------------------------------------------- the NIS interval


def _kalman_nis(batches: int, runs: int, scans: int, r_scale: float, seed: int):
    """A constant-velocity target in two axes, its position measured; a Kalman filter started
    from the true prior, with the true model except its measurement variance × ``r_scale``.
    Returns innovations (B, R, K, 2) and their covariances (B, R, K, 2, 2)."""
    rng = np.random.default_rng(seed)
    dt, q, r = 1.0, 0.5, 4.0
    F1 = np.array([[1.0, dt], [0.0, 1.0]])
    Q1 = q * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
    F, Q = np.kron(np.eye(2), F1), np.kron(np.eye(2), Q1)
    H = np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0]])
    Rt, Rf = r * np.eye(2), r * r_scale * np.eye(2)
    P0 = np.diag([100.0, 4.0, 100.0, 4.0])
    n = batches * runs
    x = rng.multivariate_normal(np.zeros(4), P0, n)   # the truth; the filter's prior is N(0, P0)
    xf, P = np.zeros((n, 4)), np.broadcast_to(P0, (n, 4, 4)).copy()
    nus, Ss = np.empty((n, scans, 2)), np.empty((n, scans, 2, 2))
    Lq, Lr = np.linalg.cholesky(Q), np.linalg.cholesky(Rt)
    for k in range(scans):
        x = x @ F.T + rng.standard_normal((n, 4)) @ Lq.T
        z = x @ H.T + rng.standard_normal((n, 2)) @ Lr.T
        xf, P = xf @ F.T, F @ P @ F.T + Q
        S = H @ P @ H.T + Rf
        nu = z - xf @ H.T
        K = P @ H.T @ np.linalg.inv(S)
        xf = xf + np.einsum("nij,nj->ni", K, nu)
        P = P - K @ S @ np.swapaxes(K, -1, -2)
        nus[:, k], Ss[:, k] = nu, S
    return nus.reshape(batches, runs, scans, 2), Ss.reshape(batches, runs, scans, 2, 2)


def _inside(nu, S) -> tuple[np.ndarray, np.ndarray]:
    """``mean_nis_inside`` and ``mean_nis`` of every batch through the track summary."""
    times = np.arange(nu.shape[2], dtype=float)
    flags = np.zeros(nu.shape[1:3], np.uint16)
    inside, mean = [], []
    for b in range(len(nu)):
        s = _values(track_summary(times, {"t": _outputs(flags, innovation=nu[b], innovation_covariance=S[b])}))
        assert s["nis_updates"] == nu.shape[1] * nu.shape[2]
        inside.append(s["mean_nis_inside"])
        mean.append((s["mean_nis"], s["mean_nis_low"], s["mean_nis_high"]))
    return np.array(inside), np.array(mean)


def test_the_mean_nis_interval_covers_a_correct_kalman_filter_at_95_percent_and_rejects_r_scaled_by_4():
    batches = 200
    nu, S = _kalman_nis(batches, runs=4, scans=25, r_scale=1.0, seed=11)
    inside, _ = _inside(nu, S)
    coverage, se = inside.mean(), np.sqrt(0.95 * 0.05 / batches)
    assert abs(coverage - 0.95) <= 3 * se, coverage
    nu, S = _kalman_nis(batches, runs=4, scans=25, r_scale=4.0, seed=12)
    inside, mean = _inside(nu, S)
    assert inside.mean() <= 0.01 and (mean[:, 0] < mean[:, 1]).mean() >= 0.99   # below: S too large


def test_mean_nis_bounds_are_the_chi2_interval_of_n_times_m_dof():
    from scipy.special import chdtri

    nis = np.full((3, 5), 2.0)
    nis[0, 0] = np.nan
    mean, low, high, n = mean_nis_bounds(nis, 2)
    assert (mean, n) == (2.0, 14)
    assert low == pytest.approx(chdtri(28, 0.975) / 14) and high == pytest.approx(chdtri(28, 0.025) / 14)
    assert np.isnan(mean_nis_bounds(np.full(4, np.nan), 2)[0])


# --------------------------------------------------------------------------- replay without truth


SCENARIOS = {"radar-tws": ("radar", ["--set", "n_scans=20"]),
             "xcorr-crossing": ("xcorr", ["--set", "crossing_angle_deg=20"]),
             "array-crossing": ("array", ["--set", "n_scans=12"]),
             "tdoa-fdoa": ("tdoa-fdoa", []),
             "colored-imm": ("colored", ["--set", "n_samples=200", "--set", "manoeuvre_first_sample=60",
                                         "--set", "manoeuvre_last_sample=120"])}
ERROR_METRICS = ("rmse", "ospa", "gospa", "nees", "mota", "idf1", "crlb", "pcrb", "efficiency", "success_rate")


@pytest.mark.parametrize("scenario", sorted(SCENARIOS))
def test_replay_without_truth_prints_the_track_summary_of_every_tracker_and_no_error(scenario, replay_without_truth):
    stage, options = SCENARIOS[scenario]
    res, out = replay_without_truth(scenario, 5, options)
    assert not [m for m in ERROR_METRICS if m in res.output.lower()]
    metrics = pl.read_csv(out.parent / "metrics.csv")
    part = metrics.filter((pl.col("stage") == stage) & pl.col("metric").is_in(list(METRICS)))
    trackers = part["tracker"].unique(maintain_order=True).to_list()
    assert trackers and (part["scope"] == "overall").all()
    lines = res.output.split("\n")
    head = lines.index(f"track summary of {stage} (no truth: no error can be computed)")
    table = lines[head + 3: head + 4 + len(trackers)]
    assert table[0].split()[:5] == ["tracker", "started", "confirmed", "deleted", "open"]
    assert [line.split()[0] for line in table[1:]] == trackers                 # one line per tracker
    for line, tracker in zip(table[1:], trackers):
        started = part.filter((pl.col("tracker") == tracker) & (pl.col("metric") == "tracks_started_per_run"))
        assert float(line.split()[1]) == pytest.approx(started["value"][0], rel=1e-3)
    # printed once: the tables above the block leave the summary's rows out
    assert "tracks_started_per_run" not in res.output


def test_with_truth_the_summary_rows_are_standard_measures_and_eval_prints_the_block_without_truth(tmp_path, without_truth):
    runner = CliRunner()
    full, bare = tmp_path / "full.mcap", tmp_path / "bare.mcap"
    assert runner.invoke(main, ["simulate", "radar-tws", "--runs", "4", "--seed", "2", "-o", str(full),
                                "--set", "n_scans=12"]).exit_code == 0
    res = runner.invoke(main, [str(full), "--out", str(tmp_path / "a" / "tracks.mcap"), "--no-rrd", "-q"])
    assert res.exit_code == 0, res.output
    standard = res.output[res.output.index("[standard measures]"):]
    assert "tracks_started_per_run" in standard and "mean_nis_inside" in standard
    assert "track summary of" not in res.output
    without_truth(full, bare)
    out = tmp_path / "b" / "tracks.mcap"
    assert runner.invoke(main, [str(bare), "--out", str(out), "--no-rrd", "-q"]).exit_code == 0
    res = runner.invoke(main, ["eval", str(bare), str(out)])
    assert res.exit_code == 0, res.output
    assert "track summary of radar (no truth: no error can be computed)" in res.output
    res = runner.invoke(main, ["eval", str(bare), str(out), "--json"])
    import json

    names = {r["metric"] for r in json.loads(res.output)}
    assert {"tracks_started_per_run", "track_lifetime_s", "mean_nis"} <= names


@pytest.mark.parametrize("runs", [13, 100])  # rows of 39 (numpy's accumulation) and 300 (scan by scan)
def test_running_max_over_scans_is_numpys_accumulation(runs):
    from trackreplay.evaluators.track_summary import SCAN_ROW_MIN, _running_max_over_scans

    assert (runs * 3 >= SCAN_ROW_MIN) == (runs == 100)  # both forms are exercised
    rng = np.random.default_rng(21)
    a = np.where(rng.random((runs, 9, 3)) < 0.3, np.arange(9, dtype=np.int16)[None, :, None], np.int16(-1))
    got = _running_max_over_scans(a)
    assert got.shape == a.shape and got.dtype == a.dtype
    np.testing.assert_array_equal(got, np.maximum.accumulate(a, axis=1))


def test_nis_of_updates_is_the_mean_nis_with_the_per_run_sums():
    """The track summary's one pass over the updates' NIS gives mean_nis_bounds, np.nansum and
    the finite counts per run, an infinite NIS counted and summed as they count and sum it."""
    from trackreplay.evaluators.track_summary import _nis_of_updates

    rng = np.random.default_rng(22)
    nis = rng.chisquare(2, size=(40, 15, 2))
    nis[rng.random(nis.shape) < 0.2] = np.nan
    nis[3, 4, 1] = np.inf
    expected = (*mean_nis_bounds(nis, 2), np.nansum(nis, axis=(1, 2)), np.sum(np.isfinite(nis), axis=(1, 2)))
    got = _nis_of_updates(nis.copy(), 2, 0.95)
    assert got[:4] == expected[:4]
    np.testing.assert_array_equal(got[4], expected[4])
    np.testing.assert_array_equal(got[5], expected[5])
    empty = _nis_of_updates(np.full((3, 4, 1), np.nan), 2, 0.95)
    assert np.isnan(empty[:3]).all() and empty[3] == 0 and (empty[4] == 0).all()
