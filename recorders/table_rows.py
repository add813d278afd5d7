"""Reading a table file (CSV or Parquet) and validating its rows: the rules every family's
table follows (``docs/importers.md``, "Tables of measurements"), one
:class:`~trackreplay.errors.InputError` naming the file and the first row at fault.

* :func:`read_table` reads a ``.csv`` or ``.parquet`` file into a polars DataFrame;
* :class:`_Rows` holds a table being validated and turns its columns into numbers (empty cells,
  text, NaN and ±Inf refused; angles in ``_deg`` converted to radians; values within the
  contract's bounds, ``trackreplay.vocabulary.VALUES``);
* :func:`_scans` numbers the runs and scans; :func:`_per_scan`, :func:`_ragged` and
  :func:`_markers` build the arrays of values a scan shares, of items (plots, peaks) and of
  scans without items.

Each family's own rules, its reader, are in its module (the ``read`` of its
:class:`~trackreplay.recorders.table_formats.TableFormat`, :data:`~trackreplay.recorders.table_formats.TABLE_MODULES`),
with its columns.
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import polars as pl

from trackreplay import vocabulary as vocab
from trackreplay.errors import InputError

MAX_RUNS = 1 << 24  # the contract's bound on a run index


# --------------------------------------------------------------------------- reading files


def read_table(path) -> pl.DataFrame:
    """Read a table from a ``.csv`` or ``.parquet`` file (chosen by the suffix).

    CSV columns are typed from every row (a column with one word in it stays text, and
    :func:`~trackreplay.recorders.tables.dataset_from_table` names the row); floats are parsed
    exactly, so a table written by polars gives back the same numbers.

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

    def __init__(self, rows: pl.DataFrame, path, fmt, what: str = "table"):
        """``fmt``: the family's :class:`~trackreplay.recorders.table_formats.TableFormat`, whose
        columns (of its sensors table when ``what`` is ``"sensors table"``) are the known ones."""
        if not isinstance(rows, pl.DataFrame):
            raise TypeError(f"rows must be a polars DataFrame, got {type(rows).__name__}")
        self.path = path
        self.fmt = fmt
        self.family = fmt.family
        self.what = what
        self.table = "sensors" if what == "sensors table" else "measurements"
        stripped = [c.strip() for c in rows.columns]
        if stripped != rows.columns and len(set(stripped)) == len(stripped):  # " range_m" after a comma and space
            rows = rows.rename(dict(zip(rows.columns, stripped)))
        self.df = rows
        self.n = rows.height
        self.known = fmt.literal_names(self.table)
        # columns numbered per target (truth0_bearing_rad, …) are matched by pattern
        self.patterns = fmt.name_patterns if self.table == "measurements" else ()

    def error(self, problem: str) -> InputError:
        return InputError(problem, self.path)

    def has(self, name: str) -> bool:
        return name in self.df.columns

    def require(self, *groups) -> None:
        """Check the header and that there are rows: each group is a required name or a tuple of
        alternatives (every missing one is named at once); then no unknown column, which may be
        a typo that would drop what it holds (truth, origin) without a word."""
        unknown = [c for c in self.df.columns if c not in self.known and not any(p.match(c) for p in self.patterns)]
        has = f"a {self.family} {self.what} has: {', '.join(self.fmt.shown_names(self.table))}"
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


def _require_min_scans(t: _Rows, sc: _Scans) -> None:
    need = t.fmt.min_scans
    if sc.n_scans < need:
        raise t.error(f"{sc.n_scans} scan time(s); the {t.family} trackers need at least {need}")


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
