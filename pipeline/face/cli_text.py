"""The text a replay prints: metric tables split to the terminal's width, verdicts, the notes
of metrics without a value, the track summary and the list of outputs written.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import click

if TYPE_CHECKING:  # annotations; polars is imported where it is used (the CLI starts fast)
    import polars as pl



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

    from trackreplay.stages import STAGE_CLASSES, stage_named

    known = {name for name, _, _ in STAGE_CLASSES}
    stages = summary["stage"].unique(maintain_order=True).to_list() if "stage" in summary.columns else []
    out = []
    for name in stages:
        stage = stage_named(name) if name in known else None
        if stage is None or not stage.declared_scopes:
            continue
        need = stage.declared_scopes_need
        if need is None or need in summary.filter(pl.col("stage") == name)["metric"].to_list():
            out += stage.declared_scopes
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
    from trackreplay.stages import stage_named

    return tuple(m for name in res.results for m in stage_named(name).report_metrics[:1])


def _print_verdicts(summary: pl.DataFrame, family_metrics=()) -> None:
    """The verdict before the detail: one line per tracker with its headline measures (± half
    their interval) and its consistency verdict (:mod:`trackreplay.evaluators.verdicts`)."""
    from trackreplay.evaluators.verdicts import tracker_verdicts

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
        from trackreplay.evaluators.missing_reasons import NO_TRUTH

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
    tracker and reason, from the ``note`` column (:mod:`trackreplay.evaluators.missing_reasons`)."""
    from trackreplay.evaluators.missing_reasons import notes_by_tracker

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
    from trackreplay import stage_scoring
    from trackreplay.stages import stages_named

    return [s.name for s in stages_named(res.results) if not stage_scoring.has_truth(s, res.dataset)]


def _table_summary(res) -> pl.DataFrame:
    """``res.summary`` as the metric tables show it: for data without truth the track summary
    rows are left out, since :func:`_track_summary_block` prints them once, one line per tracker."""
    import polars as pl

    from trackreplay.evaluators.track_summary import METRICS

    truthless = _truthless_stages(res)
    if not truthless or "stage" not in res.summary.columns:
        return res.summary
    return res.summary.filter(~(pl.col("stage").is_in(truthless) & pl.col("metric").is_in(list(METRICS))))


def _track_summary_block(summary: pl.DataFrame, stage: str) -> str:
    """The track summary of one stage (:mod:`trackreplay.evaluators.track_summary`), one line per tracker:
    tracks per run, lifetime (median, interquartile range), scans to confirmation, and the mean
    NIS against its χ² interval. A digest: the intervals over runs are in the metrics tables
    written beside. Empty without rows."""
    import polars as pl

    from trackreplay.evaluators.track_summary import METRICS

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
    printed once: :func:`trackreplay.face.stage_text.replay_report`), fitted to TABLE_WIDTH.
    For data without truth, the track summary of every stage comes first."""
    from trackreplay.face import stage_text
    from trackreplay.stages import stages_named

    truthless = _truthless_stages(res)
    for stage in stages_named(res.results):
        text = stage_text.replay_report(stage, res.summary, res.per_scan) or ""
        if stage.name in truthless:
            text += "\n\n" + _track_summary_block(res.summary, stage.name)
        text += "\n\n" + (stage_text.track_listing(stage, res.dataset, res.results[stage.name]) or "")
        if text.strip():
            click.echo("\n" + fit_width(text.strip("\n")))


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
    data, say), one line each (``trackreplay.sensor_values``)."""
    from trackreplay.design_values import design_notes

    for stage in res.results:
        for note in design_notes(res.dataset, stage):
            _echo_wrapped(f"note: {note}")


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


def print_replay_report(res, data) -> None:
    """What ``replay`` and ``replay eval`` print of a replay: the metric tables with their
    verdicts, each stage's own report and the design notes."""
    _print_summary(_table_summary(res), _metrics_title(data, res.dataset), _headline_metrics(res))
    _print_stage_reports(res)
    _print_design_notes(res)
