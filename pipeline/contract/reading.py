"""Reading files: :func:`read_dataset` (a whole file, in bulk), :func:`iter_frames` (frame by
frame, in file order), :func:`rewrite_dataset` (``replay convert upgrade``) and
:func:`dataset_topics` (docs/contract.md, "Reading").

Reading decodes each message's columns in bulk (``np.frombuffer``, no per-frame objects); the
per-frame views of :meth:`ChannelData.array` are made only when asked for. Files of contract
``replay.v1`` (one ``replay.v1.Frame`` message per run and scan) still read, frame by frame;
``replay convert upgrade IN -o OUT`` rewrites them in v2 with identical arrays. Every chunk's CRC
is checked on every read; anything wrong in a file (a CRC mismatch, a corrupt chunk, an
undecodable message, an implausible run or scan index) is an
:class:`~trackreplay.errors.InputError` naming the file and the chunk, and ``recover=True`` keeps
every intact chunk. A reader refuses schemas it does not know instead of guessing. The chunks
themselves are opened by :mod:`trackreplay.contract._records` (why not by ``mcap``'s reader is
said there).
"""

from __future__ import annotations

import json
import os
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Iterator, Mapping

import numpy as np
import zstandard
from google.protobuf.message import DecodeError
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, Chunk, Footer, Message, Metadata, Schema
from mcap.stream_reader import CRCValidationError, StreamReader

from trackreplay import vocabulary as vocab
from trackreplay.contract import _records
from trackreplay.contract.checking import (_check_density, _check_frame_time, _check_indices, _check_scans_held,
                                           _check_time_order, check_values)
from trackreplay.contract.dataset import ChannelData, ColumnArrays, Dataset, _Column, _FrameBlocks, _merge_columns
from trackreplay.contract.layout import (_SCHEMA_DATA, CONTRACT_V1, CONTRACT_V2, CONTRACT_VERSION, FRAME_SCHEMA_V1,
                                         FREE_FRAMES, MAX_FRAMES_PER_MESSAGE, MAX_INDEX, MCAP_MAGIC,
                                         METADATA_LAYOUT, SCAN_SCHEMA, SCHEMA_CONTRACTS, _BadData)
from trackreplay.contract.messages import _Block, decode_frame, decode_scan
from trackreplay.contract.writing import McapFrameWriter, atomic_output
from trackreplay.errors import InputError


# What a dependency raises on bad bytes; each becomes an InputError naming the file (and chunk).
_DATA_ERRORS = (McapError, struct.error, EOFError, ValueError, KeyError, IndexError, OverflowError, MemoryError,
                zstandard.ZstdError, DecodeError, UnicodeDecodeError)


def _describe(exc: BaseException) -> str:
    if isinstance(exc, _BadData):
        return str(exc)
    if isinstance(exc, MemoryError):
        return "too large to decode (MemoryError)"
    text = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _check_file(path: Path) -> None:
    if not path.exists():
        raise InputError("no such file", path)
    if path.is_dir():
        raise InputError("is a directory, expected an MCAP file", path)
    size = path.stat().st_size
    if size == 0:
        raise InputError("empty file (0 bytes), not an MCAP file", path)
    try:
        with open(path, "rb") as f:
            head = f.read(len(MCAP_MAGIC))
    except OSError as exc:
        raise InputError(f"cannot read ({exc.strerror or type(exc).__name__})", path) from None
    if head != MCAP_MAGIC:
        raise InputError("not an MCAP file (bad magic bytes)", path)


def _accept(schema, path) -> str:
    """The contract of a schema we read; InputError for any other."""
    if schema is not None and schema.encoding == "protobuf" and schema.name in SCHEMA_CONTRACTS:
        return SCHEMA_CONTRACTS[schema.name]
    name = None if schema is None else f"{schema.name} ({schema.encoding})"
    raise InputError(f"foreign schema {name}; this tool reads {SCAN_SCHEMA} and {FRAME_SCHEMA_V1} (protobuf) "
                     "messages", path)


def _parse_layout(record: Mapping[str, str] | None) -> dict | None:
    """The ``replay.layout`` record: topic → {"runs", "scans", "frames"} (ValueError if malformed)."""
    if record is None:
        return None
    out = {}
    for topic, text in record.items():
        try:
            v = json.loads(text)
            out[topic] = {k: int(v[k]) for k in ("runs", "scans", "frames")}
        except (ValueError, TypeError, KeyError, RecursionError):
            raise ValueError(f"{METADATA_LAYOUT} metadata is unreadable (channel {topic!r})") from None
        if min(out[topic].values()) < 0:
            raise ValueError(f"{METADATA_LAYOUT} metadata holds a negative count (channel {topic!r})")
    return out


class _Source:
    """Reads an MCAP file chunk by chunk, checking every chunk's CRC, and yields decoded messages
    of the chunks that are intact (each chunk whole or not at all).

    After :meth:`payloads` is exhausted, ``problems`` lists what was wrong (empty for a sound
    file) and ``messages`` counts the messages yielded.
    """

    def __init__(self, path: Path, topics: set | None = None):
        self.path = path
        self.topics = topics
        self.metadata: dict[str, dict[str, str]] = {}
        self.layout: dict | None = None
        self.problems: list[str] = []
        self.stream_problem: str | None = None
        self.messages = 0
        self.frames = 0
        self.decompressed = 0
        self.contracts: dict[str, str] = {}  # topic -> contract
        self.channel_ids: dict[str, int] = {}  # topic -> channel id (channels are listed in id order)
        self.known_channels: dict[int, str] = {}  # channel id -> topic, as far as read
        self.layout_problem: str | None = None
        self._zstd = zstandard.ZstdDecompressor()

    # -- chunks

    def _chunk_records(self, chunk: Chunk) -> Iterator:
        """The records of a chunk after checking its size and CRC: Schema and Channel records,
        and ``(channel_id, data)`` for each message."""
        raw = _records.decompress_chunk(chunk, self._zstd)
        self.decompressed += len(raw)
        return _records.chunk_records(raw)

    def _route(self, schema, channel) -> tuple[str, str] | None:
        """``(topic, contract)`` of a channel's messages, None for a channel not asked for."""
        topic = channel.topic
        if self.topics is not None and topic not in self.topics:
            return None
        contract = _accept(schema, self.path)
        self.channel_ids.setdefault(topic, channel.id)
        if self.contracts.setdefault(topic, contract) != contract:
            raise _BadData(f"channel {topic} mixes {self.contracts[topic]} and {contract} messages")
        return topic, contract

    def _decode_message(self, route: tuple[str, str], data) -> tuple:
        topic, contract = route
        try:
            if contract == CONTRACT_V2:
                block = decode_scan(data)
                _check_indices(int(block.runs.max()), block.scan + block.scan_count - 1, topic, self.layout)
                payload, n = block, block.n
            else:
                payload = decode_frame(data)
                run, scan, _, arrays, n = payload
                if n > 1 and (n > MAX_FRAMES_PER_MESSAGE or any(a.shape[:1] != (n,) for a in arrays.values())):
                    raise _BadData(f"batched frame does not carry {n} runs")
                if run + n > MAX_INDEX or scan >= MAX_INDEX:
                    _check_indices(run + n - 1, scan, topic, None)
        except _BadData as exc:
            raise _BadData(f"bad message on {topic}: {exc}") from None
        except (DecodeError, ValueError, OverflowError) as exc:
            raise _BadData(f"bad message on {topic}: {_describe(exc)}") from None
        self.frames += n
        if self.frames > FREE_FRAMES + self.decompressed:
            raise _BadData(f"the file claims {self.frames} frames in {self.decompressed} bytes of data")
        return topic, contract, payload

    def _chunk(self, chunk: Chunk, label: str, schemas: dict, channels: dict) -> list:
        """Decoded messages of one chunk, or [] with a problem noted."""
        try:
            out = []
            routes = {}
            for rec in self._chunk_records(chunk):
                if type(rec) is tuple:
                    cid, data = rec
                    route = routes.get(cid, 0)
                    if route == 0:
                        if cid not in channels:
                            raise _BadData(f"message on unknown channel id {cid}")
                        ch = channels[cid]
                        route = routes[cid] = self._route(schemas.get(ch.schema_id), ch)
                    if route is not None:
                        out.append(self._decode_message(route, data))
                elif isinstance(rec, Schema):
                    _define(schemas, rec)
                elif isinstance(rec, Channel):
                    _define(channels, rec)
                    self.known_channels[rec.id] = rec.topic
            return out
        except InputError:
            raise
        except (_BadData, *_DATA_ERRORS) as exc:
            self.problems.append(f"{label}: {_describe(exc)}")
            return []

    # -- the file

    def payloads(self) -> Iterator[tuple[str, str, object]]:
        try:
            with open(self.path, "rb") as f:
                summary_ok, data_problem = _records.section_crcs(f)
                f.seek(0)
                summary = None
                if summary_ok:
                    try:
                        reader = make_reader(f)
                        summary = reader.get_summary()
                        if summary is not None:
                            for schema in summary.schemas.values():
                                _accept(schema, self.path)
                            metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
                    except InputError:
                        raise
                    except _DATA_ERRORS:
                        summary = None
                else:
                    self.problems.append("summary section CRC mismatch (its index was not used)")
                indexed = summary is not None and bool(summary.chunk_indexes or (
                    summary.statistics is not None and summary.statistics.message_count == 0))
                if indexed:
                    self._set_metadata(metadata)
                    yield from self._indexed(f, summary)
                    if data_problem and not self.problems:
                        self.problems.append(data_problem)
                else:
                    yield from self._linear(f)
        except OSError as exc:
            raise InputError(f"cannot read ({exc.strerror or type(exc).__name__})", self.path) from None

    def _set_metadata(self, metadata: dict) -> None:
        try:
            self.layout = _parse_layout(metadata.pop(METADATA_LAYOUT, None))
            self.layout_problem = None
        except ValueError as exc:
            self.layout, self.layout_problem = None, str(exc)
        self.metadata = metadata

    def _indexed(self, f, summary) -> Iterator:
        chunks = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
        size = os.fstat(f.fileno()).st_size
        schemas, channels = dict(summary.schemas), dict(summary.channels)
        self.known_channels = {cid: ch.topic for cid, ch in channels.items()}
        for i, index in enumerate(chunks):
            label = f"chunk {i + 1} of {len(chunks)} (byte {index.chunk_start_offset})"
            if self.topics is not None and index.message_index_offsets and not any(
                    cid in channels and channels[cid].topic in self.topics for cid in index.message_index_offsets):
                continue
            try:
                chunk = _records.read_chunk(f, index.chunk_start_offset, index.chunk_length, size)
            except (_BadData, *_DATA_ERRORS) as exc:
                self.problems.append(f"{label}: {_describe(exc)}")
                continue
            items = self._chunk(chunk, label, schemas, channels)
            self.messages += len(items)
            yield from items

    def _linear(self, f) -> Iterator:
        """Record by record from the start: files without a summary or chunk index, and damaged files."""
        f.seek(0)
        schemas: dict = {}
        channels: dict = {}
        metadata: dict = {}
        n_chunks = 0
        done = False
        records = StreamReader(f, emit_chunks=True, validate_crcs=True).records
        while True:
            start = f.tell()
            try:
                rec = next(records)
            except StopIteration:
                done = True
                break
            except InputError:
                raise
            except _DATA_ERRORS as exc:
                after = f" after chunk {n_chunks}" if n_chunks else ""
                if isinstance(exc, CRCValidationError):
                    self.stream_problem = (f"data section CRC mismatch{after} (stored {exc.expected:#010x}, computed "
                                           f"{exc.actual:#010x}): a record outside the intact chunks is damaged")
                else:
                    self.stream_problem = f"truncated or corrupt MCAP ({type(exc).__name__}{after})"
                break
            if isinstance(rec, (Schema, Channel)):
                try:
                    _define(schemas if isinstance(rec, Schema) else channels, rec)
                except _BadData as exc:
                    self.problems.append(f"record at byte {start}: {exc}")
                    continue
                if isinstance(rec, Channel):
                    self.known_channels[rec.id] = rec.topic
            elif isinstance(rec, Metadata):
                metadata[rec.name] = dict(rec.metadata)
                self._set_metadata(dict(metadata))
            elif isinstance(rec, Chunk):
                n_chunks += 1
                items = self._chunk(rec, f"chunk {n_chunks} (byte {start})", schemas, channels)
                self.messages += len(items)
                yield from items
            elif isinstance(rec, Message):
                try:
                    if rec.channel_id not in channels:
                        raise _BadData(f"message on unknown channel id {rec.channel_id}")
                    ch = channels[rec.channel_id]
                    route = self._route(schemas.get(ch.schema_id), ch)
                    item = None if route is None else self._decode_message(route, rec.data)
                except (_BadData, *_DATA_ERRORS) as exc:
                    self.problems.append(f"message {rec.sequence} outside chunks: {_describe(exc)}")
                    continue
                if item is not None:
                    self.messages += 1
                    yield item
            elif isinstance(rec, Footer):
                done = True
                break
        if not done and self.stream_problem is None:
            self.stream_problem = "truncated or corrupt MCAP (no footer)"
        self._set_metadata(dict(metadata))

    def problem(self) -> str | None:
        """One line: the damage (the truncation first, else the first bad chunk or record)."""
        problems = self.problems + ([self.layout_problem] if self.layout_problem else [])
        if self.stream_problem is None and not problems:
            return None
        first = self.stream_problem or problems[0]
        more = len(problems) - (0 if self.stream_problem else 1)
        return first + (f" (and {more} more problem(s))" if more > 0 else "")


def _define(table: dict, rec) -> None:
    """Keep a Schema or Channel record by its id. The same record again is fine (writers repeat
    them in every chunk); the same id defined differently is damage: MCAP ids are unique in a
    file, and readers trusting one definition or the other would read different data (a channel
    renamed in one chunk would move its messages to another topic)."""
    old = table.get(rec.id)
    if old is not None and old != rec:
        kind, name = ("schema", "name") if isinstance(rec, Schema) else ("channel", "topic")
        raise _BadData(f"{kind} id {rec.id} is defined twice, differently ({kind} {getattr(old, name)!r}, then "
                       f"{getattr(rec, name)!r})")
    table[rec.id] = rec


class _Collector:
    """Per-channel accumulation of decoded messages into :class:`ChannelData`."""

    def __init__(self, path: Path):
        self.path = path
        self.v1: dict[str, tuple[list, list, list, dict]] = {}
        self.v2: dict[str, list[_Block]] = {}
        self.order: list[str] = []

    def add(self, topic: str, contract: str, payload) -> None:
        if topic not in self.v1 and topic not in self.v2:
            self.order.append(topic)
        if contract == CONTRACT_V2:
            self.v2.setdefault(topic, []).append(payload)
            return
        run, scan, t, arrays, n = payload
        b = self.v1.get(topic)
        if b is None:
            b = self.v1[topic] = ([], [], [], {})
        if n == 1:
            b[0].append(run)
            b[1].append(scan)
            b[2].append(t)
            lists = b[3]
            for name, a in arrays.items():
                items = lists.get(name)
                if items is None:
                    items = lists[name] = []
                items.append(a)
        else:
            b[0].extend(range(run, run + n))
            b[1].extend([scan] * n)
            b[2].extend([t] * n)
            for name, a in arrays.items():
                b[3].setdefault(name, []).extend(a)

    def channels(self, channel_ids: Mapping[str, int]) -> dict[str, ChannelData]:
        """Channels in the order the writer registered them (for a v1 file: of their first message)."""
        out = {}
        for topic in sorted(self.order, key=lambda t: channel_ids.get(t, 1 << 16)):
            out[topic] = self._v2(topic) if topic in self.v2 else self._v1(topic)
            _check_density(out[topic])
            if topic in vocab.TIME_ORDERED:
                _check_time_order(out[topic])
        return out

    def _v1(self, topic: str) -> ChannelData:
        runs, scans, times, arrays = self.v1.pop(topic)
        return ChannelData(np.asarray(runs, dtype=np.int64), np.asarray(scans, dtype=np.int64),
                           np.asarray(times, dtype=np.float64), arrays, topic=topic, path=str(self.path))

    def _v2(self, topic: str) -> ChannelData:
        blocks = self.v2.pop(topic)
        index = None
        if all(b.first_run is not None and b.times is None for b in blocks):
            index = _FrameBlocks(np.array([b.scan for b in blocks], np.int64),
                                 np.array([b.first_run for b in blocks], np.int64),
                                 np.array([b.n for b in blocks], np.int64),
                                 np.array([b.time_s for b in blocks], np.float64))
        elif any(b.scan_count > 1 for b in blocks) and all(b.first_run is not None for b in blocks):
            index = _grouped_index(blocks)
        if index is None:
            run = np.concatenate([b.runs for b in blocks])
            scan = np.concatenate([b.scans() for b in blocks])
            t = np.concatenate([b.times if b.times is not None else np.full(b.n, b.time_s) for b in blocks])
        parts: dict[str, list[_Column]] = {}
        for b in blocks:
            for name, col in b.columns.items():
                parts.setdefault(name, []).append(col)
        del blocks
        columns = ColumnArrays({name: _merge_columns(cols) for name, cols in parts.items()})
        if index is not None:
            return ChannelData.of_blocks(index, columns, topic=topic, path=str(self.path))
        return ChannelData(run, scan, t, columns, topic=topic, path=str(self.path))


def _grouped_index(blocks: list) -> "_FrameBlocks | None":
    """The :class:`_FrameBlocks` of messages some of which group scans (one row per scan of
    each), or None where a scan's frames do not share one time (then the per-frame arrays)."""
    scans, first, count, times = [], [], [], []
    for b in blocks:
        per = b.n // b.scan_count
        t = b.times[::per] if b.times is not None else np.full(b.scan_count, b.time_s)
        if b.times is not None and per > 1 and not np.array_equal(b.times, np.repeat(t, per)):
            return None
        scans.append(np.arange(b.scan, b.scan + b.scan_count, dtype=np.int64))
        first.append(np.full(b.scan_count, b.first_run, np.int64))
        count.append(np.full(b.scan_count, per, np.int64))
        times.append(t)
    return _FrameBlocks(np.concatenate(scans), np.concatenate(first), np.concatenate(count),
                        np.concatenate(times).astype(np.float64))


def read_dataset(path: str | Path, topics: Iterable[str] | None = None, recover: bool = False) -> Dataset:
    """Read an MCAP file of frames (contract ``replay.v2``, or ``replay.v1`` frame by frame).

    Parameters
    ----------
    path : str or Path
        The file. It is only ever opened for reading.
    topics : iterable of str, optional
        Only these channels (default: all).
    recover : bool
        For a truncated or damaged file, keep every intact chunk instead of refusing the file.

    Raises
    ------
    InputError
        Missing, empty, foreign, truncated or corrupt files (a chunk whose CRC does not match,
        that does not decompress or whose messages do not decode is named; the message says how
        many messages a ``--recover`` read keeps), and run/scan indices beyond what the file
        declares or a sane maximum.
    """
    path = Path(path)
    _check_file(path)
    source = _Source(path, None if topics is None else set(topics))
    collected = _Collector(path)
    try:
        for topic, contract, payload in source.payloads():
            collected.add(topic, contract, payload)
        problem = source.problem()
        if problem is not None and not recover:
            raise InputError(_unreadable(problem, source.messages), path)
        channels = collected.channels(source.channel_ids)
        if not recover:
            for ch in channels.values():
                _check_scans_held(ch)
        if source.layout is not None and problem is None:
            for topic, ch in channels.items():
                declared = source.layout.get(topic, {}).get("frames")
                if declared is not None and ch.n_frames != declared:
                    raise InputError(f"{topic} holds {ch.n_frames} frame(s), but the file's {METADATA_LAYOUT} "
                                     f"record declares {declared}", path)
    except MemoryError:
        raise InputError("too large to read into memory (MemoryError)", path) from None
    contracts = set(source.contracts.values())
    contract = contracts.pop() if len(contracts) == 1 else (None if not contracts else CONTRACT_V2)
    check_values(channels, path)
    return Dataset(str(path), channels, source.metadata, recovered_messages=source.messages if problem else None,
                   contract=contract)


def iter_frames(path: str | Path, recover: bool = False, meta: dict | None = None):
    """Every frame of a file in file order: ``(topic, run, scan, time_s, arrays, run_count)``
    (``run_count`` > 1 for a batched v1 frame, whose arrays lead with the run axis).

    ``meta`` (a dict) receives ``metadata`` before the first frame, and ``messages``,
    ``contracts`` (topic → contract) and ``problem`` at the end. Raises :class:`InputError`
    at the end for a damaged file unless ``recover``.
    """
    path = Path(path)
    _check_file(path)
    source = _Source(path)
    meta = {} if meta is None else meta
    for topic, contract, payload in source.payloads():
        if "metadata" not in meta:
            meta["metadata"] = dict(source.metadata)
            meta["topics"] = [t for _, t in sorted(source.known_channels.items())]
        if contract == CONTRACT_V1:
            _check_frame_time(topic, payload[0], payload[1], payload[2], path)
            yield (topic, *payload)
            continue
        block = payload
        full, partial = {}, {}
        for name, col in block.columns.items():
            if col.frames is None:
                full[name] = col.entries()
            else:
                partial[name] = dict(zip(col.frames.tolist(), col.entries()))
        for i in range(block.n):
            arrays = {}
            for name in block.columns:
                if name in full:
                    arrays[name] = full[name][i]
                elif i in partial[name]:
                    arrays[name] = partial[name][i]
            t = float(block.times[i]) if block.times is not None else block.time_s
            scan = block.scan if block.scan_count == 1 else block.scan + i // (block.n // block.scan_count)
            _check_frame_time(topic, int(block.runs[i]), scan, t, path)
            yield topic, int(block.runs[i]), scan, t, arrays, 1
    meta.setdefault("metadata", dict(source.metadata))
    meta["messages"] = source.messages
    meta["contracts"] = dict(source.contracts)
    meta["problem"] = source.problem()
    if meta["problem"] is not None and not recover:
        raise InputError(_unreadable(meta["problem"], source.messages), path)


def _unreadable(problem: str, messages: int) -> str:
    """The message for a damaged file: what --recover would keep, or that it would keep nothing."""
    if messages == 0:
        return f"{problem}; no complete chunk survives, so --recover has nothing to keep"
    return f"{problem}; {messages} message(s) in intact chunks are recoverable with --recover"


@dataclass
class RewriteReport:
    """What :func:`rewrite_dataset` did."""

    frames: int
    messages_in: int
    messages_out: int
    source_contracts: list[str]
    contract: str
    problem: str | None = None


def rewrite_dataset(src: str | Path, dst: str | Path, contract: str = CONTRACT_VERSION,
                    recover: bool = False) -> RewriteReport:
    """Rewrite ``src`` in ``contract`` (``replay convert upgrade``): the same frames, arrays and
    metadata; the scenario record's ``contract`` field names the new contract.

    Frames keep their file order; a chunk is closed whenever the scan changes from one frame to
    the next, so a scan-major file (as ``replay simulate`` writes) becomes byte for byte what
    ``replay simulate`` writes in ``contract`` with the same seed. ``dst`` may be ``src``.
    """
    if contract not in _SCHEMA_DATA:
        raise InputError(f"unknown contract {contract!r} (have: {', '.join(_SCHEMA_DATA)})")
    meta: dict = {}
    frames = 0
    with atomic_output(dst) as f:
        writer = None
        prev = None
        for topic, run, scan, t, arrays, n in iter_frames(src, recover, meta):
            if writer is None:
                writer = McapFrameWriter(f, meta["metadata"], contract)
                for known in meta["topics"]:  # channels keep their order
                    writer.channel(known)
            if prev is not None and scan != prev:
                writer.flush()
            prev = scan
            writer.write(topic, run, scan, t, arrays, run_count=n)
            frames += n
        if writer is None:
            writer = McapFrameWriter(f, meta.get("metadata"), contract)
        writer.finish()
    return RewriteReport(frames, meta.get("messages", 0), writer.messages,
                         sorted(set(meta.get("contracts", {}).values())), contract, meta.get("problem"))


def dataset_topics(path: str | Path) -> list[str]:
    """Channel topics of a file (summary only, no message decoding)."""
    path = Path(path)
    _check_file(path)
    with open(path, "rb") as f:
        try:
            summary = make_reader(f).get_summary()
        except _DATA_ERRORS as exc:
            raise InputError(f"truncated or corrupt MCAP ({type(exc).__name__})", path) from None
    return sorted(c.topic for c in summary.channels.values()) if summary else []
