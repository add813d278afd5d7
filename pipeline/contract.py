"""The MCAP data contract: the one module that knows how data sit in a file.

Every message is a ``replay.v1.Frame`` (protobuf, its FileDescriptorSet embedded in the file
as the schema, so any MCAP tool can decode it without our code)::

    message Array { string name = 1; repeated uint32 shape = 2; string dtype = 3; bytes data = 4; }
    message Frame { uint32 run = 1; uint32 scan = 2; double time_s = 3; repeated Array arrays = 4;
                    uint32 run_count = 5; }

* one message = one Monte Carlo run × one scan of one channel; ``log_time`` is the scan time
  in nanoseconds and messages are written scan-major, so log time never goes backwards;
* a *batched* frame (``run_count`` = N > 1) covers runs ``run … run + N − 1`` of one scan and
  its arrays carry a leading axis of length N; tracker outputs use it (one frame per scan
  instead of one per run and scan), measurements keep one frame per run since their lengths
  vary; readers expand batched frames, so consumers see one entry per (run, scan) either way;
* arrays travel as raw little-endian bytes with shape and numpy dtype string
  (``np.frombuffer`` on read, no copies, no text round trip: values survive exactly);
* ground truth lives on its own channels (``/truth/...``) next to the measurements;
* scenario parameters, seed, package and contract version are MCAP metadata records.

The schema name carries the contract version (``replay.v1``); a reader refuses schemas it does
not know instead of guessing.
"""

from __future__ import annotations

import json
import os
import struct
import tempfile
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Mapping

import numpy as np
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from pipeline import __version__
from pipeline.errors import InputError

CONTRACT_VERSION = "replay.v1"
FRAME_SCHEMA = f"{CONTRACT_VERSION}.Frame"
METADATA_SCENARIO = "replay.scenario"
METADATA_PROVENANCE = "replay.provenance"
MCAP_MAGIC = b"\x89MCAP0\r\n"
_ALLOWED_DTYPES = {"<f8", "<f4", "<c16", "<c8", "<i8", "<i4", "<u4", "<u2", "|u1", "|b1"}


def _build_frame_class():
    """Build the Frame message class at run time (no generated code to keep in sync)."""
    fdp = descriptor_pb2.FileDescriptorProto(
        name="replay/v1/frame.proto", package=CONTRACT_VERSION, syntax="proto3"
    )
    arr = fdp.message_type.add(name="Array")
    F = descriptor_pb2.FieldDescriptorProto
    arr.field.add(name="name", number=1, type=F.TYPE_STRING, label=F.LABEL_OPTIONAL)
    arr.field.add(name="shape", number=2, type=F.TYPE_UINT32, label=F.LABEL_REPEATED)
    arr.field.add(name="dtype", number=3, type=F.TYPE_STRING, label=F.LABEL_OPTIONAL)
    arr.field.add(name="data", number=4, type=F.TYPE_BYTES, label=F.LABEL_OPTIONAL)
    frame = fdp.message_type.add(name="Frame")
    frame.field.add(name="run", number=1, type=F.TYPE_UINT32, label=F.LABEL_OPTIONAL)
    frame.field.add(name="scan", number=2, type=F.TYPE_UINT32, label=F.LABEL_OPTIONAL)
    frame.field.add(name="time_s", number=3, type=F.TYPE_DOUBLE, label=F.LABEL_OPTIONAL)
    frame.field.add(
        name="arrays", number=4, type=F.TYPE_MESSAGE, label=F.LABEL_REPEATED,
        type_name=f".{CONTRACT_VERSION}.Array",
    )
    frame.field.add(name="run_count", number=5, type=F.TYPE_UINT32, label=F.LABEL_OPTIONAL)
    pool = descriptor_pool.DescriptorPool()
    file_desc = pool.Add(fdp)
    descriptor = pool.FindMessageTypeByName(FRAME_SCHEMA)
    fds = descriptor_pb2.FileDescriptorSet()
    fds.file.add().CopyFrom(fdp)
    del file_desc
    return message_factory.GetMessageClass(descriptor), fds.SerializeToString()


Frame, FRAME_DESCRIPTOR_SET = _build_frame_class()


# --------------------------------------------------------------------------- records


@dataclass
class ChannelData:
    """All frames of one channel, as decoded.

    Attributes
    ----------
    run, scan : ndarray of int
        Run and scan index per frame.
    time_s : ndarray of float
        Scan time per frame.
    arrays : dict of str to list of ndarray
        One list per array name, one entry per frame.
    topic : str
        The channel's topic (named in error messages).
    path : str, optional
        The file it was read from (named in error messages).
    """

    run: np.ndarray
    scan: np.ndarray
    time_s: np.ndarray
    arrays: dict[str, list[np.ndarray]]
    topic: str = "channel"
    path: str | None = None

    @property
    def n_runs(self) -> int:
        return int(self.run.max()) + 1 if self.run.size else 0

    @property
    def n_scans(self) -> int:
        return int(self.scan.max()) + 1 if self.scan.size else 0

    def array(self, name: str) -> list[np.ndarray]:
        """One array's entries, one per frame.

        Raises
        ------
        InputError
            The channel has no array ``name``, or only some of its frames carry it.
        """
        if name not in self.arrays:
            have = ", ".join(sorted(self.arrays)) or "none"
            raise InputError(f"{self.topic} lacks array {name!r} (have: {have})", self.path)
        items = self.arrays[name]
        if len(items) != self.run.size:
            raise InputError(f"{self.topic} array {name!r} is in {len(items)} of {self.run.size} frames; "
                             "every frame must carry it", self.path)
        return items

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

    def grid(self, name: str) -> np.ndarray:
        """Stack a fixed-shape array into ``[run, scan, ...]`` (NaN where a frame is missing).

        Raises
        ------
        InputError
            The array is missing or its shape differs between frames.
        """
        items = self.array(name)
        if not items:
            return np.zeros((0, 0))
        inner = items[0].shape
        bad = next((i for i, a in enumerate(items) if a.shape != inner), None)
        if bad is not None:
            raise InputError(f"{self.topic} array {name!r} has shape {inner} in {self._where(0)} but "
                             f"{items[bad].shape} in {self._where(bad)}; it must keep one shape in every frame",
                             self.path)
        dtype = np.result_type(items[0].dtype, np.float64) if items[0].dtype.kind in "iub" else items[0].dtype
        out = np.full((self.n_runs, self.n_scans, *inner), np.nan, dtype=dtype)
        out[self.run, self.scan] = np.stack(items)
        return out

    def ragged(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """Pad a variable-length array into ``[run, scan, max_len, ...]`` with NaN.

        Returns
        -------
        values : ndarray
            Padded values.
        counts : ndarray of int, shape (run, scan)
            How many entries each frame held (0 where the frame is missing).

        Raises
        ------
        InputError
            The array is missing, 0-d in some frame (no entry axis), or its entries change
            shape between frames.
        """
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
        counts = np.zeros((self.n_runs, self.n_scans), dtype=np.int64)
        lengths = np.array([a.shape[0] for a in items], dtype=np.int64)
        counts[self.run, self.scan] = lengths
        width = int(lengths.max()) if lengths.size else 0
        out = np.full((self.n_runs, self.n_scans, width, *tail), np.nan)
        if width:
            # one scatter instead of a Python loop over frames
            slot = np.arange(int(lengths.sum())) - np.repeat(np.cumsum(lengths) - lengths, lengths)
            out[np.repeat(self.run, lengths), np.repeat(self.scan, lengths), slot] = np.concatenate(items)
        return out, counts

    def times(self) -> np.ndarray:
        """Scan times ``[scan]`` (taken from run 0's frames, or the first seen per scan)."""
        t = np.full(self.n_scans, np.nan)
        t[self.scan[::-1]] = self.time_s[::-1]
        return t


@dataclass
class Dataset:
    """An MCAP file's content: channels by topic plus the metadata records."""

    path: str
    channels: dict[str, ChannelData]
    metadata: dict[str, dict[str, str]]
    recovered_messages: int | None = None
    cache: dict = field(default_factory=dict, repr=False)  # stages' decoded views, computed once

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
            except ValueError:
                raise InputError(f"{METADATA_SCENARIO} metadata: params is not valid JSON", self.path) from None
            if not isinstance(out["params"], dict):
                raise InputError(f"{METADATA_SCENARIO} metadata: params must be a JSON object", self.path)
        return out


# --------------------------------------------------------------------------- writing


def encode_frame(run: int, scan: int, time_s: float, arrays: Mapping[str, np.ndarray],
                 run_count: int = 1) -> bytes:
    """Serialise one frame; arrays keep their exact bytes, shape and dtype.

    With ``run_count`` > 1 the frame is batched: every array's first axis is the run axis.
    """
    msg = Frame(run=int(run), scan=int(scan), time_s=float(time_s),
                run_count=int(run_count) if run_count > 1 else 0)
    for name, value in arrays.items():
        a = np.asarray(value)
        if not a.flags.c_contiguous:  # (np.ascontiguousarray would turn 0-d into 1-d)
            a = a.copy(order="C")
        if a.dtype.byteorder == ">":
            a = a.astype(a.dtype.newbyteorder("<"))
        dt = a.dtype.str
        if dt not in _ALLOWED_DTYPES:
            raise ValueError(f"dtype {dt} of array {name!r} is not in the contract")
        msg.arrays.add(name=name, shape=a.shape, dtype=dt, data=a.tobytes())
    return msg.SerializeToString()


def decode_frame(data: bytes) -> tuple[int, int, float, dict[str, np.ndarray], int]:
    """Inverse of :func:`encode_frame`; returns ``(run, scan, time_s, arrays, run_count)``."""
    msg = Frame()
    msg.ParseFromString(data)
    arrays = {}
    for a in msg.arrays:
        if a.dtype not in _ALLOWED_DTYPES:
            raise ValueError(f"array {a.name!r} has dtype {a.dtype!r}, not in the contract")
        arrays[a.name] = np.frombuffer(a.data, dtype=a.dtype).reshape(tuple(a.shape))
    return msg.run, msg.scan, msg.time_s, arrays, max(msg.run_count, 1)


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

    A crash or an exception leaves any existing ``path`` untouched and removes the temporary.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=path.name + ".", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, mode) as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        publish(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


class McapFrameWriter:
    """Writes frames on named channels; one chunk is flushed per scan block."""

    def __init__(self, f, metadata: Mapping[str, Mapping[str, str]] | None = None):
        self._w = Writer(f, compression=CompressionType.ZSTD, chunk_size=1 << 20)
        # MCAP requires a profile string; "" is the documented value for no profile.
        self._w.start(profile="", library=f"trackreplay {__version__}")
        self._schema = self._w.register_schema(
            name=FRAME_SCHEMA, encoding="protobuf", data=FRAME_DESCRIPTOR_SET
        )
        self._channels: dict[str, int] = {}
        self._seq: dict[int, int] = {}
        for name, rec in (metadata or {}).items():
            self._w.add_metadata(name, {str(k): str(v) for k, v in rec.items()})

    def channel(self, topic: str) -> int:
        if topic not in self._channels:
            cid = self._w.register_channel(
                topic=topic, message_encoding="protobuf", schema_id=self._schema,
                metadata={"contract": CONTRACT_VERSION},
            )
            self._channels[topic] = cid
            self._seq[cid] = 0
        return self._channels[topic]

    def write(self, topic: str, run: int, scan: int, time_s: float, arrays: Mapping[str, np.ndarray],
              run_count: int = 1):
        cid = self.channel(topic)
        t_ns = int(round(time_s * 1e9))
        self._w.add_message(cid, log_time=t_ns, data=encode_frame(run, scan, time_s, arrays, run_count),
                            publish_time=t_ns, sequence=self._seq[cid])
        self._seq[cid] += 1

    def write_grid(self, topic: str, times: np.ndarray, arrays: Mapping[str, np.ndarray]):
        """Write ``[run, scan, ...]`` arrays as one batched frame per scan (all runs)."""
        n_runs, n_scans = next(iter(arrays.values())).shape[:2]
        for k in range(n_scans):
            self.write(topic, 0, k, times[k], {n: a[:, k] for n, a in arrays.items()}, run_count=n_runs)

    def flush(self):
        """Close the open chunk so a crash loses at most what came after it."""
        self._w.flush()

    def finish(self):
        self._w.finish()


@contextmanager
def write_dataset(path: str | Path, metadata: Mapping[str, Mapping[str, str]] | None = None):
    """Atomically write an MCAP file of frames: ``with write_dataset(p, meta) as w: w.write(...)``."""
    with atomic_output(path) as f:
        w = McapFrameWriter(f, metadata)
        yield w
        w.finish()


def scenario_metadata(scenario: str, params: Mapping, seed: int) -> dict[str, dict[str, str]]:
    """The metadata record every simulated file carries."""
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


def _check_file(path: Path) -> None:
    if not path.exists():
        raise InputError("no such file", path)
    if path.is_dir():
        raise InputError("is a directory, expected an MCAP file", path)
    size = path.stat().st_size
    if size == 0:
        raise InputError("empty file (0 bytes), not an MCAP file", path)
    with open(path, "rb") as f:
        head = f.read(len(MCAP_MAGIC))
    if head != MCAP_MAGIC:
        raise InputError("not an MCAP file (bad magic bytes)", path)


def _accept(schema, path) -> None:
    if schema is None or schema.name != FRAME_SCHEMA or schema.encoding != "protobuf":
        name = None if schema is None else f"{schema.name} ({schema.encoding})"
        raise InputError(
            f"foreign schema {name}; this tool reads {FRAME_SCHEMA} (protobuf) frames", path
        )


def _collect(messages, path, topics) -> tuple[dict[str, ChannelData], int]:
    buckets: dict[str, tuple[list, list, list, dict]] = {}
    count = 0
    for schema, channel, message in messages:
        if topics is not None and channel.topic not in topics:
            continue
        _accept(schema, path)
        try:
            run, scan, t, arrays, n = decode_frame(message.data)
        except Exception as exc:  # protobuf raises its own DecodeError family
            raise InputError(f"undecodable frame on {channel.topic}: {exc}", path) from None
        b = buckets.setdefault(channel.topic, ([], [], [], {}))
        if n == 1:
            b[0].append(run)
            b[1].append(scan)
            b[2].append(t)
            for name, a in arrays.items():
                b[3].setdefault(name, []).append(a)
        else:
            if any(a.shape[:1] != (n,) for a in arrays.values()):
                raise InputError(f"batched frame on {channel.topic} does not carry {n} runs", path)
            b[0].extend(range(run, run + n))
            b[1].extend([scan] * n)
            b[2].extend([t] * n)
            for name, a in arrays.items():
                b[3].setdefault(name, []).extend(a)
        count += 1
    channels = {
        topic: ChannelData(np.asarray(r, dtype=np.int64), np.asarray(k, dtype=np.int64),
                           np.asarray(t, dtype=np.float64), arrs, topic=topic, path=str(path))
        for topic, (r, k, t, arrs) in buckets.items()
    }
    return channels, count


def read_dataset(path: str | Path, topics: Iterable[str] | None = None, recover: bool = False) -> Dataset:
    """Read an MCAP file of frames.

    Parameters
    ----------
    path : str or Path
        The file. It is only ever opened for reading.
    topics : iterable of str, optional
        Only these channels (default: all).
    recover : bool
        For a truncated file, keep every complete chunk instead of refusing the file.

    Raises
    ------
    InputError
        Missing, empty, foreign or truncated files (the message says how many messages a
        ``--recover`` read kept).
    """
    path = Path(path)
    _check_file(path)
    topics = None if topics is None else set(topics)
    with open(path, "rb") as f:
        try:
            reader = make_reader(f)
            summary = reader.get_summary()
            if summary is None:
                raise McapError("no summary section")
            metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
            for schema in summary.schemas.values():
                _accept(schema, path)
            # File order, not log-time order: frames carry their own run/scan indices, and the
            # reader's heap merge for log-time order costs more than everything else together.
            channels, _ = _collect(reader.iter_messages(topics=topics, log_time_order=False), path, topics)
            return Dataset(str(path), channels, metadata)
        except InputError:
            raise
        except (McapError, struct.error, EOFError, ValueError, OSError) as exc:
            reason = type(exc).__name__
    channels, metadata, n = _scan_damaged(path, topics)
    if not recover:
        raise InputError(
            f"truncated or corrupt MCAP ({reason}); {n} message(s) in complete chunks are "
            "recoverable with --recover", path)
    return Dataset(str(path), channels, metadata, recovered_messages=n)


def _scan_damaged(path: Path, topics) -> tuple[dict[str, ChannelData], dict, int]:
    """Read a damaged file record by record and keep everything before the damage.

    The stream reader decompresses each chunk whole and checks its CRC, so what it yields
    comes from complete chunks only. Metadata are written first in our files, so they
    usually survive too.
    """
    schemas: dict[int, object] = {}
    chans: dict[int, object] = {}
    metadata: dict[str, dict[str, str]] = {}
    items = []
    with open(path, "rb") as f:
        try:
            for rec in StreamReader(f, validate_crcs=True).records:
                if isinstance(rec, Schema):
                    schemas[rec.id] = rec
                elif isinstance(rec, Channel):
                    chans[rec.id] = rec
                elif isinstance(rec, Metadata):
                    metadata[rec.name] = dict(rec.metadata)
                elif isinstance(rec, Message) and rec.channel_id in chans:
                    ch = chans[rec.channel_id]
                    items.append((schemas.get(ch.schema_id), ch, rec))
        except Exception:  # the damage itself: EndOfFile, struct.error, CRC or record errors
            pass
    channels, n = _collect(items, path, topics)
    return channels, metadata, n


def dataset_topics(path: str | Path) -> list[str]:
    """Channel topics of a file (summary only, no message decoding)."""
    path = Path(path)
    _check_file(path)
    with open(path, "rb") as f:
        try:
            summary = make_reader(f).get_summary()
        except (McapError, struct.error, EOFError, ValueError) as exc:
            raise InputError(f"truncated or corrupt MCAP ({type(exc).__name__})", path) from None
    return sorted(c.topic for c in summary.channels.values()) if summary else []
