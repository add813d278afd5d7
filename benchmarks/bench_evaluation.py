"""Share of a replay's wall time spent evaluating (family metrics with their Monte Carlo
intervals and the standard measures), on the 500-run radar data set and the 1200-scan
colored-noise data set (issue target: evaluation under 20 % of the replay).

    python benchmarks/bench_evaluation.py [--repeats 5]

Two denominators, both printed:

* **replay** — the wall time of ``replay FILE --out … --force`` as a user runs it, in a fresh
  process (start-up, reading, filtering, evaluating, writing the outputs, the Rerun recording,
  the tables and the figures); the evaluation time is the ``evaluate`` phase that ``--verbose``
  prints in that same process, so it includes its first-call costs;
* **compute** — ``trackreplay.replay.replay(path)`` in a warm process with nothing written: read,
  filter and evaluate alone, the harshest view of the evaluation's cost.

Medians with min–max over the repeats.
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from trackreplay.replay import replay  # noqa: E402
from trackreplay.recorders.scenarios import load_scenario  # noqa: E402
from trackreplay.recorders.simulated import record  # noqa: E402
from timing import spread  # noqa: E402  (benchmarks/ is on sys.path when run as a script)

CLI = [sys.executable, "-c", "from trackreplay.face.cli import main; main()"]


def cli_replay(path: Path, out: Path) -> tuple[float, float]:
    """Wall time of one ``replay`` command and the evaluate phase it reports."""
    t0 = time.perf_counter()
    done = subprocess.run([*CLI, "run", str(path), "--out", str(out / "tracks.mcap"), "--force", "--quiet",
                           "--verbose"], cwd=ROOT, capture_output=True, text=True, check=True)
    wall = time.perf_counter() - t0
    evaluate = float(re.search(r"timing: evaluate ([0-9.]+) s", done.stderr).group(1))
    return wall, evaluate


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    cases = [("radar-tws", 500, 1), ("colored-imm", 20, 2)]
    with tempfile.TemporaryDirectory() as tmp:
        print(f"evaluation share of a replay; median (min–max) over {args.repeats} repeats")
        print(f"{'data set':22s} {'denominator':12s} {'evaluate':>22s} {'of wall':>22s} {'share':>22s}")
        for scenario, runs, seed in cases:
            path = Path(tmp) / f"{scenario}.mcap"
            record(path, load_scenario(scenario), runs=runs, seed=seed)
            label = f"{scenario}, {runs} runs"
            cli = [cli_replay(path, Path(tmp) / f"out-{scenario}") for _ in range(args.repeats)]
            walls, evals = [c[0] for c in cli], [c[1] for c in cli]
            shares = [e / w for w, e in zip(walls, evals)]
            print(f"{label:22s} {'replay':12s} {spread(evals, unit='s'):>22s} {spread(walls, unit='s'):>22s} "
                  f"{spread(shares, 100, 1, '%'):>22s}")
            replay(path)  # warm: imports and first-call costs
            rows = [replay(path).timings for _ in range(args.repeats)]
            evals, totals = [r["evaluate_s"] for r in rows], [r["total_s"] for r in rows]
            shares = [e / t for e, t in zip(evals, totals)]
            print(f"{'':22s} {'compute':12s} {spread(evals, unit='s'):>22s} {spread(totals, unit='s'):>22s} "
                  f"{spread(shares, 100, 1, '%'):>22s}")


if __name__ == "__main__":
    main()
