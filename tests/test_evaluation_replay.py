"""The standard measures and Monte Carlo intervals as a user meets them: in `replay`, `replay
eval`, `replay compare`, `replay check`, and the posterior Cramér–Rao bound."""

from __future__ import annotations

import json
import re

import numpy as np
import polars as pl
import pytest

from trackreplay import design_values
from trackreplay.evaluators.compare import direction
from trackreplay.cores.filters.kalman import kf_predict, kf_update
from trackreplay.cores.filters.pcrb import pcrb_recursion
from trackreplay.face.cli import main
from trackreplay.contract import read_dataset
from trackreplay.replay import replay
from trackreplay.stages import stage_named

STANDARD = {"ospa_mean_m", "gospa_mean_m", "mota", "motp_m", "idf1", "nees_time_average", "nis_time_average",
            "anees_inside_fraction", "mostly_tracked_per_run", "id_switches_per_run"}


@pytest.fixture(scope="module")
def demo_result(demo_mcap):
    return replay(demo_mcap)


def test_every_metric_has_an_interval_that_holds_its_value(demo_result):
    s = demo_result.summary
    assert {"se", "ci_low", "ci_high"} <= set(s.columns)
    with_ci = s.filter(pl.col("ci_low").is_not_null())
    assert with_ci.height > 0.6 * s.filter(pl.col("value").is_not_null()).height
    assert (with_ci["ci_low"] <= with_ci["value"] + 1e-12).all() and (with_ci["value"] <= with_ci["ci_high"] + 1e-12).all()
    rmse = with_ci.filter(pl.col("metric") == "rmse_position_m")
    assert rmse.height >= 4 and (rmse["se"] > 0).all()


def test_standard_measures_are_reported_for_every_tracker(demo_result):
    s = demo_result.summary
    for tracker in ("fixed", "approximate", "exact", "kalman"):
        have = set(s.filter(pl.col("tracker") == tracker)["metric"])
        assert STANDARD <= have, STANDARD - have
    # the NEES time average's χ² bounds bracket the filter's state dimension (4 for radar)
    low = s.filter(pl.col("metric") == "nees_time_average_low")["value"]
    high = s.filter(pl.col("metric") == "nees_time_average_high")["value"]
    assert (low < 4).all() and (high > 4).all()


def test_ospa_never_exceeds_its_cutoff_and_gospa_parts_add_up(demo_result, demo_mcap):
    p = demo_result.per_scan
    cutoff = design_values.resolve(stage_named("radar"), read_dataset(demo_mcap))["ospa_cutoff_m"]
    assert p["ospa_m"].drop_nulls().max() <= cutoff + 1e-9
    # with one target and one track GOSPA (p = 2, α = 2) is √(loc² + c²/2 (missed + false))
    g = p.select("gospa_m", "gospa_localisation_m", "gospa_missed", "gospa_false").drop_nulls()
    assert g.height > 0


def test_pcrb_equals_the_kalman_covariance_on_a_linear_gaussian_model():
    rng = np.random.default_rng(4)
    dt, K = 2.0, 30
    F = np.array([[1, dt, 0, 0], [0, 1, 0, 0], [0, 0, 1, dt], [0, 0, 0, 1.0]])
    G = np.array([[dt**2 / 2, 0], [dt, 0], [0, dt**2 / 2], [0, dt]])
    Q = G @ G.T * 0.7**2
    H = np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0]])
    Rm = np.array([[40.0**2, 300.0], [300.0, 25.0**2]])
    P0 = np.diag(rng.uniform(100, 900, 4))
    info = np.broadcast_to(H.T @ np.linalg.solve(Rm, H), (K, 4, 4))
    bound = pcrb_recursion(P0, F, Q, info)
    x, P = np.zeros(4), P0
    for k in range(1, K):
        x, P = kf_predict(x, P, F, Q)
        x, P, *_ = kf_update(x, P, H @ x, H, Rm)
        np.testing.assert_allclose(bound[k], P, rtol=1e-10, atol=1e-10)


def test_pcrb_bounds_every_radar_tracker(demo_result):
    s = demo_result.summary.filter(pl.col("metric") == "position_efficiency")
    assert s.height == 4
    # an efficiency above 1 would mean an error below the bound (beyond Monte Carlo error)
    assert (s["ci_low"] < 1.0).all() and (s["value"] > 0).all()


EFFICIENCY_NAME = r"^[a-z_]+_efficiency$"


@pytest.mark.parametrize("dataset", ["radar_tws_demo", "colored_imm_demo", "tdoa_fdoa_demo"])
def test_efficiency_is_one_convention_in_every_family(dataset, demo_result, demo_mcap):
    """Every family names its efficiency ``<kind>_efficiency`` and means the same by it: the
    bound (CRLB or PCRB, as an RMS) over the RMSE of the same table row, ≤ 1 up to Monte Carlo
    error, higher is better (``docs/evaluation.md``)."""
    path = demo_mcap.parent / f"{dataset}.mcap"
    s = demo_result.summary if path == demo_mcap else replay(path).summary
    names = set(s.filter(pl.col("metric").str.contains("efficiency"))["metric"])
    assert names, dataset
    assert all(re.match(EFFICIENCY_NAME, m) and not m.startswith("efficiency_") for m in names), names
    assert all(direction(m) == 1 for m in names)
    rows: dict = {}  # (stage, kind, tracker, scope) → {metric: value}: one row of the wide table
    for r in s.iter_rows(named=True):
        rows.setdefault((r["stage"], r["kind"], r["tracker"], r["scope"]), {})[r["metric"]] = r["value"]
    checked = 0
    for where, row in rows.items():
        for metric in sorted(names & set(row)):
            eff, block = row[metric], metric.removesuffix("_efficiency")
            rmse = next(v for m, v in row.items() if m.startswith(f"rmse_{block}_"))
            bound = next(v for m, v in row.items() if m.startswith((f"crlb_{block}_", f"pcrb_{block}_")))
            if np.isnan(eff):  # no run at the truth (e.g. an estimator that cannot estimate the block)
                assert np.isnan(rmse) and np.isnan(bound), (where, metric)
                continue
            assert eff == pytest.approx(bound / rmse, rel=1e-12), (where, metric)
            checked += 1
    assert checked >= 2


def test_eval_json_carries_the_intervals(runner, demo_mcap):
    res = runner.invoke(main, ["eval", str(demo_mcap), "--json"])
    assert res.exit_code == 0, res.output
    records = json.loads(res.output)
    rmse = [r for r in records if r["metric"] == "rmse_position_m" and r["scope"] == "overall"]
    assert rmse and all(r["ci_low"] < r["value"] < r["ci_high"] for r in rmse)


@pytest.fixture(scope="module")
def two_outputs(tmp_path_factory, radar_small):
    folder = tmp_path_factory.mktemp("cmp")
    a, b = folder / "a" / "tracks.mcap", folder / "b" / "tracks.mcap"
    replay(radar_small, out_path=a)
    replay(radar_small, out_path=b)
    return radar_small, a, b


def test_compare_of_identical_outputs_finds_no_difference(runner, two_outputs):
    data, a, b = two_outputs
    res = runner.invoke(main, ["compare", str(a), str(b), "--data", str(data), "--json"])
    assert res.exit_code == 0, res.output
    rows = json.loads(res.output)
    assert rows and {r["verdict"] for r in rows} == {"no significant difference"}
    assert all(r["difference"] == 0 for r in rows)


def test_compare_of_two_trackers_has_the_signs_the_tables_show(runner, two_outputs):
    data, a, b = two_outputs
    res = runner.invoke(main, ["compare", str(a), str(b), "--data", str(data), "--pair", "kalman:fixed", "--json"])
    assert res.exit_code == 0, res.output
    rows = json.loads(res.output)
    table = replay(data).summary
    # compare lists the standard measures under the scope "standard measures", as replay prints them
    value = {(r["tracker"], r["metric"], "standard measures" if r["kind"] == "standard" else r["scope"]): r["value"]
             for r in table.iter_rows(named=True)}
    for r in rows:
        expected = value[("kalman", r["metric"], r["scope"])] - value[("fixed", r["metric"], r["scope"])]
        assert r["difference"] == pytest.approx(expected, rel=1e-9, abs=1e-12)
        if r["verdict"] in ("better", "worse"):
            assert r["ci_low"] > 0 or r["ci_high"] < 0
    assert any(r["verdict"] != "no significant difference" for r in rows)


def test_compare_refuses_outputs_of_another_data_set(runner, two_outputs, demo_mcap):
    _, a, b = two_outputs
    res = runner.invoke(main, ["compare", str(a), str(b), "--data", str(demo_mcap)])
    assert res.exit_code == 2
    assert "another data set" in res.output and "Traceback" not in res.output


def test_check_names_the_standard_errors_a_doctored_baseline_moved(runner, tmp_path, radar_small):
    import shutil

    data = tmp_path / "d"
    (data / "baselines").mkdir(parents=True)
    shutil.copy(radar_small, data / "small.mcap")
    assert runner.invoke(main, ["check", str(data), "--update"]).exit_code == 0
    path = data / "baselines" / "small.json"
    doc = json.loads(path.read_text())
    rec = next(r for r in doc["metrics"] if r["metric"] == "rmse_position_m" and r["tracker"] == "kalman"
               and r["scope"] == "overall")
    assert rec["se"] > 0
    rec["value"] -= 3 * rec["se"]
    path.write_text(json.dumps(doc))
    res = runner.invoke(main, ["check", str(data)])
    assert res.exit_code != 0
    line = next(l for l in res.output.splitlines() if "kalman rmse_position_m [overall]" in l)
    assert "+3.00 standard errors" in line


def test_a_tracker_without_covariance_is_reported_as_such_not_as_zero(demo_result, capsys):
    from trackreplay.evaluators.standard import evaluate_standard
    from trackreplay.face.cli_text import _print_summary

    result = demo_result.results["radar"]
    bare = {"bare": {"state": result["tracks"]["kalman"]["state"], "flags": result["tracks"]["kalman"]["flags"]}}
    stage = next(s for s in __import__("trackreplay.stages", fromlist=["STAGES"]).STAGES if s.name == "radar")
    design = demo_result.dataset.cache[("design", "radar")]
    reference = stage.reference(demo_result.dataset, design)
    _, summary = evaluate_standard(result["times"], bare, stage.standard_truth(reference), stage.standard_space(design))
    rows = {(r["metric"], r["scope"]): r["value"] for r in summary.iter_rows(named=True)}
    assert rows[("nees", "no covariance")] is None and rows[("nis", "no innovation covariance")] is None
    assert not any(m.startswith("nees_time") or m.startswith("anees") for m, _ in rows)
    _print_summary(summary.with_columns(pl.lit("standard").alias("kind")), "t")
    assert "no covariance" in capsys.readouterr().out
