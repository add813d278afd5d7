"""Stage: positions with AR(1) coloured noise → AR estimator, KF, KF_DP, IMM, MIMM_K, PIMM.

Input channels: ``/colored/measurements`` (``position_m`` per axis) and ``/colored/truth``
(``state`` = [p, v, a] per axis, ``alpha``; the thesis starts every filter at the true state).
Outputs on ``/tracks/colored/<tracker>``: ``state``, ``covariance``, ``model_probabilities``,
``log_likelihood``, ``nis`` (per model; for the SRIF models it is ``‖e_k‖²``, the squared SRIF
residual) and ``flags``; ``/tracks/colored/ar_estimator`` holds ``alpha``, ``alpha_biased``,
``noise_variance``, ``warm`` and ``flags`` per axis.

Trackers (spec ``shared/spec/colored-noise-imm-srif.md``; thesis ch. V):

``kf``      one CA model (Ψ = [T²/2, T, 1]), plain measurements (ignores the colour);
``kf_dp``   the same model with the decorrelation process and the AR estimator;
``imm``     CV + CA (transition) + CA (steady), Kalman filters, plain measurements;
``mimm_k``  the same models, Kalman filters, decorrelation + AR estimator;
``pimm``    the same models, square-root information filters, decorrelation + AR estimator.

Flags (decorrelating trackers): the AR estimator's bits (1 discriminant clamped, 2 α̂ limited,
4 σ_η² floored, any axis) and 8 = estimator not warm yet, plain measurement used.
Only I/O and bookkeeping live here: the numbers come from :mod:`pipeline.cores.filters.ar1_estimation`,
:mod:`pipeline.cores.filters.imm` (with :mod:`pipeline.cores.filters.kalman`, :mod:`pipeline.cores.filters.srif`,
:mod:`pipeline.cores.filters.decorrelation`) and :mod:`evaluators.colored_noise_imm`.
"""

from __future__ import annotations

import numpy as np

from evaluators import colored_noise_imm as colored_eval
from pipeline.cores.filters.ar1_estimation import estimate_ar1
from pipeline.errors import InputError, require_finite
from pipeline.cores.filters.imm import MeasurementStream, ModelFilter, check_transition, imm_filter, kinematic_model, single_model_filter
from pipeline.stages.base import Stage
from pipeline.face.timeline import color, log_series, rrb, log_metric_series

MEASUREMENTS = "/colored/measurements"
TRUTH = "/colored/truth"
MODEL_NAMES = ["cv", "ca_transition", "ca_steady"]
FLAG_NOT_WARM = 8
COLORS = {"kf": (31, 119, 180), "kf_dp": (255, 127, 14), "imm": (44, 160, 44), "mimm_k": (214, 39, 40),
          "pimm": (148, 103, 189), "cv": (227, 119, 194), "ca_transition": (188, 189, 34), "ca_steady": (23, 190, 207)}
# tracker -> (model set, filter kind, decorrelate)
TRACKERS = {"kf": ("single", "kf", False), "kf_dp": ("single", "kf", True), "imm": ("imm", "kf", False),
            "mimm_k": ("imm", "kf", True), "pimm": ("imm", "srif", True)}


def _rgb(name: str):
    return COLORS.get(name) or color(name)


def parse_matrix(text: str, name: str) -> np.ndarray:
    """``"0.99 0.01; 0.3 0.7"`` → 2-D array (rows separated by ``;``)."""
    try:
        rows = [[float(v) for v in row.replace(",", " ").split()] for row in str(text).split(";") if row.strip()]
        return np.array(rows, dtype=float)
    except ValueError:
        raise InputError(f"parameter {name!r}: cannot read {text!r} as rows of numbers separated by ';'") from None


class ColoredNoiseImmStage(Stage):
    name = "colored-noise-imm"
    input_topics = (MEASUREMENTS,)
    trackers = tuple(TRACKERS)
    output_prefix = "/tracks/colored/"
    scenario = "colored-imm"
    design_keys = ("measurement_variance_m2", "ar_forgetting_factor", "ar_zero_pole", "initial_variance",
                   "cv_process_noise", "ca_transition_process_noise", "ca_steady_process_noise",
                   "imm_transition", "kf_process_noise")

    # ------------------------------------------------------------------ inputs

    def _inputs(self, dataset):
        ch = dataset.channel(MEASUREMENTS)
        ch.require_every_frame()
        z = ch.grid("position_m")
        if z.ndim == 2:
            z = z[..., None]
        if z.ndim != 3:
            raise InputError(f"{MEASUREMENTS} position_m must be a number or one value per axis in every frame, "
                             f"got frames of shape {z.shape[2:]}", dataset.path)
        require_finite(f"{MEASUREMENTS} position_m", z, dataset.path)
        times = ch.times()
        if z.shape[1] < 4:
            raise InputError(f"{MEASUREMENTS} has {z.shape[1]} scan(s); the AR estimator needs at least 4", dataset.path)
        dt = np.diff(times)
        if not np.all(np.abs(dt - dt[0]) <= 1e-9 * max(abs(dt[0]), 1.0)) or dt[0] <= 0:
            raise InputError(f"{MEASUREMENTS} scans are not evenly spaced in time", dataset.path)
        truth = dataset.channels.get(TRUTH)
        if truth is None:
            raise InputError(f"missing channel {TRUTH!r}: the filters start at the true state (thesis ch. V)", dataset.path)
        # a missing truth frame would start or score its run from NaN, silently
        truth.require_every_frame(*z.shape[:2])
        state = truth.grid("state")
        alpha = truth.grid("alpha") if "alpha" in truth.arrays else None
        if state.shape[:2] != z.shape[:2] or state.ndim != 3 or state.shape[-1] != 3 * z.shape[-1]:
            raise InputError(f"{TRUTH} state {state.shape} does not match the measurements {z.shape}", dataset.path)
        require_finite(f"{TRUTH} state", state, dataset.path)
        if alpha is not None:
            if alpha.ndim == 2:
                alpha = alpha[..., None]
            if alpha.shape != z.shape:
                raise InputError(f"{TRUTH} alpha {alpha.shape} does not match the measurements {z.shape}", dataset.path)
            require_finite(f"{TRUTH} alpha", alpha, dataset.path)
        return z, times, float(dt[0]), state, alpha

    def _design_arrays(self, design, T, axes):
        R = float(design["measurement_variance_m2"])
        if not R > 0:
            raise InputError(f"measurement_variance_m2 must be > 0 (R positive definite), got {R}")
        if not design["initial_variance"] > 0:
            raise InputError("initial_variance must be > 0")
        for key in ("cv_process_noise", "ca_transition_process_noise", "ca_steady_process_noise", "kf_process_noise"):
            if not design[key] > 0:
                raise InputError(f"{key} must be > 0 (the square-root information filter needs Q⁻¹)")
        transition = check_transition(parse_matrix(design["imm_transition"], "imm_transition"), len(MODEL_NAMES))
        imm_models = [kinematic_model("cv", 2, T, design["cv_process_noise"], axes),
                      kinematic_model("ca_transition", 3, T, design["ca_transition_process_noise"], axes),
                      kinematic_model("ca_steady", 3, T, design["ca_steady_process_noise"], axes)]
        kf_model = kinematic_model("ca", 3, T, design["kf_process_noise"], axes, noise="increment")
        return np.eye(axes) * R, transition, imm_models, kf_model

    # ------------------------------------------------------------------ run

    def run(self, dataset, trackers, design: dict) -> dict:
        z, times, T, truth, _ = self._inputs(dataset)
        runs, scans, axes = z.shape
        R, transition, imm_models, kf_model = self._design_arrays(design, T, axes)
        ar = estimate_ar1(z, design["ar_forgetting_factor"], design["ar_zero_pole"], path=dataset.path)
        warm = ar.warm[None, :, None]
        plain = MeasurementStream(z, R)
        decorrelated = MeasurementStream(z, R, True, np.where(warm, ar.alpha, np.nan),
                                         np.where(warm, ar.noise_variance, np.nan))
        dp_flags = (np.bitwise_or.reduce(ar.flags, axis=-1) | np.where(ar.warm, 0, FLAG_NOT_WARM)[None, :]).astype(np.uint8)
        x0 = truth[:, 0]
        P0 = np.eye(3 * axes) * design["initial_variance"]
        outputs = {}
        for t in trackers:
            kind_set, kind, decorrelate = TRACKERS[t]
            stream = decorrelated if decorrelate else plain
            if kind_set == "single":
                res = single_model_filter(ModelFilter(kf_model, kind), x0, P0, stream)
            else:
                res = imm_filter([ModelFilter(m, kind) for m in imm_models], transition, x0, P0, stream)
            res["flags"] = dp_flags if decorrelate else np.zeros((runs, scans), np.uint8)
            outputs[t] = res
        outputs[colored_eval.AR_TRACKER] = {
            "alpha": ar.alpha, "alpha_biased": ar.alpha_biased, "noise_variance": ar.noise_variance,
            "warm": np.broadcast_to(ar.warm.astype(np.uint8), (runs, scans)).copy(), "flags": ar.flags}
        return {"times": times, "tracks": outputs}

    def evaluate(self, dataset, result: dict, design: dict):
        z, times, T, truth, alpha = self._inputs(dataset)
        if alpha is None:
            alpha = np.full(z.shape, np.nan)
        return colored_eval.evaluate(result["times"], result["tracks"], truth, alpha,
                                     float(design["measurement_variance_m2"]), float(design["ar_forgetting_factor"]),
                                     MODEL_NAMES)

    def figures(self, per_scan, out_dir, title: str = "") -> list:
        from evaluators.colored_noise_imm import write_figures

        return write_figures(per_scan, out_dir, title=title)

    def report(self, summary, per_scan) -> str:
        part = summary.filter(summary["stage"] == self.name) if "stage" in summary.columns else summary
        return colored_eval.report_text(part, list(TRACKERS), MODEL_NAMES)

    # ------------------------------------------------------------------ Rerun

    def blueprint(self, trackers, dataset=None, run: int = 0):
        """RMSE | model probabilities per IMM | AR estimates, SRIF residual, errors of one run."""
        shown = rrb.PlotLegend(corner=rrb.Corner2D.RightTop, visible=True)
        hidden = rrb.PlotLegend(visible=False)
        imms = [t for t in ("imm", "mimm_k", "pimm") if t in trackers]
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

    def log_rerun(self, rec, dataset, result: dict, per_scan, run: int = 0) -> None:
        times = result["times"]
        scans = np.arange(len(times))
        tracks = result["tracks"]
        z, _, _, truth, alpha = self._inputs(dataset)
        run = min(run, z.shape[0] - 1)
        for name, out in tracks.items():
            if name == colored_eval.AR_TRACKER:
                continue
            log_metric_series(rec, per_scan, name, ("rmse_position_m", "rmse_velocity_mps", "rmse_acceleration_mps2"),
                              lambda m: f"/rmse/{m.removeprefix('rmse_')}", _rgb(name))
            log_series(rec, f"/error/position_m/{name}", scans, times, out["state"][run, :, 0] - truth[run, :, 0], name,
                       _rgb(name))
            mu = out.get("model_probabilities")
            if mu is not None and mu.shape[-1] == len(MODEL_NAMES):
                for j, m in enumerate(MODEL_NAMES):
                    log_series(rec, f"/model_probability/{name}/{m}", scans, times, mu[run, :, j], m, _rgb(m))
            if name == "pimm":
                for j, m in enumerate(MODEL_NAMES):
                    log_series(rec, f"/srif/residual/{m}", scans, times, np.sqrt(out["nis"][run, :, j]), m, _rgb(m))
        ar = tracks.get(colored_eval.AR_TRACKER)
        if ar is not None:
            log_series(rec, "/ar/alpha/estimate", scans, times, ar["alpha"][run, :, 0], "α̂", (31, 119, 180))
            log_series(rec, "/ar/alpha/biased", scans, times, ar["alpha_biased"][run, :, 0], "α^b", (255, 127, 14))
            log_series(rec, "/ar/noise_variance/estimate", scans, times, ar["noise_variance"][run, :, 0], "σ̂_η²", (31, 119, 180))
            if alpha is not None:
                log_series(rec, "/ar/alpha/truth", scans, times, alpha[run, :, 0], "truth", (230, 230, 230))
                R = float(self.design(dataset)["measurement_variance_m2"])
                log_series(rec, "/ar/noise_variance/truth", scans, times, (1 - alpha[run, :, 0] ** 2) * R, "truth",
                           (230, 230, 230))
