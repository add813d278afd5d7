"""Tracks end by one documented rule (pipeline/cores/association/track_ending.py): leaving the
field by more than a margin, or coasting too long; the ending is flagged and nothing is reported
after it. And data without truth replay in every family."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from pipeline import vocabulary as vocab
from pipeline.contract import McapFrameWriter, iter_frames, read_dataset
from pipeline.cores.association.jpda import STRATEGIES, BearingTrackerDesign, ScanPeaks, track_bearing_peaks
from pipeline.cores.association.track_ending import EndingRule, coasting_run, ended
from pipeline.face.cli import main

DEG = np.pi / 180


def test_the_rule_ends_on_the_field_edge_plus_margin_and_after_n_coasted_scans():
    rule = EndingRule(field=(70 * DEG, 110 * DEG), margin=5 * DEG, max_coasted_scans=3)
    position = np.array([64.9, 65.1, 90.0, 114.9, 115.1]) * DEG
    assert ended(position, np.zeros(5), rule).tolist() == [True, False, False, False, True]
    run = np.zeros(2, int)
    for coasted in ([True, False], [True, True], [True, True]):
        run = coasting_run(run, np.array(coasted))
    assert run.tolist() == [3, 2]
    assert ended(np.full(2, 90 * DEG), run, rule).tolist() == [True, False]
    assert not ended(np.full(2, 90 * DEG), run, replace(rule, max_coasted_scans=0)).any()


def _design(**ending) -> BearingTrackerDesign:
    return BearingTrackerDesign(scan_period_s=1.0, gate_rad=10 * DEG, q_rad2=0.01 * DEG**2, amplitude_threshold=5000.0,
                                detection_probability=0.9, clutter_per_gate=2.0, clutter_alpha=4e-4,
                                sigma_p_rad=np.array([1.3 * DEG]), strength=np.array([21000.0]),
                                sigma_a=np.array([2500.0]), ending=EndingRule(**ending))


def _empty_scans(K, R=2):
    return [ScanPeaks(np.zeros((R, 0)), np.zeros((R, 0)), np.zeros((R, 0), bool)) for _ in range(K)]


def test_a_track_that_leaves_the_field_ends_flagged_and_is_never_reported_outside_it():
    # a track at 104.5° moving out at 1°/s with no peaks: it coasts out of the 70–110° field
    K, R = 40, 2
    x0 = np.tile(np.array([104.5 * DEG, 1 * DEG]), (R, 1, 1))
    P0 = np.tile(np.diag([1e-4, 1e-6]), (R, 1, 1, 1))
    out = track_bearing_peaks(_empty_scans(K, R), x0, P0,
                              _design(field=(70 * DEG, 110 * DEG), margin=5 * DEG), STRATEGIES["jpda"], start_scan=0)
    flags, bearing = out["flags"][:, :, 0], out["state"][:, :, 0, 0]
    end = np.argmax((flags & vocab.DELETED) > 0, axis=1)
    # 104.5° + k·1°/s passes 115° (edge + half a gate) at k = 11: it ends there, flagged
    assert (end == 11).all()
    assert np.all(bearing[np.isfinite(bearing)] <= 116 * DEG)
    after = np.arange(K)[None, :] > end[:, None]
    assert np.isnan(bearing[after]).all() and ((flags[after] & vocab.NO_TRACK) > 0).all()


def test_a_track_coasting_max_coasted_scans_in_a_row_ends():
    K, R = 20, 1
    x0 = np.array([[[90 * DEG, 0.0]]])
    P0 = np.array([[np.diag([1e-4, 1e-6])]])
    out = track_bearing_peaks(_empty_scans(K, R), x0, P0, _design(max_coasted_scans=4), STRATEGIES["jpda_a"],
                              start_scan=0)
    flags = out["flags"][0, :, 0]
    assert int(np.argmax((flags & vocab.DELETED) > 0)) == 4  # coasted at scans 1, 2, 3, 4
    assert np.isnan(out["state"][0, 5:, 0]).all()


# --------------------------------------------------------------------------- without truth


def without_truth(src: Path, dst: Path) -> None:
    """``src`` with its truth channels left out (a recording as a sensor would give it)."""
    meta: dict = {}
    with open(dst, "wb") as f:
        writer, previous = None, None
        for topic, run, scan, t, arrays, n in iter_frames(src, False, meta):
            if "truth" in topic:
                continue
            if writer is None:
                writer = McapFrameWriter(f, meta["metadata"])
            if previous is not None and scan != previous:
                writer.flush()
            previous = scan
            writer.write(topic, run, scan, t, arrays, run_count=n)
        writer.finish()


SCENARIOS = {"radar-tws": ["--set", "n_scans=20"], "xcorr-crossing": ["--set", "crossing_angle_deg=20"],
             "array-crossing": ["--set", "n_scans=12"], "tdoa-fdoa": [],
             "colored-imm": ["--set", "n_samples=200", "--set", "manoeuvre_first_sample=60",
                             "--set", "manoeuvre_last_sample=120"]}


@pytest.mark.parametrize("scenario", sorted(SCENARIOS))
def test_every_family_replays_a_data_set_without_its_truth(tmp_path, scenario):
    runner = CliRunner()
    full, bare = tmp_path / "full.mcap", tmp_path / "bare.mcap"
    res = runner.invoke(main, ["simulate", scenario, "--runs", "4", "--seed", "3", "-o", str(full), *SCENARIOS[scenario]])
    assert res.exit_code == 0, res.output
    without_truth(full, bare)
    assert not any("truth" in t for t in read_dataset(bare).channels)
    out = tmp_path / "o" / "tracks.mcap"
    res = runner.invoke(main, [str(bare), "--out", str(out), "--no-rrd", "-q"])
    assert res.exit_code == 0, res.output
    assert "Traceback" not in res.output and "rmse" not in res.output.lower()  # no error it cannot compute
    assert out.is_file() and (out.parent / "report.png").is_file()
    if scenario in ("xcorr-crossing", "array-crossing"):  # bearings, the one thing to show without truth
        assert "run 0 without truth: track positions (deg) per scan" in res.output
    from pipeline import vocabulary as vocab

    prefixes = tuple(f.output_prefix for f in vocab.FAMILIES.values())
    assert any(t.startswith(prefixes) for t in read_dataset(out).channels)


def test_an_unlabelled_start_does_as_well_as_the_labelled_one_and_as_the_truth_once_on_target():
    """The start from unlabelled peaks (a recording's) on the same 100 runs as the labelled
    two-point start and the truth start (the paper's): success at least the labelled start's
    within Monte Carlo error (paired); and, over the runs where both it and the truth start
    follow their targets, the bearing error after start-up within Monte Carlo error of the
    truth start's. (Both measurement starts succeed less often than the truth start: the gap is
    reported in docs/papers/bearing-peaks.md, not hidden here.)"""
    from evaluators.track_association import paired_difference, track_outcomes
    from evaluators.tracking_metrics import nanmean
    from pipeline.stages.bearing_peaks import track_simulated
    from recorders import xcorr_peaks
    from recorders.scenarios import load_scenario

    p = load_scenario("xcorr-crossing").with_overrides({"crossing_angle_deg": 20.0}).params
    data = xcorr_peaks.simulate(p, 100, 21)
    held, error = {}, {}
    for start in ("truth", "two-point", "peaks"):
        res = track_simulated(data, p, trackers=("jpda_a",), overrides={"track_start": start})
        state = res["tracks"]["jpda_a"]["state"][..., 0]
        ok, _, _ = track_outcomes(state, res["truth"], res["gate_rad"])
        held[start] = ok.all(axis=1)
        late = slice(state.shape[1] // 2, None)
        error[start] = np.sqrt(nanmean((state[:, late] - res["truth"][:, late]) ** 2, axis=(1, 2)))
    diff, se = paired_difference(held["peaks"], held["two-point"])
    assert diff >= -2 * se, (diff, se)
    both = held["peaks"] & held["truth"]
    d = error["peaks"][both] - error["truth"][both]
    assert both.sum() >= 30 and abs(d.mean()) <= 2 * d.std(ddof=1) / np.sqrt(both.sum()), (d.mean(), both.sum())
