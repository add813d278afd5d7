"""Coloured-noise scenarios through the command line: simulate, replay, eval, report, bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from trackreplay.face.cli import main
from trackreplay.contract import read_dataset, scenario_metadata
from trackreplay.recorders.colored_noise import simulate
from trackreplay.recorders.scenarios import load_scenario
from trackreplay.recorders.simulated import write_simulated

SHORT = ["--set", "n_samples=240", "--set", "manoeuvre_first_sample=80", "--set", "manoeuvre_last_sample=160"]


def invoke(*args):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


@pytest.fixture(scope="module")
def short_imm(tmp_path_factory):
    path = tmp_path_factory.mktemp("cli") / "imm.mcap"
    res = invoke("simulate", "colored-imm", "--runs", 3, "--seed", 4, "-o", path, *SHORT)
    assert res.exit_code == 0, res.output
    return path


def test_simulate_is_reproducible_and_records_the_scenario(short_imm, tmp_path):
    again = tmp_path / "again.mcap"
    assert invoke("simulate", "colored-imm", "--runs", 3, "--seed", 4, "-o", again, *SHORT).exit_code == 0
    assert again.read_bytes() == short_imm.read_bytes()
    ds = read_dataset(short_imm)
    sc = ds.scenario
    assert sc["scenario"] == "colored-imm" and sc["seed"] == "4"
    assert sc["params"]["measurement_variance_m2"] == 100.0 and sc["params"]["n_samples"] == 240
    z = ds.channel("/colored/measurements").grid("position_m")
    truth = ds.channel("/colored/truth")
    assert z.shape == (3, 240, 1)
    alpha = truth.grid("alpha")[0, :, 0]
    assert alpha[79] == 0.8187 and alpha[80] == 0.6067 and alpha[161] == 0.8187
    state = truth.grid("state")
    np.testing.assert_allclose(state[0, 0], [1000.0, 150.0, 0.0])
    np.testing.assert_allclose(z - state[..., :1], truth.grid("noise_m"), atol=1e-9)


def test_circle_is_two_dimensional(tmp_path):
    path = tmp_path / "circle.mcap"
    res = invoke("simulate", "colored-circle", "--runs", 2, "-o", path, "--set", "n_samples=50")
    assert res.exit_code == 0, res.output
    ds = read_dataset(path)
    state = ds.channel("/colored/truth").grid("state")
    assert ds.channel("/colored/measurements").grid("position_m").shape == (2, 50, 2)
    np.testing.assert_allclose(np.hypot(state[..., 0], state[..., 3]), 1000.0)
    np.testing.assert_allclose(np.hypot(state[..., 2], state[..., 5]), 100.0**2 / 1000.0)


def test_replay_eval_and_report(short_imm, tmp_path):
    out = tmp_path / "o" / "tracks.mcap"
    res = invoke(short_imm, "--out", out)
    assert res.exit_code == 0, res.output
    for text in ("[overall]", "rmse_position_m", "mimm_k", "pimm", "prob_cv", "[manoeuvre]"):
        assert text in res.output
    layout = (out.parent / "report.txt").read_text()  # the thesis's layouts of the same numbers
    assert "mean model probability" in layout and "AR(1) estimator" in layout
    assert out.exists() and out.with_suffix(".rrd").stat().st_size > 0
    res = invoke("eval", short_imm, out, "--json")
    assert res.exit_code == 0, res.output
    records = json.loads(res.output)
    names = {(r["tracker"], r["metric"], r["scope"]) for r in records}
    for t in ("kf", "kf_dp", "imm", "mimm_k", "pimm"):
        assert (t, "rmse_acceleration_mps2", "overall") in names
    assert ("imm", "prob_cv", "manoeuvre") in names
    figs = tmp_path / "figs"
    res = invoke("colored-report", short_imm, out, "-o", figs)
    assert res.exit_code == 0, res.output
    for name in ("rmse.png", "model_probabilities.png", "ar_alpha.png", "ar_noise_variance.png", "report.txt"):
        assert (figs / name).stat().st_size > 0
    assert (figs / "rmse.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize("sets,message", [
    (["measurement_variance_m2=0"], "positive definite"),
    (["alpha_cv=1.0"], "stationary"),
    (["trajectory=spiral"], "trajectory"),
])
def test_bad_scenario_parameters_exit_2(tmp_path, sets, message):
    args = ["simulate", "colored-imm", "--runs", 1, "-o", tmp_path / "x.mcap"]
    for s in sets:
        args += ["--set", s]
    res = CliRunner().invoke(main, [str(a) for a in args])
    assert res.exit_code == 2
    assert message in res.output and "Traceback" not in res.output
    assert not (tmp_path / "x.mcap").exists()


@pytest.mark.parametrize("sets,message", [
    (["imm_transition=0.9 0.2 0; 0.33 0.34 0.33; 0 0.01 0.99"], "row 1 sums to 1.1"),
    (["imm_transition=0.5 0.5; 0.5 0.5"], "3×3"),
    (["ar_forgetting_factor=1.0"], "beta"),
    (["measurement_variance_m2=-1"], "measurement_variance_m2 = -1 must be in (0, inf)"),
])
def test_bad_design_values_exit_2(short_imm, tmp_path, sets, message):
    args = [short_imm, "--no-rrd", "--out", tmp_path / "t.mcap"]
    for s in sets:
        args += ["--set", s]
    res = CliRunner().invoke(main, [str(a) for a in args])
    assert res.exit_code == 2, res.output
    assert message in res.output and "Traceback" not in res.output


def test_nan_measurement_file_exits_2(tmp_path):
    sc = load_scenario("colored-imm").with_overrides({"n_samples": "30"})
    data = simulate(sc.params, 2, 0)
    data.fixed["/colored/measurements"]["position_m"][1, 7, 0] = np.nan
    path = tmp_path / "nan.mcap"
    write_simulated(path, data, scenario_metadata(sc.name, sc.params, 0))
    before = path.read_bytes()
    res = CliRunner().invoke(main, [str(path), "--no-rrd", "--out", str(tmp_path / "t.mcap")])
    assert res.exit_code == 2
    assert "NaN" in res.output and str(path) in res.output and "Traceback" not in res.output
    assert path.read_bytes() == before


def test_a_recording_without_truth_starts_from_the_measurements(short_imm, tmp_path):
    from trackreplay.contract import write_dataset

    ds = read_dataset(short_imm)
    z = ds.channel("/colored/measurements").grid("position_m")
    times = ds.channel("/colored/measurements").times()
    recording = tmp_path / "recording.mcap"
    with write_dataset(recording) as w:  # the measurements alone, as a converted recording holds them
        w.write_grid("/colored/measurements", times, {"position_m": z})
    # the file says nothing about its sensor: the noise variance is the user's to give
    variance = ds.scenario["params"]["measurement_variance_m2"]
    res = invoke(recording, "--no-rrd", "--set", f"measurement_variance_m2={variance}",
                 "--out", tmp_path / "o" / "tracks.mcap")
    assert res.exit_code == 0, res.output
    assert "nis_time_average" in res.output and "rmse" not in res.output  # no truth: innovations only
    out = read_dataset(tmp_path / "o" / "tracks.mcap").channel("/tracks/colored/imm").grid("state")
    assert np.allclose(out[:, 0, 0], z[:, 0, 0] if z.ndim == 3 else z[:, 0])  # position from z₀
    refused = CliRunner().invoke(main, [str(recording), "--no-rrd", "--set", "track_start=truth",
                                        "--set", f"measurement_variance_m2={variance}",
                                        "--out", str(tmp_path / "p" / "tracks.mcap")])
    assert refused.exit_code == 2 and "track_start" in refused.stderr
