"""What every family's exporter shares (``docs/importers.md``, "The way back: replay export
--table"): a data set's channels → tables in exactly the import format, so that importing them
gives the same arrays bit for bit.

Each family's exporter is in its module (the ``export`` of its
:class:`~trackreplay.recorders.table_formats.TableFormat`), called by
:func:`trackreplay.recorders.tables.tables_from_dataset`; :func:`write_table` writes a table
atomically. A ragged channel (plots, peaks) becomes one row per item and one row with the
measurement empty per scan without items (:func:`_frames_to_rows`); times get the data set's
``first_time_s`` back (:func:`_times`).
"""

from __future__ import annotations

import numpy as np
import polars as pl

from trackreplay.errors import InputError


def _first_time(dataset) -> float:
    raw = dataset.scenario.get("params", {}).get("first_time_s", 0.0)
    try:
        value = float(raw)
    except (TypeError, ValueError):
        raise InputError(f"scenario record: first_time_s {raw!r} is not a number", dataset.path) from None
    if not np.isfinite(value):
        raise InputError("scenario record: first_time_s must be finite", dataset.path)
    return value


def _times(dataset, ch) -> np.ndarray:
    t = ch.times()
    t0 = _first_time(dataset)
    return t + t0 if t0 != 0 else t


def _fixed_grid(dataset, topic: str, name: str, shape: tuple, inner: tuple | None = None) -> np.ndarray:
    """``name`` of ``topic`` as (runs, scans, ...), complete and finite, covering ``shape``."""
    ch = dataset.channel(topic)
    ch.require_every_frame(*shape)
    a = ch.grid(name)
    if a.shape[:2] != shape:
        raise InputError(f"{topic} covers {a.shape[:2]} run×scan, the measurements {shape}", dataset.path)
    if inner is not None and a.shape[2:] != inner:
        raise InputError(f"{topic} {name} has frames of shape {a.shape[2:]}, expected {inner}", dataset.path)
    if not np.all(np.isfinite(a)):
        raise InputError(f"{topic} {name} holds NaN/Inf: no table value for it", dataset.path)
    return a


def _frames_to_rows(counts: np.ndarray):
    """Row layout of ragged frames: every item a row, an empty frame one marker row.

    Returns (run, scan, slot, is_item) per row, run-major, then scan, then slot.
    """
    n = np.maximum(counts, 1).ravel()
    frame = np.repeat(np.arange(counts.size), n)
    slot = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
    run, scan = np.divmod(frame, counts.shape[1])
    return run, scan, slot, slot < counts.ravel()[frame]


def _ragged_column(a: np.ndarray, run, scan, slot, item) -> np.ndarray:
    out = np.full(run.size, np.nan)
    if a.shape[2]:
        out[item] = a[run[item], scan[item], slot[item]]
    return out


def _series(name: str, values: np.ndarray, item: np.ndarray | None = None, dtype=pl.Float64) -> pl.Series:
    s = pl.Series(name, values, dtype=dtype)
    if item is not None and not item.all():
        s = s.scatter(np.flatnonzero(~item), None)
    return s


def write_table(df: pl.DataFrame, path, fmt: str) -> None:
    """Write a table atomically as ``csv`` or ``parquet`` (floats written so they read back
    exactly)."""
    from trackreplay.contract import atomic_output

    if fmt not in ("csv", "parquet"):
        raise InputError(f"unknown table format {fmt!r} (csv or parquet)")
    with atomic_output(path) as f:
        if fmt == "csv":
            df.write_csv(f)
        else:
            df.write_parquet(f)
