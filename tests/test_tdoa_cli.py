"""TDOA/FDOA as a user runs it: simulate with presets, replay, eval, crlb, cep-plane, bad input."""

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from trackreplay import stage_running
from trackreplay.face.cli import main
from trackreplay.contract import read_dataset, write_dataset
from trackreplay.replay import replay
from trackreplay.vocabulary import CONVERGED, NOT_ESTIMATED




def invoke(runner, *args):
    res = runner.invoke(main, [str(a) for a in args])
    return res


@pytest.fixture(scope="module")
def triangle3(tmp_path_factory):
    """300 runs of the triangle geometry, emitter 3, the paper's start (second solution exists)."""
    path = tmp_path_factory.mktemp("tdoa") / "tri3.mcap"
    res = CliRunner().invoke(main, ["simulate", "tdoa-fdoa", "--geometry", "triangle", "--emitter", "3",
                                    "--runs", "300", "--seed", "4", "-o", str(path)])
    assert res.exit_code == 0, res.output
    return path


# --------------------------------------------------------------------------- simulate


def test_simulate_presets_as_options_equal_set_and_carry_metadata(runner, tmp_path, sha):
    a = invoke(runner, "simulate", "tdoa-fdoa", "--geometry", "line", "--emitter", "1", "--runs", "50", "-o", "a.mcap")
    assert a.exit_code == 0, a.output
    b = invoke(runner, "simulate", "tdoa-fdoa", "--set", "geometry=line", "--set", "emitter=1", "--runs", "50", "-o", "b.mcap")
    c = invoke(runner, "simulate", "tdoa-fdoa", "--geometry=line", "--emitter=1", "--runs", "50", "-o", "c.mcap")
    assert b.exit_code == 0 and c.exit_code == 0
    assert sha(tmp_path / "a.mcap") == sha(tmp_path / "b.mcap") == sha(tmp_path / "c.mcap")
    ds = read_dataset(tmp_path / "a.mcap")
    params = ds.scenario["params"]
    assert params["geometry"] == "line" and params["emitter"] == 1 and params["carrier_hz"] == 1e9
    assert ds.scenario["seed"] == "0"
    meas = ds.channel("/emitter/measurements")
    assert meas.grid("tdoa_s").shape == (50, 1, 3) and meas.grid("fdoa_hz").shape == (50, 1, 3)
    assert ds.channel("/emitter/sensors").grid("position_m").shape == (50, 1, 3, 2)
    np.testing.assert_array_equal(ds.channel("/emitter/truth").grid("state")[0, 0], [-5000, 15000, 200, 0])


def test_simulate_option_names_map_dashes_and_reject_junk(runner):
    ok = invoke(runner, "simulate", "tdoa-fdoa", "--emitter-position-m", "-1000,20000", "--pairs", "0-1,1-2",
                "--runs", "3", "-o", "x.mcap")
    assert ok.exit_code == 0, ok.output
    assert read_dataset("x.mcap").scenario["params"]["emitter_position_m"] == "-1000,20000"
    for args, msg in ((["--bogus", "1"], "unknown parameter 'bogus'"), (["--geometry"], "needs a value"),
                      (["stray"], "unexpected argument 'stray'"), (["--geometry", "square"], "unknown geometry"),
                      (["--pairs", "0-0"], "pairs a sensor with itself"), (["--pairs", "0-1,1-0"], "repeats a pair"),
                      (["--emitter-position-m", "0,0"], "coincides with sensor 1"),
                      (["--n-epochs", "3", "--noise-scales", "1,2"], "one per epoch")):
        res = invoke(runner, "simulate", "tdoa-fdoa", *args, "--runs", "3", "-o", "y.mcap")
        assert res.exit_code == 2 and msg in res.output and "Traceback" not in res.output, (args, res.output)


def test_simulate_option_pass_through_is_general(runner):
    res = invoke(runner, "simulate", "radar-tws", "--sigma-bearing-deg", "0.5", "--runs", "2", "-o", "r.mcap")
    assert res.exit_code == 0, res.output
    assert read_dataset("r.mcap").scenario["params"]["sigma_bearing_deg"] == 0.5


# --------------------------------------------------------------------------- replay / eval


def test_replay_classifies_runs_and_eval_matches_the_output_file(runner, triangle3, tmp_path, sha):
    before = sha(triangle3)
    res = invoke(runner, triangle3, "--out", tmp_path / "o" / "t.mcap")
    assert res.exit_code == 0, res.output
    assert sha(triangle3) == before
    assert "runs_truth" in res.output and "runs_elsewhere" in res.output and "[iteration=05]" in res.output
    layout = (tmp_path / "o" / "report.txt").read_text()  # the paper's layout of the same numbers
    assert "truth" in layout and "elsewhere" in layout and "n=5" in layout
    for name in ("t.mcap", "t.rrd", "metrics.csv", "per_scan.csv"):
        assert (tmp_path / "o" / name).stat().st_size > 0
    a = json.loads(invoke(runner, "eval", triangle3, "--json").output)
    b = json.loads(invoke(runner, "eval", triangle3, tmp_path / "o" / "t.mcap", "--json").output)
    key = lambda r: (r["tracker"], r["metric"], r["scope"])  # noqa: E731
    assert sorted(a, key=key) == sorted(b, key=key)
    get = {(r["tracker"], r["metric"], r["scope"]): r["value"] for r in a}
    # every run is in exactly one class; the second solution is not averaged in
    classes = ("truth", "elsewhere", "diverged", "not_converged", "underdetermined", "unclassified")
    for t in ("joint", "tdoa", "fdoa"):
        assert sum(get[(t, f"runs_{c}", "overall")] for c in classes) == 300
    assert get[("joint", "runs_elsewhere", "overall")] > 20
    assert get[("fdoa", "runs_underdetermined", "overall")] == 300  # 2 FDOA equations, 4 unknowns
    eff = get[("joint", "position_efficiency", "overall")]
    assert 0.85 < eff < 1.15 and 0.4 < get[("joint", "inside_50pct_position", "overall")] < 0.6


def test_joint_position_equals_tdoa_only_with_three_sensors_and_unknown_velocity(triangle3):
    """Two independent FDOAs are used up by the two velocity unknowns: the joint estimator's
    position is the TDOA-only position (a property of the 3-sensor case, not of the code)."""
    res = replay(triangle3)
    joint, tdoa = (res.results["tdoa-fdoa"]["tracks"][k] for k in ("joint", "tdoa"))
    both = ((joint["flags"] & CONVERGED) > 0) & ((tdoa["flags"] & CONVERGED) > 0)
    gap = np.linalg.norm(joint["state"][..., :2] - tdoa["state"][..., :2], axis=-1)[both]
    assert both.sum() > 250 and gap.max() < 1e-3


def test_estimators_are_trackers_and_the_bound_travels_in_the_outputs(triangle3, tmp_path):
    """The estimators run through the tracker interface; the CRLB at the truth that the
    evaluator needs is the stage's ``crlb`` extra output, written and read back exactly; a
    plugged tracker of the family is scored against the joint bound."""
    plugged = tmp_path / "plugged.py"
    plugged.write_text("from trackreplay.trackers.tdoa_fdoa import JointTdoaFdoa\n\n\n"
                       "class MyJoint(JointTdoaFdoa):\n    name = 'my_joint'\n")
    out = tmp_path / "t.mcap"
    res = replay(triangle3, out_path=out, tracker_specs=[f"{plugged}:MyJoint"])
    assert not res.failures
    tracks = res.results["tdoa-fdoa"]["tracks"]
    assert set(tracks) == {"joint", "tdoa", "fdoa", "my_joint", "crlb"}
    bound = tracks["crlb"]
    assert bound["whitened_jacobian_joint"].shape == (300, 1, 6, 4)
    assert bound["crlb_covariance_tdoa"].shape == (300, 1, 2, 2)
    back = read_dataset(out).channel("/tracks/tdoa-fdoa/crlb")
    for key, a in bound.items():
        np.testing.assert_array_equal(back.grid(key), a, err_msg=key)
    tdoa = tracks["tdoa"]
    assert np.all(np.isnan(tdoa["state"][..., 2:])) and np.all(tdoa["flags"] & NOT_ESTIMATED)
    s = res.summary.filter(res.summary["scope"] == "overall")
    get = {(r["tracker"], r["metric"]): r["value"] for r in s.to_dicts()}
    for metric in ("runs_truth", "runs_elsewhere", "rmse_position_m", "position_efficiency"):
        assert get[("my_joint", metric)] == get[("joint", metric)], metric


def test_stationary_emitter_reports_a_known_velocity_with_zero_variance(runner, tmp_path):
    assert invoke(runner, "simulate", "tdoa-fdoa-noise", "--runs", "20", "-o", "s.mcap").exit_code == 0
    res = replay(tmp_path / "s.mcap", trackers=["joint"])
    out = res.results["tdoa-fdoa"]["tracks"]["joint"]
    live = np.isfinite(out["state"]).all(axis=-1)
    assert live.any() and np.all(out["state"][live][:, 2:] == 0.0)
    P = out["covariance"][live]
    assert np.all(P[:, 2:, :] == 0.0) and np.all(P[:, :, 2:] == 0.0)
    np.linalg.cholesky(P[:, :2, :2])


def test_grid_start_needs_no_prior(runner, tmp_path):
    assert invoke(runner, "simulate", "tdoa-fdoa", "--geometry", "triangle", "--emitter", "2", "--runs", "200",
                  "--noise-scales", "0.1", "-o", "g.mcap").exit_code == 0
    res = replay(tmp_path / "g.mcap", trackers=["joint"], design_overrides={"initial_guess": "grid"})
    s = {r["metric"]: r["value"] for r in res.summary.filter(res.summary["scope"] == "overall").to_dicts()}
    assert s["runs_truth"] >= 190 and 0.8 < s["position_efficiency"] < 1.2


def test_fig7_noise_study_joint_beats_single_measurement_types(runner, tmp_path):
    assert invoke(runner, "simulate", "tdoa-fdoa-noise", "--runs", "300", "--seed", "2", "-o", "n.mcap").exit_code == 0
    res = invoke(runner, "eval", "n.mcap")
    assert res.exit_code == 0 and "[sigma_range_m=" in res.output
    a = json.loads(invoke(runner, "eval", "n.mcap", "--json").output)
    noise_scopes = sorted({r["scope"] for r in a if r["scope"].startswith("sigma_range_m=")},
                          key=lambda s: float(s.split("=")[1]))
    assert len(noise_scopes) == 7
    get = {(r["tracker"], r["metric"], r["scope"]): r["value"] for r in a}
    for s in noise_scopes[:4]:  # the small-noise levels, where every run is at the truth
        joint, tdoa, fdoa = (get[(t, "rmse_position_m", s)] for t in ("joint", "tdoa", "fdoa"))
        assert joint < tdoa and joint < fdoa, (s, joint, tdoa, fdoa)
        # and the bounds agree: joint information is the sum of the two
        assert get[("joint", "crlb_position_m", s)] < min(get[("tdoa", "crlb_position_m", s)],
                                                            get[("fdoa", "crlb_position_m", s)])


def test_collinear_emitter_is_flagged_never_scored(runner, tmp_path):
    assert invoke(runner, "simulate", "tdoa-fdoa", "--emitter-position-m", "1500,0", "--runs", "50",
                  "-o", "col.mcap").exit_code == 0
    res = replay(tmp_path / "col.mcap", trackers=["joint"])
    s = {r["metric"]: r["value"] for r in res.summary.filter(res.summary["scope"] == "overall").to_dicts()}
    assert s["crlb_singular_cells"] == 50 and s["runs_truth"] == 0
    assert s["runs_unclassified"] + s["runs_diverged"] + s["runs_not_converged"] == 50
    assert np.isnan(s["position_efficiency"])


def test_underdetermined_pairs_are_a_clear_error(runner):
    assert invoke(runner, "simulate", "tdoa-fdoa", "--pairs", "0-1", "--runs", "5", "-o", "p.mcap").exit_code == 0
    res = invoke(runner, "p.mcap", "--no-rrd")
    assert res.exit_code == 2 and "2 independent equation(s) for 4 unknowns" in res.output
    assert "Traceback" not in res.output


def test_nan_measurement_is_a_one_line_error(runner, tmp_path, triangle3):
    ds = read_dataset(triangle3)
    with write_dataset(tmp_path / "nan.mcap", ds.metadata) as w:
        for topic, ch in ds.channels.items():
            for k in range(len(ch.run)):
                arrays = {n: np.array(v[k]) for n, v in ch.arrays.items()}
                if topic == "/emitter/measurements" and k == 7:
                    arrays["fdoa_hz"][1] = np.nan
                w.write(topic, int(ch.run[k]), int(ch.scan[k]), float(ch.time_s[k]), arrays)
    res = invoke(runner, tmp_path / "nan.mcap", "--no-rrd")
    assert res.exit_code == 2 and "fdoa_hz holds 1 NaN/Inf" in res.output and "nan.mcap" in res.output


def test_missing_prior_suggests_the_grid_start(runner, tmp_path, triangle3):
    ds = read_dataset(triangle3)
    with write_dataset(tmp_path / "noprior.mcap", ds.metadata) as w:
        for topic, ch in ds.channels.items():
            if topic == "/emitter/prior":
                continue
            for k in range(len(ch.run)):
                w.write(topic, int(ch.run[k]), int(ch.scan[k]), float(ch.time_s[k]),
                        {n: v[k] for n, v in ch.arrays.items()})
    res = invoke(runner, tmp_path / "noprior.mcap", "--no-rrd")
    assert res.exit_code == 2 and "initial_guess=grid" in res.output


# --------------------------------------------------------------------------- crlb / cep-plane


def test_crlb_command_prints_and_json_is_consistent(runner):
    res = invoke(runner, "crlb", "--geometry", "line", "--emitter", "1")
    assert res.exit_code == 0, res.output
    for text in ("CRLB", "projection", "slice", "semi-major", "angle", "CEP exact", "CEP paper eq. 21", "0.75"):
        assert text in res.output
    s = json.loads(invoke(runner, "crlb", "--geometry", "line", "--emitter", "1", "--json").output)
    for block in s["blocks"].values():
        p, sl = block["projection"], block["slice"]
        assert sl["cep_exact"] <= p["cep_exact"] * (1 + 1e-12)
        assert 0.9 < p["cep_075"] / p["cep_exact"] < 1.12
        assert p["semi_major"] >= p["semi_minor"] > 0
    cov = np.array(s["crlb"])
    np.testing.assert_allclose(np.sqrt(np.diag(cov)), s["std"])


@pytest.mark.parametrize("args,msg", [
    (["--set", "emitter_position_m=12000,0"], "singular"),
    (["--set", "emitter_position_m=0,0"], "coincides with sensor 1"),
    (["--set", "pairs=0-1"], "2 independent equation(s) for 4 unknowns"),
    (["--emitter", "7"], "unknown emitter"),
])
def test_crlb_degenerate_inputs_are_one_line_errors(runner, args, msg):
    res = invoke(runner, "crlb", *args)
    assert res.exit_code == 2 and msg in res.output and "Traceback" not in res.output, res.output


def test_cep_plane_command_writes_png_and_recording(runner, tmp_path):
    res = invoke(runner, "cep-plane", "--geometry", "triangle", "--extent-km", "50", "--step-m", "500")
    assert res.exit_code == 0, res.output
    assert "201 × 201" in res.output
    assert (tmp_path / "replay-out" / "cep-plane-triangle.png").stat().st_size > 10_000
    assert (tmp_path / "replay-out" / "cep-plane-triangle.rrd").stat().st_size > 10_000
    res = invoke(runner, "cep-plane", "--geometry", "line", "--cep", "paper", "--extent-km", "10", "--step-m", "1000",
                 "-o", "line.png", "--no-rrd")
    assert res.exit_code == 0 and (tmp_path / "line.png").exists() and not (tmp_path / "line.rrd").exists()
    bad = invoke(runner, "cep-plane", "--step-m", "0")
    assert bad.exit_code == 2 and "positive" in bad.output


def test_outputs_written_before_tracks_emitter_still_read(tmp_path):
    """The emitter family wrote /emitter/estimates/<estimator> before its outputs moved under
    /tracks/tdoa-fdoa/ like every family's: such a file still reads, the same arrays."""
    from types import SimpleNamespace

    from trackreplay.replay import replay
    from trackreplay.stages import stage_for_outputs

    data = Path(__file__).resolve().parents[1] / "data" / "tdoa_fdoa_demo.mcap"
    replay(data, out_path=tmp_path / "tracks.mcap")
    out = read_dataset(tmp_path / "tracks.mcap")
    assert any(t.startswith("/tracks/tdoa-fdoa/") for t in out.channels)
    old = SimpleNamespace(path=out.path, channels={t.replace("/tracks/tdoa-fdoa/", "/emitter/estimates/"): ch
                                                   for t, ch in out.channels.items()})
    stage = stage_for_outputs(old.channels)
    assert stage is not None and stage.family == "tdoa-fdoa"
    now, before = stage_running.read_outputs(stage, out), stage_running.read_outputs(stage, old)
    assert set(now["tracks"]) == set(before["tracks"]) and now["tracks"]
    for name in now["tracks"]:
        for key in now["tracks"][name]:
            np.testing.assert_array_equal(now["tracks"][name][key], before["tracks"][name][key])
