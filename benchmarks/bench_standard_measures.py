"""HOTA, CLEAR MOT and the identity measures: ours against TrackEval on the same data (issue 26).

The workload: synthetic point tracks of ``--targets`` lanes × ``--scans`` scans × ``--runs``
Monte Carlo runs (default 50 × 1,000 × 100; fixed seed), positions in metres. Each lane holds
a sequence of targets (births and deaths: lives of scans/8 – scans/2, gaps of 1 – scans/20 + 1
scans), moving at constant velocity in a 1 km square. Each target is followed, from the scan
after its birth, by a track = truth + N(0, 8 m) per axis that misses 10 % of the scans; tracks
swap targets (3 % of the scans of a run), restart with a new identity (3 %), and short-lived
false tracks (1–5 scans) appear. Every scan puts its elements in random slots, so slots are
reused by different identities and an identity wanders between slots. A scan left without any
truth or any track would get a parked far-away target or track (never matched: TrackEval
treats such scans differently, see below); the count of such scans is printed.

Timed, on prepared data:

* ours: HOTA = ``hota_sums`` (19 α, d₀ = 50 m) + ``pooled_hota``; CLEAR + identity =
  ``gated_pairs`` + ``scan_matches`` + ``assignment_metrics`` at the gate 40 m with the target
  identities (TrackEval's convention), as ``evaluators/standard.py`` calls them, and the
  totals over runs. All runs in one call each, on the (R, K, slots, 2) arrays. The row "all
  three" times them together as ``evaluators/standard.py`` runs them: the pairs closer than
  the larger of the gate and d₀ found once (``gated_pairs``), HOTA from them and CLEAR and
  identity from those within the gate (``pairs_within``); its values are checked equal, bit for
  bit, to those of the two separate calls.
* TrackEval (``trackeval.metrics.HOTA``, ``CLEAR``, ``Identity``): ``eval_sequence`` of every
  run (one run is one of its sequences) + ``combine_sequences``, on per-sequence dicts built
  before its clock starts, with the similarities of ``tests/test_multitarget_metrics.py``:
  HOTA ``max(0, 1 − d/d₀)``; CLEAR ``max(0, 1 − (d/gate)²)`` at threshold 1e-9 (our matching's
  objective); Identity ``1 − d/(2·gate)`` at threshold 0.5 (a pair within the gate). TrackEval
  evaluates sequences one after another, so its time is linear in runs: it is timed on
  ``--peer-runs`` runs (default 10) and on half as many, both printed per run, and the larger
  scaled to ``--runs``.

Every timing is repeated ``--repeats`` times (ours and TrackEval's interleaved); the table gives
median [min–max] and the ratio of the medians against the 10× target. Ours is also timed on
the ``--peer-runs`` runs alone, for the unscaled ratio on exactly TrackEval's work. Then the agreement:
ours pooled over the first ``--peer-runs`` runs against TrackEval's combination of the same
sequences (and every per-run count). MOTP and sMOTA are defined differently (ours: mean
distance of the matches in metres; TrackEval's: mean similarity), so TrackEval's are compared
with the same formula applied to our matches' distances.

Run: ``PYTHONPATH=. python benchmarks/bench_standard_measures.py`` (``--quick``: 10 targets ×
100 scans × 5 runs, about a minute; ``--repeats N``, ``--runs``, ``--scans``, ``--targets``,
``--peer-runs``, ``--seed``; ``--cpu-time`` times by the process's CPU time, for a machine busy
with other work, where the wall clock measures the other work too).
"""

from __future__ import annotations

import argparse
import datetime
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import trackeval  # noqa: E402

from trackreplay.evaluators.assignment_metrics import assignment_metrics, gated_pairs, scan_matches  # noqa: E402
from trackreplay.evaluators.hota import HOTA_ALPHAS, hota_sums, point_similarity, pooled_hota  # noqa: E402
from trackreplay.evaluators.set_distances import pairs_within  # noqa: E402
from trackreplay.evaluators.set_distances import pairwise_distance  # noqa: E402
from timing import print_table, spread  # noqa: E402

TARGET_SPEEDUP = 10.0
GATE = 40.0       # m: CLEAR matching and identity pairs closer than this
HOTA_D0 = 50.0    # m: HOTA similarity max(0, 1 − d/d₀)
AREA = 1000.0     # m: side of the square the targets start in
SIGMA = 8.0       # m: track error per axis
SPEED = 2.0       # m per scan: σ of each velocity component
MISS = 0.1        # a track misses a scan
SWAP_RATE = 0.03  # a run's scan at which two tracks swap targets
FRAG_RATE = 0.03  # a run's scan at which a track restarts with a new identity
FALSE_START = 0.2  # an idle false-track slot starts a false track (1–5 scans)
PARKED = 5e4      # m: where a parked truth / track sits (never within any gate)

# TrackEval's similarity of each metric (as tests/test_multitarget_metrics.py)
SIMILARITY = {
    "HOTA": lambda d: point_similarity(d, HOTA_D0),
    "CLEAR": lambda d: np.maximum(0.0, 1.0 - (d / GATE) ** 2),
    "Identity": lambda d: 1.0 - d / (2 * GATE),
}
FILES = ["evaluators/hota.py", "evaluators/assignment_metrics.py", "evaluators/set_distances.py",
         "evaluators/standard.py", "pipeline/batched_linalg.py"]


# --------------------------------------------------------------------------- data


def make_data(runs: int, scans: int, targets: int, seed: int = 1):
    """tracks (R, K, S, 2), track_ids (R, K, S), truths (R, K, T, 2), truth_ids (R, K, T) and the
    number of (run, scan)s that needed a parked truth or track. Identities unique within a run."""
    rng = np.random.default_rng(seed)
    R, K, L = runs, scans, targets
    k = np.arange(K)
    # lanes of successive targets: births and deaths
    life_lo, life_hi, gap_hi = max(2, K // 8), max(3, K // 2), K // 20 + 2
    start = -rng.integers(0, life_hi, (R, L))
    births, deaths = [], []
    while True:
        life = rng.integers(life_lo, life_hi, (R, L))
        births.append(start)
        deaths.append(start + life)
        start = start + life + rng.integers(1, gap_hi, (R, L))
        if start.min() >= K:
            break
    births, deaths = np.stack(births, -1), np.stack(deaths, -1)            # (R, L, G)
    G = births.shape[-1]
    seg = np.full((R, K, L), -1)
    for g in range(G):
        on = (k[None, :, None] >= births[:, None, :, g]) & (k[None, :, None] < deaths[:, None, :, g])
        seg[on] = g
    alive = seg >= 0
    segc = np.maximum(seg, 0)
    origin = rng.uniform(0, AREA, (R, L, G, 2))
    velocity = rng.normal(0, SPEED, (R, L, G, 2))
    rr, ll = np.arange(R)[:, None, None], np.arange(L)[None, None, :]
    born_at = births[rr, ll, segc]                                          # (R, K, L)
    age = (k[None, :, None] - born_at)[..., None]
    truth = origin[rr, ll, segc] + age * velocity[rr, ll, segc]
    truth[~alive] = np.nan
    truth_id = np.where(alive, ll * G + segc, -1)
    # tracks: one per lane, following its target from the scan after its birth
    track_of = L * G + np.broadcast_to(np.arange(L), (R, L)).copy()       # the tracks of the targets at scan 0
    next_id = np.full(R, L * G + L)
    track_id = np.full((R, K, L), -1)
    track = np.full((R, K, L, 2), np.nan)
    F = max(2, L // 5)
    false_left, false_id, false_at = np.zeros((R, F), int), np.full((R, F), -1), np.zeros((R, F, 2))
    false_track_id = np.full((R, K, F), -1)
    false_track = np.full((R, K, F, 2), np.nan)
    runs_ = np.arange(R)
    for s in range(K):
        new = born_at[:, s] == s                                            # a new target: a new track
        n = new.sum(axis=1)
        if n.any():
            order = np.cumsum(new, axis=1) - 1
            track_of = np.where(new, next_id[:, None] + order, track_of)
            next_id = next_id + n
        swap = rng.random(R) < SWAP_RATE
        if swap.any():
            a = rng.integers(0, L, R)
            b = (a + rng.integers(1, max(L, 2), R)) % L
            w = runs_[swap]
            track_of[w, a[swap]], track_of[w, b[swap]] = track_of[w, b[swap]], track_of[w, a[swap]]
        frag = rng.random(R) < FRAG_RATE
        if frag.any():
            w = runs_[frag]
            track_of[w, rng.integers(0, L, w.size)] = next_id[w]
            next_id[w] += 1
        shown = alive[:, s] & (s > born_at[:, s]) & (rng.random((R, L)) > MISS)
        track_id[:, s] = np.where(shown, track_of, -1)
        track[:, s] = np.where(shown[..., None], truth[:, s] + rng.normal(0, SIGMA, (R, L, 2)), np.nan)
        # false tracks
        idle = false_left == 0
        begin = idle & (rng.random((R, F)) < FALSE_START)
        if begin.any():
            order = np.cumsum(begin, axis=1) - 1
            false_id = np.where(begin, next_id[:, None] + order, false_id)
            next_id = next_id + begin.sum(axis=1)
            false_left = np.where(begin, rng.integers(1, 6, (R, F)), false_left)
            false_at = np.where(begin[..., None], rng.uniform(0, AREA, (R, F, 2)), false_at)
        on = false_left > 0
        false_track_id[:, s] = np.where(on, false_id, -1)
        false_track[:, s] = np.where(on[..., None], false_at + rng.normal(0, 2.0, (R, F, 2)), np.nan)
        false_left = np.maximum(0, false_left - 1)
    tracks = np.concatenate([track, false_track], axis=2)
    track_ids = np.concatenate([track_id, false_track_id], axis=2)
    truths, truth_ids = truth, truth_id
    # a parked element where a scan would have no truth or no track
    parked = 0

    def park(X, I, at, pid):
        nonlocal parked
        empty = ~(I >= 0).any(axis=2)
        if not empty.any():
            return X, I
        parked += int(empty.sum())
        extra = np.full(X.shape[:2] + (1, 2), np.nan)
        extra[empty] = at
        return np.concatenate([X, extra], axis=2), np.concatenate([I, np.where(empty, pid, -1)[..., None]], axis=2)

    truths, truth_ids = park(truths, truth_ids, PARKED, L * G)
    tracks, track_ids = park(tracks, track_ids, -PARKED, int(next_id.max()))
    # random slots every scan
    for name in ("truth", "track"):
        X, I = (truths, truth_ids) if name == "truth" else (tracks, track_ids)
        perm = np.argsort(rng.random(I.shape), axis=-1)
        X = np.take_along_axis(X, perm[..., None], axis=2)
        I = np.take_along_axis(I, perm, axis=2)
        if name == "truth":
            truths, truth_ids = X, I
        else:
            tracks, track_ids = X, I
    return tracks, track_ids, truths, truth_ids, parked


def describe(data) -> str:
    tracks, track_ids, truths, truth_ids, parked = data
    R = tracks.shape[0]
    n_truth = np.mean([np.unique(truth_ids[r][truth_ids[r] >= 0]).size for r in range(R)])
    n_track = np.mean([np.unique(track_ids[r][track_ids[r] >= 0]).size for r in range(R)])
    return (f"{R} runs × {tracks.shape[1]} scans, slots {truths.shape[2]} truth / {tracks.shape[2]} track; "
            f"per scan {np.mean(truth_ids >= 0) * truths.shape[2]:.1f} targets and "
            f"{np.mean(track_ids >= 0) * tracks.shape[2]:.1f} tracks present; per run {n_truth:.0f} target "
            f"and {n_track:.0f} track identities; scans given a parked element: {parked}")


# --------------------------------------------------------------------------- ours


def ours_hota(data):
    tracks, track_ids, truths, truth_ids, _ = data
    sums = hota_sums(tracks, truths, HOTA_D0, track_ids, truth_ids)
    return sums, pooled_hota(sums)


def pooled_clear_identity(a: dict, runs) -> dict:
    """Our totals over ``runs`` as TrackEval's combined fields (MOTP/sMOTA apart)."""
    t = {key: float(np.asarray(a[key])[runs].sum()) for key in
         ("matches", "misses", "false_positives", "id_switches", "mostly_tracked", "partially_tracked",
          "mostly_lost", "track_breaks", "presences", "idtp", "idfp", "idfn", "distance_sum", "targets")}
    tp, fn, fp, sw, n = t["matches"], t["misses"], t["false_positives"], t["id_switches"], t["presences"]
    gt_ids = t["mostly_tracked"] + t["partially_tracked"] + t["mostly_lost"]
    return {"CLR_TP": tp, "CLR_FN": fn, "CLR_FP": fp, "IDSW": sw, "MT": t["mostly_tracked"],
            "PT": t["partially_tracked"], "ML": t["mostly_lost"], "Frag": t["track_breaks"],
            "MOTA": 1 - (fn + fp + sw) / n, "MODA": 1 - (fn + fp) / n, "CLR_Re": tp / n, "CLR_Pr": tp / (tp + fp),
            "CLR_F1": tp / (tp + 0.5 * fn + 0.5 * fp), "MTR": t["mostly_tracked"] / gt_ids,
            "PTR": t["partially_tracked"] / gt_ids, "MLR": t["mostly_lost"] / gt_ids,
            "IDTP": t["idtp"], "IDFP": t["idfp"], "IDFN": t["idfn"],
            "IDF1": 2 * t["idtp"] / (2 * t["idtp"] + t["idfp"] + t["idfn"]),
            "IDP": t["idtp"] / (t["idtp"] + t["idfp"]), "IDR": t["idtp"] / (t["idtp"] + t["idfn"]),
            "MOTP_m": t["distance_sum"] / tp, "presences": n}


def ours_clear_identity(data, pairs=None):
    tracks, track_ids, truths, truth_ids, _ = data
    if pairs is None:
        pairs = gated_pairs(tracks, truths, GATE, track_ids=track_ids, truth_ids=truth_ids)
    match, dist = scan_matches(tracks, truths, GATE, track_ids=track_ids, truth_ids=truth_ids, pairs=pairs)
    a = assignment_metrics(tracks, truths, GATE, track_ids, matches=(match, dist), truth_ids=truth_ids, pairs=pairs)
    return a, match, dist, pooled_clear_identity(a, slice(None))


def ours_all(data):
    """All three as ``evaluators/standard.py`` computes them: the pairs closer than the larger of
    the gate and d₀ found once, HOTA from them, CLEAR and identity from those within the gate."""
    tracks, track_ids, truths, truth_ids, _ = data
    pairs = gated_pairs(tracks, truths, max(GATE, HOTA_D0), track_ids=track_ids, truth_ids=truth_ids)
    sums = hota_sums(tracks, truths, HOTA_D0, track_ids, truth_ids, pairs=pairs)
    return (sums, pooled_hota(sums)), ours_clear_identity(data, pairs_within(pairs, GATE))


# --------------------------------------------------------------------------- TrackEval


def _same(a: dict, b: dict) -> bool:
    """Every array of ``a`` equal to ``b``'s, bit for bit."""
    return all(np.array_equal(np.asarray(a[k]), np.asarray(b[k]), equal_nan=True) for k in a)


def trackeval_inputs(data, runs: int) -> dict:
    """{metric name: [per-sequence dict of run r]} for the first ``runs`` runs, with each metric's
    similarity (rows truths, columns tracks; identities compacted to 0…n−1 per run)."""
    tracks, track_ids, truths, truth_ids, _ = data
    out = {name: [] for name in SIMILARITY}
    for r in range(runs):
        on_truth, on_track = truth_ids[r] >= 0, track_ids[r] >= 0
        truth_uniq, track_uniq = np.unique(truth_ids[r][on_truth]), np.unique(track_ids[r][on_track])
        base = {"num_timesteps": tracks.shape[1], "num_gt_ids": truth_uniq.size, "num_tracker_ids": track_uniq.size,
                "num_gt_dets": int(on_truth.sum()), "num_tracker_dets": int(on_track.sum()),
                "gt_ids": [], "tracker_ids": []}
        dists = []
        for k in range(tracks.shape[1]):
            g, t = np.flatnonzero(on_truth[k]), np.flatnonzero(on_track[k])
            base["gt_ids"].append(np.searchsorted(truth_uniq, truth_ids[r, k, g]))
            base["tracker_ids"].append(np.searchsorted(track_uniq, track_ids[r, k, t]))
            dists.append(pairwise_distance(truths[r, k, g], tracks[r, k, t]))
        for name, similarity in SIMILARITY.items():
            out[name].append(dict(base, similarity_scores=[similarity(d) for d in dists]))
    return out


METRICS = {"HOTA": trackeval.metrics.HOTA({"PRINT_CONFIG": False}),
           "CLEAR": trackeval.metrics.CLEAR({"THRESHOLD": 1e-9, "PRINT_CONFIG": False}),
           "Identity": trackeval.metrics.Identity({"THRESHOLD": 0.5, "PRINT_CONFIG": False})}


def theirs(name: str, sequences: list):
    """TrackEval's per-sequence results and their combination."""
    metric = METRICS[name]
    per_run = {r: metric.eval_sequence(seq) for r, seq in enumerate(sequences)}
    return per_run, metric.combine_sequences(per_run)


#: what :func:`clock` reads: the wall clock, or with ``--cpu-time`` this process's CPU time
TIMER = time.perf_counter


def clock(fn, *args):
    t0 = TIMER()
    out = fn(*args)
    return TIMER() - t0, out


# --------------------------------------------------------------------------- agreement


def agreement(ours_h, ours_a, match, dist, their_h, their_c, their_i, n: int):
    """Rows (measure, ours, TrackEval, |difference|, agrees) over the first n runs, and the
    per-run count mismatches."""
    runs = np.arange(n)
    rows, bad = [], []

    def row(name, mine, yours, exact=False, note=""):
        diff = abs(mine - yours)
        ok = diff == 0 if exact else diff <= 1e-9 * max(1.0, abs(yours))
        fmt = (lambda v: f"{v:.0f}") if exact else (lambda v: f"{v:.12f}")
        rows.append([name + note, fmt(mine), fmt(yours), f"{diff:.1e}", "yes" if ok else "NO"])
        if not ok:
            bad.append(name)

    sums, _ = ours_h
    mine = pooled_hota(sums, runs=runs)
    comb = their_h[1]
    for key, name in (("hota", "HOTA"), ("deta", "DetA"), ("assa", "AssA"), ("loca", "LocA"), ("detre", "DetRe"),
                      ("detpr", "DetPr"), ("assre", "AssRe"), ("asspr", "AssPr")):
        row(name, mine[key], float(np.mean(comb[name])))
        per_alpha = np.max(np.abs(mine[f"{key}_alpha"] - comb[name]))
        if per_alpha > 1e-9:
            bad.append(f"{name} per α")
    for key in ("HOTA_TP", "HOTA_FN", "HOTA_FP"):
        row(key + " (Σα)", float(sums[key.split("_")[1].lower()][runs].sum()), float(np.sum(comb[key])), exact=True)
    a, _, _, _ = ours_a
    pooled = pooled_clear_identity(a, runs)
    for name in ("CLR_TP", "CLR_FN", "CLR_FP", "IDSW", "MT", "PT", "ML", "Frag"):
        row(name, pooled[name], float(their_c[1][name]), exact=True)
    for name in ("MOTA", "MODA", "CLR_Re", "CLR_Pr", "CLR_F1", "MTR", "PTR", "MLR"):
        row(name, pooled[name], float(their_c[1][name]))
    # MOTP and sMOTA: TrackEval's are means of its similarity; the same of our matches' distances
    d = dist[:n][match[:n] >= 0]
    motp_sum = float(np.sum(1 - (d / GATE) ** 2))
    row("MOTP", motp_sum / pooled["CLR_TP"], float(their_c[1]["MOTP"]), note=" (1 − d²/gate² of our matches)")
    row("sMOTA", (motp_sum - pooled["CLR_FP"] - pooled["IDSW"]) / pooled["presences"], float(their_c[1]["sMOTA"]),
        note=" (same)")
    for name in ("IDTP", "IDFP", "IDFN"):
        row(name, pooled[name], float(their_i[1][name]), exact=True)
    for name in ("IDF1", "IDP", "IDR"):
        row(name, pooled[name], float(their_i[1][name]))
    # every run's counts
    per_run_bad = 0
    keys = {"matches": ("CLEAR", "CLR_TP"), "misses": ("CLEAR", "CLR_FN"), "false_positives": ("CLEAR", "CLR_FP"),
            "id_switches": ("CLEAR", "IDSW"), "mostly_tracked": ("CLEAR", "MT"), "partially_tracked": ("CLEAR", "PT"),
            "mostly_lost": ("CLEAR", "ML"), "track_breaks": ("CLEAR", "Frag"), "idtp": ("Identity", "IDTP"),
            "idfp": ("Identity", "IDFP"), "idfn": ("Identity", "IDFN")}
    for r in runs:
        for mine_key, (metric, name) in keys.items():
            per = (their_c if metric == "CLEAR" else their_i)[0][r]
            per_run_bad += int(a[mine_key][r] != per[name])
        for key, name in (("tp", "HOTA_TP"), ("fn", "HOTA_FN"), ("fp", "HOTA_FP")):
            per_run_bad += int(np.any(sums[key][r] != their_h[0][r][name]))
    return rows, bad, per_run_bad, float(a["distance_sum"][runs].sum() / pooled["CLR_TP"])


# --------------------------------------------------------------------------- main


def _git(*a) -> str:
    """git's output with its trailing newline removed (not its leading spaces: a porcelain
    status line starts with one for a file changed but not staged)."""
    try:
        return subprocess.run(["git", *a], cwd=REPO, capture_output=True, text=True).stdout.rstrip("\n")
    except OSError:
        return ""


def _tree_state() -> str:
    changed = [line[3:] for line in _git("status", "--porcelain", "--", *FILES).split("\n") if line.strip()]
    return "measured as in the working tree: " + ", ".join(changed) if changed else "measured files as at HEAD"


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="smoke run: 10 targets × 100 scans × 5 runs")
    ap.add_argument("--repeats", type=int, default=3, help="repeats of every timing (default 3)")
    ap.add_argument("--runs", type=int, help="Monte Carlo runs (default 100; --quick 5)")
    ap.add_argument("--scans", type=int, help="scans per run (default 1000; --quick 100)")
    ap.add_argument("--targets", type=int, help="target lanes (default 50; --quick 10)")
    ap.add_argument("--peer-runs", type=int, help="runs TrackEval is timed on (default 10, and half as many; "
                                                  "--quick 4)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--cpu-time", action="store_true",
                    help="time by this process's CPU time instead of the wall clock: on a machine shared with "
                         "other work, both sides then count their own computing alone (every measured call runs "
                         "on one thread)")
    ap.add_argument("--system-allocator", action="store_true",
                    help="leave glibc's allocator as it is; by default this process keeps the memory it frees, "
                         "as the replay, eval and compare commands do (trackreplay.machine.keep_freed_memory)")
    args = ap.parse_args()
    global TIMER
    TIMER = time.process_time if args.cpu_time else time.perf_counter
    if not args.system_allocator:
        # the evaluation runs inside `replay`/`replay eval`, whose process keeps its freed memory:
        # measured as it runs there (on 2026-12-08 without it the 100-run figures took twice as
        # long, most of it the kernel faulting the same pages in again)
        from trackreplay.machine import keep_freed_memory

        print(f"   allocator: freed memory kept for reuse: {keep_freed_memory()} (--system-allocator: not)")
    q = args.quick
    R = args.runs or (5 if q else 100)
    K = args.scans or (100 if q else 1000)
    L = args.targets or (10 if q else 50)
    n2 = min(R, args.peer_runs or (4 if q else 10))
    n1 = max(1, n2 // 2)
    repeats = max(1, args.repeats)
    print(f"bench_standard_measures: {datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC, "
          f"commit {_git('rev-parse', '--short', 'HEAD')}, {os.cpu_count()} cores, "
          f"load {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    import scipy
    print(f"   numpy {np.__version__}, scipy {scipy.__version__}, trackeval {getattr(trackeval, '__version__', '?')}, "
          f"python {sys.version.split()[0]}; {_tree_state()}")
    print(f"   {L} targets × {K} scans × {R} runs, seed {args.seed}; gate {GATE:g} m, HOTA d₀ {HOTA_D0:g} m, "
          f"{HOTA_ALPHAS.size} α; {repeats} repeats")
    t0 = time.perf_counter()
    data = make_data(R, K, L, args.seed)
    print(f"   data: {describe(data)} (made in {time.perf_counter() - t0:.1f} s)")
    t0 = time.perf_counter()
    inputs = trackeval_inputs(data, n2)
    print(f"   TrackEval's per-sequence dicts of {n2} runs built in {time.perf_counter() - t0:.1f} s (not timed)")

    # warm-up (imports, caches) outside the clock
    small = tuple(x[:1, : min(K, 20)] if isinstance(x, np.ndarray) else x for x in data)
    ours_hota(small)
    ours_clear_identity(small)
    ours_all(small)
    for name in METRICS:
        theirs(name, [inputs[name][0]])

    t_ours = {"HOTA": [], "CLEAR + identity": []}
    all_ours = []
    few = tuple(x[:n2] if isinstance(x, np.ndarray) else x for x in data)
    t_few = []
    t_theirs = {(name, n): [] for name in METRICS for n in (n1, n2)}
    for _ in range(repeats):
        dt, oh = clock(ours_hota, data)
        t_ours["HOTA"].append(dt)
        dt, oa = clock(ours_clear_identity, data)
        t_ours["CLEAR + identity"].append(dt)
        dt, (oh_all, oa_all) = clock(ours_all, data)
        all_ours.append(dt)
        assert _same(oh_all[0], oh[0]) and _same(oa_all[0], oa[0]), "the shared pairs changed a value"
        t_few.append(clock(ours_all, few)[0])
        for n in (n1, n2):
            for name in METRICS:
                dt, res = clock(theirs, name, inputs[name][:n])
                t_theirs[name, n].append(dt)
                if n == n2:
                    if name == "HOTA":
                        th = res
                    elif name == "CLEAR":
                        tc = res
                    else:
                        ti = res

    def their_sum(names, n):
        return [sum(t_theirs[name, n][i] for name in names) for i in range(repeats)]

    groups = {"HOTA": ["HOTA"], "CLEAR + identity": ["CLEAR", "Identity"]}
    print()
    print(f"{'CPU time' if args.cpu_time else 'Time'} per call, median [min–max] over {repeats} repeats, s. "
          f"TrackEval timed on {n1} and {n2} runs "
          f"(per run: ms / run); its {R}-run time is the {n2}-run time × {R / n2:g}.")
    head = ["measure", f"ours, {R} runs", f"TrackEval, {n1} runs", f"TrackEval, {n2} runs",
            f"TrackEval ms/run ({n1} / {n2})", f"TrackEval × {R / n2:g} = {R} runs", "TrackEval / ours", "10× target"]
    rows, verdicts = [], []
    all_theirs = {n: their_sum(list(METRICS), n) for n in (n1, n2)}
    for label, mine, yours in [(g, t_ours[g], {n: their_sum(groups[g], n) for n in (n1, n2)}) for g in groups] + \
            [("all three", all_ours, all_theirs)]:
        scaled = [t * R / n2 for t in yours[n2]]
        ratio = statistics.median(scaled) / statistics.median(mine)
        verdict = "PASS" if ratio >= TARGET_SPEEDUP else "MISS"
        verdicts.append((label, ratio, verdict))
        rows.append([label, spread(mine), spread(yours[n1]), spread(yours[n2]),
                     f"{statistics.median(yours[n1]) / n1 * 1e3:.0f} / {statistics.median(yours[n2]) / n2 * 1e3:.0f}",
                     spread(scaled), f"{ratio:.1f}×", verdict])
    print_table(head, rows)
    print()
    detail = ", ".join(f"{name} {spread(t_theirs[name, n2], 1e3 / n2, 0)} ms/run" for name in METRICS)
    print(f"   TrackEval alone, per run on {n2} runs: {detail}")
    print(f"   ours per run: HOTA {statistics.median(t_ours['HOTA']) / R * 1e3:.1f} ms, CLEAR + identity "
          f"{statistics.median(t_ours['CLEAR + identity']) / R * 1e3:.1f} ms")
    few_ratio = statistics.median(all_theirs[n2]) / statistics.median(t_few)
    print(f"   ours on the same {n2} runs TrackEval is timed on, all three: {spread(t_few)} s "
          f"({statistics.median(t_few) / n2 * 1e3:.1f} ms/run; TrackEval / ours {few_ratio:.1f}×, unscaled)")
    lin = statistics.median(all_theirs[n2]) / n2 / (statistics.median(all_theirs[n1]) / n1)
    print(f"   linearity of TrackEval in runs: time per run at {n2} runs / at {n1} runs = {lin:.3f}")
    print(f"   ours all three in one (pairs found once): {statistics.median(all_ours) / R * 1e3:.1f} ms per run")
    label, ratio, verdict = verdicts[-1]
    print(f"   issue 26 target, HOTA + CLEAR + identity ≥ {TARGET_SPEEDUP:g}× TrackEval: {ratio:.1f}×, {verdict}")

    # agreement
    rows, bad, per_run_bad, motp_m = agreement(oh, oa, oa[1], oa[2], th, tc, ti, n2)
    print()
    print(f"Agreement over the first {n2} runs: ours pooled (totals over runs, ratios of the totals) against "
          f"TrackEval's combine_sequences")
    print_table(["measure", "ours", "TrackEval", "|diff|", "agrees"], rows)
    print(f"   per-run counts (CLEAR, identity, HOTA TP/FN/FP at every α) differing: {per_run_bad}; "
          f"our MOTP (mean distance of the matches) {motp_m:.3f} m")
    print(f"   agreement: {'all values agree' if not bad else 'DISAGREE: ' + ', '.join(bad)}")
    print(f"   load at the end {' '.join(f'{x:.2f}' for x in os.getloadavg())}; {_tree_state()}")


if __name__ == "__main__":
    main()
