"""Radar track-while-scan benchmark: replay wall time, filter throughput and MCAP I/O.

What it measures
----------------
1. **Replay, MCAP to metrics table.** A Monte Carlo data set of the bundled ``radar-tws``
   scenario (default 500 runs) is simulated into a temporary MCAP file (not timed here).
   ``trackreplay.replay.replay(path, out_path=..., rrd_path=...)`` is then timed with all four
   trackers: wall time, the breakdown from ``ReplayResult.timings`` (read, filter, evaluate,
   write, rerun) and the Rerun logging share ``rerun_s / total_s`` (target < 10 %).
2. **Filter only.** ``trackreplay.trackers.radar_tws.track_plots`` with the ``"kalman"`` strategy
   over all runs in one vectorised call, against FilterPy's ``filterpy.kalman.KalmanFilter``
   stepped run by run in a Python loop on the same data: the same converted measurements and
   per-scan converted covariance ``R = converted_covariance(r, θ, σ_r, σ_θ)``, the same ``F``
   and white-acceleration ``Q`` (design σ_v, scan period T), the same two-point start (state at
   scan 1 = ``[z1, (z1 − z0)/T]``, covariance from R0 and R1) and updates from scan 2 on.
   Prints the largest state difference between the two, the time per run-step of each, the
   speed-up (target ≥ 80×), and the time of all four strategies run back to back. Then the
   **floor** of this machine for the Kalman step: the arithmetic of one run-step
   (:data:`KALMAN_FLOPS_PER_STEP` flops, :data:`KALMAN_BYTES_PER_STEP` bytes) divided by one
   core's measured dgemm rate and copy bandwidth, and ours as a multiple of it (target ≤ 10×).
3. **MCAP I/O.** Throughput of ``trackreplay.recorders.simulated.record`` (simulate + write; write alone
   is shown too) and of ``trackreplay.contract.read_dataset``, in MB/s of file on disk (zstd
   chunks, 1 MB = 10⁶ bytes) and messages/s.

A compact summary table closes the output. Times come from ``time.perf_counter``; each figure
is the median over ``--repeats`` repetitions (more for the cheap filter-only timings). All
scratch files live in a temporary directory that is removed at exit.

How to run
----------
From the repository root, with the package installed (``pip install -e .``) and FilterPy
available (``pip install filterpy``)::

    python benchmarks/bench_radar.py              # 500 runs, 3 repeats
    python benchmarks/bench_radar.py --runs 200 --repeats 5

The exit status is 1 if the FilterPy and vectorised estimates disagree by more than
``--tolerance`` metres (default 1e-6), else 0; missed speed targets are reported, not fatal.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
# The pipeline imports rerun on first use (sweep workers never need it). Import it here so
# every timed replay measures logging, not the one-time ~0.4 s import of the first replay.
import rerun  # noqa: F401

from trackreplay.contract import read_dataset, scenario_metadata
from trackreplay.cores.filters.converted_measurements import converted_covariance, polar_to_cartesian
from trackreplay.trackers.radar_tws import STRATEGIES, TrackerDesign, track_plots
from trackreplay.cores.filters.kalman import white_acceleration_model
from trackreplay.replay import replay
from trackreplay.stages.radar import RadarStage
from trackreplay.recorders import simulator_for
from trackreplay.recorders.scenarios import load_scenario
from trackreplay.recorders.simulated import record, write_simulated

from timing import spread, time_repeats as timed  # noqa: E402

RERUN_SHARE_TARGET = 0.10
SPEEDUP_TARGET = 80.0  # batched Kalman filter at 500 runs against FilterPy per run
FLOOR_TARGET = 10.0  # the Kalman kernel within this multiple of the machine's floor

#: Floating-point operations of one run-step of the converted-measurement Kalman filter on the
#: covariance's 10 components: predict the state (4) and covariance (F P Fᵀ + Q block by
#: block: 32), convert the plot (r cos θ, r sin θ and the rotated covariance R: 12, counting
#: each sine or cosine as one), innovation covariance S = P_pos + R and its determinant (6),
#: the gain K = P Hᵀ S⁻¹ (4 × 2 entries from S's adjugate: 28), innovation and state update
#: (2 + 16), covariance update P − K S Kᵀ on 10 components (40).
KALMAN_FLOPS_PER_STEP = 4 + 32 + 12 + 6 + 28 + 18 + 40
#: Bytes one run-step must move at the least: read the plot (r, θ) and write the state (4) and
#: the covariance's 10 components, in float64.
KALMAN_BYTES_PER_STEP = 8 * (2 + 4 + 10)

_FLOOR_PROBE = """
import time, numpy as np
def best(fn):
    times = []
    for _ in range(5):
        t0 = time.perf_counter(); fn(); times.append(time.perf_counter() - t0)
    return min(times)
a = np.random.default_rng(0).random((1024, 1024)); a @ a
big = np.ones(2**25); out = np.empty_like(big); np.copyto(out, big)
print(2 * 1024**3 / best(lambda: a @ a), 2 * big.nbytes / best(lambda: np.copyto(out, big)))
"""


def machine_floor() -> tuple[float, float]:
    """(flop/s, byte/s) of one core: the best of 5 dgemm of 1024² and of 5 copies of 256 MiB,
    in a process whose BLAS is held to one thread."""
    import subprocess

    one = {k: "1" for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")}
    out = subprocess.run([sys.executable, "-c", _FLOOR_PROBE], env=dict(os.environ, **one), check=True,
                         capture_output=True, text=True).stdout.split()
    return float(out[0]), float(out[1])
MB = 1e6


def fmt_s(s: float) -> str:
    return f"{s * 1e3:9.1f} ms" if s < 10 else f"{s:9.2f} s "


def heading(text: str) -> None:
    print()
    print(text)
    print("-" * len(text))


def design_from(params: dict) -> TrackerDesign:
    """The tracker design the replay uses for this scenario (see RadarStage.run)."""
    return TrackerDesign(
        scan_period_s=params["scan_period_s"],
        sigma_v=params["design_sigma_v_mps2"],
        sigma_range_m=params["sigma_range_m"],
        sigma_bearing_rad=np.deg2rad(params["sigma_bearing_deg"]),
        nominal_cross_range_m=params["nominal_cross_range_m"],
        startup=bool(params["startup_gains"]),
    )


# --------------------------------------------------------------------------- FilterPy side


def filterpy_loop(z, R, T, F, Q, H):
    """FilterPy ``KalmanFilter`` per run, two-point start at scans 0/1, filtering from scan 2.

    Parameters
    ----------
    z : ndarray (runs, scans, 2)
        Converted plots (x, y).
    R : ndarray (runs, scans, 2, 2)
        Converted covariance of each plot.
    T : float
        Scan period (the start's velocity divisor; scans are evenly spaced).
    F, Q, H : ndarray
        Model matrices, state order ``[x, y, ẋ, ẏ]``.

    Returns
    -------
    state, covariance : ndarray (runs, scans, 4), (runs, scans, 4, 4), NaN at scan 0.
    """
    from filterpy.kalman import KalmanFilter

    n_runs, n_scans = z.shape[:2]
    state = np.full((n_runs, n_scans, 4), np.nan)
    cov = np.full((n_runs, n_scans, 4, 4), np.nan)
    for r in range(n_runs):
        kf = KalmanFilter(dim_x=4, dim_z=2)
        kf.F, kf.Q, kf.H = F, Q, H
        z0, z1, R0, R1 = z[r, 0], z[r, 1], R[r, 0], R[r, 1]
        P0 = np.empty((4, 4))
        P0[:2, :2] = R1
        P0[:2, 2:] = R1 / T
        P0[2:, :2] = R1 / T
        P0[2:, 2:] = (R1 + R0) / T**2
        kf.x = np.concatenate([z1, (z1 - z0) / T])[:, None]
        kf.P = P0
        state[r, 1], cov[r, 1] = kf.x[:, 0], kf.P
        for k in range(2, n_scans):
            kf.predict()
            kf.update(z[r, k], R=R[r, k])
            state[r, k], cov[r, k] = kf.x[:, 0], kf.P
    return state, cov


# --------------------------------------------------------------------------- main


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=500, help="Monte Carlo runs (default 500)")
    ap.add_argument("--repeats", type=int, default=3, help="repetitions of the costly timings (default 3)")
    ap.add_argument("--seed", type=int, default=2006)
    ap.add_argument("--tolerance", type=float, default=1e-6, help="max |Δstate| accepted, metres")
    args = ap.parse_args(argv)

    import filterpy

    scenario = load_scenario("radar-tws")
    params = scenario.params
    n_scans = int(params["n_scans"])
    rep = max(1, args.repeats)
    print("bench_radar: radar-tws Monte Carlo benchmark")
    print(f"  python {platform.python_version()}, numpy {np.__version__}, filterpy {filterpy.__version__}, "
          f"{os.cpu_count()} CPU(s), {platform.machine()}")
    print(f"  scenario radar-tws: {args.runs} runs × {n_scans} scans, seed {args.seed}, "
          f"median of {rep} repeat(s) unless stated")

    summary = []  # (figure, quantity, value, target, verdict)
    failed = False
    with tempfile.TemporaryDirectory(prefix="bench_radar_") as tmp:
        tmp = Path(tmp)
        data_path = tmp / "radar-tws.mcap"
        t0 = time.perf_counter()
        n_msgs = record(data_path, scenario, args.runs, args.seed)
        cold_record_s = time.perf_counter() - t0
        size_mb = data_path.stat().st_size / MB
        print(f"  setup: recorded {n_msgs} messages, {size_mb:.2f} MB in {cold_record_s:.2f} s (not timed in figure 1)")

        # ------------------------------------------------------------------ figure 1
        heading(f"[1] Replay, MCAP → metrics table ({args.runs} runs, 4 trackers, with out MCAP + .rrd)")
        out_path, rrd_path = tmp / "out.mcap", tmp / "out.rrd"
        runs_ = []
        for _ in range(rep):
            t0 = time.perf_counter()
            res = replay(data_path, out_path=out_path, rrd_path=rrd_path)
            runs_.append((time.perf_counter() - t0, dict(res.timings)))
        walls = [w for w, _ in runs_]
        wall, tm = sorted(runs_, key=lambda x: x[0])[len(runs_) // 2]  # the median repetition
        parts = ("read_s", "filter_s", "evaluate_s", "write_s", "rerun_s")
        total = tm["total_s"]
        print(f"  wall time (median)          {fmt_s(wall)}   [all: {', '.join(f'{w:.2f}' for w in walls)} s]")
        print(f"  timings['total_s']          {fmt_s(total)}")
        for k in parts:
            print(f"    {k:<12}              {fmt_s(tm[k])}   {100 * tm[k] / total:5.1f} %")
        other = total - sum(tm[k] for k in parts)
        print(f"    {'(other)':<12}              {fmt_s(other)}   {100 * other / total:5.1f} %")
        share = tm["rerun_s"] / total
        ok = share < RERUN_SHARE_TARGET
        print(f"  Rerun logging share         {100 * share:9.1f} %    target < {100 * RERUN_SHARE_TARGET:.0f} %  "
              f"-> {'PASS' if ok else 'MISS'}")
        print(f"  outputs: {out_path.stat().st_size / MB:.2f} MB MCAP, {rrd_path.stat().st_size / MB:.2f} MB .rrd, "
              f"summary table {res.summary.height} rows")
        summary += [
            ("1 replay", "wall time", f"{wall:.2f} s", "", ""),
            ("1 replay", "Rerun share of total", f"{100 * share:.1f} %", "< 10 %", "PASS" if ok else "MISS"),
        ]

        # ------------------------------------------------------------------ figure 2
        heading(f"[2] Filter only: Kalman over {args.runs} runs (same data, same model)")
        ds = read_dataset(data_path)
        rng, brg, counts, times = RadarStage().decode_plots(ds)
        design = design_from(params)
        T = design.scan_period_s
        if not (np.all(counts == 1) and np.allclose(np.diff(times), T)):
            print("  note: missed detections or uneven scans; the FilterPy loop assumes one plot per scan")
        n_runs, n_sc = counts.shape
        steps = n_runs * (n_sc - 2)  # filtered run-steps (scans 2 …), same count for both sides

        kalman = STRATEGIES["kalman"]
        ours_s, ours_all, ours = timed(lambda: track_plots(rng, brg, counts, times, design, kalman), max(7, rep))

        # FilterPy inputs: the same conversion the tracker applies to each plot (vectorised, untimed).
        z = polar_to_cartesian(rng[..., 0], brg[..., 0])
        R = converted_covariance(rng[..., 0], brg[..., 0], design.sigma_range_m, design.sigma_bearing_rad)
        from filterpy.common import Q_discrete_white_noise

        F, Q = white_acceleration_model(T, design.sigma_v)
        Q_fp = Q_discrete_white_noise(dim=2, dt=T, var=design.sigma_v**2, block_size=2, order_by_dim=False)
        q_diff = float(np.max(np.abs(Q_fp - Q)))
        H = np.hstack([np.eye(2), np.zeros((2, 2))])
        fp_s, fp_all, (fp_state, fp_cov) = timed(lambda: filterpy_loop(z, R, T, F, Q_fp, H), rep)

        sl = np.s_[:, 1:]  # scan 0 has no estimate on either side
        dx = np.abs(fp_state[sl] - ours["state"][sl])
        dP = np.abs(fp_cov[sl] - ours["covariance"][sl])
        nan_mismatch = int(np.sum(np.isnan(fp_state[sl]) != np.isnan(ours["state"][sl])))
        dpos, dvel, dcov = np.nanmax(dx[..., :2]), np.nanmax(dx[..., 2:]), np.nanmax(dP)
        agree = nan_mismatch == 0 and dpos <= args.tolerance and dvel <= args.tolerance
        failed |= not agree
        print(f"  model: T = {T:g} s, σ_v = {design.sigma_v:g} m/s², σ_r = {design.sigma_range_m:g} m, "
              f"σ_θ = {np.rad2deg(design.sigma_bearing_rad):g}°; max |Q_filterpy − Q_ours| = {q_diff:.1e}")
        print(f"  agreement over {n_runs}×{n_sc - 1} estimates: max |Δpos| = {dpos:.2e} m, "
              f"max |Δvel| = {dvel:.2e} m/s, max |ΔP| = {dcov:.2e}  -> "
              f"{'AGREE' if agree else 'DISAGREE'} (tol {args.tolerance:g})")
        per_ours, per_fp = ours_s / steps * 1e6, fp_s / steps * 1e6
        speedup = fp_s / ours_s
        print(f"  track_plots 'kalman' (one vectorised call)  {fmt_s(ours_s)}   {per_ours:7.3f} µs/run-step   "
              f"{spread(ours_all, 1e6 / steps, 3)} [median [min–max] of {len(ours_all)}]")
        print(f"  FilterPy KalmanFilter (per-run loop)        {fmt_s(fp_s)}   {per_fp:7.3f} µs/run-step   "
              f"{spread(fp_all, 1e6 / steps, 3)} [median [min–max] of {len(fp_all)}]")
        ok = speedup >= SPEEDUP_TARGET
        print(f"  speed-up                                    {speedup:9.1f} ×    target ≥ {SPEEDUP_TARGET:.0f} ×  "
              f"-> {'PASS' if ok else 'MISS'}")
        flops, bandwidth = machine_floor()
        floor_ns = 1e9 * max(KALMAN_FLOPS_PER_STEP / flops, KALMAN_BYTES_PER_STEP / bandwidth)
        above = per_ours * 1e3 / floor_ns
        floor_ok = above <= FLOOR_TARGET
        print(f"  floor: {KALMAN_FLOPS_PER_STEP} flops and {KALMAN_BYTES_PER_STEP} bytes per run-step; one core "
              f"{flops / 1e9:.1f} GFlop/s (dgemm), {bandwidth / 1e9:.1f} GB/s (copy) -> {floor_ns:.1f} ns")
        print(f"  ours {per_ours * 1e3:.0f} ns per run-step = {above:.1f} × the floor   target ≤ {FLOOR_TARGET:.0f} ×  "
              f"-> {'PASS' if floor_ok else 'MISS'}")
        print(f"  (run-step = one run × one filtered scan, {steps} in all; FilterPy time excludes the "
              f"vectorised measurement conversion)")

        def all_four():
            return {name: track_plots(rng, brg, counts, times, design, s) for name, s in STRATEGIES.items()}

        four_s, four_all, _ = timed(all_four, max(5, rep))
        print(f"  all four strategies ({', '.join(STRATEGIES)})  {fmt_s(four_s)}   "
              f"{four_s / steps * 1e6:7.3f} µs/run-step   [median of {len(four_all)}]")
        summary += [
            ("2 filter", "max |Δstate| vs FilterPy", f"{max(dpos, dvel):.1e}", f"≤ {args.tolerance:g}",
             "PASS" if agree else "FAIL"),
            ("2 filter", "ours 'kalman' per run-step", f"{per_ours:.3f} µs", "", ""),
            ("2 filter", "FilterPy per run-step", f"{per_fp:.3f} µs", "", ""),
            ("2 filter", "speed-up", f"{speedup:.1f} ×", f"≥ {SPEEDUP_TARGET:.0f} ×", "PASS" if ok else "MISS"),
            ("2 filter", "above the machine's floor", f"{above:.1f} ×", f"≤ {FLOOR_TARGET:.0f} ×",
             "PASS" if floor_ok else "MISS"),
            ("2 filter", "all four strategies", f"{four_s * 1e3:.0f} ms", "", ""),
        ]

        # ------------------------------------------------------------------ figure 3
        heading(f"[3] MCAP I/O throughput ({n_msgs} messages, {size_mb:.2f} MB on disk, zstd)")
        rec_path = tmp / "rec.mcap"
        rec_s, rec_all, _ = timed(lambda: record(rec_path, scenario, args.runs, args.seed), rep)
        sim = simulator_for(scenario.recorder)(params, args.runs, args.seed)
        meta = scenario_metadata(scenario.name, params, args.seed)
        wr_s, wr_all, _ = timed(lambda: write_simulated(rec_path, sim, meta), rep)
        rd_s, rd_all, rd = timed(lambda: read_dataset(data_path), rep)
        n_read = sum(len(ch.run) for ch in rd.channels.values())
        if n_read != n_msgs:
            print(f"  note: read {n_read} (run, scan) entries vs {n_msgs} messages written")
        rows = [("record(...)  simulate+write", rec_s, n_msgs),
                ("  of which write_simulated", wr_s, n_msgs),
                ("read_dataset(...)", rd_s, n_read)]
        for label, s, n in rows:
            print(f"  {label:<30}{fmt_s(s)}   {size_mb / s:7.2f} MB/s   {n / s:10,.0f} msg/s")
        summary += [
            ("3 MCAP", "record (sim+write)", f"{size_mb / rec_s:.2f} MB/s, {n_msgs / rec_s:,.0f} msg/s", "", ""),
            ("3 MCAP", "read_dataset", f"{size_mb / rd_s:.2f} MB/s, {n_read / rd_s:,.0f} msg/s", "", ""),
        ]

    # ---------------------------------------------------------------------- summary
    heading("Summary")
    w = [max(len(r[i]) for r in summary) for i in range(5)]
    hdr = ("figure", "quantity", "value", "target", "")
    w = [max(a, len(b)) for a, b in zip(w, hdr)]
    line = lambda r: "  " + "  ".join(c.ljust(n) for c, n in zip(r, w)).rstrip()
    print(line(hdr))
    print("  " + "  ".join("-" * n for n in w).rstrip())
    for r in summary:
        print(line(r))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
