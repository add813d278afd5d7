"""Trackers plugged in from outside the package: ``--tracker FILE.py:CLASS``, entry points, ``--set``.

Each test writes its small trackers into a file under the test's temporary folder and drives
the real command line (click's runner on ``trackreplay.face.cli:main``) or the Python API:

* a plugged tracker shows in the printed metrics, in ``tracks.mcap`` on the family's output
  channel, in ``replay eval`` (of the output file and in memory), in ``replay trackers`` with its
  family, form, parameters and units, in ``replay check`` and in a process-pool sweep;
* ``--set`` (and a sweep's ``--param``) reach its design parameters;
* a tracker that raises or returns outputs outside the vocabulary gives one ``replay: error:``
  line naming it and exit 2, after the built-ins' outputs are written;
* a bad spec gives one clear line and no traceback;
* a tracker installed by another distribution (entry point ``trackreplay.trackers``) is found by
  its name.
"""

from __future__ import annotations

import json
import shutil
import sys
import textwrap
from pathlib import Path

import numpy as np
import polars as pl
import pytest

from trackreplay import stage_running, vocabulary as vocab
from trackreplay.contract import read_dataset
from trackreplay.errors import InputError
from trackreplay.face.cli import main
from trackreplay.registry import ENTRY_POINT_GROUP, available_trackers
from trackreplay.replay import replay
from trackreplay.trackers.interface import TrackerError, call_tracker, validate_outputs

PREFIX = vocab.FAMILIES["radar"].output_prefix  # /tracks/radar/
STAGE = "radar"
REPO_DATA = Path(__file__).resolve().parents[1] / "data"

TRACKERS = '''
import numpy as np
from trackreplay import vocabulary as vocab
from trackreplay.trackers.interface import Param, Tracker


def echo(r, b, counts, offset):
    """The first plot of each scan as the position, zero velocity; NO_TRACK where none."""
    have = counts > 0
    x, y = r * np.cos(b) + offset, r * np.sin(b)
    state = np.stack([x, y, np.zeros_like(x), np.zeros_like(x)], axis=-1)
    state[~have] = np.nan
    return state, np.where(have, 0, vocab.NO_TRACK).astype(np.uint16)


class PlotEcho(Tracker):
    name = "plot_echo"
    family = "radar"
    params = (Param("offset_m", 0.0, "m", "added to the x of every estimate"),
              Param("sigma_range_m", None, "m", "plot range noise (from the scenario)"))

    def track(self, plots):
        state, flags = echo(plots.range_m[..., 0], plots.bearing_rad[..., 0], plots.counts, self.offset_m)
        cov = np.zeros(state.shape + (4,))
        cov[...] = np.diag([self.sigma_range_m ** 2] * 2 + [1e4, 1e4])
        cov[np.isnan(state).any(axis=-1)] = np.nan
        return {"state": state, "flags": flags, "covariance": cov}


class PlotEchoRun(Tracker):
    name = "plot_echo_run"
    family = "radar"
    form = "run"
    params = (Param("offset_m", 0.0, "m", "added to the x of every estimate"),)

    def track_run(self, plots):
        state, flags = echo(plots.range_m[:, 0], plots.bearing_rad[:, 0], plots.counts, self.offset_m)
        return {"state": state, "flags": flags}


class Boom(Tracker):
    name = "boom"
    family = "radar"
    form = "run"

    def track_run(self, plots):
        if plots.counts.sum() > 0:
            raise RuntimeError("kaput")


class BadShape(Tracker):
    name = "bad_shape"
    family = "radar"

    def track(self, plots):
        return {"state": np.zeros((3, 4)), "flags": np.zeros(3, np.uint16)}


class ShortState(Tracker):
    name = "short_state"
    family = "radar"

    def track(self, plots):  # [x, y, vx] where the family's state is [x, y, vx, vy]
        R, K = plots.counts.shape
        return {"state": np.zeros((R, K, 3)), "covariance": np.tile(np.eye(3), (R, K, 1, 1)),
                "flags": np.zeros((R, K), np.uint16)}


class NanState(Tracker):
    name = "nan_state"
    family = "radar"

    def track(self, plots):
        shape = plots.counts.shape
        return {"state": np.full(shape + (4,), np.nan), "flags": np.zeros(shape, np.uint16)}


class NotATracker:
    name = "not_a_tracker"


class Sonar(Tracker):
    name = "sonar"
    family = "sonar-pings"

    def track(self, plots):
        pass
'''


@pytest.fixture
def plugged(tmp_path) -> Path:
    """``plugged.py`` with the trackers above, in the runner's working directory."""
    path = tmp_path / "plugged.py"
    path.write_text(TRACKERS)
    return path


def assert_one_error_line(res, *fragments):
    """Exit 2, exactly one ``replay: error:`` line, the last on stderr, with every fragment."""
    assert res.exit_code == 2, res.output
    errors = [line for line in res.stderr.splitlines() if line.startswith("replay: error: ")]
    assert len(errors) == 1 and res.stderr.strip().splitlines()[-1] == errors[0], res.stderr
    for fragment in fragments:
        assert fragment in errors[0], errors[0]
    assert "Traceback" not in res.output
    return errors[0]


def outputs(path: Path) -> dict:
    """Tracker name → its output arrays, read back from a ``tracks.mcap``."""
    from trackreplay.stages.radar import RadarStage

    return stage_running.read_outputs(RadarStage(), read_dataset(path))["tracks"]


def eval_records(res) -> list[dict]:
    assert res.exit_code == 0, res.output
    return json.loads(res.stdout)


def overall(records, tracker, metric):
    return next(r["value"] for r in records
                if r["tracker"] == tracker and r["metric"] == metric and r["scope"] == "overall")


# --------------------------------------------------------------------------- where a plugged tracker shows


def test_plugged_tracker_in_table_tracks_and_eval(runner, radar_small, plugged):
    res = runner.invoke(main, [str(radar_small), "--tracker", "plugged.py:PlotEcho", "--no-rrd", "--out", "o/t.mcap"])
    assert res.exit_code == 0, res.output
    assert "plot_echo" in res.stdout  # the printed metrics
    channels = read_dataset(Path("o/t.mcap")).channels
    assert PREFIX + "plot_echo" in channels and PREFIX + "kalman" in channels
    out = outputs(Path("o/t.mcap"))["plot_echo"]
    assert out["state"].shape == (30, 64, 4) and out["covariance"].shape == (30, 64, 4, 4)

    from_file = eval_records(runner.invoke(main, ["eval", str(radar_small), "o/t.mcap", "--json"]))
    in_memory = eval_records(runner.invoke(main, ["eval", str(radar_small), "--tracker", "plugged.py:PlotEcho",
                                                  "--json"]))
    assert {"plot_echo", "kalman"} <= {r["tracker"] for r in from_file}
    for metric in ("rmse_position_m", "npe_mean"):
        a, b = overall(from_file, "plot_echo", metric), overall(in_memory, "plot_echo", metric)
        assert np.isfinite(a) and a == pytest.approx(b, rel=1e-12), metric
    # a tracker that echoes plots has the plots' error, far above the filters'
    assert overall(from_file, "plot_echo", "rmse_position_m") > 1.3 * overall(from_file, "kalman", "rmse_position_m")


def test_eval_of_an_output_file_refuses_tracker(runner, radar_small, plugged):
    runner.invoke(main, [str(radar_small), "--no-rrd", "--out", "o/t.mcap"])
    res = runner.invoke(main, ["eval", str(radar_small), "o/t.mcap", "--tracker", "plugged.py:PlotEcho"])
    assert_one_error_line(res, "--tracker")


def test_replay_trackers_lists_a_plugged_tracker(runner, plugged):
    res = runner.invoke(main, ["trackers", "--tracker", "plugged.py:PlotEcho", "--tracker", "plugged.py:PlotEchoRun"])
    assert res.exit_code == 0, res.output
    rows = {line.split()[0]: line.split() for line in res.stdout.splitlines() if line.strip()}
    assert rows["plot_echo"][1:5] == ["radar", "batch", "always", "plugged.py:PlotEcho"]
    assert rows["plot_echo_run"][1:3] == ["radar", "run"]
    section = res.stdout.split("design parameters of plot_echo:")[1].split("\n\n")[0]
    assert "offset_m" in section and "added to the x of every estimate" in section
    assert rows["offset_m"][1:4] == ["0", "m", "tracker"]

    listing = json.loads(runner.invoke(main, ["trackers", "--tracker", "plugged.py:PlotEcho", "--json"]).stdout)
    row = next(r for r in listing if r["name"] == "plot_echo")
    assert (row["family"], row["form"], row["stage"]) == ("radar", "batch", STAGE)
    params = {p["name"]: p for p in row["params"]}
    assert params["offset_m"] == {"name": "offset_m", "default": 0.0, "unit": "m", "from": "tracker",
                                  "doc": "added to the x of every estimate"}
    # a default left None is the family's bundled scenario value, and says so
    assert params["sigma_range_m"]["default"] == 100.0 and params["sigma_range_m"]["from"] == "scenario radar-tws"


# --------------------------------------------------------------------------- --set


def test_set_reaches_a_plugged_trackers_param(runner, radar_small, plugged):
    args = [str(radar_small), "--tracker", "plugged.py:PlotEcho", "--no-rrd"]
    assert runner.invoke(main, [*args, "--out", "a/t.mcap"]).exit_code == 0
    res = runner.invoke(main, [*args, "--out", "b/t.mcap", "--set", "offset_m=250", "--set", "sigma_range_m=50"])
    assert res.exit_code == 0, res.output
    a, b = outputs(Path("a/t.mcap")), outputs(Path("b/t.mcap"))
    live = np.isfinite(a["plot_echo"]["state"][..., 0])
    np.testing.assert_allclose(b["plot_echo"]["state"][..., 0][live] - a["plot_echo"]["state"][..., 0][live], 250.0,
                               rtol=0, atol=1e-6)
    np.testing.assert_array_equal(b["plot_echo"]["state"][..., 1], a["plot_echo"]["state"][..., 1])
    assert b["plot_echo"]["covariance"][live][:, 0, 0] == pytest.approx(50.0**2)
    assert a["plot_echo"]["covariance"][live][:, 0, 0] == pytest.approx(100.0**2)
    # sigma_range_m is a built-in design value too: the built-ins take the same --set
    assert not np.array_equal(a["kalman"]["state"], b["kalman"]["state"])


def test_set_errors_name_the_parameter(runner, radar_small, plugged):
    args = [str(radar_small), "--tracker", "plugged.py:PlotEcho", "--no-rrd", "--out", "o/t.mcap"]
    assert_one_error_line(runner.invoke(main, [*args, "--set", "offset_m=abc"]), "offset_m", "abc")
    assert_one_error_line(runner.invoke(main, [*args, "--set", "offset_mm=1"]), "offset_mm", "offset_m")


def test_set_through_the_python_api(radar_small, plugged):
    spec = f"{plugged}:PlotEcho"
    base = replay(radar_small, tracker_specs=[spec]).results[STAGE]["tracks"]["plot_echo"]["state"]
    moved = replay(radar_small, tracker_specs=[spec], design_overrides={"offset_m": -75.5})
    state = moved.results[STAGE]["tracks"]["plot_echo"]["state"]
    live = np.isfinite(base[..., 0])
    np.testing.assert_allclose(state[..., 0][live] - base[..., 0][live], -75.5, rtol=0, atol=1e-6)


def test_run_form_equals_batch_form(radar_small, plugged):
    from trackreplay.stages.radar import RadarStage

    table = available_trackers([f"{plugged}:PlotEcho", f"{plugged}:PlotEchoRun"])
    meas = RadarStage().decode(read_dataset(radar_small), {})
    batch = call_tracker(table["plot_echo"].cls(offset_m=3.0, sigma_range_m=100.0), meas)
    per_run = call_tracker(table["plot_echo_run"].cls(offset_m=3.0), meas)
    np.testing.assert_array_equal(per_run["state"], batch["state"])
    np.testing.assert_array_equal(per_run["flags"], batch["flags"])


# --------------------------------------------------------------------------- a tracker that fails


@pytest.mark.parametrize("cls, name, fragment", [
    ("Boom", "boom", "run 0: raised RuntimeError: kaput"),
    ("BadShape", "bad_shape", "output 'state' has shape (3, 4), expected (30 runs, 64 scans, ...)"),
    ("NanState", "nan_state", "NaN state without the NO_TRACK or NOT_ESTIMATED flag"),
    ("ShortState", "short_state", "state has 3 components, the family's state has 4"),
], ids=["raises", "bad-shape", "nan-state", "short-state"])
def test_failing_tracker_gives_one_line_and_the_others_are_written(runner, radar_small, plugged, cls, name, fragment):
    res = runner.invoke(main, [str(radar_small), "--tracker", f"plugged.py:{cls}", "--no-rrd", "--out", "o/t.mcap"])
    assert_one_error_line(res, f"tracker {name!r}", f"plugged.py:{cls}", fragment)
    channels = read_dataset(Path("o/t.mcap")).channels
    assert {PREFIX + t for t in ("fixed", "approximate", "exact", "kalman")} <= set(channels)
    assert PREFIX + name not in channels
    metrics = pl.read_csv("o/metrics.csv")
    assert "kalman" in metrics["tracker"].to_list() and name not in metrics["tracker"].to_list()
    assert "kalman" in res.stdout  # the built-ins' metrics were printed before the error


def test_two_failing_trackers_give_one_line_each(runner, radar_small, plugged):
    res = runner.invoke(main, [str(radar_small), "--tracker", "plugged.py:Boom", "--tracker", "plugged.py:BadShape",
                               "--tracker", "plugged.py:PlotEcho", "--no-rrd", "--out", "o/t.mcap"])
    assert res.exit_code == 2
    errors = [line for line in res.stderr.splitlines() if line.startswith("replay: error: ")]
    assert len(errors) == 2 and any("'boom'" in e for e in errors) and any("'bad_shape'" in e for e in errors)
    assert PREFIX + "plot_echo" in read_dataset(Path("o/t.mcap")).channels


def test_failing_tracker_in_eval(runner, radar_small, plugged):
    res = runner.invoke(main, ["eval", str(radar_small), "--tracker", "plugged.py:Boom", "--json"])
    assert_one_error_line(res, "'boom'", "kaput")
    assert {r["tracker"] for r in json.loads(res.stdout)} == {"fixed", "approximate", "exact", "kalman"}


def test_failing_tracker_through_the_python_api(radar_small, plugged):
    res = replay(radar_small, tracker_specs=[f"{plugged}:Boom"])
    assert set(res.results[STAGE]["tracks"]) >= {"fixed", "kalman"} and "boom" not in res.results[STAGE]["tracks"]
    (failure,) = res.failures
    assert isinstance(failure, TrackerError) and "tracker 'boom': run 0" in str(failure)


def test_failing_constructor_gives_one_line(runner, radar_small, plugged):
    plugged.write_text(TRACKERS + textwrap.dedent('''
        class Strict(PlotEcho):
            name = "strict"

            def __init__(self, **design):
                super().__init__(**design)
                if self.offset_m < 0:
                    raise ValueError("offset_m must be >= 0")
    '''))
    res = runner.invoke(main, [str(radar_small), "--tracker", "plugged.py:Strict", "--set", "offset_m=-1", "--no-rrd",
                               "--out", "o/t.mcap"])
    assert_one_error_line(res, "'strict'", "constructing it raised ValueError: offset_m must be >= 0")
    # like a tracker that fails while tracking, the built-ins' outputs are still written
    channels = read_dataset(Path("o/t.mcap")).channels
    assert {PREFIX + t for t in ("fixed", "approximate", "exact", "kalman")} <= set(channels)
    assert PREFIX + "strict" not in channels


# --------------------------------------------------------------------------- bad specs


@pytest.mark.parametrize("spec, fragments", [
    ("missing.py:PlotEcho", ["missing.py", "no such file"]),
    ("plugged.py:Nope", ["plugged.py", "no class 'Nope'", "PlotEcho"]),
    ("plugged.py:NotATracker", ["plugged.py:NotATracker", "is not a Tracker subclass"]),
    ("plugged.py:echo", ["plugged.py:echo", "is not a Tracker subclass"]),
    ("plugged.py:Sonar", ["'sonar'", "family 'sonar-pings'", "radar"]),
    ("broken.py:PlotEcho", ["broken.py", "importing it raised ZeroDivisionError"]),
    ("no_such_module_xyz:PlotEcho", ["no_such_module_xyz", "cannot import"]),
    ("plugged.py", ["'plugged.py'", "no installed tracker has that name"]),
], ids=["missing-file", "missing-class", "not-a-tracker", "a-function", "unknown-family", "import-error",
        "missing-module", "no-class-given"])
@pytest.mark.parametrize("command", ["run", "eval", "trackers"])
def test_bad_spec_gives_one_clear_line(runner, radar_small, plugged, spec, fragments, command):
    Path("broken.py").write_text("x = 1 / 0\n")
    args = {"run": [str(radar_small), "--no-rrd", "--out", "o/t.mcap"], "eval": ["eval", str(radar_small)],
            "trackers": ["trackers"]}[command]
    res = runner.invoke(main, [*args, "--tracker", spec])
    assert_one_error_line(res, *fragments)
    assert not Path("o").exists()  # refused before any work


def test_two_trackers_with_one_name_are_refused(runner, radar_small, plugged):
    shutil.copy(plugged, "copy.py")
    res = runner.invoke(main, [str(radar_small), "--tracker", "plugged.py:PlotEcho", "--tracker", "copy.py:PlotEcho"])
    assert_one_error_line(res, "two trackers are named 'plot_echo'")
    with pytest.raises(InputError, match="two trackers are named 'kalman'"):
        Path("kalman.py").write_text(TRACKERS.replace('name = "plot_echo"', 'name = "kalman"'))
        available_trackers(["kalman.py:PlotEcho"])


def test_plugged_tracker_of_a_family_the_file_lacks(runner, plugged, tmp_path):
    data = REPO_DATA / "xcorr_crossing_demo.mcap"
    res = runner.invoke(main, [str(data), "--tracker", "plugged.py:PlotEcho", "--no-rrd", "--out", "o/t.mcap"])
    assert_one_error_line(res, "'plot_echo'", "radar")


# --------------------------------------------------------------------------- check and sweep


def test_check_with_a_plugged_tracker(runner, radar_small, plugged):
    Path("d/baselines").mkdir(parents=True)
    shutil.copy(radar_small, "d/radar_small.mcap")
    res = runner.invoke(main, ["check", "d", "--update", "--tracker", "plugged.py:PlotEcho"])
    assert res.exit_code == 0, res.output
    baseline = json.loads(Path("d/baselines/radar_small.json").read_text())
    assert baseline["plugged"] == {"plot_echo": "plugged.py:PlotEcho"}
    assert "plot_echo" in {m["tracker"] for m in baseline["metrics"]}

    res = runner.invoke(main, ["check", "d", "--tracker", "plugged.py:PlotEcho"])
    assert res.exit_code == 0, res.output
    res = runner.invoke(main, ["check", "d"])  # without it: its entries are named, not failed
    assert res.exit_code == 0 and "plot_echo" in res.stdout and "--tracker plugged.py:PlotEcho" in res.stdout

    # the same name, other numbers: the check fails on the plugged tracker's metrics
    Path("moved.py").write_text(TRACKERS.replace('Param("offset_m", 0.0', 'Param("offset_m", 500.0'))
    res = runner.invoke(main, ["check", "d", "--tracker", "moved.py:PlotEcho"])
    assert res.exit_code == 1 and "plot_echo rmse_position_m" in res.stdout, res.output

    res = runner.invoke(main, ["check", "d", "--tracker", "plugged.py:Boom"])
    assert_one_error_line(res, "'boom'", "kaput", "data set radar_small")


def test_sweep_with_process_executor_includes_the_plugged_tracker(runner, plugged):
    res = runner.invoke(main, ["sweep", "radar-tws", "--param", "offset_m=0,100", "--runs", "5", "--seed", "3",
                               "-o", "sw", "--executor", "process", "--workers", "2", "--no-keep-data",
                               "--tracker", "plugged.py:PlotEcho"])
    assert res.exit_code == 0, res.output
    table = pl.read_parquet("sw/sweep.parquet").filter(pl.col("metric") == "rmse_position_m")
    rmse = {(row["tracker"], row["offset_m"]): row["value"] for row in table.iter_rows(named=True)}
    assert {t for t, _ in rmse} == {"fixed", "approximate", "exact", "kalman", "plot_echo"}
    # the swept design value reaches the plugged tracker in the worker processes; the points
    # share their data (a tracker parameter does not change the seed), so the built-ins agree
    assert rmse[("plot_echo", 100.0)] > rmse[("plot_echo", 0.0)]
    assert rmse[("kalman", 100.0)] == rmse[("kalman", 0.0)]


# --------------------------------------------------------------------------- entry points


@pytest.fixture
def installed(tmp_path, monkeypatch):
    """A distribution ``trackreplay-extra`` on sys.path whose entry point registers PlotEcho
    (module ``extra_trackers_<id>``) as an installed ``pip install`` would."""
    site = tmp_path / "site"
    module = f"extra_trackers_{abs(hash(str(tmp_path))) % 10**8}"
    dist = site / "trackreplay_extra-1.0.dist-info"
    dist.mkdir(parents=True)
    (site / f"{module}.py").write_text(TRACKERS.replace('name = "plot_echo"', 'name = "extra_echo"'))
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: trackreplay-extra\nVersion: 1.0\n")
    (dist / "entry_points.txt").write_text(f"[{ENTRY_POINT_GROUP}]\nextra_echo = {module}:PlotEcho\n")
    monkeypatch.syspath_prepend(str(site))
    yield module
    sys.modules.pop(module, None)


def test_entry_point_tracker_is_found_by_name(runner, radar_small, installed):
    entry = available_trackers()["extra_echo"]
    assert entry.source == "entry point trackreplay-extra" and entry.spec == f"{installed}:PlotEcho"

    res = runner.invoke(main, ["trackers"])
    assert res.exit_code == 0, res.output
    row = next(line.split() for line in res.stdout.splitlines() if line.startswith("extra_echo"))
    assert row[1:3] == ["radar", "batch"] and "trackreplay-extra" in row

    # not run by default (installed is not chosen), but by name: --tracker NAME or --trackers
    res = runner.invoke(main, [str(radar_small), "--no-rrd", "--out", "a/t.mcap"])
    assert res.exit_code == 0 and PREFIX + "extra_echo" not in read_dataset(Path("a/t.mcap")).channels
    res = runner.invoke(main, [str(radar_small), "--tracker", "extra_echo", "--set", "offset_m=10", "--no-rrd",
                               "--out", "b/t.mcap"])
    assert res.exit_code == 0, res.output
    assert "extra_echo" in res.stdout and PREFIX + "extra_echo" in read_dataset(Path("b/t.mcap")).channels
    res = runner.invoke(main, [str(radar_small), "--trackers", "kalman,extra_echo", "--no-rrd", "--out", "c/t.mcap"])
    assert res.exit_code == 0, res.output
    assert set(read_dataset(Path("c/t.mcap")).channels) == {PREFIX + "kalman", PREFIX + "extra_echo"}
    records = eval_records(runner.invoke(main, ["eval", str(radar_small), "--tracker", "extra_echo", "--json"]))
    assert np.isfinite(overall(records, "extra_echo", "rmse_position_m"))


# --------------------------------------------------------------------------- the guide's example


def test_the_worked_example_in_the_guide_runs(runner, radar_small, plugged):
    guide = (REPO_DATA.parent / "docs" / "trackers.md").read_text()
    code = next(b for b in guide.split("```python\n")[1:] if b.startswith('"""my_trackers.py')).split("```")[0]
    Path("my_trackers.py").write_text(code)
    res = runner.invoke(main, [str(radar_small), "--tracker", "my_trackers.py:ConstantVelocity", "--tracker",
                               "plugged.py:PlotEcho", "--set", "plot_sigma_m=120", "--no-rrd", "--out", "o/t.mcap"])
    assert res.exit_code == 0, res.output
    assert PREFIX + "cv_alpha_beta" in read_dataset(Path("o/t.mcap")).channels
    records = eval_records(runner.invoke(main, ["eval", str(radar_small), "o/t.mcap", "--json"]))
    # a filter: well below the error of the plots it filters
    assert overall(records, "cv_alpha_beta", "rmse_position_m") < 0.85 * overall(records, "plot_echo", "rmse_position_m")


# --------------------------------------------------------------------------- one tracker, every way it runs


def test_both_forms_give_identical_metrics_through_replay_eval_and_every_sweep_executor(runner, plugged):
    """PlotEcho (batch form) and PlotEchoRun (per-run form) compute the same thing; each must
    give the same metrics through replay, eval of its outputs, and a sweep on the serial,
    process and Dask executors."""
    res = runner.invoke(main, ["simulate", "radar-tws", "--runs", "6", "--seed", "4", "-o", "d.mcap"])
    assert res.exit_code == 0, res.output
    specs = ["--tracker", "plugged.py:PlotEcho", "--tracker", "plugged.py:PlotEchoRun"]
    keep = pl.col("tracker").is_in(["plot_echo", "plot_echo_run"])

    def values(table):
        if "scope" not in table.columns:  # a sweep table holds the overall scope
            table = table.with_columns(scope=pl.lit("overall"))
        t = table.filter(keep & (pl.col("scope") == "overall")).select("tracker", "metric", "scope", "value")
        t = t.drop_nulls("value")
        return {(r["metric"], r["scope"], r["tracker"].replace("_run", "")): r["value"] for r in t.iter_rows(named=True)}

    replayed = replay(Path("d.mcap"), out_path=Path("o/tracks.mcap"), tracker_specs=[f"{plugged}:PlotEcho",
                                                                                    f"{plugged}:PlotEchoRun"]).summary
    by_form = {form: {k: v for k, v in values(replayed.filter(pl.col("tracker") == name)).items()}
               for form, name in (("batch", "plot_echo"), ("run", "plot_echo_run"))}
    # the per-run form returns no covariance: the metrics both have must agree exactly
    common = by_form["batch"].keys() & by_form["run"].keys()
    assert len(common) > 20 and {k: by_form["batch"][k] for k in common} == {k: by_form["run"][k] for k in common}
    evaluated = runner.invoke(main, ["eval", "d.mcap", "o/tracks.mcap", "--json"])
    assert evaluated.exit_code == 0, evaluated.output
    assert values(pl.DataFrame(json.loads(evaluated.stdout), infer_schema_length=None)) == values(replayed)
    sweeps = {}
    for executor in ("serial", "process", "dask"):
        res = runner.invoke(main, ["sweep", "radar-tws", "--param", "sigma_range_m=100", "--runs", "6", "--seed", "4",
                                   "-o", f"sw_{executor}", "--executor", executor, "--workers", "2", "--no-keep-data",
                                   *specs])
        assert res.exit_code == 0, res.output
        sweeps[executor] = values(pl.read_parquet(f"sw_{executor}/sweep.parquet"))
    assert sweeps["serial"] and sweeps["serial"] == sweeps["process"] == sweeps["dask"]
    rmse = {k: v for k, v in sweeps["serial"].items() if k[0] == "rmse_position_m"}
    assert rmse


def test_param_bounds_are_checked_by_the_base_class():
    from trackreplay.trackers.interface import Param, Tracker

    class Bounded(Tracker):
        name, family = "bounded", "radar"
        params = (Param("gain", 0.5, "", "a gain in (0, 1)", low=0.0, high=1.0),)

    assert Bounded(gain=0.25).gain == 0.25
    for bad in (0.0, 1.0, float("nan"), None):
        with pytest.raises(ValueError, match="gain"):
            Bounded(gain=bad)


def _random_outputs(seed, runs, scans, n):
    """Positive definite covariances, finite states and no flags, (runs, scans, ...)."""
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(runs, scans, n, n))
    return (A @ np.swapaxes(A, -1, -2) + 0.1 * np.eye(n), rng.normal(size=(runs, scans, n)),
            np.zeros((runs, scans), np.uint16))


def _spoil(cov, state, flags, run, scan, problem):
    """Make one matrix ``problem``: not finite, asymmetric, indefinite, semidefinite (inside the
    check's tolerance) or a dead slot (NaN with a NaN state flagged NO_TRACK)."""
    if problem == "nan":
        cov[run, scan, 1, 2] = np.nan
    elif problem == "asymmetric":
        cov[run, scan, 0, 3] += 1e-3 * cov[run, scan, 0, 0]
    elif problem in ("indefinite", "semidefinite"):
        w, V = np.linalg.eigh(cov[run, scan])
        w[0] = -1e-3 * w[-1] if problem == "indefinite" else 0.0
        cov[run, scan] = (V * w) @ V.T
    elif problem == "dead_slot":
        cov[run, scan], state[run, scan], flags[run, scan] = np.nan, np.nan, vocab.NO_TRACK


@pytest.mark.parametrize("block", [5, 32768])
@pytest.mark.parametrize("problem, expected", [
    ("nan", "covariance not finite where the state is"),
    ("asymmetric", "covariance not symmetric"),
    ("indefinite", "covariance not positive definite"),
    ("semidefinite", None),   # a zero eigenvalue is inside the check's tolerance
    ("dead_slot", None),      # a NaN covariance where the state is NaN and flagged NO_TRACK
])
def test_the_covariance_check_names_the_first_bad_matrix(monkeypatch, block, problem, expected):
    """The output check accepts what an eigenvalue test accepts and names the run and scan of
    the first bad matrix, whatever the block it falls in."""
    import trackreplay.trackers.interface as interface

    monkeypatch.setattr(interface, "COVARIANCE_CHECK_BLOCK", block)
    runs, scans, n = 4, 3, 4
    cov, state, flags = _random_outputs(8, runs, scans, n)
    bad_run, bad_scan = 2, 1
    _spoil(cov, state, flags, bad_run, bad_scan, problem)
    out = {"state": state, "flags": flags, "covariance": cov}
    if expected is None:
        validate_outputs(out, runs, scans, "t")
        live = np.isfinite(state).all(axis=-1)
        assert np.linalg.eigvalsh(cov[live]).min() >= -1e-9 * np.abs(np.diagonal(cov[live], axis1=-2, axis2=-1)).max()
        return
    with pytest.raises(TrackerError, match=f"run {bad_run} scan {bad_scan}: {expected}"):
        validate_outputs(out, runs, scans, "t")


def runs_innermost(a):
    """The same values laid out as most trackers write them: a scan's runs side by side."""
    return np.ascontiguousarray(np.moveaxis(a, 0, -1)).transpose((a.ndim - 1,) + tuple(range(a.ndim - 1)))


@pytest.mark.parametrize("layout", [np.ascontiguousarray, runs_innermost])
@pytest.mark.parametrize("block", [6, 32768])
@pytest.mark.parametrize("problem, expected", [
    ("nan", "covariance not finite where the state is"),
    ("asymmetric", "covariance not symmetric"),
    ("indefinite", "covariance not positive definite"),
])
@pytest.mark.parametrize("dead_first_scan", [False, True])
def test_the_covariance_check_names_the_first_of_several_bad_matrices(monkeypatch, layout, block, problem, expected,
                                                                    dead_first_scan):
    """Two bad matrices, the later one in (run, scan) order lying on an earlier scan: the
    message names the first in (run, scan) order, whatever order the check reads a block in
    (scan by scan when the runs are innermost) and whether it gathers the live matrices."""
    import trackreplay.trackers.interface as interface

    monkeypatch.setattr(interface, "COVARIANCE_CHECK_BLOCK", block)
    runs, scans, n = 5, 4, 4
    cov, state, flags = _random_outputs(10, runs, scans, n)
    if dead_first_scan:  # no estimate on scan 0: the check gathers the live matrices
        cov[:, 0], state[:, 0], flags[:, 0] = np.nan, np.nan, vocab.NO_TRACK
    for run, scan in [(1, 3), (2, 1)]:
        _spoil(cov, state, flags, run, scan, problem)
    out = {"state": state, "flags": flags, "covariance": layout(cov)}
    with pytest.raises(TrackerError, match=f"run 1 scan 3: {expected}"):
        validate_outputs(out, runs, scans, "t")


@pytest.mark.parametrize("layout", [np.ascontiguousarray, runs_innermost])
@pytest.mark.parametrize("runs, scans, live_matrices", [(1, 1, 1), (5, 1, 5), (4, 3, 1), (4, 3, 12)])
def test_the_covariance_check_never_changes_the_outputs(runs, scans, live_matrices, layout):
    """The check factorises c + δI on a copy, even when a block holds one matrix (whose
    stack-last layout would otherwise be a view of the tracker's own array)."""
    rng = np.random.default_rng(9)
    A = rng.normal(size=(runs, scans, 4, 4))
    cov = layout(A @ np.swapaxes(A, -1, -2) + 0.1 * np.eye(4))
    state = rng.normal(size=(runs, scans, 4))
    flags = np.zeros((runs, scans), np.uint16)
    dead = np.arange(runs * scans) >= live_matrices
    state.reshape(-1, 4)[dead] = np.nan
    flags.reshape(-1)[dead] = vocab.NO_TRACK
    before = cov.copy()
    validate_outputs({"state": state, "flags": flags, "covariance": cov}, runs, scans, "t")
    np.testing.assert_array_equal(cov, before)


NEIGHBOUR_USER = '''
import sys

from offsets import OFFSET_M
from trackreplay.trackers.interface import Tracker


class Shifted(Tracker):
    """The first plot of every scan, shifted by a constant from the module beside this file."""
    name, family = "shifted", "radar"

    def track(self, plots):
        import numpy as np

        R, K = plots.counts.shape
        state = np.zeros((R, K, 4))
        state[..., 0] = plots.range_m[..., 0] * np.cos(plots.bearing_rad[..., 0]) + OFFSET_M
        state[..., 1] = plots.range_m[..., 0] * np.sin(plots.bearing_rad[..., 0])
        return {"state": state, "flags": np.zeros((R, K), np.uint32)}
'''


def test_a_plugged_tracker_file_imports_the_module_beside_it(runner, radar_small, tmp_path):
    """Its folder is on the path while it loads (issue 28), and only then."""
    import sys

    folder = tmp_path / "mine"
    folder.mkdir()
    (folder / "offsets.py").write_text("OFFSET_M = 25.0\n")
    (folder / "shifted.py").write_text(NEIGHBOUR_USER)
    before = list(sys.path)
    res = runner.invoke(main, [str(radar_small), "--tracker", f"{folder / 'shifted.py'}:Shifted", "--no-rrd", "--out",
                               "o/t.mcap", "--figures", "none"])
    assert res.exit_code == 0, res.output
    assert "shifted" in outputs(Path("o/t.mcap"))
    assert sys.path == before
