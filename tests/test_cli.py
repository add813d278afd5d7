"""The `replay` command as a user runs it (click.testing), including bad input."""

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from trackreplay.face.cli import main




def test_no_argument_replays_bundled_demo(runner, tmp_path):
    res = runner.invoke(main, ["--no-rrd"] if False else ["run", "--no-rrd"])
    assert res.exit_code == 0, res.output
    assert "radar_tws_demo" in res.output and "rmse_position_m" in res.output
    assert (tmp_path / "replay-out" / "radar_tws_demo" / "tracks.mcap").exists()


def test_replay_writes_outputs_and_leaves_input_untouched(runner, radar_small, tmp_path, sha):
    before = sha(radar_small)
    res = runner.invoke(main, [str(radar_small), "--out", str(tmp_path / "o" / "t.mcap")])
    assert res.exit_code == 0, res.output
    assert sha(radar_small) == before
    for name in ("t.mcap", "t.rrd", "metrics.csv", "metrics.parquet", "per_scan.csv", "report.png"):
        assert (tmp_path / "o" / name).stat().st_size > 0, name
    assert not list((tmp_path / "o").glob("*.tmp"))


def test_eval_json_is_long_form_and_matches_output_file(runner, radar_small, tmp_path):
    out = tmp_path / "o" / "t.mcap"
    assert runner.invoke(main, [str(radar_small), "--out", str(out), "--no-rrd"]).exit_code == 0
    a = json.loads(runner.invoke(main, ["eval", str(radar_small), "--json"]).output)
    b = json.loads(runner.invoke(main, ["eval", str(radar_small), str(out), "--json"]).output)
    assert {"tracker", "metric", "scope", "value"} <= set(a[0])
    key = lambda r: (r["tracker"], r["metric"], r["scope"])  # noqa: E731
    # replay in memory and re-reading the written outputs give the same numbers exactly
    assert sorted(a, key=key) == sorted(b, key=key)
    trackers = {r["tracker"] for r in a}
    assert trackers == {"fixed", "approximate", "exact", "kalman"}


def test_tracker_subset_and_unknown_tracker(runner, radar_small):
    res = runner.invoke(main, [str(radar_small), "--no-rrd", "--trackers", "fixed,kalman"])
    assert res.exit_code == 0 and "approximate" not in res.output
    res = runner.invoke(main, [str(radar_small), "--no-rrd", "--trackers", "nope"])
    assert res.exit_code == 2 and "unknown tracker(s) nope" in res.output


def test_check_passes_then_fails_on_doctored_baseline(runner, tmp_path, demo_mcap):
    data = tmp_path / "data"
    (data / "baselines").mkdir(parents=True)
    shutil.copy(demo_mcap, data / demo_mcap.name)
    assert runner.invoke(main, ["check", str(data), "--update"]).exit_code == 0
    ok = runner.invoke(main, ["check", str(data)])
    assert ok.exit_code == 0, ok.output
    bpath = data / "baselines" / "radar_tws_demo.json"
    doc = json.loads(bpath.read_text())
    rec = next(r for r in doc["metrics"] if r["metric"] == "rmse_position_m" and r["tracker"] == "approximate")
    rec["value"] *= 0.97
    bpath.write_text(json.dumps(doc))
    bad = runner.invoke(main, ["check", str(data)])
    assert bad.exit_code == 1
    assert "approximate rmse_position_m [overall]" in bad.output


def test_simulate_set_and_unknown_parameter(runner, tmp_path):
    res = runner.invoke(main, ["simulate", "radar-tws", "--runs", "3", "-o", "s.mcap", "--set", "sigma_bearing_deg=0.5"])
    assert res.exit_code == 0, res.output
    from trackreplay.contract import read_dataset

    assert read_dataset(tmp_path / "s.mcap").scenario["params"]["sigma_bearing_deg"] == 0.5
    res = runner.invoke(main, ["simulate", "radar-tws", "-o", "s2.mcap", "--set", "sigma_bearng_deg=0.5"])
    assert res.exit_code == 2 and "unknown parameter 'sigma_bearng_deg'" in res.output
    assert not (tmp_path / "s2.mcap").exists()
    res = runner.invoke(main, ["simulate", "radar-tws", "-o", "s3.mcap", "--set", "sigma_range_m=-1"])
    assert res.exit_code == 2 and "sigma_range_m must be > 0" in res.output


@pytest.mark.parametrize("content, problem", [
    (b"", "empty file"),
    (b"hello", "not an MCAP file"),
])
def test_bad_files_give_one_line(runner, tmp_path, content, problem):
    p = tmp_path / "bad.mcap"
    p.write_bytes(content)
    res = runner.invoke(main, [str(p)])
    assert res.exit_code == 2
    assert res.output.strip().count("\n") == 0 and problem in res.output and str(p) in res.output
    assert "Traceback" not in res.output


def test_truncated_file_error_and_recover(runner, radar_small, tmp_path):
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(radar_small.read_bytes()[: radar_small.stat().st_size * 2 // 3])
    res = runner.invoke(main, [str(cut), "--no-rrd"])
    assert res.exit_code == 2 and "--recover" in res.output and res.output.strip().count("\n") == 0
    res = runner.invoke(main, [str(cut), "--no-rrd", "--recover"])
    assert res.exit_code == 0, res.output
    assert "recovered" in res.output and "messages from complete chunks" in res.output


def test_missing_file(runner):
    res = runner.invoke(main, ["nope.mcap"])
    assert res.exit_code == 2 and "nope.mcap: no such file" in res.output


def test_csv_converter_round_trip_and_errors(runner, tmp_path):
    rng = np.random.default_rng(0)
    t = np.arange(20) * 5.0
    x, y = -5500 + 15 * t, 9500 - 12 * t
    r = np.hypot(x, y) + rng.normal(0, 100, t.size)
    b = np.degrees(np.arctan2(y, x)) + rng.normal(0, 1, t.size)
    lines = ["time,range_m,bearing_deg"] + [f"{a},{c},{d}" for a, c, d in zip(t + 1000.0, r, b)]
    (tmp_path / "p.csv").write_text("\n".join(lines) + "\n")
    res = runner.invoke(main, ["convert", "plots-csv", "p.csv", "-o", "p.mcap", "--set", "sigma_range_m=100",
                               "--set", "sigma_bearing_deg=1"])  # a recording's noise is what its user says
    assert res.exit_code == 0, res.output
    res = runner.invoke(main, ["p.mcap", "--no-rrd"])
    assert res.exit_code == 0 and "rms_innovation_m" in res.output
    from trackreplay.contract import read_dataset

    ds = read_dataset(tmp_path / "p.mcap")
    rr, counts = ds.channel("/radar/plots").ragged("range_m")
    np.testing.assert_array_equal(rr[0, :, 0], r)

    (tmp_path / "m.csv").write_text("time,range_m\n0,1000\n")
    res = runner.invoke(main, ["convert", "plots-csv", "m.csv", "-o", "m.mcap"])
    assert res.exit_code == 2 and "missing column(s) bearing_deg" in res.output and "m.csv" in res.output
    (tmp_path / "n.csv").write_text("time,range_m,bearing_deg\n0,1000,10\n5,NaN,11\n")
    res = runner.invoke(main, ["convert", "plots-csv", "n.csv", "-o", "n.mcap"])
    assert res.exit_code == 2 and "range_m" in res.output and "NaN" in res.output
    assert not (tmp_path / "m.mcap").exists() and not (tmp_path / "n.mcap").exists()


def test_nan_in_plots_is_refused(runner, tmp_path):
    from trackreplay.contract import write_dataset

    p = tmp_path / "nan.mcap"
    with write_dataset(p) as w:
        for k in range(4):
            w.write("/radar/plots", 0, k, 5.0 * k, {"range_m": np.array([1e4 if k != 2 else np.nan]),
                                                   "bearing_rad": np.array([0.3])})
    res = runner.invoke(main, [str(p), "--no-rrd"])
    assert res.exit_code == 2 and "NaN/Inf" in res.output and str(p) in res.output


def test_every_command_has_help_with_example(runner):
    for cmd in (["run"], ["simulate"], ["eval"], ["check"], ["view"], ["sweep"], ["convert", "plots-csv"], ["scenarios"]):
        res = runner.invoke(main, [*cmd, "--help"])
        assert res.exit_code == 0 and "Example" in res.output, cmd


def test_eval_of_an_output_file_uses_the_design_the_replay_used(runner, radar_small, tmp_path):
    """`--set` overrides travel with the outputs: eval scores with them, not with the file's."""
    import polars as pl

    out = tmp_path / "o" / "t.mcap"
    res = runner.invoke(main, [str(radar_small), "--out", str(out), "--no-rrd", "--set", "nominal_cross_range_m=60"])
    assert res.exit_code == 0, res.output
    ran = pl.read_csv(tmp_path / "o" / "metrics.csv")
    evaluated = json.loads(runner.invoke(main, ["eval", str(radar_small), str(out), "--json"]).output)
    default = json.loads(runner.invoke(main, ["eval", str(radar_small), "--json"]).output)
    pick = lambda recs: {(r["tracker"], r["metric"], r["scope"]): r["value"] for r in recs}  # noqa: E731
    ran_d = {(r["tracker"], r["metric"], r["scope"]): r["value"] for r in ran.iter_rows(named=True)}
    ev, de = pick(evaluated), pick(default)
    key = ("fixed", "rmse_position_m", "overall")
    assert ev[key] == pytest.approx(ran_d[key], rel=1e-12)
    assert ev[key] != pytest.approx(de[key], rel=1e-6)  # the override changed the fixed gains
    # the above/below-nominal split follows the overridden nominal too
    assert ev[("fixed", "scans", "cross_range_above_nominal")] == ran_d[("fixed", "scans", "cross_range_above_nominal")]


def test_the_bundled_data_sets_pass_their_baselines(runner):
    """Every change to the trackers, evaluators or read/write path leaves the bundled data sets'
    metrics within their stored tolerance (a new metric must be added to the baselines
    deliberately, with `replay check --update`)."""
    data = Path(__file__).resolve().parents[1] / "data"
    res = runner.invoke(main, ["check", str(data)])
    assert res.exit_code == 0, res.output
    assert "0 drifted" in res.output


@pytest.mark.parametrize("given", [None, "1"])
def test_the_command_line_turns_numpy_huge_pages_off_before_numpy_loads_unless_told(given):
    """numpy reads NUMPY_MADVISE_HUGEPAGE once, when it is first imported: the command line's
    module must set its default without importing numpy itself, and leave a user's value alone."""
    import os
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k != "NUMPY_MADVISE_HUGEPAGE"}
    if given is not None:
        env["NUMPY_MADVISE_HUGEPAGE"] = given
    code = ("import sys, os, trackreplay.face.cli; print('numpy' in sys.modules, "
            "os.environ['NUMPY_MADVISE_HUGEPAGE'])")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout
    assert out.split() == ["False", given or "0"]


def test_the_command_line_defers_numpy_f2py_which_scipy_imports_but_never_uses():
    """scipy's import pulls in numpy.f2py through ``from numpy import *``: under the command
    line it must stay unexecuted until something uses it, then be the ordinary module."""
    import subprocess
    import sys

    code = ("import sys, trackreplay.face.cli, scipy.special, numpy\n"
            "m = sys.modules.get('numpy.f2py')\n"
            "print(m is None or type(m).__name__ == '_LazyModule', 'numpy.f2py.crackfortran' in sys.modules)\n"
            "print(callable(numpy.f2py.run_main), type(sys.modules['numpy.f2py']).__name__, "
            "'numpy.f2py.crackfortran' in sys.modules)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["True", "False", "True", "module", "True"]
