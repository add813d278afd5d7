"""Rerun views of the array bearing replay (Ryu, Lee & Lee 2001; ``docs/papers/array.md``):
for one run the MUSIC bearing–time waterfall with the truth and every tracker's tracks over it,
the angular innovation δθ, the angle gain and PAST's subspace error; the angle MSE over runs.

Exposes ``blueprint(stage, trackers, dataset=None, run=0)`` and
``log_rerun(stage, rec, dataset, result, per_scan, run=0)`` (see :mod:`trackreplay.face.rerun_views`).
"""

from __future__ import annotations

import numpy as np
# imported with the module (0.1 s), not when the waterfall is drawn: the recording process
# imports these views while the replay runs on the other core (face/recording_process.py)
from matplotlib import colormaps

from trackreplay import vocabulary as vocab
from trackreplay.face.timeline import color, log_metric_series, log_series, rr, rrb
from trackreplay.trackers.array import STARTUP_SCANS, music_waterfall

# both trackers give the same tracks to rounding: Ryu drawn wide underneath, proposed thin on top
STYLE = {"ryu": ((214, 39, 40), -3.5, 10.0), "proposed": ((255, 80, 255), -1.5, 20.0)}


def _target_color(n: int):
    return tuple(int(255 * c) for c in colormaps["tab10"](n % 10)[:3])


def _viridis(values: np.ndarray) -> np.ndarray:
    return (colormaps["viridis"](values)[..., :3] * 255).astype(np.uint8)


def _n_tracks(out: dict, run: int) -> int:
    """Tracks of ``run``: the tracker's ``n_tracks``, else the slots holding a track after start-up."""
    if "n_tracks" in out:
        return int(out["n_tracks"][run, 0])
    flags = np.asarray(out["flags"][run, min(STARTUP_SCANS - 1, out["flags"].shape[1] - 1)], vocab.FLAG_DTYPE)
    return int(np.sum((flags & vocab.NO_TRACK) == 0))


def _grid_step_rad(stage, dataset) -> float:
    from trackreplay import design_values

    design = design_values.resolve(stage, dataset)
    if "music_grid_step_deg" not in design:  # only plugged trackers ran: the built-ins' default
        design = design_values.resolve(stage, dataset, entries=stage.entries())
    return float(np.deg2rad(float(design["music_grid_step_deg"])))


def blueprint(stage, trackers, dataset=None, run: int = 0):
    """Layout: MUSIC waterfall of one run | innovation, gain, subspace error, MSE over time."""
    shown = rrb.PlotLegend(corner=rrb.Corner2D.RightTop, visible=True)
    hidden = rrb.PlotLegend(visible=False)
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial2DView(origin="/waterfall", name=f"MUSIC bearing–time waterfall (run {run})"),
            rrb.Vertical(
                rrb.TimeSeriesView(origin="/innovation", name="angular innovation δθ (deg)", plot_legend=shown),
                rrb.TimeSeriesView(origin="/gain", name="Kalman gain (angle)", plot_legend=hidden),
                rrb.TimeSeriesView(origin="/subspace", name="PAST vs batch EVD: largest principal angle (deg)",
                                   plot_legend=hidden),
                rrb.TimeSeriesView(origin="/errors", name="angle MSE over runs (deg²)", plot_legend=shown),
            ),
            column_shares=[1.6, 1.2],
        ),
        rrb.TimePanel(state="collapsed"),
        collapse_panels=True,
    )


def log_rerun(stage, rec, dataset, result: dict, per_scan, run: int = 0) -> None:
    from trackreplay import design_values

    times = result["times"]
    scans = np.arange(len(times))
    X = stage.snapshots(dataset)
    run = min(run, X.shape[0] - 1)
    design = design_values.resolve(stage, dataset)
    tracks = result["tracks"]
    n_run = max((_n_tracks(out, run) for out in tracks.values()), default=0)
    truth, _ = stage.truth(dataset, X.shape[:2])
    grid, spectrum = music_waterfall(X[run], max(n_run, 1), float(design["spacing_wavelengths"]),
                                     _grid_step_rad(stage, dataset))
    _log_waterfall(rec, grid, spectrum, truth[run] if truth is not None else None,
                   {name: np.asarray(out["state"][run], float)[..., 0] for name, out in tracks.items()})
    for name, out in tracks.items():
        for n in range(min(_n_tracks(out, run), out["state"].shape[2])):
            if "innovation" in out:
                log_series(rec, f"/innovation/{name}/target{n}", scans, times,
                           np.rad2deg(out["innovation"][run, :, n, 0]), f"{name} {n}", _target_color(n))
            if "gain" in out:
                log_series(rec, f"/gain/{name}/target{n}", scans, times, out["gain"][run, :, n, 0, 0], f"{name} {n}",
                           _target_color(n))
        log_metric_series(rec, per_scan, name, ("mse_deg2",), lambda m: "/errors",
                          STYLE.get(name, (color(name),))[0])
    with_subspace = [out for out in tracks.values() if "subspace_error_rad" in out]
    if with_subspace:
        log_series(rec, "/subspace/past_vs_batch", scans, times, np.rad2deg(with_subspace[0]["subspace_error_rad"][run]),
                   "PAST vs EVD", (200, 200, 200))


def _log_waterfall(rec, grid, spectrum, truth, tracks, row_step_deg: float = 0.25) -> None:
    """MUSIC spectrum per scan as an image (x: scan, y: angle, top = largest angle), with the
    truth and every tracker's tracks drawn over it in the image's pixel coordinates."""
    grid_deg = np.rad2deg(grid)
    lines = [np.rad2deg(a) for a in ([truth] if truth is not None else []) + list(tracks.values())]
    finite = np.concatenate([v[np.isfinite(v)] for v in lines]) if lines else np.zeros(0)
    lo, hi = (finite.min() - 10, finite.max() + 10) if finite.size else (-90.0, 90.0)
    lo, hi = max(lo, -90.0), min(hi, 90.0)
    rows_deg = np.arange(hi, lo - 1e-9, -row_step_deg)
    K = spectrum.shape[0]
    db = 10 * np.log10(spectrum / spectrum.max(axis=1, keepdims=True))
    img = np.stack([np.interp(rows_deg, grid_deg, db[k]) for k in range(K)], axis=1)  # (rows, K)
    col = max(1, int(round(len(rows_deg) / max(K, 1))))
    img = np.repeat(img, col, axis=1)
    norm = np.clip((img + 30.0) / 30.0, 0, 1)  # 30 dB of dynamic range
    rec.log("/waterfall/music_db", rr.Image(_viridis(norm)), static=True)

    def to_px(theta_deg):
        x = (np.arange(len(theta_deg)) + 0.5) * col
        y = (hi - theta_deg) / row_step_deg
        return np.stack([x, y], axis=-1)

    if truth is not None:
        t = np.rad2deg(truth)
        rec.log("/waterfall/truth", rr.LineStrips2D([to_px(t[:, n]) for n in range(t.shape[1])],
                                                    colors=[(255, 255, 255)], radii=[-0.75],
                                                    draw_order=30.0), static=True)
    for name, est in tracks.items():
        e = np.rad2deg(est)
        strips = []
        for n in range(e.shape[1]):
            p = to_px(e[:, n])
            p = p[np.all(np.isfinite(p), axis=1)]
            if len(p) > 1:
                strips.append(p)
        rgb, width, order = STYLE.get(name, (color(name), -1.0, 15.0))
        if strips:
            rec.log(f"/waterfall/tracks/{name}", rr.LineStrips2D(strips, colors=[rgb], radii=[width], draw_order=order),
                    static=True)
    ticks = np.arange(np.ceil(lo / 10) * 10, hi + 1e-9, 10.0)
    rec.log("/waterfall/angle_ticks", rr.Points2D(np.stack([np.zeros_like(ticks), (hi - ticks) / row_step_deg], axis=-1),
                                                  labels=[f"{t:+.0f}°" for t in ticks], radii=[-2.0],
                                                  colors=[(255, 255, 255)], show_labels=True), static=True)
