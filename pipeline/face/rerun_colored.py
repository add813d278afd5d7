"""Rerun views of the coloured-noise replay (Kwon 1997; ``docs/papers/colored.md``):
RMSE over runs, each IMM's model probabilities, and for one run the AR(1) estimates, PIMM's SRIF
residual and the position error.

Exposes ``blueprint(stage, trackers, dataset=None, run=0)`` and
``log_rerun(stage, rec, dataset, result, per_scan, run=0)`` (see :mod:`trackreplay.face.rerun_views`).
"""

from __future__ import annotations

import numpy as np

from trackreplay.evaluators.colored import AR_TRACKER
from trackreplay.face.timeline import color, log_metric_series, log_series, rrb
from trackreplay.trackers.colored import MODEL_NAMES

COLORS = {"kf": (31, 119, 180), "kf_dp": (255, 127, 14), "imm": (44, 160, 44), "mimm_k": (214, 39, 40),
          "pimm": (148, 103, 189), "cv": (227, 119, 194), "ca_transition": (188, 189, 34), "ca_steady": (23, 190, 207)}
TRUTH_RGB = (230, 230, 230)


def _rgb(name: str):
    return COLORS.get(name) or color(name)


def _is_imm(out: dict) -> bool:
    mu = out.get("model_probabilities")
    return mu is not None and mu.shape[-1] == len(MODEL_NAMES)


def blueprint(stage, trackers, dataset=None, run: int = 0):
    """RMSE | model probabilities per IMM | AR estimates, SRIF residual, errors of one run."""
    shown = rrb.PlotLegend(corner=rrb.Corner2D.RightTop, visible=True)
    hidden = rrb.PlotLegend(visible=False)
    imms = [t for t in trackers if t in ("imm", "mimm_k", "pimm")]
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.TimeSeriesView(origin="/rmse/position_m", name="position RMSE (m)", plot_legend=shown),
                rrb.TimeSeriesView(origin="/rmse/velocity_mps", name="velocity RMSE (m/s)", plot_legend=hidden),
                rrb.TimeSeriesView(origin="/rmse/acceleration_mps2", name="acceleration RMSE (m/s²)", plot_legend=hidden),
            ),
            rrb.Vertical(*[rrb.TimeSeriesView(origin=f"/model_probability/{t}", name=f"{t}: model probabilities (run {run})",
                                              plot_legend=shown) for t in imms] or
                         [rrb.TextDocumentView(origin="/", name="no IMM")]),
            rrb.Vertical(
                rrb.TimeSeriesView(origin="/ar/alpha", name=f"AR coefficient (run {run}, axis 0)", plot_legend=shown),
                rrb.TimeSeriesView(origin="/ar/noise_variance", name=f"σ_η² (run {run}, axis 0)", plot_legend=shown),
                rrb.TimeSeriesView(origin="/srif/residual", name=f"PIMM SRIF residual ‖e‖ (run {run})", plot_legend=shown),
                rrb.TimeSeriesView(origin="/error/position_m", name=f"position error (run {run}, axis 0)", plot_legend=hidden),
            ),
            column_shares=[1.2, 1.0, 1.0],
        ),
        rrb.TimePanel(state="collapsed"),
        collapse_panels=True,
    )


def log_rerun(stage, rec, dataset, result: dict, per_scan, run: int = 0) -> None:
    from trackreplay import design_values

    times = result["times"]
    scans = np.arange(len(times))
    tracks = result["tracks"]
    z, _, truth, alpha = stage.decode_inputs(dataset)
    run = min(run, z.shape[0] - 1)
    for name, out in tracks.items():
        if name == AR_TRACKER:
            continue
        log_metric_series(rec, per_scan, name, ("rmse_position_m", "rmse_velocity_mps", "rmse_acceleration_mps2"),
                          lambda m: f"/rmse/{m.removeprefix('rmse_')}", _rgb(name))
        if truth is not None:
            log_series(rec, f"/error/position_m/{name}", scans, times, out["state"][run, :, 0] - truth[run, :, 0], name,
                       _rgb(name))
        if _is_imm(out):
            mu = out["model_probabilities"]
            for j, m in enumerate(MODEL_NAMES):
                log_series(rec, f"/model_probability/{name}/{m}", scans, times, mu[run, :, j], m, _rgb(m))
        if name == "pimm" and "nis" in out:
            for j, m in enumerate(MODEL_NAMES):
                log_series(rec, f"/srif/residual/{m}", scans, times, np.sqrt(out["nis"][run, :, j]), m, _rgb(m))
    ar = tracks.get(AR_TRACKER)
    if ar is not None:
        log_series(rec, "/ar/alpha/estimate", scans, times, ar["alpha"][run, :, 0], "α̂", (31, 119, 180))
        log_series(rec, "/ar/alpha/biased", scans, times, ar["alpha_biased"][run, :, 0], "α^b", (255, 127, 14))
        log_series(rec, "/ar/noise_variance/estimate", scans, times, ar["noise_variance"][run, :, 0], "σ̂_η²",
                   (31, 119, 180))
        if alpha is not None:
            log_series(rec, "/ar/alpha/truth", scans, times, alpha[run, :, 0], "truth", TRUTH_RGB)
            R = float(design_values.resolve(stage, dataset)["measurement_variance_m2"])
            log_series(rec, "/ar/noise_variance/truth", scans, times, (1 - alpha[run, :, 0] ** 2) * R, "truth",
                       TRUTH_RGB)
