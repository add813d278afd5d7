"""Stage: TWS radar plots → four trackers (fixed / approximate / exact α-β, Kalman).

Input channels: ``/radar/plots`` (``range_m``, ``bearing_rad`` per run and scan), optionally
``/radar/truth`` (``state``). Output: ``/tracks/radar/<tracker>`` with ``state``,
``covariance``, ``alpha``, ``beta`` (along-range, cross-range), ``lambda_cross``,
``innovation`` and ``flags`` per run and scan. Only decoding and bookkeeping live here; the numbers
come from :mod:`pipeline.trackers.radar_tws` and :mod:`evaluators.radar_tws`, the Rerun views from
:mod:`pipeline.face.rerun_radar_tws`.
"""

from __future__ import annotations

import numpy as np

from evaluators import radar_tws as radar_eval
from pipeline.cores.filters.converted_measurements import polar_to_cartesian
from pipeline import vocabulary as vocab
from pipeline.trackers.interface import RadarPlots
from pipeline.errors import InputError, require_finite
from pipeline.stages.base import Stage
from pipeline.trackers.radar_tws import radar_pcrb
from evaluators.standard import position_space

PLOTS = vocab.CHANNELS["radar_plots"]
TRUTH = vocab.CHANNELS["radar_truth"]
XY = "/xy/world"  # under the x/y view's origin, flipped north-up (see timeline.north_up)


class RadarTwsStage(Stage):
    name = "radar-tws"
    family = "radar-plots"
    scenario = "radar-tws"
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
        # finite values and ranges ≥ 0 are the contract's checks at read time (pipeline.vocabulary.VALUES)
        if ch.n_scans < 3:
            raise InputError(f"{PLOTS} has {ch.n_scans} scan(s); a track needs at least 3", dataset.path)
        return rng, brg, counts, ch.times()

    def decode(self, dataset, design: dict) -> RadarPlots:
        rng, brg, counts, times = self.decode_plots(dataset)
        truth = dataset.channels.get(TRUTH)
        return RadarPlots(range_m=rng, bearing_rad=brg, counts=counts, times_s=times,
                          truth_state=truth.grid("state") if truth is not None else None)

    evaluation_defaults = {"ospa_cutoff_m": 1000.0, "ospa_order": 2.0, "assignment_gate_m": 500.0}
    report_metrics = ("rmse_position_m", "rmse_velocity_mps", "npe", "alpha_cross")
    report_lines = {"npe": [1.0]}  # NPE ≥ 1: no better than the raw plots

    def figures(self, per_scan, out_dir, title: str = "", result: dict | None = None, dataset=None) -> list:
        """``report.png``: the errors per scan (with truth), else the α cross-range per scan; and
        ``tracks.png``: run 0 in the plane, every plot, the truth and each tracker's track."""
        from pathlib import Path

        from evaluators.report_plots import plot_tracks_xy

        paths = super().figures(per_scan, out_dir, title)
        if result is not None and dataset is not None:
            rng, brg, counts, _ = self.decode_plots(dataset)
            have = np.arange(rng.shape[2])[None, :] < counts[0][:, None]
            measured = polar_to_cartesian(rng[0][have], brg[0][have])
            truth = dataset.channels.get(TRUTH)
            tracks = {name: np.where(((np.asarray(out["flags"])[0] & (vocab.NO_TRACK | vocab.DELETED)) > 0)[:, None],
                                     np.nan, np.asarray(out["state"], float)[0, :, :2])
                      for name, out in result["tracks"].items() if "state" in out and "flags" in out}
            paths.append(plot_tracks_xy(tracks, Path(out_dir) / "tracks.png", measured,
                                        None if truth is None else truth.grid("state")[0, :, :2],
                                        title=f"{title}: run 0" if title else "run 0"))
        return paths

    def reference(self, dataset, design: dict) -> dict:
        rng, brg, counts, times = self.decode_plots(dataset)
        first = np.where(counts > 0, 0, -1)
        measured = polar_to_cartesian(rng[..., 0], brg[..., 0]) if rng.shape[2] else np.full(counts.shape + (2,), np.nan)
        measured[first < 0] = np.nan
        truth = dataset.channels.get(TRUTH)
        runs, fixed = {"measured": measured}, {}
        if truth is not None:
            truth_state = truth.grid("state")
            if truth_state.shape[:2] != counts.shape:
                raise InputError(f"{TRUTH} covers {truth_state.shape[:2]} run×scan, plots {counts.shape}", dataset.path)
            require_finite(f"{TRUTH} state", truth_state, dataset.path)
            runs["truth_state"] = truth_state
            runs["cross_std"] = np.hypot(truth_state[..., 0], truth_state[..., 1]) * np.deg2rad(design["sigma_bearing_deg"])
            recorded = dataset.scenario.get("params", {})
            if all(k in recorded for k in ("truth_process_noise_mps2", "sigma_range_m")):
                # the bound needs the truth's own noise, which only a simulated file records
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
        return radar_eval.evaluate(result["times"], result["tracks"], runs["measured"], runs.get("truth_state"),
                                   runs.get("cross_std"), design["nominal_cross_range_m"],
                                   None if pcrb is None else pcrb[:, 0, 0] + pcrb[:, 1, 1], groups=groups,
                                   left_out=left_out)

    def standard_space(self, design: dict, reference: dict | None = None):
        return position_space(design, truth_components=(0, 1, 2, 3), position_components=(0, 1))

    def standard_truth(self, reference: dict):
        return reference["runs"].get("truth_state")
