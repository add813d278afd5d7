"""Rerun views of the radar TWS replay: x/y of one run, the gains and the errors over time."""

from __future__ import annotations

import numpy as np

from trackreplay.evaluators import radar as radar_eval
from trackreplay import vocabulary as vocab
from trackreplay.cores.filters.converted_measurements import polar_to_cartesian
from trackreplay.face.timeline import (color, log_identified, log_metric_series, log_path, log_points, log_series,
                                    north_up, north_up_bounds, rr, rrb)

TRUTH = vocab.CHANNELS["radar_truth"]
XY = "/xy/world"  # under the x/y view's origin, flipped north-up (see timeline.north_up)


def blueprint(stage, trackers, dataset=None, run: int = 0):
    """Layout: x/y of one run | gains | errors; the x/y view is fitted to that run's plots."""
    bounds = None
    if dataset is not None:
        rng, brg, counts, _ = stage.decode_plots(dataset)
        run = min(run, counts.shape[0] - 1)
        xy = polar_to_cartesian(rng[run], brg[run]).reshape(-1, 2)
        xy = xy[np.all(np.isfinite(xy), axis=1)]
        if len(xy):
            lo, hi = xy.min(axis=0), xy.max(axis=0)
            pad = 0.08 * float(max(hi - lo)) + 1.0
            bounds = north_up_bounds(lo, hi, pad)
    if dataset is not None and stage.holds_many_targets(dataset):
        # a scene of many targets: how many tracks and targets there are, and the set errors
        return _layout(f"x / y (run {run}): tracks by identity", bounds,
                       [("/counts/confirmed", "confirmed tracks"), ("/counts/tentative", "tentative tracks"),
                        ("/counts/targets", "true targets")],
                       [("/errors/gospa_m", "GOSPA (m), mean over runs"),
                        ("/errors/gospa_missed", "missed targets (GOSPA)"), ("/errors/gospa_false", "false tracks (GOSPA)")])
    return _layout(f"x / y (run {run})", bounds,
                   [("/gains/alpha_cross", "α cross-range"), ("/gains/beta_cross", "β cross-range"),
                    ("/gains/lambda_cross", "λ_k cross-range")],
                   [("/errors/rmse_position_m", "position RMSE (m)"), ("/errors/rmse_velocity_mps", "velocity RMSE (m/s)"),
                    ("/errors/npe", "NPE")])


def _layout(title: str, bounds, middle, right):
    """x/y | a column of time series | another; each column's first series shows the legend."""
    def column(series):
        return rrb.Vertical(*(rrb.TimeSeriesView(origin=origin, name=name, plot_legend=rrb.PlotLegend(
            corner=rrb.Corner2D.RightTop, visible=True) if i == 0 else rrb.PlotLegend(visible=False))
            for i, (origin, name) in enumerate(series)))

    return rrb.Blueprint(
        rrb.Horizontal(rrb.Spatial2DView(origin="/xy", name=title, visual_bounds=bounds), column(middle), column(right),
                       column_shares=[2, 1.2, 1.2]),
        rrb.TimePanel(state="collapsed"),
        collapse_panels=True,
    )


def log_rerun(stage, rec, dataset, result: dict, per_scan, run: int = 0) -> None:
    times = result["times"]
    scans = np.arange(len(times))
    rng, brg, counts, _ = stage.decode_plots(dataset)
    run = min(run, counts.shape[0] - 1)
    plots_xy = polar_to_cartesian(rng[run], brg[run])
    north_up(rec, XY)
    log_points(rec, f"{XY}/plots/current", scans, times,
               [plots_xy[k, : counts[run, k]] for k in scans], (250, 250, 250), radius=-4.0)
    history = plots_xy.reshape(-1, 2)
    history = history[np.all(np.isfinite(history), axis=1)]
    rec.log(f"{XY}/plots/all", rr.Points2D(history, colors=[color("plots")], radii=[-1.5]), static=True)
    truth = stage.decode_truth(dataset)
    many = truth is not None and not (truth[0].shape[2] == 1 and (truth[1] == 0).all())
    if truth is not None and not many:
        log_path(rec, f"{XY}/truth", truth[0][run, :, 0, :2], color("truth"))
    elif many:
        log_identified(rec, f"{XY}/truth", scans, times, truth[0][run, :, :, :2], truth[1][run], "target ",
                       radius=-2.5)
        log_series(rec, "/counts/targets", scans, times, (truth[1][run] >= 0).sum(axis=1), "true targets",
                   color("truth"))
    for name, out in result["tracks"].items():
        if np.ndim(out["state"]) == 4:  # track slots: every track in its identity's colour
            _log_slots(rec, name, out, run, scans, times)
            log_metric_series(rec, per_scan, name, ("gospa_m", "gospa_missed", "gospa_false"),
                              lambda m: f"/errors/{m}")
            continue
        ok = radar_eval.filtered_mask(out["flags"][run])
        xy = np.where(ok[:, None], out["state"][run, :, :2], np.nan)
        log_path(rec, f"{XY}/tracks/{name}/path", xy, color(name))
        log_points(rec, f"{XY}/tracks/{name}/estimate", scans, times,
                   [xy[k : k + 1] if ok[k] else np.zeros((0, 2)) for k in scans], color(name), radius=-5.0)
        if "alpha" in out and "beta" in out:  # the paper's gain diagnostics, where a tracker has them
            log_series(rec, f"/gains/alpha_cross/{name}", scans, times, out["alpha"][run, :, 1], name)
            log_series(rec, f"/gains/beta_cross/{name}", scans, times, out["beta"][run, :, 1], name)
            log_series(rec, f"/gains/alpha_along/{name}", scans, times, out["alpha"][run, :, 0], name)
        log_metric_series(rec, per_scan, name, ("rmse_position_m", "rmse_velocity_mps", "npe"),
                          lambda m: f"/errors/{m}")
    with_lambda = [out for out in result["tracks"].values() if "lambda_cross" in out]
    if with_lambda:
        log_series(rec, "/gains/lambda_cross/measured", scans, times, with_lambda[0]["lambda_cross"][run],
                   "λ_k", (200, 200, 200))


def _log_slots(rec, name: str, out: dict, run: int, scans, times) -> None:
    """A multi-slot tracker's run: confirmed tracks labelled by identity, tentative ones as small
    points, and the counts of confirmed and tentative tracks per scan."""
    flags = np.asarray(out["flags"][run]).astype(np.int64)
    state = np.asarray(out["state"][run], float)
    ids = np.asarray(out["track_id"][run]) if "track_id" in out else np.where(
        np.isfinite(state).all(axis=-1), np.arange(state.shape[1]), -1)
    exists = (flags & (vocab.NO_TRACK | vocab.DELETED)) == 0
    tentative = exists & ((flags & vocab.INITIALISING) > 0)
    confirmed = exists & ~tentative
    # identities on hover: fifty targets' labels from three trackers would hide the scene (the
    # truth's labels stay shown)
    log_identified(rec, f"{XY}/tracks/{name}", scans, times, state[..., :2], np.where(confirmed, ids, -1),
                   f"{name} ", show_labels=False)
    log_points(rec, f"{XY}/tracks/{name}/tentative", scans, times,
               [state[k, tentative[k], :2] for k in range(len(scans))], color(name), radius=-2.0)
    log_series(rec, f"/counts/confirmed/{name}", scans, times, confirmed.sum(axis=1), f"{name} confirmed")
    log_series(rec, f"/counts/tentative/{name}", scans, times, tentative.sum(axis=1), f"{name} tentative")
