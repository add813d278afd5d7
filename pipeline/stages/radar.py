"""Stage: TWS radar plots → four trackers (fixed / approximate / exact α-β, Kalman).

Input channels: ``/radar/plots`` (``range_m``, ``bearing_rad`` per run and scan), optionally
``/radar/truth`` (``state``). Output: ``/tracks/radar/<tracker>`` with ``state``,
``covariance``, ``alpha``, ``beta`` (along-range, cross-range), ``lambda_cross``,
``innovation`` and ``flags`` per run and scan. Only decoding and bookkeeping live here; the numbers
come from :mod:`trackreplay.trackers.radar_tws` and :mod:`trackreplay.evaluators.radar`, the Rerun views from
:mod:`trackreplay.face.rerun_radar`.
"""

from __future__ import annotations

import numpy as np

from trackreplay.evaluators import radar as radar_eval
from trackreplay.cores.filters.converted_measurements import polar_to_cartesian
from trackreplay import vocabulary as vocab
from trackreplay.trackers.interface import RadarPlots
from trackreplay.errors import InputError, require_finite
from trackreplay.stage_scoring import model_recorded
from trackreplay.stages.base import Stage
from trackreplay.stages.evaluation_gates import gate_sigmas, round_up
from trackreplay.stages.truth_sets import identity_slots, single_target
from trackreplay.trackers.radar_tws import radar_pcrb
from trackreplay.evaluators.standard import position_space

#: radius, in standard deviations, of the two-dimensional Gaussian ellipse that holds all but
#: 10⁻⁴ of it (√ of the χ² quantile with 2 degrees of freedom: √(−2 ln 10⁻⁴)), the rule of
#: :mod:`trackreplay.stages.evaluation_gates` in the plane
GATE_SIGMAS = gate_sigmas(2)


PLOTS = vocab.CHANNELS["radar_plots"]
TRUTH = vocab.CHANNELS["radar_truth"]
XY = "/xy/world"  # under the x/y view's origin, flipped north-up (see timeline.north_up)


class RadarStage(Stage):
    name = "radar"
    family = "radar"
    # what the evaluator needs: the bearing noise (cross-range error) and the fixed gains' design point
    design_keys = ("sigma_bearing_deg", "nominal_cross_range_m")

    def decode_plots(self, dataset):
        """Plots as padded ``(runs, scans, width)`` range and bearing, counts and scan times
        (decoded and checked once per data set)."""
        if "radar_plots" not in dataset.cache:
            dataset.cache["radar_plots"] = self._decode_plots(dataset)
        return dataset.cache["radar_plots"]

    def _decode_plots(self, dataset):
        ch = dataset.channel(PLOTS)
        rng, counts = ch.ragged("range_m")
        brg, _ = ch.ragged("bearing_rad")
        for name, values in (("range_m", rng), ("bearing_rad", brg)):
            if values.ndim != 3:  # (runs, scans, plots): one number per plot
                raise InputError(f"{PLOTS} {name} has shape {values.shape[3:]} per plot; each plot has one "
                                 f"{name}", dataset.path)
        # finite values and ranges ≥ 0 are the contract's checks at read time (trackreplay.vocabulary.VALUES)
        if ch.n_scans < 3:
            raise InputError(f"{PLOTS} has {ch.n_scans} scan(s); a track needs at least 3", dataset.path)
        return rng, brg, counts, ch.times()

    def decode(self, dataset, design: dict) -> RadarPlots:
        rng, brg, counts, times = self.decode_plots(dataset)
        truth = self.decode_truth(dataset)
        return RadarPlots(range_m=rng, bearing_rad=brg, counts=counts, times_s=times,
                          truth_state=None if truth is None else truth[0],
                          truth_target_id=None if truth is None else truth[1])

    def holds_many_targets(self, dataset) -> bool:
        truth = dataset.channels.get(TRUTH)
        return truth is not None and "target_id" in truth.arrays

    def decode_truth(self, dataset):
        """The truth as a set per scan, ``(state (R, K, T, 4), target_id (R, K, T))`` in
        identity-stable slots (:mod:`trackreplay.stages.truth_sets`), or None without truth.
        A file written before truth sets (one ``state`` per frame, no ``target_id``) holds one
        target, identity 0. Decoded and checked once per data set."""
        if "radar_truth" not in dataset.cache:
            dataset.cache["radar_truth"] = self._decode_truth(dataset)
        return dataset.cache["radar_truth"]

    def _decode_truth(self, dataset):
        truth = dataset.channels.get(TRUTH)
        if truth is None:
            return None
        plot_counts = self.decode_plots(dataset)[2]
        if truth.n_runs > plot_counts.shape[0] or truth.n_scans > plot_counts.shape[1]:
            raise InputError(f"{TRUTH} holds truth for {truth.n_runs} run(s) × {truth.n_scans} scan(s) but "
                             f"{PLOTS} only {plot_counts.shape[0]} × {plot_counts.shape[1]}", dataset.path)
        if "target_id" not in truth.arrays:
            state = truth.grid("state")
            if state.ndim != 3 or state.shape[-1] != 4:
                raise InputError(f"{TRUTH} state has shape {state.shape[2:]} per frame; a single target's truth "
                                 "is [x, y, vx, vy] (a set of targets also carries target_id)", dataset.path)
            state = _fit_runs_scans(state, plot_counts.shape)
            return single_target(state)
        state, counts = truth.ragged("state")
        ids, id_counts = truth.ragged("target_id")
        if state.ndim != 4 or state.shape[-1] != 4:
            raise InputError(f"{TRUTH} state rows have shape {state.shape[3:]}; each target's is [x, y, vx, vy]",
                             dataset.path)
        state, ids = identity_slots(state, ids, counts, TRUTH, dataset.path)
        return _fit_runs_scans(state, plot_counts.shape), _fit_runs_scans(ids, plot_counts.shape, -1)

    def evaluation_defaults_from_data(self, dataset, design: dict) -> dict:
        """The matching gate from the plots' noise at the targets' farthest range.

        A plot's position error has along-range σ_r and cross-range r σ_θ; the gate is the
        radius holding all but 10⁻⁴ of a two-dimensional Gaussian of the larger spread
        ``√(σ_r² + (r σ_θ)²)`` at the farthest true range, rounded up to two significant digits.
        A filter's position error is at most its plots' after the first update, so a gate this
        wide does not cut a well-modelled track off its target (a fixed 500 m did, at long range
        with a coarse bearing; docs/evaluation.md, "Evaluation design values"). The GOSPA cut-off
        c, its switch penalty and HOTA's distance scale are twice the gate, the SIAP gate the gate
        (the ratios of the fixed defaults). Without truth there is nothing to score: no change."""
        truth = self.decode_truth(dataset)
        sigma_range = design.get("sigma_range_m")
        if truth is None or sigma_range is None or design.get("sigma_bearing_deg") is None:
            return {}
        far = np.hypot(truth[0][..., 0], truth[0][..., 1])
        far = far[np.isfinite(far)]
        if far.size == 0:
            return {}
        spread = np.hypot(float(sigma_range), float(far.max()) * np.deg2rad(float(design["sigma_bearing_deg"])))
        gate = round_up(GATE_SIGMAS * spread)
        return {"assignment_gate_m": gate, "siap_gate_m": gate, "ospa_cutoff_m": 2.0 * gate,
                "hota_distance_m": 2.0 * gate, "gospa_switch_penalty_m": 2.0 * gate}

    # HOTA's distance scale d₀ and GOSPA's switch penalty γ default to the cut-off c, the SIAP
    # gate to the assignment gate
    declared_scopes = tuple(radar_eval.SCOPES)
    evaluation_defaults = {"ospa_cutoff_m": 1000.0, "ospa_order": 2.0, "assignment_gate_m": 500.0,
                           "hota_distance_m": 1000.0, "gospa_switch_penalty_m": 1000.0, "siap_gate_m": 500.0}
    report_metrics = ("rmse_position_m", "rmse_velocity_mps", "npe", "alpha_cross")
    report_lines = {"npe": [1.0]}  # NPE ≥ 1: no better than the raw plots

    def figures(self, per_scan, out_dir, title: str = "", result: dict | None = None, dataset=None) -> list:
        """``report.png``: the errors per scan (with truth), else the α cross-range per scan; and
        ``tracks.png``: run 0 in the plane, every plot, the truth and each tracker's track."""
        from trackreplay.evaluators.stage_figures import plane_tracks_figure

        paths = super().figures(per_scan, out_dir, title)
        if result is not None and dataset is not None:
            rng, brg, counts, _ = self.decode_plots(dataset)
            have = np.arange(rng.shape[2])[None, :] < counts[0][:, None]
            truth = self.decode_truth(dataset)
            paths.append(plane_tracks_figure(result, out_dir, polar_to_cartesian(rng[0][have], brg[0][have]),
                                             None if truth is None else truth[0][0, :, :, :2], counts.shape[0], title))
        return paths

    def reference(self, dataset, design: dict) -> dict:
        rng, brg, counts, times = self.decode_plots(dataset)
        first = np.where(counts > 0, 0, -1)
        measured = polar_to_cartesian(rng[..., 0], brg[..., 0]) if rng.shape[2] else np.full(counts.shape + (2,), np.nan)
        measured[first < 0] = np.nan
        truth = self.decode_truth(dataset)
        runs, fixed = {"measured": measured}, {}
        if truth is not None:
            runs["truth_set"], runs["truth_ids"] = truth
        # the paper's measures follow one target through every scan: a single-target file only
        if truth is not None and truth[0].shape[2] == 1 and (truth[1] == 0).all():
            truth_state = truth[0][:, :, 0]
            require_finite(f"{TRUTH} state", truth_state, dataset.path)
            runs["truth_state"] = truth_state
            if design.get("sigma_bearing_deg") is not None:  # unknown on a recording that does not say it
                runs["cross_std"] = (np.hypot(truth_state[..., 0], truth_state[..., 1])
                                     * np.deg2rad(design["sigma_bearing_deg"]))
            recorded = dataset.scenario.get("params", {})
            if model_recorded(dataset) and all(k in recorded for k in ("truth_process_noise_mps2", "sigma_range_m")):
                # the bound needs the truth's own noise, which only a simulation records
                fixed["pcrb"] = radar_pcrb(truth_state, times, float(recorded["truth_process_noise_mps2"]),
                                           float(recorded["sigma_range_m"]),
                                           float(np.deg2rad(float(recorded.get("sigma_bearing_deg", design["sigma_bearing_deg"])))),
                                           counts > 0)
        return {"runs": runs, "fixed": fixed}

    def score(self, reference: dict, result: dict, design: dict):
        return self.score_groups(reference, result, design, None, False)

    def score_groups(self, reference: dict, result: dict, design: dict, groups, left_out: bool):
        # every radar metric is a function of per-scan sums over runs: the groups come from one pass
        runs, fixed = reference["runs"], reference.get("fixed", {})
        pcrb = fixed.get("pcrb")
        # the paper's measures score one track per run; multi-slot trackers get the standard ones
        one_track = {name: out for name, out in result["tracks"].items() if np.ndim(out.get("state")) == 3}
        if not one_track:
            return _no_family_scores(groups)
        return radar_eval.evaluate(result["times"], one_track, runs["measured"], runs.get("truth_state"),
                                   runs.get("cross_std"), design["nominal_cross_range_m"],
                                   None if pcrb is None else pcrb[:, 0, 0] + pcrb[:, 1, 1], groups=groups,
                                   left_out=left_out, records=groups is not None)

    def standard_space(self, design: dict, reference: dict | None = None):
        return position_space(design, truth_components=(0, 1, 2, 3), position_components=(0, 1))

    def standard_truth(self, reference: dict):
        return reference["runs"].get("truth_set")

    def standard_truth_ids(self, reference: dict):
        return reference["runs"].get("truth_ids")


def _fit_runs_scans(a, shape, fill=np.nan):
    """``a`` (R', K', ...) padded with ``fill`` to the plots' ``(R, K)`` (truth may stop early)."""
    if a.shape[:2] == tuple(shape):
        return a
    out = np.full(tuple(shape) + a.shape[2:], fill, dtype=a.dtype)
    out[:a.shape[0], :a.shape[1]] = a
    return out


def _no_family_scores(groups):
    """The paper's tables with no tracker in them (every tracker of the unit keeps track slots)."""
    import polars as pl

    per_scan = pl.DataFrame(schema={"tracker": pl.String, "scan": pl.Int64, "time_s": pl.Float64})
    summary = pl.DataFrame(schema={"tracker": pl.String, "metric": pl.String, "scope": pl.String,
                                   "value": pl.Float64})
    return (per_scan, summary) if groups is None else (per_scan, summary, [summary] * groups)
