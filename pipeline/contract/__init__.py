"""The MCAP data contract: the one module that knows how data sit in a file.

Contract ``replay.v2`` (written by this version) stores one protobuf ``replay.v2.Scan`` message
per channel and scan, carrying every run of that scan column by column; its FileDescriptorSet is
embedded in the file as the schema, so any MCAP tool decodes it without our code::

    message Array  { string name = 1; repeated uint32 shape = 2; string dtype = 3; bytes data = 4; }
    message Column { enum Layout { FIXED = 0; RAGGED = 1; IRREGULAR = 2; SYMMETRIC = 3; }
                     string name = 1; string dtype = 2; repeated uint32 shape = 3; bytes values = 4;
                     bytes offsets = 5; bytes frames = 6; repeated Array entries = 7; Layout layout = 8; }
    message Scan   { uint32 scan = 1; double time_s = 2; uint32 first_run = 3; uint32 frame_count = 4;
                     bytes runs = 5; bytes times_s = 6; repeated Column columns = 7; uint32 scan_count = 8; }

* a *frame* is one Monte Carlo run × one scan of one channel; a ``Scan`` message holds
  ``frame_count`` frames of one scan, runs ``first_run …`` (or the ``<u4`` list ``runs``), all at
  ``time_s`` (or the ``<f8`` list ``times_s``); ``log_time`` is the scan time in nanoseconds;
* a ``Column`` is one named array across those frames (those listed in ``frames``, ``<u4``, when
  not every frame carries it), as raw little-endian bytes with a numpy dtype string:
  ``FIXED``: every entry has ``shape``, ``values`` holds them one after the other;
  ``RAGGED``: entry i is rows ``offsets[i]:offsets[i+1]`` (``<i8``) of ``values`` (rows of
  ``shape``) — the variable-length measurement lists; ``IRREGULAR``: anything else, one
  ``Array`` per entry; ``SYMMETRIC`` (replay outputs only): real matrices symmetric to the bit,
  as their upper triangles (``shape`` is the full entry shape), expanded on reading;
* a *long recording* (at least :data:`GROUP_MIN_SCANS` scans of few runs) groups scans: a message
  with ``scan_count`` > 1 holds scans ``scan … scan + scan_count − 1``, each with the runs
  ``first_run …`` (``frame_count / scan_count`` of them), frames scan-major, their times in
  ``times_s``; the schema lists ``scan_count`` only in files that use it (:func:`scans_per_message`);
* messages are written scan-major, one chunk per scan (per group of scans in a long recording;
  zstd, CRC of every chunk), so log time never goes backwards and a crash loses at most one scan
  (one group);
* a ``replay.layout`` metadata record (written last) states, per channel, the runs, scans and
  frames written; readers check every frame's run and scan against it;
* ground truth lives on its own channels (``/truth/...``) next to the measurements;
* scenario parameters, seed, package and contract version are MCAP metadata records.

Reading decodes each message's columns in bulk (``np.frombuffer``, no per-frame objects); the
per-frame views of :meth:`ChannelData.array` are made only when asked for. Files of contract
``replay.v1`` (one ``replay.v1.Frame`` message per run and scan, see :func:`encode_frame`) still
read, frame by frame; ``replay convert upgrade IN -o OUT`` rewrites them in v2 with identical
arrays. Every chunk's CRC is checked on every read; anything wrong in a file (a CRC mismatch, a
corrupt chunk, an undecodable message, an implausible run or scan index) is an
:class:`~trackreplay.errors.InputError` naming the file and the chunk, and ``recover=True`` keeps
every intact chunk. A reader refuses schemas it does not know instead of guessing.
"""

from __future__ import annotations

import io
import json
import math
import os
import struct
import tempfile
import threading
import zlib
from collections.abc import Mapping as MappingABC
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Iterator, Mapping

import numpy as np
import zstandard
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from google.protobuf.message import DecodeError
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import Channel, Chunk, Footer, Message, Metadata, Schema
from mcap.stream_reader import CRCValidationError, StreamReader
import mcap.writer
from mcap.writer import CompressionType, Writer

from trackreplay import __version__
from trackreplay import vocabulary as vocab
from trackreplay.errors import InputError

CONTRACT_V1 = "replay.v1"
CONTRACT_V2 = "replay.v2"
CONTRACT_VERSION = CONTRACT_V2  # what this version writes
FRAME_SCHEMA_V1 = f"{CONTRACT_V1}.Frame"
SCAN_SCHEMA = f"{CONTRACT_V2}.Scan"
FRAME_SCHEMA = SCAN_SCHEMA  # the schema of the messages new files carry
SCHEMA_CONTRACTS = {FRAME_SCHEMA_V1: CONTRACT_V1, SCAN_SCHEMA: CONTRACT_V2}
METADATA_SCENARIO = "replay.scenario"
METADATA_PROVENANCE = "replay.provenance"
METADATA_LAYOUT = "replay.layout"
MCAP_MAGIC = b"\x89MCAP0\r\n"
_ALLOWED_DTYPES = {"<f8", "<f4", "<c16", "<c8", "<i8", "<i4", "<u4", "<u2", "|u1", "|b1"}

# Sane maxima: what a file may claim before the reader sizes anything by it.
MAX_INDEX = 1 << 24  # largest run or scan index (16.7 million)
MAX_FRAMES_PER_MESSAGE = 1 << 20  # runs in one v2 message (or one batched v1 frame)
FREE_FRAMES = 1 << 20  # frames a file may hold beyond one per byte of decompressed chunk data
MAX_SPARSITY = 64  # a channel's [run, scan] grid may have at most this many cells per frame it holds
MAX_CHUNK_BYTES = 1 << 30  # a chunk's declared uncompressed size
MAX_PADDED_BYTES = 1 << 30  # grid()/ragged() refuse larger outputs that are mostly padding
BLOCK_BYTES = 32 << 20  # the writer closes a message of one channel and scan beyond this
PACK_BLOCK_BYTES = 1 << 20  # scans of a symmetric grid packed in one call (McapFrameWriter.write_grid)

FIXED, RAGGED, IRREGULAR, SYMMETRIC = 0, 1, 2, 3


def _message_classes(fdp: descriptor_pb2.FileDescriptorProto, names: Iterable[str]):
    """Message classes of a file descriptor built at run time (no generated code to keep in sync),
    plus the serialized FileDescriptorSet that goes into the file as the schema."""
    pool = descriptor_pool.DescriptorPool()
    pool.Add(fdp)
    fds = descriptor_pb2.FileDescriptorSet()
    fds.file.add().CopyFrom(fdp)
    classes = [message_factory.GetMessageClass(pool.FindMessageTypeByName(n)) for n in names]
    return (*classes, fds.SerializeToString())


def _add_array_message(fdp) -> None:
    F = descriptor_pb2.FieldDescriptorProto
    arr = fdp.message_type.add(name="Array")
    arr.field.add(name="name", number=1, type=F.TYPE_STRING, label=F.LABEL_OPTIONAL)
    arr.field.add(name="shape", number=2, type=F.TYPE_UINT32, label=F.LABEL_REPEATED)
    arr.field.add(name="dtype", number=3, type=F.TYPE_STRING, label=F.LABEL_OPTIONAL)
    arr.field.add(name="data", number=4, type=F.TYPE_BYTES, label=F.LABEL_OPTIONAL)


def _build_frame_class():
    """``replay.v1.Frame``: one run × one scan (or a batch of runs with ``run_count``)."""
    F = descriptor_pb2.FieldDescriptorProto
    fdp = descriptor_pb2.FileDescriptorProto(name="replay/v1/frame.proto", package=CONTRACT_V1, syntax="proto3")
    _add_array_message(fdp)
    frame = fdp.message_type.add(name="Frame")
    frame.field.add(name="run", number=1, type=F.TYPE_UINT32, label=F.LABEL_OPTIONAL)
    frame.field.add(name="scan", number=2, type=F.TYPE_UINT32, label=F.LABEL_OPTIONAL)
    frame.field.add(name="time_s", number=3, type=F.TYPE_DOUBLE, label=F.LABEL_OPTIONAL)
    frame.field.add(name="arrays", number=4, type=F.TYPE_MESSAGE, label=F.LABEL_REPEATED,
                    type_name=f".{CONTRACT_V1}.Array")
    frame.field.add(name="run_count", number=5, type=F.TYPE_UINT32, label=F.LABEL_OPTIONAL)
    return _message_classes(fdp, [FRAME_SCHEMA_V1])


def _build_scan_class(symmetric: bool = True, grouped: bool = True):
    """``replay.v2.Scan``: every run of one scan of one channel, column by column.

    ``symmetric``: whether the ``Layout`` enum lists ``SYMMETRIC``; ``grouped``: whether ``Scan``
    lists ``scan_count`` (messages of several scans, :func:`scans_per_message`). The schema a file
    carries lists them only when the file may use them (replay outputs; long recordings), so that
    data sets stay byte for byte what earlier versions wrote; the wire format is the same either way.
    """
    F = descriptor_pb2.FieldDescriptorProto
    fdp = descriptor_pb2.FileDescriptorProto(name="replay/v2/scan.proto", package=CONTRACT_V2, syntax="proto3")
    _add_array_message(fdp)
    col = fdp.message_type.add(name="Column")
    layout = col.enum_type.add(name="Layout")
    for number, name in ((FIXED, "FIXED"), (RAGGED, "RAGGED"), (IRREGULAR, "IRREGULAR"),
                         (SYMMETRIC, "SYMMETRIC"))[:4 if symmetric else 3]:
        layout.value.add(name=name, number=number)
    col.field.add(name="name", number=1, type=F.TYPE_STRING, label=F.LABEL_OPTIONAL)
    col.field.add(name="dtype", number=2, type=F.TYPE_STRING, label=F.LABEL_OPTIONAL)
    col.field.add(name="shape", number=3, type=F.TYPE_UINT32, label=F.LABEL_REPEATED)
    col.field.add(name="values", number=4, type=F.TYPE_BYTES, label=F.LABEL_OPTIONAL)
    col.field.add(name="offsets", number=5, type=F.TYPE_BYTES, label=F.LABEL_OPTIONAL)
    col.field.add(name="frames", number=6, type=F.TYPE_BYTES, label=F.LABEL_OPTIONAL)
    col.field.add(name="entries", number=7, type=F.TYPE_MESSAGE, label=F.LABEL_REPEATED,
                  type_name=f".{CONTRACT_V2}.Array")
    col.field.add(name="layout", number=8, type=F.TYPE_ENUM, label=F.LABEL_OPTIONAL,
                  type_name=f".{CONTRACT_V2}.Column.Layout")
    scan = fdp.message_type.add(name="Scan")
    scan.field.add(name="scan", number=1, type=F.TYPE_UINT32, label=F.LABEL_OPTIONAL)
    scan.field.add(name="time_s", number=2, type=F.TYPE_DOUBLE, label=F.LABEL_OPTIONAL)
    scan.field.add(name="first_run", number=3, type=F.TYPE_UINT32, label=F.LABEL_OPTIONAL)
    scan.field.add(name="frame_count", number=4, type=F.TYPE_UINT32, label=F.LABEL_OPTIONAL)
    scan.field.add(name="runs", number=5, type=F.TYPE_BYTES, label=F.LABEL_OPTIONAL)
    scan.field.add(name="times_s", number=6, type=F.TYPE_BYTES, label=F.LABEL_OPTIONAL)
    scan.field.add(name="columns", number=7, type=F.TYPE_MESSAGE, label=F.LABEL_REPEATED,
                   type_name=f".{CONTRACT_V2}.Column")
    if grouped:
        scan.field.add(name="scan_count", number=8, type=F.TYPE_UINT32, label=F.LABEL_OPTIONAL)
    return _message_classes(fdp, [SCAN_SCHEMA])


Frame, FRAME_DESCRIPTOR_SET = _build_frame_class()
Scan, PACKED_SCAN_DESCRIPTOR_SET = _build_scan_class()
_, SCAN_DESCRIPTOR_SET = _build_scan_class(symmetric=False, grouped=False)
_, GROUPED_SCAN_DESCRIPTOR_SET = _build_scan_class(symmetric=False)

#: A channel of at least this many scans is a long recording: its scans are grouped into
#: messages when its runs are few (:func:`scans_per_message`). Below it a message per scan costs
#: a replay little (about 0.1 s a channel), and every shorter data set keeps the bytes earlier
#: versions wrote.
GROUP_MIN_SCANS = 2048
#: Frames (runs × scans) a grouped message holds at most.
GROUP_FRAMES = 1024


def scans_per_message(n_runs: int, n_scans: int) -> int:
    """How many scans one message of a channel holds: 1, or for a long recording of few runs
    (at least :data:`GROUP_MIN_SCANS` scans, at most ``GROUP_FRAMES / 8`` runs) ``GROUP_FRAMES //
    n_runs``. Each message, protobuf object and MCAP record costs tens of microseconds to write
    and to read whatever it holds: at 100,000 scans of one run, one per scan was most of a
    replay's reading and writing (docs/benchmarks.md)."""
    if n_scans < GROUP_MIN_SCANS or not 0 < n_runs <= GROUP_FRAMES // 8:
        return 1
    return GROUP_FRAMES // n_runs
_SCHEMA_DATA = {CONTRACT_V1: (FRAME_SCHEMA_V1, FRAME_DESCRIPTOR_SET), CONTRACT_V2: (SCAN_SCHEMA, SCAN_DESCRIPTOR_SET)}


# --------------------------------------------------------------------------- columns


@dataclass
class _Column:
    """One array of a channel in bulk: the entries of the frames that carry it, in frame order.

    ``FIXED``: ``values`` is ``(count, *shape)``. ``RAGGED``: entry i is
    ``values[offsets[i]:offsets[i + 1]]`` (rows of ``shape``). ``IRREGULAR``: ``items``.
    """

    kind: int
    dtype: np.dtype
    count: int
    shape: tuple = ()
    values: np.ndarray | None = None
    offsets: np.ndarray | None = None
    items: list | None = None
    frames: np.ndarray | None = None  # in a decoded message: the frames carrying it (None: all)

    def entries(self) -> list[np.ndarray]:
        if self.kind == IRREGULAR:
            return list(self.items)
        if self.kind == RAGGED:
            return np.split(self.values, self.offsets[1:-1]) if self.count else []
        if self.values.ndim == 1:  # 0-d entries: keep them arrays, as v1 frames decode
            return [self.values[i, ...] for i in range(self.count)]
        return list(self.values)

    def lengths(self) -> np.ndarray:
        return np.diff(self.offsets)

    @property
    def nbytes(self) -> int:
        if self.kind == IRREGULAR:
            return sum(a.nbytes for a in self.items)
        return self.values.nbytes


class ColumnArrays(MappingABC):
    """``ChannelData.arrays`` of a v2 file: array name → list of per-frame arrays, made on first
    access (membership and iteration need no decoding)."""

    def __init__(self, columns: dict[str, _Column]):
        self.columns = columns
        self._lists: dict[str, list] = {}

    def __getitem__(self, name: str) -> list[np.ndarray]:
        if name not in self._lists:
            self._lists[name] = self.columns[name].entries()
        return self._lists[name]

    def __contains__(self, name) -> bool:
        return name in self.columns

    def __iter__(self):
        return iter(self.columns)

    def __len__(self) -> int:
        return len(self.columns)

    def __repr__(self) -> str:
        return f"ColumnArrays({', '.join(self.columns)})"


def _merge_columns(parts: list[_Column]) -> _Column:
    """One channel-level column from the same array's columns of successive messages."""
    if len(parts) == 1:
        return parts[0]
    count = sum(p.count for p in parts)
    dtype = parts[0].dtype
    same_dtype = all(p.dtype == dtype for p in parts)
    if same_dtype and all(p.kind == FIXED and p.shape == parts[0].shape for p in parts):
        return _Column(FIXED, dtype, count, parts[0].shape, np.concatenate([p.values for p in parts]))
    tails = {p.shape if p.kind == RAGGED else p.shape[1:] for p in parts if p.kind != IRREGULAR}
    if same_dtype and len(tails) == 1 and all(p.kind == RAGGED or (p.kind == FIXED and p.shape) for p in parts):
        tail = tails.pop()
        lengths, flats = [], []
        for p in parts:
            if p.kind == RAGGED:
                lengths.append(np.diff(p.offsets))
                flats.append(p.values)
            else:
                lengths.append(np.full(p.count, p.shape[0], np.int64))
                flats.append(p.values.reshape(p.count * p.shape[0], *tail))
        offsets = np.zeros(count + 1, np.int64)
        np.cumsum(np.concatenate(lengths), out=offsets[1:])
        return _Column(RAGGED, dtype, count, tail, np.concatenate(flats), offsets)
    items: list = []
    for p in parts:
        items.extend(p.entries())
    return _Column(IRREGULAR, dtype, count, items=items)


# --------------------------------------------------------------------------- records


@dataclass(frozen=True)
class _FrameBlocks:
    """The frames of a channel as its messages list them, one row per message: every message
    carries runs ``first_run … first_run + count − 1`` of one ``scan`` at one ``time_s``.

    This is what a v2 grid holds; the per-frame run, scan and time arrays it stands for are three
    times eight bytes a frame (31 MB for a 10,000-run radar data set's two channels), made only
    when asked for.
    """

    scan: np.ndarray
    first_run: np.ndarray
    count: np.ndarray
    time_s: np.ndarray

    @property
    def n_frames(self) -> int:
        return int(self.count.sum())

    def run(self) -> np.ndarray:
        starts = np.cumsum(self.count) - self.count
        return np.arange(self.n_frames, dtype=np.int64) - np.repeat(starts - self.first_run, self.count)

    def scans(self) -> np.ndarray:
        return np.repeat(self.scan, self.count)

    def times(self) -> np.ndarray:
        return np.repeat(self.time_s, self.count)

    def scan_major(self, n_runs: int, n_scans: int) -> bool:
        """Whether the frames are every (run, scan) once, scan by scan and run by run within one."""
        if self.n_frames != n_runs * n_scans:
            return False
        starts = np.cumsum(self.count) - self.count  # frame number of each message's first frame
        return bool(np.array_equal(self.scan, starts // n_runs) and np.array_equal(self.first_run, starts % n_runs)
                    and np.all(self.first_run + self.count <= n_runs))


class ChannelData:
    """All frames of one channel, as decoded.

    Attributes
    ----------
    run, scan : ndarray of int
        Run and scan index per frame.
    time_s : ndarray of float
        Scan time per frame.
    arrays : mapping of str to list of ndarray
        One list per array name, one entry per frame (for a v2 file a :class:`ColumnArrays`
        that makes the per-frame views on first access).
    topic : str
        The channel's topic (named in error messages).
    path : str, optional
        The file it was read from (named in error messages).

    A channel read from messages that each carry consecutive runs of one scan (what the writer
    makes) keeps those messages' lists instead of ``run``, ``scan`` and ``time_s``, and makes
    the arrays on each access (:class:`_FrameBlocks`); ``n_frames``, ``n_runs``, ``n_scans`` and
    :meth:`times` need no per-frame array.
    """

    def __init__(self, run, scan, time_s, arrays: Mapping[str, list[np.ndarray]], topic: str = "channel",
                 path: str | None = None, *, blocks: _FrameBlocks | None = None):
        self._run, self._scan, self._time_s, self._blocks = run, scan, time_s, blocks
        self.arrays = arrays
        self.topic = topic
        self.path = path
        self._order: bool | None = None

    @classmethod
    def of_blocks(cls, blocks: _FrameBlocks, arrays, topic: str = "channel", path: str | None = None) -> "ChannelData":
        """A channel whose frames are the messages ``blocks`` lists (no per-frame arrays kept)."""
        return cls(None, None, None, arrays, topic, path, blocks=blocks)

    def __repr__(self) -> str:
        return f"ChannelData(topic={self.topic!r}, frames={self.n_frames}, arrays={self.arrays!r})"

    @property
    def run(self) -> np.ndarray:
        return self._run if self._blocks is None else self._blocks.run()

    @property
    def scan(self) -> np.ndarray:
        return self._scan if self._blocks is None else self._blocks.scans()

    @property
    def time_s(self) -> np.ndarray:
        return self._time_s if self._blocks is None else self._blocks.times()

    @property
    def n_frames(self) -> int:
        return self._run.size if self._blocks is None else self._blocks.n_frames

    @property
    def n_runs(self) -> int:
        if self._blocks is not None:
            b = self._blocks
            return int((b.first_run + b.count).max()) if b.count.size else 0
        return int(self._run.max()) + 1 if self._run.size else 0

    @property
    def n_scans(self) -> int:
        scan = self._scan if self._blocks is None else self._blocks.scan
        return int(scan.max()) + 1 if scan.size else 0

    def _column(self, name: str) -> _Column | None:
        """The bulk column behind ``name`` (after the checks :meth:`array` makes), or None for
        per-frame lists."""
        if not isinstance(self.arrays, ColumnArrays):
            return None
        self._check_count(name, self.arrays.columns.get(name))
        return self.arrays.columns[name]

    def _check_count(self, name: str, column: _Column | None) -> None:
        if name not in self.arrays:
            have = ", ".join(sorted(self.arrays)) or "none"
            raise InputError(f"{self.topic} lacks array {name!r} (have: {have})", self.path)
        count = column.count if column is not None else len(self.arrays[name])
        if count != self.n_frames:
            raise InputError(f"{self.topic} array {name!r} is in {count} of {self.n_frames} frames; "
                             "every frame must carry it", self.path)

    def array(self, name: str) -> list[np.ndarray]:
        """One array's entries, one per frame.

        Raises
        ------
        InputError
            The channel has no array ``name``, or only some of its frames carry it.
        """
        column = self.arrays.columns.get(name) if isinstance(self.arrays, ColumnArrays) else None
        self._check_count(name, column)
        return self.arrays[name]

    def require_every_frame(self, n_runs: int | None = None, n_scans: int | None = None) -> None:
        """Raise :class:`InputError` naming the first (run, scan) without a frame.

        :meth:`grid` fills a missing frame with NaN; a stage that cannot work with gaps calls
        this first so the user learns which frame is missing rather than that NaNs appeared.
        """
        n_runs = self.n_runs if n_runs is None else n_runs
        n_scans = self.n_scans if n_scans is None else n_scans
        seen = np.zeros((n_runs, n_scans), bool)
        inside = (self.run < n_runs) & (self.scan < n_scans)
        seen[self.run[inside], self.scan[inside]] = True
        if not seen.all():
            r, k = (int(v[0]) for v in np.nonzero(~seen))
            raise InputError(f"{self.topic} has no frame for run {r} scan {k} (it must cover all {n_runs} run(s) × "
                             f"{n_scans} scan(s))", self.path)

    def _where(self, i: int) -> str:
        return f"run {int(self.run[i])} scan {int(self.scan[i])}"

    def _guard_size(self, name: str, shape: tuple, dtype, data_bytes: int) -> None:
        """Refuse an output that would be huge and mostly padding (implausible indices or lengths)."""
        size = math.prod(int(s) for s in shape) * np.dtype(dtype).itemsize
        if size > MAX_PADDED_BYTES and size > MAX_SPARSITY * max(data_bytes, 1):
            raise InputError(f"{self.topic} array {name!r}: its [run, scan] array {tuple(int(s) for s in shape)} "
                             f"would need {size / 2**30:.1f} GiB for {data_bytes / 2**20:.1f} MiB of values; "
                             "the frames' run/scan indices or list lengths are implausible", self.path)

    def grid(self, name: str) -> np.ndarray:
        """Stack a fixed-shape array into ``[run, scan, ...]`` (NaN where a frame is missing).

        Raises
        ------
        InputError
            The array is missing or its shape differs between frames.
        """
        column = self._column(name)
        if column is None or column.kind == IRREGULAR:
            return self._grid_items(name, self.array(name))
        if column.count == 0:
            return np.zeros((0, 0))
        if column.kind == RAGGED:
            lengths = column.lengths()
            bad = np.flatnonzero(lengths != lengths[0])
            if bad.size:
                b = int(bad[0])
                first, other = (int(lengths[0]), *column.shape), (int(lengths[b]), *column.shape)
                raise InputError(f"{self.topic} array {name!r} has shape {first} in {self._where(0)} but "
                                 f"{other} in {self._where(b)}; it must keep one shape in every frame", self.path)
            values = column.values.reshape(column.count, int(lengths[0]), *column.shape)
        else:
            values = column.values
        inner = values.shape[1:]
        dtype = np.result_type(column.dtype, np.float64) if column.dtype.kind in "iub" else column.dtype
        shape = (self.n_runs, self.n_scans, *inner)
        if dtype == values.dtype and self._scan_major():
            # every frame present, scan by scan and run by run within a scan (as the writer puts
            # them): the values already are the grid, scan axis first; a read-only view of them
            # spares a copy of the largest arrays (array snapshots)
            view = values.reshape(self.n_scans, self.n_runs, *inner).swapaxes(0, 1)
            view.flags.writeable = False
            return view
        self._guard_size(name, shape, dtype, values.nbytes)
        out = np.full(shape, np.nan, dtype=dtype)
        out[self.run, self.scan] = values
        return out

    def _scan_major(self) -> bool:
        """Whether the frames are every (run, scan) once, in scan-major order."""
        if self._order is None:
            R, K = self.n_runs, self.n_scans
            if self._blocks is not None:
                self._order = self._blocks.scan_major(R, K)
            else:
                self._order = bool(self._run.size == R * K and np.array_equal(self._scan, np.repeat(np.arange(K), R))
                                   and np.array_equal(self._run, np.tile(np.arange(R), K)))
        return self._order

    def _grid_items(self, name: str, items: list) -> np.ndarray:
        if not items:
            return np.zeros((0, 0))
        inner = items[0].shape
        bad = next((i for i, a in enumerate(items) if a.shape != inner), None)
        if bad is not None:
            raise InputError(f"{self.topic} array {name!r} has shape {inner} in {self._where(0)} but "
                             f"{items[bad].shape} in {self._where(bad)}; it must keep one shape in every frame",
                             self.path)
        dtype = np.result_type(items[0].dtype, np.float64) if items[0].dtype.kind in "iub" else items[0].dtype
        shape = (self.n_runs, self.n_scans, *inner)
        self._guard_size(name, shape, dtype, sum(a.nbytes for a in items))
        out = np.full(shape, np.nan, dtype=dtype)
        out[self.run, self.scan] = np.stack(items)
        return out

    def ragged(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """Pad a variable-length array into ``[run, scan, max_len, ...]`` with NaN.

        Returns
        -------
        values : ndarray
            Padded values; a read-only view of the decoded values when every frame holds the
            same number of float64 entries and the frames are in the writer's order.
        counts : ndarray of int, shape (run, scan)
            How many entries each frame held (0 where the frame is missing); read-only with
            such a view.

        Raises
        ------
        InputError
            The array is missing, 0-d in some frame (no entry axis), or its entries change
            shape between frames.
        """
        column = self._column(name)
        if column is None or column.kind == IRREGULAR:
            items = self.array(name)
            bad = next((i for i, a in enumerate(items) if a.ndim == 0), None)
            if bad is not None:
                raise InputError(f"{self.topic} array {name!r} is a scalar in {self._where(bad)}; "
                                 "it must hold a list of entries (at least 1-D) in every frame", self.path)
            tail = items[0].shape[1:] if items else ()
            bad = next((i for i, a in enumerate(items) if a.shape[1:] != tail), None)
            if bad is not None:
                raise InputError(f"{self.topic} array {name!r} has entries of shape {tail} in {self._where(0)} but "
                                 f"{items[bad].shape[1:]} in {self._where(bad)}; entries must keep one shape",
                                 self.path)
            lengths = np.array([a.shape[0] for a in items], dtype=np.int64)
            return self._pad(name, lengths, tail, lambda: np.concatenate(items))
        if column.kind == FIXED:
            if not column.shape:
                raise InputError(f"{self.topic} array {name!r} is a scalar in {self._where(0)}; "
                                 "it must hold a list of entries (at least 1-D) in every frame", self.path)
            length, tail = column.shape[0], column.shape[1:]
            if column.dtype == np.float64 and self._scan_major():
                # as in grid(): every frame holds ``length`` entries, in the writer's order, so
                # the padded array is the values themselves (read-only views, no padding to fill:
                # 15 MB and a scatter less for a 10,000-run radar data set's plots)
                R, K = self.n_runs, self.n_scans
                view = column.values.reshape(K, R, length, *tail).swapaxes(0, 1)
                view.flags.writeable = False
                return view, np.broadcast_to(np.int64(length), (R, K))
            lengths = np.full(column.count, length, np.int64)
            return self._pad(name, lengths, tail, lambda: column.values.reshape(column.count * length, *tail))
        return self._pad(name, column.lengths(), column.shape, lambda: column.values)

    def _pad(self, name: str, lengths: np.ndarray, tail: tuple, flat) -> tuple[np.ndarray, np.ndarray]:
        counts = np.zeros((self.n_runs, self.n_scans), dtype=np.int64)
        counts[self.run, self.scan] = lengths
        width = int(lengths.max()) if lengths.size else 0
        shape = (self.n_runs, self.n_scans, width, *tail)
        self._guard_size(name, shape, np.float64, int(lengths.sum()) * math.prod(tail) * 8)
        out = np.full(shape, np.nan)
        if width:
            # one scatter instead of a Python loop over frames
            slot = np.arange(int(lengths.sum())) - np.repeat(np.cumsum(lengths) - lengths, lengths)
            out[np.repeat(self.run, lengths), np.repeat(self.scan, lengths), slot] = flat()
        return out, counts

    def times(self) -> np.ndarray:
        """Scan times ``[scan]`` (taken from run 0's frames, or the first seen per scan)."""
        t = np.full(self.n_scans, np.nan)
        if self._blocks is not None:  # per message, not per frame: the same first time per scan
            t[self._blocks.scan[::-1]] = self._blocks.time_s[::-1]
        else:
            t[self._scan[::-1]] = self._time_s[::-1]
        return t


@dataclass
class Dataset:
    """An MCAP file's content: channels by topic plus the metadata records."""

    path: str
    channels: dict[str, ChannelData]
    metadata: dict[str, dict[str, str]]
    recovered_messages: int | None = None
    cache: dict = field(default_factory=dict, repr=False)  # stages' decoded views, computed once
    contract: str | None = None  # "replay.v1" or "replay.v2" (None: no frames)

    def channel(self, topic: str) -> ChannelData:
        if topic not in self.channels:
            have = ", ".join(sorted(self.channels)) or "none"
            raise InputError(f"missing channel {topic!r} (channels present: {have})", self.path)
        return self.channels[topic]

    @property
    def scenario(self) -> dict:
        """Scenario record: name, params (dict), seed, package version."""
        rec = self.metadata.get(METADATA_SCENARIO, {})
        out = dict(rec)
        if "params" in out:
            try:
                out["params"] = json.loads(out["params"])
            except (ValueError, RecursionError):  # (RecursionError: nested deeper than json recurses)
                raise InputError(f"{METADATA_SCENARIO} metadata: params is not valid JSON", self.path) from None
            if not isinstance(out["params"], dict):
                raise InputError(f"{METADATA_SCENARIO} metadata: params must be a JSON object", self.path)
        return out


# --------------------------------------------------------------------------- writing


def _normalise(name: str, value) -> np.ndarray:
    """C-contiguous little-endian array of a contract dtype (0-d stays 0-d)."""
    a = np.asarray(value)
    if not a.flags.c_contiguous:  # (np.ascontiguousarray would turn 0-d into 1-d)
        a = a.copy(order="C")
    return _little_endian_contract_dtype(name, a)


def _little_endian_contract_dtype(name: str, a: np.ndarray) -> np.ndarray:
    """``a`` little-endian (a copy only if it was not), refused unless its dtype is in the contract."""
    if a.dtype.byteorder == ">":
        a = a.astype(a.dtype.newbyteorder("<"))
    if a.dtype.str not in _ALLOWED_DTYPES:
        raise ValueError(f"dtype {a.dtype.str} of array {name!r} is not in the contract")
    return a


def encode_frame(run: int, scan: int, time_s: float, arrays: Mapping[str, np.ndarray],
                 run_count: int = 1) -> bytes:
    """Serialise one ``replay.v1.Frame``; arrays keep their exact bytes, shape and dtype.

    With ``run_count`` > 1 the frame is batched: every array's first axis is the run axis.
    """
    msg = Frame(run=int(run), scan=int(scan), time_s=float(time_s),
                run_count=int(run_count) if run_count > 1 else 0)
    for name, value in arrays.items():
        a = _normalise(name, value)
        msg.arrays.add(name=name, shape=a.shape, dtype=a.dtype.str, data=a.tobytes())
    return msg.SerializeToString()


def decode_frame(data: bytes) -> tuple[int, int, float, dict[str, np.ndarray], int]:
    """Inverse of :func:`encode_frame`; returns ``(run, scan, time_s, arrays, run_count)``."""
    msg = Frame()
    msg.ParseFromString(data)
    arrays = {}
    for a in msg.arrays:
        arrays[a.name] = _decode_array(a)
    return msg.run, msg.scan, msg.time_s, arrays, max(msg.run_count, 1)


_DTYPES = {s: np.dtype(s) for s in _ALLOWED_DTYPES}


def _decode_array(a) -> np.ndarray:
    """One ``Array`` message as a read-only view of its bytes (ValueError if it is malformed)."""
    dtype = _DTYPES.get(a.dtype)
    if dtype is None:
        raise ValueError(f"array {a.name!r} has dtype {a.dtype!r}, not in the contract")
    # frombuffer refuses a byte count that is not a multiple of the item size and reshape one
    # that does not match the shape: a malformed array is a ValueError, never a wrong array
    return np.frombuffer(a.data, dtype=dtype).reshape(tuple(a.shape))


@dataclass
class _Part:
    """Frames of one channel and scan handed to the writer in one call.

    ``kind`` "frame": one run, arrays as they are; "batch": runs ``first_run …`` with a leading
    run axis; "ragged": runs ``first_run …``, arrays flattened over the entries of every run
    (``lengths`` per run).
    """

    kind: str
    first_run: int
    n: int
    time_s: float
    arrays: dict
    lengths: np.ndarray | None = None

    @property
    def nbytes(self) -> int:
        return sum(a.nbytes for a in self.arrays.values())

    def entry_layout(self, a: np.ndarray):
        """(lengths along the entries' first axis or None for 0-d, tail shape, set of full shapes)."""
        if self.kind == "frame":
            return (None if a.ndim == 0 else np.array([a.shape[0]])), a.shape[1:], {a.shape}
        if self.kind == "batch":
            inner = a.shape[1:]
            return (None if not inner else np.full(self.n, inner[0])), inner[1:], {inner}
        tail = a.shape[1:]
        lengths = self.lengths
        shapes = {(int(v), *tail) for v in np.unique(lengths)}
        return lengths, tail, shapes

    def entries(self, a: np.ndarray) -> list:
        if self.kind == "frame":
            return [a]
        if self.kind == "batch":
            return [a[i] for i in range(self.n)]
        return np.split(a, np.cumsum(self.lengths)[:-1])


def _encode_column(col, name: str, pieces: list[tuple[_Part, np.ndarray]], frames: np.ndarray | None) -> None:
    """Fill the ``Column`` message ``col`` with one array's entries (layout chosen from their shapes)."""
    col.name = name
    col.dtype = pieces[0][1].dtype.str
    if frames is not None:
        col.frames = frames.astype("<u4").tobytes()
    layouts = [p.entry_layout(a) for p, a in pieces]
    shapes = set().union(*(s for _, _, s in layouts))
    same_dtype = len({a.dtype.str for _, a in pieces}) == 1
    if same_dtype and len(shapes) == 1:
        col.layout = FIXED
        col.shape.extend(shapes.pop())
        col.values = b"".join(a.tobytes() for _, a in pieces)
    elif same_dtype and all(lengths is not None for lengths, _, _ in layouts) and len({t for _, t, _ in layouts}) == 1:
        col.layout = RAGGED
        col.shape.extend(layouts[0][1])
        offsets = np.zeros(1 + sum(len(lengths) for lengths, _, _ in layouts), "<i8")
        np.cumsum(np.concatenate([lengths for lengths, _, _ in layouts]), out=offsets[1:])
        col.offsets = offsets.tobytes()
        col.values = b"".join(a.tobytes() for _, a in pieces)
    else:
        col.layout = IRREGULAR
        for p, a in pieces:
            for e in p.entries(a):
                col.entries.add(shape=e.shape, dtype=e.dtype.str, data=e.tobytes())


def encode_scan(scan: int, parts: list[_Part], scan_times: np.ndarray | None = None) -> bytes:
    """Serialise the frames of one channel and scan as one ``replay.v2.Scan`` message.

    With ``scan_times`` (G > 1 times) the one part holds G scans from ``scan`` on, the same runs
    in each, frames scan-major: a message of a long recording (:func:`scans_per_message`)."""
    counts = [p.n for p in parts]
    total = sum(counts)
    msg = Scan(scan=int(scan), time_s=float(parts[0].time_s), frame_count=total)
    if scan_times is not None:
        (part,) = parts
        msg.first_run = part.first_run
        msg.scan_count = len(scan_times)
        msg.times_s = np.repeat(np.asarray(scan_times, "<f8"), total // len(scan_times)).tobytes()
        counts = [total]
    else:
        runs = np.concatenate([np.arange(p.first_run, p.first_run + p.n, dtype=np.int64) for p in parts])
        if np.array_equal(runs, np.arange(runs[0], runs[0] + total)):
            msg.first_run = int(runs[0])
        else:
            msg.runs = runs.astype("<u4").tobytes()
        times = [float(p.time_s) for p in parts]
        if any(t != times[0] or math.copysign(1, t) != math.copysign(1, times[0]) for t in times):
            msg.times_s = np.repeat(np.array(times, "<f8"), counts).tobytes()
    starts = np.cumsum([0, *counts])
    names = list(dict.fromkeys(n for p in parts for n in p.arrays))
    for name in names:
        carriers = [i for i, p in enumerate(parts) if name in p.arrays]
        frames = None
        if len(carriers) < len(parts):
            frames = np.concatenate([np.arange(starts[i], starts[i + 1]) for i in carriers])
        _encode_column(msg.columns.add(), name, [(parts[i], parts[i].arrays[name]) for i in carriers], frames)
    return msg.SerializeToString()


def publish(tmp: str | Path, path: str | Path) -> None:
    """Rename a finished temporary file over ``path`` with the permissions open() would give.

    ``mkstemp`` creates files 0600; outputs are meant to be shared like any other file.
    """
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)
    os.replace(tmp, path)


@contextmanager
def atomic_output(path: str | Path, mode: str = "wb"):
    """Open a temporary file next to ``path`` and rename it over ``path`` on success.

    A crash or an exception leaves any existing ``path`` untouched and removes the temporary; the
    temporary of a writer that was killed is removed by the next write of ``path``.
    """
    from trackreplay.paths import disk_error

    from trackreplay.paths import remove_stale_temporaries

    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        # the writing process's id in the name: a killed writer's temporary is known as such and
        # goes at the next write of the same output
        remove_stale_temporaries(path)
        fd, tmp = tempfile.mkstemp(prefix=f"{path.name}.{os.getpid()}.", suffix=".tmp", dir=path.parent)
    except OSError as exc:  # a read-only or full disk: the output is named, not its temporary
        raise (disk_error(exc, path) or exc) from None
    try:
        with os.fdopen(fd, mode) as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        publish(tmp, path)
    except BaseException as exc:
        if os.path.exists(tmp):
            os.unlink(tmp)
        named = disk_error(exc, path)  # a writer of an open file reports a full disk without a name
        if named is not None:
            raise named from None
        raise


# zstd level of the chunks of replay outputs: on tracker outputs level 1 compresses twice as fast
# as the default level 3 for the same size (ratio 1.713 against 1.716 measured on radar outputs);
# data sets, written once and read many times, keep the default
OUTPUT_ZSTD_LEVEL = 1


class _ZstdLevel(threading.local):
    """The zstd level the chunks written by this thread get (None: the library's default), and
    this thread's compressor for it (a compressor object is not shared between threads)."""

    level: int | None = None
    compressors: dict | None = None


_ZSTD_LEVEL = _ZstdLevel()


class _ZstdForMcapWriter:
    """Stands in for the ``zstandard`` module inside ``mcap.writer``, which compresses each chunk
    with ``zstandard.compress`` at the default level and has no option for another: a writer
    chooses the level for its own thread (:func:`_zstd_level`); everything else is zstandard."""

    def __getattr__(self, name):
        return getattr(zstandard, name)

    @staticmethod
    def compress(data, *args, **kwargs):
        level = _ZSTD_LEVEL.level
        if level is None or args or kwargs:
            return zstandard.compress(data, *args, **kwargs)
        cache = _ZSTD_LEVEL.compressors
        if cache is None:
            cache = _ZSTD_LEVEL.compressors = {}
        if level not in cache:
            cache[level] = zstandard.ZstdCompressor(level=level)
        return cache[level].compress(data)


mcap.writer.zstandard = _ZstdForMcapWriter()


@contextmanager
def _zstd_level(level: int | None):
    """Chunks finished by mcap's writer in this block are compressed at ``level``."""
    previous, _ZSTD_LEVEL.level = _ZSTD_LEVEL.level, level
    try:
        yield
    finally:
        _ZSTD_LEVEL.level = previous


def _triangle_indices(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Flat indices into an ``n × n`` matrix of its upper triangle row by row, and of the
    mirrored entries (the lower triangle in the same order)."""
    rows, cols = np.triu_indices(n)
    return rows * n + cols, cols * n + rows


def _square_real(dtype: np.dtype, inner: tuple) -> bool:
    """Whether entries of this dtype and shape can be stored as ``SYMMETRIC`` (real square matrices)."""
    return dtype.kind == "f" and len(inner) >= 2 and inner[-1] == inner[-2] >= 2


def upper_triangles(a: np.ndarray) -> np.ndarray | None:
    """``a``'s matrices (its last two axes) as their upper triangles, ``(..., n(n+1)/2)``, when
    every one of them is symmetric to the bit (NaN and −0 included); else None.

    Lossless by construction: the lower triangle read back is the upper one, which equals it
    bit for bit. A grid that is not exactly symmetric (a plugged tracker's rounding) is stored
    whole. What the writer's ``SYMMETRIC`` layout holds (``benchmarks/bench_output_size.py``
    measures it through this function too).
    """
    n = a.shape[-1]
    flat = a.reshape(a.shape[:-2] + (n * n,))  # a view where the matrices' entries are evenly spaced
    upper, lower = _triangle_indices(n)
    # the same bits, mirrored pair by pair, compared in place (an integer view of the same
    # width is a view of any layout): no gathered copy before the one that is written
    bits = flat.view(f"<u{a.dtype.itemsize}")
    for u, l in zip(upper.tolist(), lower.tolist()):
        if u != l and not np.array_equal(bits[..., u], bits[..., l]):
            return None
    return flat.take(upper, axis=-1)


class McapFrameWriter:
    """Writes frames on named channels; one chunk is flushed per scan block.

    ``contract`` ``replay.v2`` (default) gathers the frames of one channel and scan into one
    message (written when the channel moves on to another scan, at :meth:`flush` and at
    :meth:`finish`); ``replay.v1`` writes one message per call, as version 1 did.
    """

    def __init__(self, f, metadata: Mapping[str, Mapping[str, str]] | None = None,
                 contract: str = CONTRACT_VERSION, zstd_level: int | None = None, pack_symmetric: bool = False,
                 group_scans: bool = False):
        if contract not in _SCHEMA_DATA:
            raise ValueError(f"unknown contract {contract!r} (have: {', '.join(_SCHEMA_DATA)})")
        self.contract = contract
        self.zstd_level = zstd_level  # None: zstd's default (data sets); OUTPUT_ZSTD_LEVEL for outputs
        # grids of symmetric matrices stored as their upper triangles (replay outputs' covariances)
        self.pack_symmetric = pack_symmetric and contract == CONTRACT_V2
        # long recordings of few runs in messages of several scans (scans_per_message): replay
        # outputs, and data sets whose writer asks for it (their schema then lists scan_count)
        self.group_scans = (group_scans or pack_symmetric) and contract == CONTRACT_V2
        self._file = f
        self.messages = 0  # MCAP messages written so far
        # v2 also writes the data-section CRC (covering the metadata records, which sit outside
        # the chunks); v1 files were written without it.
        self._w = Writer(f, compression=CompressionType.ZSTD, chunk_size=1 << 20,
                         enable_data_crcs=contract != CONTRACT_V1)
        # MCAP requires a profile string; "" is the documented value for no profile.
        self._w.start(profile="", library=f"trackreplay {__version__}")
        name, data = _SCHEMA_DATA[contract]
        if self.pack_symmetric:
            data = PACKED_SCAN_DESCRIPTOR_SET
        elif self.group_scans:
            data = GROUPED_SCAN_DESCRIPTOR_SET
        self._schema = self._w.register_schema(name=name, encoding="protobuf", data=data)
        self._channels: dict[str, int] = {}
        self._seq: dict[int, int] = {}
        self._blocks: dict[str, tuple[int, list[_Part], list[int]]] = {}  # topic -> (scan, parts, [bytes])
        self._layout: dict[str, list[int]] = {}  # topic -> [runs, scans, frames]
        for name, rec in (metadata or {}).items():
            self.add_metadata(name, rec)

    def add_metadata(self, name: str, record: Mapping[str, str]) -> None:
        """A metadata record; the scenario record's ``contract`` field states this writer's contract,
        and ``replay.layout`` is the writer's own (a given one is dropped)."""
        if name == METADATA_LAYOUT:
            return
        record = {str(k): str(v) for k, v in record.items()}
        if name == METADATA_SCENARIO and "contract" in record:
            record["contract"] = self.contract
        self._w.add_metadata(name, record)

    def channel(self, topic: str) -> int:
        if topic not in self._channels:
            cid = self._w.register_channel(
                topic=topic, message_encoding="protobuf", schema_id=self._schema,
                metadata={"contract": self.contract},
            )
            self._channels[topic] = cid
            self._seq[cid] = 0
            self._layout[topic] = [0, 0, 0]
        return self._channels[topic]

    def _add_message(self, topic: str, time_s: float, data: bytes) -> None:
        from trackreplay.vocabulary import TIME_LIMIT_S

        if not (np.isfinite(time_s) and abs(time_s) <= TIME_LIMIT_S):
            # MCAP log times are unsigned nanoseconds: refuse what cannot be a recording's time
            raise InputError(f"{topic}: scan time {time_s!r} s is not a finite time within ±{TIME_LIMIT_S:g} s")
        cid = self.channel(topic)
        t_ns = int(round(time_s * 1e9))
        with _zstd_level(self.zstd_level):  # the message may close a chunk
            self._w.add_message(cid, log_time=t_ns, data=data, publish_time=t_ns, sequence=self._seq[cid])
        self._seq[cid] += 1
        self.messages += 1

    def _add(self, topic: str, scan: int, part: _Part) -> None:
        if part.n == 0:
            return
        if not (0 <= part.first_run and part.first_run + part.n <= 1 << 32 and 0 <= scan < 1 << 32):
            raise ValueError(f"run {part.first_run} (+{part.n}) or scan {scan} is outside 0 … 2³² − 1")
        self.channel(topic)
        block = self._blocks.get(topic)
        if block is not None and block[0] != scan:
            self._emit(topic)
            block = None
        if block is None:
            block = self._blocks[topic] = (scan, [], [0])
        block[1].append(part)
        block[2][0] += part.nbytes
        lay = self._layout[topic]
        lay[0] = max(lay[0], part.first_run + part.n)
        lay[1] = max(lay[1], scan + 1)
        lay[2] += part.n
        if block[2][0] >= BLOCK_BYTES:
            self._emit(topic)

    def _emit(self, topic: str) -> None:
        scan, parts, _ = self._blocks.pop(topic)
        self._add_message(topic, parts[0].time_s, encode_scan(scan, parts))

    def _emit_all(self) -> None:
        for topic in [t for t in self._channels if t in self._blocks]:
            self._emit(topic)

    def write(self, topic: str, run: int, scan: int, time_s: float, arrays: Mapping[str, np.ndarray],
              run_count: int = 1):
        """One frame (or, with ``run_count`` > 1, runs ``run …`` whose arrays lead with the run axis)."""
        if self.contract == CONTRACT_V1:
            self._add_message(topic, time_s, encode_frame(run, scan, time_s, arrays, run_count))
            return
        arrays = {name: _normalise(name, a) for name, a in arrays.items()}
        if run_count > 1:
            bad = [name for name, a in arrays.items() if a.shape[:1] != (run_count,)]
            if bad:
                raise ValueError(f"batched frame of {run_count} runs: array {bad[0]!r} has shape "
                                 f"{arrays[bad[0]].shape}")
            self._add(topic, int(scan), _Part("batch", int(run), int(run_count), float(time_s), arrays))
        else:
            self._add(topic, int(scan), _Part("frame", int(run), 1, float(time_s), arrays))

    def write_batch(self, topic: str, scan: int, time_s: float, arrays: Mapping[str, np.ndarray],
                    first_run: int = 0):
        """Runs ``first_run …`` of one scan; every array leads with the run axis (any length, 1 too)."""
        arrays = {name: _normalise(name, a) for name, a in arrays.items()}
        n = next(iter(arrays.values())).shape[0] if arrays else 0
        if self.contract == CONTRACT_V1:
            for r in range(n):
                self.write(topic, first_run + r, scan, time_s, {name: a[r] for name, a in arrays.items()})
            return
        if any(a.shape[:1] != (n,) for a in arrays.values()):
            raise ValueError(f"write_batch on {topic}: arrays differ in their run axis")
        self._add(topic, int(scan), _Part("batch", int(first_run), n, float(time_s), arrays))

    def write_ragged(self, topic: str, scan: int, time_s: float, arrays: Mapping[str, np.ndarray],
                     counts: np.ndarray, first_run: int = 0):
        """Runs ``first_run …`` of one scan, run r holding the first ``counts[r]`` entries of each
        padded array ``(runs, width, ...)``."""
        counts = np.asarray(counts, dtype=np.int64)
        if self.contract == CONTRACT_V1:
            for r in range(counts.shape[0]):
                c = counts[r]
                self.write(topic, first_run + r, scan, time_s, {name: a[r, :c] for name, a in arrays.items()})
            return
        flat = {}
        for name, a in arrays.items():
            a = np.asarray(a)
            if a.shape[:1] != counts.shape or (counts.size and counts.max() > a.shape[1]):
                raise ValueError(f"write_ragged on {topic}: array {name!r} of shape {a.shape} does not hold "
                                 f"counts up to {int(counts.max()) if counts.size else 0} for {counts.size} runs")
            mask = np.arange(a.shape[1]) < counts[:, None]
            flat[name] = _normalise(name, a[mask])
        self._add(topic, int(scan), _Part("ragged", int(first_run), counts.size, float(time_s), flat, counts))

    def write_scan_group(self, topic: str, first_scan: int, times: np.ndarray, arrays: Mapping[str, np.ndarray],
                         counts: np.ndarray | None = None):
        """Scans ``first_scan …`` (one per entry of ``times``) of one channel, every run, as one
        message (a long recording's group, :func:`scans_per_message`; needs ``group_scans``).
        Arrays are ``(runs, scans, ...)``; with ``counts`` ``(runs, scans)`` they are padded
        ``(runs, scans, width, ...)`` and frame (r, k) holds the first ``counts[r, k]`` entries."""
        times = np.asarray(times, float)
        if len(times) == 1 or not self.group_scans:
            for k, t in enumerate(times):
                if counts is None:
                    self.write_batch(topic, first_scan + k, t, {n: a[:, k] for n, a in arrays.items()})
                else:
                    self.write_ragged(topic, first_scan + k, t, {n: a[:, k] for n, a in arrays.items()}, counts[:, k])
            return
        self.channel(topic)
        if topic in self._blocks:
            self._emit(topic)
        G = len(times)
        if counts is None:
            n_runs = next(iter(arrays.values())).shape[0]
            flat = {name: _normalise(name, np.asarray(a).swapaxes(0, 1).reshape(n_runs * G, *np.shape(a)[2:]))
                    for name, a in arrays.items()}
            part = _Part("batch", 0, n_runs * G, float(times[0]), flat)
        else:
            counts = np.asarray(counts, dtype=np.int64)
            n_runs = counts.shape[0]
            scan_major = counts.T  # (scans, runs): the frames' order
            flat = {}
            for name, a in arrays.items():
                a = np.asarray(a).swapaxes(0, 1)
                mask = np.arange(a.shape[2]) < scan_major[..., None]
                flat[name] = _normalise(name, a[mask])
            part = _Part("ragged", 0, n_runs * G, float(times[0]), flat, scan_major.ravel())
        if part.n == 0:
            return
        self._add_message(topic, float(times[0]), encode_scan(first_scan, [part], times))
        lay = self._layout[topic]
        lay[0] = max(lay[0], n_runs)
        lay[1] = max(lay[1], first_scan + G)
        lay[2] += n_runs * G

    def write_grid(self, topic: str, times: np.ndarray, arrays: Mapping[str, np.ndarray]):
        """Write ``[run, scan, ...]`` arrays as one batched frame per scan (all runs)."""
        n_runs, n_scans = next(iter(arrays.values())).shape[:2]
        if self.contract != CONTRACT_V1 and n_runs and n_scans and topic not in self._blocks:
            self._write_grid_v2(topic, times, arrays, n_runs, n_scans)
            return
        for k in range(n_scans):
            if self.contract == CONTRACT_V1:
                self.write(topic, 0, k, times[k], {n: a[:, k] for n, a in arrays.items()}, run_count=n_runs)
            else:
                self.write_batch(topic, k, times[k], {n: a[:, k] for n, a in arrays.items()})
        if topic in self._blocks:  # the grid is complete: its last scan's views must not keep the arrays alive
            self._emit(topic)

    def _write_grid_v2(self, topic: str, times, arrays: Mapping[str, np.ndarray], n_runs: int, n_scans: int):
        """:meth:`write_grid` of a whole channel in contract v2: the same ``Scan`` messages, byte
        for byte, as one :meth:`write_batch` per scan, built directly.

        Every scan of a grid carries all runs with one shape per array, so each column is the
        ``FIXED`` layout and its values are the scan's slice in C order. Going through the
        general path cost a normalised copy, a ``_Part`` and the layout analysis of every array
        and scan: about 95 µs a message, most of a replay's write time on long-scan families
        (tested byte-equal to that path in ``tests/test_contract_v2.py``).

        With :attr:`pack_symmetric` (replay outputs), a scan of real square matrices that are
        symmetric to the bit is stored ``SYMMETRIC``: at 10,000 radar runs that is 37 % fewer
        covariance bytes to compress, and zstd at level 1 compressed the packed outputs 1.5×
        faster for a file 1 % smaller (``docs/benchmarks.md``).
        """
        columns, packing = [], []
        for name, a in arrays.items():
            a = np.asarray(a)
            if a.shape[:2] != (n_runs, n_scans):
                raise ValueError(f"write_grid on {topic}: array {name!r} has shape {a.shape}, expected "
                                 f"({n_runs}, {n_scans}, ...)")
            a = _little_endian_contract_dtype(name, a)  # no C-order copy of the whole grid: scans are cut below
            columns.append((name, a.dtype.str, a.shape[2:], a))
            if self.pack_symmetric and _square_real(a.dtype, a.shape[2:]):
                packing.append(len(columns) - 1)
        # symmetric grids are packed a block of scans at a time: one call per block keeps the
        # cost per scan small on few runs, and the block a few MB on many
        scan_bytes = max((columns[i][3][:, 0].nbytes for i in packing), default=0)
        step = n_scans if not scan_bytes else max(1, min(n_scans, PACK_BLOCK_BYTES // scan_bytes))
        group = scans_per_message(n_runs, n_scans) if self.group_scans else 1
        if group > 1:
            step = max(group, step // group * group)  # a packing block holds whole groups
        for first in range(0, n_scans, step):
            # each packing column's scans first … first + step − 1 as upper triangles, or None
            packed = {i: upper_triangles(columns[i][3][:, first:first + step]) for i in packing}
            if group > 1:
                self._write_grid_groups(topic, times, columns, packed, first, min(first + step, n_scans), group,
                                        n_runs)
                continue
            for k in range(first, min(first + step, n_scans)):
                msg = Scan(scan=k, time_s=float(times[k]), frame_count=n_runs)
                for i, (name, dtype, inner, a) in enumerate(columns):
                    triangles = packed.get(i)
                    if triangles is None:
                        col = msg.columns.add(name=name, dtype=dtype, layout=FIXED, values=a[:, k].tobytes())
                    else:
                        col = msg.columns.add(name=name, dtype=dtype, layout=SYMMETRIC,
                                              values=triangles[:, k - first].tobytes())
                    col.shape.extend(inner)
                self._add_message(topic, float(times[k]), msg.SerializeToString())
        lay = self._layout[topic]
        lay[0] = max(lay[0], n_runs)
        lay[1] = max(lay[1], n_scans)
        lay[2] += n_runs * n_scans

    def _write_grid_groups(self, topic: str, times, columns, packed, start: int, stop: int, group: int, n_runs: int):
        """Scans ``start … stop − 1`` of :meth:`_write_grid_v2` in messages of ``group`` scans
        (the last one may hold fewer; one of a single scan is an ordinary message)."""
        for k in range(start, stop, group):
            end = min(k + group, stop)
            G = end - k
            msg = Scan(scan=k, time_s=float(times[k]), frame_count=n_runs * G)
            if G > 1:
                msg.scan_count = G
                msg.times_s = np.repeat(np.asarray(times[k:end], "<f8"), n_runs).tobytes()
            for i, (name, dtype, inner, a) in enumerate(columns):
                triangles = packed.get(i)
                if triangles is None:
                    values = np.ascontiguousarray(a[:, k:end].swapaxes(0, 1)).tobytes()
                    col = msg.columns.add(name=name, dtype=dtype, layout=FIXED, values=values)
                else:
                    values = np.ascontiguousarray(triangles[:, k - start:end - start].swapaxes(0, 1)).tobytes()
                    col = msg.columns.add(name=name, dtype=dtype, layout=SYMMETRIC, values=values)
                col.shape.extend(inner)
            self._add_message(topic, float(times[k]), msg.SerializeToString())

    def sync(self):
        """Push the bytes written so far to the disk (``fsync``), so that the one at the end of
        :func:`write_dataset` has little left: called on the writing thread between large
        writes, it overlaps the disk with the main thread's work."""
        self._file.flush()
        os.fsync(self._file.fileno())

    def flush(self):
        """Close the open chunk so a crash loses at most what came after it."""
        self._emit_all()
        with _zstd_level(self.zstd_level):
            self._w.flush()

    def finish(self):
        self._emit_all()
        with _zstd_level(self.zstd_level):
            if self.contract != CONTRACT_V1 and self._layout:
                self._w.flush()  # the layout record follows every chunk
                self._w.add_metadata(METADATA_LAYOUT, {
                    topic: json.dumps({"runs": r, "scans": k, "frames": n}, sort_keys=True)
                    for topic, (r, k, n) in self._layout.items()})
            self._w.finish()


@contextmanager
def write_dataset(path: str | Path, metadata: Mapping[str, Mapping[str, str]] | None = None,
                  contract: str = CONTRACT_VERSION, zstd_level: int | None = None, pack_symmetric: bool = False,
                  group_scans: bool = False):
    """Atomically write an MCAP file of frames: ``with write_dataset(p, meta) as w: w.write(...)``
    (``zstd_level``: the chunks' compression level, None for zstd's default; ``pack_symmetric``:
    :meth:`McapFrameWriter.write_grid` stores symmetric matrices as their upper triangles;
    ``group_scans``: a long recording's scans may share messages, :func:`scans_per_message`)."""
    with atomic_output(path) as f:
        w = McapFrameWriter(f, metadata, contract, zstd_level, pack_symmetric, group_scans)
        yield w
        w.finish()


def scenario_metadata(scenario: str, params: Mapping, seed: int) -> dict[str, dict[str, str]]:
    """The metadata record every simulated file carries (its ``contract`` is the writer's)."""
    return {
        METADATA_SCENARIO: {
            "scenario": scenario,
            "params": json.dumps(dict(params), sort_keys=True),
            "seed": str(seed),
            "package_version": __version__,
            "contract": CONTRACT_VERSION,
        }
    }


# --------------------------------------------------------------------------- reading

# What a dependency raises on bad bytes; each becomes an InputError naming the file (and chunk).
_DATA_ERRORS = (McapError, struct.error, EOFError, ValueError, KeyError, IndexError, OverflowError, MemoryError,
                zstandard.ZstdError, DecodeError, UnicodeDecodeError)


class _BadData(Exception):
    """Something wrong inside one message or chunk (becomes an InputError or a dropped chunk)."""


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


def _u4(data: bytes, n: int, what: str) -> np.ndarray:
    if len(data) != 4 * n:
        raise _BadData(f"{what} holds {len(data)} bytes for {n} frame(s)")
    return np.frombuffer(data, "<u4")


def _decode_column(c, n: int) -> tuple[str, _Column]:
    if c.dtype not in _ALLOWED_DTYPES:
        raise _BadData(f"column {c.name!r} has dtype {c.dtype!r}, not in the contract")
    dtype = np.dtype(c.dtype)
    m = n
    frames = c.frames
    if frames:
        idx = _u4(frames, len(frames) // 4, f"column {c.name!r} frames") if len(frames) % 4 == 0 else None
        if idx is None or (idx.size and (idx[-1] >= n or (idx.size > 1 and np.any(np.diff(idx.astype(np.int64)) <= 0)))):
            raise _BadData(f"column {c.name!r} lists frames outside 0 … {n - 1} or out of order")
        m = idx.size
    shape = tuple(int(s) for s in c.shape)
    which = idx if frames else None
    if c.layout == IRREGULAR:
        if len(c.entries) != m:
            raise _BadData(f"column {c.name!r} holds {len(c.entries)} entries for {m} frame(s)")
        return c.name, _Column(IRREGULAR, dtype, m, items=[_decode_array(e) for e in c.entries], frames=which)
    values = c.values
    if c.layout == SYMMETRIC:
        return c.name, _symmetric_column(c.name, dtype, m, shape, values, which)
    row = math.prod(shape) * dtype.itemsize
    if c.layout == FIXED:
        if m * row != len(values):
            raise _BadData(f"column {c.name!r} claims {m} entries of shape {shape} ({dtype}) but holds "
                           f"{len(values)} bytes")
        return c.name, _Column(FIXED, dtype, m, shape, np.frombuffer(values, dtype).reshape(m, *shape), frames=which)
    if c.layout != RAGGED:
        raise _BadData(f"column {c.name!r} has unknown layout {c.layout}")
    if len(c.offsets) != 8 * (m + 1):
        raise _BadData(f"column {c.name!r} holds {len(c.offsets)} bytes of offsets for {m} entries")
    offsets = np.frombuffer(c.offsets, "<i8")
    if offsets[0] != 0 or np.any(np.diff(offsets) < 0) or int(offsets[-1]) * row != len(values):
        raise _BadData(f"column {c.name!r} has offsets that do not match its {len(values)} bytes of values")
    rows = int(offsets[-1])
    return c.name, _Column(RAGGED, dtype, m, shape, np.frombuffer(values, dtype).reshape(rows, *shape),
                           offsets.astype(np.int64), frames=which)


def _symmetric_column(name: str, dtype: np.dtype, m: int, shape: tuple, values: bytes, frames) -> _Column:
    """A ``SYMMETRIC`` column (entries of ``shape`` stored as their upper triangles) made whole:
    the ``FIXED`` column the writer was given."""
    if len(shape) < 2 or shape[-1] != shape[-2] or not shape[-1] or dtype.kind != "f":
        raise _BadData(f"column {name!r} is stored as symmetric matrices but has entries of shape {shape} ({dtype})")
    n = shape[-1]
    upper, lower = _triangle_indices(n)
    lead = (m, *shape[:-2])
    if math.prod(lead) * upper.size * dtype.itemsize != len(values):
        raise _BadData(f"column {name!r} claims {m} entries of symmetric {shape} ({dtype}) but holds "
                       f"{len(values)} bytes")
    packed = np.frombuffer(values, dtype).reshape(*lead, upper.size)
    full = np.empty((*lead, n * n), dtype)
    full[..., lower] = packed
    full[..., upper] = packed
    return _Column(FIXED, dtype, m, shape, full.reshape(m, *shape), frames=frames)


@dataclass
class _Block:
    """One decoded v2 message: frames of one scan."""

    scan: int
    runs: np.ndarray
    time_s: float
    times: np.ndarray | None
    columns: dict[str, _Column]
    first_run: int | None = None  # the runs are first_run … (None: the message lists them)
    scan_count: int = 1  # scans scan … scan + scan_count − 1, runs first_run … in each (scan-major)

    def scans(self) -> np.ndarray:
        """The scan of each frame."""
        if self.scan_count == 1:
            return np.full(self.n, self.scan, np.int64)
        return np.repeat(np.arange(self.scan, self.scan + self.scan_count, dtype=np.int64), self.n // self.scan_count)

    @property
    def n(self) -> int:
        return self.runs.size


def decode_scan(data: bytes) -> _Block:
    """Decode one ``replay.v2.Scan`` message (checking every count against the bytes it holds)."""
    msg = Scan()
    msg.ParseFromString(data)
    n = msg.frame_count
    if not 0 < n <= MAX_FRAMES_PER_MESSAGE:
        raise _BadData(f"message claims {n} frames (1 … {MAX_FRAMES_PER_MESSAGE} allowed)")
    first_run = None
    if msg.runs:
        runs = _u4(msg.runs, n, "runs").astype(np.int64)
    else:
        first_run = msg.first_run
        runs = np.arange(first_run, first_run + n, dtype=np.int64)
    times = np.frombuffer(msg.times_s, "<f8") if msg.times_s else None
    if times is not None and times.size != n:
        raise _BadData(f"times_s holds {len(msg.times_s)} bytes for {n} frame(s)")
    scan_count = max(1, msg.scan_count)
    if scan_count > 1:  # a group of scans (a long recording): runs first_run … in each
        if msg.runs or times is None or n % scan_count:
            raise _BadData(f"a message of {scan_count} scans must hold the same runs in each ({n} frame(s)), "
                           "from first_run, with times_s")
        runs = np.tile(np.arange(first_run, first_run + n // scan_count, dtype=np.int64), scan_count)
    columns = {}
    for c in msg.columns:
        name, col = _decode_column(c, n)
        if name in columns:
            raise _BadData(f"column {name!r} appears twice")
        columns[name] = col
    return _Block(msg.scan, runs, msg.time_s, times, columns, first_run, scan_count)


def _check_indices(runs_max: int, scan: int, topic: str, layout: dict | None) -> None:
    if runs_max >= MAX_INDEX or scan >= MAX_INDEX:
        raise _BadData(f"a frame on {topic} claims run {runs_max} scan {scan}; this reader accepts indices "
                       f"below {MAX_INDEX}")
    if layout is not None and topic in layout:
        runs, scans = layout[topic]["runs"], layout[topic]["scans"]
        if runs_max >= runs or scan >= scans:
            raise _BadData(f"a frame on {topic} claims run {runs_max} scan {scan}, but the file's "
                           f"{METADATA_LAYOUT} record declares {runs} run(s) × {scans} scan(s)")


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
        if chunk.compression not in ("", "zstd", "lz4"):
            raise _BadData(f"unknown compression {chunk.compression!r}")
        if chunk.uncompressed_size > MAX_CHUNK_BYTES:
            raise _BadData(f"declares {chunk.uncompressed_size} bytes uncompressed (this reader accepts up to "
                           f"{MAX_CHUNK_BYTES})")
        if chunk.compression == "zstd":
            raw = self._zstd.decompress(chunk.data, max_output_size=chunk.uncompressed_size)
        elif chunk.compression == "lz4":
            raw = _lz4_decompress(chunk.data, chunk.uncompressed_size)
        else:
            raw = chunk.data
        if len(raw) != chunk.uncompressed_size:
            raise _BadData(f"holds {len(raw)} bytes uncompressed, its record says {chunk.uncompressed_size}")
        if chunk.uncompressed_crc != 0:
            crc = zlib.crc32(raw)
            if crc != chunk.uncompressed_crc:
                raise _BadData(f"CRC mismatch (stored {chunk.uncompressed_crc:#010x}, computed {crc:#010x})")
        self.decompressed += len(raw)
        return _chunk_records(raw)

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
                summary_ok, data_problem = _section_crcs(f)
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
                if index.chunk_start_offset + index.chunk_length > size or index.chunk_length < 9:
                    raise _BadData(f"lies outside the file ({size} bytes)")
                f.seek(index.chunk_start_offset)
                raw = f.read(index.chunk_length)
                if raw[0] != Opcode.CHUNK:
                    raise _BadData(f"is not a chunk record (opcode {raw[0]:#04x})")
                chunk = Chunk.read(_ReadStream(raw[9:]))
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


def _lz4_decompress(data: bytes, size: int) -> bytes:
    """An lz4 chunk's bytes decompressed, never more than one byte beyond the ``size`` its record
    declares (a small chunk cannot expand to fill the memory); lz4 reports bytes that are not an
    lz4 frame as a RuntimeError, which becomes the chunk's problem here."""
    import lz4.frame

    decompressor = lz4.frame.LZ4FrameDecompressor()
    try:
        raw = decompressor.decompress(data, max_length=size + 1)
    except RuntimeError as exc:
        raise _BadData(f"is marked lz4 but does not decompress ({str(exc).strip() or type(exc).__name__})") from None
    if len(raw) == size and not decompressor.eof:
        raise _BadData("is marked lz4 but its lz4 frame ends early or holds more than its record declares")
    if decompressor.eof and decompressor.unused_data:
        raise _BadData(f"holds {len(decompressor.unused_data)} byte(s) after its lz4 frame")
    return raw


def _chunk_records(raw: bytes) -> Iterator:
    """Walk the records of a decompressed chunk: Schema and Channel records (parsed by mcap),
    ``(channel_id, data)`` for each Message (its 22-byte header read here, the data not copied)."""
    view = memoryview(raw)
    pos, end_all = 0, len(raw)
    while pos < end_all:
        if pos + 9 > end_all:
            raise _BadData("its records end in the middle of a record header")
        opcode, length = _RECORD_HEAD.unpack_from(raw, pos)
        pos += 9
        end = pos + length
        if end > end_all:
            raise _BadData(f"a record (opcode {opcode:#04x}) runs past the chunk's end")
        if opcode == Opcode.MESSAGE:
            if length < 22:
                raise _BadData(f"a message record of {length} bytes is shorter than its header")
            yield _MESSAGE_HEAD.unpack_from(raw, pos)[0], view[pos + 22:end]
        elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL):
            stream = _ReadStream(raw[pos:end])
            yield Schema.read(stream) if opcode == Opcode.SCHEMA else Channel.read(stream)
        pos = end


_RECORD_HEAD = struct.Struct("<BQ")
_MESSAGE_HEAD = struct.Struct("<HIQQ")


def _section_crcs(f) -> tuple[bool, str | None]:
    """Check the summary CRC in the footer and the data-section CRC in the DataEnd record.

    Returns ``(summary usable, problem with the data section or None)``. A file whose footer is
    missing or malformed (truncated) gets ``(True, None)``: reading it finds the damage. The
    data section is hashed only when its CRC was written (v2 writes it; v1 did not).
    """
    size = os.fstat(f.fileno()).st_size
    tail = len(MCAP_MAGIC) + 29
    if size < len(MCAP_MAGIC) + tail:
        return True, None
    f.seek(size - tail)
    footer = f.read(29)
    opcode, length, summary_start, _, summary_crc = struct.unpack("<BQQQI", footer)
    if opcode != Opcode.FOOTER or length != 20 or summary_start > size - tail:
        return True, None
    if summary_start and summary_crc:
        crc = zlib.crc32(footer[:25], _crc_range(f, summary_start, size - tail, 0))
        if crc != summary_crc:
            return False, None
    data_end = (summary_start or size - tail) - 13
    if data_end < len(MCAP_MAGIC):
        return True, None
    f.seek(data_end)
    rec = f.read(13)
    opcode, length, data_crc = struct.unpack("<BQI", rec)
    if opcode != Opcode.DATA_END or length != 4 or data_crc == 0:
        return True, None
    crc = _crc_range(f, 0, data_end, 0)
    if crc != data_crc:
        return True, (f"data section CRC mismatch (stored {data_crc:#010x}, computed {crc:#010x}) outside the "
                      "chunks: a metadata, schema or channel record is damaged")
    return True, None


def _crc_range(f, start: int, end: int, crc: int) -> int:
    f.seek(start)
    left = end - start
    while left > 0:
        block = f.read(min(left, 16 << 20))
        if not block:
            break
        crc = zlib.crc32(block, crc)
        left -= len(block)
    return crc


class _ReadStream:
    """mcap's ReadDataStream interface over bytes already in memory."""

    def __init__(self, data: bytes):
        from mcap.data_stream import ReadDataStream

        self._s = ReadDataStream(io.BytesIO(data))

    def __getattr__(self, name):
        return getattr(self._s, name)


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


def _check_time_order(ch: ChannelData) -> None:
    """Refuse scan times that do not increase from scan to scan (a tracker's time step would be
    zero or negative; the table importers refuse the same). Scans a channel does not hold are
    skipped."""
    t = ch.times()
    t = t[np.isfinite(t)]
    back = np.flatnonzero(np.diff(t) <= 0)
    if back.size:
        k = int(back[0])
        raise InputError(f"{ch.topic}: scan times must increase, but a scan at {t[k + 1]:g} s follows one at "
                         f"{t[k]:g} s", ch.path)


def _check_scans_held(ch: ChannelData) -> None:
    """Refuse a measurement channel on which no frame holds some scan below its last: that scan's
    time is unknown, a filter cannot step over it, and no output could be written for it (such a
    file was accepted by ``eval`` and failed in ``replay``). A missing truth frame is the stage's
    to name; a file read with ``recover`` keeps the gaps its lost chunks leave."""
    if not any(ch.topic in family.inputs for family in vocab.FAMILIES.values()):
        return
    held = np.zeros(ch.n_scans, bool)
    held[ch._blocks.scan if ch._blocks is not None else ch._scan] = True  # per message where it can
    if not held.all():
        k = int(np.argmin(held))
        raise InputError(f"{ch.topic}: no frame holds scan {k} (the channel's scans run 0 … {ch.n_scans - 1}), so "
                         "its time is unknown; a scan without measurements is still a frame, with none", ch.path)


def _check_density(ch: ChannelData) -> None:
    """Refuse run/scan indices that would size a [run, scan] grid far beyond the frames present."""
    frames = ch.n_frames
    cells = ch.n_runs * ch.n_scans
    if cells > MAX_SPARSITY * max(frames, 1):
        raise InputError(f"{ch.topic}: its frames claim runs up to {ch.n_runs - 1} and scans up to {ch.n_scans - 1}, "
                         f"a {ch.n_runs} × {ch.n_scans} grid, but the channel holds {frames} frame(s); "
                         f"refusing a grid with more than {MAX_SPARSITY} cells per frame", ch.path)


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


def check_values(channels: Mapping[str, "ChannelData"], path=None) -> None:
    """Refuse input values outside the declared table :data:`trackreplay.vocabulary.VALUES`
    (wrong number kind, NaN/Inf, out of range) and scan times that are not finite, negative or
    beyond :data:`trackreplay.vocabulary.TIME_LIMIT_S` (times count from the recording's start, as
    every importer writes them: an MCAP log time is unsigned, so no output could carry a
    negative one).

    Raises
    ------
    InputError
        Naming the channel, the array and the first offending run and scan.
    """
    from trackreplay import vocabulary as vocab

    topic_key = {topic: key for key, topic in vocab.CHANNELS.items()}
    for topic, ch in channels.items():
        t = np.asarray(ch.time_s, float)
        bad = ~np.isfinite(t) | (np.abs(t) > vocab.TIME_LIMIT_S)
        if bad.any():
            i = int(np.argmax(bad))
            raise InputError(f"{topic}: scan time {float(t[i])!r} s at run {ch.run[i]} scan {ch.scan[i]} is not a finite "
                             f"time within ±{vocab.TIME_LIMIT_S:g} s", path)
        if np.any(t < 0):
            i = int(np.argmax(t < 0))
            raise InputError(f"{topic}: scan time {t[i]:g} s at run {ch.run[i]} scan {ch.scan[i]} is negative; scan "
                             "times count from the recording's start (MCAP log times cannot be negative)", path)
        if ch.n_frames and not ch._scan_major():  # (every run and scan once: nothing to look for)
            # one frame per run and scan: a second one would silently replace or shadow the first
            key = ch.run.astype(np.int64) * (int(ch.scan.max()) + 1) + ch.scan.astype(np.int64)
            order = np.argsort(key, kind="stable")
            same = np.flatnonzero(np.diff(key[order]) == 0)
            if same.size:
                i = order[same[0] + 1]
                raise InputError(f"{topic} holds {same.size} duplicated frame(s), the first at run {ch.run[i]} "
                                 f"scan {ch.scan[i]}", path)
        parallel = [n for n in vocab.PARALLEL.get(topic_key.get(topic), ()) if n in ch.arrays]
        if len(parallel) > 1:
            lengths = [_item_counts(ch, n) for n in parallel]
            for name, length in zip(parallel[1:], lengths[1:]):
                bad = np.flatnonzero(length != lengths[0])
                if bad.size:
                    i = bad[0]
                    raise InputError(f"{topic}: {parallel[0]} and {name} list different numbers of items at run "
                                     f"{ch.run[i]} scan {ch.scan[i]} ({lengths[0][i]} vs {length[i]})", path)
        specs = vocab.VALUES.get(topic_key.get(topic), {})
        for name, spec in specs.items():
            if name not in ch.arrays:
                continue
            column = ch._column(name)
            # in bulk where the file stores the array as one block (v2); frame by frame otherwise,
            # and always frame by frame to name the first offending frame
            if column is not None and column.kind != IRREGULAR:
                block = column.values
            else:  # frames decoded one by one (v1, irregular): check them joined, in one pass
                items = ch.array(name)
                kinds = {np.asarray(a).dtype.kind for a in items}
                block = (np.concatenate([np.ravel(a) for a in items]) if len(kinds) == 1 and items
                         else None)
            if block is not None and _values_problem(block, spec) is None:
                continue
            for i, a in enumerate(ch.array(name)):
                problem = _values_problem(np.asarray(a), spec)
                if problem is not None:
                    raise InputError(f"{topic} {name} {problem} at run {ch.run[i]} scan {ch.scan[i]}", path)


def _item_counts(ch: "ChannelData", name: str) -> np.ndarray:
    """Items (length of the first axis) of array ``name`` in each frame, in bulk where the file
    stores it as one block."""
    column = ch._column(name)
    if column is not None and column.frames is None:
        if column.kind == RAGGED:
            return column.lengths()
        if column.kind == FIXED:
            return np.full(column.count, column.values.shape[1] if column.values.ndim > 1 else 1)
    return np.array([np.shape(a)[0] if np.ndim(a) else 1 for a in ch.array(name)])


#: Values per block of :func:`_values_problem`: its temporaries (a complex array's magnitudes)
#: stay a few MB however large the column.
VALUES_CHECK_BLOCK = 1 << 19


def _values_problem(a: np.ndarray, spec) -> str | None:
    """What is wrong with the values ``a`` under ``spec`` (see :func:`check_values`), or None."""
    if a.size == 0:
        return None
    if a.dtype.kind not in spec.kinds:
        return f"holds {a.dtype} values (expected {'/'.join(_KIND_NAMES[k] for k in spec.kinds)})"
    flat = a.reshape(-1)
    blocks = [flat[i:i + VALUES_CHECK_BLOCK] for i in range(0, flat.size, VALUES_CHECK_BLOCK)]
    if spec.finite and not all(np.isfinite(b).all() for b in blocks):
        return f"holds {sum(int(np.count_nonzero(~np.isfinite(b))) for b in blocks)} NaN/Inf value(s)"
    low = high = 0
    with np.errstate(invalid="ignore"):
        for b in blocks:
            magnitude = np.abs(b) if a.dtype.kind == "c" else b
            if spec.low is not None and a.dtype.kind != "c":
                low += int(np.count_nonzero(magnitude < spec.low))
            if spec.high is not None:
                high += int(np.count_nonzero(magnitude > spec.high))
    if low:
        return f"holds {low} negative value(s)" if spec.low == 0 else f"holds {low} value(s) below {spec.low:g}"
    if high:
        return f"holds {high} value(s) above {spec.high:g}"
    return None


_KIND_NAMES = {"f": "float", "i": "integer", "u": "unsigned integer", "c": "complex", "b": "boolean"}


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


def _check_frame_time(topic: str, run: int, scan: int, t: float, path: Path) -> None:
    """The scan-time rule of :func:`check_values` for one frame read by :func:`iter_frames` (whose
    frames are written again, and an MCAP log time cannot hold a negative or non-finite time)."""
    from trackreplay.vocabulary import TIME_LIMIT_S

    if not (math.isfinite(t) and 0 <= t <= TIME_LIMIT_S):
        raise InputError(f"{topic}: scan time {t:g} s at run {run} scan {scan} is not a time from the recording's "
                         f"start within 0 … {TIME_LIMIT_S:g} s", path)


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
