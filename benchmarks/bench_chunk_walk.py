"""Chunk walk: the contract's own record walk against ``mcap``'s ``breakup_chunk``.

What it measures
----------------
``trackreplay.contract._records`` splits a chunk's records itself instead of calling ``mcap``;
this measures why. A radar-tws data set (``--runs`` runs, 64 scans) is simulated with ``replay
simulate`` and rewritten in contract ``replay.v1`` (one message per run and scan, the case with
the most records a chunk) into a temporary folder (not timed); its chunks are read into memory
(not timed). Then, ``--repeats`` times (default 7), every chunk is decompressed, CRC-checked and
split into records:

* **contract walk**: ``_records.decompress_chunk`` and ``_records.chunk_records`` (what
  ``read_dataset`` does per chunk: a view of each message's data, no object per message);
* **mcap breakup_chunk**: ``mcap.stream_reader.breakup_chunk(chunk, validate_crc=True)`` (what
  ``mcap``'s readers do per chunk: a ``Message`` object with a copy of its data per record).

Neither decodes a message. Medians with min–max over the repeats; ``time.perf_counter``.

How to run
----------
From the repository root, with the package installed (``pip install -e .``)::

    python benchmarks/bench_chunk_walk.py               # 2,000 runs, 7 repeats
    python benchmarks/bench_chunk_walk.py --runs 500 --repeats 5
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import zstandard
from mcap.records import Chunk
from mcap.stream_reader import StreamReader, breakup_chunk

from trackreplay.contract import CONTRACT_V1, rewrite_dataset
from trackreplay.contract import _records
from timing import print_table, time_repeats, time_spread  # benchmarks/ is on sys.path when run as a script


def simulate(runs: int, out: Path) -> None:
    exe = shutil.which("replay")
    cmd = [exe] if exe else [sys.executable, "-m", "trackreplay.face.cli"]
    subprocess.run([*cmd, "simulate", "radar-tws", "--runs", str(runs), "--seed", "1", "-o", str(out)],
                   check=True, capture_output=True)


def contract_walk(chunks: list) -> int:
    zstd = zstandard.ZstdDecompressor()
    return sum(1 for chunk in chunks for _ in _records.chunk_records(_records.decompress_chunk(chunk, zstd)))


def mcap_walk(chunks: list) -> int:
    return sum(len(breakup_chunk(chunk, validate_crc=True)) for chunk in chunks)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=2000)
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        v2, v1 = Path(tmp) / "v2.mcap", Path(tmp) / "v1.mcap"
        simulate(args.runs, v2)
        rewrite_dataset(v2, v1, contract=CONTRACT_V1)
        with open(v1, "rb") as f:
            chunks = [r for r in StreamReader(f, emit_chunks=True).records if isinstance(r, Chunk)]
        size_mb = v1.stat().st_size / 1e6
    rows, medians = [], {}
    for label, walk in (("contract walk", contract_walk), ("mcap breakup_chunk", mcap_walk)):
        median, times, records = time_repeats(lambda: walk(chunks), args.repeats)
        medians[label] = median
        rows.append((label, f"{records:,}", time_spread(times)))
    print(f"radar-tws {args.runs:,} runs in contract replay.v1: {size_mb:.1f} MB, {len(chunks)} chunks")
    print_table(("walk", "records", "time"), rows)
    print(f"contract walk {medians['mcap breakup_chunk'] / medians['contract walk']:.1f}x faster")


if __name__ == "__main__":
    main()
