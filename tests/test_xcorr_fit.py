"""The peak model fitted back from peaks recovers what generated them.

Stated tolerances (simulated data, truth reference, ~2700 gates per track): λV within 5 %,
σ_p within 5 %, ẑ_a within 2 %, σ_a within 5 %, α within 5 %, P_D within 0.02; and every
estimate within 4 of its own standard errors of the generating value.
"""

import json

import numpy as np
import pytest
from click.testing import CliRunner

from trackreplay.face.cli import main
from trackreplay.cores.association.peak_model_fit import fit_peak_model
from trackreplay.recorders import xcorr_peaks, xcorr_signals
from trackreplay.recorders.scenarios import load_scenario
from trackreplay.recorders.simulated import record

TOL = {"clutter_per_gate": 0.05, "sigma_p_deg": 0.05, "amplitude_mean": 0.02, "amplitude_std": 0.05,
       "clutter_alpha": 0.05}


def fit_simulated(recorder, runs, seed, threshold=0.0, **ov):
    sc = load_scenario("xcorr-signals" if recorder is xcorr_signals else "xcorr-crossing").with_overrides(ov)
    data = recorder.simulate(sc.params, runs, seed)
    arr, counts = data.ragged["/xcorr/peaks"]
    valid = np.arange(arr["bearing_rad"].shape[2])[None, None, :] < counts[..., None]
    run, scan, _ = np.nonzero(valid)
    p = sc.params
    fit = fit_peak_model(arr["bearing_rad"][valid], arr["amplitude"][valid], run, scan,
                         data.fixed["/xcorr/truth"]["bearing_rad"], np.deg2rad(p["gate_deg"]), threshold,
                         (np.deg2rad(p["field_min_deg"]), np.deg2rad(p["field_max_deg"])))
    return p, fit


@pytest.fixture(scope="module")
def simulated_fit():
    return fit_simulated(xcorr_peaks, 150, 21, crossing_angle_deg=30.0)


@pytest.mark.parametrize("target, role", [(0, "strong"), (1, "weak")])
def test_fit_recovers_the_generating_parameters(simulated_fit, target, role):
    p, fit = simulated_fit
    tf = fit.tracks[target]
    assert tf.converged and tf.gates > 2500
    truth = {"clutter_per_gate": p[f"{role}_clutter_per_gate"], "sigma_p_deg": p[f"{role}_sigma_p_deg"],
             "amplitude_mean": p[f"{role}_amplitude_mean"], "amplitude_std": p[f"{role}_amplitude_std"],
             "clutter_alpha": p["clutter_alpha"]}
    for k, v in truth.items():
        assert abs(tf.values[k] / v - 1) < TOL[k], (k, tf.values[k], v)
        assert abs(tf.values[k] - v) < 4 * tf.stderr[k], (k, tf.values[k], v, tf.stderr[k])
    assert tf.values["detection_probability"] > 0.98


def test_background_fit_and_its_model_checks(simulated_fit):
    p, fit = simulated_fit
    bg = fit.background
    assert abs(bg.clutter_per_gate / p["background_clutter_per_gate"] - 1) < 0.05
    assert abs(bg.clutter_alpha / p["clutter_alpha"] - 1) < 0.05
    assert abs(bg.count_dispersion - 1) < 0.1  # Poisson: variance = mean
    assert bg.uniform_ks_pvalue > 0.01 and bg.exponential_ks_pvalue > 0.01


def test_fit_with_misses_and_an_amplitude_threshold():
    """P_D < 1 is recovered; a threshold τ = 5000 truncates both amplitude laws and the fit
    accounts for it (the exponential is memoryless: α unchanged; the normal is truncated)."""
    p, fit = fit_simulated(xcorr_peaks, 150, 22, threshold=5000.0, crossing_angle_deg=30.0, detection_probability=0.8)
    # the two track-start scans always carry the true peak: 2 of the ~18 usable gates per run
    for t, role in enumerate(("strong", "weak")):
        v = fit.tracks[t].values
        gates_per_run = fit.tracks[t].gates / 150
        from scipy.stats import norm

        survive = norm.sf(5000, p[f"{role}_amplitude_mean"], p[f"{role}_amplitude_std"])
        expect_pd = survive * (0.8 * (gates_per_run - 2) + 2) / gates_per_run
        assert abs(v["detection_probability"] - expect_pd) < 0.03
        assert abs(v["amplitude_mean"] / p[f"{role}_amplitude_mean"] - 1) < 0.03
        assert abs(v["amplitude_std"] / p[f"{role}_amplitude_std"] - 1) < 0.08
        assert abs(v["clutter_alpha"] / p["clutter_alpha"] - 1) < 0.1
        expect_mu = p[f"{role}_clutter_per_gate"] * np.exp(-p["clutter_alpha"] * 5000)
        assert abs(v["clutter_per_gate"] / expect_mu - 1) < 0.1


def test_signal_level_peaks_are_fitted_with_physical_strengths():
    """Fitted ẑ_a of the physical recorder = amplitude_scale × source variance; the stronger
    source is the more precise one; the clutter amplitude fit is finite and positive."""
    p, fit = fit_simulated(xcorr_signals, 8, 5, crossing_angle_deg=30.0)
    strong, weak = (f.values for f in fit.tracks)
    assert strong["amplitude_mean"] == pytest.approx(p["amplitude_scale"] * 10 ** (p["strong_snr_db"] / 10), rel=0.05)
    assert weak["amplitude_mean"] == pytest.approx(p["amplitude_scale"] * 10 ** (p["weak_snr_db"] / 10), rel=0.08)
    assert strong["sigma_p_deg"] < weak["sigma_p_deg"] < 1.0
    assert 0 < fit.background.clutter_alpha and np.isfinite(fit.background.count_dispersion)


def test_cli_fit_peaks_prints_the_model_and_json(tmp_path):
    path = tmp_path / "p.mcap"
    record(path, load_scenario("xcorr-crossing").with_overrides({"crossing_angle_deg": 30.0}), runs=30, seed=3)
    res = CliRunner().invoke(main, ["fit-peaks", str(path)])
    assert res.exit_code == 0, res.output
    for word in ("strong", "weak", "background", "λV", "calibrate the simulator: replay simulate xcorr-crossing"):
        assert word in res.output
    res = CliRunner().invoke(main, ["fit-peaks", str(path), "--json", "--reference", "jpda_a"])
    assert res.exit_code == 0, res.output
    recs = json.loads(res.output)
    weak_sp = [r["value"] for r in recs if r["track"] == "weak" and r["parameter"] == "sigma_p_deg"][0]
    assert 0.5 < weak_sp < 2.5
    bad = tmp_path / "empty.mcap"
    bad.write_bytes(b"")
    res = CliRunner().invoke(main, ["fit-peaks", str(bad)])
    assert res.exit_code == 2 and "replay: error:" in res.output and "Traceback" not in res.output
