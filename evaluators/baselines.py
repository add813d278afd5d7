"""Stored baselines and the regression check behind ``replay check``.

A baseline is a JSON file in ``data/baselines/<data set>.json`` holding the long-form metric
records ``(tracker, metric, scope, value)`` of a data set plus a tolerance per record
(``rtol``, ``atol``: the check fails when ``|new − old| > atol + rtol·|old|``). Replays are
deterministic, so the default tolerance is tight (rtol 1e-6): any change in what a tracker
computes shows up; loosen a record by hand where a metric is legitimately noisy.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import polars as pl

from pipeline import __version__
from pipeline.contract import atomic_output
from pipeline.errors import InputError

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

    def describe(self) -> str:
        if self.value is None:
            return f"{self.tracker} {self.metric} [{self.scope}]: missing (baseline {self.baseline:.6g})"
        if self.baseline is None:
            return f"{self.tracker} {self.metric} [{self.scope}]: not in baseline (value {self.value:.6g})"
        return (f"{self.tracker} {self.metric} [{self.scope}]: {self.baseline:.6g} -> {self.value:.6g} "
                f"(moved {self.value - self.baseline:+.3g}, tolerance ±{self.tolerance:.3g})")


def baseline_path(data_dir: str | Path, name: str) -> Path:
    return Path(data_dir) / "baselines" / f"{name}.json"


def write_baseline(path: str | Path, name: str, summary: pl.DataFrame, previous: dict | None = None) -> Path:
    """Write (atomically) the baseline of ``summary``; tolerances edited by hand are kept."""
    old_tol = {}
    for rec in (previous or {}).get("metrics", []):
        old_tol[tuple(rec[k] for k in KEY)] = (rec.get("rtol", DEFAULT_RTOL), rec.get("atol", DEFAULT_ATOL))
    records = []
    for row in summary.select(*KEY, "value").iter_rows(named=True):
        rtol, atol = old_tol.get(tuple(row[k] for k in KEY), (DEFAULT_RTOL, DEFAULT_ATOL))
        records.append({**{k: row[k] for k in KEY}, "value": row["value"], "rtol": rtol, "atol": atol})
    doc = {"dataset": name, "written_by": f"trackreplay {__version__}", "metrics": records}
    path = Path(path)
    with atomic_output(path, "w") as f:
        json.dump(doc, f, indent=1, sort_keys=True)
        f.write("\n")
    return path


def read_baseline(path: str | Path) -> dict:
    path = Path(path)
    try:
        doc = json.loads(path.read_text())
        doc["metrics"]
    except (OSError, json.JSONDecodeError, KeyError, TypeError) as exc:
        raise InputError(f"unreadable baseline ({type(exc).__name__})", path) from None
    return doc


def compare(summary: pl.DataFrame, baseline: dict) -> list[Drift]:
    """Every baseline record that moved beyond its tolerance or disappeared, plus new records."""
    now = {tuple(r[k] for k in KEY): r["value"] for r in summary.iter_rows(named=True)}
    drifts = []
    seen = set()
    for rec in baseline["metrics"]:
        key = tuple(rec[k] for k in KEY)
        seen.add(key)
        old = rec["value"]
        tol = rec.get("atol", DEFAULT_ATOL) + rec.get("rtol", DEFAULT_RTOL) * abs(old if old is not None else 0.0)
        new = now.get(key)
        if key not in now:
            drifts.append(Drift(*key, old, None, tol))
        elif _is_nan(old) and _is_nan(new):
            continue
        elif _is_nan(old) or _is_nan(new) or abs(new - old) > tol:
            drifts.append(Drift(*key, old, new, tol))
    for key, new in now.items():
        if key not in seen:
            drifts.append(Drift(*key, None, new, 0.0))
    return drifts


def _is_nan(v) -> bool:
    return v is None or (isinstance(v, float) and math.isnan(v))
