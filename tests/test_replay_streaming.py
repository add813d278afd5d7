"""A replay takes its trackers one at a time (filter, write while scoring, score, release):
the tables and outputs must be those of scoring every tracker at once, and the result keeps
only the runs its views read when asked to."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import polars as pl
import pytest
from polars.testing import assert_frame_equal

from trackreplay import design_values, stage_running, stage_scoring
from trackreplay.contract import read_dataset
from trackreplay.replay import replay, select_trackers
from trackreplay.stages import applicable_stages

DATA_DIR = Path(__file__).resolve().parents[1] / "data"
BUNDLED = sorted(p.name for p in DATA_DIR.glob("*.mcap"))


def _all_at_once(path):
    """The tables of the path before streaming: every tracker run, then all scored together."""
    ds = read_dataset(path)
    stages = applicable_stages(ds.channels)
    chosen = select_trackers(stages, dataset=ds)  # the trackers replay() picks for this scene
    per_scan, summary, results = [], [], {}
    for stage in stages:
        design = design_values.resolve(stage, ds, None, chosen[stage.name])
        ds.cache[("design", stage.name)] = design
        result = stage_running.run(stage, ds, chosen[stage.name], design)
        result.pop("errors")
        p, s = stage_scoring.measure(stage, ds, result, design)
        per_scan.append(p.with_columns(pl.lit(stage.name).alias("stage")))
        summary.append(s.with_columns(pl.lit(stage.name).alias("stage")))
        results[stage.name] = result
    return pl.concat(per_scan, how="diagonal"), pl.concat(summary, how="diagonal"), results


def _sorted(df):
    key = [c for c in ("stage", "tracker", "kind", "metric", "scope", "scan") if c in df.columns]
    return df.sort(key).select(sorted(df.columns))


@pytest.mark.parametrize("name", BUNDLED)
def test_one_tracker_at_a_time_scores_and_writes_what_all_at_once_does(name, tmp_path, monkeypatch):
    per_scan, summary, results = _all_at_once(DATA_DIR / name)
    monkeypatch.setattr(stage_running, "SCORING_UNIT_BYTES", 0)  # every tracker a unit of its own, as on many runs
    res = replay(DATA_DIR / name, out_path=tmp_path / "tracks.mcap")
    # the same rows and values, to the bit (only their order may differ)
    assert_frame_equal(_sorted(res.per_scan), _sorted(per_scan), check_exact=True)
    assert_frame_equal(_sorted(res.summary), _sorted(summary), check_exact=True)
    # the file holds every tracker's and extra's outputs, exactly
    out = read_dataset(tmp_path / "tracks.mcap")
    for stage_name, result in results.items():
        stage = next(s for s in applicable_stages(read_dataset(DATA_DIR / name).channels) if s.name == stage_name)
        written = stage_running.read_outputs(stage, out)["tracks"]
        assert list(written) == list(result["tracks"])  # trackers in the order they ran, extras last
        for tracker, outputs in result["tracks"].items():
            for key, value in outputs.items():
                np.testing.assert_array_equal(np.asarray(written[tracker][key], float), np.asarray(value, float),
                                              err_msg=f"{tracker} {key}")


def test_small_outputs_are_scored_in_one_unit_and_large_ones_apart(monkeypatch):
    from trackreplay.stages import stage_named

    stage = stage_named("radar")
    ds = read_dataset(DATA_DIR / "radar_tws_demo.mcap")
    entries = select_trackers([stage])[stage.name]
    design = design_values.resolve(stage, ds, None, entries)
    _, units = stage_running.run_units(stage, ds, entries, design)
    assert [own for own, _, _ in units] == [[e.name for e in entries]]
    monkeypatch.setattr(stage_running, "SCORING_UNIT_BYTES", 1)
    _, units = stage_running.run_units(stage, ds, entries, design)
    assert [own for own, _, _ in units] == [[e.name] for e in entries]


def test_kept_runs_are_the_first_runs_of_the_full_outputs():
    path = DATA_DIR / "radar_tws_demo.mcap"
    full = replay(path)
    kept = replay(path, keep_runs=2)
    assert_frame_equal(kept.summary, full.summary)
    for tracker, outputs in full.results["radar"]["tracks"].items():
        for key, value in outputs.items():
            short = kept.results["radar"]["tracks"][tracker][key]
            assert short.shape == (2,) + value.shape[1:]
            np.testing.assert_array_equal(short, value[:2])


def test_a_stage_whose_views_read_every_run_keeps_them_all():
    path = DATA_DIR / "tdoa_fdoa_demo.mcap"
    full = replay(path)
    kept = replay(path, keep_runs=1)
    for tracker, outputs in full.results["tdoa-fdoa"]["tracks"].items():
        for key, value in outputs.items():
            np.testing.assert_array_equal(kept.results["tdoa-fdoa"]["tracks"][tracker][key], value)


@pytest.mark.parametrize("on_thread", [False, True])
def test_a_failing_write_leaves_no_output_and_raises(tmp_path, monkeypatch, on_thread):
    if on_thread:  # every unit large enough to be written on the writer thread
        monkeypatch.setattr(stage_running, "SCORING_UNIT_BYTES", 0)

    def broken(stage, writer, result):
        raise OSError("disk full")

    monkeypatch.setattr(stage_running, "write_outputs", broken)
    with pytest.raises(OSError, match="disk full"):
        replay(DATA_DIR / "radar_tws_demo.mcap", out_path=tmp_path / "tracks.mcap")
    assert list(tmp_path.iterdir()) == []
