"""How small can a replay's outputs get without losing anything? Lossless encodings measured.

What it measures
----------------
A radar-tws data set is simulated (``--runs``, default 10,000, seed 7) and replayed in memory
with every built-in tracker. For the first ``--sample-runs`` runs (default 1,000) of each output
array, laid out as the outputs file lays it out (scan by scan, every run), it compresses:

* **zstd 1**: the level ``tracks.mcap`` uses (``trackreplay.contract.OUTPUT_ZSTD_LEVEL``);
* **packed + zstd 1**: what ``tracks.mcap`` holds since the ``SYMMETRIC`` layout
  (``docs/contract.md``): covariances as their upper triangles, everything else as in zstd 1;
* **zstd 9**: a slower level;
* **shuffle + zstd 9**: the bytes of every float regrouped by position (all first bytes, then
  all second bytes, …, as HDF5's and Blosc's shuffle filters do), which lets zstd see the
  slowly varying sign, exponent and high mantissa bytes together;
* **packed + zstd 9**: symmetric matrices (covariances) stored as their upper triangle only;
* **best**: the smallest of these for each array.

Sizes are scaled to all runs (they grow in proportion) and summed over the trackers; the
table ends with the total against a tenth of the outputs file that the speed issue measured at
10,000 runs (383 MB) and a tenth of today's file. Every encoding is checked to decode to the
same bits.

How to run
----------
From the repository root, with the package installed (``pip install -e .``)::

    python benchmarks/bench_output_size.py                  # 10,000 runs, 1,000 sampled
    python benchmarks/bench_output_size.py --runs 2000 --sample-runs 500
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
import zstandard

from trackreplay.contract import OUTPUT_ZSTD_LEVEL, upper_triangles
from trackreplay.replay import replay
from timing import print_table  # benchmarks/ is on sys.path when run as a script

ISSUE_FILE_MB = 383.0  # tracks.mcap at 10,000 radar runs when the speed issue was filed


def shuffled(raw: bytes, itemsize: int) -> bytes:
    """Bytes regrouped by their position within each item."""
    return np.frombuffer(raw, np.uint8).reshape(-1, itemsize).T.tobytes()


def unshuffled(data: bytes, itemsize: int) -> bytes:
    return np.frombuffer(data, np.uint8).reshape(itemsize, -1).T.tobytes()


def sizes(a: np.ndarray, symmetric: bool) -> dict:
    """Compressed bytes of ``a`` (scan-major, as the outputs file holds it) per encoding."""
    a = np.ascontiguousarray(np.swapaxes(a, 0, 1))  # scans first, every run of a scan together
    raw = a.tobytes()
    fast, slow = zstandard.ZstdCompressor(level=OUTPUT_ZSTD_LEVEL), zstandard.ZstdCompressor(level=9)
    out = {"raw": len(raw), "zstd1": len(fast.compress(raw)), "zstd9": len(slow.compress(raw))}
    item = a.dtype.itemsize
    shuffled_bytes = slow.compress(shuffled(raw, item))
    assert unshuffled(zstandard.ZstdDecompressor().decompress(shuffled_bytes), item) == raw
    out["shuffle9"] = len(shuffled_bytes)
    packed = upper_triangles(a) if symmetric else None  # the writer's own packing, None unless bit-symmetric
    if packed is not None:
        triangles = np.ascontiguousarray(packed).tobytes()
        out["packed1"] = len(fast.compress(triangles))
        out["packed9"] = len(slow.compress(triangles))
    else:
        out["packed1"], out["packed9"] = out["zstd1"], out["zstd9"]
    out["best"] = min(out["zstd1"], out["packed1"], out["zstd9"], out["shuffle9"], out["packed9"])
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=10000)
    ap.add_argument("--sample-runs", type=int, default=1000)
    args = ap.parse_args()
    import subprocess
    import sys

    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp) / "radar.mcap"
        subprocess.run([sys.executable, "-m", "trackreplay.face.cli", "simulate", "radar-tws", "--runs", str(args.runs),
                        "--seed", "7", "-o", str(data)], check=True, capture_output=True)
        result = replay(data, out_path=Path(tmp) / "tracks.mcap")
        file_mb = (Path(tmp) / "tracks.mcap").stat().st_size / 1e6
    scale = args.runs / min(args.sample_runs, args.runs)
    totals = {k: 0.0 for k in ("raw", "zstd1", "packed1", "zstd9", "shuffle9", "packed9", "best")}
    per_name: dict[str, dict] = {}
    for tracker, outputs in result.results["radar"]["tracks"].items():
        for name, a in outputs.items():
            s = sizes(np.asarray(a)[:args.sample_runs], symmetric=name.endswith("covariance"))
            row = per_name.setdefault(name, {k: 0.0 for k in totals})
            for k, v in s.items():
                row[k] += v * scale / 1e6
                totals[k] += v * scale / 1e6
    mb = lambda v: f"{v:.1f}"
    rows = [[name, *(mb(r[k]) for k in totals)] for name, r in sorted(per_name.items(), key=lambda kv: -kv[1]["best"])]
    rows.append(["all four trackers", *(mb(totals[k]) for k in totals)])
    print(f"radar-tws, {args.runs} runs, four trackers: output bytes per encoding, MB (sampled on "
          f"{min(args.sample_runs, args.runs)} runs, scaled)")
    print_table(["array", "in memory", "zstd 1", "packed + zstd 1", "zstd 9", "shuffle + zstd 9", "packed + zstd 9",
                 "best"], rows)
    best = totals["best"]
    print(f"\ntracks.mcap as written: {file_mb:.1f} MB. Smallest lossless encoding here: {best:.1f} MB, "
          f"{file_mb / best:.2f}× smaller than the file;")
    print(f"a tenth of the issue's {ISSUE_FILE_MB:.0f} MB is {ISSUE_FILE_MB / 10:.1f} MB, a tenth of today's file "
          f"{file_mb / 10:.1f} MB: {'PASS' if best <= ISSUE_FILE_MB / 10 else 'MISS'}")


if __name__ == "__main__":
    main()
