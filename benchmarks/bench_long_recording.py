"""One long recording (issue 27): a single Monte Carlo run of many scans, end to end and piece by piece.

What it measures
----------------
Data sets are simulated with ``replay simulate`` (seed 7, one run; not timed) into a work folder:
``radar-tws`` with 10,000 and 100,000 scans and, with ``--multi``, ``radar-multi`` at 50 targets
(``initial_targets_mean=50``, ``birth_rate_per_scan=0.7``: the default's 10 scaled by five) with
``--multi-scans`` scans. Then, side by side in one run, each figure the median [min–max] of
``--repeats``:

1. **Replay, one run.** ``python -m trackreplay.face.cli FILE --no-rrd --figures none -v`` in a fresh
   process, the four built-in radar trackers: wall time (target ≤ 10 s at 100,000 scans), the
   replay's own breakdown (read, filter, evaluate, write; ``-v``), and the growth exponent
   ``log(t₁₀₀ₖ / t₁₀ₖ) / log 10`` of the median wall times (target ≤ 1.02). The 10,000 and 100,000
   replays alternate, so both see the same load.
2. **Radar Kalman tracker against FilterPy.** ``track_plots`` with the ``kalman`` strategy on the
   100,000-scan run, against FilterPy's ``KalmanFilter`` stepped scan by scan on the same
   converted plots (``bench_radar.filterpy_loop``, which also checks they agree): time per scan
   and the ratio (target ≥ 1×). Beside it the run axis: the same on a 500-run, 64-scan data set
   (target ≥ 40×).
3. **Reading the one-run recording.** ``read_dataset`` of the 100,000-scan file against the zstd
   floor, decompressing the same file's chunks from memory (``bench_read.compressed_chunks``;
   target within 10×).
4. **Gauss-Newton, one run.** ``gauss_newton`` called on one run at a time against scipy
   ``least_squares`` with ``lm`` and with ``trf`` on ``bench_tdoa``'s data (target ≥ 1× both);
   with ``--no-gn`` it is left out.
5. **Many targets** (``--multi``): the one-run replay of the 50-target scenario (the family's
   multi-target trackers, ``gnn`` and ``jpda_mt``), measured only (``--multi-repeats``, default 1:
   one replay of 100,000 scans of 50 targets took 23 minutes and 10 GB on a loaded machine).

The machine's load (``os.getloadavg``) is printed before and after: on 2 shared cores timings
move with it.

How to run
----------
From the repository root::

    python benchmarks/bench_long_recording.py --repeats 5
    python benchmarks/bench_long_recording.py --repeats 5 --multi --multi-scans 100000
    python benchmarks/bench_long_recording.py --scans 20000 --repeats 3 --no-gn   # quicker
"""

from __future__ import annotations

import argparse
import math
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))  # this tree's package, installed or not (the replays run from REPO too)

from timing import print_table, spread  # noqa: E402  benchmarks/ is on sys.path when run as a script
WALL_TARGET_S = 10.0
GROWTH_TARGET = 1.02
FILTERPY_ONE_RUN_TARGET = 1.0
FILTERPY_RUN_AXIS_TARGET = 40.0
READ_FLOOR_TARGET = 10.0
MULTI_SETTINGS = ("initial_targets_mean=50", "birth_rate_per_scan=0.7")


def load() -> str:
    one, five, fifteen = os.getloadavg()
    return f"load average {one:.2f}, {five:.2f}, {fifteen:.2f} on {os.cpu_count()} cores"


def median(values) -> float:
    return float(np.median(values))


def simulate(scenario: str, runs: int, scans: int, out: Path, settings=()) -> Path:
    if not out.exists():
        args = [sys.executable, "-m", "trackreplay.face.cli", "simulate", scenario, "--runs", str(runs), "--seed", "7",
                "--set", f"n_scans={scans}", "-o", str(out)]
        for s in settings:
            args += ["--set", s]
        subprocess.run(args, check=True, capture_output=True, cwd=REPO)
    return out


TIMING = re.compile(r"timing: (read|filter|evaluate|write) ([0-9.]+) s")


def replay_once(data: Path, out: Path) -> tuple[float, dict]:
    """(wall seconds, {phase: seconds}) of one ``replay --no-rrd -v`` in a fresh process."""
    args = [sys.executable, "-m", "trackreplay.face.cli", str(data), "--out", str(out / "tracks.mcap"), "--force",
            "--figures", "none", "--no-rrd", "-v"]
    t0 = time.perf_counter()
    done = subprocess.run(args, cwd=REPO, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if done.returncode:
        raise SystemExit(f"replay {data.name} failed: {done.stderr[-400:]}")
    return wall, {m.group(1): float(m.group(2)) for m in TIMING.finditer(done.stderr)}


def bench_replays(files: dict, work: Path, repeats: int) -> dict:
    walls = {name: [] for name in files}
    phases = {name: [] for name in files}
    for _ in range(repeats):  # interleaved: every data set sees the same load
        for name, path in files.items():
            wall, parts = replay_once(path, work / f"out-{name}")
            walls[name].append(wall)
            phases[name].append(parts)
    return {name: (walls[name], phases[name]) for name in files}


def phase_spread(parts: list, phase: str) -> str:
    values = [p.get(phase, math.nan) for p in parts]
    return spread(values, 1.0, 2, "s")


def bench_filterpy(data: Path, repeats: int) -> dict:
    """Kalman track_plots against FilterPy on the runs of ``data``: (ours s, FilterPy s, scans, agree)."""
    from bench_radar import design_from, filterpy_loop
    from filterpy.common import Q_discrete_white_noise

    from trackreplay.contract import read_dataset
    from trackreplay.cores.filters.converted_measurements import converted_covariance, polar_to_cartesian
    from trackreplay.cores.filters.kalman import white_acceleration_model
    from trackreplay.stages.radar import RadarStage
    from trackreplay.trackers.radar_tws import STRATEGIES, track_plots
    from trackreplay.recorders.scenarios import load_scenario

    ds = read_dataset(data)
    rng, brg, counts, times = RadarStage().decode_plots(ds)
    design = design_from({**load_scenario("radar-tws").params, **ds.scenario.get("params", {})})
    T = design.scan_period_s
    z = polar_to_cartesian(rng[..., 0], brg[..., 0])
    R = converted_covariance(rng[..., 0], brg[..., 0], design.sigma_range_m, design.sigma_bearing_rad)
    F, _ = white_acceleration_model(T, design.sigma_v)
    Q = Q_discrete_white_noise(dim=2, dt=T, var=design.sigma_v**2, block_size=2, order_by_dim=False)
    H = np.hstack([np.eye(2), np.zeros((2, 2))])
    ours, theirs = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = track_plots(rng, brg, counts, times, design, STRATEGIES["kalman"])
        ours.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        fp_state, _ = filterpy_loop(z, R, T, F, Q, H)
        theirs.append(time.perf_counter() - t0)
    # FilterPy takes the converted covariance as it is; ours floors a plot's along-range variance
    # where it falls below 10⁻⁶ of the cross-range one (FLOORED: beyond ~5,700 km at σ_r = 100 m,
    # σ_θ = 1°, which a 100,000-scan flight reaches), so the two agree up to the first such scan
    from trackreplay.vocabulary import FLOORED

    floored = np.cumsum((out["flags"] & FLOORED) > 0, axis=1) > 0
    same = ~floored
    same[:, 0] = False
    d = np.nanmax(np.abs(fp_state - out["state"])[same])
    steps = counts.shape[0] * (counts.shape[1] - 2)
    return {"ours": ours, "theirs": theirs, "steps": steps, "max_diff": float(d), "compared": int(same.sum())}


def bench_read_floor(data: Path, repeats: int) -> dict:
    import zstandard
    from bench_read import compressed_chunks

    from trackreplay.contract import read_dataset

    chunks = compressed_chunks(data)
    reads, floors = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        read_dataset(data)
        reads.append(time.perf_counter() - t0)
        d = zstandard.ZstdDecompressor()
        t0 = time.perf_counter()
        for raw, size in chunks:
            d.decompress(raw, max_output_size=size)
        floors.append(time.perf_counter() - t0)
    return {"read": reads, "floor": floors, "chunks": len(chunks), "mb": data.stat().st_size / 1e6}


GN_TARGET = 1.0


def bench_gn_one_run(n_runs: int, repeats: int) -> dict:
    """Our Gauss-Newton and scipy ``least_squares`` (``lm``, ``trf``) called on one run at a time
    (runs 0 … n_runs − 1 in turn, the three alternated in every repeat), on ``bench_tdoa``'s data
    (line geometry, emitter 1, a start 1 % off): seconds per call, and the largest difference
    from ours in standard deviations of the measurements (``bench_tdoa.whitened``)."""
    from bench_tdoa import gn_data, whitened
    from scipy import optimize

    from trackreplay.cores.localisation.gauss_newton import gauss_newton
    from trackreplay.cores.localisation.tdoa_fdoa_model import measurement_model

    es, u, _ = gn_data(n_runs, 11, geometry="line", emitter=1, initial_relative_mse=1e-4)
    theta0 = es.emitter[0] + 0.01 * np.abs(es.emitter[0]) * np.random.default_rng(12).standard_normal((n_runs, 4))
    sp, sv, sigma = es.sensor_pos[0], es.sensor_vel[0], es.sigma[0]

    def model(th):
        return measurement_model(th, sp, sv, es.pairs, es.carrier_hz)

    def scipy_one(r, method):
        def resid(th):
            return (u[r] - measurement_model(th[None], sp, sv, es.pairs, es.carrier_hz, jacobian=False)[0]) / sigma

        def jac(th):
            return -measurement_model(th[None], sp, sv, es.pairs, es.carrier_hz)[1][0] / sigma[:, None]

        return optimize.least_squares(resid, theta0[r], jac=jac, method=method, x_scale="jac").x

    times = {"ours": [], "lm": [], "trf": []}
    found = {}
    for _ in range(repeats):
        t0 = time.perf_counter()
        ours = np.concatenate([gauss_newton(model, theta0[r:r + 1], u[r:r + 1], sigma, iterations=10).theta
                               for r in range(n_runs)])
        times["ours"].append((time.perf_counter() - t0) / n_runs)
        for method in ("lm", "trf"):
            t0 = time.perf_counter()
            found[method] = np.array([scipy_one(r, method) for r in range(n_runs)])
            times[method].append((time.perf_counter() - t0) / n_runs)
    return {**times, "diff": {m: float(whitened(es, found[m] - ours).max()) for m in ("lm", "trf")}}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--scans", type=int, default=100_000, help="scans of the long recording (default 100,000)")
    ap.add_argument("--no-gn", action="store_true", help="leave out the Gauss-Newton figures")
    ap.add_argument("--multi", action="store_true", help="also replay the 50-target radar-multi scenario")
    ap.add_argument("--multi-scans", type=int, default=100_000)
    ap.add_argument("--multi-repeats", type=int, default=1)
    ap.add_argument("--keep", help="work folder to keep (default: a temporary one)")
    args = ap.parse_args()
    print(f"before: {load()}")
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(args.keep or tmp)
        work.mkdir(parents=True, exist_ok=True)
        short = args.scans // 10
        files = {f"{short}": simulate("radar-tws", 1, short, work / f"radar-1x{short}.mcap"),
                 f"{args.scans}": simulate("radar-tws", 1, args.scans, work / f"radar-1x{args.scans}.mcap")}
        runs500 = simulate("radar-tws", 500, 64, work / "radar-500x64.mcap")

        print(f"\n1. replay --no-rrd, one run of radar-tws, four trackers; median [min–max] of {args.repeats}, "
              "fresh process each")
        got = bench_replays(files, work, args.repeats)
        rows = []
        for name, (walls, parts) in got.items():
            verdict = ""
            if name == f"{args.scans}" and args.scans == 100_000:
                verdict = "PASS" if median(walls) <= WALL_TARGET_S else "MISS"
            rows.append([f"{int(name):,} scans", spread(walls, 1.0, 2, "s"), phase_spread(parts, "read"),
                         phase_spread(parts, "filter"), phase_spread(parts, "evaluate"),
                         phase_spread(parts, "write"), f"≤ {WALL_TARGET_S:g} s" if verdict else "", verdict])
        print_table(["recording", "wall", "read", "filter", "evaluate", "write", "target", ""], rows)
        (w_short, _), (w_long, _) = got[f"{short}"], got[f"{args.scans}"]
        growth = math.log(median(w_long) / median(w_short)) / math.log(args.scans / short)
        print(f"growth exponent {short:,} → {args.scans:,} scans (medians): {growth:.3f}   target ≤ {GROWTH_TARGET} "
              f"-> {'PASS' if growth <= GROWTH_TARGET else 'MISS'}")

        print(f"\n2. radar Kalman tracker (track_plots 'kalman') against FilterPy KalmanFilter; median [min–max] "
              f"of {args.repeats}")
        rows = []
        for label, data, target in ((f"1 run × {args.scans:,} scans", files[f"{args.scans}"], FILTERPY_ONE_RUN_TARGET),
                                    ("500 runs × 64 scans", runs500, FILTERPY_RUN_AXIS_TARGET)):
            fp = bench_filterpy(data, args.repeats)
            ratio = median(fp["theirs"]) / median(fp["ours"])
            rows.append([label, spread(fp["ours"], 1e6 / fp["steps"], 3, "µs"),
                         spread(fp["theirs"], 1e6 / fp["steps"], 3, "µs"), f"{ratio:.2f}×", f"≥ {target:g}×",
                         f"{fp['max_diff']:.1e} m over {fp['compared']:,}", "PASS" if ratio >= target else "MISS"])
        print_table(["data set", "ours per run-scan", "FilterPy per run-scan", "ratio", "target",
                     "max |Δstate| (scans before any FLOORED)", ""], rows)

        print(f"\n3. reading the one-run recording (read_dataset) against its zstd floor; median [min–max] of "
              f"{args.repeats}")
        rd = bench_read_floor(files[f"{args.scans}"], args.repeats)
        times_floor = median(rd["read"]) / median(rd["floor"])
        print_table(["file", "MB", "chunks", "read", "zstd floor", "read / floor", "target", ""],
                    [[files[f"{args.scans}"].name, f"{rd['mb']:.1f}", str(rd["chunks"]), spread(rd["read"], 1.0, 3, "s"),
                      spread(rd["floor"], 1.0, 4, "s"), f"{times_floor:.1f}×", f"≤ {READ_FLOOR_TARGET:g}×",
                      "PASS" if times_floor <= READ_FLOOR_TARGET else "MISS"]])

        if not args.no_gn:
            print(f"\n4. Gauss-Newton, one run per call (20 runs in turn), against scipy least_squares; time per "
                  f"call, median [min–max] of {args.repeats}")
            gn = bench_gn_one_run(20, args.repeats)
            base = median(gn["ours"])
            print_table(["solver", "per call", "ours faster by", "target", "max difference"],
                        [["ours (gauss_newton, tracker defaults)", spread(gn["ours"], 1e6, 1, "µs"), "", "", ""]]
                        + [[f"scipy least_squares {m}", spread(gn[m], 1e6, 1, "µs"), f"{median(gn[m]) / base:.2f}×",
                            f"≥ {GN_TARGET:g}×", f"{gn['diff'][m]:.1e} σ",
                            "PASS" if median(gn[m]) / base >= GN_TARGET else "MISS"] for m in ("lm", "trf")])

        if args.multi:
            multi = simulate("radar-multi", 1, args.multi_scans, work / f"multi-1x{args.multi_scans}.mcap",
                             MULTI_SETTINGS)
            print(f"\n5. replay --no-rrd, one run of radar-multi at 50 targets ({', '.join(MULTI_SETTINGS)}), "
                  f"{args.multi_scans:,} scans; median [min–max] of {args.multi_repeats} (measured, no target)")
            walls, parts = bench_replays({"multi": multi}, work, args.multi_repeats)["multi"]
            print_table(["recording", "wall", "read", "filter", "evaluate", "write"],
                        [[f"{args.multi_scans:,} scans", spread(walls, 1.0, 1, "s"), phase_spread(parts, "read"),
                          phase_spread(parts, "filter"), phase_spread(parts, "evaluate"),
                          phase_spread(parts, "write")]])
    print(f"\nafter: {load()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
