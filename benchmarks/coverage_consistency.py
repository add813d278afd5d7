"""Coverage of the consistency bounds and rate intervals on simulated data sets.

Simulates independent data sets of a correctly modelled linear Kalman filter (2-D constant
velocity, position measurements, model matched, a transient from a wide start and then the
steady state) and counts how often the printed bounds call it consistent:

* the NEES time-average bounds (``nees_time_average_low/high``: from the spread of the per-run
  averages, Hall's skewness-corrected t over runs), and the former χ²(N·K·n)/(N·K) bound for
  comparison;
* the NIS time-average bounds (χ²(N·K·m)/(N·K));
* the Wilson intervals of the fraction of scans whose ANEES / ANIS lies inside its per-scan band
  (do they contain 0.95?);

then the rate intervals of the family tables (:func:`trackreplay.evaluators.confidence.summary_intervals`)
on Bernoulli data sets: a one-outcome-per-run rate and a rate pooled over ten correlated
outcomes per run. Every coverage is printed with its 95 % Wilson interval over the data sets.
``docs/evaluation.md`` quotes its output; ``tests/test_consistency_coverage.py`` checks the same
on fewer data sets. Run from the repository root::

    python benchmarks/coverage_consistency.py            # about three minutes
    python benchmarks/coverage_consistency.py --sets 400
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from trackreplay.evaluators.confidence import wilson_interval  # noqa: E402
from test_consistency_coverage import consistency_coverage, rate_coverage  # noqa: E402

# (runs, scans, q): q the white-acceleration density; the smaller, the longer the NEES stays
# correlated over scans (lag-1 correlation about 0.9 at q = 0.001, 0.85 at 0.01, 0.7 at 0.5)
KALMAN_CASES = [(200, 200, 0.001), (60, 100, 0.01), (30, 200, 0.001), (10, 100, 0.01), (100, 100, 0.5)]
RATE_CASES = [(60, 0.01), (60, 0.5), (200, 0.01), (200, 0.05), (200, 0.5), (1000, 0.01)]


def _coverage(hits: int, sets: int) -> str:
    low, high = wilson_interval(hits, sets)
    return f"{100 * hits / sets:5.1f} % [{100 * low:4.1f}, {100 * high:5.1f}]"


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sets", type=int, default=1000, help="data sets per Kalman case (default 1000)")
    parser.add_argument("--rate-sets", type=int, default=2000, help="data sets per rate case (default 2000)")
    args = parser.parse_args(argv)
    start = time.perf_counter()
    print(f"Kalman filter, model matched: coverage over {args.sets} data sets [95 % Wilson interval]")
    print(f"{'runs':>5} {'scans':>5} {'q':>6}  {'NEES over runs':>22} {'NEES χ²(NKn) (former)':>22} "
          f"{'NIS χ²(NKm)':>22} {'ANEES inside ∋ 0.95':>22} {'ANIS inside ∋ 0.95':>22}")
    for i, (runs, scans, q) in enumerate(KALMAN_CASES):
        batch = max(1, 2_000_000 // (runs * scans))
        h = consistency_coverage(seed=100 + i, sets=args.sets, runs=runs, scans=scans, batch=batch, q=q)
        print(f"{runs:>5} {scans:>5} {q:>6g}  {_coverage(h['nees'], args.sets):>22} "
              f"{_coverage(int(h['nees_chi2_all_values']), args.sets):>22} {_coverage(h['nis'], args.sets):>22} "
              f"{_coverage(h['anees_inside'], args.sets):>22} {_coverage(h['anis_inside'], args.sets):>22}",
              flush=True)
    print()
    print(f"rates: coverage of p over {args.rate_sets} Bernoulli data sets [95 % Wilson interval]; pooled = ten "
          "outcomes per run, intra-run correlation 0.3")
    print(f"{'runs':>5} {'p':>5}  {'one per run (Wilson)':>22} {'pooled (Korn–Graubard)':>22} {'outside [0,1]':>14}")
    for runs, p in RATE_CASES:
        r = rate_coverage(seed=7 * runs + int(1000 * p), sets=args.rate_sets, runs=runs, p=p)
        print(f"{runs:>5} {p:>5g}  {_coverage(r['run'], args.rate_sets):>22} {_coverage(r['pooled'], args.rate_sets):>22} "
              f"{r['outside_or_missing_value']:>14d}", flush=True)
    print(f"\n({time.perf_counter() - start:.0f} s)")


if __name__ == "__main__":
    main()
