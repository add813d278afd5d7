"""The radar-multi simulator: the statistics it promises, read back from the file it writes.

Every bound is five standard deviations (or a χ²/KS tail of 1e-6) of what the model promises, so
a wrong rate, a wrong noise scale or a lost plot fails while the seed's luck does not.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import integrate, stats

from trackreplay.contract import read_dataset
from trackreplay.errors import InputError
from trackreplay.face.cli import main
from trackreplay.recorders import radar_multi as rm
from trackreplay.recorders.scenarios import load_scenario, parameter_docs
from trackreplay.recorders.simulated import record

RUNS, SEED = 200, 11
Z = 5.0  # bound in standard deviations
TAIL = 1e-6  # two-sided tail of the χ² and KS tests


def params(**overrides) -> dict:
    return load_scenario("radar-multi").with_overrides(overrides).params


def truth_and_plots(data) -> dict:
    (truth, n_truth), (plots, n_plots) = data.ragged[rm.TRUTH_TOPIC], data.ragged[rm.PLOTS_TOPIC]
    return {"state": truth["state"], "target_id": truth["target_id"], "n_truth": n_truth,
            "range_m": plots["range_m"], "bearing_rad": plots["bearing_rad"], "origin": plots["origin"],
            "n_plots": n_plots}


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """The default scenario written by the real recorder and read back through the contract."""
    path = tmp_path_factory.mktemp("radar_multi") / "multi.mcap"
    record(path, load_scenario("radar-multi"), runs=RUNS, seed=SEED)
    ds = read_dataset(path)
    truth, plots = ds.channel(rm.TRUTH_TOPIC), ds.channel(rm.PLOTS_TOPIC)
    out = {}
    out["state"], out["n_truth"] = truth.ragged("state")
    out["target_id"], n = truth.ragged("target_id")
    assert np.array_equal(n, out["n_truth"])
    out["range_m"], out["n_plots"] = plots.ragged("range_m")
    for name in ("bearing_rad", "origin"):
        out[name], n = plots.ragged(name)
        assert np.array_equal(n, out["n_plots"])
    return path, out


def valid(counts, width):
    return np.arange(width) < counts[..., None]


def identity_lookup(d) -> np.ndarray:
    """``slot[r, k, id]``: the row of target ``id`` in truth frame (r, k), −1 where it is not alive."""
    R, K, W = d["target_id"].shape
    ok = valid(d["n_truth"], W)
    ids = np.where(ok, d["target_id"], -1).astype(np.int64)
    slot = np.full((R, K, int(ids.max()) + 1), -1)
    r, k, s = np.nonzero(ok)
    slot[r, k, ids[r, k, s]] = s
    return slot


# --------------------------------------------------------------------------- file and determinism


def test_the_file_reads_back_what_was_simulated(recorded):
    path, d = recorded
    mem = truth_and_plots(rm.simulate(params(), RUNS, SEED))
    R, K = RUNS, 100
    assert d["state"].shape[:2] == (R, K) and d["state"].shape[3] == 4
    for name, counts in (("state", "n_truth"), ("target_id", "n_truth"), ("range_m", "n_plots"),
                         ("bearing_rad", "n_plots"), ("origin", "n_plots")):
        assert np.array_equal(d[counts], mem[counts])
        ok = valid(d[counts], d[name].shape[2])
        assert np.array_equal(d[name][ok], mem[name][ok]), name
        assert np.isnan(d[name][~ok]).all()  # padding
    assert mem["origin"].dtype == np.int64 and mem["target_id"].dtype == np.int64
    assert read_dataset(path).scenario["scenario"] == "radar-multi"


def test_same_seed_same_bytes_other_seed_other_bytes(tmp_path):
    sc = load_scenario("radar-multi").with_overrides({"n_scans": "30"})
    a, b, c = tmp_path / "a.mcap", tmp_path / "b.mcap", tmp_path / "c.mcap"
    record(a, sc, runs=20, seed=4)
    record(b, sc, runs=20, seed=4)
    record(c, sc, runs=20, seed=5)
    assert a.read_bytes() == b.read_bytes()
    assert a.read_bytes() != c.read_bytes()


def test_plot_and_clutter_parameters_keep_the_same_targets():
    base = truth_and_plots(rm.simulate(params(n_scans=20), 30, 2))
    for change in ({"clutter_per_scan": "40"}, {"detection_probability": "0.5"}, {"sigma_range_m": "5"}):
        other = truth_and_plots(rm.simulate(params(n_scans=20, **change), 30, 2))
        assert np.array_equal(other["n_truth"], base["n_truth"])
        ok = valid(base["n_truth"], base["state"].shape[2])
        assert np.array_equal(other["state"][ok], base["state"][ok])
    # fewer detections with a lower P_D, and only of targets detected before (same uniforms)
    low = truth_and_plots(rm.simulate(params(n_scans=20, detection_probability=0.5), 30, 2))
    for d in (base, low):
        d["detected"] = {(r, k, int(o)) for r, k, s in zip(*np.nonzero(valid(d["n_plots"], d["origin"].shape[2])))
                         if (o := d["origin"][r, k, s]) >= 0}
    assert low["detected"] < base["detected"]


# --------------------------------------------------------------------------- plots


def test_clutter_count_and_positions(recorded):
    _, d = recorded
    p = params()
    ok = valid(d["n_plots"], d["origin"].shape[2])
    clutter = ok & (d["origin"] == rm.ORIGIN_CLUTTER)
    n, expected = int(clutter.sum()), RUNS * 100 * p["clutter_per_scan"]
    assert abs(n - expected) < Z * np.sqrt(expected), (n, expected)  # Poisson(N λ)
    u_range = (d["range_m"][clutter] - p["min_range_m"]) / (p["max_range_m"] - p["min_range_m"])
    half = np.deg2rad(p["sector_half_width_deg"])
    u_bearing = (d["bearing_rad"][clutter] + half) / (2 * half)
    for u in (u_range, u_bearing):
        assert stats.kstest(u, "uniform").pvalue > TAIL


def test_detection_fraction_matches_pd(recorded):
    _, d = recorded
    pd = params()["detection_probability"]
    n_alive = int(d["n_truth"].sum())
    detected = int((valid(d["n_plots"], d["origin"].shape[2]) & (d["origin"] >= 0)).sum())
    assert abs(detected - pd * n_alive) < Z * np.sqrt(n_alive * pd * (1 - pd)), (detected, n_alive)


def test_every_detection_comes_from_a_target_alive_at_its_scan_with_the_stated_noise(recorded):
    _, d = recorded
    p = params()
    ok = valid(d["n_plots"], d["origin"].shape[2])
    r, k, s = np.nonzero(ok & (d["origin"] >= 0))
    origin = d["origin"][r, k, s].astype(np.int64)
    slot = identity_lookup(d)
    assert origin.max() < slot.shape[2]
    row = slot[r, k, origin]
    assert (row >= 0).all(), "a plot names a target that is not alive at its scan"
    x = d["state"][r, k, row]
    dr = (d["range_m"][r, k, s] - np.hypot(x[:, 0], x[:, 1])) / p["sigma_range_m"]
    db = rm.wrap_angle(d["bearing_rad"][r, k, s] - np.arctan2(x[:, 1], x[:, 0])) / np.deg2rad(p["sigma_bearing_deg"])
    for z in (dr, db):
        cdf = stats.chi2.cdf(np.sum(z**2), z.size)  # Σ z² ~ χ²(n) when the noise has the stated σ
        assert TAIL / 2 < cdf < 1 - TAIL / 2, (cdf, np.std(z))
        assert abs(z.mean()) < Z / np.sqrt(z.size)  # unbiased
    assert (np.abs(d["bearing_rad"][ok]) <= np.pi).all()


def test_plot_order_gives_nothing_away(recorded):
    _, d = recorded
    W = d["origin"].shape[2]
    ok = valid(d["n_plots"], W) & (d["n_plots"][..., None] >= 2)
    r, k, s = np.nonzero(ok & (d["origin"] >= 0))
    # a detection's place in its frame, in [0, 1], is uniform when plots are shuffled: mean 1/2,
    # variance at most 1/4 (places in one frame, drawn without replacement, correlate negatively)
    position = s / (d["n_plots"][r, k] - 1)
    assert abs(position.mean() - 0.5) < Z * np.sqrt(0.25 / position.size), position.mean()
    # detections are not listed by identity
    first_two = ok[..., 1] & (d["origin"][..., 0] >= 0) & (d["origin"][..., 1] >= 0)
    ascending = (d["origin"][..., 0] < d["origin"][..., 1])[first_two]
    assert abs(ascending.mean() - 0.5) < Z * np.sqrt(0.25 / ascending.size)


# --------------------------------------------------------------------------- targets


def test_identities_are_unique_ordered_and_never_reused(recorded):
    _, d = recorded
    W = d["target_id"].shape[2]
    ok = valid(d["n_truth"], W)
    ids = d["target_id"]
    assert (ids[ok] >= 0).all() and np.array_equal(ids[ok], np.round(ids[ok]))
    pair = ok[..., 1:]
    assert (np.diff(ids, axis=2)[pair] > 0).all()  # strictly increasing in a frame: unique, ordered
    alive = identity_lookup(d) >= 0  # (run, scan, id)
    starts = alive[:, 0].astype(int) + (alive[:, 1:] & ~alive[:, :-1]).sum(axis=1)
    assert starts.max() == 1  # alive over one stretch of scans: an identity never comes back
    # identities 0, 1, 2, … in order of birth within a run
    seen = alive.any(axis=1)
    n_ids = seen.sum(axis=1)
    assert all(seen[r, :n].all() for r, n in enumerate(n_ids))
    first = np.where(seen, alive.argmax(axis=1), np.iinfo(np.int64).max)
    assert all((np.diff(first[r, :n]) >= 0).all() for r, n in enumerate(n_ids))


def test_targets_stay_in_the_region_and_are_born_at_the_stated_speeds(recorded):
    _, d = recorded
    p = params()
    ok = valid(d["n_truth"], d["state"].shape[2])
    assert rm.in_region(d["state"][ok], p).all()
    alive = identity_lookup(d)
    R, K, n = alive.shape
    r, i = np.nonzero((alive >= 0).any(axis=1))
    k = (alive[r, :, i] >= 0).argmax(axis=1)
    born = d["state"][r, k, alive[r, k, i]]
    # position at birth uniform over the area: r² uniform in [r_min², r_max²], bearing uniform
    r2 = (born[:, 0] ** 2 + born[:, 1] ** 2 - p["min_range_m"] ** 2) / (p["max_range_m"] ** 2 - p["min_range_m"] ** 2)
    half = np.deg2rad(p["sector_half_width_deg"])
    assert stats.kstest(r2, "uniform").pvalue > TAIL
    assert stats.kstest((np.arctan2(born[:, 1], born[:, 0]) + half) / (2 * half), "uniform").pvalue > TAIL
    speed = np.hypot(born[:, 2], born[:, 3])
    assert (speed >= p["min_speed_mps"] - 1e-9).all() and (speed <= p["max_speed_mps"] + 1e-9).all()
    # speed at birth uniform; heading uniform
    assert stats.kstest((speed - 50) / 200, "uniform").pvalue > TAIL
    assert stats.kstest(np.mod(np.arctan2(born[:, 3], born[:, 2]), 2 * np.pi) / (2 * np.pi), "uniform").pvalue > TAIL


def test_the_number_alive_is_steady(recorded):
    _, d = recorded
    mean = params()["initial_targets_mean"]
    n0 = int(d["n_truth"][:, 0].sum())
    assert abs(n0 - RUNS * mean) < Z * np.sqrt(RUNS * mean)  # Poisson at scan 0
    # every block of 10 scans: the mean over runs stays near the initial mean (sd ≈ 0.23 here)
    blocks = d["n_truth"].reshape(RUNS, 10, 10).mean(axis=(0, 2))
    assert np.all(np.abs(blocks - mean) < 1.2), blocks


def test_survival_and_births_without_exits():
    p = params(min_speed_mps=0, max_speed_mps=0, process_noise_m2ps3=0, survival_probability=0.9,
               initial_targets_mean=5, birth_rate_per_scan=2, clutter_per_scan=0, n_scans=40)
    d = truth_and_plots(rm.simulate(p, 100, 3))
    alive = identity_lookup(d) >= 0
    was, still = alive[:, :-1], alive[:, 1:]
    n, kept = int(was.sum()), int((was & still).sum())
    assert abs(kept - 0.9 * n) < Z * np.sqrt(n * 0.09), (kept, n)
    born = (still & ~was).sum()  # births at scans 1 … K−1
    expected = 100 * 39 * 2.0
    assert abs(born - expected) < Z * np.sqrt(expected)


def test_straight_flyers_follow_the_white_noise_model():
    p = params(turning_fraction=0, survival_probability=1, clutter_per_scan=0, process_noise_m2ps3=4.0)
    d = truth_and_plots(rm.simulate(p, 60, 8))
    alive = identity_lookup(d)
    r, k, i = np.nonzero((alive[:, :-1] >= 0) & (alive[:, 1:] >= 0))
    x0, x1 = d["state"][r, k, alive[r, k, i]], d["state"][r, k + 1, alive[r, k + 1, i]]
    T = p["scan_period_s"]
    w = x1 - rm.coordinated_turn(x0, np.zeros(len(x0)), T)
    Q = rm.process_noise_covariance(p["process_noise_m2ps3"], T)
    m = np.einsum("ni,ij,nj->n", w, np.linalg.inv(Q), w)
    cdf = stats.chi2.cdf(m.sum(), 4 * m.size)
    assert TAIL / 2 < cdf < 1 - TAIL / 2, m.mean()


def test_a_fraction_of_targets_turn_at_a_constant_rate():
    p = params(process_noise_m2ps3=0, clutter_per_scan=0, n_scans=30)
    d = truth_and_plots(rm.simulate(p, 200, 6))
    alive = identity_lookup(d)
    r, k, i = np.nonzero((alive[:, :-1] >= 0) & (alive[:, 1:] >= 0))
    v0 = d["state"][r, k, alive[r, k, i]][:, 2:]
    v1 = d["state"][r, k + 1, alive[r, k + 1, i]][:, 2:]
    rate = np.arctan2(v0[:, 0] * v1[:, 1] - v0[:, 1] * v1[:, 0], (v0 * v1).sum(axis=1)) / p["scan_period_s"]
    per_target = {}
    for key, w in zip(zip(r, i), rate):
        per_target.setdefault(key, []).append(w)
    rates = [np.array(v) for v in per_target.values()]
    assert all(np.ptp(v) < 1e-9 for v in rates)  # constant over the target's life
    first = np.array([v[0] for v in rates])
    assert np.abs(first).max() <= np.deg2rad(p["max_turn_rate_degps"]) + 1e-12
    turning = np.abs(first) > 0
    f = p["turning_fraction"]
    assert abs(turning.sum() - f * first.size) < Z * np.sqrt(first.size * f * (1 - f))
    assert stats.kstest(first[turning] / np.deg2rad(3.0) / 2 + 0.5, "uniform").pvalue > TAIL


def test_coordinated_turn_is_the_exact_flow():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(50, 4)) * [1e4, 1e4, 200, 200]
    w = np.concatenate([rng.uniform(-0.1, 0.1, 49), [0.0]])
    once = rm.coordinated_turn(x, w, 2.0)
    halves = rm.coordinated_turn(rm.coordinated_turn(x, w, 1.0), w, 1.0)
    np.testing.assert_allclose(once, halves, rtol=1e-10, atol=1e-6)
    np.testing.assert_allclose(np.hypot(once[:, 2], once[:, 3]), np.hypot(x[:, 2], x[:, 3]), rtol=1e-12)
    cv = x.copy()
    cv[:, :2] += 2.0 * x[:, 2:]
    assert np.array_equal(once[-1], cv[-1])  # ω = 0 is constant velocity, to the bit


# --------------------------------------------------------------------------- parameters


def test_clutter_density_integrates_to_the_clutter_count():
    p = params()
    lam = p["clutter_per_scan"]
    assert rm.clutter_density_per_m2(p) * rm.region_area_m2(p) == pytest.approx(lam)
    r = np.linspace(p["min_range_m"], p["max_range_m"], 100001)
    dtheta = 2 * np.deg2rad(p["sector_half_width_deg"])
    assert integrate.trapezoid(rm.clutter_density_per_m2(p, r) * r * dtheta, r) == pytest.approx(lam, rel=1e-9)
    assert rm.clutter_density_per_m2(p, 1000.0) == pytest.approx(rm.clutter_density_per_m_rad(p) / 1000)
    doc = parameter_docs(load_scenario("radar-multi").source)["clutter_per_scan"]
    for value in (rm.clutter_density_per_m_rad(p), rm.clutter_density_per_m2(p)):
        assert f"{value:.2e}".replace("e-0", "e-") in doc


@pytest.mark.parametrize("override, message", [
    ({"min_range_m": 60000.0}, "min_range_m < max_range_m"),
    ({"sector_half_width_deg": 200.0}, "sector_half_width_deg must be in (0, 180]"),
    ({"survival_probability": 0.0}, "survival_probability"),
    ({"min_speed_mps": 300.0}, "min_speed_mps ≤ max_speed_mps"),
    ({"clutter_per_scan": -1.0}, "clutter_per_scan"),
    ({"detection_probability": 1.5}, "detection_probability"),
    ({"sigma_range_m": float("nan")}, "'sigma_range_m' must be finite"),
])
def test_bad_parameters_are_refused(override, message):
    with pytest.raises(InputError, match=re.escape(message)):
        rm.simulate(params(**override), 2, 0)


def test_a_bad_parameter_is_one_line_on_the_command_line(runner):
    res = runner.invoke(main, ["simulate", "radar-multi", "--runs", "2", "-o", "x.mcap",
                               "--set", "max_range_m=500"])
    assert res.exit_code == 2, res.output
    assert res.stderr.strip().splitlines() == ["replay: error: the region must satisfy 0 ≤ min_range_m < max_range_m"]
    res = runner.invoke(main, ["simulate", "radar-multi", "--runs", "3", "--seed", "3", "-o", "ok.mcap",
                               "--set", "n_scans=5"])
    assert res.exit_code == 0, res.output


def test_importing_the_recorder_pulls_in_no_viewer_or_cli():
    code = ("import sys, trackreplay.recorders.radar_multi; "
            "print(sorted({m.split('.')[0] for m in sys.modules} & {'rerun', 'click', 'polars'}))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=Path(rm.__file__).resolve().parents[1])
    assert out.stdout.strip() == "[]"
