"""The MCAP data contract: the one package that knows how data sit in a file (docs/contract.md).

Contract ``replay.v2`` (written by this version) stores one protobuf ``replay.v2.Scan`` message
per channel and scan, carrying every run of that scan column by column, with its schema embedded
so that any MCAP tool decodes it; files of contract ``replay.v1`` (a message per run and scan)
still read. Its parts, each what its name says:

* :mod:`~trackreplay.contract.layout`: the layout on disk: contract, schema and metadata names,
  the protobuf message classes and their schemas, the column layouts (``FIXED``, ``RAGGED``,
  ``IRREGULAR``, ``SYMMETRIC``), :func:`scans_per_message` and the sane maxima a file is held to;
* :mod:`~trackreplay.contract.dataset`: what a read gives: :class:`Dataset` and
  :class:`ChannelData` (``array``, ``grid``, ``ragged``, ``times``) over bulk columns;
* :mod:`~trackreplay.contract.messages`: one message and its arrays, both ways
  (:func:`encode_scan` / :func:`decode_scan`, :func:`encode_frame` / :func:`decode_frame`,
  :func:`upper_triangles`);
* :mod:`~trackreplay.contract.writing`: :func:`write_dataset` and :class:`McapFrameWriter`,
  :func:`atomic_output` and :func:`publish`, the zstd level of outputs;
* :mod:`~trackreplay.contract.reading`: :func:`read_dataset`, :func:`iter_frames`,
  :func:`rewrite_dataset` and :func:`dataset_topics`, with every chunk's CRC checked and one
  :class:`~trackreplay.errors.InputError` naming the file and chunk for anything wrong in it;
  ``_records`` (private) walks the MCAP records of a chunk by hand, and says why;
* :mod:`~trackreplay.contract.checking`: :func:`check_values` and the rules every channel read
  meets (indices, density, scan times).

The names below are the contract's public interface; import them from ``trackreplay.contract``.
Tunables (``BLOCK_BYTES``, ``PACK_BLOCK_BYTES``, ``VALUES_CHECK_BLOCK``) are read from the
submodule that uses them: a test that changes one patches it there.
"""

from trackreplay.contract.layout import (
    CONTRACT_V1,
    CONTRACT_V2,
    CONTRACT_VERSION,
    FIXED,
    FRAME_DESCRIPTOR_SET,
    FRAME_SCHEMA,
    FRAME_SCHEMA_V1,
    FREE_FRAMES,
    GROUP_FRAMES,
    GROUP_MIN_SCANS,
    GROUPED_SCAN_DESCRIPTOR_SET,
    IRREGULAR,
    MAX_CHUNK_BYTES,
    MAX_FRAMES_PER_MESSAGE,
    MAX_INDEX,
    MAX_PADDED_BYTES,
    MAX_SPARSITY,
    MCAP_MAGIC,
    METADATA_LAYOUT,
    METADATA_PROVENANCE,
    METADATA_SCENARIO,
    PACKED_SCAN_DESCRIPTOR_SET,
    RAGGED,
    SCAN_DESCRIPTOR_SET,
    SCAN_SCHEMA,
    SCHEMA_CONTRACTS,
    SYMMETRIC,
    Frame,
    Scan,
    scans_per_message,
)
from trackreplay.contract.dataset import ChannelData, ColumnArrays, Dataset
from trackreplay.contract.messages import decode_frame, decode_scan, encode_frame, encode_scan, upper_triangles
from trackreplay.contract.writing import (
    BLOCK_BYTES,
    OUTPUT_ZSTD_LEVEL,
    PACK_BLOCK_BYTES,
    McapFrameWriter,
    atomic_output,
    publish,
    scenario_metadata,
    write_dataset,
)
from trackreplay.contract.checking import VALUES_CHECK_BLOCK, check_values
from trackreplay.contract.reading import RewriteReport, dataset_topics, iter_frames, read_dataset, rewrite_dataset

__all__ = [
    "BLOCK_BYTES", "CONTRACT_V1", "CONTRACT_V2", "CONTRACT_VERSION", "ChannelData", "ColumnArrays", "Dataset",
    "FIXED", "FRAME_DESCRIPTOR_SET", "FRAME_SCHEMA", "FRAME_SCHEMA_V1", "FREE_FRAMES", "Frame",
    "GROUPED_SCAN_DESCRIPTOR_SET", "GROUP_FRAMES", "GROUP_MIN_SCANS", "IRREGULAR", "MAX_CHUNK_BYTES",
    "MAX_FRAMES_PER_MESSAGE", "MAX_INDEX", "MAX_PADDED_BYTES", "MAX_SPARSITY", "MCAP_MAGIC", "METADATA_LAYOUT",
    "METADATA_PROVENANCE", "METADATA_SCENARIO", "McapFrameWriter", "OUTPUT_ZSTD_LEVEL",
    "PACKED_SCAN_DESCRIPTOR_SET", "PACK_BLOCK_BYTES", "RAGGED", "RewriteReport", "SCAN_DESCRIPTOR_SET",
    "SCAN_SCHEMA", "SCHEMA_CONTRACTS", "SYMMETRIC", "Scan", "VALUES_CHECK_BLOCK", "atomic_output",
    "check_values", "dataset_topics", "decode_frame", "decode_scan", "encode_frame", "encode_scan", "iter_frames",
    "publish", "read_dataset", "rewrite_dataset", "scans_per_message", "scenario_metadata", "upper_triangles",
    "write_dataset",
]
