"""Stage: TDOA/FDOA measurements → Gauss-Newton emitter position and velocity.

Input channels: ``/emitter/measurements`` (``tdoa_s``, ``fdoa_hz``, ``sigma_tdoa_s``,
``sigma_fdoa_hz`` per pair, ``pairs`` (N, 2), ``carrier_hz``) and ``/emitter/sensors``
(``position_m``, ``velocity_mps`` (M, 2)) per run and epoch; optionally ``/emitter/prior``
(``state``: the initial guess) and ``/emitter/truth`` (``state``).

Estimators (trackers), all runs and epochs in one vectorised Gauss-Newton pass each:
``joint`` (TDOA + FDOA, the paper's method), ``tdoa`` (TDOA only: position) and ``fdoa`` (FDOA
only). An estimator with fewer independent equations than unknowns for the file's pair list
(e.g. FDOA only, three sensors, moving emitter: 2 equations, 4 unknowns) is not run: its
outputs are NaN and every run carries the ``underdetermined`` flag.

Output ``/emitter/estimates/<estimator>``: ``state`` (4), ``covariance`` (4×4 at the estimate),
``iterates`` (iterations + 1, 4), ``cost``, ``iterations``, ``step_sigma``, ``flags`` (see
:mod:`pipeline.cores.localisation.gauss_newton`). Only I/O and bookkeeping live here.
"""

from __future__ import annotations

import numpy as np

from evaluators import emitter_localisation as emitter_eval
from pipeline.cores.localisation.coarse_grid_search import coarse_grid_start
from pipeline.cores.localisation.crlb import ellipse_points
from evaluators.tracking_metrics import rmse_per_scan
from pipeline.errors import InputError, require_finite
from pipeline.cores.localisation.gauss_newton import UNDERDETERMINED, gauss_newton
from pipeline.stages.base import Stage
from pipeline.cores.localisation.tdoa_fdoa_model import (MEASUREMENT_KINDS, measurement_model,
                                      measurement_rows, underdetermined_reason, unknowns)
from pipeline.face.timeline import color, north_up, north_up_bounds, rr, rrb

MEASUREMENTS = "/emitter/measurements"
SENSORS = "/emitter/sensors"
PRIOR = "/emitter/prior"
TRUTH = "/emitter/truth"
CEP_EXTENT_M = 50_000.0
CEP_STEP_M = 500.0
# Rerun's 2-D views draw +y downwards; world content lives under these entities, whose
# transform flips y so that north is up (hover still shows the true coordinates).
XY = "/xy/world"
VELOCITY_PLANE = "/velocity/world"


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


class EmitterLocalisationStage(Stage):
    name = "tdoa-fdoa"
    input_topics = (MEASUREMENTS, SENSORS)
    trackers = MEASUREMENT_KINDS
    output_prefix = "/emitter/estimates/"
    scenario = "tdoa-fdoa"
    design_keys = ("initial_guess", "iterations", "step_tolerance_sigma", "stationary_emitter",
                   "grid_extent_m", "grid_step_m", "divergence_range_m")

    def _truth(self, dataset, shape):
        truth = dataset.channels.get(TRUTH)
        if truth is None:
            return None
        state = truth.grid("state")
        if state.shape[:2] != shape:
            raise InputError(f"{TRUTH} covers {state.shape[:2]} run×epoch, measurements {shape}", dataset.path)
        if state.shape[2:] != (4,):
            raise InputError(f"{TRUTH} state must be [x, y, vx, vy] (4 values) per frame, got frames of shape "
                             f"{state.shape[2:]}", dataset.path)
        require_finite(f"{TRUTH} state", state, dataset.path)
        return state

    def _start(self, dataset, obs, kind, design, rows, free):
        R, E = obs["measured"].shape[:2]
        if design["initial_guess"] == "prior":
            prior = dataset.channels.get(PRIOR)
            if prior is None:
                raise InputError(f"no {PRIOR} channel for initial_guess=prior; use --set initial_guess=grid", dataset.path)
            start = prior.grid("state")
            if start.shape[:2] != (R, E):
                raise InputError(f"{PRIOR} covers {start.shape[:2]} run×epoch, measurements {(R, E)}", dataset.path)
            if start.shape[2:] != (4,):
                raise InputError(f"{PRIOR} state must be [x, y, vx, vy] (4 values) per frame, got frames of shape "
                                 f"{start.shape[2:]}", dataset.path)
            require_finite(f"{PRIOR} state", start, dataset.path)
            return start.reshape(R * E, 4).copy()
        if design["initial_guess"] == "grid":
            flat = {k: obs[k].reshape(R * E, *obs[k].shape[2:]) for k in ("measured", "sigma", "sensor_pos", "sensor_vel")}
            return coarse_grid_start(flat["measured"], flat["sigma"], flat["sensor_pos"], flat["sensor_vel"],
                                     obs["pairs"], obs["carrier_hz"].reshape(-1), rows, len(free) == 4,
                                     float(design["grid_extent_m"]), float(design["grid_step_m"]))
        raise InputError(f"initial_guess must be 'prior' or 'grid', not {design['initial_guess']!r}")

    def run(self, dataset, trackers, design: dict) -> dict:
        obs = read_observations(dataset)
        R, E = obs["measured"].shape[:2]
        stationary = bool(design["stationary_emitter"])
        iterations = int(design["iterations"])
        if iterations < 1:
            raise InputError("iterations must be ≥ 1")
        M = obs["sensor_pos"].shape[2]
        reasons = {k: underdetermined_reason(k, obs["pairs"], M, stationary) for k in trackers}
        if all(reasons.values()):
            raise InputError("; ".join(reasons.values()), dataset.path)
        pairs = obs["pairs"]
        limit = float(design["divergence_range_m"])
        outputs = {}
        for kind in trackers:
            if reasons[kind]:
                outputs[kind] = self._underdetermined_output(R, E, iterations)
                continue
            rows = measurement_rows(kind, len(pairs))
            free = unknowns(kind, stationary)
            theta0 = self._start(dataset, obs, kind, design, rows, free)
            if stationary:
                theta0[:, 2:] = 0.0

            def model(theta, sensor_pos, sensor_vel, carrier_hz, rows=rows):
                g, H = measurement_model(theta, sensor_pos, sensor_vel, pairs, carrier_hz)
                return g[:, rows], H[:, rows]

            def diverged(theta, sensor_pos, sensor_vel, carrier_hz):
                centre = sensor_pos.mean(axis=1)
                return np.linalg.norm(theta[:, :2] - centre, axis=1) > limit

            batch = {"sensor_pos": obs["sensor_pos"].reshape(R * E, M, 2),
                     "sensor_vel": obs["sensor_vel"].reshape(R * E, M, 2),
                     "carrier_hz": obs["carrier_hz"].reshape(R * E)}
            res = gauss_newton(model, theta0, obs["measured"].reshape(R * E, -1)[:, rows],
                               obs["sigma"].reshape(R * E, -1)[:, rows], free=free, iterations=iterations,
                               step_tolerance=float(design["step_tolerance_sigma"]), batch=batch, diverged=diverged)
            state, iterates = res.theta, res.iterates
            if kind == "tdoa" and not stationary:  # velocity is not estimated, not "known"
                state[:, 2:] = np.nan
                iterates[:, :, 2:] = np.nan
            outputs[kind] = {
                "state": state.reshape(R, E, 4), "covariance": res.covariance.reshape(R, E, 4, 4),
                "iterates": iterates.reshape(R, E, iterations + 1, 4), "cost": res.cost.reshape(R, E),
                "iterations": res.iterations.reshape(R, E).astype(np.int32),
                "step_sigma": res.step_sigma.reshape(R, E), "flags": res.flags.reshape(R, E),
            }
        return {"times": obs["times"], "tracks": outputs}

    @staticmethod
    def _underdetermined_output(R, E, iterations):
        return {"state": np.full((R, E, 4), np.nan), "covariance": np.full((R, E, 4, 4), np.nan),
                "iterates": np.full((R, E, iterations + 1, 4), np.nan), "cost": np.full((R, E), np.nan),
                "iterations": np.zeros((R, E), np.int32), "step_sigma": np.full((R, E), np.nan),
                "flags": np.full((R, E), UNDERDETERMINED, np.uint8)}

    def outputs_from_dataset(self, out_dataset) -> dict:
        result = super().outputs_from_dataset(out_dataset)
        for out in result["tracks"].values():
            if "iterations" in out:
                out["iterations"] = np.nan_to_num(out["iterations"]).astype(np.int32)
        return result

    def evaluate(self, dataset, result: dict, design: dict):
        obs = read_observations(dataset)
        truth = self._truth(dataset, obs["measured"].shape[:2])
        return emitter_eval.evaluate(result["times"], result["tracks"], obs, truth, bool(design["stationary_emitter"]))

    def report(self, summary, per_scan) -> str:
        return emitter_eval.report(summary, per_scan)

    # ------------------------------------------------------------------ Rerun

    def blueprint(self, trackers, dataset=None, run: int = 0):
        """x/y with the iterates per iteration | velocity plane | convergence | CEP planes."""
        bounds = None
        if dataset is not None:
            obs = read_observations(dataset)
            pts = [obs["sensor_pos"][0, 0]]
            truth = self._truth(dataset, obs["measured"].shape[:2])
            if truth is not None:
                pts.append(truth[0, :1, :2])
            xy = np.concatenate(pts)
            lo, hi = xy.min(axis=0), xy.max(axis=0)
            pad = 0.15 * float(max(hi - lo)) + 500.0
            bounds = north_up_bounds(lo, hi, pad)
        return rrb.Blueprint(
            rrb.Horizontal(
                rrb.Spatial2DView(origin="/xy", name="position x / y (m): iterates per iteration", visual_bounds=bounds),
                rrb.Vertical(
                    rrb.Spatial2DView(origin="/velocity", name="velocity (m/s): estimates and 50 % CRLB ellipse"),
                    rrb.TimeSeriesView(origin="/convergence", name="position RMSE (m) vs iteration",
                                       plot_legend=rrb.PlotLegend(corner=rrb.Corner2D.RightTop, visible=True)),
                ),
                rrb.Vertical(
                    rrb.Spatial2DView(origin="/cep/position", name="position CEP (m), contours 50/100/200 m"),
                    rrb.Spatial2DView(origin="/cep/velocity", name="velocity CEP (m/s), contours 5/10/15 m/s"),
                ),
                column_shares=[2, 1.3, 1.3],
            ),
            rrb.TimePanel(state="collapsed"),
            collapse_panels=True,
        )

    def log_rerun(self, rec, dataset, result: dict, per_scan, run: int = 0) -> None:
        from pipeline.cores.localisation.cep_plane import cep_plane, grid_axis
        from pipeline.face.cep_plane_views import log_cep_plane

        obs = read_observations(dataset)
        R, E = obs["measured"].shape[:2]
        run = min(run, R - 1)
        truth = self._truth(dataset, (R, E))
        design = self.design(dataset)
        stationary = bool(design["stationary_emitter"])
        sensors = obs["sensor_pos"][run, 0]
        for entity in (XY, VELOCITY_PLANE):
            north_up(rec, entity)
        rec.log(f"{XY}/sensors", rr.Points2D(sensors, colors=[(250, 250, 250)], radii=[-6.0],
                                           labels=[f"s{i}" for i in range(len(sensors))]), static=True)
        rec.log(f"{XY}/sensors/velocity", rr.Arrows2D(origins=sensors, vectors=obs["sensor_vel"][run, 0] * 5.0,
                                                    colors=[(180, 180, 180)]), static=True)
        if truth is not None:
            rec.log(f"{XY}/truth", rr.Points2D(truth[run, :1, :2], colors=[color("truth")], radii=[-7.0],
                                             labels=["emitter"]), static=True)
            rec.log(f"{VELOCITY_PLANE}/truth", rr.Points2D(truth[run, :1, 2:], colors=[color("truth")], radii=[-7.0]), static=True)
        for name, out in result["tracks"].items():
            if np.all((out["flags"] & UNDERDETERMINED) > 0):
                continue
            rgb = color(name)
            it = out["iterates"][:, 0]  # (runs, iterations + 1, 4), epoch 0
            n_it = it.shape[1]
            # the estimate cloud of every run, one frame per iteration
            clouds = [it[:, k, :2][np.all(np.isfinite(it[:, k, :2]), axis=1)] for k in range(n_it)]
            lengths = np.array([len(c) for c in clouds])
            if lengths.sum():
                flat = np.concatenate(clouds)
                rr.send_columns(f"{XY}/estimates/{name}", indexes=[rr.TimeColumn("iteration", sequence=np.arange(n_it))],
                                columns=rr.Points2D.columns(positions=flat, colors=np.tile(np.array(rgb, np.uint8), (len(flat), 1)),
                                                            radii=np.full(len(flat), -1.5, np.float32)).partition(lengths),
                                recording=rec)
            path = it[run, :, :2]
            path = path[np.all(np.isfinite(path), axis=1)]
            if len(path) > 1:
                rec.log(f"{XY}/run_{run}/{name}", rr.LineStrips2D([path], colors=[rgb], radii=[-1.0]), static=True)
            final_v = out["state"][:, 0, 2:]
            final_v = final_v[np.all(np.isfinite(final_v), axis=1)]
            if len(final_v) and not stationary:
                rec.log(f"{VELOCITY_PLANE}/estimates/{name}", rr.Points2D(final_v, colors=[rgb], radii=[-1.5]), static=True)
            if truth is None:
                continue
            _, cov, singular = emitter_eval.truth_geometry(truth[run, :1], obs["sensor_pos"][run, :1], obs["sensor_vel"][run, :1],
                                                           obs["pairs"], obs["carrier_hz"][run, :1], obs["sigma"][run, :1],
                                                           name, stationary)
            if not singular[0]:
                rec.log(f"{XY}/crlb_50pct/{name}", rr.LineStrips2D([ellipse_points(truth[run, 0, :2], cov[0, :2, :2])],
                                                                 colors=[rgb], radii=[-1.5]), static=True)
                if cov.shape[-1] == 4:
                    rec.log(f"{VELOCITY_PLANE}/crlb_50pct/{name}", rr.LineStrips2D(
                        [ellipse_points(truth[run, 0, 2:], cov[0, 2:, 2:])], colors=[rgb], radii=[-1.5]), static=True)
            first_epoch = {k: obs[k][:, :1] for k in ("sigma", "carrier_hz", "sensor_pos", "sensor_vel")}
            first_epoch["pairs"] = obs["pairs"]
            classes = emitter_eval.classes_of({k: v[:, :1] for k, v in out.items()}, name, first_epoch,
                                              truth[:, :1], stationary)[:, 0]
            ok = classes == emitter_eval.TRUTH
            if ok.any():
                rmse = rmse_per_scan(it[ok][:, :, :2], truth[ok, 0, None, :2])  # per iteration
                rec.log(f"/convergence/{name}", rr.SeriesLines(names=[name], colors=[rgb]), static=True)
                rr.send_columns(f"/convergence/{name}", indexes=[rr.TimeColumn("iteration", sequence=np.arange(n_it))],
                                columns=rr.Scalars.columns(scalars=rmse), recording=rec)
        # CEP planes of this geometry (epoch 0, joint TDOA/FDOA, the emitter's true velocity)
        if truth is not None and "joint" in result["tracks"]:
            ax = grid_axis(CEP_EXTENT_M, CEP_STEP_M)
            plane = cep_plane(obs["sensor_pos"][run, 0], obs["sensor_vel"][run, 0], obs["pairs"], truth[run, 0, 2:],
                              float(obs["carrier_hz"][run, 0]), obs["sigma"][run, 0], ax, ax, "joint", stationary)
            log_cep_plane(rec, plane, obs["sensor_pos"][run, 0], truth[run, 0, :2])
