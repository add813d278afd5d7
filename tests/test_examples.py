"""The plugged-tracker examples in ``examples/`` run through the real pipeline and say true things.

* ``filterpy_kf.py`` (FilterPy ``KalmanFilter``, per-run form) is the built-in ``kalman``
  reference re-done: its states and covariances equal the built-in's to 1e-9 relative on the
  bundled demo, and also where plots are missed (coasting) and where a scan holds several plots
  (nearest-plot choice), which the demo never exercises;
* ``polar_ekf.py`` (EKF in range and bearing, batch form) passes the common checks every
  tracker passes (``tests/test_common_trackers.py``), is as accurate as ``kalman`` on the demo,
  and is consistent (NEES inside its χ² bounds) where its motion model is the truth's — while an
  over-confident design of the same filter is caught by the same test;
* ``stonesoup_tracker.py`` (Stone Soup adapter, per-run form) runs from the command line on a
  small simulated data set and returns outputs in the vocabulary with finite errors.

FilterPy and Stone Soup come with the ``peers`` extra (installed in CI); they are imported, not
skipped.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import test_common_trackers as common
from trackreplay import design_values, stage_running
from trackreplay.evaluators.consistency import consistency_summary, normalised_squared
from trackreplay import vocabulary as vocab
from trackreplay.contract import read_dataset
from trackreplay.face.cli import main
from trackreplay.registry import available_trackers
from trackreplay.replay import replay
from trackreplay.stages.radar import RadarStage
from trackreplay.trackers.interface import RadarPlots, call_tracker, validate_outputs

REPO = Path(__file__).resolve().parents[1]
DEMO = REPO / "data" / "radar_tws_demo.mcap"
FILTERPY = str(REPO / "examples" / "filterpy_kf.py") + ":FilterPyKF"
POLAR = str(REPO / "examples" / "polar_ekf.py") + ":PolarEKF"
STONESOUP = str(REPO / "examples" / "stonesoup_tracker.py") + ":StoneSoupTracker"
PREFIX = vocab.FAMILIES["radar"].output_prefix
ALL_FLAG_BITS = np.dtype(vocab.FLAG_DTYPE).type(sum(vocab.FLAGS.values()))


def invoke(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def run_trackers(path, names, specs, overrides=None, measurements=None):
    """Outputs of the named trackers on ``path`` through the stage and ``call_tracker`` (the
    path a replay takes), with the design values the replay would use."""
    table = available_trackers(specs)
    stage = RadarStage()
    ds = read_dataset(path)
    entries = [table[n] for n in names]
    design = design_values.resolve(stage, ds, overrides, entries)
    meas = measurements if measurements is not None else stage.decode(ds, design)
    return {e.name: call_tracker(stage_running.build(e, design), meas) for e in entries}, meas, design


def simulated(tmp_path_factory, name, runs, seed, **overrides) -> Path:
    from trackreplay.recorders.scenarios import load_scenario
    from trackreplay.recorders.simulated import record

    path = tmp_path_factory.mktemp("examples") / f"{name}.mcap"
    record(path, load_scenario("radar-tws").with_overrides(overrides), runs=runs, seed=seed)
    return path


def relative_error(a, b, axes):
    """max |a − b| / max |a| per vector or matrix (``axes`` its own axes); NaN patterns must match."""
    assert np.array_equal(np.isnan(a), np.isnan(b)), "the two trackers have estimates at different scans"
    live = np.isfinite(a).all(axis=axes)
    diff = np.abs(a - b)[live].max(axis=tuple(range(1, 1 + len(axes))))
    scale = np.abs(a)[live].max(axis=tuple(range(1, 1 + len(axes))))
    return diff / scale


# --------------------------------------------------------------------------- FilterPy = built-in kalman


def assert_filterpy_equals_kalman(out):
    k, f = out["kalman"], out["filterpy_kf"]
    assert np.isfinite(k["state"]).any()
    assert relative_error(k["state"], f["state"], (-1,)).max() <= 1e-9
    assert relative_error(k["covariance"], f["covariance"], (-2, -1)).max() <= 1e-9
    np.testing.assert_array_equal(f["flags"], k["flags"])
    np.testing.assert_array_equal(f["measurement"], k["measurement"])  # the same plot chosen every scan
    for key in ("innovation", "innovation_covariance", "gain"):
        a, b = k[key], f[key]
        axes = (-1,) if a.ndim == 3 else (-2, -1)
        assert relative_error(a, b, axes).max() <= 1e-9, key


def test_filterpy_kf_equals_builtin_kalman_on_the_demo():
    out, meas, _ = run_trackers(DEMO, ["kalman", "filterpy_kf"], [FILTERPY])
    assert_filterpy_equals_kalman(out)
    # every run has a filtered track for most of the flight (not an all-NaN agreement)
    assert np.isfinite(out["filterpy_kf"]["state"][:, 2:]).all()


def test_filterpy_kf_equals_kalman_with_missed_plots(tmp_path_factory):
    # detection probability 0.7 and a wandering target: tracks start late and coast
    path = simulated(tmp_path_factory, "missed", runs=20, seed=3, detection_probability=0.7,
                     truth_process_noise_mps2=0.5)
    # the example is a filter without track management: compare with the built-in's switched off
    # (M-of-N confirmation and deletion after coasting; docs/trackers.md, track life)
    out, _, _ = run_trackers(path, ["kalman", "filterpy_kf"], [FILTERPY],
                             overrides={"confirm_hits": 0, "max_coasted_scans": 0})
    flags = out["kalman"]["flags"]
    assert np.any(flags & vocab.COASTED) and np.any(flags & vocab.INITIALISING)
    assert_filterpy_equals_kalman(out)
    # with it on (the default), the same filter: tracks that coast five scans in a row end
    managed, _, _ = run_trackers(path, ["kalman"], [])
    assert np.any(managed["kalman"]["flags"] & vocab.DELETED)


def test_filterpy_kf_equals_kalman_with_several_plots_per_scan():
    # a second, false plot 2 km away in every other scan: both must take the nearest one
    stage = RadarStage()
    rng, brg, counts, times = stage.decode_plots(read_dataset(DEMO))
    R = 30
    r2 = np.full((R, len(times), 2), np.nan)
    b2 = np.full((R, len(times), 2), np.nan)
    c2 = counts[:R].copy()
    r2[..., 0], b2[..., 0] = rng[:R, :, 0], brg[:R, :, 0]
    odd = np.arange(len(times)) % 2 == 1
    r2[:, odd, 1], b2[:, odd, 1] = rng[:R, odd, 0] + 2000.0, brg[:R, odd, 0]
    c2[:, odd] = 2
    # the false plot first in half of the runs, so "nearest" is not "first"
    swap = np.zeros_like(c2, bool)
    swap[::2, odd] = True
    r2[swap] = r2[swap][:, ::-1]
    b2[swap] = b2[swap][:, ::-1]
    plots = RadarPlots(range_m=r2, bearing_rad=b2, counts=c2, times_s=times, truth_state=None)
    out, _, _ = run_trackers(DEMO, ["kalman", "filterpy_kf"], [FILTERPY], measurements=plots)
    assert_filterpy_equals_kalman(out)


# --------------------------------------------------------------------------- polar EKF


@pytest.fixture(scope="module")
def polar_replay(tmp_path_factory):
    out = tmp_path_factory.mktemp("polar_ekf") / "tracks.mcap"
    res = replay(DEMO, out_path=out, tracker_specs=[POLAR])
    return res, out


def test_polar_ekf_passes_the_common_tracker_checks(polar_replay, monkeypatch, tmp_path_factory):
    res, out = polar_replay
    assert not res.failures
    entry = available_trackers([POLAR])["polar_ekf"]
    stage = next(s for s in common.STAGES if s.family == entry.family)
    # the common checks replay the family's demo themselves; hand them this replay instead
    monkeypatch.setattr(common, "_replayed", lambda e, factory: (res, stage, out))
    common.test_output_vocabulary(entry, tmp_path_factory)
    common.test_covariance_symmetric_positive_definite(entry, tmp_path_factory)
    common.test_write_read_round_trip_is_exact(entry, tmp_path_factory)
    assert PREFIX + "polar_ekf" in read_dataset(out).channels


def position_rmse(state, truth):
    err = state[:, 2:, :2] - truth[:, 2:, :2]  # after the two-point start
    return float(np.sqrt(np.nanmean(np.sum(err**2, axis=-1))))


def nees(out, truth):
    return consistency_summary(normalised_squared(out["state"] - truth, out["covariance"])[:, 2:], 4)


def test_polar_ekf_is_as_accurate_as_kalman_on_the_demo():
    out, meas, _ = run_trackers(DEMO, ["kalman", "polar_ekf"], [POLAR])
    truth = meas.truth_state[:, :, 0]  # the demo's one target (truth is a set of one)
    ratio = position_rmse(out["polar_ekf"]["state"], truth) / position_rmse(out["kalman"]["state"], truth)
    # at 10 km with σ_θ = 1° the polar and the converted-plot update see the same information
    assert abs(ratio - 1) <= 0.05, ratio
    # the same covariance story too: both are designed with σ_v = 0.98 m/s² for a target that flies
    # straight, so both are pessimistic by the same amount
    a, b = nees(out["polar_ekf"], truth)["time_average"], nees(out["kalman"], truth)["time_average"]
    assert abs(a / b - 1) <= 0.05, (a, b)


def test_polar_ekf_is_consistent_when_its_model_is_the_truth(tmp_path_factory):
    # truth driven by the white acceleration the filter assumes (σ_v = design σ_v)
    path = simulated(tmp_path_factory, "matched", runs=100, seed=11, truth_process_noise_mps2=0.98)
    out, meas, _ = run_trackers(path, ["polar_ekf"], [POLAR])
    s = nees(out["polar_ekf"], meas.truth_state[:, :, 0])
    # ANEES per scan inside its 95 % χ² interval at (nearly) 95 % of the scans, and on average n = 4
    assert s["inside_fraction"] >= 0.85, s["inside_fraction"]
    assert abs(s["time_average"] / 4 - 1) <= 0.1, s["time_average"]
    # the same test catches the same filter designed over-confident (σ_θ assumed 4× too small)
    out, _, _ = run_trackers(path, ["polar_ekf"], [POLAR], overrides={"sigma_bearing_deg": 0.25})
    bad = nees(out["polar_ekf"], meas.truth_state[:, :, 0])
    assert bad["inside_fraction"] < 0.5 and bad["time_average"] > 4.4, (bad["inside_fraction"], bad["time_average"])


# --------------------------------------------------------------------------- Stone Soup adapter


def test_stonesoup_adapter_runs_on_a_small_simulated_data_set(tmp_path):
    data = tmp_path / "small.mcap"
    res = invoke("simulate", "radar-tws", "--runs", 12, "--seed", 21, "-o", data)
    assert res.exit_code == 0, res.output
    out = tmp_path / "o" / "tracks.mcap"
    res = invoke(data, "--tracker", STONESOUP, "--no-rrd", "--out", out)
    assert res.exit_code == 0, res.output
    assert "stonesoup" in res.stdout

    written = read_dataset(out)
    assert PREFIX + "stonesoup" in written.channels
    tracks = stage_running.read_outputs(RadarStage(), written)["tracks"]
    o = validate_outputs(tracks["stonesoup"], 12, 64, "stonesoup")
    state, flags = o["state"], o["flags"]
    assert state.shape == (12, 64, 4) and o["covariance"].shape == (12, 64, 4, 4)
    assert not np.any(flags & ~ALL_FLAG_BITS)
    live = np.isfinite(state).all(axis=-1)
    assert live[:, 2:].all(), "a detected straight-flying target keeps its track after the start"
    np.testing.assert_array_equal(~live, (flags & vocab.NO_TRACK) > 0)
    np.linalg.cholesky(o["covariance"][live])

    truth = read_dataset(data).channel(vocab.CHANNELS["radar_truth"]).grid("state")
    err = state - truth
    assert np.isfinite(err[live]).all()
    rmse_ss = position_rmse(state, truth)
    rmse_kf = position_rmse(tracks["kalman"]["state"], truth)
    # Stone Soup's continuous white-noise Q (q = σ_v²) is several times smaller than the built-ins'
    # piecewise-constant one, the better model for this straight-flying target: a lower error, of
    # the same order
    assert 0.7 * rmse_kf < rmse_ss < rmse_kf, (rmse_ss, rmse_kf)

    res = invoke("eval", data, out, "--json")
    assert res.exit_code == 0, res.output
    records = [r for r in json.loads(res.stdout) if r["tracker"] == "stonesoup"]
    rmse = next(r["value"] for r in records if r["metric"] == "rmse_position_m" and r["scope"] == "overall")
    assert np.isfinite(rmse) and rmse > 0


# --------------------------------------------------------------------------- the command lines in the docstrings


@pytest.mark.parametrize("rel, name", [("examples/polar_ekf.py:PolarEKF", "polar_ekf"),
                                       ("examples/filterpy_kf.py:FilterPyKF", "filterpy_kf")])
def test_examples_run_from_the_repository_root(rel, name, tmp_path, monkeypatch):
    monkeypatch.chdir(REPO)
    out = tmp_path / "tracks.mcap"
    res = invoke("data/radar_tws_demo.mcap", "--tracker", rel, "--no-rrd", "--out", out)
    assert res.exit_code == 0, res.output
    assert name in res.stdout
    assert PREFIX + name in read_dataset(out).channels
    res = invoke("eval", "data/radar_tws_demo.mcap", "--tracker", rel, "--json")
    assert res.exit_code == 0, res.output
    assert name in {r["tracker"] for r in json.loads(res.stdout)}
    res = invoke("trackers", "--tracker", rel, "--json")
    assert res.exit_code == 0, res.output
    row = next(r for r in json.loads(res.stdout) if r["name"] == name)
    params = {p["name"]: p for p in row["params"]}
    # design values left None come from the radar-tws scenario, as the built-ins' do
    assert params["sigma_bearing_deg"]["unit"] == "deg" and params["sigma_bearing_deg"]["default"] == 1.0
    assert params["design_sigma_v_mps2"]["from"] == "scenario radar-tws"
