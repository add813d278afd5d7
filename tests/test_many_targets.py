"""Many targets end to end: truth sets with identities through the contract, the built-in
multi-target trackers on the radar-multi scenario, plugged trackers with any number of slots, and
bad truth refused with one line."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import polars as pl
import pytest

from trackreplay import design_values
from trackreplay.contract import read_dataset, scenario_metadata
from trackreplay.face.cli import main
from trackreplay.replay import replay
from trackreplay.stages import stage_named
from trackreplay.recorders.radar_multi import simulate
from trackreplay.recorders.scenarios import load_scenario
from trackreplay.recorders.simulated import SimulatedData, write_simulated

PREFIX = "/tracks/radar/"
TWO_SLOTS = '''
import numpy as np
from trackreplay.trackers.interface import Param, Tracker

class TwoSlots(Tracker):
    """Echoes the first two plots of every scan as two tracks (slot j is track j)."""
    name, family = "two_slots", "radar"
    params = (Param("offset_m", 0.0, "m"),)

    def track(self, plots):
        R, K = plots.counts.shape
        state = np.full((R, K, 2, 4), np.nan)
        flags = np.ones((R, K, 2), np.uint16)  # NO_TRACK
        for j in range(min(2, plots.range_m.shape[2])):
            have = plots.counts > j
            r, b = plots.range_m[..., j], plots.bearing_rad[..., j]
            state[..., j, 0] = np.where(have, r * np.cos(b) + self.offset_m, np.nan)
            state[..., j, 1] = np.where(have, r * np.sin(b), np.nan)
            state[..., j, 2:] = np.where(have[..., None], 0.0, np.nan)
            flags[..., j] = np.where(have, 0, 1)
        return {"state": state, "flags": flags}
'''


def _scenario(**changes):
    params = dict(load_scenario("radar-multi").params)
    params.update(changes)
    return params


def _write(path, params, runs, seed):
    write_simulated(path, simulate(params, runs, seed), scenario_metadata("radar-multi", params, seed))
    return path


def _metric(summary, tracker, metric):
    row = summary.filter((pl.col("tracker") == tracker) & (pl.col("metric") == metric))
    return float(row["value"][0])


def test_truth_sets_round_trip_with_their_identities(tmp_path):
    params = _scenario(n_scans=30)
    data = simulate(params, 3, 4)
    path = _write(tmp_path / "m.mcap", params, 3, 4)
    written, counts = data.ragged["/radar/truth"]
    ds = read_dataset(path)
    stage = stage_named("radar")
    state, ids = stage.decode_truth(ds)
    assert stage.holds_many_targets(ds)
    for r in range(3):
        for k in range(30):
            n = counts[r, k]
            want = {int(i): written["state"][r, k, j] for j, i in enumerate(written["target_id"][r, k, :n])}
            have = {int(i): state[r, k, s] for s, i in enumerate(ids[r, k]) if i >= 0}
            assert want.keys() == have.keys()
            for i in want:
                np.testing.assert_array_equal(have[i], want[i])
    # each identity keeps one slot for its whole life
    for r in range(3):
        for i in np.unique(ids[r][ids[r] >= 0]):
            assert len(set(np.nonzero(ids[r] == i)[1].tolist())) == 1


def test_a_single_target_file_is_a_set_of_one(demo_mcap):
    ds = read_dataset(demo_mcap)
    stage = stage_named("radar")
    state, ids = stage.decode_truth(ds)
    assert state.shape[2] == 1 and (ids == 0).all() and not stage.holds_many_targets(ds)
    np.testing.assert_array_equal(state[:, :, 0], ds.channel("/radar/truth").grid("state"))


def _separated(truth_state, ids, gate_m):
    """Whether every pair of targets stays farther apart than ``gate_m`` at every scan."""
    xy = truth_state[..., :2]
    d = np.linalg.norm(xy[:, :, :, None] - xy[:, :, None, :], axis=-1)
    both = (ids[:, :, :, None] >= 0) & (ids[:, :, None, :] >= 0) & ~np.eye(ids.shape[2], dtype=bool)
    return bool(np.all(np.where(both, d, np.inf) > gate_m))


def test_clean_scene_every_target_found_and_no_identity_lost(tmp_path):
    """No clutter, every target detected, straight flight, targets kilometres apart: each tracker
    must confirm every target after its M-of-N window and never switch or break an identity."""
    params = _scenario(clutter_per_scan=0.0, detection_probability=1.0, turning_fraction=0.0, n_scans=40,
                       initial_targets_mean=4.0, birth_rate_per_scan=0.0, survival_probability=1.0)
    path = _write(tmp_path / "clean.mcap", params, 4, 21)
    stage = stage_named("radar")
    truth, ids = stage.decode_truth(read_dataset(path))
    assert _separated(truth, ids, 2000.0)  # the premise: no two targets ever share a gate
    res = replay(path)
    s = res.summary
    for tracker in ("gnn", "jpda_mt"):
        assert _metric(s, tracker, "id_switches_per_run") == 0
        assert _metric(s, tracker, "track_breaks_per_run") == 0
        assert _metric(s, tracker, "false_tracks_per_run") == 0
        targets = (ids >= 0).any(axis=1).sum()
        # every miss is a target's tentative start, confirm_hits − 1 = 2 scans each; every false
        # positive a track coasting after its target left the region, max_coasted_scans = 5 at most
        assert _metric(s, tracker, "misses_per_run") * 4 <= 2 * targets
        assert _metric(s, tracker, "false_positives_per_run") * 4 <= 5 * targets


def test_default_scenario_within_bounds_that_follow_from_track_life(tmp_path):
    """On the default scenario (clutter, P_D 0.9, turning targets) the trackers' errors come
    mostly from track life: a target of mean life L ≈ 70 scans is missed for about 2 scans
    before 3-of-4 confirmation at P_D 0.9, and its track coasts 5 scans after it dies, so
    (2 + 5) / 70 = 0.10 of the presences are a miss or a false track. The bounds allow twice
    that (MOTA ≥ 0.8, IDF1 ≥ 0.8) and mean GOSPA at most that share of the cut-off's cost."""
    path = _write(tmp_path / "default.mcap", _scenario(n_scans=60), 8, 17)
    res = replay(path)
    s = res.summary
    for tracker in ("gnn", "jpda_mt"):
        assert _metric(s, tracker, "mota") >= 0.8
        assert _metric(s, tracker, "idf1") >= 0.8
        # GOSPA² ≈ c²/2 per missed or false target-scan (c = cut-off) + localisation; with about
        # 10 targets, 2 × 0.10 × 10 of them cost c²/2: GOSPA ≤ c·sqrt(1) = c
        cutoff = design_values.resolve(stage_named("radar"), read_dataset(path))["ospa_cutoff_m"]
        assert _metric(s, tracker, "gospa_mean_m") <= cutoff


@pytest.fixture
def two_slots(tmp_path) -> Path:
    path = tmp_path / "two_slots.py"
    path.write_text(TWO_SLOTS)
    return path


def test_a_plugged_two_slot_tracker_replays_evaluates_and_compares(runner, radar_small, two_slots):
    res = runner.invoke(main, [str(radar_small), "--tracker", "two_slots.py:TwoSlots", "--no-rrd", "--out",
                               "a/t.mcap", "--figures", "now"])
    assert res.exit_code == 0, res.output
    channels = read_dataset(Path("a/t.mcap")).channels
    assert {PREFIX + t for t in ("fixed", "kalman", "two_slots")} <= set(channels)
    metrics = pl.read_csv("a/metrics.csv")
    two = metrics.filter(pl.col("tracker") == "two_slots")
    assert {"gospa_mean_m", "mota", "idf1"} <= set(two["metric"].to_list())
    assert Path("a/tracks.png").is_file()
    res = runner.invoke(main, ["eval", str(radar_small), "a/t.mcap", "--json"])
    assert res.exit_code == 0, res.output
    assert "two_slots" in {r["tracker"] for r in json.loads(res.stdout)}
    res = runner.invoke(main, [str(radar_small), "--tracker", "two_slots.py:TwoSlots", "--no-rrd", "--out",
                               "b/t.mcap", "--set", "offset_m=50", "--figures", "none"])
    assert res.exit_code == 0, res.output
    res = runner.invoke(main, ["compare", "b/t.mcap", "a/t.mcap", "--data", str(radar_small), "-o", "cmp"])
    assert res.exit_code == 0, res.output
    table = pl.read_csv("cmp/compare.csv").filter(pl.col("tracker_a") == "two_slots")
    gospa = table.filter(pl.col("metric") == "gospa_mean_m")
    # A's tracks were moved 50 m off the plots: its GOSPA is worse, by a significant margin
    assert gospa.height == 1 and gospa["difference"][0] > 0 and gospa["verdict"][0] == "worse"


def test_a_plugged_two_slot_tracker_beside_the_multi_target_ones(runner, two_slots):
    data = Path(__file__).resolve().parents[1] / "data" / "radar_multi_demo.mcap"
    res = runner.invoke(main, [str(data), "--tracker", "two_slots.py:TwoSlots", "--out", "o/t.mcap",
                               "--figures", "none"])
    assert res.exit_code == 0, res.output
    channels = read_dataset(Path("o/t.mcap")).channels
    assert {PREFIX + t for t in ("gnn", "jpda_mt", "two_slots")} <= set(channels)
    assert Path("o/t.rrd").is_file()


def test_an_identity_twice_in_one_scan_is_refused_with_one_line(runner, tmp_path):
    params = _scenario(n_scans=10)
    data = simulate(params, 2, 3)
    arrays, counts = data.ragged["/radar/truth"]
    ids = arrays["target_id"].copy()
    r, k = np.argwhere(counts >= 2)[0]
    ids[r, k, 1] = ids[r, k, 0]
    bad = SimulatedData(times=data.times, ragged={**data.ragged, "/radar/truth": ({**arrays, "target_id": ids},
                                                                                   counts)})
    write_simulated(tmp_path / "twice.mcap", bad, scenario_metadata("radar-multi", params, 3))
    before = (tmp_path / "twice.mcap").read_bytes()
    res = runner.invoke(main, [str(tmp_path / "twice.mcap"), "--no-rrd", "--out", "o/t.mcap"])
    assert res.exit_code == 2, res.output
    errors = [line for line in res.stderr.splitlines() if line.startswith("replay: error: ")]
    assert len(errors) == 1 and f"appears twice at run {r} scan {k}" in errors[0] and "Traceback" not in res.output
    assert (tmp_path / "twice.mcap").read_bytes() == before
    assert not Path("o").exists() or not any(Path("o").iterdir())


BAD_IDS = '''
import numpy as np
from trackreplay.trackers.interface import Tracker

class _Base(Tracker):
    family = "radar"

    def outputs(self, plots):
        R, K = plots.counts.shape
        state = np.zeros((R, K, 2, 4))
        state[..., 0] = plots.range_m[..., :1] * np.cos(plots.bearing_rad[..., :1])
        return {"state": state, "flags": np.zeros((R, K, 2), np.uint16)}

class RepeatedId(_Base):
    name = "repeated_id"

    def track(self, plots):
        out = self.outputs(plots)
        out["track_id"] = np.zeros(out["flags"].shape, np.int64)  # both slots claim track 0
        return out

class FractionalId(_Base):
    name = "fractional_id"

    def track(self, plots):
        out = self.outputs(plots)
        out["track_id"] = np.broadcast_to(np.array([0.5, 1.5]), out["flags"].shape)
        return out
'''


@pytest.mark.parametrize("cls, fragment", [("RepeatedId", "run 0 scan 0: track_id 0 is in two slots"),
                                           ("FractionalId", "track_id must hold integers")])
def test_bad_track_ids_get_one_line_and_the_others_are_written(runner, radar_small, tmp_path, cls, fragment):
    (tmp_path / "bad_ids.py").write_text(BAD_IDS)
    res = runner.invoke(main, [str(radar_small), "--tracker", f"bad_ids.py:{cls}", "--no-rrd", "--out", "o/t.mcap",
                               "--figures", "none"])
    assert res.exit_code == 2, res.output
    errors = [line for line in res.stderr.splitlines() if line.startswith("replay: error: ")]
    assert len(errors) == 1 and fragment in errors[0] and "Traceback" not in res.output
    assert PREFIX + "kalman" in read_dataset(Path("o/t.mcap")).channels


LONG_TABLE = """run,time_s,range_m,bearing_deg,truth_id,truth_x_m,truth_y_m,truth_vx_mps,truth_vy_mps
0,0,10000,30,0,8660.254,5000,100,0
0,0,20000,-10,1,19696.155,-3472.964,0,150
0,0,15000,5,,,,,
0,1,10010,30.5,0,8760.254,5000,100,0
0,1,,,1,19696.155,-3322.964,0,150
0,2,10020,31,0,8860.254,5000,100,0
0,2,20050,-9.5,1,19696.155,-3172.964,0,150
0,2,30000,45,,,,,
0,3,,,,,,,
"""


def test_a_long_table_of_many_targets_converts_with_its_truth_set(runner, tmp_path):
    (tmp_path / "many.csv").write_text(LONG_TABLE)
    res = runner.invoke(main, ["convert", "plots", str(tmp_path / "many.csv"), "-o", "many.mcap",
                               "--set", "sigma_range_m=20", "--set", "sigma_bearing_deg=0.5"])
    assert res.exit_code == 0, res.output
    assert "7 plots; with truth" in res.output
    ds = read_dataset(Path("many.mcap"))
    stage = stage_named("radar")
    state, ids = stage.decode_truth(ds)
    assert stage.holds_many_targets(ds)
    # scan 1: target 1 without a plot keeps its truth; scan 3: neither plots nor targets
    np.testing.assert_array_equal(ids[0], [[0, 1], [0, 1], [0, 1], [-1, -1]])
    np.testing.assert_allclose(state[0, 1, 1], [19696.155, -3322.964, 0, 150])
    origin, counts = ds.channel("/radar/plots").ragged("origin")
    np.testing.assert_array_equal(counts[0], [3, 1, 3, 0])
    np.testing.assert_array_equal(origin[0, 0], [0, 1, -1])  # the plot without truth is nobody's
    res = runner.invoke(main, ["many.mcap", "--no-rrd", "--figures", "none", "--out", "o/t.mcap"])
    assert res.exit_code == 0, res.output
    assert {PREFIX + "gnn", PREFIX + "jpda_mt"} <= set(read_dataset(Path("o/t.mcap")).channels)


@pytest.mark.parametrize("edit, fragment", [
    (lambda s: s.replace("0,1,10010,30.5,0,8760.254", "0,1,10010,30.5,0,8700.0"), None),
    (lambda s: s.replace("0,2,10020,31,0,8860.254,5000,100,0", "0,2,10020,31,0,8860.254,5000,100,0\n"
                         "0,2,,,0,8861.0,5000,100,0"), "a target has one state a scan"),
    (lambda s: s.replace("0,0,15000,5,,,,,", "0,0,15000,5,,1.0,,,"), "names no target"),
    (lambda s: s.replace("0,1,,,1,19696.155,-3322.964,0,150", "0,1,,,1,,-3322.964,0,150"), "names target 1"),
], ids=["moved-target", "two-states", "truth-without-id", "id-without-truth"])
def test_a_long_table_with_inconsistent_truth_is_refused_with_one_line(runner, tmp_path, edit, fragment):
    (tmp_path / "many.csv").write_text(edit(LONG_TABLE))
    res = runner.invoke(main, ["convert", "plots", str(tmp_path / "many.csv"), "-o", "many.mcap"])
    if fragment is None:  # a target may move between scans: nothing to refuse
        assert res.exit_code == 0, res.output
        return
    assert res.exit_code == 2, res.output
    errors = [line for line in res.stderr.splitlines() if line.startswith("replay: error: ")]
    assert len(errors) == 1 and fragment in errors[0] and "Traceback" not in res.output
    assert not Path("many.mcap").exists()


def test_a_plugged_two_slot_tracker_sweeps_beside_the_multi_target_ones(runner, two_slots):
    res = runner.invoke(main, ["sweep", "radar-multi", "--param", "clutter_per_scan=0,20", "--runs", "3",
                               "--set", "n_scans=20", "-o", "sw", "--tracker", "two_slots.py:TwoSlots"])
    assert res.exit_code == 0, res.output
    table = pl.read_parquet("sw/sweep.parquet")
    assert {"gnn", "jpda_mt", "two_slots"} == set(table["tracker"].to_list())  # ukf runs when named
    mota = table.filter(pl.col("metric") == "mota")
    assert mota.height == 6 and mota["value"].is_finite().all()


def test_eval_takes_evaluation_design_values_and_a_tracker_subset(runner):
    data = Path(__file__).resolve().parents[1] / "data" / "radar_multi_demo.mcap"
    res = runner.invoke(main, [str(data), "--no-rrd", "--figures", "none", "--out", "o/t.mcap", "--trackers", "gnn"])
    assert res.exit_code == 0, res.output

    def values(*extra):
        r = runner.invoke(main, ["eval", str(data), "o/t.mcap", "--json", *extra])
        assert r.exit_code == 0, r.output
        return {(x["tracker"], x["metric"]): x["value"] for x in json.loads(r.stdout) if x["scope"] == "overall"}

    default, tight = values(), values("--set", "assignment_gate_m=30")
    # a 30 m gate is below the tracks' typical error (σ_r = 20 m, 0.2° at tens of km): matches are
    # lost, so MOTA falls and MOTP (the matched distance) shrinks
    assert tight[("gnn", "mota")] < default[("gnn", "mota")]
    assert tight[("gnn", "motp_m")] < default[("gnn", "motp_m")]
    res = runner.invoke(main, ["eval", str(data), "o/t.mcap", "--set", "confirm_hits=2"])
    assert res.exit_code == 2 and "only the evaluation's design values change" in res.output
    res = runner.invoke(main, ["eval", str(data), "--trackers", "ukf", "--json"])
    assert res.exit_code == 0, res.output
    assert {r["tracker"] for r in json.loads(res.stdout) if r.get("tracker")} == {"ukf"}


def test_life_tables_follow_a_hand_made_swap():
    """Two targets on parallel lines 1 km apart; track 7 follows target 0 for 3 scans, then jumps
    to target 1 (and track 9 the other way round): each target is tracked throughout by two
    identities with one switch, each track spends 3 of its 6 scans on each target."""
    from trackreplay.evaluators.life_tables import life_tables

    K = 6
    times = np.arange(K, dtype=float)
    truth = np.zeros((1, K, 2, 2))
    truth[0, :, 0] = np.stack([np.arange(K) * 10.0, np.zeros(K)], axis=-1)
    truth[0, :, 1] = np.stack([np.arange(K) * 10.0, np.full(K, 1000.0)], axis=-1)
    truth_ids = np.broadcast_to([0, 1], (1, K, 2)).copy()
    tracks = truth.copy() + 3.0
    tracks[0, 3:] = tracks[0, 3:, ::-1]  # the swap: slot 0 jumps to target 1 from scan 3 on
    track_ids = np.broadcast_to([7, 9], (1, K, 2)).copy()
    targets, lives = life_tables("t", times, tracks, track_ids, truth, truth_ids, gate=100.0)
    for row in targets.iter_rows(named=True):
        assert row["tracks"] == 2 and row["switches"] == 1 and row["tracked_fraction"] == 1.0
        assert row["rmse"] == pytest.approx(np.sqrt(18.0))
        assert (row["first_tracked_s"], row["last_tracked_s"]) == (0.0, 5.0)
    by_id = {r["track_id"]: r for r in lives.iter_rows(named=True)}
    for track in (7, 9):  # 3 scans on each target: a tie, the lower identity named
        assert by_id[track]["scans"] == 6 and by_id[track]["matched_fraction"] == 0.5
        assert by_id[track]["target_id"] == 0


def test_replay_writes_the_target_and_track_tables(runner):
    data = Path(__file__).resolve().parents[1] / "data" / "radar_multi_demo.mcap"
    res = runner.invoke(main, [str(data), "--no-rrd", "--figures", "none", "--out", "o/t.mcap", "--trackers", "gnn"])
    assert res.exit_code == 0, res.output
    targets, lives = pl.read_parquet("o/targets.parquet"), pl.read_parquet("o/track_lives.parquet")
    truth = stage_named("radar").decode_truth(read_dataset(data))[1]
    assert targets.height == sum(np.unique(truth[r][truth[r] >= 0]).size for r in range(truth.shape[0]))
    assert targets["tracked_fraction"].is_between(0, 1).all() and (lives["scans"] > 0).all()
    # a track is reported once confirmed: never before its target appeared
    assert (lives["first_s"] >= 0).all() and set(lives["target_id"].to_list()) <= set(targets["target_id"]) | {-1}


def test_a_plugged_two_slot_tracker_in_check(runner, radar_small, two_slots):
    import shutil

    Path("d/baselines").mkdir(parents=True)
    shutil.copy(radar_small, "d/radar_small.mcap")
    res = runner.invoke(main, ["check", "d", "--update", "--tracker", "two_slots.py:TwoSlots"])
    assert res.exit_code == 0, res.output
    baseline = json.loads(Path("d/baselines/radar_small.json").read_text())
    assert {"mota", "gospa_mean_m", "hota"} <= {m["metric"] for m in baseline["metrics"] if m["tracker"] == "two_slots"}
    res = runner.invoke(main, ["check", "d", "--tracker", "two_slots.py:TwoSlots"])
    assert res.exit_code == 0, res.output
    # moved 500 m off the plots: its set measures drift and the check fails on them
    Path("moved.py").write_text(TWO_SLOTS.replace('Param("offset_m", 0.0', 'Param("offset_m", 500.0'))
    res = runner.invoke(main, ["check", "d", "--tracker", "moved.py:TwoSlots"])
    assert res.exit_code == 1 and "two_slots gospa_mean_m" in res.stdout, res.output


def test_a_variant_runs_when_named_and_not_by_default(tmp_path):
    """``ukf`` (the GNN with another filter) is a built-in a replay runs only when named."""
    path = _write(tmp_path / "few.mcap", _scenario(n_scans=12, initial_targets_mean=3.0), 2, 7)
    assert set(replay(path).results["radar"]["tracks"]) == {"gnn", "jpda_mt"}
    named = replay(path, trackers=["gnn", "jpda_mt", "ukf"]).results["radar"]["tracks"]
    assert set(named) == {"gnn", "jpda_mt", "ukf"}
