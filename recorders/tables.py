"""Tables of measurements (CSV or Parquet) ↔ data sets, for every measurement family with a
tabular form: radar plots, cross-correlation peaks, TDOA/FDOA measurements (with a table of
sensors) and positions in coloured noise. The array family has its own WAV converter.

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
* :func:`convert_table` is what ``replay convert plots|peaks|tdoa-fdoa|positions`` runs: read,
  validate, record the sensor and design values the user gave with ``--set`` (nothing from a
  bundled scenario: :mod:`trackreplay.sensor_values`) and what the data hold, and write the data
  set.

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

import difflib
import re
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import NamedTuple

import numpy as np
import polars as pl

from trackreplay import vocabulary as vocab
from trackreplay.errors import InputError
from trackreplay.recorders.simulated import SimulatedData, write_simulated

# --------------------------------------------------------------------------- formats


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
        the keys of :func:`tables_from_dataset`'s result.
    notes : tuple of str
        What forms a scan and what is refused, beyond the rules every table follows.

    Iterating over a format gives the columns of its measurements table.
    """

    family: str
    command: str
    stem: str
    summary: str
    tables: dict = field(default_factory=dict)
    notes: tuple = ()

    @property
    def columns(self) -> tuple:
        return self.tables["measurements"]

    def __iter__(self):
        return iter(self.columns)


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
         "without a row at one of the scan times; fewer than 3 scans.")),
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
         "for the replay, truth that disagrees within a scan, fewer than 3 scans.")),
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
         "sensor) or (run, time, pair), values that disagree within an epoch.")),
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
         "Refused: uneven time steps, fewer than 4 scans, truth for some axes only.")),
)}

MIN_SCANS = {"radar-plots": 3, "bearing-peaks": 3, "tdoa-fdoa": 1, "colored-position": 4}
AXES = ("x", "y", "z")
MAX_RUNS = 1 << 24  # the contract's bound on a run index
MAX_SENSORS = 1 << 16  # the contract's bound on a pair's sensor index

_CH = vocab.CHANNELS
_PLOTS, _RADAR_TRUTH = _CH["radar_plots"], _CH["radar_truth"]
_PEAKS, _XCORR_TRUTH = _CH["xcorr_peaks"], _CH["xcorr_truth"]
_MEAS, _SENSORS, _PRIOR, _EMITTER_TRUTH = (_CH["emitter_measurements"], _CH["emitter_sensors"], _CH["emitter_prior"],
                                           _CH["emitter_truth"])
_COLORED, _COLORED_TRUTH = _CH["colored_measurements"], _CH["colored_truth"]

_TRUTH_XY = ("truth_x_m", "truth_y_m", "truth_vx_mps", "truth_vy_mps")
_PRIOR_XY = ("prior_x_m", "prior_y_m", "prior_vx_mps", "prior_vy_mps")
_PEAK_TRUTH = re.compile(r"^truth(\d+)_bearing_(rad|deg)$")
_PEAK_RATE = re.compile(r"^truth(\d+)_bearing_rate_(radps|degps)$")


def _check_family(family: str) -> TableFormat:
    if family not in TABLE_FORMATS:
        raise InputError(f"no table format for the family {family!r} (have: {', '.join(TABLE_FORMATS)})")
    return TABLE_FORMATS[family]


def scenario_of(family: str) -> str:
    """The bundled scenario whose parameters name ``family``'s design values (its declaration)."""
    _check_family(family)
    return vocab.FAMILIES[family].scenario


# --------------------------------------------------------------------------- reading files


def read_table(path) -> pl.DataFrame:
    """Read a table from a ``.csv`` or ``.parquet`` file (chosen by the suffix).

    CSV columns are typed from every row (a column with one word in it stays text, and
    :func:`dataset_from_table` names the row); floats are parsed exactly, so a table written by
    polars gives back the same numbers.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    polars.DataFrame

    Raises
    ------
    InputError
        No such file, a folder, another suffix, an empty or binary "CSV", or a file polars
        cannot read.
    """
    path = Path(path)
    if not path.exists():
        raise InputError("no such file", path)
    if path.is_dir():
        raise InputError("is a folder, not a table file", path)
    suffix = path.suffix.lower()
    if suffix not in (".csv", ".parquet"):
        raise InputError(f"not a CSV or Parquet file (the name ends in {path.suffix or 'no suffix'!r}; "
                         "a table is read from .csv or .parquet)", path)
    if path.stat().st_size == 0:
        raise InputError("empty file", path)
    try:
        if suffix == ".parquet":
            return pl.read_parquet(path)
        with open(path, "rb") as f:
            head = f.read(8192)
        if b"\x00" in head or head.startswith(b"PAR1"):
            raise InputError("binary content, not a CSV text file", path)
        return pl.read_csv(path, infer_schema_length=None)
    except InputError:
        raise
    except (pl.exceptions.PolarsError, OSError, ValueError, UnicodeDecodeError) as exc:
        kind = "Parquet" if suffix == ".parquet" else "CSV"
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        raise InputError(f"unreadable {kind} file ({first[:200]})", path) from None


# --------------------------------------------------------------------------- validating rows


class _Rows:
    """A table being validated: its columns as numbers, with messages naming the first bad row."""

    def __init__(self, rows: pl.DataFrame, path, family: str, known: tuple[str, ...], patterns=(),
                 what: str = "table"):
        if not isinstance(rows, pl.DataFrame):
            raise TypeError(f"rows must be a polars DataFrame, got {type(rows).__name__}")
        self.path = path
        self.family = family
        self.what = what
        stripped = [c.strip() for c in rows.columns]
        if stripped != rows.columns and len(set(stripped)) == len(stripped):  # " range_m" after a comma and space
            rows = rows.rename(dict(zip(rows.columns, stripped)))
        self.df = rows
        self.n = rows.height
        self.known, self.patterns = known, patterns

    def error(self, problem: str) -> InputError:
        return InputError(problem, self.path)

    def has(self, name: str) -> bool:
        return name in self.df.columns

    def require(self, *groups) -> None:
        """Check the header and that there are rows: each group is a required name or a tuple of
        alternatives (every missing one is named at once); then no unknown column, which may be
        a typo that would drop what it holds (truth, origin) without a word."""
        unknown = [c for c in self.df.columns if c not in self.known and not any(p.match(c) for p in self.patterns)]
        has = f"a {self.family} {self.what} has: {', '.join(_known_display(self.family, self.what))}"
        missing = []
        for g in groups:
            alts = (g,) if isinstance(g, str) else g
            if not any(self.has(a) for a in alts):
                missing.append(" or ".join(alts))
        if missing:
            strange = f"; unknown: {', '.join(map(repr, unknown))}" if unknown else ""
            sep = next((c for c in ";\t|" if len(self.df.columns) == 1 and c in self.df.columns[0]), None)
            if sep is not None:
                strange += f"; the file seems separated by {sep!r}, a CSV table by commas"
            raise self.error(f"missing column(s) {', '.join(missing)}{strange} ({has})")
        if unknown:
            hint = difflib.get_close_matches(unknown[0], self.known, n=1)
            raise self.error(f"unknown column(s) {', '.join(map(repr, unknown))}"
                             + (f" (did you mean {hint[0]!r}?)" if hint else "") + f"; {has}")
        if self.n == 0:
            raise self.error("no rows (a header only)")

    def row(self, i) -> int:
        return int(i) + 1

    def floats(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """Column ``name`` as float64 (NaN where empty) and its mask of empty cells; text,
        NaN and ±Inf are refused."""
        s = self.df[name]
        if s.dtype == pl.String:
            text = s.str.strip_chars()
            values = text.cast(pl.Float64, strict=False)
            bad = (text.is_not_null() & (text != "") & values.is_null()).to_numpy()
            if bad.any():
                i = int(np.argmax(bad))
                raise self.error(f"column {name!r} holds text {s[i]!r} at data row {self.row(i)}, where a number "
                                 "belongs")
        elif s.dtype == pl.Null:
            values = pl.Series(name, [None] * self.n, pl.Float64)
        elif s.dtype == pl.Boolean:
            raise self.error(f"column {name!r} holds true/false values, where numbers belong")
        elif s.dtype.is_numeric():
            values = s.cast(pl.Float64)
        else:
            raise self.error(f"column {name!r} holds {s.dtype} values, where numbers belong")
        empty = values.is_null().to_numpy()
        out = values.to_numpy(allow_copy=True).astype(np.float64, copy=True)
        out[empty] = np.nan
        bad = ~empty & ~np.isfinite(out)
        if bad.any():
            i = int(np.argmax(bad))
            v = out[i]
            word = "NaN" if np.isnan(v) else ("Inf" if v > 0 else "-Inf")
            raise self.error(f"column {name!r} holds {word} at data row {self.row(i)} (numbers must be finite)")
        return out, empty

    def filled(self, name: str, rows_mask: np.ndarray | None = None) -> np.ndarray:
        """Column ``name`` as float64, refusing an empty cell (on the rows of ``rows_mask``)."""
        values, empty = self.floats(name)
        if rows_mask is not None:
            empty = empty & rows_mask
        if empty.any():
            raise self.error(f"column {name!r} is empty at data row {self.row(np.argmax(empty))}")
        return values

    def angle(self, name_rad: str) -> tuple[np.ndarray, np.ndarray, str] | None:
        """``X_rad`` or its twin ``X_deg`` (``_radps``/``_degps``) in radians, its empty mask and
        the name given; None when neither is there."""
        name_deg = _degree_twin(name_rad)
        given = [n for n in (name_rad, name_deg) if self.has(n)]
        if not given:
            return None
        if len(given) == 2:
            raise self.error(f"both {name_rad!r} and {name_deg!r} given; keep one")
        values, empty = self.floats(given[0])
        if given[0] == name_deg:
            values = np.deg2rad(values)
        return values, empty, given[0]

    def integers(self, name: str, low: int, high: int, what: str, rows_mask=None) -> np.ndarray:
        """Column ``name`` as int64 in ``low … high``; empty cells (on ``rows_mask``) refused."""
        values = self.filled(name, rows_mask)
        check = np.ones(self.n, bool) if rows_mask is None else rows_mask
        frac = check & (np.round(values) != values)
        if frac.any():
            i = int(np.argmax(frac))
            raise self.error(f"column {name!r} holds a non-integer value {values[i]:g} at data row {self.row(i)} "
                             f"({what})")
        out = np.where(check, values, 0).astype(np.int64)
        bad = check & ((out < low) | (out > high))
        if bad.any():
            i = int(np.argmax(bad))
            raise self.error(f"column {name!r} holds {out[i]} at data row {self.row(i)}; {what} lie in "
                             f"{low} … {high}")
        return out

    def within(self, name: str, values: np.ndarray, spec: vocab.ValueSpec, rows_mask=None, positive=False) -> None:
        """Refuse values outside the contract's bounds for the array they fill (``positive``:
        also 0)."""
        check = np.ones(values.shape, bool) if rows_mask is None else rows_mask
        if spec.low is not None:
            below = check & ((values <= spec.low) if positive else (values < spec.low))
            if below.any():
                i = int(np.argmax(below))
                word = ("a non-positive" if positive else "a negative") if spec.low == 0 else f"below {spec.low:g}:"
                raise self.error(f"column {name!r} holds {word} value {values[i]:g} at data row {self.row(i)}")
        if spec.high is not None:
            above = check & (values > spec.high)
            if above.any():
                i = int(np.argmax(above))
                raise self.error(f"column {name!r} holds {values[i]:g} at data row {self.row(i)}, above "
                                 f"{spec.high:g} (beyond any recording)")


def _n(x) -> str:
    """A number in a message: as Python prints a float (exact, without numpy's type)."""
    return repr(float(x))


def _degree_twin(name_rad: str) -> str:
    if name_rad.endswith("_radps"):
        return name_rad[: -len("_radps")] + "_degps"
    if name_rad.endswith("_rad"):
        return name_rad[: -len("_rad")] + "_deg"
    raise ValueError(name_rad)


def _known_display(family: str, what: str) -> list[str]:
    key = "sensors" if what == "sensors table" else "measurements"
    return [c.name.replace(" | ", "|") for c in TABLE_FORMATS[family].tables[key]]


def _known_names(family: str, what: str = "table") -> tuple[str, ...]:
    """Every literal column name of a table (both forms of alternatives and angles)."""
    key = "sensors" if what == "sensors table" else "measurements"
    out = []
    for c in TABLE_FORMATS[family].tables[key]:
        for name in c.name.split(" | "):
            if "<" not in name:
                out.append(name)
    if family == "colored-position":
        for a in AXES:
            out += [f"truth_{a}_m", f"truth_v{a}_mps", f"truth_a{a}_mps2", f"truth_alpha_{a}"]
    return tuple(out)


@dataclass
class _Scans:
    """Runs, times and scans of a validated table."""

    run: np.ndarray      # (rows,) int64
    scan: np.ndarray     # (rows,) int64
    times: np.ndarray    # (K,) the distinct times, ascending
    n_runs: int

    @property
    def n_scans(self) -> int:
        return self.times.size

    @property
    def key(self) -> np.ndarray:
        return self.run * self.n_scans + self.scan

    def where(self, r, k) -> str:
        return f"run {int(r)} at time {_n(self.times[int(k)])} s"


def _scans(t: _Rows) -> _Scans:
    """Validate ``run`` and ``time_s`` (or ``time``) and number the scans."""
    t.require(("time_s", "time"))
    if t.has("time_s") and t.has("time"):
        raise t.error("both 'time_s' and 'time' given; keep one")
    tname = "time_s" if t.has("time_s") else "time"
    time = t.filled(tname)
    beyond = np.abs(time) > vocab.TIME_LIMIT_S
    if beyond.any():
        i = int(np.argmax(beyond))
        raise t.error(f"scan time {float(time[i]):g} s at data row {t.row(i)} is beyond any recording "
                      f"(|t| ≤ {vocab.TIME_LIMIT_S:g} s)")
    if time.max() - time.min() > vocab.TIME_LIMIT_S:
        raise t.error(f"the scan times span {time.max() - time.min():g} s, beyond any recording "
                      f"(≤ {vocab.TIME_LIMIT_S:g} s)")
    run = (t.integers("run", 0, MAX_RUNS - 1, "runs are counted 0, 1, …") if t.has("run")
           else np.zeros(t.n, np.int64))
    order = np.argsort(run, kind="stable")
    rs, ts = run[order], time[order]
    back = np.flatnonzero((rs[1:] == rs[:-1]) & (ts[1:] < ts[:-1]))
    if back.size:
        j = int(back[np.argmin(order[back + 1])])
        i, prev = int(order[j + 1]), int(order[j])
        raise t.error(f"{tname} goes back within run {run[i]} at data row {t.row(i)} ({_n(time[i])} s after "
                      f"{_n(time[prev])} s at data row {t.row(prev)}): sort each run's rows by time")
    present = np.unique(run)
    n_runs = int(present[-1]) + 1
    if present.size != n_runs:
        gap = int(np.flatnonzero(np.arange(present.size) != present)[0])
        raise t.error(f"no rows for run {gap}: runs are numbered 0, 1, … without gaps (the table has runs up to "
                      f"{n_runs - 1})")
    times = np.unique(time)
    if times.size * n_runs > max(1 << 22, 64 * t.n):
        raise t.error(f"the runs do not share their scan times ({n_runs} runs × {times.size} distinct times for "
                      f"{t.n} rows)")
    return _Scans(run, np.searchsorted(times, time).astype(np.int64), times, n_runs)


def _require_min_scans(t: _Rows, sc: _Scans, family: str) -> None:
    need = MIN_SCANS[family]
    if sc.n_scans < need:
        raise t.error(f"{sc.n_scans} scan time(s); the {family} trackers need at least {need}")


def _require_every_scan(t: _Rows, sc: _Scans, counts: np.ndarray, why: str) -> None:
    """Refuse a (run, scan) without rows, naming the first."""
    missing = counts.reshape(sc.n_runs, sc.n_scans) == 0
    if missing.any():
        r, k = (int(v[0]) for v in np.nonzero(missing))
        raise t.error(f"no row for {sc.where(r, k)} ({why})")


def _per_scan(t: _Rows, sc: _Scans, names: list[str], values: list[np.ndarray]) -> np.ndarray:
    """Values shared by the rows of a scan → ``(runs·scans, len(names))`` (NaN where a scan has
    no row); refuse rows of one scan that disagree."""
    key = sc.key
    order = np.argsort(key, kind="stable")
    k_sorted = key[order]
    same = k_sorted[1:] == k_sorted[:-1]
    out = np.full((sc.n_runs * sc.n_scans, len(names)), np.nan)
    for j, (name, v) in enumerate(zip(names, values)):
        vs = v[order]
        differ = same & (vs[1:] != vs[:-1])
        if differ.any():
            p = int(np.argmax(differ))
            a, b = int(order[p]), int(order[p + 1])
            raise t.error(f"column {name!r} differs within one scan ({sc.where(sc.run[a], sc.scan[a])}): {_n(v[a])} "
                          f"at data row {t.row(a)} but {_n(v[b])} at data row {t.row(b)}; it holds one value per run "
                          "and time")
        out[k_sorted, j] = vs
    return out


def _group_of(t: _Rows, names: tuple[str, ...], what: str) -> bool:
    """True when all of ``names`` are columns, False when none are; refuse some."""
    have = [n for n in names if t.has(n)]
    if have and len(have) != len(names):
        missing = [n for n in names if n not in have]
        raise t.error(f"{what} columns need all of {', '.join(names)}; missing {', '.join(missing)}")
    return bool(have)


def _ragged(sc: _Scans, present: np.ndarray, arrays: dict) -> tuple[dict, np.ndarray]:
    """Items on the rows ``present`` → ``(runs, scans, width)`` arrays in file order and counts.

    ``arrays``: name → (values per row (rows, ...), padding, dtype).
    """
    rows = np.flatnonzero(present)
    key = sc.key[rows]
    order = np.argsort(key, kind="stable")
    key_sorted = key[order]
    counts = np.bincount(key, minlength=sc.n_runs * sc.n_scans).reshape(sc.n_runs, sc.n_scans).astype(np.int64)
    # each item's slot is its rank among the rows of its scan, in file order
    slot = np.empty(rows.size, np.int64)
    slot[order] = np.arange(rows.size) - np.searchsorted(key_sorted, key_sorted, side="left")
    width = int(counts.max()) if counts.size else 0
    out = {}
    for name, (values, fill, dtype) in arrays.items():
        a = np.full((sc.n_runs * sc.n_scans, width) + values.shape[1:], fill, dtype=dtype)
        a[key, slot] = values[rows]
        out[name] = a.reshape((sc.n_runs, sc.n_scans, width) + values.shape[1:])
    return out, counts


def _markers(t: _Rows, sc: _Scans, empties: dict[str, np.ndarray], item: str, several: bool = False) -> np.ndarray:
    """Rows whose measurement columns are all empty (a scan without items); refuse a row with
    some empty, a marker beside items of its scan, and two markers for one scan (unless
    ``several``: rows that carry something else, e.g. one target's truth each)."""
    masks = list(empties.values())
    every, some = np.logical_and.reduce(masks), np.logical_or.reduce(masks)
    partial = some & ~every
    if partial.any():
        i = int(np.argmax(partial))
        empty = next(n for n, m in empties.items() if m[i])
        raise t.error(f"column {empty!r} is empty at data row {t.row(i)} while the row's other measurement columns "
                      f"are not (a row marking a scan without {item}s leaves them all empty)")
    if every.any() and not several:
        key = sc.key
        size = sc.n_runs * sc.n_scans
        items = np.bincount(key[~every], minlength=size)
        marks = np.bincount(key[every], minlength=size)
        bad = every & ((items[key] > 0) | (marks[key] > 1))
        if bad.any():
            i = int(np.argmax(bad))
            why = f"the scan has {item}s" if items[key[i]] else "another row marks it too"
            raise t.error(f"data row {t.row(i)} marks {sc.where(sc.run[i], sc.scan[i])} as a scan without "
                          f"{item}s, but {why} (duplicated scan)")
    return every


# --------------------------------------------------------------------------- families


def _radar(t: _Rows) -> SimulatedData:
    t.require(("time_s", "time"), "range_m", ("bearing_deg", "bearing_rad"))
    sc = _scans(t)
    rng, rng_empty = t.floats("range_m")
    brg, brg_empty, bname = t.angle("bearing_rad")
    # a long table of many targets has rows of truth alone, any number in a scan
    marker = _markers(t, sc, {"range_m": rng_empty, bname: brg_empty}, "plot", several=t.has("truth_id"))
    plot = ~marker
    spec = vocab.VALUES["radar_plots"]
    t.within("range_m", rng, spec["range_m"], plot)
    t.within(bname, brg, spec["bearing_rad"], plot)
    arrays, counts = _ragged(sc, plot, {"range_m": (rng, np.nan, np.float64), "bearing_rad": (brg, np.nan, np.float64)})
    data = SimulatedData(times=sc.times, ragged={_PLOTS: (arrays, counts)})
    _require_min_scans(t, sc, "radar-plots")
    if t.has("truth_id"):
        return _radar_truth_set(t, sc, data, plot)
    if _group_of(t, _TRUTH_XY, "truth"):
        values = [t.filled(n) for n in _TRUTH_XY]
        for n, v in zip(_TRUTH_XY, values):
            t.within(n, v, vocab.VALUES["radar_truth"]["state"])
        _require_every_scan(t, sc, np.bincount(sc.key, minlength=sc.n_runs * sc.n_scans),
                            "with truth columns every run needs a row at every scan time; a row with range and "
                            "bearing empty marks a scan without plots")
        state = _per_scan(t, sc, list(_TRUTH_XY), values)
        data.fixed[_RADAR_TRUTH] = {"state": state.reshape(sc.n_runs, sc.n_scans, 4)}
    return data


def _radar_truth_set(t: _Rows, sc: _Scans, data: SimulatedData, plot: np.ndarray) -> SimulatedData:
    """Truth as a set of targets per scan from a long table with ``truth_id``: each row naming a
    target gives its state at that scan; a plot on such a row came from it (``origin``), a plot on
    a row without one from no known target (−1)."""
    named = ~t.floats("truth_id")[1]
    ident = t.integers("truth_id", 0, vocab.VALUES["radar_truth"]["target_id"].high, "target identities",
                       rows_mask=named)
    values = []
    for n in _TRUTH_XY:
        v, empty = t.floats(n)
        gap = named & empty
        if gap.any():
            i = int(np.argmax(gap))
            raise t.error(f"column {n!r} is empty at data row {t.row(i)}, which names target {ident[i]} (a row with "
                          "truth_id gives all four truth columns)")
        stray = ~named & ~empty
        if stray.any():
            i = int(np.argmax(stray))
            raise t.error(f"column {n!r} holds a value at data row {t.row(i)}, which names no target (truth_id is "
                          "empty)")
        t.within(n, v, vocab.VALUES["radar_truth"]["state"], named)
        values.append(v)
    rows = np.flatnonzero(named)
    # one entry per (run, scan, target): rows repeating a target in its scan must agree
    key = (sc.key[rows] * (int(ident[rows].max(initial=0)) + 1) + ident[rows]) if rows.size else rows
    order = np.argsort(key, kind="stable")
    first = np.r_[True, key[order][1:] != key[order][:-1]] if rows.size else np.zeros(0, bool)
    for j, (name, v) in enumerate(zip(_TRUTH_XY, values)):
        vs = v[rows][order]
        differ = ~first[1:] & (vs[1:] != vs[:-1]) if rows.size else np.zeros(0, bool)
        if differ.any():
            p = int(np.argmax(differ))
            a, b = int(rows[order][p]), int(rows[order][p + 1])
            raise t.error(f"column {name!r} differs between data rows {t.row(a)} and {t.row(b)}, which give target "
                          f"{ident[a]} at {sc.where(sc.run[a], sc.scan[a])}; a target has one state a scan")
    unique = np.zeros(t.n, bool)
    unique[rows[order][first]] = True
    state = np.stack(values, axis=-1)
    arrays, counts = _ragged(sc, unique, {"state": (state, np.nan, np.float64), "target_id": (ident, -1, np.int64)})
    # targets in identity order within each scan, as the simulator writes them
    by_id = np.argsort(np.where(arrays["target_id"] >= 0, arrays["target_id"], np.iinfo(np.int64).max), axis=-1,
                       kind="stable")
    arrays = {"state": np.take_along_axis(arrays["state"], by_id[..., None], axis=2),
              "target_id": np.take_along_axis(arrays["target_id"], by_id, axis=2)}
    data.ragged[_RADAR_TRUTH] = (arrays, counts)
    origin = np.where(named, ident, -1)
    plots, plot_counts = data.ragged[_PLOTS]
    extra, _ = _ragged(sc, plot, {"origin": (origin, -1, np.int64)})
    data.ragged[_PLOTS] = ({**plots, "origin": extra["origin"]}, plot_counts)
    return data


def _peak_truth_columns(t: _Rows) -> tuple[list[str], list[str]]:
    """Canonical (radian) names of the truth bearing and rate columns, targets 0 … N−1."""
    found = {}
    for c in t.df.columns:
        for kind, pattern in (("bearing", _PEAK_TRUTH), ("rate", _PEAK_RATE)):
            m = pattern.match(c)
            if m:
                found.setdefault(kind, set()).add(int(m.group(1)))
    targets = sorted(found.get("bearing", ()))
    if targets and targets != list(range(len(targets))):
        raise t.error(f"truth bearing columns for targets {targets}: number the targets 0, 1, … without gaps")
    rates = sorted(found.get("rate", ()))
    if rates and rates != targets:
        raise t.error(f"truth bearing rate columns for targets {rates} but bearings for {targets}: give the rate of "
                      "every target or of none")
    return ([f"truth{i}_bearing_rad" for i in targets], [f"truth{i}_bearing_rate_radps" for i in rates])


def _peaks(t: _Rows) -> SimulatedData:
    t.require(("time_s", "time"), ("bearing_deg", "bearing_rad"), "amplitude")
    sc = _scans(t)
    brg, brg_empty, bname = t.angle("bearing_rad")
    amp, amp_empty = t.floats("amplitude")
    empties = {bname: brg_empty, "amplitude": amp_empty}
    if t.has("origin"):
        empties["origin"] = t.floats("origin")[1]
    marker = _markers(t, sc, empties, "peak")
    peak = ~marker
    spec = vocab.VALUES["xcorr_peaks"]
    t.within(bname, brg, spec["bearing_rad"], peak)
    t.within("amplitude", amp, spec["amplitude"], peak)
    origin = (t.integers("origin", -1, int(spec["origin"].high), "origins are target indices or −1", peak)
              if t.has("origin") else np.full(t.n, -1, np.int64))
    arrays, counts = _ragged(sc, peak, {"bearing_rad": (brg, np.nan, np.float64),
                                        "amplitude": (amp, np.nan, np.float64),
                                        "origin": (origin, -1, np.int32)})
    data = SimulatedData(times=sc.times, ragged={_PEAKS: (arrays, counts)})
    _require_min_scans(t, sc, "bearing-peaks")
    bearings, rates = _peak_truth_columns(t)
    if bearings:
        _require_every_scan(t, sc, np.bincount(sc.key, minlength=sc.n_runs * sc.n_scans),
                            "with truth columns every run needs a row at every scan time; a row with bearing and "
                            "amplitude empty marks a scan without peaks")
        truth = {}
        for array, names in (("bearing_rad", bearings), ("bearing_rate_radps", rates)):
            if not names:
                continue
            values, given_names = [], []
            for n in names:
                v, empty, given = t.angle(n)
                if empty.any():
                    raise t.error(f"column {given!r} is empty at data row {t.row(np.argmax(empty))}")
                t.within(given, v, vocab.VALUES["xcorr_truth"][array])
                values.append(v)
                given_names.append(given)
            truth[array] = _per_scan(t, sc, given_names, values).reshape(sc.n_runs, sc.n_scans, len(names))
        data.fixed[_XCORR_TRUTH] = truth
    return data


def _emitter(t: _Rows, s: _Rows | None) -> SimulatedData:
    t.require(("time_s", "time"), "sensor_a", "sensor_b", "tdoa_s", "fdoa_hz", "sigma_tdoa_s", "sigma_fdoa_hz",
              "carrier_hz")
    if s is None:
        raise t.error("a tdoa-fdoa table needs its sensors table (replay convert tdoa-fdoa FILE --sensors SENSORS)")
    sc = _scans(t)
    spec = vocab.VALUES["emitter_measurements"]
    hi = MAX_SENSORS - 1
    a = t.integers("sensor_a", 0, hi, "sensor indices count from 0")
    b = t.integers("sensor_b", 0, hi, "sensor indices count from 0")
    same = a == b
    if same.any():
        i = int(np.argmax(same))
        raise t.error(f"data row {t.row(i)} pairs sensor {a[i]} with itself")
    values = {}
    for name in ("tdoa_s", "fdoa_hz", "sigma_tdoa_s", "sigma_fdoa_hz", "carrier_hz"):
        values[name] = t.filled(name)
        t.within(name, values[name], spec[name], positive=name.startswith("sigma") or name == "carrier_hz")
    size = sc.n_runs * sc.n_scans
    key = sc.key
    # the pair list of the first epoch (run 0, first time), in file order, is the file's
    first = np.flatnonzero(key == 0)
    if first.size == 0:
        raise t.error(f"no row for {sc.where(0, 0)} (every run lists every epoch)")
    ref = list(zip(a[first].tolist(), b[first].tolist()))
    seen = {}
    for row, (i, j) in zip(first, ref):
        u = (min(i, j), max(i, j))
        if u in seen:
            raise t.error(f"pair {i}–{j} repeated in {sc.where(0, 0)} (data rows {t.row(seen[u])} and {t.row(row)})")
        seen[u] = row
    code = a * MAX_SENSORS + b
    ref_code = np.array([i * MAX_SENSORS + j for i, j in ref], np.int64)
    sorter = np.argsort(ref_code)
    pos = np.searchsorted(ref_code, code, sorter=sorter)
    pos = sorter[np.minimum(pos, ref_code.size - 1)]
    foreign = ref_code[pos] != code
    if foreign.any():
        i = int(np.argmax(foreign))
        listed = ", ".join(f"{p}–{q}" for p, q in ref)
        raise t.error(f"pair {a[i]}–{b[i]} at data row {t.row(i)} ({sc.where(sc.run[i], sc.scan[i])}) is not among "
                      f"the pairs of the first epoch ({listed}): every epoch lists the same pairs")
    P = len(ref)
    cell = key * P + pos
    dup = np.bincount(cell, minlength=size * P)
    if dup.max() > 1:
        order = np.argsort(cell, kind="stable")
        cs = cell[order]
        p = int(np.flatnonzero(cs[1:] == cs[:-1])[0])
        i, j = int(order[p]), int(order[p + 1])
        raise t.error(f"pair {a[j]}–{b[j]} repeated in {sc.where(sc.run[j], sc.scan[j])} (data rows {t.row(i)} and "
                      f"{t.row(j)}; duplicated (run, time, pair))")
    per = np.bincount(key, minlength=size)
    _require_every_scan(t, sc, per, "every run lists every epoch")
    short = per < P
    if short.any():
        c = int(np.argmax(short))
        have = {int(v) for v in pos[key == c]}
        lacking = next(q for q in range(P) if q not in have)
        raise t.error(f"{sc.where(*divmod(c, sc.n_scans))} lacks the pair {ref[lacking][0]}–{ref[lacking][1]} "
                      "(every epoch lists the same pairs)")
    _require_min_scans(t, sc, "tdoa-fdoa")
    grid = lambda v: _place(v, cell, size * P).reshape(sc.n_runs, sc.n_scans, P)  # noqa: E731
    shared = ["carrier_hz"]
    carrier = _per_scan(t, sc, shared, [values["carrier_hz"]]).reshape(sc.n_runs, sc.n_scans)
    pairs = np.broadcast_to(np.array(ref, np.int32), (sc.n_runs, sc.n_scans, P, 2))
    meas = {"tdoa_s": grid(values["tdoa_s"]), "fdoa_hz": grid(values["fdoa_hz"]),
            "sigma_tdoa_s": grid(values["sigma_tdoa_s"]), "sigma_fdoa_hz": grid(values["sigma_fdoa_hz"]),
            "pairs": pairs, "carrier_hz": carrier}
    data = SimulatedData(times=sc.times, fixed={_MEAS: meas})
    data.fixed[_SENSORS] = _sensors(s, sc, a, b, t)
    for names, topic, what, value_key in ((_TRUTH_XY, _EMITTER_TRUTH, "truth", "emitter_truth"),
                                          (_PRIOR_XY, _PRIOR, "prior", "emitter_prior")):
        if _group_of(t, names, what):
            vals = [t.filled(n) for n in names]
            for n, v in zip(names, vals):
                t.within(n, v, vocab.VALUES[value_key]["state"])
            data.fixed[topic] = {"state": _per_scan(t, sc, list(names), vals).reshape(sc.n_runs, sc.n_scans, 4)}
    return data


def _place(values: np.ndarray, cell: np.ndarray, size: int) -> np.ndarray:
    out = np.full(size, np.nan)
    out[cell] = values
    return out


def _sensors(s: _Rows, msc: _Scans, a: np.ndarray, b: np.ndarray, t: _Rows) -> dict:
    """The sensors table → ``position_m``, ``velocity_mps`` (runs, epochs, S, 2) on the
    measurement table's epochs (``msc``), checked against the pairs' sensors ``a``, ``b``."""
    s.require(("time_s", "time"), "sensor", "x_m", "y_m", "vx_mps", "vy_mps")
    sc = _scans(s)
    if sc.n_runs != msc.n_runs:
        raise s.error(f"{sc.n_runs} run(s), but the measurement table {Path(str(t.path)).name} has {msc.n_runs}")
    sensor = s.integers("sensor", 0, MAX_SENSORS - 1, "sensor indices count from 0")
    # the sensors' times must be the measurement epochs
    k = np.searchsorted(msc.times, sc.times)
    inside = k < msc.n_scans
    match = np.zeros(sc.n_scans, bool)
    match[inside] = msc.times[k[inside]] == sc.times[inside]
    if not match.all():
        extra = int(np.argmax(~match))
        i = int(np.argmax(sc.scan == extra))
        raise s.error(f"time {_n(sc.times[extra])} s at data row {s.row(i)} is not an epoch of the measurement table")
    scan = k[sc.scan]
    S = int(sensor.max()) + 1
    size = msc.n_runs * msc.n_scans
    cell = (sc.run * msc.n_scans + scan) * S + sensor
    dup = np.bincount(cell, minlength=size * S)
    if dup.max() > 1:
        order = np.argsort(cell, kind="stable")
        cs = cell[order]
        p = int(np.flatnonzero(cs[1:] == cs[:-1])[0])
        i, j = int(order[p]), int(order[p + 1])
        raise s.error(f"sensor {sensor[j]} listed twice for {msc.where(sc.run[j], scan[j])} (data rows {s.row(i)} and "
                      f"{s.row(j)}; duplicated (run, time, sensor))")
    missing = dup.reshape(size, S) == 0
    if missing.any():
        c, q = (int(v[0]) for v in np.nonzero(missing))
        r, e = divmod(c, msc.n_scans)
        lacking = "no rows" if missing[c].all() else f"no row for sensor {q}"
        raise s.error(f"{lacking} for {msc.where(r, e)} (every epoch lists sensors 0 … {S - 1})")
    unlisted = (a >= S) | (b >= S)
    if unlisted.any():
        i = int(np.argmax(unlisted))
        raise t.error(f"data row {t.row(i)} names sensor {max(a[i], b[i])}, but the sensors table "
                      f"{Path(str(s.path)).name} lists sensors 0 … {S - 1} (bad sensor index)")
    spec = vocab.VALUES["emitter_sensors"]
    out = {}
    for array, names in (("position_m", ("x_m", "y_m")), ("velocity_mps", ("vx_mps", "vy_mps"))):
        cols = []
        for n in names:
            v = s.filled(n)
            s.within(n, v, spec[array])
            cols.append(_place(v, cell, size * S).reshape(msc.n_runs, msc.n_scans, S))
        out[array] = np.stack(cols, axis=-1)
    return out


def _colored(t: _Rows) -> SimulatedData:
    t.require(("time_s", "time"), "x_m")
    if t.has("z_m") and not t.has("y_m"):
        raise t.error("column 'z_m' without 'y_m': the axes are x, y, z in order")
    axes = [a for a in AXES if t.has(f"{a}_m")]
    for a in AXES:
        if a not in axes and any(t.has(n) for n in (f"truth_{a}_m", f"truth_v{a}_mps", f"truth_a{a}_mps2",
                                                    f"truth_alpha_{a}")):
            raise t.error(f"truth columns for the axis {a} but no '{a}_m' measurements")
    sc = _scans(t)
    per = np.bincount(sc.key, minlength=sc.n_runs * sc.n_scans)
    if per.max() > 1:
        order = np.argsort(sc.key, kind="stable")
        ks = sc.key[order]
        p = int(np.flatnonzero(ks[1:] == ks[:-1])[0])
        i, j = int(order[p]), int(order[p + 1])
        raise t.error(f"{sc.where(sc.run[j], sc.scan[j])} on data rows {t.row(i)} and {t.row(j)}: one row per run "
                      "and time (duplicated time)")
    _require_every_scan(t, sc, per, "every run has a row at every time")
    shape = (sc.n_runs, sc.n_scans)
    order = sc.key  # one row per (run, scan)
    spec = vocab.VALUES["colored_measurements"]["position_m"]

    def grid(values):
        out = np.empty(sc.n_runs * sc.n_scans)
        out[order] = values
        return out.reshape(shape)

    z = []
    for a in axes:
        v = t.filled(f"{a}_m")
        t.within(f"{a}_m", v, spec)
        z.append(grid(v))
    data = SimulatedData(times=sc.times, fixed={_COLORED: {"position_m": np.stack(z, axis=-1)}})
    _require_min_scans(t, sc, "colored-position")
    dt = np.diff(sc.times)
    if not (dt[0] > 0 and np.all(np.abs(dt - dt[0]) <= 1e-9 * max(abs(dt[0]), 1.0))):
        k = int(np.argmax(np.abs(dt - dt[0]) > 1e-9 * max(abs(dt[0]), 1.0)))
        raise t.error(f"the times are not evenly spaced: step {_n(dt[k])} s after {_n(sc.times[k])} s, but "
                      f"{_n(dt[0])} s at first (the filters step at one period)")
    groups = [(f"truth_{a}_m", f"truth_v{a}_mps", f"truth_a{a}_mps2") for a in axes]
    given = [_group_of(t, g, f"the axis {a}'s truth") for a, g in zip(axes, groups)]
    alphas = [f"truth_alpha_{a}" for a in axes]
    have_alpha = [t.has(n) for n in alphas]
    if any(given) and not all(given):
        raise t.error(f"truth for the axis {axes[given.index(False)]} is missing: give the truth of every axis or "
                      "of none")
    if any(have_alpha) and not all(given):
        raise t.error("truth_alpha columns need the truth state columns (truth_<axis>_m, truth_v<axis>_mps, "
                      "truth_a<axis>_mps2)")
    if all(given):
        tspec = vocab.VALUES["colored_truth"]
        cols = []
        for g in groups:
            for n in g:
                v = t.filled(n)
                t.within(n, v, tspec["state"])
                cols.append(grid(v))
        truth = {"state": np.stack(cols, axis=-1)}
        if any(have_alpha):
            if not all(have_alpha):
                raise t.error(f"missing column {alphas[have_alpha.index(False)]!r}: the AR coefficient of every axis "
                              "or of none")
            cols = []
            for n in alphas:
                v = t.filled(n)
                t.within(n, v, tspec["alpha"])
                cols.append(grid(v))
            truth["alpha"] = np.stack(cols, axis=-1)
        data.fixed[_COLORED_TRUTH] = truth
    return data


def dataset_from_table(family: str, rows: pl.DataFrame, path, sensors: pl.DataFrame | None = None,
                       sensors_path=None) -> SimulatedData:
    """Validate a table of ``family`` and build the family's channels.

    Parameters
    ----------
    family : str
        ``radar-plots``, ``bearing-peaks``, ``tdoa-fdoa`` or ``colored-position``.
    rows : polars.DataFrame
        The measurements table (:data:`TABLE_FORMATS`); columns may be numbers or text to parse.
    path : str or Path
        The file the rows came from (named in every message).
    sensors : polars.DataFrame, optional
        The sensors table (tdoa-fdoa only, required there).
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
    _check_family(family)
    t = _Rows(rows, path, family, _known_names(family), (_PEAK_TRUTH, _PEAK_RATE) if family == "bearing-peaks" else ())
    if family != "tdoa-fdoa" and sensors is not None:
        raise InputError(f"a {family} table has no sensors table", sensors_path or path)
    if family == "radar-plots":
        return _radar(t)
    if family == "bearing-peaks":
        return _peaks(t)
    if family == "colored-position":
        return _colored(t)
    s = None if sensors is None else _Rows(sensors, sensors_path if sensors_path is not None else path, family,
                                          _known_names(family, "sensors table"), what="sensors table")
    return _emitter(t, s)


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
    of the family (:data:`trackreplay.sensor_values.SENSOR_KEYS`, e.g. a multi-target radar's
    clutter) a number. Anything else is refused, naming the known values."""
    from trackreplay.sensor_values import SENSOR_KEYS
    from trackreplay.recorders.scenarios import coerce, load_scenario

    defaults = load_scenario(scenario_of(family)).params
    out = {}
    for key, raw in given.items():
        if key in defaults:
            out[key] = coerce(key, raw, defaults[key])
        elif key in SENSOR_KEYS.get(family, ()):
            out[key] = coerce(key, raw, 0.0)
        else:
            known = ", ".join(sorted(set(defaults) | set(SENSOR_KEYS.get(family, ()))))
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
    (``docs/importers.md``, "Sensor values"). A tdoa-fdoa table without prior columns records
    ``initial_guess = "grid"`` (the replay then starts Gauss-Newton from a coarse grid search)
    unless the user says otherwise.

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
    if family == "tdoa-fdoa" and data is not None and _PRIOR not in data.fixed and "initial_guess" not in params:
        params["initial_guess"] = "grid"
        sources["initial_guess"] = sv.DATA
        notes.append("no prior columns: recorded initial_guess=grid (Gauss-Newton starts from a coarse grid search)")
    if data is not None:
        times = np.asarray(data.times, dtype=float)
        facts = {"n_runs": int(data.n_runs), "n_scans": int(times.size),
                 "time_span_s": float(times[-1] - times[0]) if times.size else 0.0}
        params.update(facts)
        sources.update(dict.fromkeys(facts, sv.DATA))
    return params, notes, sources


def sensor_summary(family: str, params: dict, sources: dict) -> str:
    """One line saying which sensor values a converted data set records and which it leaves
    unknown (:data:`trackreplay.sensor_values.SENSOR_KEYS`), for the converters to print."""
    from trackreplay.sensor_values import ESTIMABLE, SENSOR_KEYS

    keys = SENSOR_KEYS.get(family, ())
    if not keys:
        return f"sensor values: in the measurements ({family} carries its noise and geometry per item)"
    given = [(f"{k}={params[k]:g}" if isinstance(params[k], float) else f"{k}={params[k]}") + f" ({sources.get(k, '?')})"
             for k in keys if k in params]
    estimated = [k for k in keys if k not in params and k in ESTIMABLE.get(family, {})]
    unknown = [k for k in keys if k not in params and k not in estimated]
    parts = [f"given {', '.join(given)}"] if given else []
    if estimated:
        parts.append(f"estimated at replay from the data: {', '.join(estimated)}")
    if unknown:
        parts.append(f"unknown: {', '.join(unknown)} (a tracker that needs one asks for --set NAME=VALUE)")
    return "sensor values: " + "; ".join(parts)


def check_peak_field(data: SimulatedData, params: dict, path) -> None:
    """Refuse peaks outside the sensor's field (``field_min_deg`` … ``field_max_deg`` of
    ``params``), which the replay would refuse, naming the first peak with its run and time
    (``data``'s own times)."""
    arrays, counts = data.ragged[_PEAKS]
    # an unknown field is the whole of what a bearing θ = arccos(C·D/d) can be (the stage's too)
    lo, hi = float(params.get("field_min_deg", 0.0)), float(params.get("field_max_deg", 180.0))
    b = arrays["bearing_rad"]
    have = np.arange(b.shape[2]) < counts[..., None]
    outside = have & ((b < np.deg2rad(lo) - 1e-12) | (b > np.deg2rad(hi) + 1e-12))
    if outside.any():
        r, k, j = (int(v[0]) for v in np.nonzero(outside))
        raise InputError(f"peak bearing {np.rad2deg(b[r, k, j]):.6g}° (run {r}, time {_n(data.times[k])} s) lies "
                         f"outside the sensor's field [{lo:g}°, {hi:g}°] the replay uses; give the field with --set "
                         "field_min_deg=… --set field_max_deg=…", path)


def write_imported(family: str, data: SimulatedData, dst, overrides, scenario: str, source: dict, path,
                   mapped: dict | None = None):
    """Write an imported data set: the one way a table or a foreign recording becomes one.

    It records what the user gave (``overrides`` from ``--set``, ``mapped`` from a mapping
    file) and what the data hold (:func:`table_parameters`), ``source`` (the input files'
    names) and the first time ``first_time_s`` (scan times start at 0: MCAP log times are
    unsigned), marks the record a recording with the source of every value
    (:mod:`trackreplay.sensor_values`), and refuses peaks outside the sensor's field
    (:func:`check_peak_field`, naming ``path``). Written atomically.

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
    if family == "bearing-peaks":
        check_peak_field(data, params, path)
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
    if family == "tdoa-fdoa":
        if sensors_src is None:
            raise InputError("a tdoa-fdoa table needs its sensors table (--sensors SENSORS)", src)
        sensors = read_table(sensors_src)
    elif sensors_src is not None:
        raise InputError(f"--sensors belongs to tdoa-fdoa tables, not to {fmt.command}", sensors_src)
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


# --------------------------------------------------------------------------- exporting


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


def _export_radar(dataset) -> dict:
    ch = dataset.channel(_PLOTS)
    rng, counts = ch.ragged("range_m")
    brg, _ = ch.ragged("bearing_rad")
    times = _times(dataset, ch)
    run, scan, slot, item = _frames_to_rows(counts)
    cols = [pl.Series("run", run, pl.Int64), pl.Series("time_s", times[scan], pl.Float64),
            _series("range_m", _ragged_column(rng, run, scan, slot, item), item),
            _series("bearing_rad", _ragged_column(brg, run, scan, slot, item), item)]
    if _RADAR_TRUTH in dataset.channels:
        state = _fixed_grid(dataset, _RADAR_TRUTH, "state", counts.shape, (4,))
        cols += [pl.Series(n, state[run, scan, j], pl.Float64) for j, n in enumerate(_TRUTH_XY)]
    return {"measurements": pl.DataFrame(cols)}


def _export_peaks(dataset) -> dict:
    ch = dataset.channel(_PEAKS)
    brg, counts = ch.ragged("bearing_rad")
    amp, _ = ch.ragged("amplitude")
    times = _times(dataset, ch)
    run, scan, slot, item = _frames_to_rows(counts)
    cols = [pl.Series("run", run, pl.Int64), pl.Series("time_s", times[scan], pl.Float64),
            _series("bearing_rad", _ragged_column(brg, run, scan, slot, item), item),
            _series("amplitude", _ragged_column(amp, run, scan, slot, item), item)]
    if "origin" in ch.arrays:
        origin, _ = ch.ragged("origin")
        o = _ragged_column(origin, run, scan, slot, item)
        cols.append(_series("origin", np.where(item, o, 0).astype(np.int64), item, pl.Int64))
    truth = dataset.channels.get(_XCORR_TRUTH)
    if truth is not None and "bearing_rad" in truth.arrays:
        b = _fixed_grid(dataset, _XCORR_TRUTH, "bearing_rad", counts.shape)
        if b.ndim != 3:
            raise InputError(f"{_XCORR_TRUTH} bearing_rad must hold one bearing per target", dataset.path)
        cols += [pl.Series(f"truth{j}_bearing_rad", b[run, scan, j], pl.Float64) for j in range(b.shape[2])]
        if "bearing_rate_radps" in truth.arrays:
            rate = _fixed_grid(dataset, _XCORR_TRUTH, "bearing_rate_radps", counts.shape, b.shape[2:])
            cols += [pl.Series(f"truth{j}_bearing_rate_radps", rate[run, scan, j], pl.Float64)
                     for j in range(b.shape[2])]
    return {"measurements": pl.DataFrame(cols)}


def _export_emitter(dataset) -> dict:
    ch = dataset.channel(_MEAS)
    shape = (ch.n_runs, ch.n_scans)
    times = _times(dataset, ch)
    pairs_all = _fixed_grid(dataset, _MEAS, "pairs", shape)
    if pairs_all.ndim != 4 or pairs_all.shape[3] != 2:
        raise InputError(f"{_MEAS} pairs must be (P, 2) per frame", dataset.path)
    pairs = pairs_all[0, 0].astype(np.int64)
    if np.any(pairs_all != pairs):
        raise InputError(f"{_MEAS} pairs change between frames: a table lists one pair list", dataset.path)
    P = pairs.shape[0]
    values = {n: _fixed_grid(dataset, _MEAS, n, shape, (P,))
              for n in ("tdoa_s", "fdoa_hz", "sigma_tdoa_s", "sigma_fdoa_hz")}
    carrier = _fixed_grid(dataset, _MEAS, "carrier_hz", shape, ())
    R, K = shape
    run = np.repeat(np.arange(R), K * P)
    scan = np.tile(np.repeat(np.arange(K), P), R)
    q = np.tile(np.arange(P), R * K)
    cols = [pl.Series("run", run, pl.Int64), pl.Series("time_s", times[scan], pl.Float64),
            pl.Series("sensor_a", pairs[q, 0], pl.Int64), pl.Series("sensor_b", pairs[q, 1], pl.Int64)]
    cols += [pl.Series(n, v[run, scan, q], pl.Float64) for n, v in values.items()]
    cols.append(pl.Series("carrier_hz", carrier[run, scan], pl.Float64))
    for names, topic in ((_TRUTH_XY, _EMITTER_TRUTH), (_PRIOR_XY, _PRIOR)):
        if topic in dataset.channels:
            state = _fixed_grid(dataset, topic, "state", shape, (4,))
            cols += [pl.Series(n, state[run, scan, j], pl.Float64) for j, n in enumerate(names)]
    pos = _fixed_grid(dataset, _SENSORS, "position_m", shape)
    if pos.ndim != 4 or pos.shape[3] != 2:
        raise InputError(f"{_SENSORS} position_m must be (S, 2) per frame", dataset.path)
    vel = _fixed_grid(dataset, _SENSORS, "velocity_mps", shape, pos.shape[2:])
    S = pos.shape[2]
    srun = np.repeat(np.arange(R), K * S)
    sscan = np.tile(np.repeat(np.arange(K), S), R)
    sensor = np.tile(np.arange(S), R * K)
    sensors = pl.DataFrame([pl.Series("run", srun, pl.Int64), pl.Series("time_s", times[sscan], pl.Float64),
                            pl.Series("sensor", sensor, pl.Int64),
                            pl.Series("x_m", pos[srun, sscan, sensor, 0], pl.Float64),
                            pl.Series("y_m", pos[srun, sscan, sensor, 1], pl.Float64),
                            pl.Series("vx_mps", vel[srun, sscan, sensor, 0], pl.Float64),
                            pl.Series("vy_mps", vel[srun, sscan, sensor, 1], pl.Float64)])
    return {"measurements": pl.DataFrame(cols), "sensors": sensors}


def _export_colored(dataset) -> dict:
    ch = dataset.channel(_COLORED)
    shape = (ch.n_runs, ch.n_scans)
    z = _fixed_grid(dataset, _COLORED, "position_m", shape)
    if z.ndim == 2:
        z = z[..., None]
    if z.ndim != 3 or not 1 <= z.shape[2] <= len(AXES):
        raise InputError(f"{_COLORED} position_m must hold 1 to {len(AXES)} axes per frame for a table", dataset.path)
    axes = AXES[: z.shape[2]]
    times = _times(dataset, ch)
    R, K = shape
    run, scan = np.repeat(np.arange(R), K), np.tile(np.arange(K), R)
    cols = [pl.Series("run", run, pl.Int64), pl.Series("time_s", times[scan], pl.Float64)]
    cols += [pl.Series(f"{a}_m", z[run, scan, j], pl.Float64) for j, a in enumerate(axes)]
    truth = dataset.channels.get(_COLORED_TRUTH)
    if truth is not None and "state" in truth.arrays:
        state = _fixed_grid(dataset, _COLORED_TRUTH, "state", shape, (3 * len(axes),))
        for j, a in enumerate(axes):
            for c, n in enumerate((f"truth_{a}_m", f"truth_v{a}_mps", f"truth_a{a}_mps2")):
                cols.append(pl.Series(n, state[run, scan, 3 * j + c], pl.Float64))
        if "alpha" in truth.arrays:
            alpha = _fixed_grid(dataset, _COLORED_TRUTH, "alpha", shape)
            if alpha.ndim == 2:
                alpha = alpha[..., None]
            if alpha.shape[2:] != (len(axes),):
                raise InputError(f"{_COLORED_TRUTH} alpha has frames of shape {alpha.shape[2:]}, expected "
                                 f"({len(axes)},)", dataset.path)
            cols += [pl.Series(f"truth_alpha_{a}", alpha[run, scan, j], pl.Float64) for j, a in enumerate(axes)]
    return {"measurements": pl.DataFrame(cols)}


_EXPORTERS = {"radar-plots": _export_radar, "bearing-peaks": _export_peaks, "tdoa-fdoa": _export_emitter,
              "colored-position": _export_colored}


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
        ``{"measurements": DataFrame}``, plus ``"sensors"`` for tdoa-fdoa. Angles are in
        radians; times are the data set's scan times plus its recorded ``first_time_s``.

    Raises
    ------
    InputError
        The data set lacks the family's channels, or holds what a table cannot (truth with
        gaps, pairs that change between epochs, more than three position axes).
    """
    from trackreplay.contract import read_dataset

    _check_family(family)
    if isinstance(dataset, (str, Path)):
        dataset = read_dataset(dataset)
    missing = [c for c in vocab.FAMILIES[family].inputs if c not in dataset.channels]
    if missing:
        raise InputError(f"no {family} channels ({', '.join(missing)} missing)", dataset.path)
    return _EXPORTERS[family](dataset)


def exportable_families(dataset) -> tuple[list[str], list[str]]:
    """Families of a data set with a table format, and those present without one."""
    have = [f for f, fam in vocab.FAMILIES.items() if all(c in dataset.channels for c in fam.inputs)]
    return [f for f in have if f in TABLE_FORMATS], [f for f in have if f not in TABLE_FORMATS]


def table_file_names(family: str, suffix: str) -> dict[str, str]:
    """File names ``replay export --table`` gives a family's tables (keys as in
    :func:`tables_from_dataset`)."""
    stem = _check_family(family).stem
    names = {"measurements": f"{stem}.{suffix}"}
    if "sensors" in TABLE_FORMATS[family].tables:
        names["sensors"] = f"{stem}_sensors.{suffix}"
    return names


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
