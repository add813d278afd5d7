"""``replay run`` (what ``replay DATA.mcap`` means): the main job, a data set replayed through
every tracker, its outputs written as one set, its tables printed.
"""

from __future__ import annotations

import contextlib
import sys
import time
from pathlib import Path

import click

from trackreplay.errors import InputError
from trackreplay.face import progress
from trackreplay.face.cli_common import (
    DEMO_NAME,
    bundled_data_dir,
    fail_on_tracker_errors,
    resolve_tracker_specs,
    tracker_option,
    tracker_time_limit_option,
)
from trackreplay.face.cli_text import (
    _echo_wrapped,
    _list_outputs,
    _say,
    print_replay_report,
)
from trackreplay.paths import OutputSet, refuse_input_overwrite


# what a replay writes beside tracks.mcap (checked against the inputs before anything is written)
REPORT_FILES = ("metrics.csv", "metrics.parquet", "per_scan.csv", "per_scan.parquet", "targets.csv", "targets.parquet",
                "track_lives.csv", "track_lives.parquet", "report.txt", "report.png",
                "consistency.png", "errors.png", "fig7.png", "tracks.png", "positions.png")


def _spec_files(specs) -> list:
    """The tracker files of ``FILE.py:Class`` specs (inputs too: never to be written over)."""
    return [Path(s.rsplit(":", 1)[0]) for s in specs if ":" in s and s.rsplit(":", 1)[0].endswith(".py")]


def _default_out_dir(data: Path) -> Path:
    return Path.cwd() / "replay-out" / data.stem


def _export_tables(res, out_dir: Path) -> list[Path]:
    from trackreplay.contract import atomic_output
    from trackreplay.stages import stages_named

    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    tables = [("metrics", res.summary), ("per_scan", res.per_scan)]
    for name, df in (("targets", res.targets), ("track_lives", res.track_lives)):
        if df is not None and df.height:  # per true target and per track (trackreplay.evaluators.life_tables)
            tables.append((name, df))
    for name, df in tables:
        for ext in ("csv", "parquet"):
            p = out_dir / f"{name}.{ext}"
            with atomic_output(p) as f:
                df.write_csv(f) if ext == "csv" else df.write_parquet(f)
            written.append(p)
    # the papers' own table layouts (printed only in part, where they add to the tables above)
    layouts = [stage.report(res.summary, res.per_scan) or "" for stage in stages_named(res.results)]
    layouts = [text.strip("\n") for text in layouts if text.strip()]
    if layouts:
        with atomic_output(out_dir / "report.txt", "w") as f:
            f.write("\n\n".join(layouts) + "\n")
        written.append(out_dir / "report.txt")
    return written


def _report_plot(res, out_dir: Path) -> list[Path]:
    """Every applicable stage's figures (``report.png`` and the family's own) and the standard
    measures' consistency figure."""
    import polars as pl

    from trackreplay.evaluators.report_plots import plot_consistency
    from trackreplay.stages import stages_named

    paths = []
    title = Path(res.dataset.path).name
    present = stages_named(res.results)
    for stage in present:
        own = res.per_scan.filter(pl.col("stage") == stage.name) if "stage" in res.per_scan.columns else res.per_scan
        paths += stage.figures(own, out_dir, title=title, result=res.results[stage.name], dataset=res.dataset)
    x, log_x = present[0].per_scan_axis if present else ("scan", False)
    consistency = plot_consistency(res.per_scan, out_dir / "consistency.png", title=title, x=x, log_x=log_x)
    if consistency is not None:
        paths.append(consistency)
    return paths


def _draw_figures_in_background(data: Path, tracks: Path, recover: bool) -> None:
    """Start ``replay plot DATA TRACKS`` as a process of its own that outlives this one: it reads
    the finished outputs (through the contract, like ``replay eval``) and writes each figure
    atomically, so the user has the results without waiting for matplotlib."""
    import subprocess

    args = [sys.executable, "-m", "trackreplay.face.cli", "plot", str(data), str(tracks), "--quiet"]
    subprocess.Popen(args + (["--recover"] if recover else []), stdin=subprocess.DEVNULL,
                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)


def _previous_outputs(out_dir: Path, out_name: str, rrd_path: Path | None) -> list[Path]:
    """The files of an earlier replay that a replay into ``out_dir`` would replace."""
    names = [out_dir / out_name, out_dir / Path(out_name).with_suffix(".rrd").name, *(out_dir / n for n in REPORT_FILES)]
    if rrd_path is not None:
        names.append(rrd_path)
    return [p for p in dict.fromkeys(names) if p.is_file()]


def _numbered_out_dir(base: Path, out_name: str) -> Path:
    """``base`` if it holds no earlier replay, else the first of ``base-2``, ``base-3``, … that
    holds none."""
    k = 1
    candidate = base
    while _previous_outputs(candidate, out_name, None):
        k += 1
        candidate = base.with_name(f"{base.name}-{k}")
    return candidate


def _refuse_replacing(previous: list[Path], where: str) -> None:
    shown = ", ".join(p.name for p in previous[:3]) + (", …" if len(previous) > 3 else "")
    raise InputError(f"{where} already holds the outputs of an earlier replay ({shown}); add --force to replace "
                     "them, or choose another --out")


FIGURE_MODES = ("auto", "now", "background", "none")


# recordings that `replay convert` turns into a data set, and how
CONVERTED_SUFFIXES = {".csv": "replay convert plots|peaks|tdoa-fdoa|positions FILE -o DATA.mcap",
                      ".parquet": "replay convert plots|peaks|tdoa-fdoa|positions FILE -o DATA.mcap",
                      ".wav": "replay convert array-wav FILE -o DATA.mcap --spacing-m D --frequency-hz F"}


@click.command("run")
@click.argument("data", required=False, type=click.Path(dir_okay=False, path_type=Path))
@click.option("--trackers", help="Comma-separated subset, e.g. fixed,approximate (default: all that apply).")
@click.option("--out", "out_path", type=click.Path(dir_okay=False, path_type=Path),
              help="Output MCAP (default: replay-out/<name>/tracks.mcap; when that folder holds an earlier "
                   "replay, replay-out/<name>-2/, -3/, …). A folder given here that holds an earlier replay "
                   "needs --force.")
@click.option("--rrd", "rrd_path", type=click.Path(dir_okay=False, path_type=Path), help="Rerun recording (default: next to --out).")
@click.option("--no-rrd", is_flag=True, help="Skip the Rerun recording.")
@click.option("--force", is_flag=True,
              help="Replace an earlier replay's outputs: required when --out names a folder holding them; "
                   "without --out, reuse replay-out/<name>/ instead of writing to a new numbered folder.")
@click.option("--spawn", is_flag=True, help="Open the Rerun viewer on the recording.")
@click.option("--recover", is_flag=True, help="Accept a truncated MCAP: keep its complete chunks.")
@click.option("--set", "sets", multiple=True, metavar="NAME=VALUE", help="Override a tracker design value (e.g. nominal_cross_range_m=120).")
@click.option("--rerun-run", type=click.IntRange(min=0), default=0, show_default=True, help="Monte Carlo run shown in the per-run Rerun views.")
@click.option("--map", "map_path", type=click.Path(dir_okay=False, path_type=Path),
              help="DATA is an MCAP recorded by another tool: convert it through this mapping file first "
                   "(see `replay convert mcap --help`); outputs are named after DATA.")
@click.option("--figures", "figures_mode", type=click.Choice(FIGURE_MODES), default="auto", show_default=True,
              help="When the report figures are drawn: auto (in the background when the output is a terminal, "
                   "so the results do not wait for them; else before replay returns), now, background, or none. "
                   "`replay plot DATA TRACKS` draws them later.")
@tracker_option
@tracker_time_limit_option
def run_cmd(data, trackers, out_path, rrd_path, no_rrd, force, spawn, recover, sets, rerun_run, tracker_specs,
            map_path=None, figures_mode="auto", tracker_time_limit_s=None):
    """Replay a data set through every tracker that applies.

    A tracker given with --tracker runs beside the built-ins (its design values take --set too).
    If a tracker fails, the others' outputs are still written; then one line per failure and
    exit status 2. Nothing is silently replaced: a replay into the default folder that already
    holds one goes to a new numbered folder, and an --out folder holding one needs --force.

    \b
    Example:
      replay data/radar_tws_demo.mcap --trackers fixed,approximate --spawn
      replay radar.mcap --tracker my_trackers.py:ConstantVelocity --set plot_sigma_m=120
      replay radar.mcap --out study/a/tracks.mcap --force     # replace study/a's earlier replay
    """
    if data is None and map_path is not None:
        raise click.UsageError("--map needs the recording it maps: replay FOREIGN.mcap --map MAP.toml")
    if data is None:
        data = bundled_data_dir() / DEMO_NAME
        click.echo(f"no data set given: replaying the bundled demo {data}")
    from trackreplay.face import recording_process

    # before the heavy imports below: the child loads Rerun on the other core while they run
    recorder = recording_process.start(data, recover) if not no_rrd and map_path is None else None
    with recorder or contextlib.nullcontext():
        _run(data, trackers, out_path, rrd_path, no_rrd, force, spawn, recover, sets, rerun_run, tracker_specs,
             map_path, figures_mode, recorder, tracker_time_limit_s)


def _run(data, trackers, out_path, rrd_path, no_rrd, force, spawn, recover, sets, rerun_run, tracker_specs,
         map_path, figures_mode, recorder, tracker_time_limit_s=None):
    """``run_cmd``'s work, with ``recorder`` (a :class:`~trackreplay.face.recording_process.RecordingProcess`,
    or None to record in this process) already started."""
    from trackreplay.contract import read_dataset
    from trackreplay.replay import replay
    from trackreplay.recorders.scenarios import parse_assignments

    if data.suffix.lower() in CONVERTED_SUFFIXES and map_path is None:  # a recording, not yet a data set
        raise InputError(f"a {data.suffix.lstrip('.').upper()} file is converted first: "
                         f"{CONVERTED_SUFFIXES[data.suffix.lower()]} (see replay convert --help)", data)
    if spawn:  # no display: say so before the replay, not after it
        from trackreplay.face.viewer import require_display

        require_display()
    explicit_out, explicit_rrd = out_path is not None, rrd_path is not None and not no_rrd
    base = out_path.parent if explicit_out else _default_out_dir(data)
    out_dir = base if (explicit_out or force) else _numbered_out_dir(base, "tracks.mcap")
    out_path = out_path or out_dir / "tracks.mcap"
    rrd_path = None if no_rrd else (rrd_path or out_path.with_suffix(".rrd"))
    refuse_input_overwrite([data, map_path, *(_spec_files(tracker_specs))],
                           [out_path, rrd_path, *(out_dir / n for n in REPORT_FILES)])
    if not force:  # never replace an earlier replay unasked
        previous = _previous_outputs(out_dir, out_path.name, rrd_path if explicit_rrd else None)
        if previous:
            _refuse_replacing(previous, str(out_dir if explicit_out else previous[0].parent))
    if out_dir != base:
        _echo_wrapped(f"{base} holds an earlier replay: writing to {out_dir} (--force would replace it)")
    wanted = [t.strip() for t in trackers.split(",")] if trackers else None
    from trackreplay.isolation import DEFAULT_TRACKER_TIME_LIMIT_S

    limit = DEFAULT_TRACKER_TIME_LIMIT_S if tracker_time_limit_s is None else tracker_time_limit_s
    specs = resolve_tracker_specs(tracker_specs, limit)  # a tracker that does not load fails here
    if map_path is not None:  # a recording made by another tool: replay its conversion
        from trackreplay.face.cli_convert_foreign import convert_for_replay

        data = convert_for_replay(data, map_path)
    t_read = time.perf_counter()
    if recorder is not None:
        recorder.stamp_input()
    dataset = read_dataset(data, recover=recover)  # bad files fail here, before any progress output
    t_read = time.perf_counter() - t_read
    progress.timing("read", t_read)
    n_runs = max((ch.n_runs for ch in dataset.channels.values()), default=0)
    if n_runs and rerun_run >= n_runs:  # the views show the last run; say so rather than pick it silently
        _echo_wrapped(f"--rerun-run {rerun_run}: {data.name} holds runs 0–{n_runs - 1}; the Rerun views show run "
                      f"{n_runs - 1}")
        rerun_run = n_runs - 1
    # every output is staged and moved into place at the end: a crash or a kill leaves the
    # previous set untouched, never a mix (a recording elsewhere than the folder is one atomic file)
    rrd_inside = rrd_path is not None and rrd_path.parent.resolve() == out_dir.resolve()
    with OutputSet(out_dir, replaces=[out_path.with_suffix(".rrd").name, *REPORT_FILES], inputs=[data, map_path],
                   name="replay", say=_say) as outputs, \
            contextlib.closing(recorder) if recorder else contextlib.nullcontext():  # stopped before the set goes
        staged_rrd = outputs.path(rrd_path.name) if rrd_inside else rrd_path
        with progress.Phases(f"replaying {data.name}", ("filter", "evaluate", "write", "rerun")) as phases:
            res = replay(data, wanted, outputs.path(out_path.name), staged_rrd, design_overrides=parse_assignments(sets),
                         rerun_run=rerun_run, dataset=dataset, progress=phases.step, tracker_specs=specs,
                         keep_runs=rerun_run + 1,  # the views, figures and listing read runs 0 … rerun_run
                         tracker_time_limit_s=limit,
                         recorder=recorder if staged_rrd is not None else None)
        if recorder is not None and staged_rrd is not None:
            progress.timing("rerun, drawn by a second process", res.timings.get("rerun_s", 0.0))
        res.timings["read_s"] = t_read
        res.timings["total_s"] += t_read
        if res.dataset.recovered_messages is not None:
            click.echo(f"recovered {res.dataset.recovered_messages} messages from complete chunks of {data}")
        print_replay_report(res, data)
        if figures_mode == "auto":  # a converted foreign file lives only as long as this call
            figures_mode = "background" if sys.stdout.isatty() and map_path is None else "now"
        elif figures_mode == "background" and map_path is not None:
            figures_mode = "now"
        with progress.timed("tables and plots"):
            tables = [outputs.final(p) for p in _export_tables(res, outputs.stage)]
            plots = [outputs.final(p) for p in _report_plot(res, outputs.stage)] if figures_mode == "now" else []
    res.out_path = out_path
    res.rrd_path = rrd_path
    click.echo("")
    _list_outputs(out_dir, [("outputs", [res.out_path]), ("recording", [res.rrd_path] if res.rrd_path else []),
                            ("tables", tables), ("plots", plots)])
    if figures_mode == "background":  # the outputs are complete: the figures follow on their own
        _draw_figures_in_background(data, out_path, recover)
        again = f"replay plot {data} {out_path}" + (" --recover" if recover else "")
        _echo_wrapped(f"plots:     drawn in the background into {out_dir} (at once: {again})")
    if res.rrd_path:
        click.echo(f"view:      replay view {res.rrd_path}")
    t = res.timings
    click.echo(f"time:      {t['total_s']:.2f} s" + (
        f" (read {t['read_s']:.2f}, filter {t['filter_s']:.2f}, evaluate {t['evaluate_s']:.2f}, "
        f"write {t.get('write_s', 0):.2f}{' beside evaluate' if t.get('write_beside_s') else ''}, "
        f"rerun {t.get('rerun_s', 0):.2f})" if progress.verbose() else ""))
    fail_on_tracker_errors([str(exc) for exc in res.failures])
    if spawn and res.rrd_path:
        from trackreplay.face.viewer import open_viewer

        open_viewer(res.rrd_path)


COMMANDS = [run_cmd]
