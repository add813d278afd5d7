"""Rerun views of the xcorr replay (Park, Ryu & Lee 1994; ``docs/papers/xcorr.md``):
a bearing–time record of one run (peaks coloured by amplitude, truth, every tracker's tracks and
gates), the association weights and amplitude estimates of the trackers that report them, and the
error series.

Exposes ``blueprint(stage, trackers, dataset=None, run=0)`` and
``log_rerun(stage, rec, dataset, result, per_scan, run=0)`` (see :mod:`trackreplay.face.rerun_views`).
A plugged tracker gets the same views; panels for extras it does not output (β, ẑ_a, gate
centre) are simply empty for it.
"""

from __future__ import annotations

import numpy as np
# imported with the module, not when the peaks are drawn: the recording process imports these
# views while the replay runs on the other core (face/recording_process.py)
from matplotlib import colormaps

from trackreplay.face.timeline import color, log_metric_series, log_points, log_series, rr, rrb

AMPLITUDE_COLOR_MAX = 30000.0  # the paper's amplitude range 0 … 30,000
TRACKER_COLORS = {"jpda": (66, 146, 235), "jpda_a": (255, 140, 30)}
TRACK_COLORS = [(120, 200, 255), (255, 110, 110), (140, 230, 140), (230, 200, 90)]


def time_unit_s(duration_s: float, span_deg: float) -> float:
    """Seconds per vertical unit of the bearing–time view, so that it is about as tall as wide."""
    for unit in (1, 2, 5, 10, 20, 50, 100, 200, 500, 1000):
        if duration_s / unit <= 1.5 * span_deg:
            return float(unit)
    return 1000.0


def _field_deg(peaks) -> tuple[float, float]:
    return tuple(float(v) for v in np.rad2deg(peaks.field_rad))


def blueprint(stage, trackers, dataset=None, run: int = 0):
    """Bearing–time record of one run (bearing across, time down, as a sonar BTR) | association
    weights β₀ and the heaviest β per track | amplitudes ẑ_a and errors."""
    bounds, unit = None, 1.0
    if dataset is not None:
        peaks = stage.decode(dataset)
        lo, hi = _field_deg(peaks)
        t = np.asarray(peaks.times_s, float)
        unit = time_unit_s(float(np.nanmax(t) - np.nanmin(t)), hi - lo)
        bounds = rrb.VisualBounds2D(x_range=[lo, hi],
                                    y_range=[float(np.nanmin(t)) / unit - 1, float(np.nanmax(t)) / unit + 1])
    shown = rrb.PlotLegend(corner=rrb.Corner2D.RightTop, visible=True)
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial2DView(origin="/btr", visual_bounds=bounds,
                              name=f"run {run}: bearing (°) across, time down (1 unit = {unit:g} s); "
                                   "peaks coloured by amplitude"),
            rrb.Vertical(*[rrb.TimeSeriesView(origin=f"/beta/{t}", name=f"β {t}: β₀ and max β_j per track",
                                              plot_legend=shown) for t in trackers]),
            rrb.Vertical(
                rrb.TimeSeriesView(origin="/strength", name="ẑ_a used per track", plot_legend=shown),
                rrb.TimeSeriesView(origin="/errors/rmse_bearing_deg", name="bearing RMSE (°)", plot_legend=shown),
                rrb.TimeSeriesView(origin="/errors/on_own_target_fraction", name="on own target", plot_legend=shown),
            ),
            column_shares=[2, 1.2, 1.2],
        ),
        rrb.TimePanel(state="collapsed"),
        collapse_panels=True,
    )


def _log_peaks(rec, peaks, run: int, scans, times, ys) -> None:
    counts = peaks.counts[run]
    valid = np.arange(peaks.bearing_rad.shape[2])[None, :] < counts[:, None]
    scan_of = np.broadcast_to(scans[:, None], valid.shape)[valid]
    xy = np.stack([np.rad2deg(peaks.bearing_rad[run][valid]), ys[scan_of]], axis=1)
    amp = peaks.amplitude[run][valid]
    rgb = (colormaps["viridis"](np.clip(amp / AMPLITUDE_COLOR_MAX, 0, 1))[:, :3] * 255).astype(np.uint8)
    rec.log("/btr/peaks", rr.Points2D(xy, colors=rgb, radii=[-2.5]), static=True)
    by_scan = np.split(xy, np.cumsum(counts)[:-1])
    log_points(rec, "/btr/current_peaks", scans, times, by_scan, (255, 255, 255), radius=-4.5)
    if peaks.truth_bearing_rad is not None:
        truth = peaks.truth_bearing_rad
        strips = [np.stack([np.rad2deg(truth[run, :, t]), ys], 1) for t in range(truth.shape[2])]
        rec.log("/btr/truth", rr.LineStrips2D(strips, colors=[(235, 235, 235)], radii=[-1.0]), static=True)


def log_rerun(stage, rec, dataset, result: dict, per_scan, run: int = 0) -> None:
    """Bearing–time record of one run: all peaks (viridis by amplitude, 0 … 30,000), truth
    (white), each tracker's tracks with their gate edges where it reports a gate centre; β₀, the
    largest β_j per track and the amplitudes ẑ_a on the timeline where reported."""
    from trackreplay import design_values

    times = np.asarray(result["times"], float)
    scans = np.arange(len(times))
    peaks = stage.decode(dataset)
    run = min(run, peaks.bearing_rad.shape[0] - 1)
    lo, hi = _field_deg(peaks)
    ys = times / time_unit_s(float(np.nanmax(times) - np.nanmin(times)), hi - lo)
    _log_peaks(rec, peaks, run, scans, times, ys)
    half = float(design_values.resolve(stage, dataset)["gate_deg"]) / 2
    for name, out in result["tracks"].items():
        if out["state"].ndim != 4:
            continue  # not a (runs, scans, tracks, state) tracker output
        c = TRACKER_COLORS.get(name, color(name))
        T = out["state"].shape[2]
        est = np.rad2deg(out["state"][run, :, :, 0])
        strips = [np.stack([est[np.isfinite(est[:, t]), t], ys[np.isfinite(est[:, t])]], 1) for t in range(T)]
        rec.log(f"/btr/tracks/{name}", rr.LineStrips2D(strips, colors=[c], radii=[-2.5]), static=True)
        if "gate_center" in out:
            gate = np.rad2deg(out["gate_center"][run])
            edges = []
            for t in range(T):
                g = np.isfinite(gate[:, t])
                edges += [np.stack([gate[g, t] - half, ys[g]], 1), np.stack([gate[g, t] + half, ys[g]], 1)]
            rec.log(f"/btr/gates/{name}", rr.LineStrips2D(edges, colors=[(*c, 70)], radii=[-0.75]), static=True)
        log_points(rec, f"/btr/estimate/{name}", scans, times,
                   [np.stack([est[k][np.isfinite(est[k])], np.full(np.isfinite(est[k]).sum(), ys[k])], 1)
                    for k in scans], c, radius=-6.0)
        for t in range(T):
            tc = TRACK_COLORS[t % len(TRACK_COLORS)]
            dim = tuple(v // 2 for v in tc)
            if "beta0" in out:
                log_series(rec, f"/beta/{name}/track{t}/beta0", scans, times, out["beta0"][run, :, t], f"β₀ track {t}", dim)
            if "beta_top" in out:
                log_series(rec, f"/beta/{name}/track{t}/beta_max", scans, times, out["beta_top"][run, :, t, 0],
                           f"max β_j track {t}", tc)
            if "strength" in out:
                log_series(rec, f"/strength/{name}/track{t}", scans, times, out["strength"][run, :, t],
                           f"{name} track {t}", tc if name == "jpda_a" else dim)
        log_metric_series(rec, per_scan, name, ("rmse_bearing_deg", "on_own_target_fraction"),
                          lambda m: f"/errors/{m}", c)
