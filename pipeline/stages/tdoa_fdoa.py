"""Stage: TDOA/FDOA measurements → Gauss-Newton emitter position and velocity (Kim et al. 2013).

Input channels: ``/emitter/measurements`` (``tdoa_s``, ``fdoa_hz``, ``sigma_tdoa_s``,
``sigma_fdoa_hz`` per pair, ``pairs`` (N, 2), ``carrier_hz``) and ``/emitter/sensors``
(``position_m``, ``velocity_mps`` (M, 2)) per run and epoch; optionally ``/emitter/prior``
(``state``: the initial guess) and ``/emitter/truth`` (``state``). They are decoded once into a
:class:`~trackreplay.trackers.interface.TdoaFdoa` (with the truth beside it, for the bound).

Outputs on ``/tracks/tdoa-fdoa/<estimator>``: see :mod:`trackreplay.trackers.tdoa_fdoa` (the
``joint``, ``tdoa`` and ``fdoa`` estimators, or any plugged tracker of the ``tdoa-fdoa``
family). Beside them (:meth:`TdoaFdoaStage.extras`), ``/tracks/tdoa-fdoa/crlb``
holds the CRLB at the true state for every estimator kind (eq. 18; ``crlb_covariance_<kind>``,
``whitened_jacobian_<kind>``, ``crlb_singular_<kind>``, from
:func:`trackreplay.cores.localisation.tdoa_fdoa_crlb.truth_bounds`), which the evaluator's run
classification and efficiency need.

A file on which no estimator can run (fewer independent equations than unknowns for every
kind) is refused with the reason. Only decoding and bookkeeping live here: the estimators are
in :mod:`trackreplay.trackers.tdoa_fdoa`, the metrics in :mod:`trackreplay.evaluators.tdoa_fdoa`, the
Rerun views in :mod:`trackreplay.face.rerun_tdoa_fdoa`. See ``docs/papers/tdoa-fdoa.md``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import numpy as np

from trackreplay.evaluators import tdoa_fdoa as emitter_eval
from trackreplay import vocabulary as vocab
from trackreplay.cores.localisation.tdoa_fdoa_crlb import truth_bounds
from trackreplay.cores.localisation.tdoa_fdoa_model import MEASUREMENT_KINDS, equivalent_sigmas, underdetermined_reason
from trackreplay.errors import InputError, require_finite
from trackreplay.stages.base import Stage
from trackreplay.stages.evaluation_gates import gates_from_spread
from trackreplay.evaluators.standard import position_space
from trackreplay.trackers.interface import TdoaFdoa

MEASUREMENTS = vocab.CHANNELS["emitter_measurements"]
SENSORS = vocab.CHANNELS["emitter_sensors"]
PRIOR = vocab.CHANNELS["emitter_prior"]
TRUTH = vocab.CHANNELS["emitter_truth"]


@dataclass
class TdoaFdoaWithTruth(TdoaFdoa):
    """:class:`~trackreplay.trackers.interface.TdoaFdoa` with the true state ``truth_state``
    (R, E, 4) or None beside it, for the stage's CRLB extra (the estimators do not read it)."""

    truth_state: np.ndarray | None = field(default=None, metadata={"per_run": True})


def read_observations(dataset) -> dict:
    """Measurements, σ, pairs, carrier and sensors as (runs, epochs, ...) arrays, checked."""
    ch = dataset.channel(MEASUREMENTS)
    sens = dataset.channel(SENSORS)
    path = dataset.path
    arrays = {}
    # ChannelData.grid names a missing array, and a shape that changes between frames, itself
    for name in ("tdoa_s", "fdoa_hz", "sigma_tdoa_s", "sigma_fdoa_hz", "pairs", "carrier_hz"):
        arrays[name] = ch.grid(name)
    for name in ("position_m", "velocity_mps"):
        arrays[name] = sens.grid(name)
    for name, a in arrays.items():
        require_finite(f"{MEASUREMENTS if name not in ('position_m', 'velocity_mps') else SENSORS} {name}", a, path)
    for name in ("tdoa_s", "fdoa_hz", "sigma_tdoa_s", "sigma_fdoa_hz"):
        if arrays[name].ndim != 3:
            raise InputError(f"{MEASUREMENTS} {name} must be 1-D (one value per pair) in every frame, got frames of "
                             f"shape {arrays[name].shape[2:]}", path)
    if arrays["carrier_hz"].ndim != 2:
        raise InputError(f"{MEASUREMENTS} carrier_hz must be one number per frame, got frames of shape "
                         f"{arrays['carrier_hz'].shape[2:]}", path)
    for name in ("position_m", "velocity_mps"):
        a = arrays[name]
        if a.ndim != 4 or a.shape[3] != 2:
            raise InputError(f"{SENSORS} {name} must be (sensors, 2) in every frame, got frames of shape {a.shape[2:]}",
                             path)
    if arrays["velocity_mps"].shape != arrays["position_m"].shape:
        raise InputError(f"{SENSORS} velocity_mps {arrays['velocity_mps'].shape[2:]} and position_m "
                         f"{arrays['position_m'].shape[2:]} differ in shape", path)
    shape = arrays["tdoa_s"].shape[:2]
    if arrays["position_m"].shape[:2] != shape:
        raise InputError(f"{SENSORS} covers {arrays['position_m'].shape[:2]} run×epoch, measurements {shape}", path)
    pairs_all = arrays["pairs"]
    pairs = pairs_all[0, 0].astype(np.int64)
    if np.any(pairs_all != pairs):
        raise InputError(f"{MEASUREMENTS} pairs change between frames (one pair list per file)", path)
    n_sensors = arrays["position_m"].shape[2]
    if pairs.ndim != 2 or pairs.shape[1] != 2 or pairs.shape[0] == 0 or pairs.min() < 0 \
            or pairs.max() >= n_sensors or np.any(pairs[:, 0] == pairs[:, 1]):
        raise InputError(f"{MEASUREMENTS} pairs must be a non-empty (N, 2) list of distinct sensor indexes "
                         f"0..{n_sensors - 1}", path)
    n = len(pairs)
    if arrays["tdoa_s"].shape[2] != n or arrays["fdoa_hz"].shape[2] != n:
        raise InputError(f"{MEASUREMENTS} has {n} pairs but {arrays['tdoa_s'].shape[2]} TDOAs / "
                         f"{arrays['fdoa_hz'].shape[2]} FDOAs", path)
    if arrays["sigma_tdoa_s"].shape[2] != n or arrays["sigma_fdoa_hz"].shape[2] != n:
        raise InputError(f"{MEASUREMENTS} has {n} pairs but {arrays['sigma_tdoa_s'].shape[2]} TDOA σ / "
                         f"{arrays['sigma_fdoa_hz'].shape[2]} FDOA σ values", path)
    sigma = np.concatenate([arrays["sigma_tdoa_s"], arrays["sigma_fdoa_hz"]], axis=-1)
    if np.any(sigma <= 0):
        raise InputError(f"{MEASUREMENTS} holds non-positive sigma values", path)
    if np.any(arrays["carrier_hz"] <= 0):
        raise InputError(f"{MEASUREMENTS} holds a non-positive carrier_hz", path)
    return {"measured": np.concatenate([arrays["tdoa_s"], arrays["fdoa_hz"]], axis=-1), "sigma": sigma,
            "pairs": pairs, "carrier_hz": arrays["carrier_hz"], "sensor_pos": arrays["position_m"],
            "sensor_vel": arrays["velocity_mps"], "times": ch.times()}


def _state_channel(dataset, topic: str, shape) -> np.ndarray:
    """``state`` of a truth or prior channel as (runs, epochs, 4), checked against ``shape``."""
    state = dataset.channels[topic].grid("state")
    if state.shape[:2] == shape:
        dataset.channels[topic].require_every_frame(*shape)  # a gap is a missing frame, named as such
    if state.shape[:2] != shape:
        raise InputError(f"{topic} covers {state.shape[:2]} run×epoch, measurements {shape}", dataset.path)
    if state.shape[2:] != (4,):
        raise InputError(f"{topic} state must be [x, y, vx, vy] (4 values) per frame, got frames of shape "
                         f"{state.shape[2:]}", dataset.path)
    require_finite(f"{topic} state", state, dataset.path)
    return state


class TdoaFdoaStage(Stage):
    name = "tdoa-fdoa"
    family = "tdoa-fdoa"
    # what the stage itself uses: the start the decoder checks for, and the unknowns of the bound
    design_keys = ("initial_guess", "stationary_emitter")
    # the figures scatter every run's fix and the Rerun views show the convergence over runs
    views_read_all_runs = True

    # ------------------------------------------------------------------ inputs

    def observations(self, dataset) -> dict:
        """:func:`read_observations`, decoded and checked once per data set."""
        if "emitter_observations" not in dataset.cache:
            dataset.cache["emitter_observations"] = read_observations(dataset)
        return dataset.cache["emitter_observations"]

    def truth(self, dataset):
        """``/emitter/truth`` state (runs, epochs, 4), checked, or None without the channel."""
        if "emitter_truth" not in dataset.cache:
            shape = self.observations(dataset)["measured"].shape[:2]
            dataset.cache["emitter_truth"] = (_state_channel(dataset, TRUTH, shape) if TRUTH in dataset.channels
                                              else None)
        return dataset.cache["emitter_truth"]

    def decode(self, dataset, design: dict) -> TdoaFdoaWithTruth:
        obs = self.observations(dataset)
        shape = obs["measured"].shape[:2]
        stationary = bool(design["stationary_emitter"])
        reasons = [underdetermined_reason(k, obs["pairs"], obs["sensor_pos"].shape[2], stationary)
                   for k in MEASUREMENT_KINDS]
        if all(reasons):
            raise InputError("; ".join(reasons), dataset.path)
        prior = None
        if design["initial_guess"] == "prior":
            if PRIOR not in dataset.channels:
                raise InputError(f"no {PRIOR} channel for initial_guess=prior; use --set initial_guess=grid",
                                 dataset.path)
            prior = _state_channel(dataset, PRIOR, shape)
        return TdoaFdoaWithTruth(measured=obs["measured"], sigma=obs["sigma"], carrier_hz=obs["carrier_hz"],
                                 sensor_position_m=obs["sensor_pos"], sensor_velocity_mps=obs["sensor_vel"],
                                 times_s=obs["times"], pairs=obs["pairs"], prior_state=prior,
                                 truth_state=self.truth(dataset))

    def extras(self, measurements, design: dict) -> dict:
        m = measurements
        return {emitter_eval.CRLB_ENTRY: truth_bounds(getattr(m, "truth_state", None), m.sensor_position_m,
                                                      m.sensor_velocity_mps, m.pairs, m.carrier_hz, m.sigma,
                                                      bool(design["stationary_emitter"]))}

    # ------------------------------------------------------------------ evaluation

    def reference(self, dataset, design: dict) -> dict:
        obs = self.observations(dataset)
        sigma_range, sigma_rate = equivalent_sigmas(obs["sigma"], obs["carrier_hz"], len(obs["pairs"]))
        truth = self.truth(dataset)
        return {"runs": {} if truth is None else {"truth_state": truth},
                "fixed": {"sigma_range_m": sigma_range, "sigma_rate_mps": sigma_rate}}

    def score(self, reference: dict, result: dict, design: dict):
        fixed = reference["fixed"]
        return emitter_eval.evaluate(result["times"], result["tracks"], reference["runs"].get("truth_state"),
                                     fixed["sigma_range_m"], fixed["sigma_rate_mps"])

    # every estimator gives the position; the velocity not always (TDOA alone), so the standard
    # measures compare positions
    # localisation errors are hundreds of metres at the demo's geometry (its √tr CRLB ≈ 660 m)
    evaluation_defaults = {"ospa_cutoff_m": 5000.0, "ospa_order": 2.0, "assignment_gate_m": 2000.0}

    def evaluation_defaults_from_data(self, dataset, design: dict) -> dict:
        """The matching gate from the measurements' noise and the geometry (docs/evaluation.md,
        "Evaluation design values"): the spread of a fix is √tr of the joint TDOA/FDOA CRLB's
        position block at the truth (the σ of every pair, the carrier and the sensors' positions
        are in the measurements), the largest over runs and epochs where it exists; the gate holds
        all but 10⁻⁴ of a two-dimensional Gaussian of it (4.29 ×), rounded up to two significant
        digits, and the cut-off c is twice it (:mod:`trackreplay.stages.evaluation_gates`). The
        joint bound is the tightest: an estimator of one kind alone that lands outside its gate
        is farther off than the data allow. Without truth, or where no bound exists (a singular
        geometry everywhere), the fixed values."""
        truth = self.truth(dataset)
        if truth is None:
            return {}
        obs = self.observations(dataset)
        bounds = truth_bounds(truth, obs["sensor_pos"], obs["sensor_vel"], obs["pairs"], obs["carrier_hz"],
                              obs["sigma"], bool(design["stationary_emitter"]), kinds=("joint",))
        cov = bounds["crlb_covariance_joint"]
        spread = np.sqrt(cov[..., 0, 0] + cov[..., 1, 1])[~bounds["crlb_singular_joint"]]
        spread = spread[np.isfinite(spread)]
        return gates_from_spread(float(spread.max()), 2, "m") if spread.size else {}

    def standard_space(self, design: dict, reference: dict | None = None):
        return position_space(design, truth_components=(0, 1), position_components=(0, 1))

    def standard_truth(self, reference: dict):
        truth = reference["runs"].get("truth_state")
        return None if truth is None else truth[..., :2]

    def figures(self, per_scan, out_dir, title: str = "", result: dict | None = None, dataset=None) -> list:
        """``report.png``: the geometry of the first scan (sensors with their velocity, the
        emitter, every estimator's estimates over the runs with their 95 % ellipse, the joint
        CRLB's ellipse around the truth); with several noise levels (scans) also ``fig7.png``,
        RMSE and CRLB against the equivalent range noise (cf. Ho & Chan 1997, Fig. 7)."""
        from trackreplay.evaluators.stage_figures import emitter_geometry_figure, noise_study_figure

        paths = []
        if result is not None and dataset is not None:
            sensors = dataset.channel(SENSORS)
            paths.append(emitter_geometry_figure(result, out_dir, sensors.grid("position_m"),
                                                 sensors.grid("velocity_mps"), self.truth(dataset), title))
        fig7 = noise_study_figure(per_scan, out_dir, title)
        return paths + ([fig7] if fig7 is not None else [])

    replay_report_lines = ()  # every table of the layout repeats a scope of the generic tables
    per_scan_axis = ("sigma_range_m", True)  # the scans of a noise study are its noise levels

    def report(self, summary, per_scan) -> str:
        return emitter_eval.report(summary, per_scan)
