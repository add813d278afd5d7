"""Stage: ULA snapshots → multi-target bearing tracks (Ryu, Lee & Lee 2001; ``docs/papers/array.md``).

Input channels: ``/array/snapshots`` (``snapshots``: complex M × Ns per run and scan),
optionally ``/array/truth`` (``angle_rad`` (N,), ``snr_db``). Output: ``/tracks/array/<tracker>``
with the family's outputs (``state`` [θ, θ̇] per track slot, ``covariance``, ``innovation``,
``gain``, ``flags``, …; see :mod:`trackreplay.trackers.array`). Only decoding, validation and
bookkeeping live here: the trackers (``proposed``, ``ryu``) are in
:mod:`trackreplay.trackers.array`, the scores and the Table 1 text in
:mod:`trackreplay.evaluators.array`, the Rerun views in :mod:`trackreplay.face.rerun_array`.
"""

from __future__ import annotations

import numpy as np

from trackreplay.evaluators import array as array_eval
from trackreplay import vocabulary as vocab
from trackreplay.errors import InputError, require_finite
from trackreplay.stages.base import BearingStage
from trackreplay.trackers.interface import ArraySnapshots, Param

SNAPSHOTS = vocab.CHANNELS["array_snapshots"]
TRUTH = vocab.CHANNELS["array_truth"]


class ArrayStage(BearingStage):
    name = "array"
    listing = (0, "deg")  # without truth, replay lists run 0's bearings per scan
    family = "array"
    # decoding (the array's d/λ) and evaluation (the swap/loss gate)
    design_keys = ("spacing_wavelengths", "track_gate_deg")
    params = (Param("spacing_wavelengths", None, "", "d/λ, element spacing in wavelengths", low=0.0, high=1e6),
              Param("track_gate_deg", None, "deg", "a track within this of a target follows it (swap/loss "
                    "accounting; docs/papers/array.md)", low=0.0, high=180.0))

    # ------------------------------------------------------------------ input

    def snapshots(self, dataset) -> np.ndarray:
        """Validated snapshots ``(runs, scans, M, Ns)``: complex, one fixed shape, finite
        (decoded and checked once per data set; read-only, shared by every tracker)."""
        if "array_snapshots" not in dataset.cache:
            X = self._decode_snapshots(dataset)
            X.flags.writeable = False
            dataset.cache["array_snapshots"] = X
        return dataset.cache["array_snapshots"]

    def _decode_snapshots(self, dataset) -> np.ndarray:
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

    def truth(self, dataset, shape):
        """True angles ``(runs, scans, N)`` and the SNR of each run ``(runs,)`` (None without truth)."""
        truth = dataset.channels.get(TRUTH)
        if truth is None:
            return None, None
        angles = truth.grid("angle_rad")
        if angles.shape[:2] != shape:
            raise InputError(f"{TRUTH} covers {angles.shape[:2]} run×scan, snapshots {shape}", dataset.path)
        truth.require_every_frame(*shape)  # a gap is a missing frame, named as such
        require_finite(f"{TRUTH} angle_rad", angles, dataset.path)
        snr = truth.grid("snr_db")[:, 0] if "snr_db" in truth.arrays else None
        return angles, snr

    def decode(self, dataset, design: dict) -> ArraySnapshots:
        X = self.snapshots(dataset)
        M, Ns = X.shape[2:]
        if "n_sources" in design:  # a built-in tracker's fixed N: can this array hold it?
            n_req = int(design["n_sources"])
            if n_req < 0:
                raise InputError("n_sources must be ≥ 0 (0 estimates it)")
            if n_req > M - 1:
                raise InputError(f"n_sources = {n_req} targets requested, but M − 1 = {M - 1} is the most "
                                 f"an array of {M} sensors can track (the noise subspace must not be empty)",
                                 dataset.path)
            if n_req > Ns:
                raise InputError(f"{Ns} snapshots per scan are fewer than the {n_req} targets requested", dataset.path)
        truth, _ = self.truth(dataset, X.shape[:2])
        return ArraySnapshots(snapshots=X, times_s=dataset.channel(SNAPSHOTS).times(),
                              spacing_wavelengths=float(design["spacing_wavelengths"]), truth_angle_rad=truth)

    # ------------------------------------------------------------------ evaluation

    def flop_table(self, trackers, n_sensors: int) -> dict:
        """``tracker → {N: FLOPs}`` of the paper's Table 1 columns (N = 5, 6), for the trackers
        that state their innovation's cost (``innovation_flops``)."""
        classes = {e.name: e.cls for e in self.entries()}
        table = {}
        for name in trackers:
            cost = getattr(classes.get(name), "innovation_flops", None)
            if cost is not None:
                table[name] = {n: cost(n_sensors, n) for n in array_eval.FLOP_TABLE_N if n < n_sensors}
        return table

    evaluation_defaults = {"ospa_cutoff_deg": 10.0, "ospa_order": 2.0, "assignment_gate_deg": 3.0}

    def reference(self, dataset, design: dict) -> dict:
        X = self.snapshots(dataset)
        truth, snr = self.truth(dataset, X.shape[:2])
        return {"runs": {"truth": truth, "snr_db": snr}, "fixed": {"n_sensors": X.shape[2]}}

    def score(self, reference: dict, result: dict, design: dict):
        runs, M = reference["runs"], reference["fixed"]["n_sensors"]
        return array_eval.evaluate(result["times"], result["tracks"], runs["truth"], runs["snr_db"],
                                   np.deg2rad(float(design["track_gate_deg"])), M,
                                   flop_table=self.flop_table(result["tracks"], M))

    def figures(self, per_scan, out_dir, title: str = "", result: dict | None = None, dataset=None) -> list:
        """``report.png``: the bearing–time record of run 0 (tracks and truth; no field edges: the
        array sees the whole half-plane, and ±90° would squeeze the tracks); ``errors.png``: the
        MSE, innovation RMS and subspace error per scan."""
        from trackreplay.evaluators.stage_figures import bearing_figures

        truth = None
        if result is not None and dataset is not None:
            truth, _ = self.truth(dataset, self.snapshots(dataset).shape[:2])
        return bearing_figures(per_scan, None if dataset is None else result, out_dir, title, truth,
                               ("mse_deg2", "rms_innovation_deg", "subspace_error_deg"))

    # the MSE and FLOP tables (and the counted FLOPs per step) repeat the snr_db and n_targets
    # scopes; the ratios are this layout's own
    replay_report_lines = ("proposed / Ryu FLOP ratio",)

    def report(self, summary, per_scan) -> str:
        """The paper's Table 1 layout (MSE per SNR, innovation FLOPs for N = 5, 6)."""
        part = summary.filter(summary["stage"] == self.name) if "stage" in summary.columns else summary
        rows = part.filter((part["tracker"] == "data") & (part["metric"] == "n_sensors"))
        M = int(rows["value"][0]) if rows.height else None
        trackers = [t for t in part["tracker"].unique(maintain_order=True).to_list() if t != "data"]
        table = self.flop_table(trackers, M) if M is not None else {}
        steps = {(t, n): cost["steps"] for t, by_n in table.items() for n, cost in by_n.items()}
        return array_eval.table1(part, per_scan, steps)
