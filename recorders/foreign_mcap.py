"""Importer: an MCAP recorded by another tool (ROS 2, JSON or protobuf messages) → a data set.

A small TOML *mapping file* says which topic holds the measurements, where each message keeps
its time, which list field holds the items of a message (one row per item), and which field and
unit give each column of the family's canonical table
(``trackreplay.recorders.table_formats.TABLE_FORMATS``)::

    family = "…"                   # a family with a table format, e.g. the radar's (its FORMAT.family)

    [measurements]
    topic = "/radar/scan"
    time = "header.stamp"          # or "log_time", or { field = "t_ms", unit = "ms" }
    items = "returns"              # optional: one row per element of this list
    range_m = { field = "range", unit = "km" }
    bearing_rad = { field = "azimuth", unit = "deg" }
    run = "/run_id"                # optional; "/" starts at the message, not the item

A mapping of a family whose format has a ``truth_list`` (the radar's: ``truth_id`` and the four
truth columns, optionally ``run``) may add a ``[truth]`` table (the same keys): a truth list of
many targets, one truth-only row of the plots table per target, matched to the plots message of
the same time (within :data:`SAME_SCAN_S`; a time no plots message has is a scan without plots).
For a family whose format has ``empty_scan_columns`` (radar plots, peaks), a message whose item
list is empty still makes its scan (a row with the measurement empty, see
:class:`~trackreplay.recorders.foreign_decoding._Collector`).

The messages are decoded by the MCAP ecosystem's decoders chosen by the channel's encoding
(``cdr`` with a ``ros2msg`` schema: ``mcap_ros2``; ``protobuf``: ``mcap_protobuf``; ``json``: the
standard library, a whole batch of messages in one call), their fields gathered column by column
into numpy arrays, converted to SI and handed to :func:`trackreplay.recorders.tables.dataset_from_table`,
which validates them as it validates a CSV. What is checked here is only what is specific to a
foreign MCAP: the topic, the field paths, that a field holds a number, the units and the time.

The work is done in :mod:`trackreplay.recorders.foreign_mapping` (the units, field paths and the
mapping file, :func:`load_mapping`) and :mod:`trackreplay.recorders.foreign_decoding` (the
messages → tables, :func:`read_foreign_mcap`); this module turns those tables into a data set
(:func:`dataset_from_foreign`, :func:`convert_foreign_mcap`), naming the message a bad row came
from.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from trackreplay.errors import InputError
from trackreplay.recorders.foreign_decoding import ForeignTables, read_foreign_mcap
from trackreplay.recorders.foreign_mapping import (SAME_SCAN_S, TIME_COLUMN, TRUTH_TABLE, UNITS, Mapping, _formats,
                                                   load_mapping)

__all__ = ["SAME_SCAN_S", "UNITS", "ForeignTables", "Mapping", "convert_foreign_mcap", "dataset_from_foreign",
           "load_mapping", "read_foreign_mcap"]


def dataset_from_foreign(src: str | Path, mapping: Mapping):
    """The foreign file's rows as a data set (:class:`trackreplay.recorders.simulated.SimulatedData`).

    Returns
    -------
    (SimulatedData, ForeignTables)
    """
    from trackreplay.recorders.tables import dataset_from_table

    got = read_foreign_mcap(src, mapping)
    rows, origin = _measurement_rows(got, mapping, Path(src))
    try:
        data = dataset_from_table(mapping.family, rows, Path(src),
                                  sensors=got.tables.get("sensors"),
                                  sensors_path=Path(src) if "sensors" in got.tables else None)
    except InputError as exc:
        raise InputError(_with_message(exc.problem, got, mapping, origin), exc.path) from None
    return data, got


def _measurement_rows(got: ForeignTables, mapping: Mapping, src: Path):
    """The measurements table the family's validation reads, and where each of its rows came
    from (``None``: the measurements table itself, row for row).

    Beside the rows of the items it holds a row with the measurement empty for every message
    whose item list is empty (a scan without plots or peaks), and with [truth] one truth-only
    row per target (range and bearing empty, ``truth_id`` and the state), its time matched to
    the plots message of the same time (within :data:`SAME_SCAN_S`; a time no plots message
    has is a scan without plots). Rows are in time order, plots before truth at one time.
    """
    import polars as pl

    meas = got.tables["measurements"]
    empty = got.empty_rows.get("measurements")
    truth = got.tables.get(TRUTH_TABLE)
    has_empty = empty is not None and empty[0].size > 0
    if not has_empty and truth is None:
        return meas, None
    meas_spec = mapping.tables["measurements"]
    parts, tables, messages = [meas], [np.zeros(meas.height, np.int8)], [got.row_message["measurements"]]
    items = [_item_of(got.row_message["measurements"])]
    if has_empty:
        idx, cols = empty
        run = {"run": cols["run"]} if "run" in cols else {}
        parts.append(pl.DataFrame({**run, TIME_COLUMN: got.message_times["measurements"][idx],
                                   **{k: v for k, v in cols.items() if k != "run"}}))
        tables.append(np.zeros(idx.size, np.int8))
        messages.append(idx)
        items.append(np.full(idx.size, -1, np.int64))
        what = _formats()[mapping.family].item_word
        got.notes.append(f"{idx.size} message(s) on {meas_spec.topic} with an empty {meas_spec.items.text} list: "
                         f"scans without {what}")
    if truth is not None:
        truth = _matched_truth(got, mapping, pl.concat(parts, how="diagonal_relaxed"), src)
        parts.append(truth)
        tables.append(np.ones(truth.height, np.int8))
        messages.append(got.row_message[TRUTH_TABLE])
        items.append(_item_of(got.row_message[TRUTH_TABLE]))
    rows = pl.concat(parts, how="diagonal_relaxed")
    table, message, item = np.concatenate(tables), np.concatenate(messages), np.concatenate(items)
    order = np.lexsort((np.arange(rows.height), table, rows[TIME_COLUMN].to_numpy()))
    return rows[order], (table[order], message[order], item[order])


def _item_of(row_message: np.ndarray) -> np.ndarray:
    """Each row's place in its message's item list (rows of one message are consecutive)."""
    return np.arange(row_message.size) - np.searchsorted(row_message, row_message, side="left")


def _matched_truth(got: ForeignTables, mapping: Mapping, plots, src: Path):
    """The truth rows with each time set to the plots message's time it matches; refuses a
    target named twice in one scan; notes the truth times no plots message has."""
    import polars as pl

    spec, meas_spec = mapping.tables[TRUTH_TABLE], mapping.tables["measurements"]
    truth = got.tables[TRUTH_TABLE]
    msg = got.row_message[TRUTH_TABLE]
    t = truth[TIME_COLUMN].to_numpy().copy()
    scan_times = np.unique(got.message_times["measurements"])
    if t.size and scan_times.size:
        i = np.searchsorted(scan_times, t)
        below, above = scan_times[np.maximum(i - 1, 0)], scan_times[np.minimum(i, scan_times.size - 1)]
        near = np.where(t - below <= above - t, below, above)
        t = np.where(np.abs(near - t) <= SAME_SCAN_S, near, t)
    truth = truth.with_columns(pl.Series(TIME_COLUMN, t))
    run = truth["run"].to_numpy() if "run" in truth.columns else np.zeros(truth.height, np.int64)
    fmt = _formats()[mapping.family]
    ident = truth[fmt.truth_list[0]].to_numpy()  # the list's first column is the target's identity
    # a target once a scan: the first repeat (in row order) is named with its message
    keys = pl.DataFrame({"run": run, "t": t, "id": ident, "row": np.arange(truth.height)})
    first = keys.group_by(["run", "t", "id"], maintain_order=True).agg(pl.col("row").first().alias("first"))
    again = (keys.join(first, on=["run", "t", "id"], how="left").filter(pl.col("row") != pl.col("first"))
             .sort("row"))
    if again.height:
        b, a = int(again["row"][0]), int(again["first"][0])
        item = _item_of(msg)
        where = f"topic {spec.topic}, message {msg[b]}"
        twice = (f"item {item[b]} of {spec.items.text} names target {_n_id(ident[b])} again (item {item[a]})"
                 if msg[a] == msg[b] and spec.items is not None else
                 f"target {_n_id(ident[b])} is also given by message {msg[a]} at the same scan time")
        run_txt = f" of run {_n_id(run[b])}" if "run" in truth.columns else ""
        raise InputError(f"{where}: {twice}, time {float(t[b])!r} s{run_txt}; a truth list names each target once a "
                         "scan", src)
    # the truth times that are no plots message's: scans without plots
    plot_keys = pl.DataFrame({"run": plots["run"].to_numpy() if "run" in plots.columns else
                              np.zeros(plots.height, np.int64), "t": plots[TIME_COLUMN].to_numpy()}).unique()
    alone = (keys.select("run", "t", "row").with_columns(pl.col("run").cast(plot_keys["run"].dtype, strict=False))
             .join(plot_keys, on=["run", "t"], how="anti").sort("row"))
    if alone.height:
        scans = alone.unique(["run", "t"]).height
        i = int(alone["row"][0])
        run_txt = f" of run {_n_id(run[i])}" if "run" in truth.columns else ""
        got.notes.append(f"{scans} truth time(s) on {spec.topic} match no message on {meas_spec.topic} (within "
                         f"{SAME_SCAN_S:g} s): each is a scan without {fmt.item_word} (the first: message {msg[i]}, "
                         f"time {float(t[i])!r} s{run_txt})")
    return truth


def _n_id(v) -> str:
    """An identity or run as written: 3, not 3.0."""
    f = float(v)
    return str(int(f)) if f.is_integer() else repr(f)


def _with_message(problem: str, got: ForeignTables, mapping: Mapping, origin=None) -> str:
    """The table validator counts rows; say which message a row came from."""
    m = re.search(r"data row (\d+)", problem)
    if origin is not None:
        table, message, item = origin
        if m is None or not 1 <= int(m.group(1)) <= message.size:
            return problem
        i = int(m.group(1)) - 1
        spec = mapping.tables[TRUTH_TABLE if table[i] else "measurements"]
        what = (f", [{spec.table}] item {item[i]} of {spec.items.text}" if spec.items is not None and item[i] >= 0 else
                f", [{spec.table}]" if table[i] else ", its empty list" if item[i] < 0 else "")
        return f"{problem} (row {m.group(1)}: topic {spec.topic}, message {message[i]}{what})"
    table = "sensors" if "sensors" in problem and "sensors" in got.tables else "measurements"
    rows = got.row_message[table]
    if m is None or not 1 <= int(m.group(1)) <= rows.size:
        return problem
    return f"{problem} (row {m.group(1)}: topic {mapping.tables[table].topic}, message {rows[int(m.group(1)) - 1]})"


def convert_foreign_mcap(src, mapping_path, dst, overrides: dict | None = None) -> dict:
    """Convert a foreign MCAP through a mapping file into a data set at ``dst`` (atomically).

    Parameters
    ----------
    src : str or Path
        The foreign MCAP (never written).
    mapping_path : str or Path
        The TOML mapping file.
    dst : str or Path
        The data set to write.
    overrides : dict, optional
        ``--set`` values of the sensor and the trackers' design (they win over the mapping
        file's ``[sensor]`` table); nothing is taken from a bundled scenario.

    Returns
    -------
    dict
        ``family``, ``messages_in`` (per table), ``rows`` (per table), ``messages_out``.
    """
    from trackreplay.recorders import tables

    mapping = load_mapping(mapping_path)
    data, got = dataset_from_foreign(src, mapping)
    n, _, notes, _ = tables.write_imported(mapping.family, data, dst, overrides, f"{mapping.family} mcap",
                                           {"source_mcap": Path(src).name, "mapping": Path(mapping_path).name}, src,
                                           mapped=mapping.sensor)
    return {"family": mapping.family, "messages_in": got.messages,
            "rows": {t: df.height for t, df in got.tables.items()}, "messages_out": n,
            "topics": {t: s.topic for t, s in mapping.tables.items()}, "notes": [*got.notes, *notes]}
