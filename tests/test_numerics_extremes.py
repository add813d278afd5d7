"""Numerics at the edges of the accepted design values (issue 30, item 7).

Two properties, on every measurement family:

* every covariance a tracker's outputs carry where its state is finite is positive definite, as an
  eigensolver independent of the output check (LAPACK's ``eigvalsh``) finds it, or its cell is
  flagged ``NOT_POSITIVE_DEFINITE``; and the flag is never put on a matrix whose smallest
  eigenvalue is clear of rounding;
* every metric without a value (NaN or null) carries its reason in the ``note`` column, and a
  metric with a value has none; the reasons of the plainest cases are checked against the
  outputs themselves, and the printed summary lists them.

The extreme settings are the ones a sweep of each scenario's values to the edges of what it
accepts found to give singular covariances or metrics without a value.
"""

from __future__ import annotations

import numpy as np
import polars as pl
import pytest
from click.testing import CliRunner

from trackreplay import vocabulary as vocab
from trackreplay.face.cli import main
from trackreplay.replay import replay
from trackreplay.trackers import interface
from trackreplay.trackers.interface import STRICT_DEFINITENESS, TrackerError, validate_outputs
from trackreplay.recorders.scenarios import load_scenario
from trackreplay.recorders.simulated import record

EPS = np.finfo(float).eps

# (scenario, overrides): one or more settings per family whose covariances turn singular
SINGULAR_SETTINGS = [
    ("radar-tws", {"scan_period_s": "1e-9", "n_scans": "16"}),
    ("radar-multi", {"sigma_range_m": "1e-9"}),
    ("xcorr-crossing", {"strong_sigma_p_deg": "1e-300"}),
    ("array-crossing", {"innovation_variance_deg2": "1e-300"}),
    ("tdoa-fdoa", {"sigma_fdoa_hz": "1e-9"}),
    ("tdoa-fdoa-noise", {}),  # stationary emitter: the velocity is known, its variance exactly 0
    ("colored-ar", {"measurement_variance_m2": "1e-300", "n_samples": "200"}),
]

# settings whose metrics lack values, with the reason's key words for one tracker's metric
MISSING_SETTINGS = [
    ("radar-tws", {"detection_probability": "1e-9", "n_scans": "16"}, "kalman", "rmse_position_m",
     "no track in any run"),
    ("radar-multi", {"survival_probability": "1e-9"}, "gnn", "motp_m", "no scan with a confirmed track"),
    ("tdoa-fdoa", {}, "fdoa", "rmse_position_m", "UNDERDETERMINED"),
    ("tdoa-fdoa", {"sigma_tdoa_s": "1e-300"}, "joint", "nees_time_average", "DIVERGED"),
    ("tdoa-fdoa-noise", {"carrier_hz": "1"}, "fdoa", "crlb_position_m", "'truth' class"),
    ("radar-tws", {"sigma_bearing_deg": "1e-9", "n_scans": "16"}, "kalman", "position_efficiency",
     "pcrb_position_m has no value"),
    ("colored-ar", {"measurement_variance_m2": "1e-300"}, "ar_estimator", "alpha_rmse", "NaN in every run"),
    ("xcorr-crossing", {"detection_probability": "1e-9"}, "jpda", "rmse_bearing_deg_held", "no track held"),
    ("xcorr-crossing", {"amplitude_threshold": "5e9"}, "jpda", "mean_nis", "no innovation in any run"),
    ("colored-ar", {"measurement_variance_m2": "1e-300", "n_samples": "200"}, "kf", "whiteness_max_abs_rho",
     "every whitened innovation is 0"),
]


def _replayed(tmp_path, scenario, overrides, runs=3):
    path = tmp_path / "data.mcap"
    record(path, load_scenario(scenario).with_overrides(overrides), runs, 5)
    return path, replay(path)


def _outputs(res):
    for result in res.results.values():
        for name, out in result["tracks"].items():
            if "covariance" in out and "state" in out:
                yield name, out


@pytest.mark.parametrize("scenario, overrides", SINGULAR_SETTINGS, ids=[s for s, _ in SINGULAR_SETTINGS])
def test_every_covariance_written_is_positive_definite_or_flagged(tmp_path, scenario, overrides):
    _, res = _replayed(tmp_path, scenario, overrides)
    flagged_anywhere = 0
    for name, out in _outputs(res):
        live = np.isfinite(out["state"]).all(axis=-1)
        P = out["covariance"][live]
        n = P.shape[-1]
        flagged = (out["flags"][live] & vocab.NOT_POSITIVE_DEFINITE) > 0
        lowest = np.linalg.eigvalsh(P)[:, 0]
        trace = np.abs(np.trace(P, axis1=-2, axis2=-1))
        unflagged_singular = ~flagged & (lowest <= 0)
        assert not unflagged_singular.any(), (
            f"{scenario} {name}: {int(unflagged_singular.sum())} covariances with smallest eigenvalue ≤ 0 "
            f"(e.g. {lowest[unflagged_singular].min():.3g}) carry no flag")
        # the flag says "within rounding of singular": never on a matrix clear of it
        clear = lowest > 2 * STRICT_DEFINITENESS * n * trace
        assert not (flagged & clear).any(), f"{scenario} {name}: a well-conditioned covariance was flagged"
        flagged_anywhere += int(flagged.sum())
    assert flagged_anywhere, f"{scenario} {overrides}: expected singular covariances at this setting"


def _stack(matrices, runs_innermost=False):
    """(R, K, n, n) covariances and finite states for a list of R·K matrices."""
    P = np.asarray(matrices, float)
    R, K = len(P) // 2, 2
    P = P.reshape(R, K, *P.shape[-2:])
    if runs_innermost:  # the layout most trackers use: a scan's runs side by side
        P = np.ascontiguousarray(np.moveaxis(P, 0, 1)).swapaxes(0, 1)
    return P, np.zeros((R, K, P.shape[-1]))


@pytest.mark.parametrize("runs_innermost", [False, True])
@pytest.mark.parametrize("block", [1, 3, 32768])
def test_the_output_check_flags_exactly_the_singular_covariances(monkeypatch, runs_innermost, block):
    monkeypatch.setattr(interface, "COVARIANCE_CHECK_BLOCK", block)
    rng = np.random.default_rng(3)
    healthy = [a @ a.T + 0.1 * np.eye(4) for a in rng.normal(size=(7, 4, 4))]
    known = np.diag([4.0, 9.0, 0.0, 0.0])                    # components known exactly
    rounding = np.outer([1.0, 2.0, 3.0, 4.0], [1.0, 2.0, 3.0, 4.0])  # rank one
    tiny_negative = np.diag([1.0, 1.0, 1.0, -1e-17])           # within rounding of semi-definite
    matrices = healthy[:3] + [known] + healthy[3:5] + [rounding, tiny_negative] + healthy[5:] + [healthy[0], healthy[1]]
    P, state = _stack(matrices, runs_innermost)
    out = validate_outputs({"state": state, "flags": np.zeros(state.shape[:2], np.uint32), "covariance": P},
                           *state.shape[:2], "t")
    lowest = np.linalg.eigvalsh(P)[..., 0]
    expected = lowest <= STRICT_DEFINITENESS * 4 * np.abs(np.trace(P, axis1=-2, axis2=-1))
    got = (out["flags"] & vocab.NOT_POSITIVE_DEFINITE) > 0
    np.testing.assert_array_equal(got, expected)
    assert got.sum() == 3


def test_a_covariance_beyond_rounding_of_semi_definite_is_still_refused():
    P, state = _stack([np.eye(2)] * 3 + [np.diag([1.0, -1e-3])])
    with pytest.raises(TrackerError, match="run 1 scan 1: covariance not positive definite"):
        validate_outputs({"state": state, "flags": np.zeros(state.shape[:2], np.uint32), "covariance": P},
                         *state.shape[:2], "t")


@pytest.mark.parametrize("scenario, overrides, tracker, metric, reason", MISSING_SETTINGS,
                         ids=[f"{s}-{m}" for s, _, _, m, _ in MISSING_SETTINGS])
def test_every_metric_without_a_value_says_why(tmp_path, scenario, overrides, tracker, metric, reason):
    _, res = _replayed(tmp_path, scenario, overrides)
    s = res.summary
    missing = s["value"].is_null() | s["value"].is_nan()
    assert missing.any()
    assert s.filter(missing)["note"].is_null().sum() == 0, "a metric without a value has no note"
    assert s.filter(~missing)["note"].is_null().all(), "a metric with a value has a note"
    notes = s.filter(missing & (pl.col("tracker") == tracker) & (pl.col("metric") == metric))["note"].to_list()
    assert notes and all(reason in n for n in notes), notes


def test_the_plain_reasons_agree_with_the_outputs(tmp_path):
    """'no track in any run' only where every cell is NO_TRACK; 'no scan with a confirmed track'
    only where no cell holds a confirmed track; 'UNDERDETERMINED' where every cell says so."""
    _, res = _replayed(tmp_path, "radar-tws", {"detection_probability": "1e-9", "n_scans": "16"})
    for name, out in _outputs(res):
        assert np.all(out["flags"] & vocab.NO_TRACK)
    _, res = _replayed(tmp_path, "radar-multi", {"survival_probability": "1e-9"})
    for name, out in _outputs(res):
        held = np.isfinite(out["state"]).all(-1) & ((out["flags"] & vocab.NO_TRACK) == 0)
        assert not np.any(held & ((out["flags"] & (vocab.INITIALISING | vocab.DELETED)) == 0))
    _, res = _replayed(tmp_path, "tdoa-fdoa", {})
    fdoa = res.results["tdoa-fdoa"]["tracks"]["fdoa"] if "tdoa-fdoa" in res.results else next(
        r["tracks"]["fdoa"] for r in res.results.values() if "fdoa" in r["tracks"])
    assert np.all(fdoa["flags"] & vocab.UNDERDETERMINED)


def test_the_printed_summary_and_the_json_say_why(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    runner = CliRunner()
    res = runner.invoke(main, ["simulate", "tdoa-fdoa", "--runs", "3", "-o", "d.mcap"])
    assert res.exit_code == 0, res.output
    res = runner.invoke(main, ["d.mcap", "--no-rrd", "--out", "o/tracks.mcap"])
    assert res.exit_code == 0, res.output
    assert "metrics without a value, and why" in res.output
    assert "fdoa: rmse_position_m" in res.output and "UNDERDETERMINED" in res.output
    table = pl.read_csv(tmp_path / "o" / "metrics.csv")
    missing = table["value"].is_null() | table["value"].is_nan()
    assert table.filter(missing)["note"].is_null().sum() == 0
    res = runner.invoke(main, ["eval", "d.mcap", "--json"])
    assert res.exit_code == 0
    import json

    records = json.loads(res.stdout if hasattr(res, "stdout") else res.output)
    assert all(r.get("note") for r in records if r["value"] is None or r["value"] != r["value"])
