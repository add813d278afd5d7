"""Read-path benchmark: contract v1 (before) against v2 (after), with zstd as the floor.

What it measures
----------------
Three data sets are simulated with ``replay simulate`` into a temporary folder (not timed):
radar-tws with 1,000 and 10,000 runs (64 scans, ragged plots + truth) and colored-imm with
200 runs (1,200 scans). Each is also rewritten in contract ``replay.v1`` (one message per run
and scan, as version 1 wrote it) with :func:`trackreplay.contract.rewrite_dataset`; both files
hold the same frames and decode to identical arrays (checked here before timing).

For every file, ``--repeats`` times (default 5):

* **v1, 0.1 reader**: version 1's read loop, kept here as the "before": the mcap package's
  ``iter_messages(log_time_order=False)`` and one protobuf decode per message into per-frame
  lists (what ``read_dataset`` did up to contract v1);
* **read**: ``trackreplay.contract.read_dataset`` (v1 files frame by frame, v2 files in bulk;
  every chunk CRC checked);
* **+ arrays**: then every array of every channel as a stage takes it, ``grid`` (or ``ragged``
  for variable-length arrays): the decode a replay waits for;
* **zstd floor**: ``zstandard`` decompression of the same file's chunks, already in memory —
  no reader can be faster than this.

The table gives medians with min–max over the repeats, and the speed-up of v2 over v1. Times
come from ``time.perf_counter``.

How to run
----------
From the repository root, with the package installed (``pip install -e .``)::

    python benchmarks/bench_read.py               # the three data sets, 5 repeats
    python benchmarks/bench_read.py --repeats 7 --keep /tmp/read-bench
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import zstandard

from trackreplay.contract import CONTRACT_V1, decode_frame, read_dataset, rewrite_dataset
from trackreplay.errors import InputError
from timing import print_table, time_spread  # benchmarks/ is on sys.path when run as a script

SETS = [  # (label, scenario, runs)
    ("radar-tws 1,000 runs", "radar-tws", 1000),
    ("radar-tws 10,000 runs", "radar-tws", 10000),
    ("colored-imm 200 runs", "colored-imm", 200),
]


def simulate(scenario: str, runs: int, out: Path) -> None:
    exe = shutil.which("replay")
    cmd = [exe] if exe else [sys.executable, "-m", "trackreplay.face.cli"]
    subprocess.run([*cmd, "simulate", scenario, "--runs", str(runs), "--seed", "1", "-o", str(out)],
                   check=True, capture_output=True)


def read_v1_as_before(path: Path) -> dict:
    """Version 1's reader loop (pure-Python mcap iterator, one protobuf decode per message)."""
    from mcap.reader import make_reader

    buckets: dict = {}
    with open(path, "rb") as f:
        reader = make_reader(f)
        for _, channel, message in reader.iter_messages(log_time_order=False):
            run, scan, t, arrays, n = decode_frame(message.data)
            b = buckets.setdefault(channel.topic, ([], [], [], {}))
            b[0].append(run)
            b[1].append(scan)
            b[2].append(t)
            for name, a in arrays.items():
                b[3].setdefault(name, []).append(a)
    return {topic: (np.asarray(r), np.asarray(k), np.asarray(t), arrs) for topic, (r, k, t, arrs) in buckets.items()}


def decode_arrays(ds) -> int:
    """Every array of every channel as a stage takes it; returns the bytes decoded."""
    total = 0
    for ch in ds.channels.values():
        for name in ch.arrays:
            try:
                total += ch.grid(name).nbytes
            except InputError:  # variable-length lists
                total += ch.ragged(name)[0].nbytes
    return total


def compressed_chunks(path: Path) -> list[tuple[bytes, int]]:
    from mcap.reader import make_reader
    from mcap.records import Chunk
    from mcap.data_stream import ReadDataStream

    out = []
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
        for index in sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset):
            f.seek(index.chunk_start_offset + 9)
            chunk = Chunk.read(ReadDataStream(f))
            out.append((chunk.data, chunk.uncompressed_size))
    return out


def repeat(fn, n: int) -> list[float]:
    times = []
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return times


def fmt(times: list[float] | None) -> str:
    return time_spread(times) if times else "-"


def measure(path: Path, repeats: int, before: bool) -> dict:
    res = {"mb": path.stat().st_size / 1e6}
    if before:
        res["before"] = repeat(lambda: read_v1_as_before(path), repeats)
    reads, arrays = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        ds = read_dataset(path)
        t1 = time.perf_counter()
        res["decoded_mb"] = decode_arrays(ds) / 1e6
        t2 = time.perf_counter()
        reads.append(t1 - t0)
        arrays.append(t2 - t0)
        res["frames"] = sum(c.run.size for c in ds.channels.values())
        del ds
    res["read"], res["arrays"] = reads, arrays
    chunks = compressed_chunks(path)
    dctx = zstandard.ZstdDecompressor()
    res["chunks"] = len(chunks)
    res["zstd"] = repeat(lambda: [dctx.decompress(d, max_output_size=n) for d, n in chunks], repeats)
    return res


def check_same(v1: Path, v2: Path) -> None:
    a, b = read_dataset(v1), read_dataset(v2)
    for topic, x in a.channels.items():
        y = b.channel(topic)
        assert np.array_equal(x.run, y.run) and np.array_equal(x.scan, y.scan), topic
        for name in x.arrays:
            for u, v in zip(x.array(name), y.array(name)):
                assert u.dtype == v.dtype and u.shape == v.shape and u.tobytes() == v.tobytes(), (topic, name)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=5, help="timed repetitions per file (≥ 5 recommended)")
    ap.add_argument("--keep", type=Path, help="generate the data sets here and keep them (default: a temporary folder)")
    ap.add_argument("--sets", default="all", help="comma-separated indices into the data sets (0,1,2) or 'all'")
    args = ap.parse_args()
    chosen = SETS if args.sets == "all" else [SETS[int(i)] for i in args.sets.split(",")]

    work = args.keep or Path(tempfile.mkdtemp(prefix="bench-read-"))
    work.mkdir(parents=True, exist_ok=True)
    print(f"python {platform.python_version()}, numpy {np.__version__}, zstandard {zstandard.__version__}, "
          f"{os.cpu_count()} cpu(s); {args.repeats} repeats; files in {work}")
    rows = []
    try:
        for label, scenario, runs in chosen:
            v2 = work / f"{scenario}-{runs}.v2.mcap"
            v1 = work / f"{scenario}-{runs}.v1.mcap"
            if not v2.exists():
                t0 = time.perf_counter()
                simulate(scenario, runs, v2)
                print(f"simulated {label}: {v2.stat().st_size / 1e6:.1f} MB in {time.perf_counter() - t0:.1f} s")
            if not v1.exists():
                t0 = time.perf_counter()
                rewrite_dataset(v2, v1, contract=CONTRACT_V1)
                print(f"rewrote it in {CONTRACT_V1}: {v1.stat().st_size / 1e6:.1f} MB in {time.perf_counter() - t0:.1f} s")
            check_same(v1, v2)
            r1 = measure(v1, args.repeats, before=True)
            r2 = measure(v2, args.repeats, before=False)
            rows.append((label, r1, r2))
            print(f"measured {label}")
    finally:
        if args.keep is None:
            shutil.rmtree(work, ignore_errors=True)

    head = ("data set", "file", "MB", "chunks", "v1, 0.1 reader", "read", "read + arrays", "zstd floor")
    table = []
    for label, r1, r2 in rows:
        table.append((label, "v1", f"{r1['mb']:.1f}", str(r1["chunks"]), fmt(r1["before"]), fmt(r1["read"]),
                      fmt(r1["arrays"]), fmt(r1["zstd"])))
        table.append(("", "v2", f"{r2['mb']:.1f}", str(r2["chunks"]), "-", fmt(r2["read"]), fmt(r2["arrays"]),
                      fmt(r2["zstd"])))
    print()
    print_table(head, table)
    print()
    print("speed-up of v2 (medians):")
    for label, r1, r2 in rows:
        med = statistics.median
        print(f"  {label}: {r1['frames']:,} frames, {r2['decoded_mb']:.1f} MB decoded; "
              f"read {med(r1['before']) / med(r2['read']):.0f}× over the 0.1 reader on v1, "
              f"{med(r1['read']) / med(r2['read']):.0f}× over this reader on v1; "
              f"read + arrays {med(r1['arrays']) / med(r2['arrays']):.0f}×; "
              f"v2 read is {med(r2['read']) / med(r2['zstd']):.1f}× its zstd floor")
    return 0


if __name__ == "__main__":
    sys.exit(main())
