"""``replay view`` and ``replay export``: a Rerun recording opened or rendered; outputs
exported for Foxglove and PlotJuggler, or a data set's measurements as tables.
"""

from __future__ import annotations

from pathlib import Path

import click

from trackreplay.errors import InputError
from trackreplay.face import progress
from trackreplay.face.cli_common import force_option
from trackreplay.paths import refuse_input_overwrite, refuse_replacing_file


@click.command("view")
@click.argument("rrd", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--screenshot", "png", type=click.Path(dir_okay=False, path_type=Path), help="Render headless to this PNG instead of opening a window.")
@click.option("--size", default="1600x900", show_default=True, help="Window size for --screenshot.")
def view_cmd(rrd, png, size):
    """Open a recording in the Rerun viewer, or render it headless to a PNG.

    A data set (.mcap) opens as the recording of its replay, with the family's views: it is
    replayed in memory and the recording written to a temporary folder (nothing is written beside
    the data). A replay's tracks.mcap opens the tracks.rrd beside it.

    \b
    Example:
      replay view replay-out/radar_tws_demo/tracks.rrd --screenshot fig.png
      replay view data/radar_tws_demo.mcap
    """
    import shutil
    import tempfile

    from trackreplay.face.viewer import open_viewer, screenshot

    if not rrd.exists():
        raise InputError("no such recording", rrd)
    if png:
        refuse_input_overwrite([rrd], [png])
    scratch = None
    if rrd.suffix == ".mcap":
        scratch = Path(tempfile.mkdtemp(prefix="replay-view-"))
        rrd = _recording_of_mcap(rrd, scratch)
    try:
        if png:
            click.echo(f"wrote {screenshot(rrd, png, size=size)}")
        else:
            open_viewer(rrd)  # the viewer reads the file after this returns: a scratch one stays
    finally:
        if png and scratch is not None:
            shutil.rmtree(scratch, ignore_errors=True)


def _recording_of_mcap(path: Path, scratch: Path) -> Path:
    """The Rerun recording to show for an MCAP: a replay output's own (beside it), or, for a data
    set, the recording of replaying it (every tracker, written to ``scratch``)."""
    from trackreplay.contract import dataset_topics
    from trackreplay.replay import replay

    if any(t.startswith("/tracks/") for t in dataset_topics(path)):
        beside = path.with_suffix(".rrd")
        if not beside.is_file():
            raise InputError(f"a replay output without its recording ({beside.name}) beside it; replay the data set "
                             "again without --no-rrd, or view the data set itself", path)
        return beside
    target = scratch / f"{path.stem}.rrd"
    with progress.Phases(f"replaying {path.name} for the viewer", ("filter", "evaluate", "write", "rerun")) as phases:
        replay(path, rrd_path=target, progress=phases.step)
    click.echo(f"recording of {path.name}: {target}")
    return target


@click.command("export")
@click.argument("tracks", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--foxglove", is_flag=True,
              help="JSON messages with JSON Schemas in MCAP, as Foxglove and PlotJuggler read them.")
@click.option("--table", is_flag=True,
              help="A data set's input channels as tables (one per measurement family, plus the sensors of "
                   "tdoa-fdoa) in exactly the format `replay convert` reads.")
@click.option("--format", "table_format", type=click.Choice(["csv", "parquet"]), default="csv", show_default=True,
              help="File format of --table.")
@click.option("-o", "--output", required=True, type=click.Path(path_type=Path),
              help="The MCAP file to write (--foxglove) or the folder of the tables (--table).")
@click.option("--runs", "runs_spec", metavar="LIST",
              help="Monte Carlo runs to export, e.g. 0,1,2 or 0-4 (default: the first 10).")
@click.option("--data", "data_path", type=click.Path(dir_okay=False, path_type=Path),
              help="The data set the replay read, for truth and per-scan metrics (default: the one the "
                   "outputs' provenance names, beside them, here or among the bundled data sets).")
@click.option("--recover", is_flag=True, help="Accept truncated MCAP files.")
@force_option
def export_cmd(tracks, foxglove, table, table_format, output, runs_spec, data_path, recover, force):
    """Export a replay's outputs for other plotting tools, or a data set's measurements as tables.

    --foxglove writes, per chosen run, one topic per tracker (/run_000/kalman: t, scan, x, y,
    vx, vy, sd_x, …, flags) and the truth (/run_000/truth), plus the per-scan metrics over all
    runs (/metrics/kalman), as JSON messages at the scan times (docs/export.md).

    --table writes a data set's input channels (and the truth the tables carry) as CSV or
    Parquet tables into a folder, in exactly the format `replay convert plots|peaks|tdoa-fdoa|
    positions` reads: importing them gives the same arrays (docs/importers.md).

    \b
    Example:
      replay data/radar_tws_demo.mcap --out r/tracks.mcap
      replay export --foxglove r/tracks.mcap -o view.mcap
      replay export --foxglove r/tracks.mcap -o view.mcap --runs 0,1,2
      replay export --table data/radar_tws_demo.mcap -o tables/ --format parquet
    """
    from trackreplay.face.export_foxglove import export_foxglove

    if foxglove and table:
        raise click.UsageError("choose one format: --foxglove or --table")
    if table:
        from trackreplay.face.cli_convert_tables import export_tables

        if runs_spec or data_path:
            raise click.UsageError("--runs and --data belong to --foxglove; --table exports every run")
        export_tables(tracks, output, table_format, recover, force)
        return
    if not foxglove:
        raise click.UsageError("choose the format: --foxglove (JSON MCAP for Foxglove and PlotJuggler) or --table "
                               "(a data set's measurements as CSV/Parquet tables)")
    if output.is_dir():
        raise InputError("is a folder; --foxglove writes one MCAP file", output)
    refuse_input_overwrite([tracks, data_path], [output])
    refuse_replacing_file(output, force)
    with progress.bar(0, f"exporting {tracks.name}") as bar, progress.timed("export"):
        report = export_foxglove(tracks, output, runs_spec, data_path, recover, progress=bar.update)
    runs = report.runs
    shown = (f"{runs[0]}–{runs[-1]}" if runs == list(range(runs[0], runs[-1] + 1)) and len(runs) > 2
             else ",".join(map(str, runs)))
    click.echo(f"wrote {report.path}: {report.messages} messages on {len(report.topics)} topics")
    click.echo(f"  runs {shown} of {report.n_runs}; trackers {', '.join(report.trackers)}"
               f"{'; truth' if report.truth else ''}{'; per-scan metrics' if report.metrics else ''}")
    click.echo(f"  time: {report.time_base}")
    for note in report.notes:
        click.echo(f"  note: {note}")
    click.echo(f"  open it in Foxglove (Plot panel, message path {report.example}) or PlotJuggler (Load Data)")


COMMANDS = [view_cmd, export_cmd]
