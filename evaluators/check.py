"""``replay check``: re-run the bundled data sets and compare with their baselines.

A regression data set is any ``data/*.mcap`` with a baseline ``data/baselines/<stem>.json``
(replayed in memory, all trackers), and any sweep spec ``data/sweeps/<name>.toml`` with a
baseline ``data/baselines/sweep-<name>.json`` (simulated, replayed and evaluated per grid point).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import polars as pl

from evaluators.baselines import baseline_path, compare, read_baseline, write_baseline
from pipeline.errors import InputError


@dataclass
class CheckReport:
    checked: list[str] = field(default_factory=list)
    drifted: dict[str, list] = field(default_factory=dict)
    updated: list[str] = field(default_factory=list)

    @property
    def failed(self) -> bool:
        return bool(self.drifted)


def _datasets(data_dir: Path):
    for mcap in sorted(data_dir.glob("*.mcap")):
        yield mcap.stem, lambda m=mcap: _replay_summary(m)
    for spec in sorted((data_dir / "sweeps").glob("*.toml")):
        yield f"sweep-{spec.stem}", lambda s=spec: _sweep_summary(s)


def _replay_summary(path: Path) -> pl.DataFrame:
    from pipeline.replay import replay

    return replay(path).summary


def _sweep_summary(spec: Path) -> pl.DataFrame:
    from pipeline.sweep import run_sweep_spec

    table = run_sweep_spec(spec)
    return table.select(pl.col("tracker"), pl.col("metric"), pl.col("point").alias("scope"), pl.col("value"))


def run_check(data_dir: str | Path, update: bool = False, echo=print) -> CheckReport:
    """Check (or with ``update`` rewrite) every regression data set in ``data_dir``."""
    data_dir = Path(data_dir)
    if not data_dir.is_dir():
        raise InputError("no such data folder", data_dir)
    report = CheckReport()
    items = list(_datasets(data_dir))
    if not items:
        raise InputError("no data sets (*.mcap) or sweep specs (sweeps/*.toml) to check", data_dir)
    for name, compute in items:
        bpath = baseline_path(data_dir, name)
        if not bpath.exists() and not update:
            echo(f"skip  {name}: no baseline ({bpath}); create it with `replay check --update`")
            continue
        summary = compute()
        summary = summary.filter(pl.col("scope").is_not_null())
        report.checked.append(name)
        if update:
            previous = read_baseline(bpath) if bpath.exists() else None
            write_baseline(bpath, name, summary, previous)
            report.updated.append(name)
            echo(f"wrote {bpath} ({summary.height} metrics)")
            continue
        drifts = compare(summary, read_baseline(bpath))
        if drifts:
            report.drifted[name] = drifts
            echo(f"FAIL  {name}: {len(drifts)} metric(s) moved")
            for d in drifts:
                echo(f"      {d.describe()}")
        else:
            echo(f"ok    {name}: {summary.height} metrics within tolerance")
    if not update:
        echo(f"{len(report.checked)} data set(s) checked, {len(report.drifted)} drifted")
    return report
