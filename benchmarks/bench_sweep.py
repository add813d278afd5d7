"""Parameter-sweep benchmark: serial loop vs process pool vs Dask on one machine.

What it measures
----------------
A sweep of the bundled ``radar-tws`` scenario over ``--points`` values of one parameter
(default: ``sigma_bearing_deg`` at 16 values evenly spaced over 0.4–2.0 deg, ``--runs 100``
Monte Carlo runs per point, metrics only: ``keep_data=False``, ``out_dir=None``) is built once
with :func:`trackreplay.sweep.build_grid` and run with :func:`trackreplay.sweep.run_sweep` on

1. ``executor="serial"`` (one core, the baseline);
2. ``executor="process"``, ``workers=2`` (``ProcessPoolExecutor``, forkserver context). The
   forkserver is started, and imports the worker modules, by the first process-pool sweep of an
   interpreter and then stays up, so later sweeps only fork. Both are shown: the *first* sweep
   (what one ``sweep`` command pays) and a sweep with the forkserver already running;
3. ``executor="dask"``, ``workers=2``: the ``LocalCluster`` started *inside* ``run_sweep``, so
   cluster start-up and shutdown are part of the wall time ("incl. start-up");
4. Dask on a fresh ``LocalCluster`` + ``Client`` started here beforehand with the same settings
   (127.0.0.1, no dashboard, processes, 1 thread per worker); its start-up is timed on its own
   and only ``run_sweep(..., scheduler=address)`` is timed ("excl. start-up"). Start-up
   includes warming the workers (importing the pipeline on each, as a cluster that has served
   one sweep already has), so this row is the steady-state per-point cost of Dask.

For each: wall time, throughput (points/s), speed-up over serial throughput (target ≥ 1.6× for
the parallel executors) and the per-point overhead

    overhead = (wall_s × workers − Σ point_work_s) / n_points

where ``point_work_s`` is measured inside the worker by :func:`trackreplay.sweep.run_point`; it is
shown in ms and as a share of the median point's work in the serial run (target < 5 %). The
overhead is split with the completion time stamps of the ``progress`` callback: *start-up* (from
the call until the work of the first finished point began), *tail* (after the last point
finished: pool/cluster shutdown, table assembly) and the rest (dispatch, result transfer, load
imbalance at the end). The cold-start time inside ``point_work_s`` (the first point of a fresh
process imports ``trackreplay.replay`` and Rerun; counted as work by the formula) is shown as
Σ work − n × median. Up front, the cold start of a worker is timed in a fresh interpreter.

Each executor is timed ``--repeats`` times, round robin (fewer if another round would take the
timed part past ``--budget`` s); the figures are those of its fastest run (best of N: other
processes on the machine only ever add time). Before the serial runs one point is run untimed
here so the serial baseline is warm. The machine may be shared: before each timed sweep the
script waits (up to ``--quiet-wait`` s) for other processes to go quiet, and during it samples
``/proc`` to split the machine's CPU time into this process tree's and everyone else's; a
figure taken while others used ≥ 0.15 cores is flagged as pessimistic. With only one round the
"forkserver already running" row is left out.

Finally every result table is sorted by ``point_index, tracker, metric`` and compared with the
serial one with ``DataFrame.equals`` (a point's seed depends only on its parameters, so the
executors must agree exactly). A compact summary with PASS/MISS closes the output; a missed
target is reported, not an error (exit status 1 only if a point fails or tables differ).

How to run
----------
From the repository root, with the package and ``dask[distributed]`` installed::

    python benchmarks/bench_sweep.py                      # 16 points × 100 runs, 2 workers, 3 repeats
    python benchmarks/bench_sweep.py --points 8 --runs 50 --repeats 1

About 1.5 minutes on an idle 2-core machine with the defaults (Linux; elsewhere the CPU
accounting reads as zero).
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import threading
import time

import numpy as np

SPEEDUP_TARGET = 1.6
OVERHEAD_TARGET = 0.05
BUSY_OTHERS = 0.15  # cores used by other processes above which a figure is flagged
_TICK = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100


# --------------------------------------------------------------------------- CPU accounting


def _tree_cpu(root: int) -> dict[int, float]:
    """{pid: CPU seconds} of ``root`` and all its descendants (Linux /proc; {} elsewhere)."""
    out, stack = {}, [root]
    while stack:
        pid = stack.pop()
        try:
            with open(f"/proc/{pid}/stat") as f:
                txt = f.read()
            rest = txt[txt.rfind(")") + 2:].split()
            out[pid] = (int(rest[11]) + int(rest[12])) / _TICK
            for tid in os.listdir(f"/proc/{pid}/task"):  # children are listed by the forking thread
                with open(f"/proc/{pid}/task/{tid}/children") as f:
                    stack.extend(int(c) for c in f.read().split())
        except (OSError, ValueError, IndexError):
            continue
    return out


def _machine_busy_s() -> float:
    try:
        with open("/proc/stat") as f:
            v = [int(x) for x in f.readline().split()[1:]]
    except (OSError, ValueError):
        return 0.0
    return (sum(v[:8]) - v[3] - v[4]) / _TICK  # all but idle and iowait


class CpuMonitor:
    """CPU seconds used by this process tree vs. by everything else while the block runs.

    A thread walks this process's tree every ``interval`` s (< 1 ms a walk); a process of ours
    that exits between two walks loses at most ``interval`` s of CPU from "ours" (to "others").
    """

    def __init__(self, interval: float = 0.05):
        self.interval = interval

    def _sample(self):
        self._last.update(_tree_cpu(os.getpid()))

    def _loop(self):
        while not self._stop.wait(self.interval):
            self._sample()

    def __enter__(self):
        self._last = {}
        self._sample()
        self._base = dict(self._last)
        self._busy0 = _machine_busy_s()
        self._t0 = time.perf_counter()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()
        self._sample()
        self.wall = time.perf_counter() - self._t0
        busy = _machine_busy_s() - self._busy0
        self.ours = sum(c - self._base.get(p, 0.0) for p, c in self._last.items())
        self.others = max(0.0, busy - self.ours)
        return False

    @property
    def other_cores(self) -> float:
        return self.others / self.wall if self.wall > 0 else 0.0


def wait_quiet(max_wait: float, window: float = 1.0) -> float:
    """Wait (≤ max_wait s) for a ``window`` in which other processes use < BUSY_OTHERS cores.

    Returns the other processes' load in the last window (cores)."""
    deadline = time.perf_counter() + max_wait
    while True:
        with CpuMonitor(interval=window) as m:
            time.sleep(window)
        if m.other_cores < BUSY_OTHERS or time.perf_counter() >= deadline:
            return m.other_cores


# --------------------------------------------------------------------------- helpers


def _section(text: str) -> None:
    print()
    print(text)
    print("-" * len(text))


def _cold_import() -> dict:
    """Wall time of a fresh interpreter importing the worker modules, and the biggest imports."""
    import subprocess

    def run(code, *flags):
        t = time.perf_counter()
        p = subprocess.run([sys.executable, *flags, "-c", code], capture_output=True, text=True, check=True)
        return time.perf_counter() - t, p.stderr

    mods = "import trackreplay.sweep, trackreplay.replay, trackreplay.recorders.simulated"
    python_s, _ = run("pass")
    total_s, _ = run(mods)
    _, log = run(mods, "-X", "importtime")
    cum = {}
    for line in log.splitlines():  # "import time: self [us] | cumulative | name"
        parts = line.split("|")
        if len(parts) == 3 and parts[1].strip().isdigit():
            name = parts[2].strip()
            if name in ("numpy", "polars", "rerun", "trackreplay.sweep", "trackreplay.replay", "trackreplay.recorders.simulated"):
                cum[name] = max(cum.get(name, 0.0), int(parts[1]) / 1e6)
    return {"python": python_s, "total": total_s, "top": sorted(cum.items(), key=lambda kv: -kv[1])}


def _timed_sweep(run_sweep, tasks, swept, quiet_wait, **kw):
    """run_sweep with completion time stamps (s since the call) and CPU accounting."""
    before = wait_quiet(quiet_wait)
    stamps = []
    with CpuMonitor() as mon:
        t0 = time.perf_counter()
        rep = run_sweep(tasks, swept, None, progress=lambda n: stamps.append(time.perf_counter() - t0), **kw)
    return {"rep": rep, "stamps": stamps, "mon": mon, "before": before}


def _analyse(name, run, workers, n, serial_tp, median_ref):
    rep, stamps, mon = run["rep"], run["stamps"], run["mon"]
    work = rep.point_work_s
    total_work = float(np.sum(work))
    overhead = (rep.wall_s * workers - total_work) / n
    tp = n / rep.wall_s
    # run_sweep appends a point's work to point_work_s before calling progress, so work[0] is the
    # work of the point that finished first and stamps[0] its completion time.
    startup = stamps[0] - work[0] if stamps else float("nan")
    tail = rep.wall_s - stamps[-1] if stamps else float("nan")
    return {
        "name": name, "wall": rep.wall_s, "tp": tp, "speedup": tp / serial_tp, "workers": workers,
        "overhead_s": overhead, "overhead_share": overhead / median_ref, "work_sum": total_work,
        "median": rep.median_point_s, "startup": startup, "tail": tail,
        "cold_excess": total_work - n * float(np.median(work)), "failed": rep.failed,
        "ours_cpu": mon.ours, "other_cores": mon.other_cores, "before": run["before"],
        "cluster": run.get("cluster"),
    }


def _print_result(r, show_speedup=True):
    if r["cluster"]:
        c = r["cluster"]
        print(f"  LocalCluster + Client start-up {c['start']:6.2f} s   "
              f"(not in the figures below; shutdown {c['stop']:.2f} s)")
    print(f"  wall time                 {r['wall']:8.2f} s")
    print(f"  throughput                {r['tp']:8.2f} points/s")
    if show_speedup:
        ok = r["speedup"] >= SPEEDUP_TARGET
        print(f"  speed-up vs serial        {r['speedup']:8.2f} ×    target ≥ {SPEEDUP_TARGET} ×  "
              f"-> {'PASS' if ok else 'MISS'}")
    print(f"  Σ point work              {r['work_sum']:8.2f} s    (median point {1e3 * r['median']:.0f} ms)")
    ok = r["overhead_share"] < OVERHEAD_TARGET
    print(f"  overhead per point        {1e3 * r['overhead_s']:8.1f} ms   = {100 * r['overhead_share']:5.1f} % of the "
          f"median point's work   target < {100 * OVERHEAD_TARGET:.0f} %  -> {'PASS' if ok else 'MISS'}")
    w = r["workers"]
    rest = r["wall"] * w - r["work_sum"] - w * (r["startup"] + r["tail"])
    print(f"    where it goes (worker-s, ×{w}): start-up {w * r['startup']:.2f}, tail {w * r['tail']:.2f}, "
          f"rest (dispatch, transfer, imbalance) {rest:+.2f}")
    print(f"    cold start inside the work (Σ work − n × median): {r['cold_excess']:+.2f} s")
    flag = "   <- shared machine: figures pessimistic" if r["other_cores"] >= BUSY_OTHERS else ""
    print(f"  CPU: this process tree {r['ours_cpu']:.2f} core-s ({r['ours_cpu'] / r['wall']:.2f} cores), "
          f"other processes {r['other_cores']:.2f} cores{flag}")
    if r["failed"]:
        print(f"  FAILED points: {r['failed']}")


# --------------------------------------------------------------------------- main


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--points", type=int, default=16, help="grid points (default 16)")
    ap.add_argument("--runs", type=int, default=100, help="Monte Carlo runs per point (default 100)")
    ap.add_argument("--workers", type=int, default=2, help="workers of the parallel executors (default 2)")
    ap.add_argument("--param", default="sigma_bearing_deg", help="swept parameter (default sigma_bearing_deg)")
    ap.add_argument("--lo", type=float, default=0.4, help="first value (default 0.4)")
    ap.add_argument("--hi", type=float, default=2.0, help="last value (default 2.0)")
    ap.add_argument("--seed", type=int, default=2024)
    ap.add_argument("--repeats", type=int, default=3, help="timed sweeps per executor, fastest shown (default 3)")
    ap.add_argument("--budget", type=float, default=150.0,
                    help="no further round of repeats once it would take the timed sweeps past this many s (default 150)")
    ap.add_argument("--quiet-wait", type=float, default=5.0,
                    help="before each timed sweep wait up to this many s for other processes to go quiet (default 5)")
    args = ap.parse_args()

    import dask
    import distributed
    import polars as pl
    from dask.distributed import Client, LocalCluster

    from trackreplay.sweep import build_grid, run_point, run_sweep

    n, W = args.points, args.workers
    values = [f"{v:.4g}" for v in np.linspace(args.lo, args.hi, n)]
    swept = [args.param]
    tasks = build_grid("radar-tws", {args.param: values}, args.runs, args.seed, keep_data=False, out_dir=None)

    print("bench_sweep: radar-tws parameter sweep, serial vs process pool vs Dask")
    print(f"  python {platform.python_version()}, numpy {np.__version__}, polars {pl.__version__}, "
          f"dask {dask.__version__}, distributed {distributed.__version__}, "
          f"{len(os.sched_getaffinity(0)) if hasattr(os, 'sched_getaffinity') else os.cpu_count()} CPUs")
    print(f"  grid: {args.param} = {values[0]}..{values[-1]} ({n} points) × {args.runs} runs, seed {args.seed}, "
          f"keep_data=False, workers={W}, repeats={args.repeats}")

    t = time.perf_counter()
    warm = run_point(tasks[0])  # so the serial baseline measures steady-state work only
    print(f"  warm-up point in this process (untimed): {time.perf_counter() - t:.2f} s"
          + (f"  ERROR {warm.error}" if warm.error else ""))
    imp = _cold_import()
    print(f"  cold start of a worker (fresh interpreter importing trackreplay.sweep, trackreplay.replay, "
          f"trackreplay.recorders.simulated): {imp['total']:.2f} s")
    print(f"    [bare interpreter {imp['python']:.2f} s; cumulative imports: "
          + ", ".join(f"{k} {v:.2f} s" for k, v in imp["top"]) + "]")

    from trackreplay.sweep.executors import _preload_worker

    def dask_excl():
        t = time.perf_counter()
        cluster = LocalCluster(n_workers=W, threads_per_worker=1, processes=True,
                               host="127.0.0.1", dashboard_address=None)
        client = Client(cluster)
        client.wait_for_workers(W)
        client.run(_preload_worker)  # warm workers: part of start-up, not of the points
        start_s = time.perf_counter() - t
        try:
            run = _timed_sweep(run_sweep, tasks, swept, args.quiet_wait, executor="dask", workers=W,
                               scheduler=cluster.scheduler_address)
        finally:
            t = time.perf_counter()
            client.close()
            cluster.close()
        run["cluster"] = {"start": start_s, "stop": time.perf_counter() - t}
        return run

    runners = {
        "serial": lambda: _timed_sweep(run_sweep, tasks, swept, args.quiet_wait, executor="serial"),
        "process": lambda: _timed_sweep(run_sweep, tasks, swept, args.quiet_wait, executor="process", workers=W),
        "dask_incl": lambda: _timed_sweep(run_sweep, tasks, swept, args.quiet_wait, executor="dask", workers=W),
        "dask_excl": dask_excl,
    }
    runs = {k: [] for k in runners}
    print(f"\n  timed sweeps, round robin ({args.repeats} × each, time budget {args.budget:.0f} s):")
    t_start = time.perf_counter()
    for i in range(args.repeats):
        t_round = time.perf_counter()
        if i and (t_round - t_start) * (i + 1) / i > args.budget:
            print(f"    (stopping after {i} round{'s' if i > 1 else ''}: another would exceed the budget)")
            break
        for key, fn in runners.items():
            run = fn()
            runs[key].append(run)
            rep, mon = run["rep"], run["mon"]
            line = (f"    {i + 1}  {key:<10} wall {rep.wall_s:6.2f} s   Σ work {sum(rep.point_work_s):6.2f} s   "
                    f"other processes {mon.other_cores:.2f} cores")
            if run["before"] >= BUSY_OTHERS:
                line += f" (before: {run['before']:.2f})"
            if "cluster" in run:
                line += f"   cluster start-up {run['cluster']['start']:.2f} s"
            print(line)

    def best_run(lst):
        return min(lst, key=lambda r: r["rep"].wall_s) if lst else None

    # The process pool's first sweep starts the forkserver; later ones reuse it.
    chosen = {
        "serial": best_run(runs["serial"]),
        "process_first": runs["process"][0],
        "process_warm": best_run(runs["process"][1:]),
        "dask_incl": best_run(runs["dask_incl"]),
        "dask_excl": best_run(runs["dask_excl"]),
    }
    titles = {
        "serial": ("serial", "1. serial"),
        "process_first": ("process, 1st sweep", f"2a. process pool, {W} workers: first sweep (starts the forkserver)"),
        "process_warm": ("process, forkserver up", f"2b. process pool, {W} workers: forkserver already running"),
        "dask_incl": ("dask incl. start-up",
                      f"3. dask, LocalCluster started by run_sweep ({W} workers, incl. start-up)"),
        "dask_excl": ("dask excl. start-up", f"4. dask on a running LocalCluster ({W} workers, excl. start-up)"),
    }
    serial = chosen["serial"]["rep"]
    median_ref = serial.median_point_s  # steady-state work of one point: the common reference
    serial_tp = n / serial.wall_s
    results = {}
    for key, run in chosen.items():
        if run is None:
            continue
        workers = 1 if key == "serial" else W
        results[key] = _analyse(titles[key][0], run, workers, n, serial_tp, median_ref)
        _section(titles[key][1])
        _print_result(results[key], show_speedup=key != "serial")
        src = runs[key.split("_")[0] if key.startswith("process") else key]
        if key != "process_first" and len(src) > 1:
            shown = src[1:] if key == "process_warm" else src
            walls = ", ".join(f"{r['rep'].wall_s:.2f}" for r in shown)
            print(f"  (fastest of: {walls} s)")

    _section("5. identical result tables")
    keys = ["point_index", "tracker", "metric"]
    ref = runs["serial"][0]["rep"].table.sort(keys)
    same_all = True
    for key in runners:
        others = [r["rep"].table.sort(keys) for r in runs[key]][1 if key == "serial" else 0:]
        if not others:
            continue
        same = all(ref.equals(o) for o in others)
        same_all &= same
        print(f"  serial vs {key:<10} ({len(others)} table{'s' if len(others) > 1 else ''} of {ref.height} rows): "
              f"{'identical' if same else 'DIFFERENT'}")
    failed_any = any(r["rep"].failed for lst in runs.values() for r in lst)

    _section("summary")
    cl = float(np.median([r["cluster"]["start"] for r in runs["dask_excl"]]))
    print(f"  {n} points × {args.runs} runs; median point work {1e3 * median_ref:.0f} ms (serial, warm); "
          f"{W} workers; LocalCluster start-up {cl:.2f} s (median); best of {len(runs['serial'])}")
    rows = [("executor", "wall s", "points/s", "speed-up", "ovh ms/pt", "ovh/median", "others' cores",
             "speed-up ≥ 1.6×", "ovh < 5 %")]
    for key, r in results.items():
        rows.append((r["name"], f"{r['wall']:.2f}", f"{r['tp']:.2f}", f"{r['speedup']:.2f} ×",
                     f"{1e3 * r['overhead_s']:.1f}", f"{100 * r['overhead_share']:.1f} %", f"{r['other_cores']:.2f}",
                     "-" if key == "serial" else ("PASS" if r["speedup"] >= SPEEDUP_TARGET else "MISS"),
                     "PASS" if r["overhead_share"] < OVERHEAD_TARGET else "MISS"))
    rows.append(("tables identical", "", "", "", "", "", "", "", "PASS" if same_all else "FAIL"))
    w = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    for i, row in enumerate(rows):
        print("  " + "  ".join(c.ljust(w[j]) if j == 0 else c.rjust(w[j]) for j, c in enumerate(row)).rstrip())
        if i == 0:
            print("  " + "  ".join("-" * x for x in w))
    if any(r["other_cores"] >= BUSY_OTHERS for r in results.values()):
        print(f"  note: other processes used ≥ {BUSY_OTHERS} cores during some runs; those figures are pessimistic")
    return 0 if (same_all and not failed_any) else 1


if __name__ == "__main__":
    sys.exit(main())
