"""IMM benchmark (Kwon 1997 experiment): our vectorised IMM vs FilterPy, and SRIF vs KF per step.

What it measures
----------------
1. **The thesis's IMM experiment, whole Monte Carlo.** ``colored-imm`` (1-D manoeuvre, AR(1)
   coloured noise, R = 100 m²) with ``--runs`` runs (default 50) × 1200 scans is simulated once
   (not timed). The standard IMM (one 2-state CV, two 3-state CA models, the thesis's transition
   matrix, Kalman filters, plain measurements) runs over all runs in one pass of
   :func:`pipeline.cores.filters.imm.imm_filter`. FilterPy's ``IMMEstimator`` needs equal state sizes, so it
   gets three 3-state ``KalmanFilter`` objects, the CV model written as a 3-state model whose
   acceleration row and column of Φ are zero and whose process noise puts the CV model's q on the
   acceleration: exactly the mixing rule of :mod:`pipeline.cores.filters.imm`, so both compute the same
   numbers. FilterPy is stepped run by run, scan by scan (``predict(); update(z)``), on the same
   measurements with the same initial state, P₀, models and transition matrix. Printed: wall
   time of each for the whole Monte Carlo, time per run-step, the speed-up (target ≥ 30×) and
   the largest difference between the two combined state estimates (and model probabilities).
2. **The three IMMs of the thesis** (IMM, MIMM_K, PIMM) on the same data, wall time each.
3. **SRIF vs KF cost per step** in our implementation, same CA model, all runs at once:
   the SRIF carrying its factors (``pipeline.cores.filters.srif.srif_filter``: two QRs and the moments) vs the
   Kalman filter (``kf_predict`` + ``kf_update`` + ``gaussian_log_likelihood``), and the same two
   as IMM model strategies (the SRIF then also converts the mixed moments to factors). Printed
   as time per run-step and the ratio SRIF / KF.

Times are medians over ``--repeats`` repetitions (FilterPy: ``--peer-repeats``, default 1,
since one pass takes tens of seconds), from ``time.perf_counter``.

How to run
----------
From the repository root with the package and FilterPy installed (``pip install -e ".[peers]"``)::

    python benchmarks/bench_imm.py               # 50 runs, the thesis's experiment
    python benchmarks/bench_imm.py --runs 10 --repeats 5

Exit status 1 if FilterPy and our IMM disagree by more than ``--tolerance`` (default 1e-6 m),
else 0; a missed speed target is reported, not fatal.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time

import numpy as np

from pipeline.cores.filters.imm import MeasurementStream, ModelFilter, imm_filter, kinematic_model, single_model_filter
from pipeline.cores.filters.kalman import gaussian_log_likelihood, kf_predict, kf_update
from pipeline.cores.filters.srif import srif_filter
from pipeline.trackers.colored_noise import parse_matrix
from recorders.colored_noise import simulate
from recorders.scenarios import load_scenario

from timing import timed  # noqa: E402

SPEEDUP_TARGET = 30.0


def filterpy_imm(z, x0, P0, p, transition):
    """FilterPy's IMMEstimator, run by run; returns combined states and model probabilities."""
    from filterpy.kalman import IMMEstimator, KalmanFilter

    T = p["sample_period_s"]
    F3 = np.array([[1.0, T, T * T / 2], [0.0, 1.0, T], [0.0, 0.0, 1.0]])
    Fcv = np.array([[1.0, T, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 0.0]])
    gcv = np.array([[T * T / 2], [T], [0.0]])
    gca = np.array([[T**3 / 6], [T * T / 2], [T]])
    Qcv = p["cv_process_noise"] * gcv @ gcv.T
    Qcv[2, 2] = p["cv_process_noise"]
    models = [(Fcv, Qcv), (F3, p["ca_transition_process_noise"] * gca @ gca.T),
              (F3, p["ca_steady_process_noise"] * gca @ gca.T)]
    H = np.array([[1.0, 0.0, 0.0]])
    R = np.array([[p["measurement_variance_m2"]]])
    runs, scans, _ = z.shape
    states = np.full((runs, scans, 3), np.nan)
    mus = np.full((runs, scans, 3), np.nan)
    for r in range(runs):
        filters = []
        for F, Q in models:
            kf = KalmanFilter(dim_x=3, dim_z=1)
            kf.F, kf.Q, kf.H, kf.R = F, Q, H, R
            kf.x = x0[r].reshape(3, 1).copy()
            kf.P = P0.copy()
            filters.append(kf)
        imm = IMMEstimator(filters, np.full(3, 1.0 / 3.0), transition)
        states[r, 0], mus[r, 0] = x0[r], imm.mu
        for k in range(1, scans):
            imm.predict()
            imm.update(z[r, k])
            states[r, k] = imm.x[:, 0]
            mus[r, k] = imm.mu
    return states, mus


def kf_core(x0, P0, model, z, R):
    x, P = x0.copy(), np.broadcast_to(P0, (x0.shape[0],) + P0.shape).copy()
    for k in range(1, z.shape[1]):
        x, P = kf_predict(x, P, model.F, model.Q)
        x, P, nu, S, _ = kf_update(x, P, z[:, k], model.H, R)
        gaussian_log_likelihood(nu, S)
    return x


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=50)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--peer-repeats", type=int, default=1)
    ap.add_argument("--tolerance", type=float, default=1e-6)
    args = ap.parse_args(argv)

    sc = load_scenario("colored-imm")
    p = sc.params
    data = simulate(p, args.runs, args.seed)
    z = data.fixed["/colored/measurements"]["position_m"]
    truth = data.fixed["/colored/truth"]["state"]
    runs, scans, _ = z.shape
    T = p["sample_period_s"]
    transition = parse_matrix(p["imm_transition"], "imm_transition")
    x0 = truth[:, 0].copy()
    P0 = p["initial_variance"] * np.eye(3)
    R = np.array([[p["measurement_variance_m2"]]])
    models = [kinematic_model("cv", 2, T, p["cv_process_noise"]),
              kinematic_model("ca_transition", 3, T, p["ca_transition_process_noise"]),
              kinematic_model("ca_steady", 3, T, p["ca_steady_process_noise"])]
    plain = MeasurementStream(z, R)
    steps = runs * (scans - 1)
    print(f"bench_imm: {runs} runs × {scans} scans × 3 models (colored-imm, seed {args.seed}); "
          f"python {platform.python_version()}, numpy {np.__version__}, {os.cpu_count()} CPUs")

    # 1. our IMM vs FilterPy
    ours_s, ours = timed(lambda: imm_filter([ModelFilter(m) for m in models], transition, x0, P0, plain), args.repeats)
    try:
        import filterpy  # noqa: F401
    except ModuleNotFoundError:
        print("FilterPy is not installed: pip install -e '.[peers]'")
        return 1
    peer_s, (fp_states, fp_mus) = timed(lambda: filterpy_imm(z, x0, P0, p, transition), args.peer_repeats)
    dx = float(np.max(np.abs(fp_states[:, 1:] - ours["state"][:, 1:])))
    dmu = float(np.max(np.abs(fp_mus[:, 1:] - ours["model_probabilities"][:, 1:])))
    speedup = peer_s / ours_s
    print("\n1. The thesis's IMM experiment (whole Monte Carlo)")
    print(f"   {'':34s} {'wall':>10s} {'per run-step':>14s}")
    print(f"   {'ours: pipeline.cores.filters.imm.imm_filter':34s} {ours_s:9.3f}s {ours_s / steps * 1e6:11.1f} µs")
    print(f"   {'FilterPy IMMEstimator (3-state)':34s} {peer_s:9.3f}s {peer_s / steps * 1e6:11.1f} µs")
    print(f"   speed-up {speedup:.1f}× (target ≥ {SPEEDUP_TARGET:.0f}×: {'met' if speedup >= SPEEDUP_TARGET else 'MISSED'})")
    print(f"   largest difference: state {dx:.3g} (m, m/s, m/s²), model probability {dmu:.3g}")

    # 2. the three IMMs
    from pipeline.cores.filters.ar1_estimation import estimate_ar1

    t0 = time.perf_counter()
    ar = estimate_ar1(z, p["ar_forgetting_factor"], p["ar_zero_pole"])
    ar_s = time.perf_counter() - t0
    warm = ar.warm[None, :, None]
    dec = MeasurementStream(z, R, True, np.where(warm, ar.alpha, np.nan), np.where(warm, ar.noise_variance, np.nan))
    mimm_s, _ = timed(lambda: imm_filter([ModelFilter(m) for m in models], transition, x0, P0, dec), args.repeats)
    pimm_s, _ = timed(lambda: imm_filter([ModelFilter(m, "srif") for m in models], transition, x0, P0, dec), args.repeats)
    print("\n2. The thesis's three IMMs on the same data (wall, whole Monte Carlo)")
    print(f"   AR estimator {ar_s * 1e3:.1f} ms | IMM {ours_s:.3f} s | MIMM_K {mimm_s:.3f} s | PIMM {pimm_s:.3f} s")

    # 3. SRIF vs KF per step
    ca = models[2]
    kf_s, _ = timed(lambda: kf_core(x0, P0, ca, z, R), args.repeats)
    sr_s, _ = timed(lambda: srif_filter(x0, P0, ca.F, ca.G, ca.q, ca.H, z, R), args.repeats)
    kf_m, _ = timed(lambda: single_model_filter(ModelFilter(ca), x0, P0, plain), args.repeats)
    sr_m, _ = timed(lambda: single_model_filter(ModelFilter(ca, "srif"), x0, P0, plain), args.repeats)
    print("\n3. SRIF vs KF, one 3-state CA model, all runs per call (time per run-step)")
    print(f"   {'':40s} {'KF':>10s} {'SRIF':>10s} {'SRIF/KF':>8s}")
    print(f"   {'filter cores (SRIF carries its factors)':40s} {kf_s / steps * 1e6:8.2f}µs {sr_s / steps * 1e6:8.2f}µs {sr_s / kf_s:7.2f}×")
    print(f"   {'as IMM model strategies (from moments)':40s} {kf_m / steps * 1e6:8.2f}µs {sr_m / steps * 1e6:8.2f}µs {sr_m / kf_m:7.2f}×")

    print("\nsummary")
    print(f"   IMM Monte Carlo: ours {ours_s:.3f} s vs FilterPy {peer_s:.2f} s -> {speedup:.1f}× ; "
          f"max |Δx| {dx:.2g}; SRIF/KF per step {sr_s / kf_s:.2f}× (cores), {sr_m / kf_m:.2f}× (IMM strategies)")
    if dx > args.tolerance:
        print(f"FAIL: FilterPy and our IMM differ by {dx:.3g} > {args.tolerance}")
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
