"""Share of a replay's wall time spent evaluating (family metrics with their jackknife intervals
and the standard measures), on the 500-run radar data set and the 1200-scan colored-noise data
set (issue target: evaluation under 20 % of the replay).

    python benchmarks/bench_evaluation.py [--repeats 5]

Prints, per data set, the medians with min–max over the repeats of the filter, evaluate and total
times of ``replay(path)`` (no outputs written, no Rerun), and the evaluation's share.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pipeline.replay import replay  # noqa: E402
from recorders.scenarios import load_scenario  # noqa: E402
from recorders.simulated import record  # noqa: E402


def spread(values) -> str:
    return f"{statistics.median(values):7.3f} s ({min(values):.3f}–{max(values):.3f})"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    cases = [("radar-tws", 500, 1), ("colored-imm", 20, 2)]
    with tempfile.TemporaryDirectory() as tmp:
        print(f"evaluation share of replay wall time; median (min–max) over {args.repeats} repeats")
        print(f"{'data set':28s} {'filter':>24s} {'evaluate':>24s} {'total':>24s}  share")
        for scenario, runs, seed in cases:
            path = Path(tmp) / f"{scenario}.mcap"
            record(path, load_scenario(scenario), runs=runs, seed=seed)
            replay(path)  # warm: imports and first-call costs are not the evaluation's
            rows = [replay(path).timings for _ in range(args.repeats)]
            f, e, t = ([r[k] for r in rows] for k in ("filter_s", "evaluate_s", "total_s"))
            share = [ei / ti for ei, ti in zip(e, t)]
            label = f"{scenario}, {runs} runs"
            print(f"{label:28s} {spread(f):>24s} {spread(e):>24s} {spread(t):>24s}  "
                  f"{100 * statistics.median(share):.1f} % ({100 * min(share):.1f}–{100 * max(share):.1f})")


if __name__ == "__main__":
    main()
