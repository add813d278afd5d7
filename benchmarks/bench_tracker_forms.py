"""What the per-run tracker form costs over the batch form.

A trivial tracker (it returns the first converted plot of each scan as its state) is written in
both forms of the tracker interface (``docs/trackers.md``) and called through
``trackreplay.trackers.interface.call_tracker`` — the path every tracker takes in a replay, with
the output validation — on a radar data set of 500 runs × 64 scans held in memory. The
difference is what the pipeline's loop over runs and the stacking of per-run outputs cost.

Run from the repository root::

    python benchmarks/bench_tracker_forms.py              # 500 runs × 64 scans, 7 repeats
    python benchmarks/bench_tracker_forms.py --runs 2000 --repeats 5

Prints the median and the min–max over the repeats of each form, and the overhead per run.
"""

from __future__ import annotations

import argparse

import numpy as np

from trackreplay import vocabulary as vocab
from trackreplay.trackers.interface import RadarPlots, Tracker, call_tracker
from timing import time_repeats


class FirstPlotBatch(Tracker):
    name = "first_plot_batch"
    family = "radar"

    def track(self, plots):
        r, b = plots.range_m[..., 0], plots.bearing_rad[..., 0]
        state = np.stack([r * np.cos(b), r * np.sin(b), np.zeros_like(r), np.zeros_like(r)], axis=-1)
        flags = np.where(plots.counts > 0, 0, vocab.NO_TRACK).astype(np.uint16)
        return {"state": state, "flags": flags}


class FirstPlotRun(Tracker):
    name = "first_plot_run"
    family = "radar"
    form = "run"

    def track_run(self, plots):
        r, b = plots.range_m[:, 0], plots.bearing_rad[:, 0]
        state = np.stack([r * np.cos(b), r * np.sin(b), np.zeros_like(r), np.zeros_like(r)], axis=-1)
        flags = np.where(plots.counts > 0, 0, vocab.NO_TRACK).astype(np.uint16)
        return {"state": state, "flags": flags}


def measurements(runs: int, scans: int, seed: int = 0) -> RadarPlots:
    rng = np.random.default_rng(seed)
    return RadarPlots(range_m=rng.uniform(5e3, 2e4, (runs, scans, 1)),
                      bearing_rad=rng.uniform(-np.pi, np.pi, (runs, scans, 1)),
                      counts=np.ones((runs, scans), np.int64), times_s=5.0 * np.arange(scans))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=500)
    ap.add_argument("--scans", type=int, default=64)
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args()
    meas = measurements(args.runs, args.scans)
    batch_out = call_tracker(FirstPlotBatch(), meas)
    run_out = call_tracker(FirstPlotRun(), meas)
    np.testing.assert_array_equal(batch_out["state"], run_out["state"])  # same numbers both ways
    print(f"trivial tracker, {args.runs} runs × {args.scans} scans, {args.repeats} repeats (median, min–max)")
    rows = {}
    for label, tracker in (("batch form", FirstPlotBatch()), ("per-run form", FirstPlotRun())):
        med, times, _ = time_repeats(lambda: call_tracker(tracker, meas), args.repeats)
        rows[label] = med
        print(f"  {label:13s} {1e3 * med:9.2f} ms   ({1e3 * min(times):.2f}–{1e3 * max(times):.2f} ms)")
    extra = rows["per-run form"] - rows["batch form"]
    print(f"  per-run overhead: {1e3 * extra:.2f} ms in all, {1e6 * extra / args.runs:.1f} µs per run "
          f"({rows['per-run form'] / rows['batch form']:.1f}× the batch form)")


if __name__ == "__main__":
    main()
