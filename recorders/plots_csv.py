"""The earlier radar plots CSV converter, kept for code that imports it.

Every table format, radar plots included, is read by :mod:`recorders.tables`; ``replay convert
plots-csv`` is an alias of ``replay convert plots``. The columns are those of
``TABLE_FORMATS["radar-plots"]`` (``time, range_m, bearing_deg[, run]`` as before, or
``time_s``, ``bearing_rad`` and truth columns).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from pipeline.contract import scenario_metadata
from recorders.simulated import SimulatedData, write_simulated
from recorders.tables import dataset_from_table, read_table


def read_plots_csv(path: str | Path) -> tuple[SimulatedData, float]:
    """Read a radar plots table as the earlier converter did: rows in any order, grouped into
    scans by run and time (file order kept within a scan).

    Unlike ``replay convert plots``, rows whose times go back within a run are accepted here:
    they are sorted (stably) by run and time first, so a row number in a message counts the
    sorted rows.

    Returns
    -------
    data : SimulatedData
        ``/radar/plots`` (and ``/radar/truth`` with truth columns), scan times from 0.
    first_time_s : float
        The table's first time.
    """
    rows = read_table(path)
    keys = [c for c in ("run", "time_s", "time") if c in rows.columns and rows[c].dtype.is_numeric()]
    if keys:
        rows = rows.sort(keys, maintain_order=True, nulls_last=True)
    data = dataset_from_table("radar-plots", rows, path)
    t0 = float(data.times[0])
    return replace(data, times=data.times - t0), t0


def convert_plots_csv(src, dst, params: dict) -> int:
    """Write the table's plots to ``dst`` with ``params`` (sensor and design values) as metadata;
    returns the number of MCAP messages."""
    data, t0 = read_plots_csv(src)
    params = dict(params, source_table=Path(src).name, first_time_s=t0)
    return write_simulated(dst, data, scenario_metadata("radar-plots table", params, seed=-1))
