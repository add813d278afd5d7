"""Tracks end by one documented rule (pipeline/cores/association/track_management.py): leaving the
field by more than a margin, or coasting too long; the ending is flagged and nothing is reported
after it. And data without truth replay in every family."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from trackreplay import design_values, vocabulary as vocab
from trackreplay.contract import read_dataset
from trackreplay.cores.association.jpda import STRATEGIES, BearingTrackerDesign
from trackreplay.cores.association.jpda_tracking import ScanPeaks, track_bearing_peaks
from trackreplay.cores.association.track_management import EndingRule, coasting_run, ended

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


SCENARIOS = {"radar-tws": ["--set", "n_scans=20"], "xcorr-crossing": ["--set", "crossing_angle_deg=20"],
             "array-crossing": ["--set", "n_scans=12"], "tdoa-fdoa": [],
             "colored-imm": ["--set", "n_samples=200", "--set", "manoeuvre_first_sample=60",
                             "--set", "manoeuvre_last_sample=120"]}


@pytest.mark.parametrize("scenario", sorted(SCENARIOS))
def test_every_family_replays_a_data_set_without_its_truth(scenario, replay_without_truth):
    res, out = replay_without_truth(scenario, 3, SCENARIOS[scenario])
    assert "rmse" not in res.output.lower()  # no error it cannot compute
    assert out.is_file() and (out.parent / "report.png").is_file()
    if scenario in ("xcorr-crossing", "array-crossing"):  # bearings, the one thing to show without truth
        assert "run 0 without truth: track positions (deg) per scan" in res.output
    from trackreplay import vocabulary as vocab

    prefixes = tuple(f.output_prefix for f in vocab.FAMILIES.values())
    assert any(t.startswith(prefixes) for t in read_dataset(out).channels)


def test_an_unlabelled_start_does_as_well_as_the_labelled_one_and_as_the_truth_once_on_target():
    """The start from unlabelled peaks (a recording's) on the same 100 runs as the labelled
    two-point start and the truth start (the paper's): success at least the labelled start's
    within Monte Carlo error (paired); and, over the runs where both it and the truth start
    follow their targets, the bearing error after start-up within Monte Carlo error of the
    truth start's. (Both measurement starts succeed less often than the truth start: the gap is
    reported in docs/papers/xcorr.md, not hidden here.)"""
    from trackreplay.evaluators.xcorr import paired_difference, track_outcomes
    from trackreplay.evaluators.tracking_metrics import nanmean
    from recorded_peaks import track_recorded
    from trackreplay.recorders import xcorr_peaks
    from trackreplay.recorders.scenarios import load_scenario

    p = load_scenario("xcorr-crossing").with_overrides({"crossing_angle_deg": 20.0}).params
    data = xcorr_peaks.simulate(p, 100, 21)
    held, error = {}, {}
    for start in ("truth", "two-point", "peaks"):
        res = track_recorded(data, p, trackers=("jpda_a",), overrides={"track_start": start}, seed=21)
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


# --------------------------------------------------------------------------- confirmation (M-of-N)


@pytest.mark.parametrize("m, n, start_hits", [(3, 4, 2), (2, 3, 1), (4, 6, 1), (1, 1, 1)])
def test_batch_confirmation_agrees_with_the_scan_loop(m, n, start_hits):
    """`confirmation_scans` (batch trackers) and `TrackLife` (scan loops) are one rule."""
    from trackreplay.cores.association.track_management import ConfirmationRule, TrackLife, confirmation_scans

    rule = ConfirmationRule(m, n)
    hit = np.random.default_rng(m * 10 + n).random((400, 10)) < 0.6
    tentative, failed = confirmation_scans(hit, rule, start_hits)
    life = TrackLife((400,), rule)
    life.start(np.ones(400, bool), hits=start_hits, scans=1)
    loop_tentative = np.zeros_like(hit)
    loop_tentative[:, 0] = life.tentative
    loop_failed = np.full(400, -1)
    for k in range(1, hit.shape[1]):
        t, ending = life.step(hit[:, k], np.zeros(400))
        loop_tentative[:, k] = t
        loop_failed[ending & (loop_failed < 0)] = k
    assert np.array_equal(failed, loop_failed)
    assert np.array_equal(tentative, loop_tentative)
    # the rule itself, counted by hand: confirmed once M hits are in, never after the window
    counted = np.cumsum(hit, axis=1) - hit[:, :1] + start_hits
    confirmed_at = np.where((counted >= m).any(axis=1), np.argmax(counted >= m, axis=1), 99)
    assert np.all((failed >= 0) == (confirmed_at >= n))


def _radar_design(**management):
    from trackreplay.cores.association.track_management import ConfirmationRule, EndingRule
    from trackreplay.trackers.radar_tws import TrackerDesign

    return TrackerDesign(scan_period_s=1.0, sigma_v=1.0, sigma_range_m=20.0, sigma_bearing_rad=0.01,
                         nominal_cross_range_m=100.0, confirmation=ConfirmationRule(3, 4),
                         ending=EndingRule(max_coasted_scans=5), **management)


def _radar_plots(K, have):
    """One target at (10 km, 0) moving at (−50, 20) m/s, noise-free plots where ``have`` (R, K)."""
    t = np.arange(K, dtype=float)
    x, y = 10_000.0 - 50.0 * t, 20.0 * t
    rng = np.where(have, np.hypot(x, y)[None, :], np.nan)[..., None]
    brg = np.where(have, np.arctan2(y, x)[None, :], np.nan)[..., None]
    return rng, brg, have.astype(np.int64), t


def test_a_radar_target_that_stops_producing_plots_is_deleted_and_restarted_when_they_return():
    from trackreplay.trackers.radar_tws import STRATEGIES, track_plots

    K = 30
    have = np.ones((2, K), bool)
    have[:, 10:20] = False
    rng, brg, counts, t = _radar_plots(K, have)
    out = track_plots(rng, brg, counts, t, _radar_design(), STRATEGIES["kalman"])
    flags = out["flags"][0]
    deleted = np.flatnonzero(flags & vocab.DELETED)
    # coasted at scans 10 … 14: the fifth coasted scan in a row ends it
    assert deleted.tolist() == [14]
    assert np.all(flags[10:14] & vocab.COASTED)
    assert np.isnan(out["state"][0, 14:21]).all() and np.all(flags[14:21] & vocab.NO_TRACK)
    # plots return at 20: a new two-point start at 21 (tentative), confirmed by the plot of 22
    assert flags[21] & vocab.INITIALISING and not flags[22] & (vocab.INITIALISING | vocab.NO_TRACK)
    assert np.isfinite(out["state"][0, 21:]).all()


def test_a_tentative_radar_track_that_cannot_be_confirmed_is_deleted():
    from trackreplay.trackers.radar_tws import STRATEGIES, track_plots

    K = 8
    have = np.zeros((1, K), bool)
    have[0, :2] = True   # two plots start a track at scan 1; no plot follows
    rng, brg, counts, t = _radar_plots(K, have)
    flags = track_plots(rng, brg, counts, t, _radar_design(), STRATEGIES["fixed"])["flags"][0]
    # 3 of the first 4 scans: after the misses of scans 2 and 3 it cannot get there
    assert flags[1] & vocab.INITIALISING and flags[2] & vocab.INITIALISING and flags[2] & vocab.COASTED
    assert np.flatnonzero(flags & vocab.DELETED).tolist() == [3]
    assert np.all(flags[3:] & vocab.NO_TRACK)


def test_an_array_track_that_leaves_the_field_is_deleted_and_never_reported_outside_it():
    """d = 0.6 λ: the field free of grating lobes is |θ| < arcsin(1/0.6 − 1) = 41.8°. A target
    moving from 0° to 78° leaves it at scan 21; its track ends within a scan, flagged."""
    from trackreplay.trackers import array as ab
    from trackreplay.trackers.interface import ArraySnapshots
    from trackreplay.recorders.array_snapshots import steering_vectors
    from trackreplay.recorders.scenarios import load_scenario

    R, K, M, Ns = 10, 40, 15, 30
    theta = np.deg2rad(np.linspace(0.0, 78.0, K))
    rng = np.random.default_rng(1)
    source = (rng.standard_normal((R, K, 1, Ns)) + 1j * rng.standard_normal((R, K, 1, Ns))) * np.sqrt(5.0)
    noise = (rng.standard_normal((R, K, M, Ns)) + 1j * rng.standard_normal((R, K, M, Ns))) * np.sqrt(0.5)
    X = steering_vectors(theta[:, None], M, 0.6)[None] @ source + noise
    p = load_scenario("array-crossing").params
    design = {q.name: p.get(q.name, q.default) for q in ab.PARAMS}
    out = ab.Proposed(**dict(design, n_sources=1)).track(
        ArraySnapshots(snapshots=X, times_s=np.arange(K, dtype=float), spacing_wavelengths=0.6))
    field = np.arcsin(1 / 0.6 - 1)
    flags, bearing = out["flags"][:, :, 0], out["state"][:, :, 0, 0]
    leaves = int(np.argmax(theta > field))
    end = np.argmax((flags & vocab.DELETED) > 0, axis=1)
    assert ((flags & vocab.DELETED) > 0).sum(axis=1).tolist() == [1] * R  # flagged once per run
    assert np.all((end >= leaves - 1) & (end <= leaves + 2)), (end, leaves)
    assert np.nanmax(np.abs(bearing)) <= field
    assert np.all(flags[np.arange(K)[None, :] > end[:, None]] == vocab.NO_TRACK)


def test_a_scan_without_enough_peaks_leaves_a_slot_empty_instead_of_failing():
    from trackreplay.trackers.xcorr import one_point_start, strongest_start_peaks

    bearing = np.deg2rad(np.array([[[80.0, 95.0, 0.0]], [[88.0, 0.0, 0.0]]]))  # (R=2, K=1, W=3)
    amplitude = np.array([[[9000.0, 20000.0, 0.0]], [[30000.0, 0.0, 0.0]]])
    z0 = strongest_start_peaks(bearing, amplitude, np.array([[2], [1]]), np.array([21000.0, 9000.0]), 5000.0)
    assert np.allclose(np.rad2deg(z0[0]), [95.0, 80.0]) and np.isclose(np.rad2deg(z0[1, 0]), 88.0)
    assert np.isnan(z0[1, 1])
    x0, P0 = one_point_start(z0, np.deg2rad([1.0, 2.0]), np.deg2rad(0.5))
    assert np.array_equal(x0[..., 1], np.zeros((2, 2))) and np.allclose(P0[0, 1], np.diag(np.deg2rad([2.0, 0.5])) ** 2)


# --------------------------------------------------------------------------- started from measurements


def _found(full: Path, tracks_of: Path, window: slice, overrides=None) -> dict:
    """Per tracker, the runs whose confirmed tracks over ``window`` match the truth's targets:
    every target mostly tracked and no false track (the assignment metrics of
    ``evaluators/assignment_metrics.py``, in the family's space and match gate)."""
    from trackreplay.evaluators.assignment_metrics import assignment_metrics
    from trackreplay.replay import applicable_stages, replay

    res = replay(tracks_of, design_overrides=overrides)
    ds = read_dataset(full)
    found = {}
    for stage in applicable_stages(ds.channels):
        design = design_values.resolve(stage, ds)
        reference = stage.reference(ds, design)
        truth, space = stage.standard_truth(reference), stage.standard_space(design, reference)
        truth = truth if truth.ndim == 4 else truth[:, :, None]
        position = list(space.position_components)
        for name, out in res.results[stage.name]["tracks"].items():
            if "state" not in out:  # a side output (the AR(1) estimator)
                continue
            state, flags = np.asarray(out["state"], float), np.asarray(out["flags"])
            if flags.ndim == 2:
                state, flags = state[:, :, None], flags[:, :, None]
            confirmed = (flags & (vocab.NO_TRACK | vocab.DELETED | vocab.INITIALISING)) == 0
            tracks = np.where(confirmed[..., None], state[..., position], np.nan)[:, window]
            targets = truth[..., [space.truth_components.index(c) for c in position]][:, window]
            m = assignment_metrics(tracks, targets, space.gate, angular=space.angular)
            found[name] = (m["mostly_tracked"] == m["targets"]) & (m["false_tracks"] == 0)
    return found


FOUND = {  # scenario, overrides, runs, the window after start-up (scans)
    "radar-tws": ({}, 60, slice(4, None)),
    "array-crossing": ({}, 40, slice(4, None)),
    "colored-imm": ({"n_samples": 300, "manoeuvre_first_sample": 100, "manoeuvre_last_sample": 200}, 30,
                    slice(4, None)),
}


@pytest.mark.parametrize("scenario", sorted(FOUND))
def test_tracks_started_from_measurements_find_the_targets(tmp_path, scenario, without_truth):
    """Truth stripped, default scenario: the confirmed tracks match the targets in ≥ 95 % of runs."""
    from trackreplay.recorders.scenarios import load_scenario
    from trackreplay.recorders.simulated import record

    overrides, runs, window = FOUND[scenario]
    full, bare = tmp_path / "full.mcap", tmp_path / "bare.mcap"
    record(full, load_scenario(scenario).with_overrides(overrides), runs, 5)
    without_truth(full, bare)
    for name, ok in _found(full, bare, window).items():
        assert ok.mean() >= 0.95, (name, ok.mean())


def test_peak_tracks_started_from_one_peak_are_found_as_often_as_truth_started_ones(tmp_path, without_truth):
    """The default crossing (strong and weak target in clutter): even started at the truth, the
    weak track is pulled off by clutter in some runs before the crossing, so ≥ 95 % is not a
    property of the tracker. What the start must do is find the targets as often as the truth
    start does (paired over the same 150 runs, within Monte Carlo error), before the crossing."""
    from trackreplay.evaluators.xcorr import paired_difference
    from trackreplay.recorders.scenarios import load_scenario
    from trackreplay.recorders.simulated import record

    full, bare = tmp_path / "full.mcap", tmp_path / "bare.mcap"
    record(full, load_scenario("xcorr-crossing"), 150, 5)
    without_truth(full, bare)
    before_crossing = slice(4, 40)
    from_peaks, from_truth = _found(full, bare, before_crossing), _found(full, full, before_crossing)
    for name in from_truth:
        diff, se = paired_difference(from_peaks[name], from_truth[name])
        assert diff >= -2 * se and from_peaks[name].mean() >= 0.8, (name, from_peaks[name].mean(),
                                                                     from_truth[name].mean(), se)


def test_colored_filters_started_from_measurements_converge_to_the_truth_started_error(tmp_path):
    """After start-up the measurement start's position RMSE is the truth start's within Monte
    Carlo error (paired over runs), for every filter; early on it is worse (the start matters)."""
    from trackreplay.recorders.scenarios import load_scenario
    from trackreplay.recorders.simulated import record
    from trackreplay.replay import replay

    full = tmp_path / "full.mcap"
    record(full, load_scenario("colored-imm").with_overrides(
        {"n_samples": 400, "manoeuvre_first_sample": 150, "manoeuvre_last_sample": 250}), 30, 8)
    truth = read_dataset(full).channel(vocab.CHANNELS["colored_truth"]).grid("state")
    results = {start: replay(full, design_overrides={"track_start": start}).results["colored"]["tracks"]
               for start in ("truth", "measurements")}
    late, early = slice(200, None), slice(1, 6)
    for name, out in results["truth"].items():
        if "state" not in out:
            continue
        err = {s: (np.asarray(results[s][name]["state"])[..., 0::3] - truth[..., 0::3]) ** 2 for s in results}
        rmse = {s: np.sqrt(e[:, late].mean(axis=(1, 2))) for s, e in err.items()}
        d = rmse["measurements"] - rmse["truth"]
        se = d.std(ddof=1) / np.sqrt(d.size)
        assert abs(d.mean()) <= 2 * se + 1e-9 * rmse["truth"].mean(), (name, d.mean(), se)
        assert err["measurements"][:, early].mean() > err["truth"][:, early].mean(), name
