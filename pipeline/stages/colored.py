"""Stage: positions with AR(1) coloured noise → AR estimator, KF, KF_DP, IMM, MIMM_K, PIMM.

Input channels: ``/colored/measurements`` (``position_m`` per axis) and, optionally,
``/colored/truth`` (``state`` = [p, v, a] per axis, ``alpha``). The thesis starts every filter at
the true state (Kwon 1997, ch. V); a file without truth (a recording) starts them from the
measurements instead (``track_start="auto"``, the default), and ``--set track_start=truth``
insists on the truth. Outputs on ``/tracks/colored/<tracker>``: see
:mod:`trackreplay.trackers.colored`; ``/tracks/colored/ar_estimator`` (:meth:`extras`) holds
``alpha``, ``alpha_biased``, ``noise_variance``, ``flags`` per axis and ``warm``.

Only decoding and bookkeeping live here: the trackers are in
:mod:`trackreplay.trackers.colored`, the metrics in :mod:`trackreplay.evaluators.colored`,
the Rerun views in :mod:`trackreplay.face.rerun_colored`. See
``docs/papers/colored.md``.
"""

from __future__ import annotations


import numpy as np

from trackreplay.evaluators import colored as colored_eval
from trackreplay import vocabulary as vocab
from trackreplay.errors import InputError, require_finite
from trackreplay.stage_scoring import model_recorded
from trackreplay.stages.base import Stage
from trackreplay.stages.evaluation_gates import gates_from_spread
from trackreplay.evaluators.standard import position_space
from trackreplay.trackers.colored import MODEL_NAMES, ar1_outputs, colored_noise_pcrb
from trackreplay.trackers.interface import ColoredPositions

MEASUREMENTS = vocab.CHANNELS["colored_measurements"]
TRUTH = vocab.CHANNELS["colored_truth"]


class ColoredStage(Stage):
    name = "colored"
    family = "colored"
    # what the stage itself uses: the AR estimator's output (extras) and the evaluator
    design_keys = ("measurement_variance_m2", "ar_forgetting_factor", "ar_zero_pole")

    # ------------------------------------------------------------------ inputs

    def decode_inputs(self, dataset):
        """``(z, times, truth_state, truth_alpha)`` checked, decoded once per data set; the truth
        arrays are None when the file has no ``/colored/truth``."""
        if "colored_inputs" not in dataset.cache:
            dataset.cache["colored_inputs"] = self._decode_inputs(dataset)
        return dataset.cache["colored_inputs"]

    def _decode_inputs(self, dataset):
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
            return z, times, None, None
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
        return z, times, state, alpha

    def decode(self, dataset, design: dict) -> ColoredPositions:
        z, times, state, _ = self.decode_inputs(dataset)
        if state is None and design.get("track_start") == "truth":
            raise InputError(f"missing channel {TRUTH!r}: the filters start at the true state (thesis ch. V); "
                             "replay with --set track_start=measurements to start from the measurements",
                             dataset.path)
        return ColoredPositions(position_m=z, times_s=times, truth_state=state)

    def extras(self, measurements, design: dict) -> dict:
        return {colored_eval.AR_TRACKER: ar1_outputs(measurements, design["ar_forgetting_factor"],
                                                     design["ar_zero_pole"])}

    # ------------------------------------------------------------------ evaluation

    # the kinematic scopes need truth
    declared_scopes, declared_scopes_need = ("overall", "manoeuvre", "constant_velocity"), "rmse_position_m"
    evaluation_defaults = {"ospa_cutoff_m": 100.0, "ospa_order": 2.0, "assignment_gate_m": 50.0}

    def evaluation_defaults_from_data(self, dataset, design: dict) -> dict:
        """The matching gate from the measurement noise (docs/evaluation.md, "Evaluation design
        values"): each axis of a measured position has variance ``measurement_variance_m2`` (the
        coloured noise's stationary variance), so its error in the plane has spread √(2σ²); the
        gate holds all but 10⁻⁴ of a two-dimensional Gaussian of it (4.29 ×), rounded up to two
        significant digits, and the cut-off c is twice it (:mod:`trackreplay.stages.evaluation_gates`).
        A recording that does not say the variance keeps the fixed values."""
        variance = design.get("measurement_variance_m2")
        return {} if variance is None else gates_from_spread(float(np.sqrt(2.0 * float(variance))), 2, "m")

    def reference(self, dataset, design: dict) -> dict:
        _, times, state, alpha = self.decode_inputs(dataset)
        fixed = {}
        recorded = dataset.scenario.get("params", {})
        q = recorded.get("process_noise_variance")
        if model_recorded(dataset) and state is not None and alpha is not None and q is not None and float(q) > 0 \
                and "measurement_variance_m2" in recorded:
            # the bound needs the truth's own noise, which only a simulation records; without
            # process noise the truth is deterministic and, from a true start, the bound is zero
            bound = colored_noise_pcrb(alpha, times, float(q), float(recorded["measurement_variance_m2"]))
            axes = state.shape[-1] // 3
            fixed["pcrb_position_var"] = axes * bound[:, 0, 0]
            fixed["pcrb_velocity_var"] = axes * bound[:, 1, 1]
        return {"runs": {"truth_state": state, "truth_alpha": alpha}, "fixed": fixed}

    def score(self, reference: dict, result: dict, design: dict):
        runs, fixed = reference["runs"], reference.get("fixed", {})
        return colored_eval.evaluate(result["times"], result["tracks"], runs["truth_state"], runs["truth_alpha"],
                                     # unknown on a recording that does not say it: the AR
                                     # estimator's noise variance is then not scored
                                     float("nan") if design["measurement_variance_m2"] is None
                                     else float(design["measurement_variance_m2"]), float(design["ar_forgetting_factor"]),
                                     list(MODEL_NAMES), fixed.get("pcrb_position_var"), fixed.get("pcrb_velocity_var"))

    def standard_space(self, design: dict, reference: dict | None = None):
        state = None if reference is None else reference["runs"]["truth_state"]
        n = 3 if state is None else state.shape[-1]
        # state [p, v, a] per axis: the positions are every third component
        return position_space(design, truth_components=range(n), position_components=range(0, n, 3))

    def standard_truth(self, reference: dict):
        return reference["runs"]["truth_state"]

    report_metrics = ("rmse_position_m", "rmse_velocity_mps")

    def figures(self, per_scan, out_dir, title: str = "", result: dict | None = None, dataset=None) -> list:
        """``report.png``: the RMSE per scan (with truth); ``positions.png``: run 0's position
        per axis against time, measurements, truth and every filter, and each IMM's model
        probabilities (the report figure when the data have no truth); and the thesis's figures."""
        from pathlib import Path

        from trackreplay.evaluators.stage_figures import positions_figure

        paths = super().figures(per_scan, out_dir, title)
        if result is not None and dataset is not None:
            z, times, state, _ = self.decode_inputs(dataset)
            path = Path(out_dir) / ("positions.png" if paths else "report.png")
            paths.append(positions_figure(result, path, times, z[0], None if state is None else state[0], title,
                                          MODEL_NAMES))
        return paths + colored_eval.write_figures(per_scan, out_dir, title=title)

    # the RMSE, model-probability and AR tables repeat the scopes of the generic tables
    replay_report_lines = ("PIMM vs MIMM_K",)

    def report(self, summary, per_scan) -> str:
        part = summary.filter(summary["stage"] == self.name) if "stage" in summary.columns else summary
        trackers = list(self.trackers)
        trackers += [t for t in part["tracker"].unique(maintain_order=True).to_list()
                     if t not in trackers and not t.startswith(colored_eval.AR_TRACKER)]
        return colored_eval.report_text(part, trackers, list(MODEL_NAMES))
