"""``replay sweep``: a grid of scenario parameters simulated, replayed and scored.
"""

from __future__ import annotations

import time
from pathlib import Path

import click

from trackreplay.errors import InputError
from trackreplay.face import progress
from trackreplay.face.cli_common import (
    EVALUATION_VALUES_EPILOG,
    fail_on_tracker_errors,
    resolve_tracker_specs,
    tracker_option,
    tracker_time_limit_option,
)


@click.command("sweep", epilog=EVALUATION_VALUES_EPILOG)
@click.argument("scenario")
@click.option("--param", "params", multiple=True, required=True, metavar="NAME=v1,v2,...",
              help="A swept parameter and its values (repeat for a cartesian grid): a scenario parameter, a "
                   "tracker's design value or an evaluation design value.")
@click.option("--set", "sets", multiple=True, metavar="NAME=VALUE",
              help="A value fixed at every point: a scenario parameter, a tracker's design value or an evaluation "
                   "design value (listed below).")
@click.option("--runs", default=100, show_default=True, type=click.IntRange(min=1))
@click.option("--seed", default=0, show_default=True, type=click.IntRange(min=0), help="Base seed; each point's seed derives from it and the point.")
@click.option("--trackers", help="Comma-separated subset of trackers.")
@click.option("-o", "--output", "out_dir", required=True, type=click.Path(file_okay=False, path_type=Path))
@click.option("--executor", type=click.Choice(["serial", "process", "dask"]), default="process", show_default=True)
@click.option("--workers", type=click.IntRange(min=1), help="Processes (default: the machine's cores).")
@click.option("--scheduler", metavar="ADDRESS", help="Send the work to an existing Dask cluster (implies --executor dask).")
@click.option("--keep-data/--no-keep-data", default=True, show_default=True, help="Keep each point's data set and recording.")
@click.option("--resume", is_flag=True, help="Reuse the points already in the output folder whose record (scenario parameters, runs, seed, trackers, version) is unchanged; refuses a folder that holds another sweep.")
@click.option("--force", is_flag=True, help="Compute every point again in a folder that holds an earlier sweep.")
@tracker_option
@tracker_time_limit_option
def sweep_cmd(scenario, params, sets, runs, seed, trackers, out_dir, executor, workers, scheduler, keep_data, resume,
              force, tracker_specs, tracker_time_limit_s=None):
    """Simulate, replay and evaluate every point of a parameter grid.

    Writes sweep.parquet / sweep.csv (one row per point × tracker × metric), a PNG per metric
    and, with --keep-data, each point's data set and recording under points/. A tracker given
    with --tracker runs beside the built-ins on every point and every executor; its design
    parameters take --set and --param like the scenario's (they do not change a point's seed).

    Evaluation design values (the matching gate, the GOSPA cut-off and order, HOTA's distance
    scale, the SIAP gate) take --set and --param too: every point is scored with them, its seed
    unchanged. A name that is also a scenario parameter is the scenario's (it changes the data
    set, whose scenario record the evaluation reads). Each point's point.json records the
    evaluation values it was scored with, sweep.json those of the sweep.

    \b
    Example:
      replay sweep radar-tws --param sigma_bearing_deg=0.5,1,2 --param nominal_cross_range_m=100,150 \\
             --runs 100 --seed 7 -o study/
      replay sweep radar-tws --param plot_sigma_m=100,200 --tracker my_trackers.py:ConstantVelocity -o cv/
      replay sweep radar-tws --param sigma_bearing_deg=0.5,1,2 --set assignment_gate_m=2000 -o gate/
    """
    from trackreplay.registry import canonical_spec
    from trackreplay.sweep import (build_grid, check_evaluation_values, check_resume, parse_param_specs, run_sweep,
                                write_sweep_outputs)
    from trackreplay.recorders.scenarios import parse_assignments

    if scheduler:
        executor = "dask"
    specs = parse_param_specs(params)
    fixed = parse_assignments(sets)
    wanted = [t.strip() for t in trackers.split(",")] if trackers else None
    plugged = [canonical_spec(s) for s in resolve_tracker_specs(tracker_specs, tracker_time_limit_s)]
    from trackreplay.recorders.scenarios import load_scenario

    scenario_keys = load_scenario(scenario).defaults
    # names that are not scenario parameters may be trackers' design parameters or evaluation values
    foreign = [n for n in (*fixed, *specs) if n not in scenario_keys]
    design_defaults, evaluation = (_sweep_design_defaults(scenario, fixed, wanted, plugged) if (plugged or foreign)
                                   else ({}, {}))
    for option, names in (("--set", fixed), ("--param", specs)):
        unknown = [n for n in names if n not in scenario_keys and n not in design_defaults]
        if unknown:
            raise InputError(f"{option} {unknown[0]}: unknown parameter {unknown[0]!r} for scenario {scenario!r}: not "
                             f"one of its parameters ({', '.join(scenario_keys)}), a design value of its trackers "
                             "(`replay trackers`) or one of its evaluation design values "
                             f"({', '.join(evaluation) or 'none'})")
    check_evaluation_values({n: [fixed[n]] if n in fixed else specs[n] for n in (*fixed, *specs)
                             if n in evaluation and n not in scenario_keys})
    tasks = build_grid(scenario, specs, runs, seed, wanted, out_dir, keep_data, fixed, plugged, design_defaults,
                       **({} if tracker_time_limit_s is None else {"tracker_time_limit_s": tracker_time_limit_s}))
    if wanted:
        from trackreplay.registry import available_trackers
        from trackreplay.stages import STAGES

        known = {t for s in STAGES for t in s.trackers} | set(available_trackers(plugged))
        bad = [t for t in wanted if t not in known]
        if bad:
            raise InputError(f"unknown tracker(s) {', '.join(bad)} (have: {', '.join(sorted(known))})")
    spec = {"scenario": scenario, "params": specs, "fixed": fixed, "runs": runs, "seed": seed,
            "trackers": wanted, "tracker_specs": plugged, "executor": executor, "points": len(tasks)}
    if resume:
        check_resume(out_dir, spec)
    elif not force and (out_dir / "sweep.json").is_file():
        raise InputError(f"{out_dir} holds an earlier sweep; add --resume to reuse its finished points, --force to "
                         "compute them all again, or choose another -o")
    counts = {"done": 0, "resumed": 0, "failed": 0}
    label = f"sweep {scenario} ({len(tasks)} points, {executor})"
    with progress.bar(len(tasks), label, show_pos=True) as bar:
        def tally(kind: str) -> None:
            counts[kind] += 1
            bar.set_label(f"{label}: {counts['done']} done, {counts['resumed']} resumed, {counts['failed']} failed")

        t0 = time.perf_counter()
        report = run_sweep(tasks, list(specs), out_dir, executor, workers, scheduler, resume, bar.update, tally)
        progress.timing("points", time.perf_counter() - t0)
    with progress.timed("tables and plots"):
        write_sweep_outputs(report, list(specs), spec)
    for note in report.notes:
        click.echo(note, err=True)
    median = (f", median point {report.median_point_s:.2f} s" if report.point_work_s else "")
    click.echo(f"points: {report.done} done, {report.skipped} resumed, {len(report.failed)} failed; "
               f"wall {report.wall_s:.1f} s{median}")
    for label, err in report.failed.items():
        click.echo(f"FAILED {label}: {err}", err=True)
    click.echo(f"table: {out_dir / 'sweep.parquet'} (+ .csv); plots: {out_dir / 'plots'}/")
    fail_on_tracker_errors(report.tracker_failure_lines())
    if report.failed:
        raise click.exceptions.Exit(1)


def _sweep_design_defaults(scenario: str, fixed: dict, wanted, plugged) -> tuple[dict, dict]:
    """Design parameters (name → default) of the trackers a sweep runs and of its evaluation,
    after checking that every plugged tracker consumes what the scenario records; and the
    evaluation's alone."""
    from trackreplay import design_values
    from trackreplay.registry import available_trackers
    from trackreplay.stages import STAGES
    from trackreplay.sweep import scenario_families
    from trackreplay.recorders.scenarios import load_scenario

    scenario_keys = load_scenario(scenario).defaults
    families = scenario_families(scenario, {k: v for k, v in fixed.items() if k in scenario_keys})
    table = available_trackers(plugged)
    chosen = [e for e in table.values() if e.spec in plugged or (e.name in wanted if wanted else e.builtin)]
    for e in chosen:
        if e.spec in plugged and e.family not in families:
            raise InputError(f"tracker {e.name!r} consumes {e.family} measurements; scenario {scenario!r} "
                             f"records {', '.join(sorted(families)) or 'none of the families'}")
    out, evaluation = {}, {}
    for stage in STAGES:
        if stage.family in families:
            entries = [e for e in chosen if e.family == stage.family]
            out.update(design_values.parameter_defaults(stage, entries))
            evaluation.update({k: v for k, v in stage.evaluation_defaults.items() if k not in evaluation})
    return out, evaluation


COMMANDS = [sweep_cmd]
