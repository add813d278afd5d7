"""Write-path benchmark: a replay's outputs file at each zstd level, against what the disk alone costs.

What it measures
----------------
A radar-tws data set (``--runs``, default 10,000, seed 7) is simulated into a work folder and
replayed once in memory with the four built-in trackers (not timed). Their outputs are then
written ``--repeats`` times (default 5) to ``tracks.mcap`` in the work folder, the levels
interleaved so that every one sees the same load, each as a replay writes them
(:func:`trackreplay.contract.write_dataset` with the outputs' packing, one channel per tracker,
:func:`trackreplay.stage_running.write_outputs`), at:

* **zstd 1**: what ``replay`` wrote up to 2026-12-08;
* **zstd −1, −3**: zstd's fast levels, which trade size for speed; −3 is
  :data:`trackreplay.contract.OUTPUT_ZSTD_LEVEL`, what ``replay`` writes now;
* **zstd 3**: zstd's default level, the data sets' level.

Beside them, two floors: **disk alone**, the same number of bytes as ``replay``'s file written
with one ``write`` per MB (no encoding, no compression) and synced; **zstd alone**, the same
arrays' bytes compressed in memory at ``replay``'s level, scan by scan as the file holds them.

Each write is timed from the open to the end of the final ``fsync`` (wall, ``time.perf_counter``)
and by the CPU time of the writing thread (``time.thread_time``; what the writer takes from
the evaluation it runs beside). The table gives median [min–max] and the file's size.

How to run
----------
From the repository root, with the package installed (``pip install -e .``)::

    python benchmarks/bench_write.py                      # 10,000 runs, 5 repeats
    python benchmarks/bench_write.py --runs 2000 --repeats 3 --keep /tmp/write-bench
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import zstandard

from timing import print_table, spread  # benchmarks/ is on sys.path when run as a script
from trackreplay import stage_running
from trackreplay.contract import OUTPUT_ZSTD_LEVEL, write_dataset
from trackreplay.replay import replay
from trackreplay.stages import stage_named

MB = 1e6
LEVELS = (1, -1, -3, 3)
assert OUTPUT_ZSTD_LEVEL in LEVELS, "replay's own level is one of those compared"


def write_file(path: Path, stage, result: dict, level: int) -> tuple[float, float, int]:
    """(wall s, writing thread's CPU s, bytes) of the outputs file of ``result`` at ``level``."""
    t0, c0 = time.perf_counter(), time.thread_time()
    with write_dataset(path, {}, zstd_level=level, pack_symmetric=True) as w:
        stage_running.write_outputs(stage, w, result)
    return time.perf_counter() - t0, time.thread_time() - c0, path.stat().st_size


def disk_alone(path: Path, nbytes: int) -> tuple[float, float]:
    """(wall s, CPU s) of writing ``nbytes`` to ``path`` a MB at a time and syncing it."""
    block = os.urandom(1 << 20)
    t0, c0 = time.perf_counter(), time.thread_time()
    with open(path, "wb") as f:
        for _ in range(nbytes >> 20):
            f.write(block)
        f.flush()
        os.fsync(f.fileno())
    return time.perf_counter() - t0, time.thread_time() - c0


def zstd_alone(result: dict) -> tuple[float, float]:
    """(wall s, CPU s) of compressing every output array at ``replay``'s level, a scan of all runs
    a frame."""
    compressor = zstandard.ZstdCompressor(level=OUTPUT_ZSTD_LEVEL)
    scans = [np.ascontiguousarray(a[:, k]).tobytes() for out in result["tracks"].values() for a in out.values()
             if isinstance(a, np.ndarray) and a.ndim >= 2 for k in range(a.shape[1])]
    t0, c0 = time.perf_counter(), time.thread_time()
    for raw in scans:
        compressor.compress(raw)
    return time.perf_counter() - t0, time.thread_time() - c0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=10_000)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--keep", help="work folder to keep (default: a temporary one)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(args.keep or tmp)
        work.mkdir(parents=True, exist_ok=True)
        data = work / f"radar-tws-{args.runs}.mcap"
        if not data.exists():
            subprocess.run([sys.executable, "-m", "trackreplay.face.cli", "-q", "simulate", "radar-tws", "--runs",
                            str(args.runs), "--seed", "7", "-o", str(data)], check=True, stdout=subprocess.DEVNULL)
        res = replay(data)
        stage = stage_named("radar")
        result = res.results[stage.name]
        raw = sum(a.nbytes for out in result["tracks"].values() for a in out.values() if isinstance(a, np.ndarray))
        walls = {level: [] for level in LEVELS}
        cpus = {level: [] for level in LEVELS}
        sizes = {}
        floors = {"disk alone": ([], []), f"zstd {OUTPUT_ZSTD_LEVEL} alone": ([], [])}
        for _ in range(args.repeats):
            for level in LEVELS:
                wall, cpu, size = write_file(work / "tracks.mcap", stage, result, level)
                walls[level].append(wall)
                cpus[level].append(cpu)
                sizes[level] = size
            for name, (wall_list, cpu_list) in floors.items():
                wall, cpu = (disk_alone(work / "disk.bin", sizes[OUTPUT_ZSTD_LEVEL]) if name == "disk alone"
                             else zstd_alone(result))
                wall_list.append(wall)
                cpu_list.append(cpu)
        (work / "disk.bin").unlink(missing_ok=True)
        print(f"outputs of {len(result['tracks'])} trackers × {args.runs} runs: {raw / MB:.0f} MB in memory; "
              f"median [min–max] of {args.repeats}, the levels interleaved")
        rows = [[f"zstd {level}" + (" (replay's)" if level == OUTPUT_ZSTD_LEVEL else ""),
                 spread(walls[level], 1.0, 2, "s"), spread(cpus[level], 1.0, 2, "s"), f"{sizes[level] / MB:.0f} MB"]
                for level in LEVELS]
        rows += [[name, spread(w, 1.0, 2, "s"), spread(c, 1.0, 2, "s"),
                  f"{sizes[OUTPUT_ZSTD_LEVEL] / MB:.0f} MB" if name == "disk alone" else ""]
                 for name, (w, c) in floors.items()]
        print_table(["write", "wall (to the end of fsync)", "writing thread's CPU", "file"], rows)


if __name__ == "__main__":
    main()
