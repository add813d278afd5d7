"""The ``replay`` command line.

``replay DATA.mcap`` replays a data set (``replay`` alone replays the bundled demo); the other
commands simulate, convert, evaluate, check against baselines, sweep parameters, view and
export. User errors print one line and exit with status 2; only bugs show a traceback. Progress
bars go to stderr, only when it is a terminal (:mod:`pipeline.face.progress`); results go to
stdout.
"""

from __future__ import annotations

import contextlib
import json
import os
import sys
import time
from pathlib import Path

# numpy asks the kernel for transparent huge pages on every array of 4 MB and more; a replay
# makes its large arrays once, fills them once and frees them, and on this 2-core machine the
# page faults (with compaction) cost more than the huge pages save: 10,000 radar runs 0.13–0.48 s
# faster without, in 6 of 6 interleaved pairs, 1,000 array runs 0.43–0.96 s in 3 of 3, no change
# on 500 coloured-noise or 10 radar runs (docs/benchmarks.md). numpy reads this when it is first
# imported, which the command line does lazily, after this line; a value the user set stands.
os.environ.setdefault("NUMPY_MADVISE_HUGEPAGE", "0")
# the Rerun SDK logs its own failures (a full disk, say) as lines on stderr; they reach the user
# as the one line naming the file (pipeline.paths.disk_error), so its log stays off unless asked
os.environ.setdefault("RUST_LOG", "off")

import click

from pipeline.face import lazy_imports

lazy_imports.defer()  # numpy.f2py, which scipy's import pulls in for nothing: 0.08–0.15 s of every replay

from pipeline import __version__
from pipeline.errors import InputError
from pipeline.face import progress
from pipeline.paths import OutputSet, refuse_input_overwrite, refuse_replacing_file

DEMO_NAME = "radar_tws_demo.mcap"


class UserError(click.ClickException):
    exit_code = 2

    def show(self, file=None):
        click.echo(f"replay: error: {self.format_message()}", err=True)


def bundled_data_dir() -> Path:
    """``data/`` of the source tree when run from a clone, else the installed copy."""
    local = Path.cwd() / "data"
    if (local / "baselines").is_dir():
        return local
    try:
        from importlib.resources import files

        return Path(str(files("replay_data")))
    except ModuleNotFoundError:
        return Path(__file__).resolve().parents[2] / "data"


def checkout_data_dir(start: Path | None = None) -> Path | None:
    """``data/`` of the source checkout that ``start`` (default: the current folder) is in:
    the nearest folder upwards holding ``pyproject.toml`` and ``data/baselines/``."""
    here = (start or Path.cwd()).resolve()
    for folder in (here, *here.parents):
        if (folder / "pyproject.toml").is_file() and (folder / "data" / "baselines").is_dir():
            return folder / "data"
    return None


def inside_installed_package(path: Path) -> bool:
    """True when ``path`` lies in an installed package (site-packages, dist-packages or an
    interpreter's library folder), where nothing should be written."""
    import site
    import sysconfig

    resolved = Path(path).resolve()
    if any(part in ("site-packages", "dist-packages") for part in resolved.parts):
        return True
    roots = {sysconfig.get_paths().get(k) for k in ("purelib", "platlib")}
    try:
        roots |= set(site.getsitepackages())
    except AttributeError:  # some virtualenvs lack it
        pass
    for root in filter(None, roots):
        try:
            resolved.relative_to(Path(root).resolve())
            return True
        except ValueError:
            continue
    return False


TRACKER_HELP = ("A plugged tracker to run beside the built-ins: FILE.py:CLASS, MODULE:CLASS or the name of an "
                "installed (entry-point) tracker; repeat for several (see `replay trackers`).")


def force_option(f):
    """``--force``: replace the output file if it exists (without it, an existing one is refused)."""
    return click.option("--force", is_flag=True, help="Replace the output file if it exists.")(f)


def tracker_option(f):
    """The ``--tracker SPEC`` option (repeatable) shared by run, eval, check, sweep and trackers."""
    return click.option("--tracker", "tracker_specs", multiple=True, metavar="SPEC", help=TRACKER_HELP)(f)


def tracker_time_limit_option(f):
    """``--tracker-time-limit SECONDS``: how long a plugged tracker may run (run and sweep)."""
    from pipeline.isolation import DEFAULT_TRACKER_TIME_LIMIT_S

    return click.option("--tracker-time-limit", "tracker_time_limit_s", type=click.FloatRange(min=0),
                        default=DEFAULT_TRACKER_TIME_LIMIT_S, show_default=True, metavar="SECONDS",
                        help="Seconds a plugged (--tracker) tracker may take, its first import included, before "
                             "it is stopped and reported as failed; 0: no limit. Plugged trackers run in a child "
                             "process (one that exits or hangs fails alone); the built-ins run unlimited.")(f)


def resolve_tracker_specs(specs, time_limit_s: float | None = None) -> list[str]:
    """``--tracker`` values as loadable specs, each loaded once here so that a bad one fails
    before any work with one line.

    ``FILE.py:CLASS`` and ``MODULE:CLASS`` stay as given; the name of an installed
    (entry-point) tracker becomes its ``module:Class`` spec; a built-in's name is dropped (the
    built-ins run anyway).

    Raises
    ------
    InputError
        A file, module or class that does not load, a class that is not a Tracker, an unknown
        name, or two trackers with one name.
    """
    from pipeline.isolation import DEFAULT_TRACKER_TIME_LIMIT_S
    from pipeline.registry import available_trackers

    limit = DEFAULT_TRACKER_TIME_LIMIT_S if time_limit_s is None else time_limit_s
    out = []
    installed = None
    for spec in dict.fromkeys(s.strip() for s in specs):
        if ":" in spec:
            out.append(spec)
            continue
        installed = installed if installed is not None else available_trackers((), limit)
        entry = installed.get(spec)
        if entry is None:
            raise InputError(f"--tracker {spec!r}: no installed tracker has that name (known: "
                             f"{', '.join(sorted(installed))}); give FILE.py:CLASS or MODULE:CLASS")
        if not entry.builtin:
            out.append(entry.spec)
    if out:  # the plugged trackers load, and no name clashes with another tracker
        available_trackers(out, limit)
    return out


class InternalError(UserError):
    """A failure that is the program's, not the input's: one line still, exit status 3."""

    exit_code = 3


def fail_on_tracker_errors(lines) -> None:
    """Print one ``replay: error:`` line per failed tracker and exit 2 (after the outputs are written)."""
    if lines:
        for line in lines:
            click.echo(f"replay: error: {line}", err=True)
        raise click.exceptions.Exit(2)


class ReplayGroup(click.Group):
    """``replay FILE`` means ``replay run FILE``; a mistyped command gets a suggestion; every user
    error, click's own usage errors included, becomes one line and exit status 2."""

    def parse_args(self, ctx, args):
        args = list(args)
        # the group's own flags (--quiet, --verbose) may come first: `replay -q data.mcap`
        i = 0
        while i < len(args) and args[i] in GROUP_FLAGS:
            i += 1
        if i == len(args):
            if not any(a in ("-h", "--help", "--version") for a in args):
                args = [*args, "run"]
        elif args[i] not in self.commands and not args[i].startswith("-"):
            if not _looks_like_data(args[i]):
                import difflib

                close = difflib.get_close_matches(args[i], list(self.commands), n=1)
                hint = f" (did you mean '{close[0]}'?)" if close else ""
                raise click.UsageError(f"no such command or file {args[i]!r}{hint}; see `replay --help`")
            args = [*args[:i], "run", *args[i:]]
        elif args[i].split("=")[0] in self._run_options():
            # `replay --rerun-run 5 data.mcap`: options of run before the data file mean run too
            args = [*args[:i], "run", *args[i:]]
        return super().parse_args(ctx, args)

    def _run_options(self) -> set:
        run = self.commands.get("run")
        names = {o for p in (run.params if run is not None else ()) for o in getattr(p, "opts", ())}
        return {n for n in names if n.startswith("-")} - {"-h", "--help", "-q", "--quiet", "-v", "--verbose"}

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except InputError as exc:
            raise UserError(str(exc)) from None
        except OSError as exc:
            # the file system's answer (a folder that is a file, no permission, disk full)
            where = f"{exc.filename}: " if exc.filename else ""
            raise UserError(f"{where}{exc.strerror or exc}") from None
        except MemoryError:
            raise UserError("not enough memory for this data set (MemoryError)") from None
        except (click.ClickException, click.exceptions.Exit, click.exceptions.Abort):
            raise
        except Exception as exc:  # a bug of ours: one line for the user, the traceback with --verbose
            from pipeline.face import progress

            if progress.verbose():
                raise
            raise InternalError(f"internal error: {type(exc).__name__}: {exc} (run again with --verbose for the "
                                "traceback, and please report it)") from None

    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True, **extra):
        import warnings

        # numerical warnings on odd but accepted data would break the one-line error contract;
        # what they signal reaches the user as flags in the outputs or as a one-line error
        warnings.filterwarnings("ignore", category=RuntimeWarning)
        try:
            rv = super().main(args, prog_name, complete_var, standalone_mode=False, **extra)
        except click.UsageError as exc:
            where = f" ({exc.ctx.command_path})" if exc.ctx is not None and exc.ctx.command_path != "replay" else ""
            click.echo(f"replay: error: {exc.format_message()}{where}", err=True)
            sys.exit(2)
        except click.ClickException as exc:
            exc.show()
            sys.exit(exc.exit_code)
        except click.exceptions.Abort:
            click.echo("replay: interrupted", err=True)
            sys.exit(130)
        except KeyboardInterrupt:
            click.echo("replay: interrupted", err=True)
            sys.exit(130)
        if isinstance(rv, int) and standalone_mode:
            sys.exit(rv)
        if standalone_mode:
            sys.exit(0)
        return rv


GROUP_FLAGS = ("-q", "--quiet", "-v", "--verbose")


def _looks_like_data(arg: str) -> bool:
    """A first argument that is a data set rather than a (mistyped) command name."""
    path = Path(arg)
    return path.exists() or path.suffix != "" or "/" in arg or "\\" in arg


@click.group(cls=ReplayGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="replay")
@progress.progress_options
def main():
    """Offline replay and evaluation of target-tracking algorithms.

    Progress bars appear on stderr when it is a terminal; --quiet (here or on any command)
    turns them off, --verbose adds the time of each phase.

    \b
    Examples:
      replay                                   # the bundled demo data set
      replay data/radar_tws_demo.mcap
      replay simulate radar-tws --runs 500 --seed 7 -o radar.mcap
      replay scenarios radar-tws               # its parameters, units and defaults
      replay eval radar.mcap --json
      replay check
      replay sweep radar-tws --param sigma_bearing_deg=0.5,1,2 --runs 100 -o study/
      replay export --foxglove replay-out/radar_tws_demo/tracks.mcap -o view.mcap
    """


# --------------------------------------------------------------------------- run


# what a replay writes beside tracks.mcap (checked against the inputs before anything is written)
REPORT_FILES = ("metrics.csv", "metrics.parquet", "per_scan.csv", "per_scan.parquet", "targets.csv", "targets.parquet",
                "track_lives.csv", "track_lives.parquet", "report.txt", "report.png",
                "consistency.png", "errors.png", "fig7.png", "tracks.png", "positions.png")


def _spec_files(specs) -> list:
    """The tracker files of ``FILE.py:Class`` specs (inputs too: never to be written over)."""
    return [Path(s.rsplit(":", 1)[0]) for s in specs if ":" in s and s.rsplit(":", 1)[0].endswith(".py")]


def _default_out_dir(data: Path) -> Path:
    return Path.cwd() / "replay-out" / data.stem


def _cell(value, low, high) -> str:
    """A metric as read in a report: integers as integers, otherwise 4 significant digits, and
    ± half the 95 % interval over Monte Carlo runs where there is one."""
    if value is None or value != value:
        return "—"
    text = f"{int(value)}" if float(value).is_integer() and abs(value) < 1e9 else f"{value:.4g}"
    if low is not None and high is not None and high > low:
        text += f" ± {(high - low) / 2:.2g}"
    return text


TABLE_WIDTH = 100  # printed tables are split (or wrapped) to fit this many columns


def _declared_scopes(summary: pl.DataFrame) -> list[str]:
    """The scopes the stages in ``summary`` always report, so that an empty one is named rather
    than silently missing (a stage leaves out a scope no scan falls in)."""
    import polars as pl

    from evaluators.radar_tws import SCOPES as RADAR_SCOPES

    stages = summary["stage"].unique(maintain_order=True).to_list() if "stage" in summary.columns else []
    out = []
    for stage in stages:
        if stage == "radar-tws":
            out += RADAR_SCOPES
        elif stage == "colored-noise-imm":
            part = summary.filter(pl.col("stage") == stage)
            if "rmse_position_m" in part["metric"].to_list():  # the kinematic scopes need truth
                out += ("overall", "manoeuvre", "constant_velocity")
    return list(dict.fromkeys(out))


def _column_groups(widths: list[int], first: int, width: int, headers=None) -> list[list[int]]:
    """Indices of the columns (after the first, of ``widths``) cut into as few contiguous groups
    as fit ``width`` each (with the first column, ``first`` wide), choosing among the cuts the
    one that keeps repeated headers (e.g. "eff" of position and of velocity) in different
    groups, starts groups at a header not seen before, and balances the widths."""
    from itertools import combinations

    n = len(widths)
    fits = lambda a, b: first + sum(widths[a:b]) <= width or b - a == 1  # noqa: E731
    if n == 0 or fits(0, n):
        return [list(range(n))]
    headers = list(headers) if headers is not None else [None] * n
    for g in range(2, n + 1):
        if n > 24 and g > 3:  # too many ways to cut: fill greedily
            break
        best = None
        for cuts in combinations(range(1, n), g - 1):
            bounds = [0, *cuts, n]
            parts = list(zip(bounds, bounds[1:]))
            if not all(fits(a, b) for a, b in parts):
                continue
            dups = sum(len(h) - len(set(h)) for h in ([x for x in headers[a:b] if x] for a, b in parts))
            restarts = sum(1 for a, _ in parts[1:] if headers[a] and headers[a] in headers[:a])
            score = (dups, restarts, max(sum(widths[a:b]) for a, b in parts))
            if best is None or score < best[0]:
                best = (score, parts)
        if best is not None:
            return [list(range(a, b)) for a, b in best[1]]
    groups, current, used = [], [], first
    for i, w in enumerate(widths):
        if current and used + w > width:
            groups.append(current)
            current, used = [], first
        current.append(i)
        used += w
    return groups + [current] if current else groups


def _metrics_title(data: Path, dataset) -> str:
    """``metrics for NAME (R runs)``, the same for ``replay`` and ``replay eval``."""
    runs = max((ch.n_runs for ch in dataset.channels.values()), default=0)
    return f"metrics for {Path(data).name} ({runs} runs)"


def _headline_metrics(res) -> tuple:
    """The first measure each stage's report shows (e.g. the radar position RMSE), for the
    verdict lines."""
    from pipeline.stages import stage_named

    return tuple(m for name in res.results for m in stage_named(name).report_metrics[:1])


def _print_verdicts(summary: pl.DataFrame, family_metrics=()) -> None:
    """The verdict before the detail: one line per tracker with its headline measures (± half
    their interval) and its consistency verdict (:mod:`evaluators.verdicts`)."""
    from evaluators.verdicts import tracker_verdicts

    table = tracker_verdicts(summary, family_metrics)
    if table.height == 0:
        return
    width = max(len(t) for t in table["tracker"].to_list())
    click.echo("verdict per tracker (filter consistency, and what tested it):")
    for r in table.iter_rows(named=True):
        verdict = r["verdict"] + (f" ({r['tested_by']})" if r["tested_by"] else "")
        line = f"  {r['tracker']:<{width}}  {verdict:<19}"
        for i, m in enumerate(r["measures"]):  # as many measures as fit the tables' width
            item = f"{',' if i else ''} {m['metric']} {_cell(m['value'], m['ci_low'], m['ci_high'])}"
            if len(line) + len(item) > TABLE_WIDTH:
                break
            line += item
        click.echo(line)
        if r["note"]:
            import textwrap

            indent = " " * (width + 4)
            click.echo(textwrap.fill(r["note"], TABLE_WIDTH, initial_indent=indent, subsequent_indent=indent))
    click.echo("")


def _print_summary(summary: pl.DataFrame, title: str, family_metrics=()) -> None:
    """The verdict lines (:func:`_print_verdicts`), then one table per scope (and one for the
    standard measures): metrics down, trackers across; a table wider than TABLE_WIDTH is split
    into several with the metric column repeated, and a scope without values says so."""
    import polars as pl

    for c in ("ci_low", "ci_high"):
        if c not in summary.columns:
            summary = summary.with_columns(pl.lit(None, pl.Float64).alias(c))
    if "kind" not in summary.columns:
        summary = summary.with_columns(pl.lit("family").alias("kind"))
    summary = summary.with_columns(
        section=pl.when(pl.col("kind") == "standard").then(pl.lit("standard measures")).otherwise(pl.col("scope")))
    # rows starting "no " say why in their cell; errors without truth are left out of the report
    # (the track summary stands in for them)
    missing = summary.filter(~pl.col("scope").str.starts_with("no ")) if "note" in summary.columns else summary
    if "note" in missing.columns:
        from evaluators.missing_reasons import NO_TRUTH

        missing = missing.filter(~(pl.col("note") == NO_TRUTH).any().over("metric"))
    sections = summary["section"].unique(maintain_order=True).to_list()
    sections = [s for s in dict.fromkeys([*_declared_scopes(summary), *sections]) if s is not None]
    if not (summary["kind"] == "family").any():
        # no tracker the family's own measures apply to (multi-target trackers on a paper's
        # family): its scopes would all print empty
        sections = [s for s in sections if s in set(summary["section"].to_list())]
    sections.sort(key=lambda s: (s != "overall", s == "standard measures"))
    # a measure a tracker cannot have (NEES without a covariance) is shown as such, never as 0
    summary = summary.filter(pl.col("value").is_not_null() | pl.col("scope").str.starts_with("no "))
    # a standard-error column a metric carries beside itself is its ± already (kept in the files)
    summary = summary.filter(~pl.col("metric").str.ends_with("_stderr"))
    # a metric no tracker has a number for in a section (an error without truth) is left out
    # rather than printed as a row of dashes
    summary = summary.filter(pl.col("value").is_null() | pl.col("value").is_not_nan().any().over("section", "metric"))
    click.echo(title + "   (± half the 95 % interval over Monte Carlo runs)")
    if summary.height:
        click.echo("")
        _print_verdicts(summary, family_metrics)
    if summary.height == 0:
        click.echo("\n(no metric has a value: nothing to show)")
        return
    trackers = summary["tracker"].unique(maintain_order=True).to_list()
    overall: dict = {}
    with pl.Config(tbl_rows=400, tbl_cols=30, tbl_width_chars=TABLE_WIDTH, tbl_hide_dataframe_shape=True,
                   tbl_hide_column_data_types=True, fmt_str_lengths=60, tbl_cell_alignment="RIGHT"):
        for section in sections:
            part = summary.filter(pl.col("section") == section)
            click.echo(f"\n[{section}]")
            if part.height == 0:
                click.echo("(empty: no scan falls in this scope, so it has no metrics)")
                continue
            metrics = part["metric"].unique(maintain_order=True).to_list()
            cells = {(r["metric"], r["tracker"]): (_cell(r["value"], r["ci_low"], r["ci_high"])
                                                   if r["value"] is not None else r["scope"])
                     for r in part.iter_rows(named=True)}
            if section == "overall":
                overall = cells
            elif section != "standard measures" and cells and all(overall.get(k) == v for k, v in cells.items()):
                # a scope every scan falls in (e.g. a manoeuvre that lasts the whole run)
                click.echo("(every scan falls in this scope: its metrics are those of [overall])")
                continue
            shown = [t for t in trackers if any((m, t) in cells for m in metrics)]
            columns = {t: [cells.get((m, t), "") for m in metrics] for t in shown}
            # a box-table column takes its widest cell + 3 (padding and rule); the frame 1 more
            first = max(len("metric"), *(len(m) for m in metrics)) + 4
            widths = [max(len(t), *(len(c) for c in columns[t])) + 3 for t in shown]
            for group in _column_groups(widths, first, TABLE_WIDTH):
                # a split table shows only the metrics its trackers have
                rows = [k for k, m in enumerate(metrics) if any(columns[shown[i]][k] for i in group)]
                click.echo(pl.DataFrame({"metric": [metrics[k] for k in rows],
                                         **{shown[i]: [columns[shown[i]][k] for k in rows] for i in group}}))
    _print_missing_notes(missing)


MISSING_NOTES_SHOWN = 12  # reasons printed under the tables; the rest are in metrics.csv


def _print_missing_notes(summary: pl.DataFrame) -> None:
    """Why the metrics without a value have none (shown — or left out of the tables): one line per
    tracker and reason, from the ``note`` column (:mod:`evaluators.missing_reasons`)."""
    from evaluators.missing_reasons import notes_by_tracker

    notes = notes_by_tracker(summary)
    if not notes:
        return
    click.echo("\nmetrics without a value, and why (column 'note' of metrics.csv):")
    for tracker, metrics, note in notes[:MISSING_NOTES_SHOWN]:
        named = ", ".join(metrics[:4]) + (f" and {len(metrics) - 4} more" if len(metrics) > 4 else "")
        _echo_wrapped(f"  {tracker}: {named}: {note}", indent="    ")
    if len(notes) > MISSING_NOTES_SHOWN:
        click.echo(f"  … {len(notes) - MISSING_NOTES_SHOWN} more in the note column of metrics.csv")


def _is_rule(line: str) -> bool:
    body = line.strip()
    return len(body) >= 3 and set(body) <= set("-=─━")


def _split_text_table(rows: list[str], width: int) -> list[str] | None:
    """A space-aligned text table wider than ``width`` as several tables, each with the first
    column repeated; None when its columns cannot be told apart."""
    body = [r for r in rows if not _is_rule(r)]
    if len(body) < 2:
        return None
    n = max(len(r) for r in body)
    padded = [r.ljust(n) for r in body]
    blank = [all(r[c] == " " for r in padded) for c in range(n)]
    segments, c = [], 0
    while c < n:
        if blank[c]:
            c += 1
            continue
        start = c
        while c < n and not blank[c]:
            c += 1
        segments.append((start, c))
    header, data = padded[0], padded[1:]
    # a header word over no value, or values under no header word, belong to the next column
    # (right-aligned numbers under a wider header; "[ 1.2]"-style cells)
    columns, pending = [], None
    for start, end in segments:
        begin = start if pending is None else pending
        if header[start:end].strip() and any(r[start:end].strip() for r in data):
            columns.append((begin, end))
            pending = None
        else:
            pending = begin
    if pending is not None and columns:
        columns[-1] = (columns[-1][0], segments[-1][1])
    if len(columns) < 3:
        return None
    label_end = columns[0][1]
    pieces = [(columns[k - 1][1], columns[k][1]) for k in range(1, len(columns))]
    groups = _column_groups([b - a for a, b in pieces], label_end, width,
                            [" ".join(header[a:b].split()) for a, b in pieces])
    if len(groups) < 2:
        return None
    out = []
    for g, group in enumerate(groups):
        if g:
            out.append("")
        part_width = label_end + sum(pieces[i][1] - pieces[i][0] for i in group)
        for r in rows:
            if _is_rule(r):
                out.append(r.strip()[0] * part_width)
                continue
            r = r.ljust(n)
            out.append((r[:label_end] + "".join(r[a:b] for a, b in (pieces[i] for i in group))).rstrip())
    return out


def fit_width(text: str, width: int = TABLE_WIDTH) -> str:
    """``text`` with every space-aligned table wider than ``width`` split into narrower ones
    (first column repeated) and every longer prose line wrapped."""
    import textwrap

    lines = text.split("\n")
    out, i = [], 0
    while i < len(lines):
        line = lines[i]
        if len(line) <= width:
            out.append(line)
            i += 1
            continue
        j = i
        while j < len(lines) and (len(lines[j]) > width or _is_rule(lines[j])) and \
                ("  " in lines[j].strip() or _is_rule(lines[j])):
            j += 1
        split = _split_text_table(lines[i:j], width) if j - i >= 2 else None
        if split is not None:
            out += split
            i = j
            continue
        indent = line[: len(line) - len(line.lstrip())]
        out += textwrap.wrap(line, width, initial_indent="", subsequent_indent=indent + "  ",
                             break_long_words=False, break_on_hyphens=False) or [line]
        i += 1
    return "\n".join(out)


def _truthless_stages(res) -> list[str]:
    """The stages of ``res`` whose data hold no truth (a recording)."""
    from pipeline.stages import stages_named

    return [s.name for s in stages_named(res.results) if not s.has_truth(res.dataset)]


def _table_summary(res) -> pl.DataFrame:
    """``res.summary`` as the metric tables show it: for data without truth the track summary
    rows are left out, since :func:`_track_summary_block` prints them once, one line per tracker."""
    import polars as pl

    from evaluators.track_summary import METRICS

    truthless = _truthless_stages(res)
    if not truthless or "stage" not in res.summary.columns:
        return res.summary
    return res.summary.filter(~(pl.col("stage").is_in(truthless) & pl.col("metric").is_in(list(METRICS))))


def _track_summary_block(summary: pl.DataFrame, stage: str) -> str:
    """The track summary of one stage (:mod:`evaluators.track_summary`), one line per tracker:
    tracks per run, lifetime (median, interquartile range), scans to confirmation, and the mean
    NIS against its χ² interval. A digest: the intervals over runs are in the metrics tables
    written beside. Empty without rows."""
    import polars as pl

    from evaluators.track_summary import METRICS

    part = summary.filter(pl.col("metric").is_in(list(METRICS)))
    if "stage" in part.columns:
        part = part.filter(pl.col("stage") == stage)
    if part.height == 0:
        return ""
    values = {(r["tracker"], r["metric"]): r["value"] for r in part.iter_rows(named=True)}
    trackers = part["tracker"].unique(maintain_order=True).to_list()
    cell = lambda t, m: _cell(values.get((t, m)), None, None)  # noqa: E731
    unflagged = any(values.get((t, "tracks_ended_unflagged_per_run")) for t in trackers)
    header = ["tracker", "started", "confirmed", "deleted", "open", *(["unflagged"] if unflagged else []),
              "life s (IQR)", "scans", "confirm", "mean NIS"]
    lines = []
    for t in trackers:
        nis, low, high = (values.get((t, m)) for m in ("mean_nis", "mean_nis_low", "mean_nis_high"))
        verdict = "—" if nis is None or low is None else (
            f"{nis:.3g} " + ("in" if values.get((t, "mean_nis_inside")) else ">" if nis > high else "<")
            + f" [{low:.3g}, {high:.3g}]")
        lines.append([t, *(cell(t, f"tracks_{c}_per_run") for c in ("started", "confirmed", "deleted", "open")),
                      *([cell(t, "tracks_ended_unflagged_per_run")] if unflagged else []),
                      f"{cell(t, 'track_lifetime_s')} ({cell(t, 'track_lifetime_s_iqr')})",
                      cell(t, "track_lifetime_scans"), cell(t, "scans_to_confirmation"), verdict])
    widths = [max(len(r[i]) for r in [header, *lines]) for i in range(len(header))]
    fmt = lambda r: "  ".join(c.ljust(w) if i in (0, len(r) - 1) else c.rjust(w)  # noqa: E731
                              for i, (c, w) in enumerate(zip(r, widths))).rstrip()
    return "\n".join([f"track summary of {stage} (no truth: no error can be computed)",
                      "tracks per run; lifetime median, s (interquartile range) and scans; mean scans to confirm;",
                      "mean NIS of all updates, below (<), inside (in) or above (>) its χ² 95 % interval",
                      fmt(header), *(fmt(r) for r in lines)])


def _print_stage_reports(res) -> None:
    """What the stages add after the generic summary that it does not show (each result is
    printed once: :meth:`pipeline.stages.base.Stage.replay_report`), fitted to TABLE_WIDTH.
    For data without truth, the track summary of every stage comes first."""
    from pipeline.stages import stages_named

    truthless = _truthless_stages(res)
    for stage in stages_named(res.results):
        text = stage.replay_report(res.summary, res.per_scan) or ""
        if stage.name in truthless:
            text += "\n\n" + _track_summary_block(res.summary, stage.name)
        text += "\n\n" + (stage.track_listing(res.dataset, res.results[stage.name]) or "")
        if text.strip():
            click.echo("\n" + fit_width(text.strip("\n")))


def _export_tables(res, out_dir: Path) -> list[Path]:
    from pipeline.contract import atomic_output
    from pipeline.stages import stages_named

    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    tables = [("metrics", res.summary), ("per_scan", res.per_scan)]
    for name, df in (("targets", res.targets), ("track_lives", res.track_lives)):
        if df is not None and df.height:  # per true target and per track (evaluators.life_tables)
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

    from evaluators.report_plots import plot_consistency
    from pipeline.stages import stages_named

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

    args = [sys.executable, "-m", "pipeline.face.cli", "plot", str(data), str(tracks), "--quiet"]
    subprocess.Popen(args + (["--recover"] if recover else []), stdin=subprocess.DEVNULL,
                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)


def _say(line: str) -> None:
    """A one-line note of an output set (leftovers of an interrupted run removed, files kept), on stderr."""
    _echo_wrapped(f"replay: note: {line}", err=True)


def _echo_wrapped(text: str, indent: str = "", err: bool = False) -> None:
    """``text`` wrapped at :data:`TABLE_WIDTH` columns (paths are never broken)."""
    import textwrap

    click.echo(textwrap.fill(text, TABLE_WIDTH, subsequent_indent=indent, break_long_words=False,
                             break_on_hyphens=False), err=err)


def _list_outputs(folder: Path, groups, err: bool = False) -> None:
    """Where the files went: the folder once, then the file names per kind (a file elsewhere,
    e.g. an ``--rrd`` path, in full), every line within :data:`TABLE_WIDTH` columns where the
    names allow it. CSV and Parquet twins are listed once, as ``name.csv (+ .parquet)``."""
    folder = Path(folder)
    _echo_wrapped(f"written to {folder}{'/' if not str(folder).endswith('/') else ''}", err=err)
    for kind, paths in groups:
        paths = [Path(p) for p in paths]
        names = [p.name if p.parent == folder else str(p) for p in paths if p.suffix != ".parquet"]
        twins = any(p.suffix == ".parquet" for p in paths)
        if names:
            tail = " (+ .parquet)" if twins and kind == "tables" else ""
            _echo_wrapped(f"{kind + ':':10s} {', '.join(names)}{tail}", indent=" " * 11, err=err)


def _print_design_notes(res) -> None:
    """What the stages chose for the user on this data set (a sensor value estimated from the
    data, say), one line each (``pipeline.sensor_values``)."""
    from pipeline.stages.base import design_notes

    for stage in res.results:
        for note in design_notes(res.dataset, stage):
            _echo_wrapped(f"note: {note}")


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


@main.command("run")
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
    from pipeline.face import recording_process

    # before the heavy imports below: the child loads Rerun on the other core while they run
    recorder = recording_process.start(data, recover) if not no_rrd and map_path is None else None
    with recorder or contextlib.nullcontext():
        _run(data, trackers, out_path, rrd_path, no_rrd, force, spawn, recover, sets, rerun_run, tracker_specs,
             map_path, figures_mode, recorder, tracker_time_limit_s)


def _run(data, trackers, out_path, rrd_path, no_rrd, force, spawn, recover, sets, rerun_run, tracker_specs,
         map_path, figures_mode, recorder, tracker_time_limit_s=None):
    """``run_cmd``'s work, with ``recorder`` (a :class:`~pipeline.face.recording_process.RecordingProcess`,
    or None to record in this process) already started."""
    from pipeline.contract import read_dataset
    from pipeline.replay import replay
    from recorders.scenarios import parse_assignments

    if data.suffix.lower() in CONVERTED_SUFFIXES and map_path is None:  # a recording, not yet a data set
        raise InputError(f"a {data.suffix.lstrip('.').upper()} file is converted first: "
                         f"{CONVERTED_SUFFIXES[data.suffix.lower()]} (see replay convert --help)", data)
    if spawn:  # no display: say so before the replay, not after it
        from pipeline.face.viewer import require_display

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
    from pipeline.isolation import DEFAULT_TRACKER_TIME_LIMIT_S

    limit = DEFAULT_TRACKER_TIME_LIMIT_S if tracker_time_limit_s is None else tracker_time_limit_s
    specs = resolve_tracker_specs(tracker_specs, limit)  # a tracker that does not load fails here
    if map_path is not None:  # a recording made by another tool: replay its conversion
        from pipeline.face.cli_convert_foreign import convert_for_replay

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
        _print_summary(_table_summary(res), _metrics_title(data, res.dataset), _headline_metrics(res))
        _print_stage_reports(res)
        _print_design_notes(res)
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
        from pipeline.face.viewer import open_viewer

        open_viewer(res.rrd_path)


# --------------------------------------------------------------------------- simulate / convert


def _parameter_options(args) -> dict:
    """Extra ``--name value`` / ``--name=value`` options of ``simulate`` → scenario overrides
    (``--emitter-velocity-mps`` names ``emitter_velocity_mps``), exactly like ``--set name=value``."""
    out, i = {}, 0
    while i < len(args):
        arg = args[i]
        if not arg.startswith("--") or arg == "--":
            raise InputError(f"unexpected argument {arg!r} (scenario parameters go as --name value or --set name=value)")
        name, eq, value = arg[2:].partition("=")
        if not eq:
            if i + 1 >= len(args) or args[i + 1].startswith("--"):
                raise InputError(f"option --{name} needs a value")
            value, i = args[i + 1], i + 1
        out[name.replace("-", "_")] = value
        i += 1
    return out


@main.command("simulate", context_settings={"ignore_unknown_options": True, "allow_extra_args": True})
@click.argument("scenario")
@click.option("--runs", default=100, show_default=True, type=click.IntRange(min=1), help="Monte Carlo runs.")
@click.option("--seed", default=0, show_default=True, type=click.IntRange(min=0), help="Random seed (same seed, same bytes).")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False, path_type=Path))
@click.option("--set", "sets", multiple=True, metavar="NAME=VALUE", help="Override a scenario parameter.")
@force_option
@click.pass_context
def simulate_cmd(ctx, scenario, runs, seed, output, sets, force):
    """Simulate a scenario (a name from data/scenarios/ or a TOML path) into an MCAP file.

    Any scenario parameter also works as an option: --name value means --set name=value.

    \b
    Example:
      replay simulate radar-tws --runs 500 --seed 7 -o radar.mcap --set sigma_bearing_deg=0.5
      replay simulate tdoa-fdoa --geometry line --emitter 1 --runs 1000 -o emitter.mcap
    """
    from recorders import recorder_module
    from recorders.scenarios import load_scenario, parse_assignments
    from recorders.simulated import write_simulated
    from pipeline.contract import scenario_metadata

    sc = load_scenario(scenario).with_overrides({**_parameter_options(ctx.args), **parse_assignments(sets)})
    rec = recorder_module(sc.recorder)
    t0 = time.perf_counter()
    refuse_input_overwrite([Path(scenario)], [output])
    refuse_replacing_file(output, force)
    with progress.bar(1, f"simulating {sc.name} ({runs} runs)") as bar, progress.timed("simulate"):
        data = rec.simulate(sc.params, runs, seed)
        bar.update(1)
    with progress.bar(len(data.times), f"writing {output.name}") as bar, progress.timed("write"):
        n = write_simulated(output, data, scenario_metadata(sc.name, sc.params, seed), bar.update)
    click.echo(f"wrote {output}: {n} messages, {data.n_runs} runs × {len(data.times)} scans, seed {seed} "
               f"({time.perf_counter() - t0:.2f} s)")


def _format_value(v, limit: int = 24) -> str:
    """A scenario parameter's value as typed on the command line; never blank."""
    if isinstance(v, bool):
        text = str(v).lower()
    elif isinstance(v, float):
        text = f"{v:g}"
    elif isinstance(v, list):
        text = "[" + ", ".join(_format_value(x, 10**6) for x in v) + "]"
    elif isinstance(v, str):
        text = v if v.strip() else "(none)"
    else:
        text = str(v)
    return text if len(text) <= limit else text[: limit - 1] + "…"


def _wrap_cells(header, rows, last_width_min: int = 24, width: int = TABLE_WIDTH) -> list[str]:
    """A left-aligned text table whose last column wraps to keep every line within ``width``."""
    import textwrap

    widths = [max(len(str(c)) for c in col) for col in zip(header, *[r[:-1] for r in rows])]
    lead = sum(w + 2 for w in widths)
    last = max(last_width_min, width - lead)
    out = []
    for row in (header, *rows):
        left = "".join(str(c).ljust(w + 2) for c, w in zip(row[:-1], widths))
        parts = textwrap.wrap(str(row[-1]), last) or [""]
        out.append((left + parts[0]).rstrip())
        out += [(" " * lead + p).rstrip() for p in parts[1:]]
    return out


@main.command("scenarios")
@click.argument("name", required=False)
def scenarios_cmd(name):
    """List the bundled scenarios, or show one scenario's parameters.

    With NAME (a bundled scenario or a TOML path): every parameter with its default, its unit
    (from the suffix of its name: _m, _s, _deg, _mps, _mps2, _hz, _db, _rad, ...; count,
    probability, flag, ... for the dimensionless ones) and its meaning (the comment after it in
    the scenario file, or the comment lines directly above it). Any of them can be changed with
    `replay simulate NAME --set name=value` (or --name value).

    \b
    Example:
      replay scenarios
      replay scenarios radar-tws
      replay simulate radar-tws --set sigma_bearing_deg=0.5 -o radar.mcap
    """
    from recorders.scenarios import available_scenarios, load_scenario, parameter_docs, parameter_unit

    if name is None:
        rows = []
        for n in available_scenarios():
            sc = load_scenario(n)
            rows.append((n, f"{len(sc.params)}", sc.description or "-"))
        for line in _wrap_cells(("SCENARIO", "PARAMETERS", "DESCRIPTION"), rows):
            click.echo(line)
        click.echo("\nparameters, units and defaults of one: replay scenarios NAME")
        return
    import textwrap

    sc = load_scenario(name)
    docs = parameter_docs(sc.source)
    click.echo(textwrap.fill(f"{sc.name}: {sc.description or '(no description)'}", TABLE_WIDTH,
                             subsequent_indent="  "))
    click.echo(f"recorder {sc.recorder}; file {sc.source}")
    click.echo("")
    rows = [(k, _format_value(v), parameter_unit(k, v) or "-", docs.get(k, "-")) for k, v in sc.params.items()]
    for line in _wrap_cells(("NAME", "DEFAULT", "UNIT", "MEANING"), rows):
        click.echo(line)
    click.echo(f"\nchange any: replay simulate {sc.name} --set NAME=VALUE -o data.mcap (a list: comma-separated)")


@main.group("convert")
def convert_group():
    """Convert recorded data into the MCAP data contract.

    Tables of measurements (CSV or Parquet) come in with plots, peaks, tdoa-fdoa and positions;
    `replay export --table` writes a data set's measurements out in the same format.

    \b
    Example:
      replay convert plots plots.csv -o plots.mcap --set sigma_bearing_deg=0.8
      replay convert tdoa-fdoa pairs.parquet --sensors sensors.parquet -o emitter.mcap
      replay convert array-wav array.wav -o rec.mcap --spacing-m 0.04 --frequency-hz 2000
    """


# --------------------------------------------------------------------------- eval / check


@main.command("eval")
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
def eval_cmd(data, outputs, as_json, per_scan, export_dir, recover, trackers, sets, tracker_specs):
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

    from pipeline.replay import evaluate_files, replay
    from recorders.scenarios import parse_assignments

    if tracker_specs and outputs is not None:
        raise InputError("--tracker applies when eval replays in memory (no OUTPUTS); the trackers of "
                         f"{outputs} already ran")
    if export_dir:
        refuse_input_overwrite([data, outputs], [export_dir / n for n in REPORT_FILES])
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
        _print_summary(_table_summary(res), _metrics_title(data, res.dataset), _headline_metrics(res))
        _print_stage_reports(res)
        _print_design_notes(res)
    if export_dir:
        # the tables and figures as one set (pipeline.paths.OutputSet): all of them or none
        with progress.timed("export"), OutputSet(export_dir, replaces=REPORT_FILES, inputs=[data, outputs],
                                                 name="export", say=_say) as staged:
            tables = [staged.final(p) for p in _export_tables(res, staged.stage)]
            plots = [staged.final(p) for p in _report_plot(res, staged.stage)]
        # with --json, stdout stays pure JSON: the paths go to stderr
        click.echo("", err=as_json)
        _list_outputs(export_dir, [("tables", tables), ("plots", plots)], err=as_json)
    fail_on_tracker_errors([str(exc) for exc in getattr(res, "failures", [])])


@main.command("plot")
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
    from pipeline.replay import replay_of_files

    refuse_input_overwrite([data, outputs], [outputs.parent / n for n in REPORT_FILES if n.endswith(".png")])
    res = replay_of_files(data, outputs, recover=recover)
    from pipeline.paths import link_into_set, set_version_folder

    # outputs of a published set (links into its version folder): the figures join that set
    version = set_version_folder(outputs)
    with progress.timed("plots"):
        plots = _report_plot(res, version or outputs.parent)
    if version is not None:
        for p in plots:
            link_into_set(outputs, p.name)
        plots = [outputs.parent / p.name for p in plots]
    _list_outputs(outputs.parent, [("plots", plots)])


def _json_value(v):
    if isinstance(v, float) and v != v:
        return None
    return v


# The evaluation design values of every stage with their defaults (Stage.evaluation_defaults;
# tests/test_evaluation_design_values.py keeps this text equal to them): written out here so
# that `--help` needs no import of the stages.
EVALUATION_VALUES_EPILOG = """Evaluation design values (--set NAME=VALUE) with each stage's fixed defaults; a data set's
scenario record, or the data set itself, may give others (docs/evaluation.md, "Evaluation design values"):

\b
  radar-tws          ospa_cutoff_m=1000, ospa_order=2, assignment_gate_m=500,
                     hota_distance_m=1000, gospa_switch_penalty_m=1000, siap_gate_m=500
  xcorr-peaks        ospa_cutoff_deg=10, ospa_order=2, assignment_gate_deg=5
  array-bearing      ospa_cutoff_deg=10, ospa_order=2, assignment_gate_deg=3
  tdoa-fdoa          ospa_cutoff_m=5000, ospa_order=2, assignment_gate_m=2000
  colored-noise-imm  ospa_cutoff_m=100, ospa_order=2, assignment_gate_m=50"""

EVALUATION_SET_HELP = ("Score with this evaluation design value (the matching gate, the GOSPA cut-off and order, "
                       "HOTA's distance scale, the SIAP gate; listed below); repeatable.")


@main.command("compare", epilog=EVALUATION_VALUES_EPILOG)
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
def compare_cmd(a_path, b_path, data_path, pairs, as_json, out_dir, recover, sets):
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

    from evaluators.compare import write_comparison_figure
    from pipeline.contract import atomic_output
    from pipeline.replay import compare_files, format_evaluation_values
    from recorders.scenarios import parse_assignments

    overrides = parse_assignments(sets)
    parsed = []
    for p in pairs:
        if p.count(":") != 1 or not all(p.split(":")):
            raise InputError(f"--pair {p!r}: expected A_NAME:B_NAME")
        parsed.append(tuple(p.split(":")))
    out_dir = out_dir or Path.cwd() / "replay-out" / "compare"
    refuse_input_overwrite([a_path, b_path, data_path],
                           [out_dir / n for n in ("compare.csv", "compare.parquet", "compare.png", "compare.rrd")])
    cmp = compare_files(a_path, b_path, data_path, parsed or None, recover, overrides)
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
    out_dir.mkdir(parents=True, exist_ok=True)
    with atomic_output(out_dir / "compare.csv", "w") as f:
        table.write_csv(f)
    record = {"a": str(a_path), "b": str(b_path), "data": Path(cmp.dataset.path).name, "stage": cmp.stage.name,
              "evaluation": cmp.evaluation, "evaluation_set": list(cmp.evaluation_set)}
    with atomic_output(out_dir / "compare.parquet", "wb") as f:
        table.write_parquet(f, metadata={"replay.compare": json.dumps(record, default=str)})
    write_comparison_figure(table, out_dir / "compare.png", f"A = {a_path.name}  vs  B = {b_path.name}")
    from pipeline.face.rerun_views import log_comparison

    log_comparison(cmp, out_dir / "compare.rrd")
    if not as_json:
        click.echo(f"tables: {out_dir / 'compare.csv'} (+ .parquet); plot: {out_dir / 'compare.png'}; "
                   f"recording: {out_dir / 'compare.rrd'}")


@main.command("help")
@click.argument("command", required=False)
@click.pass_context
def help_cmd(ctx, command):
    """The help of replay, or of one command.

    \b
    Example:
      replay help
      replay help sweep
    """
    group = ctx.parent.command
    if command is None:
        click.echo(group.get_help(ctx.parent))
        return
    cmd = group.get_command(ctx.parent, command)
    if cmd is None:
        import difflib

        close = difflib.get_close_matches(command, list(group.commands), n=1)
        raise click.UsageError(f"no such command {command!r}" + (f" (did you mean '{close[0]}'?)" if close else ""))
    with click.Context(cmd, info_name=command, parent=ctx.parent) as sub:
        click.echo(cmd.get_help(sub))


@main.command("check", epilog=EVALUATION_VALUES_EPILOG)
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
    from pipeline.check import UPDATE_WITH_SET, evaluation_values, run_check
    from recorders.scenarios import parse_assignments

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
            # one of these lines ends each data set (pipeline.check's report lines)
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


# --------------------------------------------------------------------------- sweep


@main.command("sweep", epilog=EVALUATION_VALUES_EPILOG)
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
    from pipeline.registry import canonical_spec
    from pipeline.sweep import (build_grid, check_evaluation_values, check_resume, parse_param_specs, run_sweep,
                                write_sweep_outputs)
    from recorders.scenarios import parse_assignments

    if scheduler:
        executor = "dask"
    specs = parse_param_specs(params)
    fixed = parse_assignments(sets)
    wanted = [t.strip() for t in trackers.split(",")] if trackers else None
    plugged = [canonical_spec(s) for s in resolve_tracker_specs(tracker_specs, tracker_time_limit_s)]
    from recorders.scenarios import load_scenario

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
        from pipeline.registry import available_trackers
        from pipeline.stages import STAGES

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
    from pipeline.registry import available_trackers
    from pipeline.stages import STAGES
    from pipeline.sweep import scenario_families
    from recorders.scenarios import load_scenario

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
            out.update(stage.parameter_defaults(entries))
            evaluation.update({k: v for k, v in stage.evaluation_defaults.items() if k not in evaluation})
    return out, evaluation


# --------------------------------------------------------------------------- trackers


def tracker_listing(specs=()) -> list[dict]:
    """Every tracker found (built-in, entry points, ``specs``) with its design parameters.

    A parameter whose default is None takes its value from the bundled scenario of the stage
    that consumes the tracker's family (:meth:`pipeline.stages.base.Stage.parameter_defaults`);
    ``from`` says which (``"tracker"`` or ``"scenario <name>"``), and ``default`` stays None when
    neither has one (the value must then come from the data set or ``--set``).
    """
    from pipeline.registry import available_trackers
    from pipeline.stages import STAGES

    stages = {}
    for s in STAGES:
        stages.setdefault(s.family, s)
    rows = []
    for e in available_trackers(specs).values():
        stage = stages.get(e.family)
        try:
            resolved = stage.parameter_defaults([e]) if stage is not None else {}
        except InputError:  # a parameter neither the tracker nor the scenario sets: resolve one by one
            from recorders.scenarios import load_scenario

            scenario = load_scenario(stage.scenario).params
            resolved = {p.name: scenario.get(p.name) for p in e.cls.params if p.default is None}
        params = []
        for p in e.cls.params:
            if p.default is not None:
                default, origin = p.default, "tracker"
            else:
                default = resolved.get(p.name)
                origin = f"scenario {stage.scenario}" if stage is not None and default is not None else "data set / --set"
            params.append({"name": p.name, "default": default, "unit": p.unit, "from": origin, "doc": p.doc})
        if not e.builtin:
            runs = "always"  # a plugged tracker runs beside the built-ins
        elif not getattr(e.cls, "runs_by_default", True):
            runs = "when-named"
        else:
            runs = "many-targets" if getattr(e.cls, "targets", "one") == "many" else "paper-scenes"
        rows.append({"name": e.name, "family": e.family, "form": e.cls.form, "source": e.source, "runs": runs,
                     "spec": e.spec, "stage": stage.name if stage is not None else None, "params": params})
    return rows


def _format_default(v) -> str:
    if v is None:
        return "-"
    if isinstance(v, bool):
        return str(v).lower()
    if isinstance(v, float):
        return f"{v:g}"
    if isinstance(v, (list, tuple)):
        return ",".join(_format_default(x) for x in v)
    return str(v)


def _table(header, rows, indent="") -> list[str]:
    widths = [max(len(str(c)) for c in col) for col in zip(header, *rows)]
    out = []
    for row in (header, *rows):
        out.append(indent + "  ".join(str(c).ljust(w) for c, w in zip(row, widths)).rstrip())
    return out


@main.command("trackers")
@tracker_option
@click.option("--json", "as_json", is_flag=True, help="Print the listing as JSON.")
def trackers_cmd(tracker_specs, as_json):
    """List the trackers: built-in, installed (entry points) and plugged with --tracker.

    For each: its measurement family, form (batch: all runs at once; run: one run at a time),
    which data sets a replay runs it on without --trackers (paper-scenes: a built-in made for
    the papers' scenes; many-targets: for truth sets of many targets among clutter; when-named: a
    variant run only when named; always: a plugged one), where it comes from, and
    its design parameters with default and unit (a default taken from
    the stage's bundled scenario says so). Any of them can be changed with --set NAME=VALUE.

    \b
    Example:
      replay trackers
      replay trackers --tracker my_trackers.py:ConstantVelocity --json
    """
    rows = tracker_listing(resolve_tracker_specs(tracker_specs))
    if as_json:
        click.echo(json.dumps(rows, indent=1, default=str))
        return
    for line in _table(("TRACKER", "FAMILY", "FORM", "BY-DEFAULT-ON", "SOURCE"),
                       [(r["name"], r["family"], r["form"], r["runs"], r["source"]) for r in rows]):
        click.echo(line)
    # trackers with the same parameter table share one listing
    groups: dict[str, list] = {}
    for r in rows:
        if r["params"]:
            groups.setdefault(json.dumps(r["params"], default=str), []).append(r)
    for members in groups.values():
        click.echo(f"\ndesign parameters of {', '.join(r['name'] for r in members)}:")
        params = members[0]["params"]
        for line in _table(("NAME", "DEFAULT", "UNIT", "FROM", "MEANING"),
                           [(p["name"], _format_default(p["default"]), p["unit"] or "-", p["from"], p["doc"])
                            for p in params], indent="  "):
            click.echo(line)


# --------------------------------------------------------------------------- view


@main.command("view")
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

    from pipeline.face.viewer import open_viewer, screenshot

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
    from pipeline.contract import dataset_topics
    from pipeline.replay import replay

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


# --------------------------------------------------------------------------- export


@main.command("export")
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
    from pipeline.face.export_foxglove import export_foxglove

    if foxglove and table:
        raise click.UsageError("choose one format: --foxglove or --table")
    if table:
        from pipeline.face.cli_convert_tables import export_tables

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


# --------------------------------------------------------------------------- extensions
# Paper-specific commands (e.g. `replay crlb`) live next to their paper's code; each module
# listed here exposes COMMANDS, a list of click commands added to `replay`, and may expose
# CONVERT_COMMANDS, added under `replay convert` (the modules never import this one: no circle).
EXTENSION_MODULES: tuple[str, ...] = (
    "pipeline.face.cli_emitter",
    "pipeline.face.cli_colored_noise",
    "pipeline.face.cli_xcorr",
    "pipeline.face.cli_array",
    "pipeline.face.cli_convert_upgrade",
    "pipeline.face.cli_convert_tables",
    "pipeline.face.cli_convert_foreign",
    "pipeline.face.cli_info",
    # one line per module: "pipeline.cli_<paper>",
)


def _register_extensions() -> None:
    import importlib

    for name in EXTENSION_MODULES:
        module = importlib.import_module(name)
        for cmd in module.COMMANDS:
            main.add_command(cmd)
        for cmd in getattr(module, "CONVERT_COMMANDS", ()):
            convert_group.add_command(cmd)


_register_extensions()
for _command in main.commands.values():  # --quiet / --verbose are accepted by every command
    progress.add_progress_options(_command)

if __name__ == "__main__":  # pragma: no cover
    main()
