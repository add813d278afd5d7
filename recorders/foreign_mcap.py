"""Importer: an MCAP recorded by another tool (ROS 2, JSON or protobuf messages) → a data set.

A small TOML *mapping file* says which topic holds the measurements, where each message keeps
its time, which list field holds the items of a message (one row per item), and which field and
unit give each column of the family's canonical table (``trackreplay.recorders.tables.TABLE_FORMATS``)::

    family = "radar-plots"

    [measurements]
    topic = "/radar/scan"
    time = "header.stamp"          # or "log_time", or { field = "t_ms", unit = "ms" }
    items = "returns"              # optional: one row per element of this list
    range_m = { field = "range", unit = "km" }
    bearing_rad = { field = "azimuth", unit = "deg" }
    run = "/run_id"                # optional; "/" starts at the message, not the item

A radar-plots mapping may add a ``[truth]`` table (the same keys; columns ``truth_id`` and the
four truth columns, optionally ``run``): a truth list of many targets, one truth-only row of the
plots table per target, matched to the plots message of the same time (within
:data:`SAME_SCAN_S`; a time no plots message has is a scan without plots). For radar plots and
peaks, a message whose item list is empty still makes its scan (a row with the measurement
empty, see :class:`_Collector`).

The messages are decoded by the MCAP ecosystem's decoders chosen by the channel's encoding
(``cdr`` with a ``ros2msg`` schema: ``mcap_ros2``; ``protobuf``: ``mcap_protobuf``; ``json``: the
standard library, a whole batch of messages in one call), their fields gathered column by column
into numpy arrays, converted to SI and handed to :func:`trackreplay.recorders.tables.dataset_from_table`,
which validates them as it validates a CSV. What is checked here is only what is specific to a
foreign MCAP: the topic, the field paths, that a field holds a number, the units and the time.
"""

from __future__ import annotations

import itertools
import json
import math
import re
import struct
import tomllib
from dataclasses import dataclass, field
from operator import attrgetter, itemgetter
from pathlib import Path

import numpy as np

from trackreplay.errors import InputError

# --------------------------------------------------------------------------- units

# unit → (dimension, factor to the SI unit of that dimension); SI inside, everything else at
# this boundary only
UNITS = {
    "m": ("length", 1.0), "km": ("length", 1e3), "cm": ("length", 1e-2), "mm": ("length", 1e-3),
    "ft": ("length", 0.3048), "nmi": ("length", 1852.0), "mi": ("length", 1609.344),
    "rad": ("angle", 1.0), "mrad": ("angle", 1e-3), "deg": ("angle", math.pi / 180.0),
    "s": ("time", 1.0), "ms": ("time", 1e-3), "us": ("time", 1e-6), "ns": ("time", 1e-9),
    "Hz": ("frequency", 1.0), "kHz": ("frequency", 1e3), "MHz": ("frequency", 1e6), "GHz": ("frequency", 1e9),
    "m/s": ("speed", 1.0), "km/h": ("speed", 1.0 / 3.6), "kn": ("speed", 1852.0 / 3600.0), "ft/s": ("speed", 0.3048),
    "m/s2": ("acceleration", 1.0), "ft/s2": ("acceleration", 0.3048), "g": ("acceleration", 9.80665),
    "rad/s": ("angular rate", 1.0), "deg/s": ("angular rate", math.pi / 180.0),
    "1": ("number", 1.0),
}
# a canonical column's unit, from the end of its name
_SUFFIX_UNITS = (("_mps2", "m/s2"), ("_mps", "m/s"), ("_radps", "rad/s"), ("_degps", "deg/s"), ("_hz", "Hz"),
                 ("_rad", "rad"), ("_deg", "deg"), ("_m", "m"), ("_s", "s"))


def column_unit(column: str) -> str:
    """The unit of a canonical table column (``range_m`` → ``m``; ``amplitude`` → ``1``)."""
    for suffix, unit in _SUFFIX_UNITS:
        if column.endswith(suffix):
            return unit
    return "1"


def unit_factor(unit: str, column: str, where: str, path) -> float:
    """The factor that turns values in ``unit`` into the unit of ``column`` (refuses a unit
    that is not known or measures something else)."""
    if unit not in UNITS:
        raise InputError(f"{where}: unit {unit!r} is not known (known: {', '.join(UNITS)})", path)
    target = column_unit(column)
    (dim, f), (tdim, tf) = UNITS[unit], UNITS[target]
    if dim != tdim:
        raise InputError(f"{where}: unit {unit!r} measures {dim}, but {column} is a {tdim}"
                         f"{'' if tdim == 'number' else f' in {target}'}", path)
    return f / tf


# --------------------------------------------------------------------------- field paths

_PATH = re.compile(r"[A-Za-z_][A-Za-z0-9_]*(\[\d+\])*(\.[A-Za-z_][A-Za-z0-9_]*(\[\d+\])*)*")
_STEP = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)|\[(\d+)\]")


@dataclass(frozen=True)
class FieldPath:
    """A dotted field path with list indices (``returns[0].range``), from the item or, with a
    leading ``/``, from the message."""

    text: str
    steps: tuple  # str (a field name) or int (a list index)
    from_message: bool

    @classmethod
    def parse(cls, text, where: str, path) -> "FieldPath":
        if not isinstance(text, str):
            raise InputError(f"{where}: a field path is text such as \"header.stamp\", not {text!r}", path)
        body = text[1:] if text.startswith("/") else text
        if not _PATH.fullmatch(body):
            raise InputError(f"{where}: {text!r} is not a field path (names joined by dots, list indices "
                             "in brackets: returns[0].range)", path)
        steps = tuple(m.group(1) if m.group(1) else int(m.group(2)) for m in _STEP.finditer(body))
        return cls(text, steps, text.startswith("/"))

    def getter(self, by_key: bool):
        """One callable for the whole path: attribute access for decoded ROS 2 and protobuf
        messages (consecutive names in one C-level ``attrgetter``), keys for JSON."""
        parts, names = [], []
        for step in self.steps:
            if isinstance(step, str) and not by_key:
                names.append(step)
                continue
            if names:
                parts.append(attrgetter(".".join(names)))
                names = []
            parts.append(itemgetter(step))
        if names:
            parts.append(attrgetter(".".join(names)))
        if len(parts) == 1:
            return parts[0]
        if len(parts) == 2:
            a, b = parts
            return lambda x: b(a(x))

        def get(x):
            for p in parts:
                x = p(x)
            return x
        return get


_MISSING = (AttributeError, KeyError, IndexError, TypeError)


def _fields_of(obj) -> list[str]:
    if isinstance(obj, dict):
        return [str(k) for k in obj]
    descriptor = getattr(obj, "DESCRIPTOR", None)
    if descriptor is not None and hasattr(descriptor, "fields"):
        return [f.name for f in descriptor.fields]
    slots = getattr(type(obj), "__slots__", None)
    if slots:
        return list(slots)
    return sorted(k for k in getattr(obj, "__dict__", {}) if not k.startswith("_"))


def _kind(obj) -> str:
    if isinstance(obj, bool):
        return "a boolean"
    if obj is None:
        return "null"
    if isinstance(obj, (int, float)):
        return "a number"
    if isinstance(obj, str):
        return "text"
    if isinstance(obj, dict) or _fields_of(obj):
        return "a message"
    if _is_list(obj):
        return f"a list of {len(obj)}"
    return type(obj).__name__


def _explain_missing(root, fp: FieldPath, shown: str, root_name: str = "the message") -> str:
    """Why ``fp`` does not resolve on ``root``: the step that fails and what is there instead."""
    obj, done = root, ""
    for step in fp.steps:
        here = f"{done}.{step}" if isinstance(step, str) and done else (step if isinstance(step, str) else f"{done}[{step}]")
        if isinstance(step, int):
            if not _is_list(obj):
                return f"field {shown!r}: {done or root_name} is {_kind(obj)}, not a list"
            if step >= len(obj):
                return f"field {shown!r}: index {step} is beyond the list {done} (length {len(obj)})"
            obj = obj[step]
        else:
            names = _fields_of(obj)
            if step not in names:
                where = f"in {done}" if done else f"in {root_name}"
                if not names:
                    return f"field {shown!r}: {done or root_name} is {_kind(obj)}, it has no field {step!r}"
                return f"field {shown!r}: no field {step!r} {where} (it has: {', '.join(names)})"
            obj = obj[step] if isinstance(obj, dict) else getattr(obj, step)
        done = here
    return f"field {shown!r} does not resolve"


def _is_list(obj) -> bool:
    return (not isinstance(obj, (str, bytes, dict)) and hasattr(obj, "__len__") and hasattr(obj, "__getitem__")
            and not _fields_of(obj))


# --------------------------------------------------------------------------- the mapping file

TABLE_KEYS = ("topic", "time", "items")
TIME_COLUMN = "time_s"
# [truth]: a list of targets with identities per message (many targets), for the radar family;
# its rows are truth-only rows of the plots table (range and bearing empty)
TRUTH_TABLE = "truth"
TRUTH_FAMILIES = ("radar-plots",)
# the optional table of values the recording's sensor had (its noise, scan period, …), recorded
# with the source "mapping file" (trackreplay.sensor_values); what it does not say stays unknown
SENSOR_TABLE = "sensor"
TRUTH_COLUMNS = ("truth_id", "truth_x_m", "truth_y_m", "truth_vx_mps", "truth_vy_mps")
# families whose message with an empty item list is still a scan (a row with these columns
# empty marks a scan without plots, or peaks)
EMPTY_SCAN_COLUMNS = {"radar-plots": ("range_m", "bearing_rad", "bearing_deg"),
                      "bearing-peaks": ("bearing_rad", "bearing_deg", "amplitude", "origin")}
# a truth time this close to a plots message's time is that scan's time (the same instant,
# written in another form: a stamp here, milliseconds there)
SAME_SCAN_S = 1e-6


@dataclass(frozen=True)
class ColumnSpec:
    """One canonical column: a field (with a factor to the column's unit) or a constant."""

    name: str
    field: FieldPath | None
    factor: float = 1.0
    value: float | None = None


@dataclass(frozen=True)
class TableSpec:
    """How one input table (``measurements`` or ``sensors``) is read from one topic."""

    table: str
    topic: str
    time: FieldPath | None  # None: the message's log time
    time_factor: float
    items: FieldPath | None
    columns: tuple


@dataclass(frozen=True)
class Mapping:
    """A parsed mapping file: the family and one :class:`TableSpec` per input table."""

    family: str
    tables: dict
    path: Path = field(compare=False)
    sensor: dict = field(default_factory=dict)  # the [sensor] table: values of the recording's sensor


def _formats() -> dict:
    from trackreplay.recorders.tables import TABLE_FORMATS

    return TABLE_FORMATS


def _table_columns(family: str, table: str) -> list:
    """Every column name the family's ``table`` accepts, as regular expressions read from
    ``TABLE_FORMATS`` (``truth<t>_bearing_rad`` stands for ``truth0_bearing_rad``, …)."""
    if table == TRUTH_TABLE:
        return [re.compile(re.escape(c) + "$") for c in ("run", *TRUTH_COLUMNS)]
    out = []
    for col in _formats()[family].tables[table]:
        for name in col.name.split("|"):
            pattern = re.escape(name.strip()).replace(re.escape("<axis>"), "[xyz]")
            out.append(re.compile(re.sub(re.escape("<") + r"\w+" + re.escape(">"), r"\\d+", pattern) + "$"))
    return out


def _column_names(family: str, table: str) -> list[str]:
    if table == TRUTH_TABLE:
        return ["run", *TRUTH_COLUMNS]
    return [c.name.replace(" | ", "|") for c in _formats()[family].tables[table]]


def _tables_of(family: str) -> tuple[str, ...]:
    return tuple(_formats()[family].tables)


def load_mapping(path: str | Path) -> Mapping:
    """Read and check a mapping file.

    Parameters
    ----------
    path : str or Path
        The TOML mapping file.

    Returns
    -------
    Mapping
        The family and, per input table, the topic, time source, item list and columns.

    Raises
    ------
    InputError
        A missing or unreadable file, text that is not TOML, a missing or unknown key, an
        unknown family or column, a field path that is not one, a unit that is not known or
        measures something else than its column.
    """
    path = Path(path)
    if not path.exists():
        raise InputError("no such file", path)
    if path.is_dir():
        raise InputError("is a folder, not a mapping file", path)
    try:
        doc = tomllib.loads(path.read_bytes().decode("utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"not a TOML mapping file ({exc})", path) from None
    formats = _formats()
    family = doc.get("family")
    if family is None:
        raise InputError(f"missing key 'family' (one of: {', '.join(formats)})", path)
    if family not in formats:
        raise InputError(f"family {family!r} has no table format (have: {', '.join(formats)})", path)
    tables = _tables_of(family) + ((TRUTH_TABLE,) if family in TRUTH_FAMILIES else ())
    if TRUTH_TABLE in doc and TRUTH_TABLE not in tables:
        raise InputError(f"[truth] (a list of targets with identities) belongs to "
                         f"{' or '.join(TRUTH_FAMILIES)} mappings; a {family} mapping carries its truth in the "
                         "columns of [measurements]", path)
    unknown = [k for k in doc if k not in ("family", SENSOR_TABLE, *tables)]
    if unknown:
        raise InputError(f"unknown key {unknown[0]!r} (a mapping of {family} has: family, "
                         f"{', '.join(f'[{t}]' for t in tables)}, [{SENSOR_TABLE}])", path)
    sensor = doc.get(SENSOR_TABLE, {})
    if not isinstance(sensor, dict) or any(isinstance(v, (dict, list)) for v in sensor.values()):
        raise InputError(f"[{SENSOR_TABLE}] holds one value per name (sigma_range_m = 50), no tables or lists", path)
    if "measurements" not in doc:
        raise InputError("missing table [measurements] (its topic, time and columns)", path)
    specs = {}
    for table in tables:
        if table in doc:
            specs[table] = _table_spec(family, table, doc[table], path)
    if "sensors" in tables and "sensors" not in specs:
        raise InputError(f"missing table [sensors] (a {family} mapping reads the sensors too)", path)
    if TRUTH_TABLE in specs:
        _check_truth_spec(specs, path)
    if sensor:  # names and types checked here, so that a bad value names the mapping file
        from trackreplay.recorders.tables import _given_values

        try:
            _given_values(family, sensor, f"[{SENSOR_TABLE}]")
        except InputError as exc:
            raise InputError(exc.problem, path) from None
    return Mapping(family, specs, path, dict(sensor))


def _check_truth_spec(specs: dict, path) -> None:
    """[truth] gives an identity and the whole state of every target; the truth then comes from
    there alone, and both tables say the run or neither does."""
    have = {c.name for c in specs[TRUTH_TABLE].columns}
    missing = [c for c in TRUTH_COLUMNS if c not in have]
    if missing:
        raise InputError(f"[truth]: missing column(s) {', '.join(missing)} (each target of a truth list gives "
                         f"{', '.join(TRUTH_COLUMNS)})", path)
    meas = {c.name for c in specs["measurements"].columns}
    twice = [c for c in TRUTH_COLUMNS if c in meas]
    if twice:
        raise InputError(f"[measurements] {twice[0]}: with a [truth] table the truth comes from there alone (map it "
                         "in [truth])", path)
    if ("run" in meas) != ("run" in have):
        one, other = ("measurements", "truth") if "run" in meas else ("truth", "measurements")
        raise InputError(f"[{one}] maps run but [{other}] does not: map the run in both tables or in neither", path)


def _table_spec(family: str, table: str, doc, path) -> TableSpec:
    if not isinstance(doc, dict):
        raise InputError(f"[{table}] must be a table of keys", path)
    for key in ("topic", "time"):
        if key not in doc:
            hint = "the topic to read" if key == "topic" else '"log_time" or a field path such as "header.stamp"'
            raise InputError(f"[{table}]: missing key {key!r} ({hint})", path)
    topic = doc["topic"]
    if not isinstance(topic, str) or not topic:
        raise InputError(f"[{table}]: topic must be a topic name such as \"/radar/scan\"", path)
    time, time_factor = _time_spec(table, doc["time"], path)
    items = None if doc.get("items") is None else FieldPath.parse(doc["items"], f"[{table}] items", path)
    if items is not None and items.from_message:
        items = FieldPath(items.text, items.steps, False)
    allowed = _table_columns(family, table)
    columns = []
    for name, spec in doc.items():
        if name in TABLE_KEYS:
            continue
        where = f"[{table}] {name}"
        if name == TIME_COLUMN:
            raise InputError(f"{where}: the time comes from the key 'time' (\"log_time\" or a field path)", path)
        if not any(p.match(name) for p in allowed):
            shown = [c for c in _column_names(family, table) if not c.startswith("time")]
            raise InputError(f"[{table}]: {name!r} is not a column of the {family} {table} table (columns: "
                             f"{', '.join(shown)})", path)
        columns.append(_column_spec(name, spec, where, path))
    if not columns:
        raise InputError(f"[{table}]: no columns (give each column a field, e.g. range_m = "
                         "{ field = \"range\", unit = \"m\" })", path)
    return TableSpec(table, topic, time, time_factor, items, tuple(columns))


def _time_spec(table: str, spec, path):
    where = f"[{table}] time"
    if spec == "log_time":
        return None, 1.0
    if isinstance(spec, dict):
        _only_keys(spec, ("field", "unit"), where, path)
        if "field" not in spec:
            raise InputError(f"{where}: missing key 'field'", path)
        return FieldPath.parse(spec["field"], where, path), unit_factor(spec.get("unit", "s"), TIME_COLUMN, where, path)
    return FieldPath.parse(spec, where, path), 1.0


def _only_keys(spec: dict, keys, where, path) -> None:
    extra = [k for k in spec if k not in keys]
    if extra:
        raise InputError(f"{where}: unknown key {extra[0]!r} (allowed: {', '.join(keys)})", path)


def _column_spec(name: str, spec, where: str, path) -> ColumnSpec:
    if isinstance(spec, str):
        return ColumnSpec(name, FieldPath.parse(spec, where, path))
    if not isinstance(spec, dict):
        raise InputError(f"{where}: give a field path or {{ field = \"...\", unit = \"...\" }}, not {spec!r}", path)
    _only_keys(spec, ("field", "unit", "value"), where, path)
    if ("field" in spec) == ("value" in spec):
        raise InputError(f"{where}: give either 'field' (read from each message) or 'value' (a constant)", path)
    factor = unit_factor(spec.get("unit", column_unit(name)), name, where, path)
    if "value" in spec:
        value = spec["value"]
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise InputError(f"{where}: value must be a number, not {value!r}", path)
        return ColumnSpec(name, None, factor, value)
    return ColumnSpec(name, FieldPath.parse(spec["field"], where, path), factor)


# --------------------------------------------------------------------------- decoding

BATCH = 4096  # messages decoded and gathered at a time: bounded memory, numpy-sized work
# RecursionError: a message nested deeper than the decoders recurse (JSON arrays in arrays, say)
_DECODE_ERRORS = (struct.error, EOFError, ValueError, KeyError, IndexError, OverflowError, TypeError,
                  UnicodeDecodeError, NotImplementedError, AssertionError, RecursionError)
MCAP_MAGIC = b"\x89MCAP0\r\n"


def _decoder_factories():
    from mcap_protobuf.decoder import DecoderFactory as ProtobufDecoders
    from mcap_ros2.decoder import DecoderFactory as Ros2Decoders

    return [Ros2Decoders(), ProtobufDecoders()]


def _data_errors():
    from google.protobuf.message import DecodeError
    from mcap.exceptions import McapError

    return (McapError, DecodeError, *_DECODE_ERRORS)


class _Collector:
    """Gathers one table's rows, batch by batch, as numpy columns."""

    def __init__(self, spec: TableSpec, src: Path, item_columns: tuple = ()):
        self.spec, self.src = spec, src
        self.log_times: list[np.ndarray] = []
        self.times: list[np.ndarray] = []
        self.counts: list[np.ndarray] = []
        self.values: dict[str, list[np.ndarray]] = {c.name: [] for c in spec.columns if c.field is not None}
        self.messages = 0
        self.getters: dict | None = None
        self.stamp = None
        # a message whose item list is empty is still a scan (without plots or peaks) when every
        # other column than the item's own measurement (``item_columns``) comes from the message
        # or is a constant: its row then carries those and leaves the measurement empty
        self.marks_empty = bool(item_columns) and spec.items is not None and all(
            c.name in item_columns or c.field is None or c.field.from_message for c in spec.columns)
        self.item_columns = item_columns
        self.message_values: dict[str, list[np.ndarray]] = {
            c.name: [] for c in spec.columns if self.marks_empty and c.field is not None and c.name not in item_columns}
        self.empty_rows: tuple | None = None  # (message indices, columns) of the empty messages, after frame()
        self.message_times: np.ndarray | None = None  # every message's time (log-time order), after frame()

    def where(self, index: int, log_time: int | None = None) -> str:
        at = "" if log_time is None else f", log time {log_time / 1e9:.9f} s"
        return f"topic {self.spec.topic}, message {index}{at}"

    def _compile(self, by_key: bool) -> None:
        s = self.spec
        self.getters = {c.name: c.field.getter(by_key) for c in s.columns if c.field is not None}
        self.items = None if s.items is None else s.items.getter(by_key)
        self.time = None if s.time is None else s.time.getter(by_key)
        self.by_key = by_key

    def add(self, decoded: list, log_times: list[int], by_key: bool) -> None:
        """Gather the rows of a batch of decoded messages (in file order)."""
        if self.getters is None or by_key != self.by_key:
            self._compile(by_key)
        first = self.messages
        n = len(decoded)
        self.messages += n
        lt = np.asarray(log_times, np.int64)
        self.log_times.append(lt)
        self.times.append(self._times(decoded, lt, first))
        if self.items is None:
            items, counts = decoded, None
        else:
            lists = self._gather(self.items, decoded, self.spec.items, first, decoded)
            for i, v in enumerate(lists):
                if not _is_list(v):
                    raise InputError(f"{self.where(first + i)}: items {self.spec.items.text!r} is {_kind(v)}, not a "
                                     "list", self.src)
            counts = np.fromiter(map(len, lists), np.int64, n)
            items = list(itertools.chain.from_iterable(lists))
        self.counts.append(np.ones(n, np.int64) if counts is None else counts)
        for c in self.spec.columns:
            if c.field is None:
                continue
            if c.field.from_message or self.items is None:
                raw = self._gather(self.getters[c.name], decoded, c.field, first, decoded)
                vals = self._numbers(raw, c, first, None)
                if c.name in self.message_values:
                    self.message_values[c.name].append(vals)
                if counts is not None:
                    vals = np.repeat(vals, counts)
            else:
                raw = self._gather(self.getters[c.name], items, c.field, first, decoded, counts)
                vals = self._numbers(raw, c, first, counts)
            self.values[c.name].append(vals)

    def _gather(self, get, objs: list, fp: FieldPath, first: int, decoded: list, counts=None) -> list:
        try:
            return list(map(get, objs))
        except _MISSING:
            pass
        # the error path: find the first object the path does not resolve on, and say why
        for i, obj in enumerate(objs):
            try:
                get(obj)
            except _MISSING:
                msg = i if counts is None else int(np.searchsorted(np.cumsum(counts), i, side="right"))
                shown = fp.text if (counts is None or self.spec.items is None) else f"{self.spec.items.text}[].{fp.text}"
                root = "the message" if counts is None else f"item {i - int(np.sum(counts[:msg]))} of {self.spec.items.text}"
                raise InputError(f"{self.where(first + msg)}: {_explain_missing(obj, fp, shown, root)}", self.src) from None
        raise AssertionError("unreachable: the path resolved on every object the second time")

    def _numbers(self, raw: list, c: ColumnSpec | None, first: int, counts, what: str | None = None) -> np.ndarray:
        """The values as a float64 or int64 array, each checked to be a number (not text, not
        a boolean, not a message or list), converted by the column's factor."""
        name = what or c.name
        try:
            arr = np.asarray(raw) if raw else np.zeros(0)
        except (ValueError, TypeError):
            arr = np.asarray(raw, dtype=object)
        # JSON is untyped: a boolean among numbers would pass numpy's conversion as 0 or 1
        mixed = self.by_key and arr.dtype.kind in "fiu" and not {float, int}.issuperset(set(map(type, raw)))
        if mixed or arr.ndim != 1 or arr.dtype.kind not in "fiu":
            for i, v in enumerate(raw):
                if isinstance(v, bool) or not isinstance(v, (int, float)):
                    msg = i if counts is None else int(np.searchsorted(np.cumsum(counts), i, side="right"))
                    shown = repr(v) if isinstance(v, str) and len(v) < 40 else _kind(v)
                    raise InputError(f"{self.where(first + msg)}: {name} holds {shown} where a number belongs "
                                     f"(field {c.field.text if c else self.spec.time.text!r})", self.src)
            raise InputError(f"{self.where(first)}: {name} holds numbers beyond 64 bits", self.src)
        factor = 1.0 if c is None else c.factor
        if factor != 1.0:
            arr = arr * factor
        return arr

    def _times(self, decoded: list, lt: np.ndarray, first: int) -> np.ndarray:
        s = self.spec
        if s.time is None:
            return lt * 1e-9
        raw = self._gather(self.time, decoded, s.time, first, decoded)
        if self.stamp is None:
            self.stamp = _stamp_fields(raw[0]) if raw else False
        if self.stamp:
            sec_name, nsec_name = self.stamp
            by_key = self.by_key
            try:
                sec = [v[sec_name] if by_key else getattr(v, sec_name) for v in raw]
                nsec = [v[nsec_name] if by_key else getattr(v, nsec_name) for v in raw]
            except _MISSING:
                for i, v in enumerate(raw):
                    if _stamp_fields(v) != self.stamp:
                        raise InputError(f"{self.where(first + i)}: time {s.time.text!r} is {_kind(v)}, not a stamp "
                                         f"with {sec_name} and {nsec_name}", self.src) from None
                raise
            sec = self._numbers(sec, None, first, None, f"time {s.time.text}.{sec_name}")
            nsec = self._numbers(nsec, None, first, None, f"time {s.time.text}.{nsec_name}")
            return sec + nsec * 1e-9
        for i, v in enumerate(raw[:1]):
            if not isinstance(v, (int, float)) or isinstance(v, bool):
                raise InputError(f"{self.where(first + i)}: time {s.time.text!r} is {_kind(v)}, neither a number nor a "
                                 "stamp (sec and nanosec)", self.src)
        vals = self._numbers(raw, None, first, None, f"time {s.time.text}")
        return vals * s.time_factor

    def frame(self) -> dict:
        """The table as columns (rows in log-time order), ready for ``polars.DataFrame``."""
        s = self.spec
        if self.messages == 0:
            raise InputError(f"topic {s.topic} holds no messages", self.src)
        counts = np.concatenate(self.counts)
        times = np.concatenate(self.times)
        log_times = np.concatenate(self.log_times)
        cols = {name: np.concatenate(parts) for name, parts in self.values.items()}
        msg = np.repeat(np.arange(counts.size), counts)
        per_message = {name: np.concatenate(parts) for name, parts in self.message_values.items()}
        if np.any(np.diff(log_times) < 0):  # MCAP allows messages out of log-time order in the file
            order = np.argsort(log_times, kind="stable")
            rank = np.empty_like(order)
            rank[order] = np.arange(order.size)
            rows = np.argsort(rank[msg], kind="stable")
            cols = {k: v[rows] for k, v in cols.items()}
            msg = rank[msg][rows]
            times, log_times, counts = times[order], log_times[order], counts[order]
            per_message = {k: v[order] for k, v in per_message.items()}
        total = msg.size
        for c in s.columns:
            if c.field is None:
                cols[c.name] = np.full(total, c.value * c.factor if c.factor != 1.0 else c.value)
        check_msg, check_run = msg, cols.get("run")
        if self.marks_empty:
            empty = np.flatnonzero(counts == 0)
            marks = {}
            for c in s.columns:
                if c.name in self.item_columns:
                    continue
                marks[c.name] = (per_message[c.name][empty] if c.field is not None else
                                 np.full(empty.size, c.value * c.factor if c.factor != 1.0 else c.value))
            self.empty_rows = (empty, marks)
            if empty.size:  # an empty message is a scan too: its time must step like the others'
                check_msg = np.concatenate([msg, empty])
                check_run = None if check_run is None else np.concatenate([check_run, marks["run"]])
        self._check_times(times, log_times, check_msg, check_run)
        self.row_message = msg
        self.message_times = times
        first = [c for c in ("run",) if c in cols]
        return {**{c: cols[c] for c in first}, TIME_COLUMN: times[msg], **{k: v for k, v in cols.items() if k not in first}}

    def _check_times(self, times, log_times, msg, run) -> None:
        """Each message is one scan of its run: within a run, times increase from message to
        message (in log-time order); an equal or earlier time is refused."""
        bad = ~np.isfinite(times)
        if bad.any():
            i = int(np.argmax(bad))
            raise InputError(f"{self.where(i, int(log_times[i]))}: time is {times[i]} (not finite)", self.src)
        if msg.size < 2:
            return
        run = np.zeros(msg.size, np.int64) if run is None else run
        order = np.lexsort((msg, run))
        r, m, t = run[order], msg[order], times[msg[order]]
        step = (r[1:] == r[:-1]) & (m[1:] != m[:-1])
        back, same = step & (t[1:] < t[:-1]), step & (t[1:] == t[:-1])
        bad = back | same
        if bad.any():
            hits = np.flatnonzero(bad)
            k = hits[np.argmin(m[hits + 1])]  # the first message (in log-time order) that is out of step
            i, j = int(m[k + 1]), int(m[k])
            kind = "the same as" if t[k + 1] == t[k] else "earlier than"
            run_txt = f" of run {r[k]}" if np.any(run) else ""
            raise InputError(f"{self.where(i, int(log_times[i]))}: time {float(t[k + 1])!r} s is {kind} the time of "
                             f"message {j} ({float(t[k])!r} s){run_txt}; each message is one scan, so times must "
                             "increase",
                             self.src)


def _stamp_fields(v):
    """The (seconds, nanoseconds) field names of a time stamp (ROS 2 ``builtin_interfaces/Time``,
    protobuf ``Timestamp``, or a JSON object of either), or None when ``v`` is not one."""
    names = set(_fields_of(v)) if not isinstance(v, (int, float, str)) else set()
    for pair in (("sec", "nanosec"), ("seconds", "nanos"), ("secs", "nsecs"), ("sec", "nsec")):
        if set(pair) <= names:
            return pair
    return None


@dataclass
class ForeignTables:
    """What :func:`read_foreign_mcap` gathered: the rows of each input table and counts."""

    family: str
    tables: dict  # table -> polars.DataFrame
    messages: dict  # table -> messages read
    row_message: dict  # table -> (rows,) index of the message (in log-time order) each row came from
    # table -> (message indices, {column: values}) of the messages whose item list is empty, for
    # the families where such a message is a scan without plots (or peaks)
    empty_rows: dict = field(default_factory=dict)
    message_times: dict = field(default_factory=dict)  # table -> (messages,) time of every message, s
    notes: list = field(default_factory=list)  # what the user should know (scans without plots, …)


def read_foreign_mcap(src: str | Path, mapping: Mapping) -> ForeignTables:
    """Decode the mapped topics of a foreign MCAP into the family's canonical tables.

    Parameters
    ----------
    src : str or Path
        The MCAP file (only ever opened for reading).
    mapping : Mapping
        From :func:`load_mapping`.

    Returns
    -------
    ForeignTables
        One polars DataFrame per input table, columns in SI (``time_s``, the mapped columns).

    Raises
    ------
    InputError
        A file that is missing or not MCAP, a topic it does not hold, an encoding no decoder
        reads, a message that does not decode, a field path that does not resolve, a field
        that holds no number, a time that is not finite or does not increase.
    """
    import polars as pl
    from mcap.reader import make_reader

    src = Path(src)
    _check_mcap(src)
    collectors = {t: _Collector(spec, src, EMPTY_SCAN_COLUMNS.get(mapping.family, ()) if t == "measurements" else ())
                  for t, spec in mapping.tables.items()}
    by_topic: dict[str, list] = {}
    for c in collectors.values():
        by_topic.setdefault(c.spec.topic, []).append(c)
    errors = _data_errors()
    try:
        with open(src, "rb") as f:
            reader = make_reader(f, decoder_factories=_decoder_factories())
            summary = reader.get_summary()
            if summary is not None:
                present = {ch.topic for ch in summary.channels.values()}
                for topic in by_topic:
                    if topic not in present:
                        raise InputError(f"topic {topic!r} is not in the file (topics: "
                                         f"{', '.join(sorted(present)) or 'none'})", src)
            _read_all(reader, by_topic, src)
    except InputError:
        raise
    except errors as exc:
        raise InputError(f"unreadable MCAP ({type(exc).__name__}: {exc})", src) from None
    for topic, cs in by_topic.items():
        if all(c.messages == 0 for c in cs):
            raise InputError(f"topic {topic!r} holds no messages", src)
    tables = {t: pl.DataFrame(c.frame()) for t, c in collectors.items()}
    return ForeignTables(mapping.family, tables, {t: c.messages for t, c in collectors.items()},
                         {t: c.row_message for t, c in collectors.items()},
                         {t: c.empty_rows for t, c in collectors.items() if c.empty_rows is not None},
                         {t: c.message_times for t, c in collectors.items()})


def _check_mcap(src: Path) -> None:
    if not src.exists():
        raise InputError("no such file", src)
    if src.is_dir():
        raise InputError("is a folder, not an MCAP file", src)
    with open(src, "rb") as f:
        head = f.read(len(MCAP_MAGIC))
    if head != MCAP_MAGIC:
        raise InputError("not an MCAP file (it does not start with the MCAP magic bytes)", src)


def _read_all(reader, by_topic: dict, src: Path) -> None:
    """One pass over the file in file order; each channel's messages are decoded batch by batch
    by its encoding's decoder, JSON a whole batch per ``json.loads``."""
    pending: dict[int, tuple] = {}  # channel id -> (channel, schema, decode, [data], [log_time])
    counts: dict[str, int] = {}
    for schema, channel, message in reader.iter_messages(topics=list(by_topic), log_time_order=False):
        entry = pending.get(channel.id)
        if entry is None:
            entry = pending[channel.id] = (channel, schema, _decoder(reader, channel, schema, src), [], [])
        entry[3].append(message.data)
        entry[4].append(message.log_time)
        if len(entry[3]) >= BATCH:
            _flush(entry, by_topic, counts, src)
    for entry in pending.values():
        _flush(entry, by_topic, counts, src)


def _decoder(reader, channel, schema, src: Path):
    """``None`` for JSON (decoded in bulk here), else the ecosystem decoder of the channel."""
    if channel.message_encoding == "json":
        return None
    for factory in reader._decoder_factories:
        try:
            decode = factory.decoder_for(channel.message_encoding, schema)
        except _data_errors() as exc:
            raise InputError(f"topic {channel.topic}: its schema {getattr(schema, 'name', '')!r} does not parse "
                             f"({exc})", src) from None
        if decode is not None:
            return decode
    sch = "no schema" if schema is None else f"schema encoding {schema.encoding!r}"
    raise InputError(f"topic {channel.topic}: message encoding {channel.message_encoding!r} with {sch} is not "
                     "supported (read: cdr with ros2msg, protobuf, json)", src)


def _flush(entry, by_topic: dict, counts: dict, src: Path) -> None:
    channel, schema, decode, datas, log_times = entry
    if not datas:
        return
    first = counts.get(channel.topic, 0)
    if decode is None:
        decoded = _json_batch(datas, channel.topic, first, src)
    else:
        decoded = []
        try:
            for d in datas:
                decoded.append(decode(d))
        except _data_errors() as exc:
            raise InputError(f"topic {channel.topic}, message {first + len(decoded)}: does not decode as "
                             f"{getattr(schema, 'name', channel.message_encoding)} ({type(exc).__name__}: {exc})",
                             src) from None
    counts[channel.topic] = first + len(datas)
    for c in by_topic[channel.topic]:
        c.add(decoded, log_times, by_key=decode is None)
    datas.clear()
    log_times.clear()


def _json_batch(datas: list, topic: str, first: int, src: Path) -> list:
    """Every message of a batch in one ``json.loads`` call (one JSON array); a message that
    does not parse on its own is then found and named."""
    try:
        out = json.loads(b"[" + b",".join(datas) + b"]")
        if len(out) == len(datas):
            return out
    except (ValueError, UnicodeDecodeError, RecursionError):
        pass
    for i, d in enumerate(datas):
        try:
            json.loads(d)
        except (ValueError, UnicodeDecodeError) as exc:
            raise InputError(f"topic {topic}, message {first + i}: not valid JSON ({exc})", src) from None
        except RecursionError:  # the json module recurses once per level
            raise InputError(f"topic {topic}, message {first + i}: JSON nested too deeply to read", src) from None
    raise InputError(f"topic {topic}, message {first}: the batch of JSON messages does not parse", src)


# --------------------------------------------------------------------------- conversion


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
        what = "peaks" if mapping.family == "bearing-peaks" else "plots"
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
    ident = truth["truth_id"].to_numpy()
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
                         f"{SAME_SCAN_S:g} s): each is a scan without plots (the first: message {msg[i]}, time "
                         f"{float(t[i])!r} s{run_txt})")
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
