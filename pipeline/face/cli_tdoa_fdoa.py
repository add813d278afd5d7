"""``replay crlb`` and ``replay cep-plane``: the TDOA/FDOA bound at one geometry, and over a grid.

Both read the ``tdoa-fdoa`` scenario (presets ``--geometry line|triangle``, ``--emitter 1|2|3``,
any parameter with ``--set name=value``), so a bound and a simulated data set always describe
the same configuration. Kim et al. (2013), eqs. 18–22 and Figs. 5–6; see
``docs/papers/tdoa-fdoa.md``. The face holds no numerics: the numbers come from
:mod:`trackreplay.cores.localisation.tdoa_fdoa_crlb` and :mod:`trackreplay.cores.localisation.cep_plane`,
the pictures from :mod:`trackreplay.face.rerun_tdoa_fdoa_cep_plane`.
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import click

from trackreplay.errors import InputError
from trackreplay.paths import refuse_input_overwrite

ESTIMATORS = ("joint", "tdoa", "fdoa")


def _scenario(name, geometry, emitter, sets):
    from trackreplay.recorders.scenarios import load_scenario, parse_assignments
    from trackreplay.recorders.tdoa_fdoa import resolve

    overrides = parse_assignments(sets)
    if geometry is not None:
        overrides["geometry"] = geometry
    if emitter is not None:
        overrides["emitter"] = str(emitter)
    sc = load_scenario(name).with_overrides(overrides)
    return sc, resolve(sc.params)


def crlb_summary(es, epoch: int = 0, kind: str = "joint", stationary: bool = False, probability: float = 0.5) -> dict:
    """CRLB, projections, slices, ellipses and CEPs of one resolved scenario epoch (plain numbers):
    :func:`trackreplay.cores.localisation.tdoa_fdoa_crlb.crlb_summary` at that epoch's geometry."""
    from trackreplay.cores.localisation.tdoa_fdoa_crlb import crlb_summary as summary

    if not 0 <= epoch < len(es.times):
        raise InputError(f"epoch {epoch} outside 0..{len(es.times) - 1}")
    return summary(es.emitter[epoch], es.sensor_pos[epoch], es.sensor_vel[epoch], es.pairs, es.carrier_hz,
                   es.sigma[epoch], kind, stationary, probability)


def _fmt(v, width=12):
    return f"{v:>{width}.5g}" if v is not None else f"{'-':>{width}}"


def _print_crlb(sc, es, s: dict, epoch: int) -> None:
    p = sc.params
    pairs = ",".join(f"{i}-{j}" for i, j in es.pairs)
    click.echo(f"CRLB: scenario {sc.name}, geometry {p['geometry']}, emitter {p['emitter']}, estimator {s['estimator']}, "
               f"epoch {epoch}")
    click.echo("  sensors (m): " + "  ".join(f"({x:g}, {y:g})" for x, y in es.sensor_pos[epoch])
               + "   velocities (m/s): " + "  ".join(f"({x:g}, {y:g})" for x, y in es.sensor_vel[epoch]))
    th = s["emitter"]
    click.echo(f"  emitter: x {th[0]:g} m, y {th[1]:g} m, vx {th[2]:g} m/s, vy {th[3]:g} m/s")
    click.echo(f"  pairs {pairs}: {s['independent_equations']} independent equations for {s['unknowns']} unknowns; "
               f"σ_TDOA {es.sigma[epoch, 0] * 1e9:g} ns, σ_FDOA {es.sigma[epoch, es.n_pairs]:g} Hz, f0 {es.carrier_hz / 1e9:g} GHz")
    names = s["state_names"]
    click.echo("\nCRLB (units m, m/s; products thereof):")
    click.echo(" " * 8 + "".join(f"{n:>14}" for n in names))
    for n, row in zip(names, s["crlb"]):
        click.echo(f"{n:>8}" + "".join(f"{v:>14.6g}" for v in row))
    click.echo("standard deviations: " + ", ".join(f"{n} {v:.4g}" for n, v in zip(names, s["std"])))
    P = s["probability"]
    for label, e in s["blocks"].items():
        u = e["unit"]
        click.echo(f"\n{label + ' (' + u + ')':<26}{'projection (marginal, eq. 19)':>32}{'slice (others known, eq. 20)':>32}")
        for how in ("projection", "slice"):
            c = e[how]["covariance"]
            e[how]["_cov"] = f"[{c[0][0]:.5g}, {c[0][1]:.5g}; {c[1][1]:.5g}]"
        rows = [("covariance [a, b; d]", "_cov"), (f"{P:g} ellipse semi-major", "semi_major"),
                (f"{P:g} ellipse semi-minor", "semi_minor"), ("major axis angle (deg)", "angle_deg"),
                ("CEP exact", "cep_exact"), ("CEP 0.75·√(λ1+λ2)", "cep_075"), ("CEP paper eq. 21", "cep_paper")]
        for title, key in rows:
            a, b = e["projection"][key], e["slice"][key]
            if isinstance(a, str):
                click.echo(f"  {title:<24}{a:>32}{b:>32}")
            else:
                click.echo(f"  {title:<24}{_fmt(a, 32)}{_fmt(b, 32)}")


def _common_options(f):
    f = click.option("--set", "sets", multiple=True, metavar="NAME=VALUE", help="Any tdoa-fdoa scenario parameter.")(f)
    f = click.option("--scenario", default="tdoa-fdoa", show_default=True, help="Scenario name or TOML path.")(f)
    f = click.option("--estimator", type=click.Choice(ESTIMATORS), default="joint", show_default=True,
                     help="Measurements used: joint TDOA+FDOA, TDOA only or FDOA only.")(f)
    f = click.option("--emitter", type=int, help="Table 1 emitter preset (1, 2, 3).")(f)
    f = click.option("--geometry", help="Sensor geometry preset: line (Table 2) or triangle (Table 3).")(f)
    return f


@click.command("crlb")
@_common_options
@click.option("--epoch", default=0, show_default=True, help="Epoch of the scenario.")
@click.option("--probability", default=0.5, show_default=True, type=click.FloatRange(0, 1, min_open=True, max_open=True),
              help="P_e of the ellipses and CEPs.")
@click.option("--json", "as_json", is_flag=True, help="Print the numbers as JSON.")
def crlb_cmd(sets, scenario, estimator, emitter, geometry, epoch, probability, as_json):
    """CRLB, projections, slices, ellipses and CEPs of one TDOA/FDOA geometry.

    Prints the 4-state CRLB, its position and velocity projections (eq. 19) and slices
    (eq. 20), their error ellipses and CEPs (exact, 0.75·√(λ1+λ2), and the paper's eq. 21).

    \b
    Example:
      replay crlb --geometry line --emitter 1
      replay crlb --geometry triangle --emitter 3 --set sigma_fdoa_hz=5 --json
    """
    sc, es = _scenario(scenario, geometry, emitter, sets)
    s = crlb_summary(es, epoch, estimator, bool(sc.params["stationary_emitter"]), probability)
    if as_json:
        click.echo(json.dumps(s))
    else:
        _print_crlb(sc, es, s, epoch)


MAX_GRID_POINTS = 251_001  # 501 × 501; larger grids are refused rather than exhausting memory


@click.command("cep-plane")
@_common_options
@click.option("--extent-km", default=50.0, show_default=True, type=float, help="Grid half-width in x and y.")
@click.option("--step-m", default=500.0, show_default=True, type=float, help="Grid spacing.")
@click.option("--cep", "method", type=click.Choice(["exact", "paper", "approx"]), default="exact", show_default=True,
              help="CEP formula: exact 2-D Gaussian, the paper's eq. 21, or 0.75·√(λ1+λ2).")
@click.option("--probability", default=0.5, show_default=True, type=click.FloatRange(0, 1, min_open=True, max_open=True))
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path),
              help="PNG to write (default: replay-out/cep-plane-<geometry>.png).")
@click.option("--rrd", "rrd_path", type=click.Path(dir_okay=False, path_type=Path), help="Rerun recording (default: next to the PNG).")
@click.option("--no-rrd", is_flag=True, help="Skip the Rerun recording.")
def cep_plane_cmd(sets, scenario, estimator, emitter, geometry, extent_km, step_m, method, probability, output, rrd_path, no_rrd):
    """Position and velocity CEP planes over a grid, as PNG and Rerun images.

    The paper's Figs. 5-6: contours at 50/100/200 m and 5/10/15 m/s.

    The emitter's velocity (from --emitter or --set emitter_velocity_mps) is used at every grid
    point. Points where no CRLB exists (on a sensor, or collinear with the sensors) are blank.

    Writes replay-out/cep-plane-<geometry>.png and .rrd unless -o / --rrd say otherwise.

    \b
    Example:
      replay cep-plane --geometry triangle --extent-km 50 --step-m 500
      replay cep-plane --geometry line --cep paper -o line.png --no-rrd
    """
    from trackreplay.cores.localisation.cep_plane import cep_plane, cep_plane_areas, grid_axis
    from trackreplay.face.rerun_tdoa_fdoa_cep_plane import log_cep_plane, write_cep_png

    if not (extent_km > 0 and step_m > 0 and math.isfinite(extent_km) and math.isfinite(step_m)):
        raise InputError("--extent-km and --step-m must be positive")
    if method == "approx" and probability != 0.5:
        raise InputError("--cep approx is the 50 % approximation; use --probability 0.5 or --cep exact")
    sc, es = _scenario(scenario, geometry, emitter, sets)
    axis = grid_axis(extent_km * 1e3, step_m)
    if axis.size ** 2 > MAX_GRID_POINTS:
        raise InputError(f"grid of {axis.size} × {axis.size} points is too large (at most {MAX_GRID_POINTS}); "
                         "increase --step-m or reduce --extent-km")
    stationary = bool(sc.params["stationary_emitter"])
    from trackreplay.cores.localisation.tdoa_fdoa_model import underdetermined_reason

    reason = underdetermined_reason(estimator, es.pairs, es.sensor_pos.shape[1], stationary)
    if reason:
        raise InputError(reason)
    t0 = time.perf_counter()
    plane = cep_plane(es.sensor_pos[0], es.sensor_vel[0], es.pairs, es.emitter[0, 2:], es.carrier_hz, es.sigma[0],
                      axis, axis, estimator, stationary, method, probability)
    elapsed = time.perf_counter() - t0
    label = sc.params["geometry"] if not sc.params["sensor_positions_m"] else "custom"
    output = output or Path.cwd() / "replay-out" / f"cep-plane-{label}.png"
    rrd_path = None if no_rrd else (rrd_path or output.with_suffix(".rrd"))
    refuse_input_overwrite([Path(scenario)] if Path(scenario).suffix else [], [output, rrd_path])
    output.parent.mkdir(parents=True, exist_ok=True)
    title = (f"{sc.name}: geometry {label}, emitter velocity ({es.emitter[0, 2]:g}, {es.emitter[0, 3]:g}) m/s, "
             f"{estimator}, σ_TDOA {es.sigma[0, 0] * 1e9:g} ns, σ_FDOA {es.sigma[0, es.n_pairs]:g} Hz")
    png = write_cep_png(plane, output, es.sensor_pos[0], es.emitter[0, :2], title)
    click.echo(f"CEP planes, {axis.size} × {axis.size} points (±{extent_km:g} km, {step_m:g} m), {method} CEP at "
               f"P = {probability:g}: computed in {elapsed:.3f} s")
    for key, stats in cep_plane_areas(plane, step_m).items():
        unit = "m" if key == "position_m" else "m/s"
        parts = ", ".join(f"< {lv:g} {unit}: {a:.0f} km²" for lv, a in stats["area_km2"].items())
        click.echo(f"  {key.split('_')[0]:<9} min {stats['min']:.4g} {unit}; area {parts}")
    click.echo(f"  no CRLB at {int(plane.singular.sum())} grid point(s) (on a sensor or collinear with sensors)")
    click.echo(f"png:       {png}")
    if rrd_path is not None:
        from trackreplay.face.timeline import recording

        rrd_path.parent.mkdir(parents=True, exist_ok=True)
        with recording(rrd_path, "trackreplay", f"cep-plane-{label}") as rec:
            log_cep_plane(rec, plane, es.sensor_pos[0], es.emitter[0, :2])
        click.echo(f"recording: {rrd_path}   (view: replay view {rrd_path})")


COMMANDS = [crlb_cmd, cep_plane_cmd]
