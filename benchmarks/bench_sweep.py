"""Parameter-sweep benchmark: serial loop vs process pool vs Dask on one machine.

What it measures
----------------
A sweep of the bundled ``radar-tws`` scenario over ``--points`` values of one parameter
(default: ``sigma_bearing_deg`` at 16 values evenly spaced over 0.4–2.0 deg, ``--runs 100``
Monte Carlo runs per point, metrics only: ``keep_data=False``, ``out_dir=None``) is built once
with :func:`pipeline.sweep.build_grid` and run with :func:`pipeline.sweep.run_sweep` on

1. ``executor="serial"`` (one core, the baseline);
2. ``executor="process"``, ``workers=2`` (``ProcessPoolExecutor``, forkserver context);
3. ``executor="dask"``, ``workers=2``: the ``LocalCluster`` started *inside* ``run_sweep``, so
   cluster start-up and shutdown are part of the wall time ("incl. start-up");
4. Dask again on a ``LocalCluster`` + ``Client`` started here beforehand with the same settings
   (127.0.0.1, no dashboard, processes, 1 thread per worker); its start-up is timed on its own
   and only ``run_sweep(..., scheduler=address)`` is timed ("excl. start-up").

For each: wall time, throughput (points/s), speed-up over serial throughput (target ≥ 1.6× for
the parallel executors) and the per-point overhead

    overhead = (wall_s × workers − Σ point_work_s) / n_points

where ``point_work_s`` is measured inside the worker by :func:`pipeline.sweep.run_point`; it is
shown in ms and as a share of the median point's work (target < 5 %). The overhead is split by
completion time stamps (``progress`` callback): *start-up* (until the first finished point's work
began), *tail* (after the last point finished: pool/cluster shutdown, table assembly) and the
rest (scheduling, result transfer, load imbalance while the last points run). The excess work of
the first point in each fresh process (lazy imports, counted as work, not overhead) is shown too.

Finally the four result tables are sorted by ``point_index, tracker, metric`` and compared with
``DataFrame.equals`` (each point's seed depends only on its parameters, so the executors must
agree exactly). A compact summary table with PASS/MISS closes the output; a missed target is
reported, not an error (exit status 1 only if a point fails or the tables differ).

Before the serial run one point is run untimed in this process so that the serial baseline is
warm (imports done); the parallel executors' workers start cold, as in real use.

How to run
----------
From the repository root, with the package and ``dask[distributed]`` installed::

    python benchmarks/bench_sweep.py                      # 16 points × 100 runs, 2 workers
    python benchmarks/bench_sweep.py --points 8 --runs 50

Takes about a minute on a 2-core machine with the defaults.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time

import numpy as np


SPEEDUP_TARGET = 1.6
OVERHEAD_TARGET = 0.05


def _section(text: str) -> None:
    print()
    print(text)
    print("-" * len(text))


def _timed_sweep(run_sweep, tasks, swept, **kw):
    """run_sweep with completion time stamps (seconds since the call)."""
    stamps = []
    t0 = time.perf_counter()
    rep = run_sweep(tasks, swept, None, progress=lambda n: stamps.append(time.perf_counter() - t0), **kw)
    return rep, stamps


def _analyse(name, rep, stamps, workers, n, serial_tp, median_ref):
    work = rep.point_work_s
    total_work = float(np.sum(work))
    overhead = (rep.wall_s * workers - total_work) / n
    tp = n / rep.wall_s
    # start-up: from the call until the first finished point's work began (work[0] is that point:
    # run_sweep appends its work before calling progress); tail: after the last completion.
    startup = stamps[0] - work[0] if stamps else float("nan")
    tail = rep.wall_s - stamps[-1] if stamps else float("nan")
    cold_excess = total_work - n * float(np.median(work))
    return {
        "name": name, "wall": rep.wall_s, "tp": tp, "speedup": tp / serial_tp if serial_tp else 1.0,
        "overhead_s": overhead, "overhead_share": overhead / median_ref, "work_sum": total_work,
        "median": rep.median_point_s, "startup": startup, "tail": tail, "cold_excess": cold_excess,
        "workers": workers, "failed": rep.failed,
    }


def _print_row(r, show_speedup=True):
    print(f"  wall time                 {r['wall']:8.2f} s")
    print(f"  throughput                {r['tp']:8.2f} points/s")
    if show_speedup:
        ok = r["speedup"] >= SPEEDUP_TARGET
        print(f"  speed-up vs serial        {r['speedup']:8.2f} ×    target ≥ {SPEEDUP_TARGET} ×  -> {'PASS' if ok else 'MISS'}")
    ok = r["overhead_share"] < OVERHEAD_TARGET
    print(f"  Σ point work              {r['work_sum']:8.2f} s    (median point {1e3 * r['median']:.0f} ms)")
    print(f"  overhead per point        {1e3 * r['overhead_s']:8.1f} ms   = {100 * r['overhead_share']:5.1f} % of median "
          f"point work   target < {100 * OVERHEAD_TARGET:.0f} %  -> {'PASS' if ok else 'MISS'}")
    rest = r["wall"] * r["workers"] - r["work_sum"] - r["workers"] * (r["startup"] + r["tail"])
    print(f"    where it goes (×{r['workers']} worker-s): start-up {r['startup']:.2f} s, tail {r['tail']:.2f} s, "
          f"rest (dispatch/transfer/imbalance) {rest:+.2f} worker-s")
    print(f"    cold-start excess inside work (Σ work − n × median): {r['cold_excess']:+.2f} s")
    if r["failed"]:
        print(f"  FAILED points: {r['failed']}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--points", type=int, default=16, help="grid points (default 16)")
    ap.add_argument("--runs", type=int, default=100, help="Monte Carlo runs per point (default 100)")
    ap.add_argument("--workers", type=int, default=2, help="workers of the parallel executors (default 2)")
    ap.add_argument("--param", default="sigma_bearing_deg", help="swept parameter (default sigma_bearing_deg)")
    ap.add_argument("--lo", type=float, default=0.4, help="first value (default 0.4)")
    ap.add_argument("--hi", type=float, default=2.0, help="last value (default 2.0)")
    ap.add_argument("--seed", type=int, default=2024)
    args = ap.parse_args()

    import dask
    import distributed
    import polars as pl

    from pipeline.sweep import build_grid, run_point, run_sweep

    n, W = args.points, args.workers
    values = [f"{v:.4g}" for v in np.linspace(args.lo, args.hi, n)]
    specs = {args.param: values}
    swept = [args.param]
    tasks = build_grid("radar-tws", specs, args.runs, args.seed, keep_data=False, out_dir=None)

    print("bench_sweep: radar-tws parameter sweep, serial vs process pool vs Dask")
    print(f"  python {platform.python_version()}, numpy {np.__version__}, polars {pl.__version__}, "
          f"dask {dask.__version__}, distributed {distributed.__version__}, "
          f"{len(os.sched_getaffinity(0)) if hasattr(os, 'sched_getaffinity') else os.cpu_count()} CPUs")
    print(f"  grid: {args.param} = {values[0]}..{values[-1]} ({n} points) × {args.runs} runs, seed {args.seed}, "
          f"keep_data=False, workers={W}")

    # Warm the parent process so the serial baseline measures steady-state work only.
    t = time.perf_counter()
    warm = run_point(tasks[0])
    print(f"  warm-up point in this process (untimed in figures): {time.perf_counter() - t:.2f} s"
          + (f"  ERROR {warm.error}" if warm.error else ""))

    results, tables = {}, {}

    # ------------------------------------------------------------------ serial
    _section("1. serial")
    rep, st = _timed_sweep(run_sweep, tasks, swept, executor="serial")
    median_ref = rep.median_point_s  # the steady-state work of one point, common reference
    serial_tp = n / rep.wall_s
    results["serial"] = _analyse("serial", rep, st, 1, n, serial_tp, median_ref)
    tables["serial"] = rep.table
    _print_row(results["serial"], show_speedup=False)

    # ------------------------------------------------------------------ process pool
    _section(f"2. process pool (forkserver, {W} workers)")
    rep, st = _timed_sweep(run_sweep, tasks, swept, executor="process", workers=W)
    results["process"] = _analyse("process", rep, st, W, n, serial_tp, median_ref)
    tables["process"] = rep.table
    _print_row(results["process"])

    # ------------------------------------------------------------------ dask, cluster inside run_sweep
    _section(f"3. dask LocalCluster started by run_sweep ({W} workers, incl. start-up)")
    rep, st = _timed_sweep(run_sweep, tasks, swept, executor="dask", workers=W)
    results["dask_incl"] = _analyse("dask (incl. start-up)", rep, st, W, n, serial_tp, median_ref)
    tables["dask_incl"] = rep.table
    _print_row(results["dask_incl"])

    # ------------------------------------------------------------------ dask, cluster started here
    _section(f"4. dask on a running LocalCluster ({W} workers, excl. start-up)")
    from dask.distributed import Client, LocalCluster

    t = time.perf_counter()
    cluster = LocalCluster(n_workers=W, threads_per_worker=1, processes=True,
                           host="127.0.0.1", dashboard_address=None)
    client = Client(cluster)
    client.wait_for_workers(W)
    cluster_start = time.perf_counter() - t
    try:
        rep, st = _timed_sweep(run_sweep, tasks, swept, executor="dask", workers=W, scheduler=cluster.scheduler_address)
    finally:
        t = time.perf_counter()
        client.close()
        cluster.close()
        cluster_stop = time.perf_counter() - t
    results["dask_excl"] = _analyse("dask (excl. start-up)", rep, st, W, n, serial_tp, median_ref)
    tables["dask_excl"] = rep.table
    print(f"  LocalCluster + Client start-up {cluster_start:8.2f} s   (not in the figures below; shutdown {cluster_stop:.2f} s)")
    _print_row(results["dask_excl"])

    # ------------------------------------------------------------------ identical results
    _section("5. identical result tables")
    keys = ["point_index", "tracker", "metric"]
    ref = tables["serial"].sort(keys)
    same_all = True
    for k in ("process", "dask_incl", "dask_excl"):
        other = tables[k].sort(keys)
        same = ref.equals(other)
        same_all &= same
        print(f"  serial vs {k:<10} {ref.height} vs {other.height} rows: {'identical' if same else 'DIFFERENT'}")
    failed_any = any(r["failed"] for r in results.values())

    # ------------------------------------------------------------------ summary
    _section("summary")
    print(f"  points {n}, runs/point {args.runs}, median point work {1e3 * median_ref:.0f} ms (serial, warm); "
          f"workers {W}; dask cluster start-up {cluster_start:.2f} s")
    rows = [("executor", "wall s", "points/s", "speed-up", "ovh ms/pt", "ovh % med", "speed-up ≥1.6×", "ovh <5 %")]
    for key in ("serial", "process", "dask_incl", "dask_excl"):
        r = results[key]
        par = key != "serial"
        rows.append((r["name"], f"{r['wall']:.2f}", f"{r['tp']:.2f}", f"{r['speedup']:.2f} ×",
                     f"{1e3 * r['overhead_s']:.1f}", f"{100 * r['overhead_share']:.1f} %",
                     ("PASS" if r["speedup"] >= SPEEDUP_TARGET else "MISS") if par else "-",
                     "PASS" if r["overhead_share"] < OVERHEAD_TARGET else "MISS"))
    rows.append(("tables identical", "", "", "", "", "", "", "PASS" if same_all else "FAIL"))
    w = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    for i, row in enumerate(rows):
        print("  " + "  ".join(c.ljust(w[j]) if j == 0 else c.rjust(w[j]) for j, c in enumerate(row)))
        if i == 0:
            print("  " + "  ".join("-" * x for x in w))
    return 0 if (same_all and not failed_any) else 1


if __name__ == "__main__":
    sys.exit(main())
