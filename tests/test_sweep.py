"""Sweeps: same table on every executor, resume, failure isolation, early input errors."""

import os
import signal
import subprocess
import sys
import time

import polars as pl
import pytest
from click.testing import CliRunner

from trackreplay import sweep as sw
from trackreplay.face.cli import main

SPECS = {"sigma_bearing_deg": ["0.5", "1", "2"], "nominal_cross_range_m": ["120", "150"]}


def grid(out_dir=None, keep=False, runs=8):
    return sw.build_grid("radar-tws", SPECS, runs, 7, None, out_dir, keep)


def table(executor, out_dir=None, **kw):
    rep = sw.run_sweep(grid(out_dir), list(SPECS), out_dir, executor, workers=2, **kw)
    assert not rep.failed, rep.failed
    return rep.table.sort(["point_index", "tracker", "metric"])


def test_identical_tables_on_serial_process_and_dask():
    serial = table("serial")
    assert serial.height == 6 * 4 * serial["metric"].n_unique()
    assert serial.equals(table("process"))
    assert serial.equals(table("dask"))


def test_point_seed_depends_on_point_not_order():
    a = sw.point_seed(7, (("x", 1.0), ("y", 2)))
    assert a == sw.point_seed(7, (("y", 2), ("x", 1.0)))
    assert a != sw.point_seed(8, (("x", 1.0), ("y", 2)))
    assert a != sw.point_seed(7, (("x", 1.5), ("y", 2)))


def test_resume_recomputes_only_missing_points(tmp_path):
    full = table("serial", tmp_path)
    victim = tmp_path / "points" / "sigma_bearing_deg=1,nominal_cross_range_m=150" / "metrics.parquet"
    victim.unlink()
    rep = sw.run_sweep(grid(tmp_path), list(SPECS), tmp_path, "serial", resume=True)
    assert (rep.done, rep.skipped) == (1, 5)
    assert rep.table.sort(["point_index", "tracker", "metric"]).equals(full)


def test_resume_after_a_killed_sweep(tmp_path):
    out = tmp_path / "study"
    # enough points that the kill, issued once two are finished, always lands before the last
    values = "0.5,0.6,0.7,0.8,0.9,1,1.2,1.5,2,2.5,3,4"
    points = len(values.split(","))
    cmd = [sys.executable, "-m", "trackreplay.face.cli", "sweep", "radar-tws", "--param", f"sigma_bearing_deg={values}",
           "--runs", "150", "--executor", "serial", "--no-keep-data", "-o", str(out)]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.monotonic() + 120
    # a point is finished once its record is written, after its metrics (point.json last): a
    # kill between the two leaves metrics that the resume computes again
    while time.monotonic() < deadline and len(list(out.glob("points/*/point.json"))) < 2:
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    finished = len(list(out.glob("points/*/point.json")))
    assert 2 <= finished < points, finished
    for f in out.glob("points/*/metrics.parquet"):  # every result that appeared is whole
        pl.read_parquet(f)
    # a SIGKILL can land inside an atomic write and leave its temporary (no handler runs): the
    # resume sweeps those up, and none of them was ever read as a result
    res = CliRunner().invoke(main, cmd[3:] + ["--resume"])
    assert res.exit_code == 0, res.output
    assert not list(out.rglob("*.tmp"))
    assert f"{points - finished} done, {finished} resumed, 0 failed" in res.output
    assert pl.read_parquet(out / "sweep.parquet")["point"].n_unique() == points


def test_failing_point_is_reported_and_others_complete(tmp_path, monkeypatch):
    from trackreplay.sweep import point

    real = point._run_point

    def flaky(task):
        if task.label.startswith("sigma_bearing_deg=2"):
            raise RuntimeError("sensor model exploded")
        return real(task)

    monkeypatch.setattr(point, "_run_point", flaky)  # run_point calls it
    rep = sw.run_sweep(grid(tmp_path), list(SPECS), tmp_path, "serial")
    assert set(rep.failed) == {"sigma_bearing_deg=2,nominal_cross_range_m=120", "sigma_bearing_deg=2,nominal_cross_range_m=150"}
    assert all("sensor model exploded" in e for e in rep.failed.values())
    assert rep.done == 4 and rep.table["point"].n_unique() == 4


@pytest.mark.parametrize("args, message", [
    (["--param", "sigma_bearng_deg=1,2"], "unknown parameter 'sigma_bearng_deg'"),
    (["--param", "sigma_bearing_deg="], "empty value list"),
    (["--param", "sigma_bearing_deg=1,-2"], "grid point sigma_bearing_deg=-2: sigma_bearing_deg must be in (0, 23)"),
    (["--param", "n_scans=10,abc"], "cannot read 'abc' as int"),
])
def test_bad_sweep_input_fails_before_any_work(tmp_path, args, message):
    out = tmp_path / "s"
    res = CliRunner().invoke(main, ["sweep", "radar-tws", *args, "--runs", "2", "-o", str(out)])
    assert res.exit_code == 2, res.output
    assert message in res.output
    assert not out.exists()


def test_cli_sweep_writes_table_csv_and_plots(tmp_path):
    out = tmp_path / "s"
    res = CliRunner().invoke(main, ["sweep", "radar-tws", "--param", "sigma_bearing_deg=0.5,1", "--runs", "5",
                                    "--executor", "serial", "-o", str(out)])
    assert res.exit_code == 0, res.output
    t = pl.read_parquet(out / "sweep.parquet")
    assert {"point", "sigma_bearing_deg", "tracker", "metric", "value"} <= set(t.columns)
    assert pl.read_csv(out / "sweep.csv").height == t.height
    assert (out / "plots" / "rmse_position_m.png").stat().st_size > 0
    assert (out / "points" / "sigma_bearing_deg=0.5" / "tracks.rrd").exists()
    # bearing noise up → position error up, for every tracker
    rm = t.filter(pl.col("metric") == "rmse_position_m").pivot(on="sigma_bearing_deg", index="tracker", values="value")
    assert (rm["1.0"] > rm["0.5"]).all()
