"""How data sit in a file: the MCAP layout of contract ``replay.v2`` (and ``replay.v1``).

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

Files of contract ``replay.v1`` (one ``replay.v1.Frame`` message per run and scan) still read.
This module holds the names, the schemas (built at run time: no generated code to keep in sync)
and the sane maxima a reader holds a file to; docs/contract.md is the full description.
"""

from __future__ import annotations

from typing import Iterable

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

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

# the layouts of a Column (its ``Layout`` enum)
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


# what a writer of each contract registers as its schema: (name, FileDescriptorSet)
_SCHEMA_DATA = {CONTRACT_V1: (FRAME_SCHEMA_V1, FRAME_DESCRIPTOR_SET), CONTRACT_V2: (SCAN_SCHEMA, SCAN_DESCRIPTOR_SET)}


class _BadData(Exception):
    """Something wrong inside one message or chunk (becomes an InputError or a dropped chunk)."""
