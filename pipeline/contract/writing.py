"""Writing files: :func:`write_dataset` and its :class:`McapFrameWriter`, atomic outputs
(:func:`atomic_output`, :func:`publish`) and the zstd level of the chunks (docs/contract.md).

Every file appears complete or not at all: it is written to a temporary next to its path and
renamed over it on success. Replay outputs are written at :data:`OUTPUT_ZSTD_LEVEL` with their
symmetric matrices packed; data sets keep zstd's default level and the bytes earlier versions wrote.
"""

from __future__ import annotations

import json
import os
import tempfile
import threading
from contextlib import contextmanager
from pathlib import Path
from typing import Mapping

import numpy as np
import zstandard
import mcap.writer
from mcap.writer import CompressionType, Writer

from trackreplay import __version__
from trackreplay.contract.layout import (_SCHEMA_DATA, CONTRACT_V1, CONTRACT_V2, CONTRACT_VERSION, FIXED,
                                         GROUPED_SCAN_DESCRIPTOR_SET, METADATA_LAYOUT, METADATA_SCENARIO,
                                         PACKED_SCAN_DESCRIPTOR_SET, SYMMETRIC, Scan, scans_per_message)
from trackreplay.contract.messages import (_little_endian_contract_dtype, _normalise, _Part, _square_real,
                                           encode_frame, encode_scan, upper_triangles)
from trackreplay.errors import InputError


BLOCK_BYTES = 32 << 20  # the writer closes a message of one channel and scan beyond this
PACK_BLOCK_BYTES = 1 << 20  # scans of a symmetric grid packed in one call (McapFrameWriter.write_grid)


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


# zstd level of the chunks of replay outputs: one of zstd's fast levels. Tracker outputs are
# floats that compress little at any level (1.29× at level 1 at 10,000 radar runs), and at
# level −3 the writer takes a third less CPU and the write finishes 1.2 s sooner for a file
# 7.5 % larger (590 against 549 MB, ``benchmarks/bench_write.py``): the writer runs beside the
# evaluation, and at level 1 it was the longer of the two. Data sets, written once and read
# many times, keep the default level
OUTPUT_ZSTD_LEVEL = -3


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
            # each packing column's scans first … first + step − 1 as upper triangles, or None,
            # scan by scan ((step, runs, …): a scan's triangles are then one contiguous piece)
            packed = {i: upper_triangles(columns[i][3][:, first:first + step].swapaxes(0, 1)) for i in packing}
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
                                              values=triangles[k - first].tobytes())
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
                    values = triangles[k - start:end - start].tobytes()  # scan-major already
                    col = msg.columns.add(name=name, dtype=dtype, layout=SYMMETRIC, values=values)
                col.shape.extend(inner)
            self._add_message(topic, float(times[k]), msg.SerializeToString())

    def start_writeback(self):
        """Hand the bytes written so far to the system and have it start writing them to the
        disk, without waiting, so that the ``fsync`` at the end of :func:`write_dataset` has
        little left: called on the writing thread between large writes, the disk then works
        beside the main thread's.

        Linux starts the writeback of a file's dirty pages on ``posix_fadvise(DONTNEED)`` (and
        drops the pages already on the disk from its cache: nothing reads the outputs back while
        they are written). Waiting for them here instead (``fsync``) kept the writing thread,
        the longer of the two at 10,000 radar runs, 0.3 s longer (``docs/benchmarks.md``).
        Where there is no ``posix_fadvise`` the final ``fsync`` writes everything.
        """
        self._file.flush()
        advise = getattr(os, "posix_fadvise", None)
        if advise is not None:
            try:
                advise(self._file.fileno(), 0, 0, os.POSIX_FADV_DONTNEED)
            except OSError:  # a file system that takes no advice: the final fsync still writes it all
                pass

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
