"""Stage: ULA snapshots → multi-target bearing tracks (MUSIC start-up, PAST, angular innovation).

Input channels: ``/array/snapshots`` (``snapshots``: complex M × Ns per run and scan),
optionally ``/array/truth`` (``angle_rad`` (N,), ``snr_db``). Output:
``/tracks/array/<tracker>`` with ``angle_rad``, ``rate_radps``, ``angle_std_rad``,
``predicted_rad``, ``innovation_rad``, ``gain`` (N × 2), ``flags``, ``n_tracks``,
``source_count``, ``subspace_error_rad`` (PAST vs per-scan EVD) and ``innovation_time_s``
(measured wall time of the innovation step per run and scan). Trackers are the two innovation
strategies on one tracker: ``proposed`` (closed form) and ``ryu`` ((2N+1)-dim least squares).

Only I/O, validation and bookkeeping live here; the numbers come from
:mod:`pipeline.trackers.array_bearing` and :mod:`evaluators.array_bearing`.
"""

from __future__ import annotations

import numpy as np
import polars as pl

from evaluators import array_bearing as array_eval
from pipeline.cores.array.angular_innovation import INNOVATIONS
from pipeline.errors import InputError, require_finite
from pipeline.cores.array.flop_counts import ANALYTIC
from pipeline.stages.base import Stage
from pipeline.trackers.array_bearing import SUBSPACES, SubspaceTrackerDesign, music_waterfall, track_bearings
from pipeline.face.timeline import color, log_series, rr, rrb, log_metric_series

SNAPSHOTS = "/array/snapshots"
TRUTH = "/array/truth"
LABELS = {"ryu": "Ryu 1999", "proposed": "proposed"}
BATCH_RUNS = 300  # the paper's 100 runs × 3 SNRs in one vectorised call
# both trackers give the same tracks to rounding: Ryu drawn wide underneath, proposed thin on top
STYLE = {"ryu": ((214, 39, 40), -3.5, 10.0), "proposed": ((255, 80, 255), -1.5, 20.0)}


def tracker_design(design: dict) -> SubspaceTrackerDesign:
    """Scenario design values (degrees at this boundary) → the tracker's SI design."""
    deg2 = np.deg2rad(1.0) ** 2
    crit = str(design["source_count_criterion"]).lower()
    if crit not in ("mdl", "aic"):
        raise InputError(f"source_count_criterion must be mdl or aic, got {crit!r}")
    if design["subspace_tracker"] not in SUBSPACES:
        raise InputError(f"subspace_tracker must be one of {', '.join(SUBSPACES)}, got {design['subspace_tracker']!r}")
    if not 0 < design["past_forgetting"] <= 1:
        raise InputError("past_forgetting must be in (0, 1]")
    for key in ("process_noise_q_deg2", "innovation_variance_deg2", "scan_period_s", "music_grid_step_deg",
                "track_gate_deg", "spacing_wavelengths"):
        if not design[key] > 0:
            raise InputError(f"{key} must be > 0")
    return SubspaceTrackerDesign(
        spacing_wavelengths=float(design["spacing_wavelengths"]), scan_period_s=float(design["scan_period_s"]),
        process_noise_q=float(design["process_noise_q_deg2"]) * deg2,
        innovation_variance=float(design["innovation_variance_deg2"]) * deg2,
        forgetting=float(design["past_forgetting"]), source_count=crit, n_sources=int(design["n_sources"]),
        grid_step_rad=np.deg2rad(float(design["music_grid_step_deg"])), subspace=str(design["subspace_tracker"]))


class ArrayBearingStage(Stage):
    name = "array-bearing"
    input_topics = (SNAPSHOTS,)
    trackers = tuple(INNOVATIONS)
    output_prefix = "/tracks/array/"
    scenario = "array-crossing"
    design_keys = ("spacing_wavelengths", "scan_period_s", "process_noise_q_deg2", "innovation_variance_deg2",
                   "past_forgetting", "source_count_criterion", "n_sources", "music_grid_step_deg",
                   "subspace_tracker", "track_gate_deg")

    # ------------------------------------------------------------------ input

    def _snapshots(self, dataset, design: dict | None = None) -> np.ndarray:
        """Validated snapshots ``(runs, scans, M, Ns)``: complex, one fixed shape, finite."""
        ch = dataset.channel(SNAPSHOTS)
        items = ch.array("snapshots")
        first = items[0]
        if first.dtype.kind != "c":
            raise InputError(f"{SNAPSHOTS} snapshots must be complex (complex64/complex128), got {first.dtype}", dataset.path)
        if first.ndim != 2:
            raise InputError(f"{SNAPSHOTS} snapshots must be 2-D (sensors × snapshots), got shape {first.shape}", dataset.path)
        bad = next((a.shape for a in items if a.shape != first.shape), None)
        if bad is not None:
            raise InputError(f"{SNAPSHOTS} snapshots change shape between frames ({first.shape} vs {bad})", dataset.path)
        if any(a.dtype.kind != "c" for a in items):
            raise InputError(f"{SNAPSHOTS} snapshots mix complex and real frames", dataset.path)
        M, Ns = first.shape
        if M < 2:
            raise InputError(f"{SNAPSHOTS} has {M} sensor(s); an array needs at least 2", dataset.path)
        if len(items) != ch.n_runs * ch.n_scans:
            raise InputError(f"{SNAPSHOTS} has {len(items)} frames, expected runs × scans = "
                             f"{ch.n_runs} × {ch.n_scans} (missing frames)", dataset.path)
        if ch.n_scans < 3:
            raise InputError(f"{SNAPSHOTS} has {ch.n_scans} scan(s); two start-up scans and one tracked scan "
                             "are the minimum", dataset.path)
        X = ch.grid("snapshots")
        require_finite(f"{SNAPSHOTS} snapshots", X, dataset.path)
        if design is not None:
            n_req = int(design["n_sources"])
            if n_req < 0:
                raise InputError("n_sources must be ≥ 0 (0 estimates it)")
            if n_req > M - 1:
                raise InputError(f"n_sources = {n_req} targets requested, but M − 1 = {M - 1} is the most "
                                 f"an array of {M} sensors can track (the noise subspace must not be empty)",
                                 dataset.path)
            if n_req > Ns:
                raise InputError(f"{Ns} snapshots per scan are fewer than the {n_req} targets requested", dataset.path)
        truth = dataset.channels.get(TRUTH)
        if truth is not None and "angle_rad" in truth.arrays:
            first_truth = truth.array("angle_rad")[0]
            if first_truth.ndim != 1:
                raise InputError(f"{TRUTH} angle_rad must be 1-D (one angle per target) in every frame, got shape "
                                 f"{first_truth.shape}", dataset.path)
            n_true = first_truth.shape[0]
            if n_true > M - 1:
                raise InputError(f"{TRUTH} holds {n_true} targets, more than M − 1 = {M - 1}", dataset.path)
            if n_true > Ns:
                raise InputError(f"{Ns} snapshots per scan are fewer than the {n_true} targets", dataset.path)
        return X

    def _truth(self, dataset, shape):
        truth = dataset.channels.get(TRUTH)
        if truth is None:
            return None, None
        angles = truth.grid("angle_rad")
        if angles.shape[:2] != shape:
            raise InputError(f"{TRUTH} covers {angles.shape[:2]} run×scan, snapshots {shape}", dataset.path)
        require_finite(f"{TRUTH} angle_rad", angles, dataset.path)
        snr = truth.grid("snr_db")[:, 0] if "snr_db" in truth.arrays else None
        return angles, snr

    # ------------------------------------------------------------------ run / evaluate

    def run(self, dataset, trackers, design: dict) -> dict:
        X = self._snapshots(dataset, design)
        d = tracker_design(design)
        outputs = track_bearings(X, d, tuple(trackers))
        times = dataset.channel(SNAPSHOTS).times()
        return {"times": times, "tracks": outputs}

    def evaluate(self, dataset, result: dict, design: dict):
        ch = dataset.channel(SNAPSHOTS)
        M = ch.array("snapshots")[0].shape[0]
        truth, snr = self._truth(dataset, (ch.n_runs, ch.n_scans))
        return array_eval.evaluate(result["times"], result["tracks"], truth, snr,
                                   np.deg2rad(float(design["track_gate_deg"])), M)

    def report(self, summary, per_scan) -> str:
        """The paper's Table 1 layout (MSE per SNR, innovation FLOPs and time for N = 5, 6)."""
        return table1(summary, per_scan)

    # ------------------------------------------------------------------ Rerun

    def blueprint(self, trackers, dataset=None, run: int = 0):
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

    def log_rerun(self, rec, dataset, result: dict, per_scan, run: int = 0) -> None:
        times = result["times"]
        scans = np.arange(len(times))
        X = self._snapshots(dataset)
        run = min(run, X.shape[0] - 1)
        design = tracker_design(self.design(dataset))
        any_out = next(iter(result["tracks"].values()))
        n_run = int(any_out["n_tracks"][run, 0])
        truth, _ = self._truth(dataset, X.shape[:2])
        grid, spectrum = music_waterfall(X[run], max(n_run, 1), design)
        _log_waterfall(rec, grid, spectrum, truth[run] if truth is not None else None,
                       {name: out["angle_rad"][run] for name, out in result["tracks"].items()})
        for name, out in result["tracks"].items():
            for n in range(n_run):
                log_series(rec, f"/innovation/{name}/target{n}", scans, times,
                           np.rad2deg(out["innovation_rad"][run, :, n]), f"{name} {n}", _target_color(n))
                log_series(rec, f"/gain/{name}/target{n}", scans, times, out["gain"][run, :, n, 0], f"{name} {n}",
                           _target_color(n))
            log_metric_series(rec, per_scan, name, ("mse_deg2",), lambda m: "/errors",
                              STYLE.get(name, (color(name),))[0])
        log_series(rec, "/subspace/past_vs_batch", scans, times, np.rad2deg(any_out["subspace_error_rad"][run]),
                   "PAST vs EVD", (200, 200, 200))


def _target_color(n: int):
    from matplotlib import colormaps

    return tuple(int(255 * c) for c in colormaps["tab10"](n % 10)[:3])


def _viridis(values: np.ndarray) -> np.ndarray:
    from matplotlib import colormaps

    return (colormaps["viridis"](values)[..., :3] * 255).astype(np.uint8)


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


# --------------------------------------------------------------------------- Table 1


def _value(summary, tracker, metric, scope):
    hit = summary.filter((pl.col("tracker") == tracker) & (pl.col("metric") == metric) & (pl.col("scope") == scope))
    return float(hit["value"][0]) if hit.height else float("nan")


def table1(summary: pl.DataFrame, per_scan: pl.DataFrame, time_repeats: int = 200) -> str:
    """Text table in the layout of the paper's Table 1, plus swaps/losses and timings."""
    from pipeline.cores.array.flop_counts import time_innovation

    s = summary
    trackers = [t for t in ("ryu", "proposed") if t in set(s["tracker"].to_list())]
    if not trackers:
        return ""
    M = int(_value(s, "data", "n_sensors", "data")) if np.isfinite(_value(s, "data", "n_sensors", "data")) else None
    snr_scopes = sorted({sc for sc in s["scope"].to_list() if sc.startswith("snr_db=")}, key=lambda x: float(x[7:]))
    runs = _value(s, trackers[0], "runs", snr_scopes[0]) if snr_scopes else _value(s, "data", "runs", "data")
    n_true = _value(s, "data", "n_targets", "data")
    lines = [f"Table 1 (layout of Ryu, Lee & Lee 2001): M = {M}, "
             + (f"N = {n_true:g} targets, {runs:g} runs per SNR" if np.isfinite(n_true) else "no truth")]
    head = f"{'algorithm':<20}" + "".join(f"{'MSE ' + sc[7:] + ' dB':>12}" for sc in snr_scopes)
    head += "".join(f"{'FLOPs N=' + str(n) + ' model/counted':>28}" for n in (5, 6))
    head += "".join(f"{'µs/scan N=' + str(n):>14}" for n in (5, 6))
    lines += [head, "-" * len(head)]
    timing = {}
    for t in trackers:
        row = f"{LABELS[t]:<20}" + "".join(f"{_value(s, t, 'angle_mse_deg2', sc):>12.4f}" for sc in snr_scopes)
        for n in (5, 6):
            model = _value(s, t, "innovation_flops_model", f"n_targets={n}")
            counted = _value(s, t, "innovation_flops_counted", f"n_targets={n}")
            row += f"{model:>16,.0f} / {counted:>9,.0f}" if np.isfinite(model) else f"{'–':>28}"
        for n in (5, 6):
            if M is not None and n < M:
                timing[(t, n)] = time_innovation(t, M, n, repeats=time_repeats) * 1e6
                row += f"{timing[(t, n)]:>14.1f}"
            else:
                row += f"{'–':>14}"
        lines.append(row)
    # The paper's own Table 1 is quoted in the README for comparison; the code reports only what
    # it measures, so no printed number of the paper can turn into an expected output.
    if M is not None and {"ryu", "proposed"} <= set(trackers):
        ratio = " ".join(f"N={n}: model {ANALYTIC['proposed'](M, n) / ANALYTIC['ryu'](M, n):.3f}, counted "
                         f"{_value(s, 'proposed', 'innovation_flops_counted', f'n_targets={n}') / _value(s, 'ryu', 'innovation_flops_counted', f'n_targets={n}'):.3f}, "
                         f"time {timing[('proposed', n)] / timing[('ryu', n)]:.3f};" for n in (5, 6) if n < M)
        lines.append(f"proposed / Ryu ratio  {ratio}")
    if M is not None:
        from pipeline.cores.array.flop_counts import counted_flops

        for n in (5, 6):
            if n < M:
                steps = "; ".join(f"{LABELS[t]}: " + " + ".join(f"{k} {v:,}" for k, v in counted_flops(t, M, n).items())
                                  for t in trackers)
                lines.append(f"counted FLOPs per step, N={n}: {steps}")
    lines.append("µs/scan: one innovation call for all N targets of one scan (single run, best of "
                 f"{time_repeats}); counted FLOPs exclude the steering vectors both need.")
    if M is not None and {"ryu", "proposed"} <= set(trackers):
        batched = {(t, n): time_innovation(t, M, n, batch=BATCH_RUNS, repeats=max(5, time_repeats // 5)) * 1e6
                   for t in ("proposed", "ryu") for n in (5, 6) if n < M}
        lines.append(f"batched over {BATCH_RUNS} runs (µs per run-scan): " + "; ".join(
            f"N={n}: proposed {batched[('proposed', n)]:.2f}, Ryu {batched[('ryu', n)]:.2f}, ratio "
            f"{batched[('proposed', n)] / batched[('ryu', n)]:.3f}" for n in (5, 6) if n < M))
    if snr_scopes:
        lines.append("")
        lines.append(f"{'per SNR':<20}{'MSE clean':>11}{'swaps/run':>11}{'no-swap runs':>14}"
                     f"{'losses/run':>12}{'no-loss runs':>14}{'N correct':>11}")
        for t in trackers:
            for sc in snr_scopes:
                lines.append(f"{LABELS[t] + ' ' + sc[7:] + ' dB':<20}"
                             f"{_value(s, t, 'angle_mse_deg2_clean', sc):>11.4f}"
                             f"{_value(s, t, 'track_swaps_per_run', sc):>11.3f}"
                             f"{_value(s, t, 'runs_without_swap', sc):>14.1%}"
                             f"{_value(s, t, 'target_losses_per_run', sc):>12.3f}"
                             f"{_value(s, t, 'runs_without_loss', sc):>14.1%}"
                             f"{_value(s, t, 'source_count_correct', sc):>11.1%}")
        lines.append("MSE clean: runs with no swap and no loss only (the table's MSE keeps every run).")
    if "innovation_time_us" in per_scan.columns:
        measured = per_scan.group_by("tracker").agg(pl.col("innovation_time_us").filter(pl.col("innovation_time_us") > 0).mean())
        parts = [f"{LABELS.get(r['tracker'], r['tracker'])} {r['innovation_time_us']:.2f} µs"
                 for r in measured.sort("tracker").iter_rows(named=True) if r["innovation_time_us"] is not None]
        if parts:
            lines.append("innovation time per run-scan in this replay (all runs batched): " + ", ".join(parts))
    return "\n".join(lines)
