"""A sweep's files: the table as Parquet and CSV, the spec as JSON, one plot per metric."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING

import polars as pl

from trackreplay import __version__
from trackreplay.sweep.evaluation import EVALUATION_METADATA, evaluation_summary
from trackreplay.sweep.folder import _folder_lock, _named_output, _remove_temporaries
from trackreplay.sweep.interruption import _stop_on_signals

if TYPE_CHECKING:
    from trackreplay.sweep.run import SweepReport


def write_sweep_outputs(report: SweepReport, swept: list[str], spec: dict) -> list[Path]:
    """Table as Parquet + CSV, the spec as JSON (with the evaluation design values the points were
    scored with: :func:`evaluation_summary`), and one PNG per metric vs the first swept parameter."""
    out = report.out_dir
    with _stop_on_signals(), _folder_lock(out):
        try:
            return _write_sweep_outputs(report, swept, {**spec, "version": __version__,
                                                        "evaluation": evaluation_summary(report.evaluation)})
        finally:
            # a signal can land between a temporary's creation and the code that removes it
            # (inside tempfile.mkstemp); whatever is left is swept up here
            _remove_temporaries(out)


def _write_sweep_outputs(report: SweepReport, swept: list[str], spec: dict) -> list[Path]:
    from trackreplay.evaluators.report_plots import plot_facets, plot_metrics_vs

    out = report.out_dir
    paths = []
    with _named_output(out / "sweep.parquet") as f:
        report.table.write_parquet(f, metadata={EVALUATION_METADATA: json.dumps(spec.get("evaluation", {}),
                                                                                default=str)})
    with _named_output(out / "sweep.csv") as f:
        report.table.write_csv(f)
    with _named_output(out / "sweep.json", "w") as f:
        json.dump(spec, f, indent=1, default=str)
    paths += [out / "sweep.parquet", out / "sweep.csv", out / "sweep.json"]
    if report.table.height == 0:
        return paths
    x = swept[0]
    others = swept[1:]
    wide = report.table.pivot(on="metric", index=["point", *swept, "tracker"], values="value", aggregate_function="first")
    plot_dir = out / "plots"
    for metric in report.table["metric"].unique(maintain_order=True):
        values = report.table.filter(pl.col("metric") == metric)["value"].drop_nulls().drop_nans()
        if values.n_unique() <= 1:
            continue  # the same at every point for every tracker (a bound, a count that stays 0): nothing to plot
        title = f"{spec.get('scenario', '')}: {metric} vs {x}"
        if others:  # one panel per combination of the other parameters' values, readable for any number
            paths.append(plot_facets(wide, x, metric, others, plot_dir / f"{metric}.png", title=title))
        else:
            paths.append(plot_metrics_vs(wide, x, [metric], plot_dir / f"{metric}.png", title=title))
    return paths
