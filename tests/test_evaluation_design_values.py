"""Evaluation design values (the matching gate, GOSPA's c and p, HOTA's scale, the SIAP gate) are
design values on every command that scores: `replay compare`, `replay check` and `replay sweep`
take `--set NAME=VALUE` for them, score exactly as `replay eval` does with the same values,
refuse an unknown name with one line, list them in `--help` and record them with their outputs
(issue 26, item 3)."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import polars as pl
import pytest

from trackreplay.contract import METADATA_PROVENANCE, read_dataset
from trackreplay.face.cli import main

GATE, CUTOFF = "assignment_gate_m=30", "ospa_cutoff_m=200"  # far below the radar data's own values
DEPENDENT = ("mota", "motp_m", "ospa_mean_m")  # metrics that move with them


def invoke(runner, *args):
    return runner.invoke(main, [str(a) for a in args])


def one_line_error(res, *words):
    """Exit status 2 and one `replay: error:` line holding ``words``."""
    assert res.exit_code == 2, res.output
    lines = res.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("replay: error: "), res.output
    assert all(w in lines[0] for w in words), lines[0]
    assert "Traceback" not in res.output


def eval_values(runner, *args) -> dict:
    """(tracker, metric, scope) → value of `replay eval ... --json`, the standard measures under
    the scope "standard measures" as compare lists them."""
    res = invoke(runner, "eval", *args, "--json")
    assert res.exit_code == 0, res.output
    return {(r["tracker"], r["metric"], "standard measures" if r.get("kind") == "standard" else r["scope"]): r["value"]
            for r in json.loads(res.stdout) if r.get("tracker")}


def sets(*assignments):
    return [x for a in assignments for x in ("--set", a)]


@pytest.fixture(scope="module")
def replayed(tmp_path_factory, radar_small):
    """Two replay outputs of the small radar data set (two trackers: fast)."""
    from click.testing import CliRunner

    folder = tmp_path_factory.mktemp("replayed")
    for side in ("a", "b"):
        res = CliRunner().invoke(main, [str(radar_small), "--no-rrd", "--figures", "none", "--trackers",
                                        "kalman,fixed", "--out", str(folder / side / "tracks.mcap")])
        assert res.exit_code == 0, res.output
    return radar_small, folder / "a" / "tracks.mcap", folder / "b" / "tracks.mcap"


def test_compare_scores_both_sides_with_the_set_values_as_eval_does(runner, replayed):
    data, a, b = replayed
    res = invoke(runner, "compare", a, b, "--data", data, "--json", "-o", "cmp", *sets(GATE, CUTOFF))
    assert res.exit_code == 0, res.output
    rows = json.loads(res.stdout)
    expect_a, expect_b = (eval_values(runner, data, side, *sets(GATE, CUTOFF)) for side in (a, b))
    assert rows
    for r in rows:
        assert r["value_a"] == pytest.approx(expect_a[(r["tracker_a"], r["metric"], r["scope"])], rel=1e-12, nan_ok=True)
        assert r["value_b"] == pytest.approx(expect_b[(r["tracker_b"], r["metric"], r["scope"])], rel=1e-12, nan_ok=True)
    # the values matter: the metrics that depend on them differ from the defaults', the others not
    default = eval_values(runner, data, a)
    for metric in DEPENDENT:
        key = ("kalman", metric, "standard measures")
        assert expect_a[key] != default[key]
    assert expect_a[("kalman", "rmse_position_m", "overall")] == default[("kalman", "rmse_position_m", "overall")]
    # recorded in compare.parquet's metadata
    record = json.loads(pl.read_parquet_metadata(Path("cmp") / "compare.parquet")["replay.compare"])
    assert record["evaluation"]["assignment_gate_m"] == 30.0 and record["evaluation"]["ospa_cutoff_m"] == 200.0
    assert set(record["evaluation_set"]) == {"assignment_gate_m", "ospa_cutoff_m"}
    # and printed
    res = invoke(runner, "compare", a, b, "--data", data, "-o", "cmp2", *sets(GATE))
    assert res.exit_code == 0 and "assignment_gate_m=30 (--set)" in " ".join(res.output.split())


def test_compare_refuses_an_unknown_name_and_a_trackers_design_value(runner, replayed):
    data, a, b = replayed
    res = invoke(runner, "compare", a, b, "--data", data, "-o", "cmp", "--set", "asignment_gate_m=30")
    one_line_error(res, "asignment_gate_m", "not an evaluation design value", "assignment_gate_m", "ospa_cutoff_m")
    res = invoke(runner, "compare", a, b, "--data", data, "-o", "cmp", "--set", "nominal_cross_range_m=120")
    one_line_error(res, "nominal_cross_range_m", "replay again", "assignment_gate_m")
    one_line_error(invoke(runner, "compare", a, b, "--data", data, "-o", "cmp", "--set", "ospa_order=0.5"),
                   "ospa_order")
    assert not Path("cmp").exists()


def _drifts(output: str) -> dict:
    """(tracker, metric, scope) → (baseline, value) of a check's drift lines."""
    found = re.findall(r"^\s+(\S+) (\S+) \[(.+?)\]: (\S+) -> (\S+) \(moved", output, flags=re.M)
    return {(t, m, s): (float(old), float(new)) for t, m, s, old, new in found}


def test_check_scores_the_data_sets_with_the_set_values_as_eval_does(runner, tmp_path, radar_small):
    data = tmp_path / "d"
    (data / "baselines").mkdir(parents=True)
    shutil.copy(radar_small, data / "small.mcap")
    assert invoke(runner, "check", data, "--update").exit_code == 0
    assert invoke(runner, "check", data).exit_code == 0
    res = invoke(runner, "check", data, *sets(GATE, CUTOFF))
    assert res.exit_code == 1, res.output  # the baselines hold the defaults' metrics
    note = [line for line in res.output.splitlines() if "non-default evaluation values" in line]
    assert len(note) == 1 and "assignment_gate_m=30" in note[0] and "ospa_cutoff_m=200" in note[0]
    drifts = _drifts(res.output)
    before, after = eval_values(runner, data / "small.mcap"), eval_values(runner, data / "small.mcap", *sets(GATE, CUTOFF))
    scope = lambda key: (key[0], key[1], "standard measures" if key[2] == "overall" and key not in before else key[2])
    assert drifts
    for key, (old, new) in drifts.items():
        assert old == float(f"{before[scope(key)]:.6g}") and new == float(f"{after[scope(key)]:.6g}")
    moved = {k for k in before if k[1] in DEPENDENT and before[k] != after[k]}
    assert moved and {(t, m) for t, m, _ in moved} <= {(t, m) for t, m, _ in drifts}
    # --update keeps the defaults' baselines: refused with --set
    one_line_error(invoke(runner, "check", data, "--update", *sets(GATE)), "--update", "--set")


def test_check_refuses_an_unknown_name(runner, tmp_path):
    one_line_error(invoke(runner, "check", tmp_path, "--set", "gate_m=3"), "gate_m", "assignment_gate_m",
                   "assignment_gate_deg", "ospa_cutoff_deg")
    one_line_error(invoke(runner, "check", tmp_path, "--set", "confirm_hits=2"), "confirm_hits", "evaluation design values only")


@pytest.mark.parametrize("executor", ["serial", "process"])
def test_sweep_scores_every_point_with_the_set_values_as_eval_does(runner, executor):
    args = ["sweep", "radar-tws", "--param", "ospa_cutoff_m=200,300", "--runs", "4", "--seed", "3",
            "--executor", executor, "--workers", "2", "--trackers", "kalman"]
    res = invoke(runner, *args, *sets(GATE, "sigma_bearing_deg=0.5"), "-o", "s")
    assert res.exit_code == 0, res.output
    assert invoke(runner, *args, *sets("sigma_bearing_deg=0.5"), "--no-keep-data", "-o", "d").exit_code == 0
    table, default = pl.read_parquet("s/sweep.parquet"), pl.read_parquet("d/sweep.parquet")
    assert table["point"].to_list() == default["point"].to_list() and table["point"].n_unique() == 2
    # the evaluation values change no point's seed: every point scores the same data set
    assert table["seed"].n_unique() == 1 and table["seed"].to_list() == default["seed"].to_list()
    spec = json.loads(Path("s/sweep.json").read_text())
    assert spec["evaluation"]["radar"]["assignment_gate_m"] == 30.0
    assert spec["evaluation"]["radar"]["ospa_cutoff_m"] == {"ospa_cutoff_m=200": 200.0, "ospa_cutoff_m=300": 300.0}
    assert json.loads(pl.read_parquet_metadata("s/sweep.parquet")["replay.evaluation"]) == spec["evaluation"]
    for label in table["point"].unique().to_list():
        point = Path("s/points") / label
        cutoff = label.rsplit("=", 1)[1]
        used = json.loads((point / "point.json").read_text())["evaluation"]["radar"]
        assert used["assignment_gate_m"] == 30.0 and used["ospa_cutoff_m"] == float(cutoff)
        design = json.loads(read_dataset(point / "tracks.mcap").metadata[METADATA_PROVENANCE]["design"])
        assert design["radar"]["assignment_gate_m"] == 30.0
        # the point's metrics are those eval gives on its data set with the same values
        expect = eval_values(runner, point / "data.mcap", "--trackers", "kalman", *sets(GATE, f"ospa_cutoff_m={cutoff}"))
        for r in table.filter(pl.col("point") == label).iter_rows(named=True):
            key = next(k for k in (("kalman", r["metric"], "overall"), ("kalman", r["metric"], "standard measures"))
                       if k in expect)
            assert r["value"] == pytest.approx(expect[key], rel=1e-12, nan_ok=True)
        mota = lambda t: t.filter((pl.col("point") == label) & (pl.col("metric") == "mota"))["value"][0]
        assert mota(table) != mota(default)
    # a sweep of the evaluation value alone: its metrics move, the tracker's do not
    ospa = table.filter(pl.col("metric") == "ospa_mean_m")["value"].to_list()
    rmse = table.filter(pl.col("metric") == "rmse_position_m")["value"].to_list()
    assert ospa[0] != ospa[1] and rmse[0] == rmse[1]


def test_sweep_refuses_an_unknown_name_and_a_value_out_of_range(runner):
    args = ["sweep", "radar-tws", "--param", "sigma_bearing_deg=1", "--runs", "2", "--executor", "serial", "-o", "s"]
    one_line_error(invoke(runner, *args, "--set", "asignment_gate_m=30"), "unknown parameter 'asignment_gate_m'",
                   "assignment_gate_m", "ospa_cutoff_m", "siap_gate_m")
    one_line_error(invoke(runner, *args, "--param", "ospa_order=2,0.5"), "ospa_order")
    assert not Path("s").exists()


def test_replay_records_the_set_values_in_its_outputs_provenance(runner, radar_small):
    res = invoke(runner, radar_small, "--no-rrd", "--figures", "none", "--trackers", "kalman", "--out", "o/t.mcap",
                 *sets(GATE))
    assert res.exit_code == 0, res.output
    design = json.loads(read_dataset("o/t.mcap").metadata[METADATA_PROVENANCE]["design"])["radar"]
    assert design["assignment_gate_m"] == 30.0


@pytest.mark.parametrize("command", ["compare", "check", "sweep"])
def test_help_lists_every_stages_evaluation_values_with_their_defaults(runner, command):
    from trackreplay.stages import STAGES

    text = " ".join(invoke(runner, command, "--help").output.split())
    assert "--set NAME=VALUE" in text
    for stage in STAGES:
        listed = re.search(rf"{re.escape(stage.name)} ((?:\w+=[\d.]+,? )+)", text + " ")
        assert listed, (stage.name, text)
        values = dict(item.split("=") for item in listed.group(1).replace(",", "").split())
        assert values == {k: f"{v:g}" for k, v in stage.evaluation_defaults.items()}, stage.name
