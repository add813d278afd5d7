"""Structure-aware mutation fuzzing of the MCAP input path (issue 30).

Every mutant goes through ``replay eval FILE --json`` and ``replay FILE`` (outputs on) and must
end one of two ways: refused with one line ``replay: error: FILE: <problem>`` and exit 2, or
accepted with the metrics that the data it holds give. What the file holds is read by a decoder
written here, independent of the reader under test: the plain ``mcap`` reader for the records
and protobuf classes built from the schema the file itself carries, decoded into frames as
``docs/contract.md`` lays them out. An accepted mutant whose frames equal the original's must
give the original's metrics; one holding other frames must give the metrics of those frames
written afresh (``trackreplay.contract.write_dataset``, the writer) and replayed; anything else is
a silent corruption.

The mutations know the file's structure (see ``docs/contract.md``):

* fields of the ``replay.v2.Scan`` / ``Column`` / ``Array`` messages (counts, runs, times, names,
  dtypes, shapes, values, offsets, frame lists, layouts), re-encoded and rewritten with valid CRCs;
* huge or off-by-one length prefixes at real record boundaries, at the top level and inside a
  chunk, and damage inside a chunk's records **with the chunk's CRC recomputed** (so the damage
  reaches the decoder, not the CRC check);
* chunks marked lz4 or zstd that hold other bytes, wrong declared sizes, unknown compressions;
* duplicated, renamed and swapped channels, channels pointing at missing schemas, wrong schemas
  (names, encodings, descriptor bytes), damaged metadata records (layout and scenario);
* the old blind byte damage (bit flips, overwrites, truncations, cut and repeated spans).

Base files come from five families' scenarios (radar, array, bearing peaks, emitter, coloured
noise) and a radar file whose chunks are lz4. ``tests/test_fuzz.py`` runs a few hundred mutants;
the full run is a script::

    python tests/fuzz_mcap.py --mutants 10000 --seed 1

which prints the count of each outcome: refused with one line, refused with one line per failed
tracker, accepted and correct, exit 3, silent corruptions, tracebacks, hangs (a time limit per
mutant), inputs modified, and more.
"""

from __future__ import annotations

import argparse
import io
import json
import math
import random
import shutil
import struct
import sys
import tempfile
import time
import traceback
import zlib
from dataclasses import dataclass, field, replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402
from mcap.records import (Channel, Chunk, ChunkIndex, DataEnd, Footer, Header, Message, MessageIndex,  # noqa: E402
                          Metadata, MetadataIndex, Opcode, Schema, Statistics, SummaryOffset)
from mcap.data_stream import RecordBuilder  # noqa: E402
from mcap.stream_reader import StreamReader  # noqa: E402

MAGIC = b"\x89MCAP0\r\n"

# --------------------------------------------------------------------------- base files

# (name, scenario, runs, overrides): small, but every family's channels and layouts
BASES = (
    ("radar", "radar-tws", 3, {"n_scans": 10}),
    ("array", "array-crossing", 2, {"n_scans": 6, "n_sensors": 6, "snapshots_per_scan": 8}),
    ("peaks", "xcorr-crossing", 2, {"crossing_angle_deg": 60}),
    ("emitter", "tdoa-fdoa", 3, {"n_epochs": 3}),
    ("colored", "colored-ar", 2, {"n_samples": 30}),
)


def small_dataset(folder: Path, scenario: str = "radar-tws", runs: int = 3, overrides: dict | None = None,
                  name: str = "small") -> Path:
    """A small data set written through the real recorder."""
    from trackreplay.recorders.scenarios import load_scenario
    from trackreplay.recorders.simulated import record

    path = folder / f"{name}.mcap"
    record(path, load_scenario(scenario).with_overrides(overrides or {"n_scans": 10}), runs=runs, seed=9)
    return path


# --------------------------------------------------------------------------- the file as records


@dataclass
class McapModel:
    """An MCAP file as its records: what the mutations edit and :func:`assemble` writes back."""

    header: Header
    chunks: list  # per chunk, its records in order (Schema, Channel, Message)
    metadata_before: list  # Metadata records before the first chunk
    metadata_after: list  # ... and after the last
    compression: str = "zstd"


def parse(data: bytes) -> McapModel:
    """Records of a sound file, read with the plain ``mcap`` stream reader."""
    header, chunks, before, after = None, [], [], []
    for rec in StreamReader(io.BytesIO(data), emit_chunks=True, validate_crcs=True).records:
        if isinstance(rec, Header):
            header = rec
        elif isinstance(rec, Chunk):
            raw = _decompress(rec.compression, rec.data)
            chunks.append(_inner_records(raw))
        elif isinstance(rec, Metadata):
            (after if chunks else before).append(rec)
        elif isinstance(rec, (Schema, Channel, Message)):
            chunks.append([rec])
    return McapModel(header, chunks, before, after)


def _inner_records(raw: bytes) -> list:
    """The records of a decompressed chunk (the stream reader reads them; it ends on EndOfFile)."""
    from mcap.exceptions import EndOfFile

    out, records = [], StreamReader(io.BytesIO(raw), skip_magic=True).records
    while True:
        try:
            out.append(next(records))
        except (StopIteration, EndOfFile):
            return out


def _decompress(compression: str, data: bytes) -> bytes:
    if compression == "zstd":
        import zstandard

        return zstandard.ZstdDecompressor().decompressobj().decompress(data)
    if compression == "lz4":
        import lz4.frame

        return lz4.frame.decompress(data)
    return data


def _compress(compression: str, raw: bytes) -> bytes:
    if compression == "zstd":
        import zstandard

        return zstandard.ZstdCompressor().compress(raw)
    if compression == "lz4":
        import lz4.frame

        return lz4.frame.compress(raw)
    return raw


def _records_bytes(records) -> tuple[bytes, list[int]]:
    """Serialized records and the offset of each."""
    b = RecordBuilder()
    offsets = []
    for rec in records:
        offsets.append(b.count)
        rec.write(b)
    return b.end(), offsets


@dataclass
class ChunkDamage:
    """How one chunk is written wrongly: ``inner`` edits its uncompressed bytes (the CRC and size
    are then computed from the edited bytes unless ``keep_crc``); ``label`` is the compression
    it claims, ``actual`` the one applied; ``size_delta`` is added to its declared size."""

    index: int
    inner: object = None
    label: str | None = None
    actual: str | None = None
    size_delta: int = 0
    keep_crc: bool = False


def assemble(model: McapModel, damage: ChunkDamage | None = None, data_crc: bool = True) -> bytes:
    """A complete MCAP file (chunks, message indexes, data-section CRC, summary with chunk and
    metadata indexes, statistics, summary offsets, footer CRC) from ``model``."""
    out = io.BytesIO()
    out.write(MAGIC)
    b = RecordBuilder()
    model.header.write(b)
    out.write(b.end())
    metadata_index, chunk_index = [], []
    schemas, channels, counts = {}, {}, {}
    times = []

    def write_metadata(records):
        for m in records:
            start = out.tell()
            m.write(b)
            out.write(b.end())
            metadata_index.append(MetadataIndex(offset=start, length=out.tell() - start, name=m.name))

    write_metadata(model.metadata_before)
    for i, records in enumerate(model.chunks):
        raw, offsets = _records_bytes(records)
        messages = [(r, o) for r, o in zip(records, offsets) if isinstance(r, Message)]
        for r in records:
            if isinstance(r, Schema):
                schemas[r.id] = r
            elif isinstance(r, Channel):
                channels[r.id] = r
        for m, _ in messages:
            counts[m.channel_id] = counts.get(m.channel_id, 0) + 1
            times.append(m.log_time)
        crc = zlib.crc32(raw)
        label = actual = model.compression
        size_delta = 0
        if damage is not None and damage.index == i:
            if damage.inner is not None:
                raw = damage.inner(raw, offsets)
                if not damage.keep_crc:
                    crc = zlib.crc32(raw)
            label = damage.label if damage.label is not None else label
            actual = damage.actual if damage.actual is not None else actual
            size_delta = damage.size_delta
        start_t = min((m.log_time for m, _ in messages), default=0)
        end_t = max((m.log_time for m, _ in messages), default=0)
        chunk = Chunk(compression=label, data=_compress(actual, raw), message_start_time=start_t,
                      message_end_time=end_t, uncompressed_crc=crc,
                      uncompressed_size=max(0, len(raw) + size_delta) % 2**64)
        start = out.tell()
        chunk.write(b)
        out.write(b.end())
        chunk_length = out.tell() - start
        index_offsets = {}
        for cid in sorted({m.channel_id for m, _ in messages}):
            index_offsets[cid] = out.tell()
            MessageIndex(channel_id=cid, records=[(m.log_time, o) for m, o in messages if m.channel_id == cid]).write(b)
            out.write(b.end())
        chunk_index.append(ChunkIndex(
            message_start_time=start_t, message_end_time=end_t, chunk_start_offset=start, chunk_length=chunk_length,
            message_index_offsets=index_offsets, message_index_length=out.tell() - start - chunk_length,
            compression=label, compressed_size=len(chunk.data), uncompressed_size=chunk.uncompressed_size))
    write_metadata(model.metadata_after)
    DataEnd(data_section_crc=zlib.crc32(out.getvalue()) if data_crc else 0).write(b)
    out.write(b.end())
    summary_start = out.tell()
    s = RecordBuilder()
    groups = []

    def group(opcode, records):
        start = s.count
        for r in records:
            r.write(s)
        groups.append(SummaryOffset(group_opcode=opcode, group_start=summary_start + start, group_length=s.count - start))

    group(Opcode.SCHEMA, [schemas[k] for k in sorted(schemas)])
    group(Opcode.CHANNEL, [channels[k] for k in sorted(channels)])
    group(Opcode.STATISTICS, [Statistics(
        message_count=sum(counts.values()), schema_count=len(schemas), channel_count=len(channels),
        attachment_count=0, metadata_count=len(metadata_index), chunk_count=len(chunk_index),
        message_start_time=min(times, default=0), message_end_time=max(times, default=0),
        channel_message_counts=counts)])
    group(Opcode.CHUNK_INDEX, chunk_index)
    group(Opcode.METADATA_INDEX, metadata_index)
    offsets_start = summary_start + s.count
    for g in groups:
        g.write(s)
    summary = s.end()
    crc = zlib.crc32(struct.pack("<BQQQ", Opcode.FOOTER, 20, summary_start, offsets_start), zlib.crc32(summary))
    out.write(summary)
    Footer(summary_start=summary_start, summary_offset_start=offsets_start, summary_crc=crc).write(b)
    out.write(b.end())
    out.write(MAGIC)
    return out.getvalue()


def record_boundaries(data: bytes) -> list[tuple[int, int, int]]:
    """``(offset, opcode, length)`` of every top-level record of a sound file."""
    out, pos = [], len(MAGIC)
    while pos + 9 <= len(data) - len(MAGIC):
        op, length = struct.unpack_from("<BQ", data, pos)
        out.append((pos, op, length))
        pos += 9 + length
    return out


# --------------------------------------------------------------------------- independent decoder

ALLOWED_DTYPES = {"<f8", "<f4", "<c16", "<c8", "<i8", "<i4", "<u4", "<u2", "|u1", "|b1"}
LAYOUT_RECORD = "replay.layout"


class Unreadable(Exception):
    """The file is not a valid ``replay.v2`` data set, as far as this decoder sees."""


def _scan_class(schema: Schema):
    """``replay.v2.Scan`` built from the FileDescriptorSet the file carries."""
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    if schema is None or schema.encoding != "protobuf" or schema.name != "replay.v2.Scan":
        raise Unreadable(f"schema {None if schema is None else (schema.name, schema.encoding)} is not replay.v2.Scan")
    fds = descriptor_pb2.FileDescriptorSet.FromString(schema.data)
    pool = descriptor_pool.DescriptorPool()
    for fdp in fds.file:
        pool.Add(fdp)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName("replay.v2.Scan"))


def _array(dtype: str, shape, data: bytes) -> np.ndarray:
    if dtype not in ALLOWED_DTYPES:
        raise Unreadable(f"dtype {dtype!r}")
    shape = tuple(int(s) for s in shape)
    if math.prod(shape) * np.dtype(dtype).itemsize != len(data):
        raise Unreadable("values do not match their shape")
    return np.frombuffer(data, dtype).reshape(shape)


def decode_scan_message(scan_msg) -> list[tuple[int, int, float, dict]]:
    """Frames ``(run, scan, time_s, arrays)`` of one Scan message, following docs/contract.md."""
    n = scan_msg.frame_count
    if n == 0:
        raise Unreadable("message without frames")
    if scan_msg.runs:
        if len(scan_msg.runs) != 4 * n:
            raise Unreadable("runs list length")
        runs = [int(r) for r in np.frombuffer(scan_msg.runs, "<u4")]
    else:
        runs = [scan_msg.first_run + i for i in range(n)]
    if scan_msg.times_s:
        if len(scan_msg.times_s) != 8 * n:
            raise Unreadable("times list length")
        times = [float(t) for t in np.frombuffer(scan_msg.times_s, "<f8")]
    else:
        times = [scan_msg.time_s] * n
    arrays = [dict() for _ in range(n)]
    for col in scan_msg.columns:
        if col.frames:
            if len(col.frames) % 4:
                raise Unreadable("frames list length")
            which = [int(i) for i in np.frombuffer(col.frames, "<u4")]
            if any(i >= n for i in which) or any(b <= a for a, b in zip(which, which[1:])):
                raise Unreadable("frames out of range or order")
        else:
            which = list(range(n))
        m = len(which)
        shape = tuple(int(s) for s in col.shape)
        if col.dtype not in ALLOWED_DTYPES:
            raise Unreadable(f"dtype {col.dtype!r}")
        dt = np.dtype(col.dtype)
        if col.layout == 2:  # IRREGULAR
            if len(col.entries) != m:
                raise Unreadable("entries count")
            entries = [_array(e.dtype, e.shape, e.data) for e in col.entries]
        elif col.layout == 0:  # FIXED
            if m * math.prod(shape) * dt.itemsize != len(col.values):
                raise Unreadable("fixed values length")
            entries = list(np.frombuffer(col.values, dt).reshape(m, *shape))
        elif col.layout == 1:  # RAGGED
            if len(col.offsets) != 8 * (m + 1):
                raise Unreadable("offsets length")
            off = np.frombuffer(col.offsets, "<i8")
            row = math.prod(shape) * dt.itemsize
            if off[0] != 0 or np.any(np.diff(off) < 0) or int(off[-1]) * row != len(col.values):
                raise Unreadable("offsets")
            flat = np.frombuffer(col.values, dt).reshape(int(off[-1]), *shape)
            entries = [flat[off[i]:off[i + 1]] for i in range(m)]
        elif col.layout == 3:  # SYMMETRIC: upper triangles row by row
            if len(shape) < 2 or shape[-1] != shape[-2] or shape[-1] == 0 or dt.kind != "f":
                raise Unreadable("symmetric shape")
            k = shape[-1]
            iu = np.triu_indices(k)
            lead = shape[:-2]
            if m * math.prod(lead) * len(iu[0]) * dt.itemsize != len(col.values):
                raise Unreadable("symmetric values length")
            packed = np.frombuffer(col.values, dt).reshape(m, *lead, len(iu[0]))
            full = np.zeros((m, *lead, k, k), dt)
            full[..., iu[0], iu[1]] = packed
            full[..., iu[1], iu[0]] = packed
            entries = list(full)
        else:
            raise Unreadable(f"layout {col.layout}")
        for i, e in zip(which, entries):
            if col.name in arrays[i]:
                raise Unreadable(f"column {col.name!r} twice")
            arrays[i][col.name] = e
    return [(runs[i], int(scan_msg.scan), times[i], arrays[i]) for i in range(n)]


@dataclass
class Content:
    """What a file holds: metadata (without the layout record) and every channel's frames."""

    metadata: dict
    frames: dict = field(default_factory=dict)  # topic -> {(run, scan): (time_s, {name: array})}

    def same_as(self, other: "Content") -> bool:
        if self.metadata != other.metadata or self.frames.keys() != other.frames.keys():
            return False
        for topic, frames in self.frames.items():
            theirs = other.frames[topic]
            if frames.keys() != theirs.keys():
                return False
            for key, (t, arrays) in frames.items():
                t2, arrays2 = theirs[key]
                if struct.pack("<d", t) != struct.pack("<d", t2) or arrays.keys() != arrays2.keys():
                    return False
                for name, a in arrays.items():
                    b = arrays2[name]
                    if a.dtype != b.dtype or a.shape != b.shape or a.tobytes() != b.tobytes():
                        return False
        return True


def decode_independently(path: Path) -> Content:
    """The file's frames read with the plain ``mcap`` reader (CRCs checked) and the protobuf
    schema the file carries; :class:`Unreadable` for a file that breaks the contract."""
    from mcap.reader import make_reader

    try:
        with open(path, "rb") as f:
            reader = make_reader(f, validate_crcs=True)
            metadata = {}
            for m in reader.iter_metadata():
                if m.name in metadata:
                    raise Unreadable(f"metadata {m.name} twice")
                metadata[m.name] = dict(m.metadata)
            classes, frames = {}, {}
            for schema, channel, message in reader.iter_messages(log_time_order=False):
                if channel.message_encoding != "protobuf":
                    raise Unreadable("message encoding")
                key = None if schema is None else (schema.id, schema.name, schema.encoding, schema.data)
                if key not in classes:
                    classes[key] = _scan_class(schema)
                msg = classes[key]()
                msg.ParseFromString(message.data)
                for run, scan, t, arrays in decode_scan_message(msg):
                    channel_frames = frames.setdefault(channel.topic, {})
                    if (run, scan) in channel_frames:
                        raise Unreadable(f"frame run {run} scan {scan} of {channel.topic} twice")
                    channel_frames[(run, scan)] = (t, arrays)
    except Unreadable:
        raise
    except Exception as exc:  # whatever the plain reader or protobuf says: not readable by them
        raise Unreadable(f"{type(exc).__name__}: {exc}") from None
    layout_text = metadata.pop(LAYOUT_RECORD, None)
    if layout_text is not None:
        for topic, text in layout_text.items():
            try:
                v = json.loads(text)
                runs, scans, count = int(v["runs"]), int(v["scans"]), int(v["frames"])
            except Exception:
                raise Unreadable("layout record") from None
            held = frames.get(topic, {})
            if len(held) != count or any(r >= runs or k >= scans for r, k in held):
                raise Unreadable(f"layout record disagrees with {topic}")
    return Content(metadata, frames)


def write_content(content: Content, path: Path) -> None:
    """The frames written afresh by the project's writer, scan by scan (the reference a mutant
    holding other frames is judged against)."""
    from trackreplay.contract import write_dataset

    order = sorted({(k[1], k[0], topic) for topic, frames in content.frames.items() for k in frames})
    with write_dataset(path, content.metadata) as w:
        for scan, run, topic in order:
            t, arrays = content.frames[topic][(run, scan)]
            w.write(topic, run, scan, t, {n: np.array(a) for n, a in arrays.items()})


# --------------------------------------------------------------------------- mutations

HUGE = (2**64 - 1, 2**63 - 1, 2**63, 2**40, 2**32 + 1, 2**32 - 1, 2**31, 2**24, 65537)
HUGE32 = (2**32 - 1, 2**31, 2**24, 2**20 + 1, 65536)
TIMES = (-1.0, -1e3, -0.0, float("nan"), float("inf"), -float("inf"), 1e10, 2e10, 1e300, 5e-324, 0.0)
NUMBERS = (float("nan"), float("inf"), -float("inf"), -1.0, 0.0, -0.0, 1e12, 1e300, -1e300, 5e-324, 1.0)


def _messages(model: McapModel) -> list[tuple[int, int]]:
    return [(i, j) for i, recs in enumerate(model.chunks) for j, r in enumerate(recs) if isinstance(r, Message)]


def _copy(model: McapModel) -> McapModel:
    return replace(model, chunks=[list(c) for c in model.chunks], metadata_before=list(model.metadata_before),
                   metadata_after=list(model.metadata_after))


def _schema_of(model: McapModel, channel_id: int) -> Schema | None:
    channels = {r.id: r for c in model.chunks for r in c if isinstance(r, Channel)}
    schemas = {r.id: r for c in model.chunks for r in c if isinstance(r, Schema)}
    ch = channels.get(channel_id)
    return None if ch is None else schemas.get(ch.schema_id)


def _f4(x: float) -> bytes:
    with np.errstate(over="ignore"):  # 1e300 becomes inf in float32, as intended
        return np.array(x, "<f4").tobytes()


def _bytes_edit(data: bytes, rng: random.Random) -> bytes:
    """A structured edit of a little-endian byte string of numbers."""
    kind = rng.randrange(7)
    b = bytearray(data)
    if kind == 0 or not b:
        return bytes(b) + bytes(rng.randrange(256) for _ in range(rng.choice([1, 4, 8, 16])))
    if kind == 1:
        return bytes(b[:rng.randrange(len(b))])
    if kind == 2:  # a float64 value replaced by an extreme one, at an 8-byte boundary
        if len(b) >= 8:
            i = 8 * rng.randrange(len(b) // 8)
            b[i:i + 8] = struct.pack("<d", rng.choice(NUMBERS))
        return bytes(b)
    if kind == 3:  # a float32 / uint32 slot
        if len(b) >= 4:
            i = 4 * rng.randrange(len(b) // 4)
            b[i:i + 4] = rng.choice([_f4(rng.choice(NUMBERS)), struct.pack("<I", rng.choice(HUGE32))])
        return bytes(b)
    if kind == 4:  # an int64 slot made huge or negative
        if len(b) >= 8:
            i = 8 * rng.randrange(len(b) // 8)
            b[i:i + 8] = struct.pack("<q", rng.choice([-1, -2**63, 2**62, 2**31, 1]))
        return bytes(b)
    if kind == 5:
        i = rng.randrange(len(b))
        b[i] ^= 1 << rng.randrange(8)
        return bytes(b)
    return b""


def mutate_scan_field(model: McapModel, rng: random.Random) -> bytes:
    """One field of one Scan message (or of one of its columns or entries) changed."""
    model = _copy(model)
    ci, j = rng.choice(_messages(model))
    msg_rec = model.chunks[ci][j]
    scan_cls = _scan_class(_schema_of(model, msg_rec.channel_id))
    msg = scan_cls.FromString(msg_rec.data)
    target = rng.randrange(14)
    cols = list(msg.columns)
    col = rng.choice(cols) if cols else None
    if target == 0:
        msg.scan = rng.choice([msg.scan + 1, max(0, msg.scan - 1), 2**24, 2**32 - 1, 2**24 - 1, 0])
    elif target == 1:
        msg.time_s = rng.choice(TIMES + (msg.time_s + 1e-9, msg.time_s * 2))
    elif target == 2:
        msg.first_run = rng.choice([msg.first_run + 1, 2**24, 2**32 - msg.frame_count, 2**32 - 1, 1])
    elif target == 3:
        msg.frame_count = rng.choice([0, msg.frame_count + 1, max(0, msg.frame_count - 1), 2**20, 2**20 + 1,
                                      2**32 - 1])
    elif target == 4:
        runs = np.arange(msg.first_run, msg.first_run + msg.frame_count, dtype="<u4")
        choice = rng.randrange(4)
        if choice == 0 and runs.size > 1:
            runs[1] = runs[0]  # a duplicated run
        elif choice == 1:
            runs = runs[::-1].copy()
        elif choice == 2:
            runs[-1] = rng.choice(HUGE32)
        msg.runs = runs.tobytes() if choice != 3 else _bytes_edit(runs.tobytes(), rng)
    elif target == 5:
        times = np.full(msg.frame_count, msg.time_s, "<f8")
        if times.size:
            times[rng.randrange(times.size)] = rng.choice(TIMES)
        msg.times_s = rng.choice([times.tobytes(), times.tobytes()[:-8], _bytes_edit(times.tobytes(), rng)])
    elif col is None:
        msg.columns.add(name="extra", dtype="<f8", values=b"\0" * 8 * msg.frame_count)
    elif target == 6:
        others = [c.name for c in cols if c.name != col.name]
        col.name = rng.choice(others + ["", "x" * 300, col.name.upper(), col.name + "_", "\u00e9\u20ac"])
    elif target == 7:
        col.dtype = rng.choice(sorted(ALLOWED_DTYPES) + [">f8", "<f16", "O", "", "<U4", "<M8", "V8"])
    elif target == 8:
        shape = list(col.shape)
        choice = rng.randrange(5)
        if choice == 0:
            shape.append(rng.choice([1, 2, 0, 2**31]))
        elif choice == 1 and shape:
            shape.pop()
        elif choice == 2 and shape:
            shape[rng.randrange(len(shape))] = rng.choice([0, 1, 2**31, 2**32 - 1, 3])
        elif choice == 3:
            shape = [0, 2**31 + 1]
        else:
            shape = shape[::-1]
        del col.shape[:]
        col.shape.extend(shape)
    elif target == 9:
        if col.layout == 2 and col.entries:
            e = rng.choice(list(col.entries))
            which = rng.randrange(3)
            if which == 0:
                e.data = _bytes_edit(e.data, rng)
            elif which == 1:
                e.dtype = rng.choice(sorted(ALLOWED_DTYPES) + ["O", ""])
            else:
                del e.shape[:]
                e.shape.extend(rng.choice([[], [2**31], [0], [1, 1]]))
        else:
            col.values = _bytes_edit(col.values, rng)
    elif target == 10:
        off = np.frombuffer(col.offsets, "<i8").copy() if col.offsets and len(col.offsets) % 8 == 0 else \
            np.zeros(msg.frame_count + 1, "<i8")
        if off.size:
            off[rng.randrange(off.size)] = rng.choice([-1, 2**62, 2**31, int(off[-1]) + 1, 0])
        col.offsets = rng.choice([off.tobytes(), off.tobytes()[:-8], _bytes_edit(off.tobytes(), rng)])
    elif target == 11:
        n = msg.frame_count
        col.frames = rng.choice([np.arange(n, dtype="<u4")[::-1].tobytes(), np.array([n], "<u4").tobytes(),
                                 np.zeros(2, "<u4").tobytes(), b"\1\0", np.arange(max(0, n - 1), dtype="<u4").tobytes()])
    elif target == 12:
        col.layout = rng.choice([0, 1, 2, 3, 7, 2**31 - 1])
    else:
        choice = rng.randrange(4)
        if choice == 0:
            del msg.columns[cols.index(col)]
        elif choice == 1:
            msg.columns.add().CopyFrom(col)
        elif choice == 2:
            msg.columns.add(name="unexpected", dtype="<f8", values=b"\0" * 8 * msg.frame_count)
        else:  # an unknown field number: readers must skip it
            return assemble(_with_message(model, ci, j, msg.SerializeToString() + b"\xf8\x06\x01"))
    return assemble(_with_message(model, ci, j, msg.SerializeToString()))


def mutate_every_scan(model: McapModel, rng: random.Random) -> bytes:
    """One change made to every Scan message alike, so that the file stays consistent with itself:
    every time shifted (below zero too) or scaled, scan indices spread or moved, runs renumbered."""
    model = _copy(model)
    choice = rng.randrange(6)
    shift = rng.choice([-1000.0, -1e-9, -5.0, 1e10, 0.5, -1e10])
    scale = rng.choice([1e9, 1e-12, 0.0, -1.0, 3.0])
    scan_step = rng.choice([2, 1000, 2**16])
    run_shift = rng.choice([1, 5, 2**24 - 4, 2**20])
    for ci, j in _messages(model):
        rec = model.chunks[ci][j]
        msg = _scan_class(_schema_of(model, rec.channel_id)).FromString(rec.data)
        if choice == 0:
            msg.time_s = msg.time_s + shift
        elif choice == 1:
            msg.time_s = msg.time_s * scale
        elif choice == 2:
            msg.scan = msg.scan * scan_step
        elif choice == 3:
            msg.scan = msg.scan + run_shift
        elif choice == 4:
            msg.first_run = msg.first_run + run_shift
        else:  # times as a per-frame list instead of one time (the same values: the same data)
            msg.times_s = np.full(msg.frame_count, msg.time_s, "<f8").tobytes()
        _with_message(model, ci, j, msg.SerializeToString())
    if choice in (2, 3, 4):  # the layout record would refuse the new indices: drop it (a reader may not need it)
        model.metadata_before = [m for m in model.metadata_before if m.name != LAYOUT_RECORD]
        model.metadata_after = [m for m in model.metadata_after if m.name != LAYOUT_RECORD]
    return assemble(model)


def _with_message(model: McapModel, ci: int, j: int, data: bytes, **fields) -> McapModel:
    model.chunks[ci][j] = replace(model.chunks[ci][j], data=data, **fields)
    return model


def mutate_message_record(model: McapModel, rng: random.Random) -> bytes:
    """A Message record's header: log time, channel id, sequence, or its payload cut."""
    model = _copy(model)
    ci, j = rng.choice(_messages(model))
    m = model.chunks[ci][j]
    choice = rng.randrange(5)
    if choice == 0:
        return assemble(_with_message(model, ci, j, m.data, log_time=rng.choice([0, 2**63, 2**64 - 1, m.log_time + 1])))
    if choice == 1:
        ids = sorted({r.id for c in model.chunks for r in c if isinstance(r, Channel)})
        return assemble(_with_message(model, ci, j, m.data, channel_id=rng.choice(ids + [0, 999, 65535])))
    if choice == 2:
        return assemble(_with_message(model, ci, j, m.data, sequence=rng.choice([0, 2**32 - 1])))
    if choice == 3:
        return assemble(_with_message(model, ci, j, m.data[:rng.randrange(len(m.data) + 1)]))
    # the same message twice, or moved to another chunk
    other = rng.randrange(len(model.chunks))
    if rng.random() < 0.5:
        model.chunks[other].append(m)
    else:
        del model.chunks[ci][j]
        model.chunks[other].append(m)
    return assemble(model)


def mutate_chunk_inside(model: McapModel, rng: random.Random) -> bytes:
    """Damage inside one chunk's uncompressed records, its CRC recomputed so the damage reaches
    the decoder: a huge or off-by-one length prefix at a real inner record boundary (or in a
    Schema/Channel string length), another opcode, random bytes, a cut or an extra record."""
    i = rng.randrange(len(model.chunks))
    choice = rng.randrange(6)

    def inner(raw: bytes, offsets: list) -> bytes:
        b = bytearray(raw)
        at = rng.choice(offsets) if offsets else 0
        if choice == 0 and offsets:  # the record's length prefix
            length = struct.unpack_from("<Q", b, at + 1)[0]
            struct.pack_into("<Q", b, at + 1, rng.choice(HUGE + (length + 1, max(0, length - 1), 0)) % 2**64)
        elif choice == 1 and offsets:  # a length prefix inside the record (first 4- or 8-byte field after fixed parts)
            pos = at + 9 + rng.choice([0, 2, 4, 6, 8, 12, 16, 22])
            if pos + 4 <= len(b):
                struct.pack_into("<I", b, pos, rng.choice(HUGE32 + (0, 1)))
        elif choice == 2 and offsets:
            b[at] = rng.choice([0, Opcode.CHUNK, Opcode.FOOTER, Opcode.METADATA, Opcode.DATA_END, 0x80, 0xFF])
        elif choice == 3:
            for _ in range(rng.randint(1, 8)):
                k = rng.randrange(len(b))
                b[k] = rng.randrange(256)
        elif choice == 4:
            del b[rng.randrange(len(b)):]
        else:
            extra = struct.pack("<BQ", rng.choice([Opcode.MESSAGE, Opcode.CHANNEL, Opcode.SCHEMA, 0x42]),
                                rng.choice([0, 4, 22, 2**40]))
            b[at:at] = extra + b"\0" * rng.choice([0, 4, 22])
        return bytes(b)

    return assemble(model, ChunkDamage(i, inner=inner))


def mutate_chunk_compression(model: McapModel, rng: random.Random) -> bytes:
    """A chunk marked lz4 or zstd holding other bytes, a wrong declared size, an unknown
    compression, or a stale CRC."""
    i = rng.randrange(len(model.chunks))
    choice = rng.randrange(7)
    if choice == 0:  # marked lz4, holding zstd bytes / raw records / garbage
        actual = rng.choice(["zstd", ""])
        return assemble(model, ChunkDamage(i, label="lz4", actual=actual))
    if choice == 1:
        return assemble(model, ChunkDamage(i, label="zstd", actual=rng.choice(["lz4", ""])))
    if choice == 2:
        return assemble(model, ChunkDamage(i, label="", actual=rng.choice(["lz4", "zstd"])))
    if choice == 3:
        return assemble(model, ChunkDamage(i, label=rng.choice(["gzip", "LZ4", "zstd ", "\u00ff"])))
    if choice == 4:
        return assemble(model, ChunkDamage(i, size_delta=rng.choice([-1, 1, 2**30, 2**40, -10**6])))
    if choice == 5:  # lz4-marked garbage that starts like an lz4 frame
        return assemble(model, ChunkDamage(i, label="lz4", actual="",
                                           inner=lambda raw, offs: b"\x04\x22\x4d\x18" + raw[4:]))
    return assemble(model, ChunkDamage(i, inner=lambda raw, offs: raw[:-1] + bytes([raw[-1] ^ 1]), keep_crc=True))


def mutate_channels(model: McapModel, rng: random.Random) -> bytes:
    """Channels duplicated, renamed, swapped or pointed at a missing schema; message encodings."""
    model = _copy(model)
    where = [(i, j) for i, c in enumerate(model.chunks) for j, r in enumerate(c) if isinstance(r, Channel)]
    ci, j = rng.choice(where)
    ch = model.chunks[ci][j]
    topics = sorted({model.chunks[a][b].topic for a, b in where})
    choice = rng.randrange(6)
    if choice == 0:  # a second channel with the same topic carries some (or copies of all) messages
        new_id = max(model.chunks[a][b].id for a, b in where) + 1
        model.chunks[ci].insert(j + 1, replace(ch, id=new_id))
        copy_all = rng.random() < 0.3
        for c in model.chunks:
            for k, r in list(enumerate(c)):
                if isinstance(r, Message) and r.channel_id == ch.id and (copy_all or rng.random() < 0.5):
                    if copy_all:
                        c.append(replace(r, channel_id=new_id))
                    else:
                        c[k] = replace(r, channel_id=new_id)
    elif choice == 1:
        model.chunks[ci][j] = replace(ch, topic=rng.choice(topics + ["/radar/plotz", "", "/tracks/radar/kalman",
                                                                     ch.topic + "/", "/RADAR/PLOTS"]))
    elif choice == 2 and len(where) > 1:
        (a, b), (c_, d) = rng.sample(where, 2)
        t1, t2 = model.chunks[a][b].topic, model.chunks[c_][d].topic
        model.chunks[a][b] = replace(model.chunks[a][b], topic=t2)
        model.chunks[c_][d] = replace(model.chunks[c_][d], topic=t1)
    elif choice == 3:
        model.chunks[ci][j] = replace(ch, schema_id=rng.choice([0, 2, 77]))
    elif choice == 4:
        model.chunks[ci][j] = replace(ch, message_encoding=rng.choice(["json", "cdr", "", "protobuf2"]))
    else:
        model.chunks[ci][j] = replace(ch, metadata={"contract": rng.choice(["replay.v1", "", "replay.v9"])})
    return assemble(model)


def mutate_schema(model: McapModel, rng: random.Random) -> bytes:
    """A wrong schema: another name, another encoding, descriptor bytes damaged or of another
    message, or a second schema for the same channel."""
    model = _copy(model)
    where = [(i, j) for i, c in enumerate(model.chunks) for j, r in enumerate(c) if isinstance(r, Schema)]
    ci, j = rng.choice(where)
    s = model.chunks[ci][j]
    choice = rng.randrange(5)
    if choice == 0:
        model.chunks[ci][j] = replace(s, name=rng.choice(["replay.v1.Frame", "replay.v2.Column", "replay.v2.Scan2",
                                                          "", "Scan", "replay.v2.Array"]))
    elif choice == 1:
        model.chunks[ci][j] = replace(s, encoding=rng.choice(["jsonschema", "ros2msg", "", "flatbuffer"]))
    elif choice == 2:
        model.chunks[ci][j] = replace(s, data=_bytes_edit(s.data, rng))
    elif choice == 3:  # the v1 Frame descriptor under the v2 name (and so v2 bytes read by another layout)
        from google.protobuf import descriptor_pb2

        fds = descriptor_pb2.FileDescriptorSet.FromString(s.data)
        for msg in fds.file[0].message_type:
            if msg.name == "Scan":
                for f in msg.field:
                    if f.name == "frame_count":
                        f.number, f.name = 8, "unused"
                    elif f.name == "first_run":
                        f.type = descriptor_pb2.FieldDescriptorProto.TYPE_INT64
        model.chunks[ci][j] = replace(s, data=fds.SerializeToString())
    else:
        model.chunks[ci].insert(j + 1, replace(s, data=b"\x0a\x00"))
    return assemble(model)


def _deep_json(depth: int) -> str:
    return "[" * depth + "]" * depth


def mutate_metadata(model: McapModel, rng: random.Random) -> bytes:
    """The layout or scenario record changed: counts, JSON that does not parse or nests deeply,
    values of the wrong type, the record repeated or removed."""
    model = _copy(model)
    lists = [model.metadata_before, model.metadata_after]
    records = [(li, k) for li, lst in enumerate(lists) for k in range(len(lst))]
    li, k = rng.choice(records)
    rec = lists[li][k]
    values = dict(rec.metadata)
    choice = rng.randrange(6)
    key = rng.choice(sorted(values)) if values else "x"
    if choice == 0 and values:
        try:
            v = json.loads(values[key])
        except ValueError:
            v = None
        if isinstance(v, dict) and v:
            sub = rng.choice(sorted(v))
            v[sub] = rng.choice([-1, 0, 2**24, 2**63, 1e300, "3", None, [1], float("nan"), True])
            values[key] = json.dumps(v)
        else:
            values[key] = rng.choice(["-1", "1e400", "nan", "", "0"])
    elif choice == 1:
        values[key] = rng.choice(["{", "]", _deep_json(100000), '{"a": ' + _deep_json(5000) + "}", "\x00", "[]"])
    elif choice == 2:
        values.pop(key, None)
    elif choice == 3:
        lists[li].insert(k, Metadata(name=rec.name, metadata=dict(rec.metadata)))
        return assemble(model)
    elif choice == 4:
        del lists[li][k]
        return assemble(model)
    else:
        values[rng.choice(["/radar/plots", "/x", key + "2"])] = json.dumps({"frames": 1, "runs": 1, "scans": 1})
    lists[li][k] = Metadata(name=rec.name, metadata=values)
    return assemble(model)


def mutate_top_level(data: bytes, rng: random.Random) -> bytes:
    """A huge or off-by-one length prefix at a real top-level record boundary, or a length field
    inside a record (a chunk's data length, a string length), CRCs left as they were."""
    b = bytearray(data)
    bounds = record_boundaries(data)
    at, op, length = rng.choice(bounds)
    choice = rng.randrange(3)
    if choice == 0:
        struct.pack_into("<Q", b, at + 1, rng.choice(HUGE + (length + 1, max(0, length - 1), 0)) % 2**64)
    elif choice == 1 and op == Opcode.CHUNK:
        # Chunk: start(8) end(8) size(8) crc(4) compression(4+n) data_len(8) data
        comp_len = struct.unpack_from("<I", b, at + 9 + 28)[0]
        field_at = rng.choice([at + 9 + 16, at + 9 + 28, at + 9 + 32 + comp_len])
        width = 4 if field_at == at + 9 + 28 else 8
        struct.pack_into("<I" if width == 4 else "<Q", b, field_at,
                         rng.choice(HUGE32 if width == 4 else HUGE) % (2**32 if width == 4 else 2**64))
    else:
        pos = at + 9 + rng.choice([0, 2, 4, 8, 16])
        if pos + 4 <= len(b):
            struct.pack_into("<I", b, pos, rng.choice(HUGE32 + (0,)))
    return bytes(b)


def mutate_bytes(data: bytes, rng: random.Random) -> bytes:
    """Blind damage: bit flips, byte overwrites, a truncation, a deleted or duplicated span, or a
    large integer written over a field."""
    b = bytearray(data)
    kind = rng.randrange(6)
    if kind == 0:
        for _ in range(rng.randint(1, 4)):
            i = rng.randrange(len(b))
            b[i] ^= 1 << rng.randrange(8)
    elif kind == 1:
        i = rng.randrange(len(b))
        for j in range(i, min(len(b), i + rng.randint(1, 16))):
            b[j] = rng.randrange(256)
    elif kind == 2:
        del b[rng.randrange(len(b)):]
    elif kind == 3:
        i = rng.randrange(len(b))
        del b[i:i + rng.randint(1, 64)]
    elif kind == 4:
        i = rng.randrange(len(b))
        b[i:i] = b[i:i + rng.randint(1, 256)]
    else:
        i = rng.randrange(max(1, len(b) - 8))
        b[i:i + 8] = rng.choice([2**63 - 1, 2**32, 65536, 2**40]).to_bytes(8, "little")
    return bytes(b)


# (name, weight, function of (model, original bytes, rng))
MUTATIONS = (
    ("scan_field", 30, lambda m, d, r: mutate_scan_field(m, r)),
    ("every_scan", 6, lambda m, d, r: mutate_every_scan(m, r)),
    ("message_record", 6, lambda m, d, r: mutate_message_record(m, r)),
    ("chunk_inside", 14, lambda m, d, r: mutate_chunk_inside(m, r)),
    ("chunk_compression", 8, lambda m, d, r: mutate_chunk_compression(m, r)),
    ("channels", 8, lambda m, d, r: mutate_channels(m, r)),
    ("schema", 6, lambda m, d, r: mutate_schema(m, r)),
    ("metadata", 8, lambda m, d, r: mutate_metadata(m, r)),
    ("top_level_length", 8, lambda m, d, r: mutate_top_level(d, r)),
    ("bytes", 12, lambda m, d, r: mutate_bytes(d, r)),
)


def make_mutant(bases: dict, seed: int, i: int) -> tuple[str, str, bytes]:
    """Mutant ``i`` of seed ``seed``: (base name, mutation name, bytes); the same for any order
    or number of workers."""
    rng = random.Random(f"{seed}:{i}")
    base = rng.choice(sorted(bases))
    names = [m[0] for m in MUTATIONS]
    kind = rng.choices(names, weights=[m[1] for m in MUTATIONS])[0]
    fn = dict((m[0], m[2]) for m in MUTATIONS)[kind]
    model, data = bases[base]["model"], bases[base]["bytes"]
    return base, kind, fn(model, data, rng)


# --------------------------------------------------------------------------- running the tool


def _invoke(args: list[str]) -> dict:
    """The CLI in this process: exit code, stdout, stderr, and a traceback if one escaped."""
    from click.testing import CliRunner

    from trackreplay.face.cli import main

    res = CliRunner().invoke(main, args)
    tb = None
    if res.exception is not None and not isinstance(res.exception, SystemExit):
        tb = "".join(traceback.format_exception(res.exception))
    elif "Traceback (most recent call last)" in res.output:
        tb = res.output
    return {"code": res.exit_code, "stdout": res.stdout, "stderr": res.stderr, "traceback": tb}


def run_tool(path: Path, out: Path) -> dict:
    """``replay eval PATH --json`` and ``replay PATH`` (outputs in ``out``) on one file."""
    before = path.read_bytes()
    ev = _invoke(["eval", str(path), "--json"])
    if out.exists():
        shutil.rmtree(out)
    rn = _invoke([str(path), "--out", str(out / "tracks.mcap"), "--no-rrd", "--figures", "none"])
    metrics = out / "metrics.csv"
    rn["metrics"] = metrics.read_text() if rn["code"] == 0 and metrics.exists() else None
    rn["left_output"] = out.exists() and rn["code"] != 0 and _one_line(rn["stderr"], path)
    modified = path.read_bytes() != before
    if out.exists():
        shutil.rmtree(out)
    return {"eval": ev, "run": rn, "input_modified": modified}


def _one_line(stderr: str, path: Path) -> bool:
    lines = [line for line in stderr.splitlines() if line.strip()]
    return len(lines) == 1 and lines[0].startswith(f"replay: error: {path}: ")


def _error_lines_only(stderr: str) -> bool:
    lines = [line for line in stderr.splitlines() if line.strip()]
    return bool(lines) and all(line.startswith("replay: error: ") for line in lines)


def reference(path: Path, folder: Path) -> dict:
    """What the tool reports for a sound file: eval's JSON and replay's metrics.csv."""
    r = run_tool(path, folder / "ref-out")
    return {"eval": r["eval"]["stdout"] if r["eval"]["code"] == 0 else None,
            "run": r["run"]["metrics"], "codes": (r["eval"]["code"], r["run"]["code"]),
            "stderr": r["eval"]["stderr"] + r["run"]["stderr"]}


OUTCOMES = ("refused_one_line", "refused_per_tracker", "accepted_correct", "exit3", "silent_corruption",
            "traceback", "hang", "input_modified", "not_one_line", "left_output", "inconsistent")
FAILURES = ("exit3", "silent_corruption", "traceback", "hang", "input_modified", "not_one_line", "left_output")


def judge(path: Path, result: dict, original: Content, original_ref: dict, folder: Path) -> tuple[str, str]:
    """One outcome (see OUTCOMES) and a short description for a mutant's two runs."""
    ev, rn = result["eval"], result["run"]
    if ev["traceback"] or rn["traceback"]:
        tb = ev["traceback"] or rn["traceback"]
        return "traceback", tb.strip().splitlines()[-1]
    if 3 in (ev["code"], rn["code"]):
        return "exit3", (ev["stderr"] + rn["stderr"]).strip().splitlines()[-1]
    if result["input_modified"]:
        return "input_modified", "the input changed"
    if rn.get("left_output"):
        return "left_output", "a refused replay left its output folder"
    for r in (ev, rn):
        if r["code"] not in (0, 2) or (r["code"] == 2 and not _error_lines_only(r["stderr"])):
            return "not_one_line", f"exit {r['code']}: {r['stderr'].strip()[-300:]}"
    accepted = [ev["code"] == 0, rn["code"] == 0]
    if not any(accepted):
        if _one_line(ev["stderr"], path) and _one_line(rn["stderr"], path):
            return "refused_one_line", ev["stderr"].strip()
        return "refused_per_tracker", ev["stderr"].strip().splitlines()[0]
    # accepted by at least one: what does the file hold?
    try:
        content = decode_independently(path)
        same = content.same_as(original)
        why = "same frames as the original" if same else "other frames"
    except Unreadable as exc:
        content, same, why = None, None, f"independent decoder: {exc}"
    if same or content is None:
        ref = original_ref
    else:
        clean = folder / "clean.mcap"
        try:
            write_content(content, clean)
        except Exception as exc:  # the writer refuses what the reader accepted
            return "silent_corruption", f"accepted, but its frames cannot be written ({type(exc).__name__}: {exc})"
        ref = reference(clean, folder)
    if ev["code"] == 0 and ev["stdout"] != ref["eval"]:
        return "silent_corruption", f"eval accepted with other metrics ({why})"
    if rn["code"] == 0 and rn["metrics"] != ref["run"]:
        return "silent_corruption", f"replay accepted with other metrics ({why})"
    if not all(accepted):
        return "inconsistent", f"eval exit {ev['code']}, replay exit {rn['code']}: " \
                               f"{(ev['stderr'] + rn['stderr']).strip()[:300]}"
    return "accepted_correct", why


# --------------------------------------------------------------------------- workers


def _worker(conn, bases_ref: dict, folder: Path) -> None:
    """Runs mutants sent by the parent: (i, base, path) -> (i, outcome, description).

    The worker first runs the tool on every base file itself: a mutant is compared with what
    the same code, in the same process, reports for its original (the project's modules may
    change on disk during a long run; a reference from another process could then differ)."""
    import warnings

    warnings.filterwarnings("ignore")
    bases_ref = {name: dict(b) for name, b in bases_ref.items()}
    for name, b in bases_ref.items():
        original = folder / f"base-{name}.mcap"
        original.write_bytes(b["bytes"])
        b["ref"] = reference(original, folder)
    while True:
        job = conn.recv()
        if job is None:
            return
        i, base, path = job
        try:
            result = run_tool(Path(path), folder / "out")
            outcome = judge(Path(path), result, bases_ref[base]["content"], bases_ref[base]["ref"], folder)
        except BaseException as exc:  # the fuzzer's own failure: reported, never hidden
            outcome = ("traceback", f"in the fuzzer: {type(exc).__name__}: {exc}")
        conn.send((i, *outcome))


class _Pool:
    """Worker processes, one mutant each at a time; a worker that passes the time limit is killed
    (by its own pid) and replaced. Workers are spawned, not forked: the parent has run the tool
    (polars and zstd thread pools), and a fork of a process with threads can deadlock."""

    def __init__(self, jobs: int, bases: dict, folder: Path):
        import multiprocessing

        self.ctx = multiprocessing.get_context("spawn")
        self.bases, self.folder = bases, folder
        self.workers = [self._start(k) for k in range(jobs)]

    def _start(self, k: int):
        parent, child = self.ctx.Pipe()
        wf = self.folder / f"w{k}"
        wf.mkdir(exist_ok=True)
        proc = self.ctx.Process(target=_worker, args=(child, self.bases, wf), daemon=True)
        proc.start()
        return {"proc": proc, "conn": parent, "folder": wf, "job": None, "since": 0.0}

    def run(self, jobs, timeout: float):
        """Yields (i, base, kind, outcome, description) for every job ``(i, base, kind, bytes)``."""
        jobs = iter(jobs)
        pending = True
        while True:
            for k, w in enumerate(self.workers):
                if w["job"] is None and pending:
                    try:
                        i, base, kind, data = next(jobs)
                    except StopIteration:
                        pending = False
                        continue
                    path = w["folder"] / f"mutant-{base}.mcap"
                    path.write_bytes(data)
                    w["job"], w["since"] = (i, base, kind), time.monotonic()
                    w["conn"].send((i, base, str(path)))
            busy = [w for w in self.workers if w["job"] is not None]
            if not busy and not pending:
                break
            from multiprocessing.connection import wait

            ready = wait([w["conn"] for w in busy], timeout=1.0)
            for k, w in enumerate(self.workers):
                if w["job"] is None:
                    continue
                if w["conn"] in ready:
                    try:
                        i, outcome, text = w["conn"].recv()
                    except EOFError:  # the worker died: the tool ended the process
                        i, outcome, text = w["job"][0], "traceback", "the process ended without a word"
                        self._replace(k)
                    yield i, w["job"][1], w["job"][2], outcome, text
                    w["job"] = None
                elif time.monotonic() - w["since"] > timeout:
                    i, base, kind = w["job"]
                    self._replace(k)
                    yield i, base, kind, "hang", f"no answer within {timeout:.0f} s"

    def _replace(self, k: int) -> None:
        w = self.workers[k]
        if w["proc"].is_alive():
            w["proc"].kill()
        w["proc"].join()
        self.workers[k] = self._start(k)

    def close(self) -> None:
        for w in self.workers:
            if w["proc"].is_alive():
                w["conn"].send(None)
                w["proc"].join(5)
                if w["proc"].is_alive():
                    w["proc"].kill()


def prepare_bases(folder: Path, names=None) -> dict:
    """Every base file: its bytes, its records, what the independent decoder reads from it, and
    what the tool reports for it; plus ``radar-lz4``, the radar file with lz4 chunks."""
    bases = {}
    for name, scenario, runs, overrides in BASES:
        if names is not None and name not in names:
            continue
        path = small_dataset(folder, scenario, runs, overrides, name)
        bases[name] = {"bytes": path.read_bytes(), "model": parse(path.read_bytes())}
    if "radar" in bases:
        lz4_model = replace(bases["radar"]["model"], compression="lz4")
        bases["radar-lz4"] = {"bytes": assemble(lz4_model), "model": lz4_model}
    for name, b in bases.items():
        path = folder / f"{name}.mcap"
        path.write_bytes(b["bytes"])
        b["content"] = decode_independently(path)
        b["ref"] = reference(path, folder)
        assert b["ref"]["codes"] == (0, 0), (name, b["ref"]["stderr"])
        # the assembler itself: the file rebuilt from its records reads as the original
        rebuilt = folder / f"{name}-rebuilt.mcap"
        rebuilt.write_bytes(assemble(b["model"]))
        assert decode_independently(rebuilt).same_as(b["content"]), name
    return bases


def run(mutants: int, seed: int, folder: Path | None = None, jobs: int = 1, timeout: float = 120.0,
        names=None, progress: int = 0) -> dict:
    """Fuzz ``mutants`` mutants; returns the count of each outcome, per mutation kind too, and
    examples of every failure."""
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(folder or tmp)
        bases = prepare_bases(folder, names)
        counts = {o: 0 for o in OUTCOMES}
        counts["tried"] = 0
        by_kind: dict = {}
        by_base: dict = {}
        examples: list = []
        pool = _Pool(jobs, bases, folder)
        t0 = time.monotonic()
        try:
            gen = ((i, *make_mutant(bases, seed, i)) for i in range(mutants))
            for i, base, kind, outcome, text in pool.run(gen, timeout):
                counts["tried"] += 1
                counts[outcome] += 1
                by_kind.setdefault(kind, {}).setdefault(outcome, 0)
                by_kind[kind][outcome] += 1
                by_base.setdefault(base, {}).setdefault(outcome, 0)
                by_base[base][outcome] += 1
                if outcome in FAILURES or outcome == "inconsistent" or outcome == "refused_per_tracker":
                    examples.append(f"mutant {i} ({base}, {kind}): {outcome}: {text}")
                if progress == 1:
                    print(f"  mutant {i} ({base}, {kind}): {outcome}: {text[:200]}", flush=True)
                elif progress and counts["tried"] % progress == 0:
                    print(f"  {counts['tried']} mutants, {time.monotonic() - t0:.0f} s: "
                          + ", ".join(f"{o} {counts[o]}" for o in OUTCOMES if counts[o]), flush=True)
        finally:
            pool.close()
        counts["by_kind"], counts["by_base"], counts["examples"] = by_kind, by_base, examples
        counts["failures"] = sum(counts[o] for o in FAILURES)
        return counts


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--mutants", type=int, default=10000)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--jobs", type=int, default=1, help="worker processes (default 1)")
    ap.add_argument("--timeout", type=float, default=120.0, help="seconds a mutant may take before it is a hang")
    ap.add_argument("--progress", type=int, default=250, help="print the counts every this many mutants "
                    "(1: every mutant's outcome)")
    ap.add_argument("--json", type=Path, help="also write the counts and examples to this file")
    args = ap.parse_args()
    t0 = time.perf_counter()
    c = run(args.mutants, args.seed, jobs=args.jobs, timeout=args.timeout, progress=args.progress)
    print(f"seed {args.seed}: mutants tried {c['tried']}, refused with one line {c['refused_one_line']}, "
          f"refused with one line per failed tracker {c['refused_per_tracker']}, accepted and correct "
          f"{c['accepted_correct']}, exit 3 {c['exit3']}, silent corruptions {c['silent_corruption']}, "
          f"tracebacks {c['traceback']}, hangs {c['hang']}, inputs modified {c['input_modified']}, "
          f"not one line {c['not_one_line']}, output left behind {c['left_output']}, eval and replay "
          f"disagree {c['inconsistent']} ({time.perf_counter() - t0:.0f} s)")
    for kind, outcomes in sorted(c["by_kind"].items()):
        print(f"  {kind:18s} " + ", ".join(f"{o} {n}" for o, n in sorted(outcomes.items())))
    for base, outcomes in sorted(c["by_base"].items()):
        print(f"  {base:18s} " + ", ".join(f"{o} {n}" for o, n in sorted(outcomes.items())))
    for e in c["examples"][:40]:
        print("  example:", e)
    if args.json:
        args.json.write_text(json.dumps(c, indent=1))
    sys.exit(1 if c["failures"] else 0)


if __name__ == "__main__":
    main()
