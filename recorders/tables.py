"""Tables of measurements (CSV or Parquet) ↔ data sets, for every measurement family with a
tabular form (:data:`TABLE_FORMATS`, one module per family: radar plots, cross-correlation peaks,
TDOA/FDOA measurements with a table of sensors, positions in coloured noise). A family without one
(the array's snapshots) has a converter of its own.

A table is *long*: one row per measurement item (a plot, a peak, a sensor pair, a position),
with the Monte Carlo run (or recording index) and the scan time on every row. The rows of one
run and time form one scan. :data:`TABLE_FORMATS` describes the columns of every family; the
command-line help is written from it (and ``docs/importers.md`` is tested to list every column).

* :func:`read_table` reads a ``.csv`` or ``.parquet`` file into a polars DataFrame;
* :func:`dataset_from_table` validates a table and builds exactly the arrays the family's
  simulator builds (:class:`trackreplay.recorders.simulated.SimulatedData`);
* :func:`tables_from_dataset` is the way back: a data set's input channels (and the truth the
  tables carry) as tables in the import format, so that simulate → export → import gives the
  same arrays bit for bit;
* :func:`convert_table` is what ``replay convert <command>`` of a table format runs: read,
  validate, record the sensor and design values the user gave with ``--set`` (nothing from a
  bundled scenario: :mod:`trackreplay.sensor_values`) and what the data hold, and write the data
  set.

This module is the public face of the table importers and exporters; the work is done in

* :mod:`trackreplay.recorders.table_formats`: :class:`TableFormat` and :data:`TABLE_FORMATS`, the
  formats the families declare in their own modules (``TABLE_MODULES``: each family's columns,
  notes, fewest scans, reader, exporter, command and the hooks where it differs);
* :mod:`trackreplay.recorders.table_rows`: :func:`read_table` and the validation every table
  shares (the rules below);
* :mod:`trackreplay.recorders.table_exporters`: what the exporters share, and :func:`write_table`.

Rules every importer applies (a broken rule is one :class:`~trackreplay.errors.InputError` naming
the file and the first row at fault; rows are counted from 1 after the header):

* ``run`` is optional (default 0); runs are numbered 0, 1, … without gaps. ``time_s`` is
  required (``time`` is accepted for it). Angles are ``*_rad`` or ``*_deg`` (converted on
  input); SI units everywhere else.
* Within a run the rows are in time order (equal times are one scan). Every run has the same
  scan times, except that a run of the ragged families (plots, peaks) may skip a scan when the
  table carries no truth (the scan then has no plots).
* Numbers are numbers: text, NaN and ±Inf are refused, and so are empty cells, except that a
  row of the ragged families whose measurement columns are all empty marks a scan without
  plots (or peaks).
* A value a whole scan shares (truth, the prior fix, the carrier) is repeated on every row of
  the scan and must agree.
* Values lie within the contract's declared bounds (``trackreplay.vocabulary.VALUES``): no
  negative range, amplitude or σ.

The MCAP log times are unsigned, so the data set's scan times start at 0: the first time of
the table is recorded as the parameter ``first_time_s`` and the exporter adds it back.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import polars as pl

from trackreplay import vocabulary as vocab
from trackreplay.errors import InputError
from trackreplay.recorders.simulated import SimulatedData, write_simulated
from trackreplay.recorders.table_exporters import write_table
from trackreplay.recorders.table_formats import (TABLE_FORMATS, TableColumn, TableFormat, _check_family, scenario_of,
                                                 table_formats)
from trackreplay.recorders.table_rows import _Rows, read_table

__all__ = ["TABLE_FORMATS", "ConvertReport", "TableColumn", "TableFormat", "convert_table", "dataset_from_table",
           "exportable_families", "read_table", "scenario_of", "sensor_summary", "table_file_names",
           "table_parameters", "tables_from_dataset", "write_imported", "write_table"]


# --------------------------------------------------------------------------- importing and exporting


def dataset_from_table(family: str, rows: pl.DataFrame, path, sensors: pl.DataFrame | None = None,
                       sensors_path=None) -> SimulatedData:
    """Validate a table of ``family`` and build the family's channels.

    Parameters
    ----------
    family : str
        A family with a table format (a key of :data:`TABLE_FORMATS`).
    rows : polars.DataFrame
        The measurements table (:data:`TABLE_FORMATS`); columns may be numbers or text to parse.
    path : str or Path
        The file the rows came from (named in every message).
    sensors : polars.DataFrame, optional
        The sensors table (of a family whose format has one; required there).
    sensors_path : str or Path, optional
        Its file.

    Returns
    -------
    SimulatedData
        The arrays the family's simulator builds, with the truth (and prior) the table carries;
        ``times`` are the table's scan times as they are (see :func:`convert_table` for the shift
        to 0 a data set needs).

    Raises
    ------
    InputError
        Naming ``path`` (or ``sensors_path``) and the first bad row.
    """
    fmt = _check_family(family)
    t = _Rows(rows, path, fmt)
    if "sensors" not in fmt.tables:
        if sensors is not None:
            raise InputError(f"a {family} table has no sensors table", sensors_path or path)
        return fmt.read(t)
    s = None if sensors is None else _Rows(sensors, sensors_path if sensors_path is not None else path, fmt,
                                          what="sensors table")
    return fmt.read(t, s)


def tables_from_dataset(dataset, family: str) -> dict[str, pl.DataFrame]:
    """A data set's input channels of ``family`` (and the truth, prior, the tables carry) as
    tables in exactly the import format: importing them gives the same arrays bit for bit.

    Parameters
    ----------
    dataset : trackreplay.contract.Dataset, str or Path
        A data set read with :func:`trackreplay.contract.read_dataset`, or its file.
    family : str

    Returns
    -------
    dict
        ``{"measurements": DataFrame}``, plus ``"sensors"`` for a format with a sensors table.
        Angles are in radians; times are the data set's scan times plus its recorded
        ``first_time_s``.

    Raises
    ------
    InputError
        The data set lacks the family's channels, or holds what a table cannot (truth with
        gaps, pairs that change between epochs, more than three position axes).
    """
    from trackreplay.contract import read_dataset

    fmt = _check_family(family)
    if isinstance(dataset, (str, Path)):
        dataset = read_dataset(dataset)
    missing = [c for c in vocab.FAMILIES[family].inputs if c not in dataset.channels]
    if missing:
        raise InputError(f"no {family} channels ({', '.join(missing)} missing)", dataset.path)
    return fmt.export(dataset)


def exportable_families(dataset) -> tuple[list[str], list[str]]:
    """Families of a data set with a table format, and those present without one."""
    have = [f for f, fam in vocab.FAMILIES.items() if all(c in dataset.channels for c in fam.inputs)]
    formats = table_formats()
    return [f for f in have if f in formats], [f for f in have if f not in formats]


def table_file_names(family: str, suffix: str) -> dict[str, str]:
    """File names ``replay export --table`` gives a family's tables (keys as in
    :func:`tables_from_dataset`)."""
    fmt = _check_family(family)
    stem = fmt.stem
    names = {"measurements": f"{stem}.{suffix}"}
    if "sensors" in fmt.tables:
        names["sensors"] = f"{stem}_sensors.{suffix}"
    return names


# --------------------------------------------------------------------------- converting


@dataclass
class ConvertReport:
    """What :func:`convert_table` wrote."""

    path: Path
    messages: int
    runs: int
    scans: int
    items: int
    truth: bool
    params: dict
    notes: list = field(default_factory=list)
    sources: dict = field(default_factory=dict)


def _given_values(family: str, given: dict, what: str) -> dict:
    """``given`` (``--set`` or a mapping file's ``[sensor]`` table) parsed to each value's type:
    a parameter of the family's bundled scenario takes its default's type, another sensor value
    of the family (its ``sensor_keys`` in :data:`trackreplay.vocabulary.FAMILIES`, e.g. a multi-target radar's
    clutter) a number. Anything else is refused, naming the known values."""
    from trackreplay.recorders.scenarios import coerce, load_scenario
    from trackreplay.vocabulary import FAMILIES

    defaults = load_scenario(scenario_of(family)).params
    out = {}
    for key, raw in given.items():
        if key in defaults:
            out[key] = coerce(key, raw, defaults[key])
        elif key in FAMILIES[family].sensor_keys:
            out[key] = coerce(key, raw, 0.0)
        else:
            known = ", ".join(sorted(set(defaults) | set(FAMILIES[family].sensor_keys)))
            raise InputError(f"{what}: unknown parameter {key!r} for {family} (known: {known})")
        if out[key] is None:
            raise InputError(f"{what}: parameter {key!r}: cannot read {raw!r}")
    return out


def table_parameters(family: str, overrides: dict | None = None,
                     data: SimulatedData | None = None, mapped: dict | None = None) -> tuple[dict, list, dict]:
    """Values recorded with an imported table: what the user said about the sensor and the
    trackers (``overrides``, from ``--set``; ``mapped``, from a mapping file's ``[sensor]``
    table; the flag wins) and what the data themselves hold (runs, scans, time span), with
    notes on choices made for the user.

    Nothing is taken from a bundled scenario: a sensor value the user did not give is unknown
    (``docs/importers.md``, "Sensor values"). A family's format may add values the data imply
    that the user did not give (its ``data_values``, recorded with the source "data": a table of
    TDOA/FDOA measurements without a prior fix records ``initial_guess = "grid"``).

    Returns
    -------
    params : dict
    notes : list of str
    sources : dict
        ``{parameter: source}`` (:data:`trackreplay.sensor_values.SOURCES`) of every value of ``params``.
    """
    from trackreplay import sensor_values as sv

    mapped = _given_values(family, dict(mapped or {}), "mapping file [sensor]")
    flagged = _given_values(family, dict(overrides or {}), "--set")
    params, sources, notes = {}, {}, []
    for values, source in ((mapped, sv.MAPPING_FILE), (flagged, sv.CONVERTER_FLAG)):
        params.update(values)
        sources.update(dict.fromkeys(values, source))
    implied = _check_family(family).data_values
    if implied is not None and data is not None:
        values, told = implied(data, params)
        params.update(values)
        sources.update(dict.fromkeys(values, sv.DATA))
        notes += told
    if data is not None:
        times = np.asarray(data.times, dtype=float)
        facts = {"n_runs": int(data.n_runs), "n_scans": int(times.size),
                 "time_span_s": float(times[-1] - times[0]) if times.size else 0.0}
        params.update(facts)
        sources.update(dict.fromkeys(facts, sv.DATA))
    return params, notes, sources


def sensor_summary(family: str, params: dict, sources: dict) -> str:
    """One line saying which sensor values a converted data set records and which it leaves
    unknown (the family's ``sensor_keys``), for the converters to print."""
    from trackreplay.vocabulary import FAMILIES

    keys = FAMILIES[family].sensor_keys
    if not keys:
        return f"sensor values: in the measurements ({family} carries its noise and geometry per item)"
    given = [(f"{k}={params[k]:g}" if isinstance(params[k], float) else f"{k}={params[k]}") + f" ({sources.get(k, '?')})"
             for k in keys if k in params]
    estimated = [k for k in keys if k not in params and k in FAMILIES[family].estimable_keys]
    unknown = [k for k in keys if k not in params and k not in estimated]
    parts = [f"given {', '.join(given)}"] if given else []
    if estimated:
        parts.append(f"estimated at replay from the data: {', '.join(estimated)}")
    if unknown:
        parts.append(f"unknown: {', '.join(unknown)} (a tracker that needs one asks for --set NAME=VALUE)")
    return "sensor values: " + "; ".join(parts)


def write_imported(family: str, data: SimulatedData, dst, overrides, scenario: str, source: dict, path,
                   mapped: dict | None = None):
    """Write an imported data set: the one way a table or a foreign recording becomes one.

    It records what the user gave (``overrides`` from ``--set``, ``mapped`` from a mapping
    file) and what the data hold (:func:`table_parameters`), ``source`` (the input files'
    names) and the first time ``first_time_s`` (scan times start at 0: MCAP log times are
    unsigned), marks the record a recording with the source of every value
    (:mod:`trackreplay.sensor_values`), and refuses what the replay would refuse given the
    recorded values (the format's ``check_values``, e.g. peaks outside the sensor's field, naming
    ``path``). Written atomically.

    Returns
    -------
    messages : int
    params : dict
        What was recorded.
    notes : list of str
        What the user should know (e.g. values taken from the data).
    sources : dict
        The source of every recorded value.
    """
    import json

    from trackreplay import sensor_values as sv
    from trackreplay.contract import METADATA_SCENARIO, scenario_metadata

    params, notes, sources = table_parameters(family, overrides, data, mapped)
    t0 = float(data.times[0])
    check = _check_family(family).check_values
    if check is not None:
        check(data, params, path)
    params.update(source, first_time_s=t0)
    sources.update(dict.fromkeys([*source, "first_time_s"], sv.DATA))
    metadata = scenario_metadata(scenario, params, seed=-1)
    metadata[METADATA_SCENARIO].update(origin=sv.ORIGIN_RECORDING, sources=json.dumps(sources, sort_keys=True))
    messages = write_simulated(dst, replace(data, times=data.times - t0), metadata)
    return messages, params, notes, sources


def convert_table(family: str, src, dst, overrides: dict | None = None, sensors_src=None) -> ConvertReport:
    """Read a table file (and its sensors table), validate it and write a data set.

    The data set records the values ``overrides`` gives (``--set``; see
    :func:`table_parameters`; nothing from a bundled scenario), the runs, scans and time span
    it holds, the source file's name and the table's first time ``first_time_s`` (its scan
    times start at 0).

    Returns
    -------
    ConvertReport
    """
    fmt = _check_family(family)
    rows = read_table(src)
    sensors = None
    if "sensors" in fmt.tables:
        if sensors_src is None:
            raise InputError(f"a {family} table needs its sensors table (--sensors SENSORS)", src)
        sensors = read_table(sensors_src)
    elif sensors_src is not None:
        with_sensors = [f for f, other in table_formats().items() if "sensors" in other.tables]
        raise InputError(f"--sensors belongs to {' and '.join(with_sensors)} tables, not to {fmt.command}",
                         sensors_src)
    data = dataset_from_table(family, rows, src, sensors, sensors_src)
    source = {"source_table": Path(src).name}
    if sensors_src is not None:
        source["source_sensors_table"] = Path(sensors_src).name
    messages, params, notes, sources = write_imported(family, data, dst, overrides, f"{family} table", source, src)
    family_of = vocab.FAMILIES[family]
    measured = [counts for topic, (_, counts) in data.ragged.items() if topic in family_of.inputs]
    items = int(sum(int(c.sum()) for c in measured)) if measured else int(rows.height)
    truth = family_of.truth in data.fixed or family_of.truth in data.ragged
    return ConvertReport(Path(dst), messages, data.n_runs, int(data.times.size), items, truth, params, notes, sources)
