"""``replay check``: re-run the bundled data sets and compare with their baselines.

A regression data set is any ``data/*.mcap`` with a baseline ``data/baselines/<stem>.json``
(replayed in memory, all trackers), and any sweep spec ``data/sweeps/<name>.toml`` with a
baseline ``data/baselines/sweep-<name>.json`` (simulated, replayed and evaluated per grid point).

Plugged trackers (``replay check --tracker SPEC``) run beside the built-ins on every data set
and sweep of their measurement family. Their metrics are compared with the baseline entries
that exist for them; ``--update`` adds them and records the tracker's spec in the baseline's
``plugged`` table, so a later check without ``--tracker`` skips (and names) those entries
instead of reporting them missing. A tracker that fails is reported once, with the data set.

Evaluation design values (``replay check --set NAME=VALUE``: the matching gate, the GOSPA
cut-off and order, HOTA's distance scale, the SIAP gate) score every data set and sweep whose
stage declares the name with that value. The baselines hold the metrics of the default values,
so such a check says so in one line before it starts (the metrics that depend on the values may
drift), and ``--update`` refuses them: a baseline of non-default values would make every later
plain check fail.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import polars as pl

from trackreplay.evaluators.baselines import baseline_path, compare, plugged_trackers, read_baseline, write_baseline
from trackreplay.errors import InputError


#: why ``replay check --update`` refuses ``--set``
UPDATE_WITH_SET = ("--update with --set: the baselines hold the metrics of the default evaluation values, and a later "
                   "check without --set would fail against these; drop --set to update them, or --update to see how "
                   "the values move the metrics")


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
    from trackreplay.registry import available_trackers

    table = available_trackers(tracker_specs)
    return {e.source: (e.name, e.family) for e in table.values() if e.source in tracker_specs}


def evaluation_values(overrides: dict | None) -> dict:
    """``--set`` values of a check (name → text or number) as evaluation design values: name →
    value, parsed to the type of its default and range-checked by every stage that declares it.

    Raises
    ------
    InputError
        One line: a name that no stage declares as an evaluation design value (a tracker's is
        refused too: the baselines hold the trackers as they are), listing the known ones; or a
        value out of its range.
    """
    from trackreplay.design_values import check
    from trackreplay.replay import evaluation_catalogue
    from trackreplay.stages import stage_named
    from trackreplay.recorders.scenarios import coerce

    catalogue = evaluation_catalogue()
    known = list(dict.fromkeys(k for values in catalogue.values() for k in values))
    out = {}
    for key, value in (overrides or {}).items():
        if key not in known:
            raise InputError(f"--set {key}: check takes evaluation design values only, and {key!r} is none of them "
                             f"(known: {', '.join(known)}); a tracker's design value changes with `replay DATA --set`")
        for stage, values in catalogue.items():
            if key in values:
                out[key] = coerce(key, value, values[key])
                check(stage_named(stage), {key: out[key]})
    return out


def evaluation_note(evaluation: dict) -> str:
    """The line a check with ``--set`` evaluation values prints first: which values, for which
    stages, and that the baselines hold the defaults'."""
    from trackreplay.replay import evaluation_catalogue, format_evaluation_values

    catalogue = evaluation_catalogue()
    parts = [f"{format_evaluation_values({k: v})} ({', '.join(s for s, values in catalogue.items() if k in values)})"
             for k, v in evaluation.items()]
    return (f"note  scoring with non-default evaluation values: {'; '.join(parts)}; the baselines hold the "
            "defaults' metrics, so the metrics that depend on these may drift")


def _datasets(data_dir: Path, plugged: dict, evaluation: dict | None = None, echo=print):
    for mcap in sorted(data_dir.glob("*.mcap")):
        yield mcap.stem, lambda m=mcap: _replay_summary(m, plugged, evaluation, echo)
    for spec in sorted((data_dir / "sweeps").glob("*.toml")):
        yield f"sweep-{spec.stem}", lambda s=spec: _sweep_summary(s, plugged, evaluation)


def _replay_summary(path: Path, plugged: dict, evaluation: dict | None = None, echo=print) -> _Outcome:
    from trackreplay.contract import read_dataset
    from trackreplay.replay import replay
    from trackreplay.stages import applicable_stages

    ds = read_dataset(path)
    stages = applicable_stages(ds.channels)
    families = {s.family for s in stages}
    specs = [spec for spec, (_, family) in plugged.items() if family in families]
    # the values that every stage of the data set declares (a replay gives its overrides to each
    # stage); a value only some stages of a data set of several families declare is left out
    overrides = {k: v for k, v in (evaluation or {}).items() if all(k in s.evaluation_defaults for s in stages)}
    left_out = [k for k in (evaluation or {}) if k not in overrides and any(k in s.evaluation_defaults for s in stages)]
    if left_out:
        echo(f"note  {path.stem}: {', '.join(left_out)} left at the default (not an evaluation value of every "
             f"stage of this data set: {', '.join(s.name for s in stages)})")
    res = replay(path, dataset=ds, tracker_specs=specs, design_overrides=overrides or None)
    return _Outcome(res.summary, [(exc.path or "", str(exc)) for exc in res.failures])


def _sweep_summary(spec: Path, plugged: dict, evaluation: dict | None = None) -> _Outcome:
    from trackreplay.sweep import scenario_families, sweep_spec_report, sweep_spec_scenario

    specs = []
    if plugged:
        families = scenario_families(sweep_spec_scenario(spec))
        specs = [s for s, (_, family) in plugged.items() if family in families]
    report = sweep_spec_report(spec, tracker_specs=specs, evaluation=evaluation)
    table = report.table
    if table.height == 0:
        table = pl.DataFrame(schema={"tracker": pl.Utf8, "metric": pl.Utf8, "point": pl.Utf8, "value": pl.Float64,
                                     "se": pl.Float64})
    failures = [(where, f"{message} (point {label})")
                for label, errors in report.tracker_failures.items() for where, message in errors]
    # the standard error rides along, so that a drift says how many of them it moved
    return _Outcome(table.select(pl.col("tracker"), pl.col("metric"), pl.col("point").alias("scope"), pl.col("value"),
                                 pl.col("se")), failures)


def run_check(data_dir: str | Path, update: bool = False, echo=print, tracker_specs=(),
              evaluation: dict | None = None) -> CheckReport:
    """Check (or with ``update`` rewrite) every regression data set in ``data_dir``.

    Parameters
    ----------
    tracker_specs : sequence of str
        Plugged trackers (``FILE.py:Class`` or ``module:Class``) to run beside the built-ins on
        the data sets of their family.
    evaluation : dict, optional
        Evaluation design values (name → value, :func:`evaluation_values`) every data set and
        sweep whose stage declares the name is scored with; refused with ``update``.

    Returns
    -------
    CheckReport
        ``drifted`` lists the metrics that moved; ``errors`` one line per tracker that failed
        (its first failure, naming the tracker, run, scan and data set).
    """
    data_dir = Path(data_dir)
    evaluation = evaluation_values(evaluation)
    if evaluation and update:
        raise InputError(UPDATE_WITH_SET)
    if not data_dir.is_dir():
        raise InputError("no such data folder", data_dir)
    plugged = _plugged_families(list(tracker_specs))
    plugged_names = {name: spec for spec, (name, _) in plugged.items()}
    report = CheckReport()
    items = list(_datasets(data_dir, plugged, evaluation, echo))
    if not items:
        raise InputError("no data sets (*.mcap) or sweep specs (sweeps/*.toml) to check", data_dir)
    if evaluation:
        echo(evaluation_note(evaluation))
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
