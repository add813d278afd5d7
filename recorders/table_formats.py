"""The table of every family with a tabular form (radar plots, cross-correlation peaks,
TDOA/FDOA measurements with a table of sensors, positions in coloured noise): one entry per
family in :data:`TABLE_FORMATS`, holding everything a family's table import and export is —
its columns (units, meanings), the notes of what forms a scan and what is refused, the fewest
scans its trackers need, its reader (:mod:`trackreplay.recorders.table_readers`) and its
exporter (:mod:`trackreplay.recorders.table_exporters`).

The command-line help of ``replay convert <command>`` is written from an entry, and
``docs/importers.md`` is tested to list every column. A mapping file of a foreign MCAP names
the same columns (:mod:`trackreplay.recorders.foreign_mapping`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, NamedTuple

from trackreplay import vocabulary as vocab
from trackreplay.errors import InputError
from trackreplay.recorders import table_exporters as exporters
from trackreplay.recorders import table_readers as readers
from trackreplay.recorders.table_rows import _PEAK_RATE, _PEAK_TRUTH, AXES


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
        ``"measurements"`` (and ``"sensors"`` for tdoa-fdoa) → tuple of :class:`TableColumn`;
        the keys of :func:`trackreplay.recorders.tables.tables_from_dataset`'s result.
    notes : tuple of str
        What forms a scan and what is refused, beyond the rules every table follows.
    min_scans : int
        The fewest scan times the family's trackers need.
    read : callable
        ``read(rows)`` (``read(rows, sensors)`` for a family with a sensors table): the rows
        (:class:`~trackreplay.recorders.table_rows._Rows`), validated, → the arrays the family's
        simulator builds, :class:`~trackreplay.recorders.simulated.SimulatedData`
        (:mod:`trackreplay.recorders.table_readers`).
    export : callable
        ``export(dataset)`` → ``{table: DataFrame}``, the way back
        (:mod:`trackreplay.recorders.table_exporters`).
    name_patterns : tuple of re.Pattern
        Measurement columns numbered per target (``truth0_bearing_rad``, …).
    extra_names : tuple of str
        Measurement column names written per axis in :attr:`tables` (``truth_<axis>_m``),
        spelled out.

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


_RUN = TableColumn("run", "index", False, "Monte Carlo run or recording index, from 0 without gaps (default 0)")
_TIME = TableColumn("time_s | time", "s", True, "scan time; the rows of one run and time form one scan")


def _truth_xy(what: str) -> tuple:
    return (
        TableColumn("truth_x_m", "m", False, f"{what} x at the scan (e.g. from GPS), for scoring; the same on "
                                             "every row of one run and time; all four truth columns or none"),
        TableColumn("truth_y_m", "m", False, f"{what} y"),
        TableColumn("truth_vx_mps", "m/s", False, f"{what} x velocity"),
        TableColumn("truth_vy_mps", "m/s", False, f"{what} y velocity"),
    )


TABLE_FORMATS: dict[str, TableFormat] = {f.family: f for f in (
    TableFormat(
        "radar-plots", "plots", "radar_plots", "one row per radar plot (range, bearing) of a scan",
        {"measurements": (
            _RUN, _TIME,
            TableColumn("range_m", "m", True, "plot range, ≥ 0"),
            TableColumn("bearing_rad | bearing_deg", "rad | °", True,
                        "plot bearing, counter-clockwise from +x (x = r cos θ, y = r sin θ)"),
            *_truth_xy("true target"),
            TableColumn("truth_id", "index", False,
                        "identity of the target the row's truth columns describe (many targets: a long "
                        "table, one row per plot and per target; a plot on the same row came from it)"),
        )},
        ("Several rows of one run and time are several plots of that scan.",
         "With truth_id, the truth is a set of targets per scan: every row naming a target gives its state "
         "(the same on every row of that target and scan); rows with range and bearing empty carry truth "
         "alone, rows with the truth columns empty a plot alone (clutter, or of no known target).",
         "A row with range and bearing both empty marks a scan without plots (it may carry the truth); "
         "it may not share its scan with plots or with another such row.",
         "Refused: a negative range; a scan whose truth columns disagree between rows; with truth, a run "
         "without a row at one of the scan times; fewer than 3 scans."),
        min_scans=3, read=readers.read_radar_plots, export=exporters.export_radar_plots),
    TableFormat(
        "bearing-peaks", "peaks", "bearing_peaks", "one row per cross-correlation peak (bearing, amplitude) of a scan",
        {"measurements": (
            _RUN, _TIME,
            TableColumn("bearing_rad | bearing_deg", "rad | °", True,
                        "peak bearing θ = arccos(C·D/d), within the sensor's field "
                        "(field_min_deg … field_max_deg)"),
            TableColumn("amplitude", "-", True, "peak amplitude, ≥ 0"),
            TableColumn("origin", "index", False,
                        "target a true peak came from (0, 1, …), −1 for clutter or unknown (default −1); for "
                        "judging only, trackers never read it"),
            TableColumn("truth<t>_bearing_rad | truth<t>_bearing_deg", "rad | °", False,
                        "true bearing of target t = 0, 1, … at the scan, for scoring; the same on every row of "
                        "one run and time"),
            TableColumn("truth<t>_bearing_rate_radps | truth<t>_bearing_rate_degps", "rad/s | °/s", False,
                        "its bearing rate (with the bearings, for every target or none)"),
        )},
        ("Several rows of one run and time are several peaks of that scan, kept in the order of the file.",
         "A row with bearing, amplitude (and origin) empty marks a scan without peaks.",
         "Refused: a negative amplitude, an origin below −1, a bearing outside the sensor's field recorded "
         "for the replay, truth that disagrees within a scan, fewer than 3 scans."),
        min_scans=3, read=readers.read_bearing_peaks, export=exporters.export_bearing_peaks,
        name_patterns=(_PEAK_TRUTH, _PEAK_RATE)),
    TableFormat(
        "tdoa-fdoa", "tdoa-fdoa", "tdoa_fdoa", "one row per sensor pair of a measurement epoch",
        {"measurements": (
            _RUN, TableColumn("time_s | time", "s", True, "epoch time; the rows of one run and time form one epoch"),
            TableColumn("sensor_a", "index", True, "first sensor of the pair (a sensor of the sensors table, from 0)"),
            TableColumn("sensor_b", "index", True, "second sensor of the pair"),
            TableColumn("tdoa_s", "s", True, "time difference of arrival (r_a − r_b)/c"),
            TableColumn("fdoa_hz", "Hz", True, "frequency difference of arrival f₀(ṙ_a − ṙ_b)/c"),
            TableColumn("sigma_tdoa_s", "s", True, "standard deviation of the TDOA, > 0"),
            TableColumn("sigma_fdoa_hz", "Hz", True, "standard deviation of the FDOA, > 0"),
            TableColumn("carrier_hz", "Hz", True, "the emitter's carrier f₀, > 0; the same on every row of an epoch"),
            *_truth_xy("true emitter"),
            TableColumn("prior_x_m", "m", False,
                        "a coarse fix Gauss-Newton may start from (initial_guess=prior); the same on every row "
                        "of an epoch; all four prior columns or none (without them the replay starts from a "
                        "grid search: initial_guess=grid)"),
            TableColumn("prior_y_m", "m", False, "the fix's y"),
            TableColumn("prior_vx_mps", "m/s", False, "the fix's x velocity"),
            TableColumn("prior_vy_mps", "m/s", False, "the fix's y velocity"),
         ),
         "sensors": (
            _RUN, TableColumn("time_s | time", "s", True, "epoch time (the measurement table's epochs)"),
            TableColumn("sensor", "index", True, "sensor index, 0 … S−1 in every epoch"),
            TableColumn("x_m", "m", True, "sensor position x"),
            TableColumn("y_m", "m", True, "sensor position y"),
            TableColumn("vx_mps", "m/s", True, "sensor velocity x"),
            TableColumn("vy_mps", "m/s", True, "sensor velocity y"),
         )},
        ("Every epoch lists the same pairs (in any order; the first epoch's order is kept) and the sensors "
         "table lists every sensor once per epoch.",
         "Refused: a pair of a sensor with itself or repeated in an epoch, a sensor index the sensors table "
         "does not list, σ or carrier ≤ 0, an epoch missing from either table, a duplicated (run, time, "
         "sensor) or (run, time, pair), values that disagree within an epoch."),
        min_scans=1, read=readers.read_tdoa_fdoa, export=exporters.export_tdoa_fdoa),
    TableFormat(
        "colored-position", "positions", "colored_positions", "one row per position measurement (run and time)",
        {"measurements": (
            _RUN, TableColumn("time_s | time", "s", True, "measurement time, evenly spaced"),
            TableColumn("x_m", "m", True, "measured position, first axis"),
            TableColumn("y_m", "m", False, "second axis (a 2-D target)"),
            TableColumn("z_m", "m", False, "third axis (with y_m)"),
            TableColumn("truth_<axis>_m", "m", False,
                        "true position on each axis (truth_x_m, …), for scoring and the thesis's true start"),
            TableColumn("truth_v<axis>_mps", "m/s", False, "true velocity (truth_vx_mps, …)"),
            TableColumn("truth_a<axis>_mps2", "m/s²", False,
                        "true acceleration (truth_ax_mps2, …); the three truth columns of every axis or none"),
            TableColumn("truth_alpha_<axis>", "-", False,
                        "true AR(1) coefficient of the axis's measurement noise, in [−1, 1] (with the truth)"),
        )},
        ("One row per run and time: a duplicated (run, time) is refused.",
         "Refused: uneven time steps, fewer than 4 scans, truth for some axes only."),
        min_scans=4, read=readers.read_colored_positions, export=exporters.export_colored_positions,
        extra_names=tuple(n for a in AXES for n in (f"truth_{a}_m", f"truth_v{a}_mps", f"truth_a{a}_mps2",
                                                    f"truth_alpha_{a}"))),
)}


def _check_family(family: str) -> TableFormat:
    if family not in TABLE_FORMATS:
        raise InputError(f"no table format for the family {family!r} (have: {', '.join(TABLE_FORMATS)})")
    return TABLE_FORMATS[family]


def scenario_of(family: str) -> str:
    """The bundled scenario whose parameters name ``family``'s design values (its declaration)."""
    _check_family(family)
    return vocab.FAMILIES[family].scenario
