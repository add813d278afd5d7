"""The mapping file of a foreign MCAP (``docs/importers.md``, "Recordings made by other tools"):
a small TOML file saying which topic holds the measurements, where each message keeps its time,
which list field holds the items of a message, and which field and unit give each column of the
family's canonical table (:data:`trackreplay.recorders.table_formats.TABLE_FORMATS`), and for a
family whose format says so a ``[truth]`` list of targets (its ``truth_list``).

* :data:`UNITS`, :func:`unit_factor`: the units a mapping may name, converted to SI here (SI
  inside, everything else at this boundary only);
* :class:`FieldPath`: a dotted field path with list indices, compiled to one getter, and the
  words that say why a path does not resolve on a message;
* :func:`load_mapping`: the file read and checked into a :class:`Mapping` (one
  :class:`TableSpec` per input table).

The messages are read by :mod:`trackreplay.recorders.foreign_decoding`; the conversion is
:func:`trackreplay.recorders.foreign_mcap.convert_foreign_mcap`.
"""

from __future__ import annotations

import math
import re
import tomllib
from dataclasses import dataclass, field
from operator import attrgetter, itemgetter
from pathlib import Path

from trackreplay import vocabulary as vocab
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
# [truth]: a list of targets with identities per message (many targets), for a family whose table
# format names its columns (TableFormat.truth_list); its rows are truth-only rows of the
# measurements table (the measurement empty)
TRUTH_TABLE = "truth"
# the optional table of values the recording's sensor had (its noise, scan period, …), recorded
# with the source "mapping file" (trackreplay.sensor_values); what it does not say stays unknown
SENSOR_TABLE = "sensor"
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
    # imported when first needed: the table modules bring polars, which starting `replay` avoids
    from trackreplay.recorders.table_formats import TABLE_FORMATS

    return TABLE_FORMATS


def _truth_families() -> tuple[str, ...]:
    """The families whose mappings may add a ``[truth]`` list of targets."""
    return tuple(f for f, fmt in _formats().items() if fmt.truth_list)


def _table_columns(family: str, table: str) -> list:
    """Every column name the family's ``table`` accepts, as regular expressions read from
    ``TABLE_FORMATS`` (``truth<t>_bearing_rad`` stands for ``truth0_bearing_rad``, …)."""
    if table == TRUTH_TABLE:
        return [re.compile(re.escape(c) + "$") for c in ("run", *_formats()[family].truth_list)]
    out = []
    for col in _formats()[family].tables[table]:
        for name in col.name.split("|"):
            pattern = re.escape(name.strip()).replace(re.escape("<axis>"), "[xyz]")
            out.append(re.compile(re.sub(re.escape("<") + r"\w+" + re.escape(">"), r"\\d+", pattern) + "$"))
    return out


def _column_names(family: str, table: str) -> list[str]:
    if table == TRUTH_TABLE:
        return ["run", *_formats()[family].truth_list]
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
    if family in vocab.FORMER_FAMILY_NAMES:
        raise InputError(f"family {family!r} is now called {vocab.FORMER_FAMILY_NAMES[family]!r}: "
                         f"write family = {vocab.FORMER_FAMILY_NAMES[family]!r}", path)
    if family not in formats:
        raise InputError(f"family {family!r} has no table format (have: {', '.join(formats)})", path)
    tables = _tables_of(family) + ((TRUTH_TABLE,) if formats[family].truth_list else ())
    if TRUTH_TABLE in doc and TRUTH_TABLE not in tables:
        raise InputError(f"[truth] (a list of targets with identities) belongs to "
                         f"{' or '.join(_truth_families())} mappings; a {family} mapping carries its truth in the "
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
        _check_truth_spec(specs, formats[family].truth_list, path)
    if sensor:  # names and types checked here, so that a bad value names the mapping file
        from trackreplay.recorders.tables import _given_values

        try:
            _given_values(family, sensor, f"[{SENSOR_TABLE}]")
        except InputError as exc:
            raise InputError(exc.problem, path) from None
    return Mapping(family, specs, path, dict(sensor))


def _check_truth_spec(specs: dict, columns: tuple, path) -> None:
    """[truth] gives an identity and the whole state of every target (``columns``, the format's
    ``truth_list``); the truth then comes from there alone, and both tables say the run or
    neither does."""
    have = {c.name for c in specs[TRUTH_TABLE].columns}
    missing = [c for c in columns if c not in have]
    if missing:
        raise InputError(f"[truth]: missing column(s) {', '.join(missing)} (each target of a truth list gives "
                         f"{', '.join(columns)})", path)
    meas = {c.name for c in specs["measurements"].columns}
    twice = [c for c in columns if c in meas]
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
