"""Stored baselines and the regression check behind ``replay check``.

A baseline is a JSON file in ``data/baselines/<data set>.json`` holding the long-form metric
records ``(tracker, metric, scope, value)`` of a data set plus a tolerance per record
(``rtol``, ``atol``: the check fails when ``|new − old| > atol + rtol·|old|``). Replays are
deterministic, so the default tolerance is tight (rtol 1e-6): any change in what a tracker
computes shows up; loosen a record by hand where a metric is legitimately noisy.

Records of plugged trackers (``replay check --tracker SPEC --update``) sit beside the built-ins'
and the baseline's ``plugged`` table maps each such tracker to its spec: a check that does not
run it skips its records, and an update that does not run it keeps them.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import polars as pl

from trackreplay import __version__
from trackreplay.contract import atomic_output
from trackreplay.errors import InputError

DEFAULT_RTOL = 1e-6
DEFAULT_ATOL = 1e-9
KEY = ("tracker", "metric", "scope")


@dataclass
class Drift:
    """One metric that moved beyond its tolerance (or vanished)."""

    tracker: str
    metric: str
    scope: str
    baseline: float | None
    value: float | None
    tolerance: float
    se: float | None = None  # the metric's Monte Carlo standard error recorded with the baseline

    def describe(self) -> str:
        if self.value is None:
            return f"{self.tracker} {self.metric} [{self.scope}]: missing (baseline {_number(self.baseline)})"
        if self.baseline is None:
            return f"{self.tracker} {self.metric} [{self.scope}]: not in baseline (value {_number(self.value)})"
        moved = self.value - self.baseline
        text = (f"{self.tracker} {self.metric} [{self.scope}]: {self.baseline:.6g} -> {self.value:.6g} "
                f"(moved {moved:+.3g}, tolerance ±{self.tolerance:.3g}")
        if self.se is not None and self.se > 0:
            # what Monte Carlo chance alone moves a metric by is a few of these
            text += f"; {moved / self.se:+.2f} standard errors"
        return text + ")"


def _number(value) -> str:
    """A value as a drift line prints it; a metric without one (NaN, null) says so."""
    return "none" if value is None else f"{value:.6g}"


def baseline_path(data_dir: str | Path, name: str) -> Path:
    return Path(data_dir) / "baselines" / f"{name}.json"


def write_baseline(path: str | Path, name: str, summary: pl.DataFrame, previous: dict | None = None,
                   plugged: dict | None = None) -> Path:
    """Write (atomically) the baseline of ``summary``; tolerances edited by hand are kept.

    Parameters
    ----------
    plugged : dict, optional
        Plugged trackers in ``summary`` → their spec. The records of plugged trackers of
        ``previous`` that ``summary`` does not hold are kept, with their spec.
    """
    old_tol = {}
    for rec in (previous or {}).get("metrics", []):
        old_tol[tuple(rec[k] for k in KEY)] = (rec.get("rtol", DEFAULT_RTOL), rec.get("atol", DEFAULT_ATOL))
    records = []
    with_se = summary if "se" in summary.columns else summary.with_columns(pl.lit(None, pl.Float64).alias("se"))
    for row in with_se.select(*KEY, "value", "se").iter_rows(named=True):
        rtol, atol = old_tol.get(tuple(row[k] for k in KEY), (DEFAULT_RTOL, DEFAULT_ATOL))
        record = {**{k: row[k] for k in KEY}, "value": row["value"], "rtol": rtol, "atol": atol}
        if row["se"] is not None and row["se"] == row["se"]:
            record["se"] = row["se"]
        records.append(record)
    present = set(summary["tracker"].unique()) if summary.height else set()
    kept = {n: spec for n, spec in plugged_trackers(previous or {}).items() if n not in present}
    records += [rec for rec in (previous or {}).get("metrics", []) if rec["tracker"] in kept]
    doc = {"dataset": name, "written_by": f"trackreplay {__version__}", "metrics": records}
    table = {**kept, **(plugged or {})}
    if table:
        doc["plugged"] = dict(sorted(table.items()))
    path = Path(path)
    with atomic_output(path, "w") as f:
        json.dump(doc, f, indent=1, sort_keys=True)
        f.write("\n")
    return path


def plugged_trackers(baseline: dict) -> dict:
    """Plugged trackers with records in ``baseline`` → the spec they were loaded from."""
    table = baseline.get("plugged") or {}
    return dict(table) if isinstance(table, dict) else {}


def read_baseline(path: str | Path) -> dict:
    path = Path(path)
    try:
        doc = json.loads(path.read_text())
        doc["metrics"]
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, KeyError, TypeError) as exc:  # not text: named too
        raise InputError(f"unreadable baseline ({type(exc).__name__})", path) from None
    return doc


def compare(summary: pl.DataFrame, baseline: dict, unbaselined=()) -> list[Drift]:
    """Every baseline record that moved beyond its tolerance or disappeared, plus new records.

    Records of the baseline's plugged trackers that ``summary`` does not hold at all (the
    tracker was not given) are skipped, and so are the new records of the trackers in
    ``unbaselined`` (plugged trackers that have no baseline records yet).
    """
    now = {tuple(r[k] for k in KEY): r["value"] for r in summary.iter_rows(named=True)}
    present = {key[0] for key in now}
    absent_plugged = {n for n in plugged_trackers(baseline) if n not in present}
    unbaselined = set(unbaselined)
    drifts = []
    seen = set()
    for rec in baseline["metrics"]:
        key = tuple(rec[k] for k in KEY)
        seen.add(key)
        if key[0] in absent_plugged:
            continue
        old = rec["value"]
        tol = rec.get("atol", DEFAULT_ATOL) + rec.get("rtol", DEFAULT_RTOL) * abs(old if old is not None else 0.0)
        new = now.get(key)
        if key not in now:
            drifts.append(Drift(*key, old, None, tol))
        elif _is_nan(old) and _is_nan(new):
            continue
        elif _is_nan(old) or _is_nan(new) or abs(new - old) > tol:
            drifts.append(Drift(*key, old, new, tol, rec.get("se")))
    for key, new in now.items():
        if key not in seen and key[0] not in unbaselined:
            drifts.append(Drift(*key, None, new, 0.0))
    return drifts


def _is_nan(v) -> bool:
    return v is None or (isinstance(v, float) and math.isnan(v))
