"""What a family's table is, and the registry of the families that have one.

A family with a tabular form declares it once, in its own module (:data:`TABLE_MODULES`: one
``recorders/<stem>_table.py`` per family), as a :class:`TableFormat` named ``FORMAT``: its
columns (units, meanings), the notes of what forms a scan and what is refused, the fewest scans
its trackers need, its reader and exporter, the ``replay convert`` command that reads it and the
words of its help, its sample files, and the hooks the generic importers call where a family
differs (a sensors table, values the data imply, a check against the recorded sensor values, a
foreign MCAP's truth list and scans without items). The generic code
(:mod:`trackreplay.recorders.tables`, :mod:`trackreplay.recorders.table_rows`,
:mod:`trackreplay.recorders.foreign_mcap`, :mod:`trackreplay.face.cli_convert_tables`) reads
these fields and never names a family.

:data:`TABLE_FORMATS` (``{family: TableFormat}``, in the order of :data:`TABLE_MODULES`) is
built on first use. This module and the families' modules import neither numpy nor polars at
import time: ``replay --help`` lists the convert commands from the formats without them
(``tests/test_startup_imports.py``). ``docs/importers.md`` is tested to list every column; a
mapping file of a foreign MCAP names the same columns (:mod:`trackreplay.recorders.foreign_mapping`).
"""

from __future__ import annotations

import functools
import importlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, NamedTuple

from trackreplay import vocabulary as vocab
from trackreplay.errors import InputError

#: the modules (in ``trackreplay.recorders``) that declare a family's table format: a declared
#: family's ``recorders/<stem>_table.py`` where it has one, in the declaration's order
TABLE_MODULES = tuple(f"{family.stem}_table" for family in vocab.FAMILIES.values()
                      if (Path(__file__).parent / f"{family.stem}_table.py").is_file())


class TableColumn(NamedTuple):
    """One column of a table format: its name (alternatives joined by ``|``), unit, whether it
    is required, and its meaning."""

    name: str
    unit: str
    required: bool
    meaning: str


@dataclass(frozen=True)
class TableFormat:
    """The table format of one measurement family.

    Attributes
    ----------
    family : str
        A key of :data:`trackreplay.vocabulary.FAMILIES`.
    command : str
        ``replay convert <command>`` reads it.
    stem : str
        File name (without suffix) ``replay export --table`` writes it to.
    summary : str
        What a row is.
    tables : dict
        ``"measurements"`` (and ``"sensors"`` for a family with a table of sensors) → tuple of
        :class:`TableColumn`; the keys of :func:`trackreplay.recorders.tables.tables_from_dataset`'s
        result.
    notes : tuple of str
        What forms a scan and what is refused, beyond the rules every table follows.
    min_scans : int
        The fewest scan times the family's trackers need.
    read : callable
        ``read(rows)`` (``read(rows, sensors)`` for a family with a sensors table): the rows
        (:class:`~trackreplay.recorders.table_rows._Rows`), validated, → the arrays the family's
        simulator builds, :class:`~trackreplay.recorders.simulated.SimulatedData`.
    export : callable
        ``export(dataset)`` → ``{table: DataFrame}``, the way back.
    name_patterns : tuple of re.Pattern
        Measurement columns numbered per target (``truth0_bearing_rad``, …).
    extra_names : tuple of str
        Measurement column names written per axis in :attr:`tables` (``truth_<axis>_m``),
        spelled out.
    aliases : tuple of str
        Earlier names of :attr:`command`, still accepted.
    title : str
        The family's tables in a few words, capitalised (the converter's help).
    item_word : str
        What an item of a scan is called, plural (``wrote …: 120 plots``; "scans without plots").
    samples : dict
        ``{table: file name}`` of the bundled sample in ``data/samples`` (the help's example).
    sample_sensor_values : dict
        The sensor values the samples were made with (``docs/importers.md``, "Sample tables").
    table_help : dict
        ``{table: help}`` of the converter's option for each table beside the measurements.
    empty_scan_columns : tuple of str
        The measurement columns a row leaves empty to mark a scan without items; a foreign
        message with an empty item list is such a scan. Empty: every scan has its rows.
    truth_list : tuple of str
        The columns of a foreign mapping's ``[truth]`` table (a list of targets with identities
        per message, its rows truth-only rows of the measurements table), the target's identity
        first; empty: the family's mappings carry their truth in the columns of ``[measurements]``.
    data_values : callable, optional
        ``data_values(data, params)`` → ``(values, notes)``: values the imported data imply
        that the user did not give (recorded with the source "data"), and what to tell the user.
    check_values : callable, optional
        ``check_values(data, params, path)``: refuse what the replay would refuse given the
        recorded values (raises :class:`~trackreplay.errors.InputError` naming ``path``).

    Iterating over a format gives the columns of its measurements table.
    """

    family: str
    command: str
    stem: str
    summary: str
    tables: dict = field(default_factory=dict)
    notes: tuple = ()
    min_scans: int = 1
    read: Callable | None = None
    export: Callable | None = None
    name_patterns: tuple = ()
    extra_names: tuple = ()
    aliases: tuple = ()
    title: str = ""
    item_word: str = "rows"
    samples: dict = field(default_factory=dict)
    sample_sensor_values: dict = field(default_factory=dict)
    table_help: dict = field(default_factory=dict)
    empty_scan_columns: tuple = ()
    truth_list: tuple = ()
    data_values: Callable | None = None
    check_values: Callable | None = None

    @property
    def columns(self) -> tuple:
        return self.tables["measurements"]

    def __iter__(self):
        return iter(self.columns)

    def shown_names(self, table: str = "measurements") -> list[str]:
        """The columns of ``table`` as an error message lists them (``time_s|time``)."""
        return [c.name.replace(" | ", "|") for c in self.tables[table]]

    def literal_names(self, table: str = "measurements") -> tuple[str, ...]:
        """Every literal column name of ``table`` (both forms of alternatives and angles; the
        measurements table's :attr:`extra_names` too)."""
        out = []
        for c in self.tables[table]:
            for name in c.name.split(" | "):
                if "<" not in name:
                    out.append(name)
        if table == "measurements":
            out += self.extra_names
        return tuple(out)


# columns several families share
RUN = TableColumn("run", "index", False, "Monte Carlo run or recording index, from 0 without gaps (default 0)")
TIME = TableColumn("time_s | time", "s", True, "scan time; the rows of one run and time form one scan")
#: a planar state's truth columns: position and velocity
TRUTH_XY = ("truth_x_m", "truth_y_m", "truth_vx_mps", "truth_vy_mps")


def truth_xy_columns(what: str) -> tuple:
    """The four columns of :data:`TRUTH_XY`, ``what`` (the true target, emitter) described."""
    return (
        TableColumn("truth_x_m", "m", False, f"{what} x at the scan (e.g. from GPS), for scoring; the same on "
                                             "every row of one run and time; all four truth columns or none"),
        TableColumn("truth_y_m", "m", False, f"{what} y"),
        TableColumn("truth_vx_mps", "m/s", False, f"{what} x velocity"),
        TableColumn("truth_vy_mps", "m/s", False, f"{what} y velocity"),
    )


@functools.cache
def table_formats() -> dict[str, TableFormat]:
    """``{family: TableFormat}`` of every module of :data:`TABLE_MODULES`, in that order."""
    formats = {}
    for name in TABLE_MODULES:
        fmt = importlib.import_module(f"trackreplay.recorders.{name}").FORMAT
        formats[fmt.family] = fmt
    return formats


def __getattr__(name: str):
    # TABLE_FORMATS is built on first use: the families' modules import this one for TableFormat
    if name == "TABLE_FORMATS":
        return table_formats()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _check_family(family: str) -> TableFormat:
    formats = table_formats()
    if family not in formats:
        raise InputError(f"no table format for the family {family!r} (have: {', '.join(formats)})")
    return formats[family]


def scenario_of(family: str) -> str:
    """The bundled scenario whose parameters name ``family``'s design values (its declaration)."""
    _check_family(family)
    return vocab.FAMILIES[family].scenario
