"""What a user runs: simulate, replay, sweep, bundled data, Rerun output and bad input."""

import json
from pathlib import Path

import numpy as np
import polars as pl
import pytest
from click.testing import CliRunner

from trackreplay import vocabulary as vocab
from trackreplay.evaluators.baselines import compare, read_baseline
from trackreplay.face.cli import main
from trackreplay.contract import read_dataset, scenario_metadata
from trackreplay.replay import replay
from trackreplay.recorders import xcorr_peaks
from trackreplay.recorders.scenarios import load_scenario
from trackreplay.recorders.simulated import SimulatedData, write_simulated

REPO = Path(__file__).resolve().parents[1]


def invoke(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    path = tmp_path_factory.mktemp("xc") / "cross.mcap"
    res = invoke("simulate", "xcorr-crossing", "--runs", 8, "--seed", 2, "-o", path, "--set", "crossing_angle_deg=30")
    assert res.exit_code == 0, res.output
    return path


def test_simulate_both_scenarios_write_peaks_and_truth(small, tmp_path):
    ds = read_dataset(small)
    assert {"/xcorr/peaks", "/xcorr/truth"} <= set(ds.channels)
    assert ds.scenario["params"]["crossing_angle_deg"] == 30.0 and ds.scenario["seed"] == "2"
    out = tmp_path / "man.mcap"
    res = invoke("simulate", "xcorr-maneuver", "--runs", 3, "-o", out, "--set", "min_distance_deg=2")
    assert res.exit_code == 0, res.output
    truth = read_dataset(out).channel("/xcorr/truth").grid("bearing_rad")
    assert np.rad2deg(np.min(truth[0, :, 0] - truth[0, :, 1])) == pytest.approx(2.0, abs=0.1)


def test_replay_runs_both_filters_prints_fig8_table_and_writes_rerun(small, tmp_path):
    out = tmp_path / "o" / "tracks.mcap"
    res = invoke(small, "--out", out)
    assert res.exit_code == 0, res.output
    assert "jpda_a" in res.output and "success_rate" in res.output
    assert "track association (Park, Ryu & Lee 1994, Fig. 8)" in (out.parent / "report.txt").read_text()
    assert out.with_suffix(".rrd").stat().st_size > 10_000
    ds = read_dataset(out)
    assert {"/tracks/xcorr/jpda", "/tracks/xcorr/jpda_a"} <= set(ds.channels)
    # eval from the written outputs gives the same numbers as the in-memory replay
    res2 = invoke("eval", small, out, "--json")
    recs = {(r["tracker"], r["metric"], r["scope"]): r["value"] for r in json.loads(res2.output)}
    mem = replay(small).summary
    for r in mem.iter_rows(named=True):
        v = recs[(r["tracker"], r["metric"], r["scope"])]
        assert (v is None and np.isnan(r["value"])) or v == pytest.approx(r["value"], rel=1e-12, abs=1e-12)
    rates = mem.filter(pl.col("scope") == "overall").pivot(on="metric", index="tracker", values="value")
    assert np.allclose(rates["success_rate"] + rates["swap_rate"] + rates["loss_rate"], 1.0)


def test_design_override_and_two_point_start(small):
    a = replay(small, design_overrides={"track_start": "two-point"}).summary
    assert a.filter(pl.col("metric") == "success_rate").height == 2
    res = invoke(small, "--no-rrd", "--set", "q_deg2=abc")
    assert res.exit_code == 2 and "cannot read 'abc' as float" in res.output


def test_sweep_makes_the_fig8_table_and_plot(tmp_path):
    out = tmp_path / "study"
    res = invoke("sweep", "xcorr-crossing", "--param", "crossing_angle_deg=20,30", "--runs", 6,
                 "--executor", "serial", "--no-keep-data", "-o", out)
    assert res.exit_code == 0, res.output
    t = pl.read_parquet(out / "sweep.parquet")
    assert {"success_rate", "swap_rate", "loss_rate"} <= set(t["metric"].unique())
    assert set(t["tracker"].unique()) == {"jpda", "jpda_a"}
    assert (out / "plots" / "success_rate.png").stat().st_size > 0
    res = invoke("association-table", out)
    assert res.exit_code == 0, res.output
    assert "crossing_angle_deg" in res.output and "jpda_a" in res.output
    assert (out / "fig8.png").stat().st_size > 0


def test_bundled_demo_matches_its_baseline():
    summary = replay(REPO / "data" / "xcorr_crossing_demo.mcap").summary
    assert compare(summary, read_baseline(REPO / "data" / "baselines" / "xcorr_crossing_demo.json")) == []


# --------------------------------------------------------------------------- bad input


def _write(path, data, params, seed=0):
    write_simulated(path, data, scenario_metadata("xcorr-crossing", params, seed))
    return path


@pytest.fixture(scope="module")
def base_data():
    p = load_scenario("xcorr-crossing").with_overrides({"crossing_angle_deg": 30.0}).params
    return p, xcorr_peaks.simulate(p, 3, 1)


def _modified(base_data, fn):
    p, data = base_data
    arrays, counts = data.ragged["/xcorr/peaks"]
    arrays = {k: v.copy() for k, v in arrays.items()}
    counts = counts.copy()
    fn(arrays, counts)
    return p, SimulatedData(data.times, fixed=data.fixed, ragged={"/xcorr/peaks": (arrays, counts)})


@pytest.mark.parametrize("name, fn, message", [
    ("negative", lambda a, c: a["amplitude"].__setitem__((0, 5, 0), -10.0), "amplitude holds 1 negative value"),
    ("outside", lambda a, c: a["bearing_rad"].__setitem__((1, 7, 0), np.deg2rad(130.0)),
     "outside the sensor's field [70°, 110°]"),
    ("nan", lambda a, c: a["bearing_rad"].__setitem__((2, 3, 1), np.nan), "NaN/Inf"),
    ("nan_amp", lambda a, c: a["amplitude"].__setitem__((2, 3, 1), np.inf), "NaN/Inf"),
])
def test_bad_peaks_give_one_line_errors(base_data, tmp_path, name, fn, message):
    p, data = _modified(base_data, fn)
    path = _write(tmp_path / f"{name}.mcap", data, p)
    before = path.read_bytes()
    res = invoke(path, "--no-rrd", "--out", tmp_path / "o.mcap")
    assert res.exit_code == 2, res.output
    line = res.output.strip().splitlines()[-1]
    assert line.startswith("replay: error:") and str(path) in line and message in line
    assert "Traceback" not in res.output and path.read_bytes() == before
    assert not (tmp_path / "o.mcap").exists()


def test_empty_scans_coast_and_stay_finite(base_data, tmp_path):
    def empty(a, c):
        c[:, 10:20] = 0
    p, data = _modified(base_data, empty)
    path = _write(tmp_path / "gap.mcap", data, p)
    res = replay(path)
    out = res.results["xcorr"]["tracks"]["jpda_a"]
    assert np.all(out["flags"][:, 10:20] & vocab.COASTED)
    assert np.all(out["beta0"][:, 10:20] == 1.0)
    var = out["covariance"][:, 9:20, :, 0, 0]
    assert np.all(np.diff(var, axis=1) > 0)  # coasting: uncertainty grows every empty scan
    assert np.all(np.isfinite(out["state"][:, 1:]))


def test_missing_labels_for_two_point_start_and_missing_truth(base_data, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # the default replay-out/<name>/ lands here, not in the checkout
    def unlabel(a, c):
        a["origin"][0, 1] = -1
    p, data = _modified(base_data, unlabel)
    path = _write(tmp_path / "nolabel.mcap", data, p)
    res = invoke(path, "--no-rrd", "--set", "track_start=two-point")
    assert res.exit_code == 2 and "no labelled true peak (origin = 0) at scan 1 of run 0" in res.output
    p, data = base_data
    no_truth = SimulatedData(data.times, ragged=data.ragged)
    path = _write(tmp_path / "notruth.mcap", no_truth, p)
    res = invoke(path, "--no-rrd", "--set", "track_start=truth")
    assert res.exit_code == 2 and "track_start='truth' needs /xcorr/truth" in res.output
    res = invoke(path, "--no-rrd")  # auto: no truth, labelled peaks: the two-point start
    assert res.exit_code == 0, res.output  # no truth: association statistics only
    res = invoke(path, "--no-rrd", "--set", "track_start=peaks")  # as a recording without labels
    assert res.exit_code == 0, res.output
