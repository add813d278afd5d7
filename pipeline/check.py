"""``replay check``: re-run the bundled data sets and compare with their baselines.

A regression data set is any ``data/*.mcap`` with a baseline ``data/baselines/<stem>.json``
(replayed in memory, all trackers), and any sweep spec ``data/sweeps/<name>.toml`` with a
baseline ``data/baselines/sweep-<name>.json`` (simulated, replayed and evaluated per grid point).

Plugged trackers (``replay check --tracker SPEC``) run beside the built-ins on every data set
and sweep of their measurement family. Their metrics are compared with the baseline entries
that exist for them; ``--update`` adds them and records the tracker's spec in the baseline's
``plugged`` table, so a later check without ``--tracker`` skips (and names) those entries
instead of reporting them missing. A tracker that fails is reported once, with the data set.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import polars as pl

from evaluators.baselines import baseline_path, compare, plugged_trackers, read_baseline, write_baseline
from pipeline.errors import InputError


@dataclass
class CheckReport:
    checked: list[str] = field(default_factory=list)
    drifted: dict[str, list] = field(default_factory=dict)
    updated: list[str] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)  # one line per tracker that failed

    @property
    def failed(self) -> bool:
        return bool(self.drifted)


@dataclass
class _Outcome:
    """What checking one data set produced: its summary and the trackers that failed on it."""

    summary: pl.DataFrame
    failures: list = field(default_factory=list)  # (where, message)


def _plugged_families(tracker_specs) -> dict[str, tuple[str, str]]:
    """spec → (tracker name, family) of every plugged tracker."""
    from pipeline.registry import available_trackers

    table = available_trackers(tracker_specs)
    return {e.source: (e.name, e.family) for e in table.values() if e.source in tracker_specs}


def _datasets(data_dir: Path, plugged: dict):
    for mcap in sorted(data_dir.glob("*.mcap")):
        yield mcap.stem, lambda m=mcap: _replay_summary(m, plugged)
    for spec in sorted((data_dir / "sweeps").glob("*.toml")):
        yield f"sweep-{spec.stem}", lambda s=spec: _sweep_summary(s, plugged)


def _replay_summary(path: Path, plugged: dict) -> _Outcome:
    from pipeline.contract import read_dataset
    from pipeline.replay import replay
    from pipeline.stages import applicable_stages

    ds = read_dataset(path)
    families = {s.family for s in applicable_stages(ds.channels)}
    specs = [spec for spec, (_, family) in plugged.items() if family in families]
    res = replay(path, dataset=ds, tracker_specs=specs)
    return _Outcome(res.summary, [(exc.path or "", str(exc)) for exc in res.failures])


def _sweep_summary(spec: Path, plugged: dict) -> _Outcome:
    from pipeline.sweep import scenario_families, sweep_spec_report, sweep_spec_scenario

    specs = []
    if plugged:
        families = scenario_families(sweep_spec_scenario(spec))
        specs = [s for s, (_, family) in plugged.items() if family in families]
    report = sweep_spec_report(spec, tracker_specs=specs)
    table = report.table
    if table.height == 0:
        table = pl.DataFrame(schema={"tracker": pl.Utf8, "metric": pl.Utf8, "point": pl.Utf8, "value": pl.Float64,
                                     "se": pl.Float64})
    failures = [(where, f"{message} (point {label})")
                for label, errors in report.tracker_failures.items() for where, message in errors]
    # the standard error rides along, so that a drift says how many of them it moved
    return _Outcome(table.select(pl.col("tracker"), pl.col("metric"), pl.col("point").alias("scope"), pl.col("value"),
                                 pl.col("se")), failures)


def run_check(data_dir: str | Path, update: bool = False, echo=print, tracker_specs=()) -> CheckReport:
    """Check (or with ``update`` rewrite) every regression data set in ``data_dir``.

    Parameters
    ----------
    tracker_specs : sequence of str
        Plugged trackers (``FILE.py:Class`` or ``module:Class``) to run beside the built-ins on
        the data sets of their family.

    Returns
    -------
    CheckReport
        ``drifted`` lists the metrics that moved; ``errors`` one line per tracker that failed
        (its first failure, naming the tracker, run, scan and data set).
    """
    data_dir = Path(data_dir)
    if not data_dir.is_dir():
        raise InputError("no such data folder", data_dir)
    plugged = _plugged_families(list(tracker_specs))
    plugged_names = {name: spec for spec, (name, _) in plugged.items()}
    report = CheckReport()
    items = list(_datasets(data_dir, plugged))
    if not items:
        raise InputError("no data sets (*.mcap) or sweep specs (sweeps/*.toml) to check", data_dir)
    ran: set[str] = set()
    failures: dict[str, list[tuple[str, str]]] = {}  # where → [(message, data set), ...]
    for name, compute in items:
        bpath = baseline_path(data_dir, name)
        if not bpath.exists() and not update:
            echo(f"skip  {name}: no baseline ({bpath}); create it with `replay check --update`")
            continue
        outcome = compute()
        for where, message in outcome.failures:
            failures.setdefault(where, []).append((message, name))
        summary = outcome.summary.filter(pl.col("scope").is_not_null())
        present = set(summary["tracker"].unique())
        ran |= present & set(plugged_names)
        report.checked.append(name)
        if update:
            previous = read_baseline(bpath) if bpath.exists() else None
            write_baseline(bpath, name, summary, previous, {n: s for n, s in plugged_names.items() if n in present})
            report.updated.append(name)
            echo(f"wrote {bpath} ({summary.height} metrics)")
            continue
        baseline = read_baseline(bpath)
        in_baseline = {rec["tracker"] for rec in baseline["metrics"]}
        new = sorted(n for n in present & set(plugged_names) if n not in in_baseline)
        for n in new:
            echo(f"note  {name}: tracker {n!r} has no baseline entries yet; add them with "
                 f"`replay check --tracker {plugged_names[n]} --update`")
        skipped = sorted(n for n in plugged_trackers(baseline) if n not in present)
        for n in skipped:
            echo(f"note  {name}: baseline entries of plugged tracker {n!r} not checked (give "
                 f"--tracker {plugged_trackers(baseline)[n]})")
        drifts = compare(summary, baseline, unbaselined=new)
        if drifts:
            report.drifted[name] = drifts
            echo(f"FAIL  {name}: {len(drifts)} metric(s) moved")
            for d in drifts:
                echo(f"      {d.describe()}")
        else:
            echo(f"ok    {name}: {summary.height} metrics within tolerance")
    for spec, (tracker, family) in plugged.items():
        if tracker not in ran and spec not in failures:
            echo(f"note  tracker {tracker!r} ({family}) ran on no data set with a baseline in {data_dir}")
    for items in failures.values():  # one line per failing tracker: its first failure
        message, name = items[0]
        more = f"; failed on {len(items)} data sets" if len(items) > 1 else ""
        report.errors.append(f"{message} (data set {name}{more})")
    if not update:
        echo(f"{len(report.checked)} data set(s) checked, {len(report.drifted)} drifted")
    return report
