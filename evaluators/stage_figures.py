"""The report figures of a replay, drawn from the trackers' outputs and what a stage decoded.

A stage (:meth:`trackreplay.stages.base.Stage.figures`) decodes what its figures show of the data
set (plots, peaks, truth, sensors) and hands the arrays here; everything drawn from the outputs
(which tracks are shown, in which units, against what) is done here, so that stages stay thin
(``docs/architecture.md``) and these functions read plain arrays, no stage. The drawing itself is
:mod:`trackreplay.evaluators.report_plots`'s. Radians inside; degrees only on the figures' axes.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from trackreplay import vocabulary as vocab


def _drawn(result: dict) -> dict:
    """``{tracker: outputs}`` of ``result`` that are tracks (a state and flags), not extras."""
    return {name: out for name, out in result["tracks"].items() if "state" in out and "flags" in out}


def per_scan_figure(per_scan, path, metrics, title: str = "", hlines: dict | None = None):
    """``metrics`` per scan against time, one panel each (those the table has), or None."""
    import polars as pl

    from trackreplay.evaluators.report_plots import plot_metrics_vs

    metrics = [m for m in metrics if m in per_scan.columns and per_scan[m].drop_nulls().len()]
    if not metrics:
        return None
    part = per_scan.filter(pl.col(metrics[0]).is_not_null())
    return plot_metrics_vs(part, "time_s", metrics, path, title=title, hlines=hlines or {})


def metrics_report(per_scan, out_dir, metrics, title: str = "", hlines: dict | None = None) -> list:
    """``report.png``: ``metrics`` per scan against time (:func:`per_scan_figure`), every tracker
    distinguishable; ``[]`` when the table has none of them."""
    path = per_scan_figure(per_scan, Path(out_dir) / "report.png", metrics, title, hlines)
    return [] if path is None else [path]


def bearing_time_record(result: dict, out_dir, title: str = "", truth_rad=None, peaks=None, field_deg=None,
                        run: int = 0) -> Path:
    """``report.png`` of a bearing family: run ``run``'s tracks of every tracker (state component
    0, radians) on a bearing–time record, with the truth ``(runs, scans, T)`` and the measured
    bearings ``(time_s, bearing_rad)`` where given; a scan without a track is a gap."""
    from trackreplay.evaluators.report_plots import plot_bearing_time

    drawn = _drawn(result)
    tracks = {name: np.rad2deg(np.asarray(out["state"], float)[run, ..., 0]) for name, out in drawn.items()}
    for name, bearings in tracks.items():
        bearings[(np.asarray(drawn[name]["flags"])[run] & (vocab.NO_TRACK | vocab.DELETED)) > 0] = np.nan
    truth = None if truth_rad is None else np.rad2deg(np.asarray(truth_rad, float)[run])
    measured = None if peaks is None else (peaks[0], np.rad2deg(peaks[1]))
    label = f"{title}: run {run}" if title else f"run {run}"
    return plot_bearing_time(result["times"], tracks, Path(out_dir) / "report.png", truth_deg=truth,
                             peaks=measured, field_deg=field_deg, title=f"{label}, bearing–time record")


def bearing_figures(per_scan, result: dict | None, out_dir, title: str, truth_rad, error_metrics, peaks=None,
                    field_deg=None) -> list:
    """A bearing family's figures: :func:`bearing_time_record` of run 0 (with ``result``) and
    ``errors.png``, ``error_metrics`` per scan (those the table has)."""
    paths = [] if result is None else [bearing_time_record(result, out_dir, title, truth_rad, peaks, field_deg)]
    errors = per_scan_figure(per_scan, Path(out_dir) / "errors.png", error_metrics, title)
    return paths + ([errors] if errors else [])


def plane_tracks_figure(result: dict, out_dir, measured_xy, truth_xy, n_runs: int, title: str = "") -> Path:
    """``tracks.png``: run 0 in the plane, every plot ``measured_xy`` (n, 2), the truth (scans,
    [T,] 2) and each tracker's confirmed track (a tentative one is a hypothesis, and clutter
    starts many)."""
    from trackreplay.evaluators.report_plots import plot_tracks_xy

    hidden = vocab.NO_TRACK | vocab.DELETED | vocab.INITIALISING
    tracks = {name: np.where(((np.asarray(out["flags"])[0] & hidden) > 0)[..., None],
                             np.nan, np.asarray(out["state"], float)[0, ..., :2])
              for name, out in _drawn(result).items()}
    truth = None if truth_xy is None else (truth_xy[:, 0] if truth_xy.shape[1] == 1 else truth_xy)
    return plot_tracks_xy(tracks, Path(out_dir) / "tracks.png", measured_xy, truth,
                          title=f"{title}: run 0 of {n_runs}" if title else f"run 0 of {n_runs}")


def positions_figure(result: dict, path, times, measured, truth_state, title: str, model_names) -> Path:
    """Run 0's position per axis against time (state ``[p, v, a]`` per axis): the measurements
    ``(scans, axes)``, the truth ``(scans, 3 axes)`` and every filter, with each IMM's model
    probabilities (outputs ``model_probabilities``)."""
    from trackreplay.evaluators.report_plots import plot_positions_time

    positions = {name: np.asarray(out["state"], float)[0, :, 0::3] for name, out in _drawn(result).items()}
    probabilities = {name: np.asarray(out["model_probabilities"], float)[0]
                     for name, out in result["tracks"].items() if "model_probabilities" in out}
    return plot_positions_time(times, positions, path, measured, None if truth_state is None else truth_state[:, 0::3],
                               title=f"{title}: run 0" if title else "run 0",
                               model_probabilities=probabilities, model_names=model_names)


def emitter_geometry_figure(result: dict, out_dir, sensor_position_m, sensor_velocity_mps, truth_state,
                            title: str = "", scan: int = 0) -> Path:
    """``report.png`` of the emitter family: the geometry of scan ``scan`` (sensors with their
    velocity, the emitter, every estimator's estimates over the runs with their median reported
    95 % ellipse, the joint CRLB's mean ellipse around the truth; Kim et al. 2013, eq. 18)."""
    from trackreplay.evaluators.report_plots import plot_emitter_geometry

    drawn = _drawn(result)
    estimates = {name: np.asarray(out["state"], float)[:, scan, :2] for name, out in drawn.items()}
    reported = {name: np.nanmedian(np.asarray(out["covariance"], float)[:, scan, :2, :2], axis=0)
                for name, out in drawn.items() if "covariance" in out
                and np.isfinite(np.asarray(out["covariance"], float)[:, scan, :2, :2]).all(axis=(1, 2)).any()}
    crlb = result["tracks"].get("crlb", {}).get("crlb_covariance_joint")
    bound = None
    if crlb is not None and truth_state is not None:
        block = np.asarray(crlb, float)[:, scan, :2, :2]
        bound = np.nanmean(block, axis=0) if np.isfinite(block).all(axis=(1, 2)).any() else None
    label = f"{title}, " if title else ""
    return plot_emitter_geometry(sensor_position_m[0, scan], sensor_velocity_mps[0, scan], Path(out_dir) / "report.png",
                                 truth_m=None if truth_state is None else truth_state[0, scan, :2],
                                 estimates=estimates, covariances=reported, bound_covariance=bound,
                                 title=f"{label}scan {scan}: {len(result['times'])} scan(s), "
                                       f"{next(iter(estimates.values())).shape[0]} runs")


def noise_study_figure(per_scan, out_dir, title: str = ""):
    """``fig7.png`` of a noise study (scans are noise levels ``sigma_range_m``): position RMSE and
    CRLB against the equivalent range noise (cf. Ho & Chan 1997, Fig. 7), or None with one level."""
    import polars as pl

    from trackreplay.evaluators.report_plots import plot_metrics_vs

    levels = per_scan["sigma_range_m"].unique().len() if "sigma_range_m" in per_scan.columns else 0
    if levels <= 1 or "rmse_position_m" not in per_scan.columns:
        return None
    series = [per_scan.select("sigma_range_m", pl.format("{} RMSE", "tracker").alias("series"),
                              pl.col("rmse_position_m").alias("position error (m)"))]
    if "crlb_position_m" in per_scan.columns:
        series.append(per_scan.select("sigma_range_m", pl.format("{} CRLB", "tracker").alias("series"),
                                      pl.col("crlb_position_m").alias("position error (m)")))
    table = pl.concat(series).drop_nulls()
    return plot_metrics_vs(table, "sigma_range_m", ["position error (m)"], Path(out_dir) / "fig7.png",
                           group="series", log_x=True, log_y=True,
                           title=f"{title}: position RMSE and CRLB against the range noise")
