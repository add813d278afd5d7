"""Decoding a foreign MCAP's mapped topics into the family's canonical tables, column by column.

The messages are decoded by the MCAP ecosystem's decoders chosen by the channel's encoding
(``cdr`` with a ``ros2msg`` schema: ``mcap_ros2``; ``protobuf``: ``mcap_protobuf``; ``json``: the
standard library, a whole batch of messages in one call), :data:`BATCH` messages at a time; a
:class:`_Collector` per input table gathers their fields into numpy arrays in SI
(:class:`~trackreplay.recorders.foreign_mapping.TableSpec` says which), checks that each field
holds a number and that each message's time steps forward, and :func:`read_foreign_mcap` returns
the tables as polars DataFrames (:class:`ForeignTables`).
"""

from __future__ import annotations

import itertools
import json
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from trackreplay.errors import InputError
from trackreplay.recorders.foreign_mapping import (TIME_COLUMN, ColumnSpec, FieldPath, Mapping, TableSpec,
                                                   _explain_missing, _fields_of, _formats, _is_list, _kind, _MISSING)

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
        From :func:`~trackreplay.recorders.foreign_mapping.load_mapping`.

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
    # a family whose rows may mark a scan without items: a message with an empty list is one
    empty_scan = _formats()[mapping.family].empty_scan_columns
    collectors = {t: _Collector(spec, src, empty_scan if t == "measurements" else ())
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
