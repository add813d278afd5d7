"""The verdict line per tracker: the consistency verdict follows the interval test, and the CLI
prints it before the tables."""

from __future__ import annotations

import math

import polars as pl
import pytest

from trackreplay.evaluators.verdicts import consistency_verdict, tracker_verdicts


@pytest.mark.parametrize("value, low, high, verdict", [
    (4.0, 3.5, 4.5, "consistent"), (3.5, 3.5, 4.5, "consistent"), (4.6, 3.5, 4.5, "optimistic"),
    (3.4, 3.5, 4.5, "pessimistic"), (None, 3.5, 4.5, "untestable"), (4.0, math.nan, 4.5, "untestable"),
    (45.0, 3.5, 4.5, "optimistic"), (45.1, 3.5, 4.5, "implausible"),
])
def test_consistency_verdict_is_the_interval_test(value, low, high, verdict):
    assert consistency_verdict(value, low, high) == verdict


def _rows(tracker, **values):
    return [{"tracker": tracker, "metric": m, "scope": "overall", "value": v, "ci_low": None, "ci_high": None}
            for m, v in values.items()]


def test_nees_decides_before_nis_and_a_tracker_without_either_is_untestable():
    summary = pl.DataFrame(
        _rows("a", nees_time_average=9.0, nees_time_average_low=3.5, nees_time_average_high=4.5,
              nis_time_average=2.0, nis_time_average_low=1.8, nis_time_average_high=2.2, mota=0.9)
        + _rows("b", nis_time_average=1.5, nis_time_average_low=1.8, nis_time_average_high=2.2, mota=0.8)
        + _rows("c", mota=0.7) + _rows("side_output", alpha=0.9))
    table = {r["tracker"]: r for r in tracker_verdicts(summary).iter_rows(named=True)}
    assert (table["a"]["verdict"], table["a"]["tested_by"]) == ("optimistic", "NEES")
    assert (table["b"]["verdict"], table["b"]["tested_by"]) == ("pessimistic", "NIS")
    assert table["c"]["verdict"] == "untestable" and [m["metric"] for m in table["c"]["measures"]] == ["mota"]
    assert "side_output" not in table


def test_replay_prints_the_verdicts_first(runner, demo_mcap):
    from trackreplay.face.cli import main

    res = runner.invoke(main, [str(demo_mcap), "--no-rrd", "--figures", "none", "--out", "o/t.mcap"])
    assert res.exit_code == 0, res.output
    lines = res.output.splitlines()
    first = next(i for i, line in enumerate(lines) if line.startswith("verdict per tracker"))
    assert "(NEES)" in res.output  # with truth, the NEES decides
    table = next(i for i, line in enumerate(lines) if line.startswith("["))
    assert first < table
    for tracker in ("fixed", "approximate", "exact", "kalman"):
        line = next(line for line in lines[first:table] if line.strip().startswith(tracker))
        assert any(v in line for v in ("consistent", "optimistic", "pessimistic")) and "rmse_position_m" in line


def test_a_tracker_following_clutter_is_called_implausible_in_plain_words(runner, tmp_path):
    """A recording of many targets among clutter, without truth, replayed by the papers'
    single-target trackers without a gate: their tracks jump between plots, and the verdict says
    so instead of printing a healthy track summary (issue 28)."""
    from trackreplay.face.cli import main
    from trackreplay.recorders.radar_multi import simulate
    from trackreplay.recorders.scenarios import load_scenario
    from trackreplay.recorders.simulated import write_simulated
    from trackreplay.contract import scenario_metadata

    params = dict(load_scenario("radar-multi").params, n_scans=40)
    data = simulate(params, 2, 5)
    data.fixed.pop("/radar/truth", None)
    data.ragged.pop("/radar/truth", None)
    write_simulated(tmp_path / "rec.mcap", data, scenario_metadata("radar-multi", params, 5))
    res = runner.invoke(main, [str(tmp_path / "rec.mcap"), "--no-rrd", "--figures", "none", "--out", "o/t.mcap"])
    assert res.exit_code == 0, res.output
    lines = res.output.splitlines()
    kalman = next(i for i, line in enumerate(lines) if line.strip().startswith("kalman"))
    assert "implausible (NIS)" in lines[kalman]
    assert "follows clutter or another object" in " ".join(" ".join(lines[kalman + 1:kalman + 4]).split())


def test_the_bundled_demo_has_no_implausible_tracker(demo_mcap):
    from trackreplay.replay import replay

    table = tracker_verdicts(replay(demo_mcap).summary)
    assert "implausible" not in table["verdict"].to_list() and set(table["note"].to_list()) == {""}
