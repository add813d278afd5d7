"""``replay eval``, ``replay plot``, ``replay compare`` and ``replay check``: scoring outputs,
comparing two trackers' outputs and checking bundled data sets against their baselines.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import click

from trackreplay.errors import InputError
from trackreplay.face import progress
from trackreplay.face.cli_common import (
    EVALUATION_SET_HELP,
    EVALUATION_VALUES_EPILOG,
    _json_value,
    bundled_data_dir,
    checkout_data_dir,
    fail_on_tracker_errors,
    force_option,
    inside_installed_package,
    resolve_tracker_specs,
    tracker_option,
)
from trackreplay.face.cli_run import REPORT_FILES, _export_tables, _report_plot
from trackreplay.face.cli_text import (
    _cell,
    _echo_wrapped,
    _list_outputs,
    _say,
    print_replay_report,
)
from trackreplay.paths import OutputSet, refuse_input_overwrite


@click.command("eval")
@click.argument("data", type=click.Path(dir_okay=False, path_type=Path))
@click.argument("outputs", required=False, type=click.Path(dir_okay=False, path_type=Path))
@click.option("--json", "as_json", is_flag=True, help="Print long-form JSON records (tracker, metric, scope, value).")
@click.option("--per-scan", is_flag=True, help="Include per-scan records (scope 'scan:K') in --json.")
@click.option("--export", "export_dir", type=click.Path(file_okay=False, path_type=Path),
              help="Also write CSV/Parquet tables and PNG plots into this folder (their paths are printed).")
@click.option("--recover", is_flag=True, help="Accept truncated MCAP files.")
@click.option("--trackers", help="Comma-separated subset of trackers (replaying in memory).")
@click.option("--set", "sets", multiple=True, metavar="NAME=VALUE",
              help="Override a design value: an evaluation value (assignment_gate_m, ospa_cutoff_m, ospa_order, "
                   "hota_distance_m, …) for any OUTPUTS, a tracker's too when replaying in memory.")
@tracker_option
@force_option
def eval_cmd(data, outputs, as_json, per_scan, export_dir, recover, trackers, sets, tracker_specs, force):
    """Metrics of a data set, from a replay output file or by replaying in memory.

    Replaying in memory (no OUTPUTS), --tracker adds a plugged tracker and --trackers picks some;
    an output file's metrics cover the trackers it holds, plugged ones included. --set changes
    a design value: with OUTPUTS only the evaluation's own (the matching gate, the GOSPA
    cut-off and order, HOTA's distance scale), since the trackers already ran.

    \b
    Example:
      replay eval radar.mcap replay-out/radar/tracks.mcap --json
      replay eval radar.mcap replay-out/radar/tracks.mcap --set assignment_gate_m=2000
      replay eval radar.mcap --tracker my_trackers.py:ConstantVelocity --trackers kalman,constant_velocity
      replay eval radar.mcap --export tables/
    """
    import polars as pl

    from trackreplay.replay import evaluate_files, replay
    from trackreplay.recorders.scenarios import parse_assignments

    if tracker_specs and outputs is not None:
        raise InputError("--tracker applies when eval replays in memory (no OUTPUTS); the trackers of "
                         f"{outputs} already ran")
    if export_dir:
        refuse_input_overwrite([data, outputs], [export_dir / n for n in REPORT_FILES])
        _refuse_earlier([export_dir / n for n in REPORT_FILES], force, "--export folder")
    specs = resolve_tracker_specs(tracker_specs)
    overrides = parse_assignments(sets)
    if trackers and outputs is not None:
        raise InputError(f"--trackers applies when eval replays in memory (no OUTPUTS); {outputs} holds the "
                         "trackers that ran")
    if outputs is None:  # replay in memory, phase by phase
        wanted = [t.strip() for t in trackers.split(",")] if trackers else None
        with progress.Phases(f"evaluating {data.name}", ("filter", "evaluate")) as phases:
            res = replay(data, wanted, recover=recover, tracker_specs=specs, progress=phases.step,
                         design_overrides=overrides)
    else:
        with progress.bar(1, f"evaluating {outputs.name}") as bar, progress.timed("evaluate"):
            res = evaluate_files(data, outputs, recover=recover, evaluation_overrides=overrides)
            bar.update(1)
    if as_json:
        records = res.summary.to_dicts()
        if per_scan:
            metrics = [c for c in res.per_scan.columns if c not in ("tracker", "scan", "time_s", "stage")]
            long = res.per_scan.unpivot(on=metrics, index=["tracker", "scan", "stage"], variable_name="metric", value_name="value")
            long = long.with_columns(pl.format("scan:{}", pl.col("scan")).alias("scope")).drop("scan")
            records += long.select("tracker", "metric", "scope", "value", "stage").to_dicts()
        click.echo(json.dumps([{k: _json_value(v) for k, v in r.items()} for r in records]))
    else:
        print_replay_report(res, data)
    if export_dir:
        # the tables and figures as one set (trackreplay.paths.OutputSet): all of them or none
        with progress.timed("export"), OutputSet(export_dir, replaces=REPORT_FILES, inputs=[data, outputs],
                                                 name="export", say=_say) as staged:
            tables = [staged.final(p) for p in _export_tables(res, staged.stage)]
            plots = [staged.final(p) for p in _report_plot(res, staged.stage)]
        # with --json, stdout stays pure JSON: the paths go to stderr
        click.echo("", err=as_json)
        _list_outputs(export_dir, [("tables", tables), ("plots", plots)], err=as_json)
    fail_on_tracker_errors([str(exc) for exc in getattr(res, "failures", [])])


@click.command("plot")
@click.argument("data", type=click.Path(dir_okay=False, path_type=Path))
@click.argument("outputs", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--recover", is_flag=True, help="Accept a truncated MCAP: keep its complete chunks.")
def plot_cmd(data, outputs, recover):
    """Draw a replay's figures (report.png and the family's own) next to its OUTPUTS.

    `replay DATA` draws them itself, in the background when its output is a terminal; this
    draws them again, or for a replay run with --figures none.

    \b
    Example:
      replay plot radar.mcap replay-out/radar/tracks.mcap
    """
    from trackreplay.replay import replay_of_files

    refuse_input_overwrite([data, outputs], [outputs.parent / n for n in REPORT_FILES if n.endswith(".png")])
    res = replay_of_files(data, outputs, recover=recover)
    from trackreplay.paths import link_into_set, set_version_folder

    # outputs of a published set (links into its version folder): the figures join that set
    version = set_version_folder(outputs)
    with progress.timed("plots"):
        plots = _report_plot(res, version or outputs.parent)
    if version is not None:
        for p in plots:
            link_into_set(outputs, p.name)
        plots = [outputs.parent / p.name for p in plots]
    _list_outputs(outputs.parent, [("plots", plots)])


@click.command("compare", epilog=EVALUATION_VALUES_EPILOG)
@click.argument("a_path", metavar="A", type=click.Path(dir_okay=False, path_type=Path))
@click.argument("b_path", metavar="B", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--data", "data_path", type=click.Path(dir_okay=False, path_type=Path),
              help="The data set both were replayed from (default: the one A's provenance names).")
@click.option("--pair", "pairs", multiple=True, metavar="A_NAME:B_NAME",
              help="Compare tracker A_NAME of A with B_NAME of B (default: the trackers both hold).")
@click.option("--json", "as_json", is_flag=True, help="Print the comparison as JSON records.")
@click.option("-o", "--out", "out_dir", type=click.Path(file_okay=False, path_type=Path),
              help="Write compare.csv/.parquet, compare.png and compare.rrd here (default: replay-out/compare).")
@click.option("--recover", is_flag=True, help="Accept truncated MCAP files.")
@click.option("--set", "sets", multiple=True, metavar="NAME=VALUE", help=EVALUATION_SET_HELP)
@force_option
def compare_cmd(a_path, b_path, data_path, pairs, as_json, out_dir, recover, sets, force):
    """Paired comparison of two replays of the same data set (A − B, run against run).

    Every metric of both, the difference with its 95 % interval from the paired runs, and a
    verdict: better / worse for A, or no significant difference. Outputs of different data sets
    are refused.

    Both sides are scored with the same evaluation design values: those recorded in A's
    provenance, changed by --set. Only evaluation values change here (the trackers already
    ran; a tracker's design value is refused: replay again). The values used are printed and
    recorded in compare.parquet's metadata (key replay.compare).

    \b
    Example:
      replay data/radar_tws_demo.mcap --out before/tracks.mcap
      replay data/radar_tws_demo.mcap --out after/tracks.mcap --set nominal_cross_range_m=120
      replay compare after/tracks.mcap before/tracks.mcap
      replay compare after/tracks.mcap before/tracks.mcap --set assignment_gate_m=2000
    """
    import polars as pl

    from trackreplay.evaluators.compare import write_comparison_figure
    from trackreplay.replay import compare_files, format_evaluation_values
    from trackreplay.recorders.scenarios import parse_assignments

    overrides = parse_assignments(sets)
    parsed = []
    for p in pairs:
        if p.count(":") != 1 or not all(p.split(":")):
            raise InputError(f"--pair {p!r}: expected A_NAME:B_NAME")
        parsed.append(tuple(p.split(":")))
    names = ("compare.csv", "compare.parquet", "compare.png", "compare.rrd")
    if out_dir is None:  # the default folder: the next free replay-out/compare, compare-2, …
        out_dir = base = Path.cwd() / "replay-out" / "compare"
        k = 1
        while not force and any((out_dir / n).exists() for n in names):
            k += 1
            out_dir = base.with_name(f"{base.name}-{k}")
    refuse_input_overwrite([a_path, b_path, data_path], [out_dir / n for n in names])
    cmp = compare_files(a_path, b_path, data_path, parsed or None, recover, overrides)
    _refuse_earlier([out_dir / n for n in names], force, "-o folder")  # after the --set values are checked
    table = cmp.table
    evaluation = ", ".join(format_evaluation_values({k: v}) + (" (--set)" if k in cmp.evaluation_set else "")
                           for k, v in cmp.evaluation.items())
    if as_json:
        click.echo(json.dumps([{k: _json_value(v) for k, v in r.items()} for r in table.to_dicts()]))
    else:
        click.echo(f"A = {a_path}\nB = {b_path}\ndata set: {Path(cmp.dataset.path).name}; "
                   "difference A − B with ± half its 95 % paired interval")
        if evaluation:
            _echo_wrapped(f"evaluation values (both sides): {evaluation}", indent="  ")
        with pl.Config(tbl_rows=400, tbl_width_chars=160, tbl_hide_dataframe_shape=True,
                       tbl_hide_column_data_types=True, fmt_str_lengths=40):
            shown = table.with_columns(
                pl.struct("difference", "ci_low", "ci_high").map_elements(
                    lambda r: _cell(r["difference"], r["ci_low"], r["ci_high"]), return_dtype=pl.String).alias("A − B"),
                *(pl.col(c).map_elements(lambda v: _cell(v, None, None), return_dtype=pl.String) for c in ("value_a", "value_b")))
            click.echo(shown.select("tracker_a", "tracker_b", "metric", "scope", "value_a", "value_b", "A − B", "verdict"))
        counts = table["verdict"].value_counts(sort=True)
        click.echo("verdicts: " + ", ".join(f"{r['verdict']} {r['count']}" for r in counts.iter_rows(named=True)))
    record = {"a": str(a_path), "b": str(b_path), "data": Path(cmp.dataset.path).name, "stage": cmp.stage.name,
              "evaluation": cmp.evaluation, "evaluation_set": list(cmp.evaluation_set)}
    from trackreplay.face.rerun_views import log_comparison

    # the tables, the figure and the recording as one set (trackreplay.paths.OutputSet): all or none
    with OutputSet(out_dir, inputs=[a_path, b_path, data_path], name="compare", say=_say) as staged:
        table.write_csv(staged.path("compare.csv"))
        table.write_parquet(staged.path("compare.parquet"),
                            metadata={"replay.compare": json.dumps(record, default=str)})
        write_comparison_figure(table, staged.path("compare.png"), f"A = {a_path.name}  vs  B = {b_path.name}")
        log_comparison(cmp, staged.path("compare.rrd"))
    if not as_json:
        click.echo(f"tables: {out_dir / 'compare.csv'} (+ .parquet); plot: {out_dir / 'compare.png'}; "
                   f"recording: {out_dir / 'compare.rrd'}")


def _refuse_earlier(paths, force: bool, what: str) -> None:
    """An earlier run's outputs are replaced only when asked (``--force``), as replay's are."""
    earlier = [p for p in paths if p.exists() or p.is_symlink()]
    if earlier and not force:
        shown = ", ".join(p.name for p in earlier[:3]) + (", …" if len(earlier) > 3 else "")
        raise InputError(f"already holds the outputs of an earlier run ({shown}); add --force to replace them, "
                         f"or choose another {what}", earlier[0].parent)


@click.command("check", epilog=EVALUATION_VALUES_EPILOG)
@click.argument("data_dir", required=False, type=click.Path(file_okay=False, path_type=Path))
@click.option("--update", is_flag=True,
              help="Rewrite the baselines (DATA_DIR/baselines/) from the current code, deliberately; refused "
                   "for the copy inside an installed package: pass the checkout's data folder.")
@click.option("--set", "sets", multiple=True, metavar="NAME=VALUE",
              help=EVALUATION_SET_HELP + " Not with --update: the baselines hold the defaults' metrics.")
@tracker_option
def check_cmd(data_dir, update, sets, tracker_specs):
    """Re-run every bundled data set and compare its metrics with the stored baselines.

    DATA_DIR defaults to the data/ folder of the checkout you are in (found from the current
    folder upwards), else to the installed copy. Exits 1 and names every metric that moved
    beyond its tolerance. A tracker given with
    --tracker runs beside the built-ins on every data set and sweep of its family; its metrics
    are compared with the baseline entries that exist for it, and --update adds them.

    --set scores every data set and sweep whose stage has that evaluation design value with it
    (the others with their defaults). The baselines hold the metrics of the defaults: the check
    says so in one line first, the metrics that depend on the values may drift (exit 1), and
    --update refuses --set.

    \b
    Example:
      replay check data/
      replay check --update        # after a deliberate change
      replay check --tracker my_trackers.py:ConstantVelocity --update
      replay check --set assignment_gate_m=2000   # which metrics move with the gate
    """
    from trackreplay.check import UPDATE_WITH_SET, evaluation_values, run_check
    from trackreplay.recorders.scenarios import parse_assignments

    evaluation = evaluation_values(parse_assignments(sets))
    if evaluation and update:
        raise InputError(UPDATE_WITH_SET)
    data_dir = data_dir or checkout_data_dir() or bundled_data_dir()
    if update and inside_installed_package(data_dir):
        raise InputError(f"{data_dir} is inside an installed package: --update will not rewrite its baselines; pass "
                         "the data folder to update, e.g. `replay check path/to/checkout/data --update`")
    specs = resolve_tracker_specs(tracker_specs)
    click.echo(f"{'updating baselines of' if update else 'checking'} the data sets in {data_dir}")
    names = ([m.stem for m in sorted(Path(data_dir).glob("*.mcap"))]
             + [f"sweep-{t.stem}" for t in sorted((Path(data_dir) / "sweeps").glob("*.toml"))])
    with progress.bar(len(names), "check", show_pos=True) as bar:
        state = {"i": 0, "t": time.perf_counter()}

        def label():
            return f"check {names[state['i']]}" if state["i"] < len(names) else "check"

        bar.set_label(label())

        def echo(line=""):
            # one of these lines ends each data set (trackreplay.check's report lines)
            if line.split(" ", 1)[0] not in ("ok", "FAIL", "wrote", "skip"):
                bar.echo(line)
                return
            finished = names[state["i"]] if state["i"] < len(names) else None
            state["i"] += 1
            bar.pos = min(bar.pos + 1, bar.length)
            bar.label = label()
            bar.echo(line)
            if finished is not None and progress.verbose():
                bar.echo(f"timing: {finished} {time.perf_counter() - state['t']:.2f} s", err=True)
            state["t"] = time.perf_counter()

        report = run_check(data_dir, update=update, echo=echo, tracker_specs=specs, evaluation=evaluation)
    fail_on_tracker_errors(report.errors)
    if report.failed:
        raise click.exceptions.Exit(1)


COMMANDS = [eval_cmd, plot_cmd, compare_cmd, check_cmd]
