"""The MCAP records of a file walked by hand: chunks located, decompressed and CRC-checked, and the
records inside a chunk split; private to :mod:`trackreplay.contract.reading`.

Why not ``mcap``'s own reader here: ``mcap.stream_reader.breakup_chunk`` (what
``McapReader.iter_messages`` and ``StreamReader`` use inside a chunk) makes a ``Message`` object
holding a copy of its bytes for every record, where the reader needs only a view of each message's
data (a file of replay.v1 frames holds a message per run and scan: 256,000 for 2,000 radar runs);
and it decompresses lz4 without a bound on the output and zstd to whatever size the chunk
declares, where the reader holds both to
:data:`~trackreplay.contract.layout.MAX_CHUNK_BYTES` so that a small chunk cannot claim the
memory. So this module reads the 9-byte record heads and the 22-byte message heads itself and
hands out each message's data as a view of the decompressed chunk; Schema, Channel and Chunk
records are still parsed by ``mcap`` (``Schema.read``, ``Channel.read``, ``Chunk.read``), and
files without a chunk index, or damaged ones, are read record by record with ``mcap``'s
``StreamReader`` (``reading._Source._linear``), each chunk then walked here.
On that v1 file (6.9 MB, 64 chunks, 256,003 records) decompressing, checking and splitting
every chunk took 730 [617–814] ms here against 4.16 [3.74–4.71] s with ``breakup_chunk``, 5.7×
(``python benchmarks/bench_chunk_walk.py``, 7 repeats, on a 2-core machine shared with other work).

The footer's summary CRC and the DataEnd record's data-section CRC are checked here too, before
``mcap``'s summary is trusted (:func:`section_crcs`).
"""

from __future__ import annotations

import io
import os
import struct
import zlib
from typing import Iterator

import zstandard
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, Schema

from trackreplay.contract.layout import MAX_CHUNK_BYTES, MCAP_MAGIC, _BadData

RECORD_HEAD = struct.Struct("<BQ")  # opcode, record length
MESSAGE_HEAD = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time


def read_chunk(f, offset: int, length: int, size: int) -> Chunk:
    """The Chunk record of ``length`` bytes at ``offset`` of the file ``f`` (``size`` bytes), where
    the summary's chunk index places it."""
    if offset + length > size or length < 9:
        raise _BadData(f"lies outside the file ({size} bytes)")
    f.seek(offset)
    raw = f.read(length)
    if raw[0] != Opcode.CHUNK:
        raise _BadData(f"is not a chunk record (opcode {raw[0]:#04x})")
    return Chunk.read(ReadStream(raw[9:]))


def decompress_chunk(chunk: Chunk, zstd: zstandard.ZstdDecompressor) -> bytes:
    """A chunk's records decompressed, after checking its declared size, and its CRC after."""
    if chunk.compression not in ("", "zstd", "lz4"):
        raise _BadData(f"unknown compression {chunk.compression!r}")
    if chunk.uncompressed_size > MAX_CHUNK_BYTES:
        raise _BadData(f"declares {chunk.uncompressed_size} bytes uncompressed (this reader accepts up to "
                       f"{MAX_CHUNK_BYTES})")
    if chunk.compression == "zstd":
        raw = zstd.decompress(chunk.data, max_output_size=chunk.uncompressed_size)
    elif chunk.compression == "lz4":
        raw = lz4_decompress(chunk.data, chunk.uncompressed_size)
    else:
        raw = chunk.data
    if len(raw) != chunk.uncompressed_size:
        raise _BadData(f"holds {len(raw)} bytes uncompressed, its record says {chunk.uncompressed_size}")
    if chunk.uncompressed_crc != 0:
        crc = zlib.crc32(raw)
        if crc != chunk.uncompressed_crc:
            raise _BadData(f"CRC mismatch (stored {chunk.uncompressed_crc:#010x}, computed {crc:#010x})")
    return raw


def chunk_records(raw: bytes) -> Iterator:
    """Walk the records of a decompressed chunk: Schema and Channel records (parsed by mcap),
    ``(channel_id, data)`` for each Message (its 22-byte header read here, the data not copied)."""
    view = memoryview(raw)
    pos, end_all = 0, len(raw)
    while pos < end_all:
        if pos + 9 > end_all:
            raise _BadData("its records end in the middle of a record header")
        opcode, length = RECORD_HEAD.unpack_from(raw, pos)
        pos += 9
        end = pos + length
        if end > end_all:
            raise _BadData(f"a record (opcode {opcode:#04x}) runs past the chunk's end")
        if opcode == Opcode.MESSAGE:
            if length < 22:
                raise _BadData(f"a message record of {length} bytes is shorter than its header")
            yield MESSAGE_HEAD.unpack_from(raw, pos)[0], view[pos + 22:end]
        elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL):
            stream = ReadStream(raw[pos:end])
            yield Schema.read(stream) if opcode == Opcode.SCHEMA else Channel.read(stream)
        pos = end


def lz4_decompress(data: bytes, size: int) -> bytes:
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


def section_crcs(f) -> tuple[bool, str | None]:
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
        crc = zlib.crc32(footer[:25], crc_range(f, summary_start, size - tail, 0))
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
    crc = crc_range(f, 0, data_end, 0)
    if crc != data_crc:
        return True, (f"data section CRC mismatch (stored {data_crc:#010x}, computed {crc:#010x}) outside the "
                      "chunks: a metadata, schema or channel record is damaged")
    return True, None


def crc_range(f, start: int, end: int, crc: int) -> int:
    f.seek(start)
    left = end - start
    while left > 0:
        block = f.read(min(left, 16 << 20))
        if not block:
            break
        crc = zlib.crc32(block, crc)
        left -= len(block)
    return crc


class ReadStream:
    """mcap's ReadDataStream interface over bytes already in memory."""

    def __init__(self, data: bytes):
        from mcap.data_stream import ReadDataStream

        self._s = ReadDataStream(io.BytesIO(data))

    def __getattr__(self, name):
        return getattr(self._s, name)
