"""Stage: cross-correlation peaks (bearing, amplitude) → JPDA and amplitude-aided JPDA_A.

Input channels: ``/xcorr/peaks`` (ragged ``bearing_rad``, ``amplitude``, ``origin``: target
index of a true peak, −1 for clutter), optionally ``/xcorr/truth`` (``bearing_rad`` per target).
Tracks start (design ``track_start``) either at the true bearing and bearing rate of scan 0
with the covariance P(0|0) of spec eq. 8c (``truth``, the default: Fig. 8 measures association,
not track initiation), or from the labelled true peaks of scans 0 and 1 by two-point
differencing, whose covariance *is* eq. 8c (``two-point``; filtering then starts at scan 2). Output: ``/tracks/xcorr/<tracker>`` with ``state`` [θ, θ̇] per
track, ``covariance``, ``beta0``, ``beta_top``/``beta_index`` (largest peak weights),
``strength``, ``n_gated``, ``gate_center`` and ``flags``. Only I/O and bookkeeping live here:
the numbers come from :mod:`pipeline.cores.association.jpda` and :mod:`evaluators.track_association`.
"""

from __future__ import annotations

import numpy as np
import polars as pl

from evaluators import track_association as assoc_eval
from pipeline.errors import InputError, check_all, require_finite
from pipeline.cores.association.jpda import STRATEGIES, BearingTrackerDesign, ScanPeaks, track_bearing_peaks, two_point_start
from pipeline.stages.base import Stage
from pipeline.face.timeline import color, log_points, log_series, rr, rrb, log_metric_series

PEAKS = "/xcorr/peaks"
TRUTH = "/xcorr/truth"
AMPLITUDE_COLOR_MAX = 30000.0  # the paper's amplitude range 0 … 30,000
TRACKER_COLORS = {"jpda": (66, 146, 235), "jpda_a": (255, 140, 30)}
TRACK_COLORS = [(120, 200, 255), (255, 110, 110), (140, 230, 140), (230, 200, 90)]


def time_unit_s(duration_s: float, span_deg: float) -> float:
    """Seconds per vertical unit of the bearing–time view, so that it is about as tall as wide."""
    for unit in (1, 2, 5, 10, 20, 50, 100, 200, 500, 1000):
        if duration_s / unit <= 1.5 * span_deg:
            return float(unit)
    return 1000.0


def recorded_float(dataset, key: str, default: float) -> float:
    """A number from the file's scenario record (``default`` if absent), checked finite."""
    raw = dataset.scenario.get("params", {}).get(key, default)
    try:
        value = float(raw)
    except (TypeError, ValueError):
        raise InputError(f"scenario record: parameter {key!r}: cannot read {raw!r} as float", dataset.path) from None
    if not np.isfinite(value):
        raise InputError(f"scenario record: parameter {key!r} must be finite", dataset.path)
    return value


def field_deg(dataset) -> tuple[float, float]:
    """The sensor's field of bearings ``(min, max)`` in degrees from the scenario record (default 0…180)."""
    return recorded_float(dataset, "field_min_deg", 0.0), recorded_float(dataset, "field_max_deg", 180.0)


def read_peaks(dataset):
    """Flat peaks of a data set, checked: bearings in the sensor's field, amplitudes ≥ 0, finite.

    Returns
    -------
    dict with ``run``, ``scan``, ``slot`` (position in its frame), ``bearing``, ``amplitude``,
    ``origin`` (−1 where unlabelled), ``n_runs``, ``n_scans``, ``times``.
    """
    ch = dataset.channel(PEAKS)
    columns = {name: ch.array(name) for name in ("bearing_rad", "amplitude", "origin")
               if name != "origin" or "origin" in ch.arrays}
    for name, items in columns.items():
        bad = next((i for i, a in enumerate(items) if a.ndim != 1), None)
        if bad is not None:
            raise InputError(f"{PEAKS} {name} must be 1-D (one value per peak) in every frame; run {ch.run[bad]} "
                             f"scan {ch.scan[bad]} holds shape {items[bad].shape}", dataset.path)
    lengths = np.array([a.shape[0] for a in columns["bearing_rad"]], np.int64)
    for name, items in columns.items():
        bad = next((i for i, (a, n) in enumerate(zip(items, lengths)) if a.shape[0] != n), None)
        if bad is not None:
            raise InputError(f"{PEAKS}: bearing_rad and {name} differ in length in run {ch.run[bad]} scan "
                             f"{ch.scan[bad]} ({lengths[bad]} vs {items[bad].shape[0]})", dataset.path)
    frame = np.repeat(np.arange(lengths.size), lengths)
    starts = np.r_[0, np.cumsum(lengths)[:-1]]
    flat = lambda name, dt: (np.concatenate([np.asarray(a, dt) for a in columns[name]])
                             if lengths.sum() else np.zeros(0, dt))
    bearing, amplitude = flat("bearing_rad", float), flat("amplitude", float)
    origin = flat("origin", np.int64) if "origin" in ch.arrays else np.full(bearing.size, -1, np.int64)
    require_finite(f"{PEAKS} bearing_rad", bearing, dataset.path)
    require_finite(f"{PEAKS} amplitude", amplitude, dataset.path)
    if np.any(amplitude < 0):
        raise InputError(f"{PEAKS} holds {int(np.sum(amplitude < 0))} peak(s) with negative amplitude "
                         "(correlation peak amplitudes are ≥ 0)", dataset.path)
    lo, hi = field_deg(dataset)
    outside = (bearing < np.deg2rad(lo) - 1e-12) | (bearing > np.deg2rad(hi) + 1e-12)
    if np.any(outside):
        raise InputError(f"{PEAKS} holds {int(outside.sum())} peak(s) with bearings outside the sensor's field "
                         f"[{lo:g}°, {hi:g}°]", dataset.path)
    if ch.n_scans < 3:
        raise InputError(f"{PEAKS} has {ch.n_scans} scan(s); a track needs at least 3", dataset.path)
    return {"run": ch.run[frame], "scan": ch.scan[frame], "slot": np.arange(bearing.size) - starts[frame],
            "bearing": bearing, "amplitude": amplitude, "origin": origin, "n_runs": ch.n_runs,
            "n_scans": ch.n_scans, "times": ch.times()}


def scans_from_flat(peaks: dict) -> list[ScanPeaks]:
    """One :class:`ScanPeaks` per scan, padded only to that scan's largest frame."""
    R, K = peaks["n_runs"], peaks["n_scans"]
    order = np.argsort(peaks["scan"], kind="stable")
    bounds = np.searchsorted(peaks["scan"][order], np.arange(K + 1))
    out = []
    for k in range(K):
        idx = order[bounds[k]:bounds[k + 1]]
        w = int(peaks["slot"][idx].max()) + 1 if idx.size else 0
        b, a, v = np.zeros((R, w)), np.zeros((R, w)), np.zeros((R, w), bool)
        r, s = peaks["run"][idx], peaks["slot"][idx]
        b[r, s], a[r, s], v[r, s] = peaks["bearing"][idx], peaks["amplitude"][idx], True
        out.append(ScanPeaks(b, a, v))
    return out


def start_peaks(peaks: dict, n_tracks: int, path) -> tuple[np.ndarray, np.ndarray]:
    """Bearings ``(R, T)`` of the labelled true peaks of scans 0 and 1 (the two-point start)."""
    R = peaks["n_runs"]
    z = np.full((2, R, n_tracks), np.nan)
    sel = (peaks["scan"] < 2) & (peaks["origin"] >= 0) & (peaks["origin"] < n_tracks)
    z[peaks["scan"][sel], peaks["run"][sel], peaks["origin"][sel]] = peaks["bearing"][sel]
    missing = ~np.isfinite(z)
    if missing.any():
        k, r, t = (int(v[0]) for v in np.nonzero(missing))
        raise InputError(f"{PEAKS}: no labelled true peak (origin = {t}) at scan {k} of run {r}; tracks start "
                         "from the labelled true peaks of scans 0 and 1", path)
    return z[0], z[1]


def read_truth(dataset, n_runs: int, n_scans: int) -> np.ndarray | None:
    """True bearings ``(R, K, T)`` of :data:`TRUTH`, checked against the peaks' ``(R, K)``.

    Returns
    -------
    ndarray or None
        None when the file has no truth bearings.

    Raises
    ------
    InputError
        Frames that are not one bearing per target (1-D), a missing frame, a run × scan
        coverage other than the peaks', no targets, or NaN/Inf.
    """
    truth = dataset.channels.get(TRUTH)
    if truth is None or "bearing_rad" not in truth.arrays:
        return None
    items = truth.array("bearing_rad")
    bad = next((i for i, a in enumerate(items) if a.ndim != 1), None)
    if bad is not None:
        raise InputError(f"{TRUTH} bearing_rad must be 1-D (one bearing per target) in every frame; run "
                         f"{truth.run[bad]} scan {truth.scan[bad]} holds shape {items[bad].shape}", dataset.path)
    b = truth.grid("bearing_rad")
    if b.shape[:2] != (n_runs, n_scans):
        raise InputError(f"{TRUTH} covers {b.shape[:2]} run×scan, peaks {(n_runs, n_scans)}", dataset.path)
    if b.shape[2] < 1:
        raise InputError(f"{TRUTH} bearing_rad holds no targets", dataset.path)
    truth.require_every_frame(n_runs, n_scans)
    require_finite(f"{TRUTH} bearing_rad", b, dataset.path)
    return b


class BearingPeaksStage(Stage):
    name = "xcorr-peaks"
    input_topics = (PEAKS,)
    trackers = tuple(STRATEGIES)
    output_prefix = "/tracks/xcorr/"
    scenario = "xcorr-crossing"
    design_keys = ("scan_period_s", "gate_deg", "q_deg2", "amplitude_threshold", "design_detection_probability",
                   "design_clutter_per_gate", "clutter_alpha", "pair",
                   "strong_sigma_p_deg", "strong_amplitude_mean", "strong_amplitude_std",
                   "weak_sigma_p_deg", "weak_amplitude_mean", "weak_amplitude_std",
                   "amplitude_tracking", "initial_strength", "tracked_amplitude_std", "max_cluster_tracks",
                   "track_start")

    # ------------------------------------------------------------------ inputs

    def _n_tracks(self, dataset, peaks) -> int:
        truth = read_truth(dataset, peaks["n_runs"], peaks["n_scans"])
        if truth is not None:
            return int(truth.shape[2])
        n = int(peaks["origin"].max()) + 1 if peaks["origin"].size else 0
        if n < 1:
            raise InputError(f"{PEAKS} carries no labelled true peaks and there is no {TRUTH}: cannot start tracks",
                             dataset.path)
        return n

    def _roles(self, design: dict, n_tracks: int) -> tuple[str, ...]:
        from pipeline.trackers.peak_roles import track_roles

        roles = track_roles(design)
        if len(roles) != n_tracks:
            raise InputError(f"the data hold {n_tracks} target(s) but pair={design['pair']!r} describes {len(roles)}")
        return roles

    def tracker_design(self, design: dict, n_tracks: int) -> BearingTrackerDesign:
        roles = self._roles(design, n_tracks)
        per = lambda key: np.array([float(design[f"{r}_{key}"]) for r in roles])
        checks = [(design["gate_deg"] > 0, "gate_deg must be > 0"), (design["q_deg2"] >= 0, "q_deg2 must be ≥ 0"),
                  (0 < design["design_detection_probability"] <= 1, "design_detection_probability must be in (0, 1]"),
                  (design["design_clutter_per_gate"] > 0, "design_clutter_per_gate must be > 0"),
                  (design["clutter_alpha"] > 0, "clutter_alpha must be > 0"),
                  (design["max_cluster_tracks"] >= 1, "max_cluster_tracks must be ≥ 1"),
                  (np.all(per("sigma_p_deg") > 0) and np.all(per("amplitude_std") > 0),
                   "σ_p and σ_a of every role must be > 0")]
        check_all(checks)
        return BearingTrackerDesign(
            scan_period_s=float(design["scan_period_s"]), gate_rad=float(np.deg2rad(design["gate_deg"])),
            q_rad2=float(design["q_deg2"]) * np.deg2rad(1.0) ** 2,
            amplitude_threshold=float(design["amplitude_threshold"]),
            detection_probability=float(design["design_detection_probability"]),
            clutter_per_gate=float(design["design_clutter_per_gate"]), clutter_alpha=float(design["clutter_alpha"]),
            sigma_p_rad=np.deg2rad(per("sigma_p_deg")), strength=per("amplitude_mean"), sigma_a=per("amplitude_std"),
            amplitude_tracking=bool(design["amplitude_tracking"]), initial_strength=float(design["initial_strength"]),
            tracked_sigma_a=float(design["tracked_amplitude_std"]), max_cluster_tracks=int(design["max_cluster_tracks"]))

    def _start(self, dataset, peaks, design: dict, d: BearingTrackerDesign, T: int):
        """Initial states, covariances and the scan they belong to (see the module docstring)."""
        mode = design["track_start"]
        if mode == "two-point":
            z0, z1 = start_peaks(peaks, T, dataset.path)
            x0, P0 = two_point_start(z0, z1, d.scan_period_s, d.sigma_p_rad)
            return x0, P0, 1
        if mode != "truth":
            raise InputError(f"track_start must be 'truth' or 'two-point' (got {mode!r})")
        truth = dataset.channels.get(TRUTH)
        if truth is None or "bearing_rate_radps" not in truth.arrays:
            raise InputError(f"track_start='truth' needs {TRUTH} (bearing_rad, bearing_rate_radps); "
                             "use --set track_start=two-point for data without truth", dataset.path)
        b = read_truth(dataset, peaks["n_runs"], peaks["n_scans"])
        if b is None:
            raise InputError(f"track_start='truth' needs {TRUTH} bearing_rad; use --set track_start=two-point "
                             "for data without truth", dataset.path)
        rate = truth.grid("bearing_rate_radps")
        if rate.shape != b.shape:
            raise InputError(f"{TRUTH} bearing_rate_radps has shape {rate.shape} (run×scan×target) but bearing_rad "
                             f"{b.shape}; they must match", dataset.path)
        require_finite(f"{TRUTH} bearing_rate_radps", rate, dataset.path)
        x0 = np.stack([b[:, 0], rate[:, 0]], axis=-1)
        # eq. 8c: the covariance of a two-point start, here around the true initial state
        _, P0 = two_point_start(b[:, 0], b[:, 0], d.scan_period_s, d.sigma_p_rad)
        return x0, P0, 0

    # ------------------------------------------------------------------ run / evaluate

    def run(self, dataset, trackers, design: dict) -> dict:
        peaks = read_peaks(dataset)
        T = self._n_tracks(dataset, peaks)
        d = self.tracker_design(design, T)
        x0, P0, start = self._start(dataset, peaks, design, d, T)
        scans = scans_from_flat(peaks)
        outputs = {t: track_bearing_peaks(scans, x0, P0, d, STRATEGIES[t], start) for t in trackers}
        return {"times": peaks["times"], "tracks": outputs}

    def evaluate(self, dataset, result: dict, design: dict):
        any_out = next(iter(result["tracks"].values()))
        R, K, T = any_out["beta0"].shape
        truth = read_truth(dataset, R, K)
        return assoc_eval.evaluate(result["times"], result["tracks"], truth, float(np.deg2rad(design["gate_deg"])),
                                   self._roles(design, T),
                                   first_filtered_scan=2 if design["track_start"] == "two-point" else 1)

    def report(self, summary, per_scan) -> str:
        if "stage" in summary.columns:
            summary = summary.filter(pl.col("stage") == self.name)
        return assoc_eval.success_table(summary)

    # ------------------------------------------------------------------ Rerun

    def blueprint(self, trackers, dataset=None, run: int = 0):
        """Layout: bearing–time record of one run (bearing across, time down, as a sonar BTR) |
        association weights β₀ and the heaviest β per track | amplitudes ẑ_a and errors."""
        bounds, unit = None, 1.0
        if dataset is not None:
            ch = dataset.channel(PEAKS)
            lo, hi = self._field_deg(dataset)
            t = ch.times()
            unit = time_unit_s(float(np.nanmax(t) - np.nanmin(t)), hi - lo)
            bounds = rrb.VisualBounds2D(x_range=[lo, hi], y_range=[float(np.nanmin(t)) / unit - 1, float(np.nanmax(t)) / unit + 1])
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

    def _field_deg(self, dataset) -> tuple[float, float]:
        return field_deg(dataset)

    def log_rerun(self, rec, dataset, result: dict, per_scan, run: int = 0) -> None:
        """Bearing–time record of one run: all peaks (viridis by amplitude, 0 … 30,000), truth
        (white), each filter's tracks (JPDA blue, JPDA_A orange) with their gate edges; β₀ and
        the largest β_j per track and the amplitudes ẑ_a on the timeline."""
        from matplotlib import colormaps

        times = result["times"]
        scans = np.arange(len(times))
        peaks = read_peaks(dataset)
        run = min(run, peaks["n_runs"] - 1)
        lo, hi = self._field_deg(dataset)
        unit = time_unit_s(float(np.nanmax(times) - np.nanmin(times)), hi - lo)
        ys = times / unit
        sel = peaks["run"] == run
        order = np.argsort(peaks["scan"][sel], kind="stable")
        xy = np.stack([np.rad2deg(peaks["bearing"][sel]), ys[peaks["scan"][sel]]], axis=1)[order]
        amp = peaks["amplitude"][sel][order]
        rgb = (colormaps["viridis"](np.clip(amp / AMPLITUDE_COLOR_MAX, 0, 1))[:, :3] * 255).astype(np.uint8)
        rec.log("/btr/peaks", rr.Points2D(xy, colors=rgb, radii=[-2.5]), static=True)
        by_scan = np.split(xy, np.searchsorted(peaks["scan"][sel][order], scans[1:]))
        log_points(rec, "/btr/current_peaks", scans, times, by_scan, (255, 255, 255), radius=-4.5)
        truth = read_truth(dataset, peaks["n_runs"], peaks["n_scans"])
        if truth is not None:
            strips = [np.stack([np.rad2deg(truth[run, :, t]), ys], 1) for t in range(truth.shape[2])]
            rec.log("/btr/truth", rr.LineStrips2D(strips, colors=[(235, 235, 235)], radii=[-1.0]), static=True)
        half = float(np.rad2deg(self.tracker_half_gate(dataset)))
        for name, out in result["tracks"].items():
            c = TRACKER_COLORS.get(name, color(name))
            T = out["state"].shape[2]
            est = np.rad2deg(out["state"][run, :, :, 0])
            gate = np.rad2deg(out["gate_center"][run])
            strips, edges = [], []
            for t in range(T):
                ok = np.isfinite(est[:, t])
                strips.append(np.stack([est[ok, t], ys[ok]], 1))
                g = np.isfinite(gate[:, t])
                edges += [np.stack([gate[g, t] - half, ys[g]], 1), np.stack([gate[g, t] + half, ys[g]], 1)]
            rec.log(f"/btr/tracks/{name}", rr.LineStrips2D(strips, colors=[c], radii=[-2.5]), static=True)
            rec.log(f"/btr/gates/{name}", rr.LineStrips2D(edges, colors=[(*c, 70)], radii=[-0.75]), static=True)
            log_points(rec, f"/btr/estimate/{name}", scans, times,
                       [np.stack([est[k][np.isfinite(est[k])], np.full(np.isfinite(est[k]).sum(), ys[k])], 1)
                        for k in scans], c, radius=-6.0)
            for t in range(T):
                tc = TRACK_COLORS[t % len(TRACK_COLORS)]
                log_series(rec, f"/beta/{name}/track{t}/beta0", scans, times, out["beta0"][run, :, t],
                           f"β₀ track {t}", tuple(v // 2 for v in tc))
                log_series(rec, f"/beta/{name}/track{t}/beta_max", scans, times, out["beta_top"][run, :, t, 0],
                           f"max β_j track {t}", tc)
                log_series(rec, f"/strength/{name}/track{t}", scans, times, out["strength"][run, :, t],
                           f"{name} track {t}", tc if name == "jpda_a" else tuple(v // 2 for v in tc))
            log_metric_series(rec, per_scan, name, ("rmse_bearing_deg", "on_own_target_fraction"),
                              lambda m: f"/errors/{m}", c)

    def tracker_half_gate(self, dataset) -> float:
        return float(np.deg2rad(self.design(dataset)["gate_deg"])) / 2


def track_simulated(data, params: dict, trackers=("jpda", "jpda_a"), overrides: dict | None = None) -> dict:
    """Run the trackers on an in-memory :class:`recorders.simulated.SimulatedData` (no MCAP
    round trip; what a replay of the written file computes, for Monte Carlo studies).

    Returns
    -------
    dict
        ``{"tracks": {tracker: outputs}, "truth": (R, K, T) bearings, "gate_rad": V, "times": (K,)}``.
    """
    from pipeline.cores.association.jpda import scans_from_padded

    stage = BearingPeaksStage()
    design = {k: params[k] for k in stage.design_keys}
    design.update(overrides or {})
    arr, counts = data.ragged[PEAKS]
    truth = data.fixed[TRUTH]
    T = truth["bearing_rad"].shape[-1]
    d = stage.tracker_design(design, T)
    if design["track_start"] == "two-point":
        valid = np.arange(arr["origin"].shape[2])[None, None, :] < counts[..., None]
        r, k, j = np.nonzero(valid & (np.arange(arr["origin"].shape[1]) < 2)[None, :, None])
        peaks = {"run": r, "scan": k, "origin": arr["origin"][r, k, j].astype(np.int64),
                 "bearing": arr["bearing_rad"][r, k, j], "n_runs": counts.shape[0]}
        x0, P0 = two_point_start(*start_peaks(peaks, T, "simulated data"), d.scan_period_s, d.sigma_p_rad)
        start = 1
    else:
        b = truth["bearing_rad"]
        x0 = np.stack([b[:, 0], truth["bearing_rate_radps"][:, 0]], axis=-1)
        _, P0 = two_point_start(b[:, 0], b[:, 0], d.scan_period_s, d.sigma_p_rad)
        start = 0
    scans = scans_from_padded(arr["bearing_rad"], arr["amplitude"], counts)
    tracks = {t: track_bearing_peaks(scans, x0, P0, d, STRATEGIES[t], start) for t in trackers}
    return {"tracks": tracks, "truth": truth["bearing_rad"], "gate_rad": d.gate_rad, "times": data.times}
