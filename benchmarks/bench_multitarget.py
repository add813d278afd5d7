"""Multi-target radar trackers: our GNN and JPDA against Stone Soup's, side by side (issue 25).

The workload is the ``radar-multi`` scenario (``recorders/radar_multi.py``) with a steady number
of targets: no turns, no deaths but by leaving the region (``survival_probability = 1``), and a
birth rate that replaces the targets flying out (calibrated once from the recorder itself, see
:func:`birth_rate_for`). Radar at the origin, bearing from +x (x = r cos θ, y = r sin θ), region
1–50 km and ±60°, speeds 50–250 m/s, q = 1 m²/s³, T = 1 s, P_D = 0.9, σ_r = 20 m, σ_θ = 0.2°,
Poisson clutter uniform in range and bearing. If the recorder cannot be imported, a small
generator of the same model (:func:`own_generator`, an exact number of targets alive) stands in.

1. 50 targets, 20 clutter a scan, one run: ours (``gnn``, ``jpda_mt``) against Stone Soup's GNN
   (``GNNWith2DAssignment``) and JPDA (``JPDAwithEHM``), built from its own components with the
   same model and gate (EKF on ``CartesianToBearingRange``, CV ×2, ``DistanceHypothesiser`` with
   Mahalanobis distance and missed distance √χ²_gate, ``PDAHypothesiser`` with the clutter
   density per metre and radian, ``MultiMeasurementInitiator`` for 3-of-4-like confirmation,
   ``UpdateTimeStepsDeleter(5)``, ``MultiTargetTracker`` / ``MultiTargetMixtureTracker``). Stone
   Soup's ``Detection`` objects are built before its clock starts. Per scan: median [min–max]
   over the repeats (ours and Stone Soup's interleaved), the ratio of the medians, a "floor"
   (a minimal numpy GNN: batched EKF over fixed tracks, one ``linear_sum_assignment`` a scan, no
   track management), and agreement: confirmed tracks at the end and mean GOSPA (c = 500 m,
   p = 2, α = 2) of each tracker against the truth.
2. Scaling of ours: targets 10/50/200 × clutter 0/20/100, with fitted exponents.
3. The run axis: 100 runs of the 50-target case against one run, time per run-scan.
4. End to end: ``replay --no-rrd`` of 200 targets × 100 clutter × 2,000 scans in a fresh
   process: wall time and peak memory (target < 20 s, < 2 GB); when it misses, a cProfile of a
   shorter replay says where the time goes.

Run: ``pip install ".[peers]" && PYTHONPATH=. python benchmarks/bench_multitarget.py``
(``--quick``: a smoke run of every section in about a minute; ``--section 1`` …; ``--scans``,
``--peer-scans``, ``--repeats``; ``--profile``: cProfile of ours per scan).
"""

from __future__ import annotations

import argparse
import cProfile
import datetime
import io
import os
import pstats
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from trackreplay.evaluators.set_distances import gospa  # noqa: E402
from trackreplay import vocabulary as vocab  # noqa: E402
from trackreplay.trackers.interface import RadarPlots  # noqa: E402
from trackreplay.trackers.radar_multi_target import GnnTracker, JpdaTracker  # noqa: E402
from timing import print_table, spread  # noqa: E402

E2E_TARGET_S, E2E_TARGET_MB = 20.0, 2000.0
GOSPA_C, GOSPA_P = 500.0, 2.0
MB = 1e6

#: the benchmark's scenario values (the recorder's names); targets and clutter vary per case
BASE = dict(scan_period_s=1.0, min_range_m=1000.0, max_range_m=50000.0, sector_half_width_deg=60.0,
            survival_probability=1.0, min_speed_mps=50.0, max_speed_mps=250.0, process_noise_m2ps3=1.0,
            turning_fraction=0.0, max_turn_rate_degps=0.0, detection_probability=0.9, sigma_range_m=20.0,
            sigma_bearing_deg=0.2)
#: our trackers' design (the brief's values; clutter_per_scan set per case)
DESIGN = dict(sigma_range_m=20.0, sigma_bearing_deg=0.2, process_noise_m2ps3=1.0, detection_probability=0.9,
              min_range_m=1000.0, max_range_m=50000.0, sector_half_width_deg=60.0,
              association_gate_probability=0.9997, initial_speed_sigma_mps=150.0, confirm_hits=3,
              confirm_window=4, max_coasted_scans=5)
OURS = {"gnn": GnnTracker, "jpda_mt": JpdaTracker}


# --------------------------------------------------------------------------- data


def _recorder():
    try:
        from trackreplay.recorders import radar_multi
        from trackreplay.recorders.scenarios import load_scenario

        load_scenario("radar-multi")
        return radar_multi
    except Exception as exc:  # the recorder is not there (yet): the benchmark's own generator
        print(f"   (recorders/radar_multi.py not usable: {exc!r}; using the benchmark's own generator)")
        return None


RECORDER = None
_BIRTH_CACHE: dict = {}


def scenario_params(targets: float, clutter: float, scans: int) -> dict:
    """``load_scenario('radar-multi').params`` with the benchmark's values."""
    from trackreplay.recorders.scenarios import load_scenario

    p = dict(load_scenario("radar-multi").params)
    p.update(BASE, n_scans=int(scans), initial_targets_mean=float(targets), clutter_per_scan=float(clutter))
    p["birth_rate_per_scan"] = birth_rate_for(p, targets)
    return p


def birth_rate_for(p: dict, targets: float) -> float:
    """Births a scan that keep ``targets`` alive on average: targets / mean lifetime, the mean
    lifetime (scans until a target born uniformly over the area flies out) measured once on 4,000
    targets of the recorder itself."""
    if "life" not in _BIRTH_CACHE:
        q = dict(p, initial_targets_mean=4000.0, birth_rate_per_scan=0.0, n_scans=3000, clutter_per_scan=0.0)
        _, counts = RECORDER.simulate(q, 1, 12345).ragged[vocab.CHANNELS["radar_truth"]]
        _BIRTH_CACHE["life"] = counts.sum() / counts[0, 0]
    return float(targets / _BIRTH_CACHE["life"])


def own_generator(p: dict, runs: int, seed: int) -> dict:
    """The same model without the recorder: exactly ``initial_targets_mean`` targets alive, one
    that leaves the region replaced by a newborn uniform over its area."""
    rng = np.random.default_rng(seed)
    R, K, N = runs, int(p["n_scans"]), int(round(p["initial_targets_mean"]))
    T, q = p["scan_period_s"], p["process_noise_m2ps3"]
    lo, hi, half = p["min_range_m"], p["max_range_m"], np.deg2rad(p["sector_half_width_deg"])

    def born(n):
        r = np.sqrt(lo**2 + rng.random(n) * (hi**2 - lo**2))
        th = half * (2 * rng.random(n) - 1)
        sp = rng.uniform(p["min_speed_mps"], p["max_speed_mps"], n)
        hd = rng.uniform(0, 2 * np.pi, n)
        return np.stack([r * np.cos(th), r * np.sin(th), sp * np.cos(hd), sp * np.sin(hd)], -1)

    F = np.kron(np.array([[1, T], [0, 1]]), np.eye(2))
    Lq = np.linalg.cholesky(np.kron(q * np.array([[T**3 / 3, T**2 / 2], [T**2 / 2, T]]), np.eye(2)))
    x = born(R * N).reshape(R, N, 4)
    ids = np.tile(np.arange(N), (R, 1))
    nxt = np.full(R, N)
    truth = np.empty((R, K, N, 4))
    tid = np.empty((R, K, N), np.int64)
    rng_lists, brg_lists, org_lists = [], [], []
    for k in range(K):
        if k:
            x = x @ F.T + rng.standard_normal((R, N, 4)) @ Lq.T
            r = np.hypot(x[..., 0], x[..., 1])
            out = (r < lo) | (r > hi) | (np.abs(np.arctan2(x[..., 1], x[..., 0])) > half)
            if out.any():
                x[out] = born(int(out.sum()))
                rr, _ = np.nonzero(out)
                ids[out] = nxt[rr] + (np.cumsum(out, axis=1)[out] - 1)
                nxt += out.sum(axis=1)
        truth[:, k], tid[:, k] = x, ids
        det = rng.random((R, N)) < p["detection_probability"]
        rr = np.hypot(x[..., 0], x[..., 1]) + p["sigma_range_m"] * rng.standard_normal((R, N))
        bb = np.arctan2(x[..., 1], x[..., 0]) + np.deg2rad(p["sigma_bearing_deg"]) * rng.standard_normal((R, N))
        nc = rng.poisson(p["clutter_per_scan"], R)
        for run in range(R):
            cr = rng.uniform(lo, hi, nc[run])
            cb = rng.uniform(-half, half, nc[run])
            perm = rng.permutation(det[run].sum() + nc[run])
            rng_lists.append(np.r_[rr[run][det[run]], cr][perm])
            brg_lists.append(np.r_[bb[run][det[run]], cb][perm])
            org_lists.append(np.r_[ids[run][det[run]], np.full(nc[run], -1)][perm])
    counts = np.array([a.size for a in rng_lists]).reshape(K, R).T
    W = int(counts.max())
    rg, bg = np.full((K, R, W), np.nan), np.full((K, R, W), np.nan)
    for i, (a, b) in enumerate(zip(rng_lists, brg_lists)):
        rg[i // R, i % R, : a.size], bg[i // R, i % R, : b.size] = a, b
    return {"range_m": rg.transpose(1, 0, 2), "bearing_rad": bg.transpose(1, 0, 2), "counts": counts,
            "times": np.arange(K) * T, "truth_xy": truth[..., :2]}


def make_data(targets, clutter, scans, runs=1, seed=1) -> dict:
    """Plots (R, K, W), counts (R, K), times (K,) and truth positions (R, K, n, 2) NaN-padded."""
    if RECORDER is None:
        p = dict(BASE, n_scans=scans, initial_targets_mean=targets, clutter_per_scan=clutter)
        d = own_generator(p, runs, seed)
    else:
        p = scenario_params(targets, clutter, scans)
        sim = RECORDER.simulate(p, runs, seed)
        plots, counts = sim.ragged[vocab.CHANNELS["radar_plots"]]
        truth, tcounts = sim.ragged[vocab.CHANNELS["radar_truth"]]
        d = {"range_m": plots["range_m"], "bearing_rad": plots["bearing_rad"], "counts": counts,
             "times": np.asarray(sim.times, float), "truth_xy": truth["state"][..., :2],
             "truth_counts": tcounts}
    d["params"] = p
    tc = d.get("truth_counts")
    if tc is None:
        tc = np.isfinite(d["truth_xy"][..., 0]).sum(-1)
    d["alive"] = tc
    return d


def plots_of(d: dict, scans: int | None = None) -> RadarPlots:
    K = scans or d["counts"].shape[1]
    return RadarPlots(range_m=d["range_m"][:, :K], bearing_rad=d["bearing_rad"][:, :K], counts=d["counts"][:, :K],
                      times_s=d["times"][:K])


def ours(name: str, clutter: float):
    """Our tracker with the benchmark's design (q = 1 m²/s³, the targets' own: they do not turn)."""
    cls = OURS[name]
    names = {p.name for p in cls.params}
    design = dict(DESIGN, clutter_per_scan=float(clutter))
    if "process_noise_m2ps3" not in names and "design_process_noise_m2ps3" in names:
        design["design_process_noise_m2ps3"] = design.pop("process_noise_m2ps3")
    return cls(**design)


def confirmed_xy(out: dict) -> np.ndarray:
    """Positions (R, K, S, 2) of confirmed tracks (coasted included), NaN elsewhere."""
    f = out["flags"]
    ok = (f & (vocab.NO_TRACK | vocab.INITIALISING | vocab.DELETED)) == 0
    return np.where(ok[..., None], out["state"][..., :2], np.nan)


# --------------------------------------------------------------------------- Stone Soup


def stonesoup_detections(d: dict, scans: int):
    """Stone Soup's detections of run 0, one set per scan (built before any timing)."""
    from stonesoup.models.measurement.nonlinear import CartesianToBearingRange
    from stonesoup.types.angle import Bearing
    from stonesoup.types.array import StateVector
    from stonesoup.types.detection import Detection

    p = d["params"]
    mm = CartesianToBearingRange(ndim_state=4, mapping=(0, 2), translation_offset=StateVector([0.0, 0.0]),
                                 noise_covar=np.diag([np.deg2rad(p["sigma_bearing_deg"]) ** 2,
                                                      p["sigma_range_m"] ** 2]))
    start = datetime.datetime(2026, 1, 1)
    scans_out = []
    for k in range(scans):
        ts = start + datetime.timedelta(seconds=float(d["times"][k]))
        n = int(d["counts"][0, k])
        # Stone Soup's measurement is [bearing, range] (bearing from +x, counter-clockwise, as ours)
        dets = {Detection(StateVector([Bearing(b), r]), timestamp=ts, measurement_model=mm)
                for r, b in zip(d["range_m"][0, k, :n], d["bearing_rad"][0, k, :n])}
        scans_out.append((ts, dets))
    return mm, scans_out


def stonesoup_tracker(kind: str, mm, clutter: float, p: dict):
    """Stone Soup's GNN or JPDA-EHM tracker from its own components, our model and gate."""
    from stonesoup.dataassociator.neighbour import GNNWith2DAssignment
    from stonesoup.dataassociator.probability import JPDAwithEHM
    from stonesoup.deleter.time import UpdateTimeStepsDeleter
    from stonesoup.hypothesiser.distance import DistanceHypothesiser
    from stonesoup.hypothesiser.probability import PDAHypothesiser
    from stonesoup.initiator.simple import MultiMeasurementInitiator
    from stonesoup.measures import Mahalanobis
    from stonesoup.models.transition.linear import CombinedLinearGaussianTransitionModel, ConstantVelocity
    from stonesoup.predictor.kalman import ExtendedKalmanPredictor
    from stonesoup.tracker.simple import MultiTargetMixtureTracker, MultiTargetTracker
    from stonesoup.types.state import GaussianState
    from stonesoup.updater.kalman import ExtendedKalmanUpdater

    q = float(DESIGN["process_noise_m2ps3"])
    p_gate = float(DESIGN["association_gate_probability"])
    gate_chi2 = -2.0 * np.log1p(-p_gate)
    transition = CombinedLinearGaussianTransitionModel([ConstantVelocity(q), ConstantVelocity(q)])  # [x, vx, y, vy]
    predictor = ExtendedKalmanPredictor(transition)
    updater = ExtendedKalmanUpdater(mm)
    gnn_hyp = DistanceHypothesiser(predictor, updater, measure=Mahalanobis(), missed_distance=float(np.sqrt(gate_chi2)))
    v0 = float(DESIGN["initial_speed_sigma_mps"]) ** 2
    # one-point start at the plot (the initiator maps the plot and its covariance into x/y), zero-mean velocity
    prior = GaussianState(np.zeros((4, 1)), np.diag([0.0, v0, 0.0, v0]))
    # M-of-N: a holding track is released after 3 updates (its start counts, like ours) and
    # dropped after 2 scans in a row without one (ours: as soon as 3 of 4 cannot be reached)
    initiator = MultiMeasurementInitiator(prior_state=prior, measurement_model=mm, deleter=UpdateTimeStepsDeleter(2),
                                          data_associator=GNNWith2DAssignment(gnn_hyp), updater=updater,
                                          min_points=int(DESIGN["confirm_hits"]))
    deleter = UpdateTimeStepsDeleter(int(DESIGN["max_coasted_scans"]))
    if kind == "gnn":
        return MultiTargetTracker(initiator=initiator, deleter=deleter, detector=None,
                                  data_associator=GNNWith2DAssignment(gnn_hyp), updater=updater)
    extent = (p["max_range_m"] - p["min_range_m"]) * 2 * np.deg2rad(p["sector_half_width_deg"])
    density = max(clutter, 1e-12 * extent) / extent  # per radian of bearing and metre of range
    pda = PDAHypothesiser(predictor, updater, clutter_spatial_density=density,
                          prob_detect=float(DESIGN["detection_probability"]), prob_gate=p_gate)
    return MultiTargetMixtureTracker(initiator=initiator, deleter=deleter, detector=None,
                                     data_associator=JPDAwithEHM(pda), updater=updater)


def stonesoup_run(kind, mm, scans, clutter, p):
    """(seconds per scan of the tracking loop alone, confirmed positions per scan)."""
    tracker = stonesoup_tracker(kind, mm, clutter, p)
    xy, busy = [], 0.0
    for ts, dets in scans:
        t0 = time.perf_counter()
        _, tracks = tracker.update_tracker(ts, dets)
        busy += time.perf_counter() - t0
        xy.append(np.array([[float(t.state_vector[0, 0]), float(t.state_vector[2, 0])] for t in tracks]).reshape(-1, 2))
    width = max(1, max(a.shape[0] for a in xy))
    padded = np.full((len(xy), width, 2), np.nan)
    for k, a in enumerate(xy):
        padded[k, : a.shape[0]] = a
    return busy / len(scans), padded


# --------------------------------------------------------------------------- the floor


def floor_gnn(d: dict, scans: int):
    """A minimal GNN loop as a reference cost: one EKF per target started at the truth, batched
    predict / predicted measurement / gate, one ``linear_sum_assignment`` a scan (a miss column
    per track at the gate's cost), update of the assigned tracks; no starts, no deletions."""
    from scipy.optimize import linear_sum_assignment

    p = d["params"]
    T, q = p["scan_period_s"], p["process_noise_m2ps3"]
    F = np.kron(np.array([[1, T], [0, 1]]), np.eye(2))
    Q = np.kron(q * np.array([[T**3 / 3, T**2 / 2], [T**2 / 2, T]]), np.eye(2))
    Rm = np.diag([p["sigma_range_m"] ** 2, np.deg2rad(p["sigma_bearing_deg"]) ** 2])
    gate = -2.0 * np.log1p(-DESIGN["association_gate_probability"])
    n0 = int(d["alive"][0, 0])
    x = np.concatenate([d["truth_xy"][0, 0, :n0], np.zeros((n0, 2))], axis=1)
    P = np.broadcast_to(np.diag([100.0, 100.0, 100.0, 100.0]), (n0, 4, 4)).copy()
    BIG = 1e9
    for k in range(1, scans):
        n = int(d["counts"][0, k])
        z = np.stack([d["range_m"][0, k, :n], d["bearing_rad"][0, k, :n]], -1)
        x = x @ F.T
        P = F @ P @ F.T + Q
        r2 = x[:, 0] ** 2 + x[:, 1] ** 2
        r = np.sqrt(r2)
        H = np.zeros((n0, 2, 4))
        H[:, 0, 0], H[:, 0, 1] = x[:, 0] / r, x[:, 1] / r
        H[:, 1, 0], H[:, 1, 1] = -x[:, 1] / r2, x[:, 0] / r2
        PHt = P @ H.transpose(0, 2, 1)
        S = H @ PHt + Rm
        Si = np.linalg.inv(S)
        nu = z[None, :, :] - np.stack([r, np.arctan2(x[:, 1], x[:, 0])], -1)[:, None, :]
        nu[..., 1] = (nu[..., 1] + np.pi) % (2 * np.pi) - np.pi
        d2 = np.einsum("twi,tij,twj->tw", nu, Si, nu)
        cost = np.full((n0, n + n0), BIG)
        cost[:, :n] = np.where(d2 <= gate, d2, BIG)
        cost[np.arange(n0), n + np.arange(n0)] = gate
        rows, cols = linear_sum_assignment(cost)
        hit = cols < n
        t, j = rows[hit], cols[hit]
        Kg = PHt[t] @ Si[t]
        x[t] = x[t] + (Kg @ nu[t, j][..., None])[..., 0]
        P[t] = P[t] - Kg @ H[t] @ P[t]
    return x


# --------------------------------------------------------------------------- sections


def time_ours(name, d, scans=None, repeats=1):
    """Per-scan seconds of each repeat and the last output."""
    rp = plots_of(d, scans)
    K = rp.counts.shape[1]
    tr = ours(name, d["params"]["clutter_per_scan"])
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = tr.track(rp)
        times.append((time.perf_counter() - t0) / K)
    return times, out


def section_1(args, repeats):
    K, Kp = args.scans, min(args.peer_scans, args.scans)
    print(f"== 1. 50 targets, 20 clutter a scan, one run: ours {K} scans, Stone Soup {Kp} scans "
          f"(--peer-scans; ours timed on both lengths), {repeats} repeats interleaved")
    d = make_data(50, 20.0, K, seed=args.seed)
    alive = d["alive"][0]
    print(f"   targets alive {np.mean(alive):.1f} [{alive.min()}–{alive.max()}], plots a scan "
          f"{np.mean(d['counts']):.1f}; Stone Soup's Detection objects built first (not timed)")
    import stonesoup

    t0 = time.perf_counter()
    mm, ss_scans = stonesoup_detections(d, Kp)
    print(f"   building {sum(len(s) for _, s in ss_scans)} Stone Soup detections: {time.perf_counter() - t0:.2f} s "
          f"(Stone Soup {stonesoup.__version__})")
    for name in OURS:  # warm-up
        time_ours(name, d, 20)
    t = {k: [] for k in ("gnn", "jpda_mt", "gnn@peer", "jpda_mt@peer", "ss_gnn", "ss_jpda", "floor")}
    outs, ss_xy = {}, {}
    for i in range(repeats):
        for name in OURS:
            tt, outs[name] = time_ours(name, d)
            t[name] += tt
            tt, outs[name + "@peer"] = time_ours(name, d, Kp)
            t[name + "@peer"] += tt
        for kind in ("gnn", "jpda"):
            sec, ss_xy[kind] = stonesoup_run(kind, mm, ss_scans, 20.0, d["params"])
            t["ss_" + kind].append(sec)
        t0 = time.perf_counter()
        floor_gnn(d, K)
        t["floor"].append((time.perf_counter() - t0) / (K - 1))
        print(f"   repeat {i + 1}/{repeats} done ({datetime.datetime.now():%H:%M:%S}, load {os.getloadavg()[0]:.2f})",
              flush=True)
    med = {k: statistics.median(v) for k, v in t.items()}
    truth = d["truth_xy"][0]
    rows = []

    def agreement(xy, n):
        g = gospa(xy[:n], truth[:n], GOSPA_C, GOSPA_P)
        return (int(np.isfinite(xy[n - 1, :, 0]).sum()),
                f"{np.mean(g['gospa']):.0f} ({np.mean(g['missed']):.1f} / {np.mean(g['false']):.1f})")

    for name, ss, label in (("gnn", "gnn", "GNN"), ("jpda_mt", "jpda", "JPDA")):
        c_full, g_full = agreement(confirmed_xy(outs[name])[0], K)
        c_p, g_p = agreement(confirmed_xy(outs[name + "@peer"])[0], Kp)
        s_c, s_g = agreement(ss_xy[ss], Kp)
        rows.append([f"ours {label} ({K} scans)", spread(t[name], 1e3, 2), "", c_full, g_full])
        rows.append([f"ours {label} ({Kp} scans)", spread(t[name + "@peer"], 1e3, 2), "", c_p, g_p])
        peer = "GNNWith2DAssignment" if ss == "gnn" else "JPDAwithEHM"
        rows.append([f"Stone Soup {peer} ({Kp} scans)", spread(t["ss_" + ss], 1e3, 2),
                     f"{med['ss_' + ss] / med[name + '@peer']:.1f}× ours ({Kp} sc.)", s_c, s_g])
    rows.append([f"floor: numpy GNN loop ({K} scans)", spread(t["floor"], 1e3, 3),
                 f"ours GNN {med['gnn'] / med['floor']:.1f}× floor", "", ""])
    print(f"   truth at the end: {int(d['alive'][0, K - 1])} targets ({K} scans), {int(d['alive'][0, Kp - 1])} "
          f"({Kp} scans); GOSPA c = {GOSPA_C:g} m, p = {GOSPA_P:g}, α = 2, mean over the scans")
    print_table(["tracker", "ms / scan", "ratio of medians", "confirmed at end", "mean GOSPA m (missed / false a scan)"], rows)
    # ours against Stone Soup directly: the same GOSPA between the two confirmed sets, scan by scan
    # (and each library's GNN against its JPDA, for scale)
    pairs = (("ours GNN", confirmed_xy(outs["gnn@peer"])[0], "Stone Soup GNN", ss_xy["gnn"]),
             ("ours JPDA", confirmed_xy(outs["jpda_mt@peer"])[0], "Stone Soup JPDA", ss_xy["jpda"]),
             ("ours GNN", confirmed_xy(outs["gnn@peer"])[0], "ours JPDA", confirmed_xy(outs["jpda_mt@peer"])[0]),
             ("Stone Soup GNN", ss_xy["gnn"], "Stone Soup JPDA", ss_xy["jpda"]))
    for a_label, a, b_label, b in pairs:
        g = gospa(a, b, GOSPA_C, GOSPA_P)
        both = g["assigned"]
        loc = np.sqrt(np.sum(g["localisation"] ** 2) / max(int(np.sum(both)), 1))
        print(f"   {a_label} vs {b_label}, {Kp} scans: mean GOSPA {np.mean(g['gospa']):.0f} m; a scan "
              f"{np.mean(both):.1f} track pairs within {GOSPA_C:g} m (RMS distance {loc:.1f} m), "
              f"{np.mean(g['false']):.2f} of the first's and {np.mean(g['missed']):.2f} of the second's without a partner")
    return d


def _fit(xs, ys):
    xs, ys = np.log(np.asarray(xs, float)), np.log(np.asarray(ys, float))
    return float(np.polyfit(xs, ys, 1)[0])


def section_2(args, repeats):
    K = args.scaling_scans
    targets, clutters = ((10, 50), (0.0, 10.0, 20.0)) if args.quick else ((10, 50, 200), (0.0, 20.0, 100.0))
    print(f"== 2. scaling of ours: targets × clutter, one run, {K} scans, {repeats} repeats (ms / scan)")
    med = {}
    rows = []
    for n in targets:
        for c in clutters:
            d = make_data(n, c, K, seed=args.seed)
            row = [n, f"{c:g}", f"{np.mean(d['counts']):.0f}"]
            for name in OURS:
                time_ours(name, d, min(K, 10))
                tt, _ = time_ours(name, d, repeats=repeats)
                med[name, n, c] = statistics.median(tt)
                row.append(spread(tt, 1e3, 2))
            rows.append(row)
            print(f"   targets {n}, clutter {c:g} done", flush=True)
    print_table(["targets", "clutter", "plots/scan", "ours GNN", "ours JPDA"], rows)
    for name in OURS:
        vs_n = ", ".join(f"clutter {c:g}: {_fit(targets, [med[name, n, c] for n in targets]):.2f}" for c in clutters)
        hi = clutters[1:]
        vs_c = ", ".join(f"{n} targets: {_fit(hi, [med[name, n, c] for c in hi]):.2f}" for n in targets)
        print(f"   {name}: time/scan ∝ targets^a, a = {vs_n}")
        print(f"   {name}: time/scan ∝ clutter^b ({' → '.join(f'{c:g}' for c in hi)}), b = {vs_c}")


def section_3(args, repeats):
    K, R = args.runs_scans, 100
    print(f"== 3. the run axis: 50 targets, 20 clutter, {K} scans, 1 run against {R} runs in one call, {repeats} repeats")
    d1, dR = make_data(50, 20.0, K, 1, args.seed), make_data(50, 20.0, K, R, args.seed)
    rows = []
    for name in OURS:
        time_ours(name, d1, min(K, 10))
        t1, _ = time_ours(name, d1, repeats=repeats)
        tR, _ = time_ours(name, dR, repeats=repeats)
        per1 = np.asarray(t1)
        perR = np.asarray(tR) / R
        gain = np.median(per1) / np.median(perR)
        rows.append([name, spread(per1, 1e3, 3), spread(perR, 1e3, 3),
                     f"{gain:.1f}× ({'PASS' if gain >= 5.0 else 'MISS'}: target ≥ 5×)"])
    print_table(["tracker", "1 run: ms / run-scan", f"{R} runs: ms / run-scan", "gain of the run axis"], rows)


def _cli(*a):
    return [sys.executable, "-m", "trackreplay.face.cli", *a]


def _replay(data: Path, out: Path, timeout: float, *extra):
    """(wall s, peak MB, error text or None) of ``replay --no-rrd`` in a fresh process."""
    env = dict(os.environ, PYTHONPATH=str(REPO))
    args = _cli("-q", str(data), "--no-rrd", "--out", str(out / "tracks.mcap"), "--force", "--figures", "none",
                *extra)
    t0 = time.perf_counter()
    err = out.parent / f"{out.name}.stderr"
    with open(err, "wb") as fh:
        child = subprocess.Popen(args, env=env, cwd=data.parent, stdout=subprocess.DEVNULL, stderr=fh)
        deadline = t0 + timeout
        while True:
            pid, status, usage = os.wait4(child.pid, os.WNOHANG)
            if pid:
                break
            if time.perf_counter() > deadline:
                child.kill()
                _, status, usage = os.wait4(child.pid, 0)
                return time.perf_counter() - t0, usage.ru_maxrss * 1024 / MB, f"stopped after {timeout:.0f} s"
            time.sleep(0.05)
    wall = time.perf_counter() - t0
    code = os.waitstatus_to_exitcode(status)
    text = None if code == 0 else err.read_text(errors="replace").strip().splitlines()[-1:] or [f"exit {code}"]
    return wall, usage.ru_maxrss * 1024 / MB, (text[0] if text else None)


def _simulate_file(path: Path, targets, clutter, scans, seed):
    p = scenario_params(targets, clutter, scans)
    sets = []
    for key in ("n_scans", "initial_targets_mean", "birth_rate_per_scan", "survival_probability", "turning_fraction",
                "max_turn_rate_degps", "clutter_per_scan", "min_speed_mps", "max_speed_mps"):
        sets += ["--set", f"{key}={p[key]}"]
    subprocess.run(_cli("simulate", "radar-multi", "--runs", "1", "--seed", str(seed), "-o", str(path), *sets),
                   check=True, capture_output=True, env=dict(os.environ, PYTHONPATH=str(REPO)))


def section_4(args):
    K, Ks = args.e2e_scans, args.e2e_profile_scans
    print(f"== 4. end to end: replay --no-rrd of 200 targets × 100 clutter × {K} scans, one run, fresh process "
          f"(target < {E2E_TARGET_S:g} s, < {E2E_TARGET_MB:g} MB; stopped after {args.e2e_timeout:g} s)")
    if RECORDER is None:
        print("   skipped: needs the radar-multi recorder (replay simulate radar-multi)")
        return
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        data = tmp / "multi.mcap"
        t0 = time.perf_counter()
        _simulate_file(data, 200, 100.0, K, args.seed)
        print(f"   simulated {data.stat().st_size / MB:.1f} MB in {time.perf_counter() - t0:.1f} s")
        wall, peak, err = _replay(data, tmp / "out", args.e2e_timeout)
        ok = err is None and wall < E2E_TARGET_S and peak < E2E_TARGET_MB
        print(f"   replay (the default trackers, gnn and jpda_mt): {wall:.1f} s, peak {peak:.0f} MB"
              f"{'' if err is None else ' — ' + err}: {'PASS' if ok else 'MISS'}")
        wall3, peak3, err3 = _replay(data, tmp / "out3", args.e2e_timeout, "--trackers", "gnn,jpda_mt,ukf")
        print(f"   replay --trackers gnn,jpda_mt,ukf (ukf runs when named): {wall3:.1f} s, peak {peak3:.0f} MB"
              f"{'' if err3 is None else ' — ' + err3}")
        if ok:
            return
        short = tmp / "short.mcap"
        _simulate_file(short, 200, 100.0, Ks, args.seed)
        wall, peak, err = _replay(short, tmp / "out_short", args.e2e_timeout)
        print(f"   the same at {Ks} scans: {wall:.1f} s, peak {peak:.0f} MB{'' if err is None else ' — ' + err}")
        prof = tmp / "replay.prof"
        subprocess.run([sys.executable, "-m", "cProfile", "-o", str(prof), "-m", "trackreplay.face.cli", "-q", str(short),
                        "--no-rrd", "--out", str(tmp / "out_prof" / "tracks.mcap"), "--force", "--figures", "none"],
                       capture_output=True, env=dict(os.environ, PYTHONPATH=str(REPO)), cwd=tmp)
        print(f"   where the time goes (cProfile of that replay, top by own time):")
        _print_profile(pstats.Stats(str(prof)), 12)


def _print_profile(stats, n):
    buf = io.StringIO()
    stats.stream = buf
    stats.sort_stats("tottime").print_stats(n)
    total = stats.total_tt
    for line in buf.getvalue().splitlines():
        parts = line.split()
        if len(parts) >= 6 and parts[1].replace(".", "").isdigit() and "(" in parts[-1]:
            where = parts[-1].replace(str(REPO) + "/", "").replace(sys.prefix, "<py>")
            print(f"      {float(parts[1]):7.2f} s own {float(parts[1]) / total:5.1%}  cum {float(parts[3]):7.2f} s  "
                  f"{parts[0]:>8} calls  {where}")


def section_profile(args):
    """cProfile of ours per scan on the section-1 case and on the heaviest scaling case."""
    for n, c, K in ((50, 20.0, args.scans), (200, 100.0, args.scaling_scans)):
        print(f"== profile of ours: {n} targets, {c:g} clutter, {K} scans, one run (cProfile, top by own time)")
        d = make_data(n, c, K, seed=args.seed)
        for name in OURS:
            pr = cProfile.Profile()
            tr = ours(name, c)
            pr.enable()
            tr.track(plots_of(d))
            pr.disable()
            st = pstats.Stats(pr)
            print(f"   {name}: {st.total_tt / K * 1e3:.2f} ms / scan under the profiler")
            _print_profile(st, 10)


def _tree_state() -> str:
    """HEAD and which of the files under test differ from it (they are measured as they are)."""
    files = ["pipeline/trackers/radar_multi_target.py", "pipeline/cores/association/jpda.py",
             "pipeline/cores/association/gnn.py", "pipeline/cores/association/track_management.py",
             "pipeline/cores/filters/track_filter.py", "recorders/radar_multi.py"]
    try:
        head = subprocess.run(["git", "log", "-1", "--format=%h"], cwd=REPO, capture_output=True, text=True).stdout.strip()
        st = subprocess.run(["git", "status", "--porcelain", "--", *files], cwd=REPO, capture_output=True,
                            text=True).stdout.split("\n")
        changed = [line[3:] for line in st if line.strip()]
    except OSError:
        return "not a git checkout"
    return f"HEAD {head}" + (f"; measured as in the working tree: {', '.join(changed)}" if changed else "")


def main():
    global RECORDER
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="smoke run: few scans and the minimum repeats")
    ap.add_argument("--repeats", type=int, help="repeats of every timing (default 5, at least 5)")
    ap.add_argument("--scans", type=int, help="scans of section 1 for ours (default 1000)")
    ap.add_argument("--peer-scans", type=int, help="scans of section 1 for Stone Soup (default 200)")
    ap.add_argument("--scaling-scans", type=int, help="scans of section 2 (default 100)")
    ap.add_argument("--runs-scans", type=int, help="scans of section 3 (default 100)")
    ap.add_argument("--e2e-scans", type=int, help="scans of section 4 (default 2000)")
    ap.add_argument("--e2e-profile-scans", type=int, help="scans of the profiled replay when section 4 misses (default 200)")
    ap.add_argument("--e2e-timeout", type=float, default=600.0, help="stop the end-to-end replay after this (s)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--section", type=int, action="append", choices=(1, 2, 3, 4), help="run only these sections")
    ap.add_argument("--profile", action="store_true", help="also cProfile ours per scan")
    args = ap.parse_args()
    q = args.quick
    repeats = max(5, args.repeats or 5)
    args.scans = args.scans or (60 if q else 1000)
    args.peer_scans = args.peer_scans or (20 if q else 200)
    args.scaling_scans = args.scaling_scans or (15 if q else 100)
    args.runs_scans = args.runs_scans or (10 if q else 100)
    args.e2e_scans = args.e2e_scans or (20 if q else 2000)
    args.e2e_profile_scans = args.e2e_profile_scans or (10 if q else 200)
    sections = set(args.section or (1, 2, 3, 4))
    print(f"bench_multitarget: {datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC, "
          f"{os.cpu_count()} cores, load {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    RECORDER = _recorder()
    print(f"   tree: {_tree_state()}")
    if 1 in sections:
        section_1(args, repeats)
    if 2 in sections:
        section_2(args, repeats)
    if 3 in sections:
        section_3(args, repeats)
    if 4 in sections:
        section_4(args)
    if args.profile:
        section_profile(args)
    print(f"   load at the end {' '.join(f'{x:.2f}' for x in os.getloadavg())}; tree: {_tree_state()}")


if __name__ == "__main__":
    main()
