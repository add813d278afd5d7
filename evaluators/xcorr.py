"""Track-association outcomes of multi-target bearing trackers: success, swap and loss.

The paper (Park, Ryu & Lee 1994, Fig. 8) reports a "percentage of success" without defining
it; these are our definitions, fixed before looking at any result. Per Monte Carlo run, track t
is started on target t; ``h = V/2`` is half the gate; the judge is the truth bearings.

* Track t is **on** target u at scan k when target u is the target nearest to the track's
  bearing estimate and ``|θ̂_t(k) − θ_u(k)| ≤ h``.
* Target u is **resolvable** at a scan when it is more than a full gate V from every other
  target (no peak can fall in its gate and another target's, so a track on it follows it
  unambiguously). With the paper's two targets this is "the scan is resolvable": the two are
  more than a gate apart. Any number of targets is judged the same way, target by target.
* Track t is **swapped** if it is on another target at the final scan, or on another target
  while that target is resolvable (this includes coalescence: two tracks ending on one target).
* Track t is **held** if it is on its own target at the final scan and not swapped.
* Track t is **lost** if it is neither: at the final scan no target is within h of it.

Run outcome (a partition of the runs, so the three rates sum to one):
**success** = every track held; **swap** = some track swapped; **loss** = otherwise (some
track lost, none swapped). ``coalescence_rate`` (a part of the swaps) counts runs whose final
scan has two or more tracks on one target, the classic JPDA failure for similar targets. ``success_rate_stderr`` is the binomial standard error
``√(p(1−p)/n)``; the interval of every rate is Wilson's with the runs as the trials (one outcome
per run: :func:`trackreplay.evaluators.confidence.proportion_intervals`), which stays inside [0, 1] where
``p ± 1.96·stderr`` does not (a loss rate of 0.01 over 100 runs: [0.002, 0.054], not
[−0.010, 0.030]). A difference between two trackers on the same runs is judged with the paired
standard error of the per-run success indicators (:func:`paired_difference`).

Scopes in the summary: ``overall`` (run outcomes, headline) and ``track=<t>:<role>`` (per-track
held / swapped / lost rates and bearing RMSE of held tracks).
"""

from __future__ import annotations

import numpy as np
import polars as pl

from trackreplay.evaluators.tracking_metrics import long_form, nanmean, rms
from trackreplay.vocabulary import INITIALISING

SUCCESS, SWAP, LOSS = 0, 1, 2


def on_target(estimate: np.ndarray, truth: np.ndarray, half_gate: float) -> np.ndarray:
    """Which target each track is on, ``−1`` for none.

    Parameters
    ----------
    estimate : ndarray (..., T) track bearings (NaN: no estimate)
    truth : ndarray (..., U) target bearings

    Returns
    -------
    ndarray of int (..., T)
    """
    d = np.abs(estimate[..., :, None] - truth[..., None, :])
    d = np.where(np.isfinite(d), d, np.inf)
    nearest = np.argmin(d, axis=-1)
    close = np.take_along_axis(d, nearest[..., None], axis=-1)[..., 0] <= half_gate
    return np.where(close, nearest, -1)


def resolvable_scans(truth: np.ndarray, gate: float) -> np.ndarray:
    """Scans where every pair of targets is more than a gate apart; truth (..., K, U) → (..., K)."""
    U = truth.shape[-1]
    if U < 2:
        return np.ones(truth.shape[:-1], bool)
    d = np.where(np.eye(U, dtype=bool), np.inf, np.abs(truth[..., :, None] - truth[..., None, :]))
    return np.min(d, axis=(-1, -2)) > gate


def resolvable_targets(truth: np.ndarray, gate: float) -> np.ndarray:
    """Targets more than a gate from every other target; truth (..., U) → (..., U) (one target:
    always). For two targets each is resolvable exactly where :func:`resolvable_scans` holds."""
    U = truth.shape[-1]
    if U < 2:
        return np.ones(truth.shape, bool)
    d = np.where(np.eye(U, dtype=bool), np.inf, np.abs(truth[..., :, None] - truth[..., None, :]))
    return np.min(d, axis=-1) > gate


def track_outcomes(estimate: np.ndarray, truth: np.ndarray, gate: float):
    """Per-track held / swapped / lost.

    Parameters
    ----------
    estimate : ndarray (R, K, T)
        Track bearings per run and scan (track t started on target t).
    truth : ndarray (R, K, T)
        Target bearings.
    gate : float
        Gate width V (same unit as the bearings).

    Returns
    -------
    held, swapped, lost : ndarray of bool (R, T)
    """
    T = estimate.shape[-1]
    on = on_target(estimate, truth, gate / 2)  # (R, K, T)
    own = np.arange(T)
    final = on[:, -1]
    elsewhere = (on >= 0) & (on != own)
    # on another target while that target is resolvable (two targets: while the scan is)
    resolvable = np.take_along_axis(resolvable_targets(truth, gate), np.maximum(on, 0), axis=-1)  # (R, K, T)
    swapped = (final >= 0) & (final != own) | np.any(elsewhere & resolvable, axis=1)
    held = (final == own) & ~swapped
    lost = ~held & ~swapped
    return held, swapped, lost


def run_outcomes(held: np.ndarray, swapped: np.ndarray) -> np.ndarray:
    """Run outcome (R,): SUCCESS if every track held, SWAP if any swapped, else LOSS."""
    return np.where(held.all(axis=1), SUCCESS, np.where(swapped.any(axis=1), SWAP, LOSS))


def coalesced(estimate: np.ndarray, truth: np.ndarray, gate: float) -> np.ndarray:
    """Runs (R,) whose final scan has two or more tracks on the same target."""
    final = on_target(estimate[:, -1], truth[:, -1], gate / 2)  # (R, T)
    same = (final[:, :, None] == final[:, None, :]) & (final[:, :, None] >= 0)
    return np.any(same & ~np.eye(final.shape[1], dtype=bool), axis=(1, 2))


def separation_deg(truth: np.ndarray) -> np.ndarray:
    """Smallest bearing separation (deg) between two targets per scan, truth (K, U) → (K,);
    NaN with one target."""
    U = truth.shape[-1]
    if U < 2:
        return np.full(truth.shape[0], np.nan)
    if U == 2:
        return np.rad2deg(np.abs(truth[:, 0] - truth[:, -1]))
    d = np.where(np.eye(U, dtype=bool), np.inf, np.abs(truth[:, :, None] - truth[:, None, :]))
    return np.rad2deg(np.min(d, axis=(-1, -2)))


def paired_difference(success_a: np.ndarray, success_b: np.ndarray) -> tuple[float, float]:
    """Mean of ``a − b`` over the same runs and its standard error (paired indicators)."""
    d = np.asarray(success_a, float) - np.asarray(success_b, float)
    n = d.size
    return float(d.mean()), float(d.std(ddof=1) / np.sqrt(n)) if n > 1 else float("nan")


def first_update_scan(flags: np.ndarray) -> int:
    """The first scan at which no track of any run is still ``INITIALISING``.

    ``flags`` (R, K, T) of :data:`trackreplay.vocabulary.FLAGS`: a tracker flags the scans up to
    and including its track start (state NaN before it, start values at it), so this is 1 when
    tracks start at scan 0 and 2 after a two-point start on scans 0 and 1.
    """
    flags = np.asarray(flags)
    initialising = np.any((flags & INITIALISING) > 0, axis=tuple(i for i in range(flags.ndim) if i != 1))
    filtered = np.flatnonzero(~initialising)
    return int(filtered[0]) if filtered.size else int(initialising.size)


def evaluate(times, tracks: dict, truth_bearing: np.ndarray | None, gate_rad: float, roles=None,
             first_filtered_scan: int | None = None):
    """Per-scan and summary tables of the bearing trackers.

    Parameters
    ----------
    times : ndarray (K,)
    tracks : dict
        ``tracker -> {"state" (R, K, T, 2), "flags" (R, K, T), ...}`` in the output vocabulary;
        the JPDA diagnostics ``beta0`` and ``n_gated`` (R, K, T) are reported where a tracker
        has them.
    truth_bearing : ndarray (R, K, T) or None
        Without truth only association statistics (β₀, gated counts) are reported.
    gate_rad : float
    roles : sequence of str, optional
        Names of the targets for the per-track scopes (e.g. strong, weak).
    first_filtered_scan : int, optional
        First scan with a filter update; scan-averaged gated counts and the RMSE of held tracks
        are taken from it on (earlier scans hold start values, not estimates). Default: from
        each tracker's ``INITIALISING`` flags (:func:`first_update_scan`): 1 when tracks
        start at scan 0 (true start), 2 after a two-point start on scans 0 and 1.

    Returns
    -------
    per_scan, summary : polars.DataFrame
        Summary in long form ``tracker, metric, scope, value``.
    """
    scans = np.arange(len(times))
    per_scan_parts, summary_parts = [], []
    for name, out in tracks.items():
        est = out["state"][..., 0]
        R, K, T = est.shape
        f = int(first_filtered_scan) if first_filtered_scan is not None else first_update_scan(out["flags"])
        roles_ = list(roles) if roles is not None and len(roles) == T else [f"target{t}" for t in range(T)]
        cols = {"tracker": [name] * K, "scan": scans, "time_s": np.asarray(times, float)}
        row = {"tracker": name, "scope": "overall", "runs": float(R)}
        if "beta0" in out:
            cols["mean_beta0"] = nanmean(out["beta0"], axis=(0, 2))
            row["mean_beta0"] = float(nanmean(out["beta0"]))
        if "n_gated" in out:
            cols["mean_gated_peaks"] = out["n_gated"].astype(float).mean(axis=(0, 2))
            row["mean_gated_peaks"] = float(out["n_gated"][:, f:].mean()) if K > f else np.nan
        rows = [row]
        if truth_bearing is not None:
            held, swapped, lost = track_outcomes(est, truth_bearing, gate_rad)
            outcome = run_outcomes(held, swapped)
            p = float(np.mean(outcome == SUCCESS))
            err = np.rad2deg(est - truth_bearing)
            on = on_target(est, truth_bearing, gate_rad / 2)
            cols["rmse_bearing_deg"] = rms(err, axis=(0, 2))
            cols["on_own_target_fraction"] = np.mean(on == np.arange(T), axis=(0, 2))
            cols["separation_deg"] = separation_deg(truth_bearing[0])
            held_err = np.where(held[:, None, :], err, np.nan)
            row.update(success_rate=p, swap_rate=float(np.mean(outcome == SWAP)),
                       loss_rate=float(np.mean(outcome == LOSS)),
                       coalescence_rate=float(np.mean(coalesced(est, truth_bearing, gate_rad))),
                       success_rate_stderr=float(np.sqrt(p * (1 - p) / R)),
                       rmse_bearing_deg_held=float(rms(held_err[:, f:])) if held.any() else np.nan)
            for t in range(T):
                per_track = {"tracker": name, "scope": f"track={t}:{roles_[t]}",
                             "held_rate": float(held[:, t].mean()), "swapped_rate": float(swapped[:, t].mean()),
                             "lost_rate": float(lost[:, t].mean()),
                             "rmse_bearing_deg_held": float(rms(held_err[:, f:, t]))
                             if held[:, t].any() else np.nan}
                if "beta0" in out:
                    per_track["mean_beta0"] = float(nanmean(out["beta0"][..., t]))
                rows.append(per_track)
        per_scan_parts.append(pl.DataFrame(cols))
        summary_parts.append(long_form(pl.DataFrame(rows, infer_schema_length=None), ["tracker", "scope"]).drop_nulls("value"))
    per_scan = pl.concat(per_scan_parts, how="diagonal")
    summary = pl.concat(summary_parts).select("tracker", "metric", "scope", "value")
    return per_scan, summary


def success_table(summary: pl.DataFrame) -> str:
    """Fig. 8 style text: success / swap / loss per tracker, the success rate with its 95 %
    Wilson interval over runs (one outcome per run; inside 0–100 %)."""
    from trackreplay.evaluators.confidence import wilson_interval

    ov = summary.filter(pl.col("scope") == "overall")
    if "success_rate" not in set(ov["metric"].to_list()):
        return ""
    wide = ov.pivot(on="metric", index="tracker", values="value", aggregate_function="first").sort("tracker")
    lines = ["track association (Park, Ryu & Lee 1994, Fig. 8): success = every track ends on its own target,",
             "never on another; in brackets its 95 % Wilson interval over runs",
             f"{'tracker':<10} {'success':>22} {'swap':>8} {'loss':>8} {'runs':>6}"]
    for r in wide.iter_rows(named=True):
        runs = int(r["runs"])
        low, high = wilson_interval(round(r["success_rate"] * runs), runs)
        interval = f"[{100 * low:.1f}, {100 * high:.1f}]"
        lines.append(f"{r['tracker']:<10} {100 * r['success_rate']:>6.1f} % {interval:>13} "
                     f"{100 * r['swap_rate']:>6.1f} % {100 * r['loss_rate']:>6.1f} % {runs:>6d}")
    return "\n".join(lines)
