"""Stage: cross-correlation peaks (bearing, amplitude) → the xcorr trackers (JPDA, JPDA_A).

Input channels: ``/xcorr/peaks`` (ragged ``bearing_rad``, ``amplitude``, ``origin``: target
index of a true peak, −1 for clutter), optionally ``/xcorr/truth`` (``bearing_rad`` and
``bearing_rate_radps`` per target). Output: ``/tracks/xcorr/<tracker>``. Only decoding and
bookkeeping live here: the trackers are in :mod:`trackreplay.trackers.xcorr` (Park, Ryu &
Lee 1994; see ``docs/papers/xcorr.md``), the scores in
:mod:`trackreplay.evaluators.xcorr`, the Rerun views in :mod:`trackreplay.face.rerun_xcorr`.
"""

from __future__ import annotations

import numpy as np
import polars as pl

from trackreplay.evaluators import xcorr as assoc_eval
from trackreplay import vocabulary as vocab
from trackreplay.errors import InputError, require_finite
from trackreplay.stages.base import BearingStage
from trackreplay.stages.evaluation_gates import gates_from_spread
from trackreplay.trackers.interface import BearingPeaks
from trackreplay.trackers.xcorr_peak_roles import roles_for

PEAKS = vocab.CHANNELS["xcorr_peaks"]
TRUTH = vocab.CHANNELS["xcorr_truth"]
MAX_TRACKS = 100  # tracks started on data without truth or labels (n_targets)


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
    """Flat peaks of a data set, checked: one value per peak, bearings in the sensor's field.

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
    # equal lengths, finite values and amplitudes ≥ 0 are the contract's checks at read time
    # (trackreplay.vocabulary.PARALLEL and VALUES); the field of view is this sensor's own
    lengths = np.array([a.shape[0] for a in columns["bearing_rad"]], np.int64)
    frame = np.repeat(np.arange(lengths.size), lengths)
    starts = np.r_[0, np.cumsum(lengths)[:-1]]
    flat = lambda name, dt: (np.concatenate([np.asarray(a, dt) for a in columns[name]])
                             if lengths.sum() else np.zeros(0, dt))
    bearing, amplitude = flat("bearing_rad", float), flat("amplitude", float)
    origin = flat("origin", np.int64) if "origin" in ch.arrays else np.full(bearing.size, -1, np.int64)
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


def padded_peaks(peaks: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Flat peaks of :func:`read_peaks` → ``(R, K, W)`` bearing, amplitude (NaN-padded), origin
    (−1-padded) and ``(R, K)`` counts, in the order the frames list them."""
    R, K = peaks["n_runs"], peaks["n_scans"]
    counts = np.zeros((R, K), np.int64)
    np.maximum.at(counts, (peaks["run"], peaks["scan"]), peaks["slot"] + 1)
    W = int(counts.max()) if counts.size else 0
    bearing, amplitude = np.full((R, K, W), np.nan), np.full((R, K, W), np.nan)
    origin = np.full((R, K, W), -1, np.int64)
    at = (peaks["run"], peaks["scan"], peaks["slot"])
    bearing[at], amplitude[at], origin[at] = peaks["bearing"], peaks["amplitude"], peaks["origin"]
    return bearing, amplitude, origin, counts


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


def read_truth_rate(dataset, bearing: np.ndarray | None) -> np.ndarray | None:
    """True bearing rates ``(R, K, T)`` of :data:`TRUTH`, checked against its bearings; None when
    the file has no truth bearings or no rates."""
    truth = dataset.channels.get(TRUTH)
    if bearing is None or truth is None or "bearing_rate_radps" not in truth.arrays:
        return None
    rate = truth.grid("bearing_rate_radps")
    if rate.shape != bearing.shape:
        raise InputError(f"{TRUTH} bearing_rate_radps has shape {rate.shape} (run×scan×target) but bearing_rad "
                         f"{bearing.shape}; they must match", dataset.path)
    require_finite(f"{TRUTH} bearing_rate_radps", rate, dataset.path)
    return rate


def n_targets(peaks: dict, truth: np.ndarray | None, path, design: dict | None = None) -> int:
    """Track slots to fill: the targets of the truth, else the labels of the peaks, else the
    design's ``n_targets`` (a recording: as many tracks as it asks for; 2 by default)."""
    if truth is not None:
        return int(truth.shape[2])
    n = int(peaks["origin"].max()) + 1 if peaks["origin"].size else 0
    if n >= 1:
        return n
    wanted = (design or {}).get("n_targets")
    if wanted is None:
        raise InputError(f"{PEAKS} carries no labelled true peaks and there is no {TRUTH}: set n_targets= to say "
                         "how many tracks to start", path)
    if isinstance(wanted, bool) or int(wanted) != wanted or not 1 <= int(wanted) <= MAX_TRACKS:
        raise InputError(f"n_targets must be a whole number in 1…{MAX_TRACKS} (got {wanted!r})", path)
    return int(wanted)


class XcorrStage(BearingStage):
    name = "xcorr"
    listing = (0, "deg")  # without truth, replay lists run 0's bearings per scan
    family = "xcorr"
    # what the evaluator needs: the gate (judge of "on target") and the targets' roles; the
    # tracks to start on data without truth or labels
    design_keys = ("gate_deg", "pair", "roles", "n_targets")

    def decode(self, dataset, design: dict | None = None) -> BearingPeaks:
        """The peaks as :class:`~trackreplay.trackers.interface.BearingPeaks`, checked (decoded
        once per data set; the design does not enter)."""
        if "bearing_peaks" not in dataset.cache:
            from trackreplay.design_values import resolve

            peaks = read_peaks(dataset)
            truth = read_truth(dataset, peaks["n_runs"], peaks["n_scans"])
            rate = read_truth_rate(dataset, truth)
            bearing, amplitude, origin, counts = padded_peaks(peaks)
            dataset.cache["bearing_peaks"] = BearingPeaks(
                bearing_rad=bearing, amplitude=amplitude, origin=origin, counts=counts, times_s=peaks["times"],
                field_rad=tuple(float(v) for v in np.deg2rad(field_deg(dataset))),
                n_targets=n_targets(peaks, truth, dataset.path, design or resolve(self, dataset)),
                truth_bearing_rad=truth, truth_rate_radps=rate)
        return dataset.cache["bearing_peaks"]

    # the field of bearings a recording does not give: every bearing arccos(C·D/d) can have
    when_unsaid = {key: (value, "the whole field a bearing arccos(C·D/d) can have is read, 0° … 180°")
                   for key, value in (("field_min_deg", 0.0), ("field_max_deg", 180.0))}
    evaluation_defaults = {"ospa_cutoff_deg": 10.0, "ospa_order": 2.0, "assignment_gate_deg": 5.0}

    def evaluation_defaults_from_data(self, dataset, design: dict) -> dict:
        """The matching gate from the peaks' bearing noise (docs/evaluation.md, "Evaluation design
        values"): a true peak's bearing has σ ``strong_sigma_p_deg`` or ``weak_sigma_p_deg`` (the
        strong and the weak target's; the larger is taken), and the gate is the half-width holding
        all but 10⁻⁴ of a one-dimensional Gaussian of it (3.89 σ), rounded up to two significant
        digits; the cut-off c is twice it (:mod:`trackreplay.stages.evaluation_gates`). A recording
        that says neither σ keeps the fixed values."""
        sigmas = [float(design[k]) for k in ("strong_sigma_p_deg", "weak_sigma_p_deg") if design.get(k) is not None]
        return gates_from_spread(max(sigmas), 1, "deg") if sigmas else {}

    def reference(self, dataset, design: dict) -> dict:
        m = self.decode(dataset)
        return {"runs": {"truth": m.truth_bearing_rad}, "fixed": {}}

    def score(self, reference: dict, result: dict, design: dict):
        tracks = {n: o for n, o in result["tracks"].items() if "state" in o}
        T = next(iter(tracks.values()))["state"].shape[2]
        return assoc_eval.evaluate(result["times"], tracks, reference["runs"]["truth"],
                                   float(np.deg2rad(design["gate_deg"])), roles_for(design, T))

    def figures(self, per_scan, out_dir, title: str = "", result: dict | None = None, dataset=None) -> list:
        """``report.png``: the bearing–time record of run 0 (peaks, truth, tracks); ``errors.png``:
        bearing RMSE, on-own-target fraction and the JPDA's miss probability per scan."""
        from trackreplay.evaluators.stage_figures import bearing_figures

        errors = ("rmse_bearing_deg", "on_own_target_fraction", "mean_beta0")
        if result is None or dataset is None:
            return bearing_figures(per_scan, None, out_dir, title, None, errors)
        m = self.decode(dataset)
        scan, slot = np.nonzero(np.arange(m.bearing_rad.shape[-1]) < m.counts[0][:, None])
        peaks = (np.asarray(m.times_s, float)[scan], m.bearing_rad[0][scan, slot])
        return bearing_figures(per_scan, result, out_dir, title, m.truth_bearing_rad, errors, peaks,
                               field_deg(dataset))

    replay_report_lines = ()  # the Fig. 8 success table repeats success_rate, swap_rate and loss_rate

    def report(self, summary, per_scan) -> str:
        if "stage" in summary.columns:
            summary = summary.filter(pl.col("stage") == self.name)
        return assoc_eval.success_table(summary)
