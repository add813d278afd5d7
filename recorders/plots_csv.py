"""Converter: a CSV of recorded radar plots → the same MCAP channels the simulator writes.

Columns: ``time, range_m, bearing_deg[, run]`` (bearing counter-clockwise from +x, degrees at
this boundary only). Rows with the same run and time form one scan; scans are numbered by time
within each run and must share their times across runs. There is no truth in a recording, so
the evaluator reports what needs no truth (and says what it skipped).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import polars as pl

from pipeline.contract import scenario_metadata
from pipeline.errors import InputError
from recorders.radar_tws import PLOTS_TOPIC
from recorders.simulated import SimulatedData, write_simulated

REQUIRED = ("time", "range_m", "bearing_deg")


def read_plots_csv(path: str | Path) -> tuple[SimulatedData, float]:
    """Parse and validate the CSV; every problem is an :class:`InputError` naming the file."""
    path = Path(path)
    if not path.exists():
        raise InputError("no such file", path)
    try:
        df = pl.read_csv(path, infer_schema_length=10000)
    except (pl.exceptions.PolarsError, OSError, UnicodeDecodeError) as exc:
        raise InputError(f"unreadable CSV ({str(exc).splitlines()[0]})", path) from None
    missing = [c for c in REQUIRED if c not in df.columns]
    if missing:
        raise InputError(f"missing column(s) {', '.join(missing)} (need {', '.join(REQUIRED)}[, run])", path)
    if df.height == 0:
        raise InputError("no rows", path)
    if "run" not in df.columns:
        df = df.with_columns(pl.lit(0).alias("run"))
    try:
        run_values = df["run"].cast(pl.Float64)
    except pl.exceptions.PolarsError:
        raise InputError("non-numeric values in time/range_m/bearing_deg/run", path) from None
    fractional = run_values.is_not_null() & (run_values.round(0) != run_values)
    if fractional.any():
        raise InputError(f"column 'run' holds {int(fractional.sum())} non-integer value(s) (run indices count runs)", path)
    try:
        df = df.select(pl.col("run").cast(pl.Float64).cast(pl.Int64), pl.col("time").cast(pl.Float64),
                       pl.col("range_m").cast(pl.Float64), pl.col("bearing_deg").cast(pl.Float64))
    except pl.exceptions.PolarsError:
        raise InputError("non-numeric values in time/range_m/bearing_deg/run", path) from None
    for col in ("time", "range_m", "bearing_deg"):
        bad = df.filter(pl.col(col).is_null() | ~pl.col(col).is_finite())
        if bad.height:
            raise InputError(f"column {col!r} has {bad.height} empty/NaN/Inf value(s) (first at data row {_first_row(df, col)})", path)
    if (df["range_m"] < 0).any():
        raise InputError("negative range_m", path)
    if (df["run"] < 0).any():
        raise InputError("negative run index", path)
    times = np.unique(df["time"].to_numpy())
    runs = int(df["run"].max()) + 1
    scan = np.searchsorted(times, df["time"].to_numpy())
    run = df["run"].to_numpy()
    counts = np.zeros((runs, times.size), np.int64)
    np.add.at(counts, (run, scan), 1)
    width = int(counts.max())
    rng = np.full((runs, times.size, width), np.nan)
    brg = np.full_like(rng, np.nan)
    # Each row's slot is its rank among the rows of its (run, scan) in file order: a stable sort
    # by (run, scan) keeps file order within a group, and the rank is the distance to the group's start.
    key = run * times.size + scan
    order = np.argsort(key, kind="stable")
    sorted_key = key[order]
    slot = np.empty_like(order)
    slot[order] = np.arange(order.size) - np.searchsorted(sorted_key, sorted_key, side="left")
    rng[run, scan, slot] = df["range_m"].to_numpy()
    brg[run, scan, slot] = np.deg2rad(df["bearing_deg"].to_numpy())
    # MCAP log times are unsigned: scan times start at 0 and the first CSV time goes to metadata.
    data = SimulatedData(times=times - times[0], ragged={PLOTS_TOPIC: ({"range_m": rng, "bearing_rad": brg}, counts)})
    return data, float(times[0])


def _first_row(df: pl.DataFrame, col: str) -> int:
    mask = (df[col].is_null() | ~df[col].is_finite()).to_numpy()
    return int(np.argmax(mask)) + 1


def convert_plots_csv(src, dst, params: dict) -> int:
    """Write the CSV's plots to ``dst`` with ``params`` (sensor and design values) as metadata."""
    data, t0 = read_plots_csv(src)
    params = dict(params, source_csv=Path(src).name, first_time_s=t0)
    return write_simulated(dst, data, scenario_metadata("radar-csv", params, seed=-1))
