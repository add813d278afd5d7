"""Rerun views of the TDOA/FDOA replay (Kim et al. 2013; see ``docs/papers/tdoa-fdoa.md``).

x/y with every run's Gauss-Newton iterates, one frame per iteration (eqs. 15–17) | the velocity
plane with the estimates and the 50 % CRLB ellipse at the truth (eqs. 18, 22) | position RMSE
per iteration over the runs at the truth | the CEP planes of the geometry (Figs. 5–6).

Exposes ``blueprint(stage, trackers, dataset=None, run=0)`` and
``log_rerun(stage, rec, dataset, result, per_scan, run=0)`` (see :mod:`trackreplay.face.rerun_views`).
Drawing only: the estimates and the bound come from the replay's outputs (the stage's ``crlb``
extra), the run classes from :mod:`trackreplay.evaluators.tdoa_fdoa`, ellipses and CEP planes from
:mod:`trackreplay.cores.localisation`.
"""

from __future__ import annotations

import numpy as np

from trackreplay.evaluators import tdoa_fdoa as emitter_eval
from trackreplay.evaluators.tracking_metrics import rmse_per_scan
from trackreplay.face.timeline import color, north_up, north_up_bounds, rr, rrb
from trackreplay.vocabulary import UNDERDETERMINED

CEP_EXTENT_M = 50_000.0
CEP_STEP_M = 500.0
# Rerun's 2-D views draw +y downwards; world content lives under these entities, whose
# transform flips y so that north is up (hover still shows the true coordinates).
XY = "/xy/world"
VELOCITY_PLANE = "/velocity/world"


def blueprint(stage, trackers, dataset=None, run: int = 0):
    """x/y with the iterates per iteration | velocity plane | convergence | CEP planes."""
    bounds = None
    if dataset is not None:
        obs = stage.observations(dataset)
        pts = [obs["sensor_pos"][0, 0]]
        truth = stage.truth(dataset)
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


def log_rerun(stage, rec, dataset, result: dict, per_scan, run: int = 0) -> None:
    from trackreplay import design_values
    from trackreplay.cores.localisation.crlb import ellipse_points
    from trackreplay.face.rerun_tdoa_fdoa_cep_plane import log_cep_plane

    obs = stage.observations(dataset)
    R, E = obs["measured"].shape[:2]
    run = min(run, R - 1)
    truth = stage.truth(dataset)
    design = design_values.resolve(stage, dataset)
    stationary = bool(design["stationary_emitter"])
    crlb = result["tracks"].get(emitter_eval.CRLB_ENTRY)
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
        rec.log(f"{VELOCITY_PLANE}/truth", rr.Points2D(truth[run, :1, 2:], colors=[color("truth")], radii=[-7.0]),
                static=True)
    for name, out in result["tracks"].items():
        if name == emitter_eval.CRLB_ENTRY or "iterates" not in out or np.all((out["flags"] & UNDERDETERMINED) > 0):
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
                            columns=rr.Points2D.columns(positions=flat,
                                                        colors=np.tile(np.array(rgb, np.uint8), (len(flat), 1)),
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
        if truth is None or crlb is None:
            continue
        _, cov, singular = emitter_eval.bound_of(crlb, name)
        if not singular[run, 0]:
            c = cov[run, 0]
            rec.log(f"{XY}/crlb_50pct/{name}", rr.LineStrips2D([ellipse_points(truth[run, 0, :2], c[:2, :2])],
                                                             colors=[rgb], radii=[-1.5]), static=True)
            if c.shape[-1] == 4:
                rec.log(f"{VELOCITY_PLANE}/crlb_50pct/{name}", rr.LineStrips2D(
                    [ellipse_points(truth[run, 0, 2:], c[2:, 2:])], colors=[rgb], radii=[-1.5]), static=True)
        first = {k: v[:, :1] for k, v in out.items()}
        classes = emitter_eval.classes_of(first, {k: v[:, :1] for k, v in crlb.items()}, name, truth[:, :1])[:, 0]
        ok = classes == emitter_eval.TRUTH
        if ok.any():
            rmse = rmse_per_scan(it[ok][:, :, :2], truth[ok, 0, None, :2])  # per iteration
            rec.log(f"/convergence/{name}", rr.SeriesLines(names=[name], colors=[rgb]), static=True)
            rr.send_columns(f"/convergence/{name}", indexes=[rr.TimeColumn("iteration", sequence=np.arange(n_it))],
                            columns=rr.Scalars.columns(scalars=rmse), recording=rec)
    # CEP planes of this geometry (epoch 0, joint TDOA/FDOA, the emitter's true velocity)
    if truth is not None and "joint" in result["tracks"]:
        log_cep_plane(rec, _cep_plane_of(stage, dataset, run, stationary), obs["sensor_pos"][run, 0],
                      truth[run, 0, :2])


def prepare(stage, dataset) -> None:
    """The CEP planes of run 0 with the data set's own design, computed ahead (0.3 s on a
    2-core machine; :func:`trackreplay.face.rerun_views.prepare_views`): the recording shows run 0
    unless asked otherwise."""
    from trackreplay import design_values

    if stage.truth(dataset) is not None:
        _cep_plane_of(stage, dataset, 0, bool(design_values.resolve(stage, dataset)["stationary_emitter"]))


def _cep_plane_of(stage, dataset, run: int, stationary: bool):
    """The joint TDOA/FDOA CEP plane of ``run``'s geometry at epoch 0 and the emitter's true
    velocity, computed once per (run, stationarity) of a data set."""
    from trackreplay.cores.localisation.cep_plane import cep_plane, grid_axis

    key = ("cep_plane", run, stationary)
    if key not in dataset.cache:
        obs, truth = stage.observations(dataset), stage.truth(dataset)
        ax = grid_axis(CEP_EXTENT_M, CEP_STEP_M)
        dataset.cache[key] = cep_plane(obs["sensor_pos"][run, 0], obs["sensor_vel"][run, 0], obs["pairs"],
                                       truth[run, 0, 2:], float(obs["carrier_hz"][run, 0]), obs["sigma"][run, 0],
                                       ax, ax, "joint", stationary)
    return dataset.cache[key]
