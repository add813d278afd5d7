"""Metrics of the array bearing trackers: angle MSE per SNR, track swaps and losses, FLOPs.

Definitions (angles in degrees at this boundary only):

* **Association.** Each track is tied to one true target at the end of the start-up (scan 1,
  the paper's k = 0): the assignment minimising the summed angle differences (for sorted sets of
  equal size, the rank pairing). Targets left without a track count as lost from the start.
* **MSE** (the paper's Table 1 quantity): mean of (θ̂ₙ − θ_a(n))² over runs, tracked scans
  (scan ≥ 2) and tracks, in deg², per SNR. Nothing is excluded: a track that follows the wrong
  target keeps contributing its error. ``angle_mse_deg2_clean`` is the same over the runs with no
  swap and no loss, for comparison with a figure that excludes divergences.
* **Following.** Track n *is on* target j at a scan if |θ̂ₙ − θⱼ| ≤ gate (``track_gate_deg``).
  Counted only at scans where target j is at least 2·gate away from every other target, so that
  the gates do not overlap and "which target" is unambiguous (during a crossing nothing is
  counted; what happens there shows once the targets have separated).
* **Swap**: track n is on another target j ≠ a(n) while j's own track is not on j (the targets
  exchanged tracks). **Loss**: a target with no track on it. Per run we count the tracks that
  ever swapped and the targets ever lost; two tracks merging onto one target (coalescence) is
  a loss of the other target, not a swap.

Scopes in the summary: ``overall`` (every run), ``snr_db=<v>`` per SNR of the file,
``n_targets=5`` / ``n_targets=6`` (FLOPs of the innovation for the paper's two table columns)
and ``data`` (sizes of the data set).
"""

from __future__ import annotations

import numpy as np
import polars as pl

from evaluators.tracking_metrics import long_form, nanmean, rms
from pipeline.cores.array.flop_counts import ANALYTIC, counted_flops
from pipeline.trackers.array_bearing import STARTUP_SCANS

FLOP_TABLE_N = (5, 6)


def associate(track_angles: np.ndarray, truth_angles: np.ndarray) -> np.ndarray:
    """Truth index of each track, from the start-up angles.

    Parameters
    ----------
    track_angles : ndarray, shape (runs, Nt)
        Tracks' angles at the end of the start-up (NaN for padding).
    truth_angles : ndarray, shape (runs, N)

    Returns
    -------
    ndarray of int, shape (runs, Nt)
        ``a(n)``, or −1 for a track with no target.
    """
    runs, nt = track_angles.shape
    n_true = truth_angles.shape[1]
    out = np.full((runs, nt), -1, np.int64)
    have = np.isfinite(track_angles)
    k = have.sum(axis=1)
    equal = k == n_true
    if equal.any():  # sorted sets of equal size: rank pairing is the optimal 1-D assignment
        order_truth = np.argsort(truth_angles[equal], axis=1)
        order_track = np.argsort(np.where(have[equal], track_angles[equal], np.inf), axis=1)[:, :n_true]
        rows = np.arange(equal.sum())[:, None]
        sub = np.full((equal.sum(), nt), -1, np.int64)
        sub[rows, order_track] = order_truth
        out[equal] = sub
    if (~equal).any():  # a different count at start-up (rare): Hungarian per such run
        from scipy.optimize import linear_sum_assignment

        for r in np.flatnonzero(~equal):
            idx = np.flatnonzero(have[r])
            cost = np.abs(track_angles[r, idx, None] - truth_angles[r, None, :])
            i, j = linear_sum_assignment(cost)
            out[r, idx[i]] = j
    return out


def follow_events(est: np.ndarray, truth: np.ndarray, assoc: np.ndarray, gate_rad: float):
    """Swaps and losses per run and scan (see the module docstring).

    Parameters
    ----------
    est : ndarray, shape (runs, scans, Nt)
    truth : ndarray, shape (runs, scans, N)
    assoc : ndarray of int, shape (runs, Nt)
    gate_rad : float

    Returns
    -------
    swapped : ndarray of bool, shape (runs, scans, Nt)
    lost : ndarray of bool, shape (runs, scans, N)
    """
    runs, K, nt = est.shape
    n_true = truth.shape[-1]
    sep = np.abs(truth[..., :, None] - truth[..., None, :])
    sep[..., np.arange(n_true), np.arange(n_true)] = np.inf
    valid = np.min(sep, axis=-1) >= 2 * gate_rad  # (runs, scans, N)
    valid[:, :STARTUP_SCANS] = False
    dist = np.abs(est[..., :, None] - truth[..., None, :])  # (runs, scans, Nt, N)
    on = (dist <= gate_rad) & valid[..., None, :]
    on = np.where(np.isnan(dist), False, on)
    own = assoc[:, None, :, None] == np.arange(n_true)[None, None, None, :]  # (runs, 1, Nt, N)
    own_on = np.any(on & own, axis=-2)  # target j's own track is on it, (runs, scans, N)
    lost = valid & ~np.any(on, axis=-2)
    swapped = np.any(on & ~own & ~own_on[..., None, :], axis=-1)
    return swapped, lost


def evaluate(times, tracks: dict, truth_angles=None, snr_db=None, gate_rad: float = np.deg2rad(3.0),
             n_sensors: int | None = None):
    """Per-scan and summary tables.

    Parameters
    ----------
    times : ndarray (scans,)
    tracks : dict
        ``tracker -> {"angle_rad", "innovation_rad", "gain", "subspace_error_rad", "n_tracks",
        "innovation_time_s", ...}`` with a leading run axis.
    truth_angles : ndarray (runs, scans, N), optional
        Without truth only what needs none is reported.
    snr_db : ndarray (runs,), optional
        Nominal SNR of each run (per-SNR scopes).
    gate_rad : float
        Following gate.
    n_sensors : int, optional
        M, for the FLOP records.

    Returns
    -------
    per_scan, summary : polars.DataFrame
    """
    scans = np.arange(len(times))
    per_scan_parts, summary_rows = [], []
    groups = [("overall", slice(None))]
    if snr_db is not None and truth_angles is not None:
        groups += [(f"snr_db={v:g}", snr_db == v) for v in np.unique(snr_db)]
    for name, out in tracks.items():
        est = out["angle_rad"]
        tracked = np.zeros(est.shape[:2], bool)
        tracked[:, STARTUP_SCANS:] = True
        innov_deg = np.rad2deg(out["innovation_rad"])
        sub_err = np.rad2deg(out["subspace_error_rad"])
        n_tracks = np.asarray(out["n_tracks"][:, 0], dtype=np.int64)
        cols = {
            "tracker": [name] * len(times), "scan": scans, "time_s": times,
            "rms_innovation_deg": rms(innov_deg, axis=(0, 2)),
            "gain_angle": nanmean(out["gain"][..., 0], axis=(0, 2)),
            "gain_rate_per_s": nanmean(out["gain"][..., 1], axis=(0, 2)),
            "subspace_error_deg": nanmean(sub_err, axis=0),
            "innovation_time_us": nanmean(out["innovation_time_s"], axis=0) * 1e6,
        }
        common = {"n_tracks_mean": float(np.mean(n_tracks)),
                  "rms_innovation_deg": float(rms(innov_deg[:, STARTUP_SCANS:])),
                  "subspace_error_deg": float(nanmean(sub_err[:, STARTUP_SCANS:]))}
        if truth_angles is not None:
            truth = truth_angles
            assoc = associate(est[:, STARTUP_SCANS - 1], truth[:, STARTUP_SCANS - 1])
            own_truth = np.where(assoc >= 0, 0, np.nan)[:, None, :] + np.take_along_axis(
                truth, np.maximum(assoc, 0)[:, None, :].repeat(truth.shape[1], axis=1), axis=2)
            err_deg = np.rad2deg(est - own_truth)
            err_deg[:, :STARTUP_SCANS] = np.nan
            se = err_deg**2
            swapped, lost = follow_events(est, truth, assoc, gate_rad)
            n_true = truth.shape[-1]
            missing = n_true - np.sum(assoc >= 0, axis=1)  # targets without a track from the start
            swaps_run = np.sum(np.any(swapped, axis=1), axis=-1)
            losses_run = np.maximum(np.sum(np.any(lost, axis=1), axis=-1), missing)
            clean = (swaps_run == 0) & (losses_run == 0)
            cols["mse_deg2"] = nanmean(se, axis=(0, 2))
            if snr_db is not None:
                for v in np.unique(snr_db):
                    cols[f"mse_deg2_snr{v:g}dB"] = nanmean(se[snr_db == v], axis=(0, 2))
            for scope, sel in groups:
                idx = np.arange(est.shape[0])[sel]
                row = {"tracker": name, "scope": scope,
                       "angle_mse_deg2": float(nanmean(se[idx])),
                       "angle_mse_deg2_clean": float(nanmean(se[idx][clean[idx]])) if clean[idx].any() else np.nan,
                       "track_swaps_per_run": float(np.mean(swaps_run[idx])),
                       "runs_without_swap": float(np.mean(swaps_run[idx] == 0)),
                       "target_losses_per_run": float(np.mean(losses_run[idx])),
                       "runs_without_loss": float(np.mean(losses_run[idx] == 0)),
                       "source_count_correct": float(np.mean(n_tracks[idx] == n_true)),
                       "runs": float(idx.size)}
                if scope == "overall":
                    row.update(common)
                summary_rows.append(row)
        else:
            summary_rows.append({"tracker": name, "scope": "overall", **common, "runs": float(est.shape[0])})
        if n_sensors is not None:
            n_mode = int(np.bincount(n_tracks).argmax()) if n_tracks.size else 0
            overall = next(r for r in summary_rows if r["tracker"] == name and r["scope"] == "overall")
            if 1 <= n_mode < n_sensors:
                overall["innovation_flops_model"] = float(ANALYTIC[name](n_sensors, n_mode))
                overall["innovation_flops_counted"] = float(_counted_core(name, n_sensors, n_mode))
            for n in FLOP_TABLE_N:
                if n < n_sensors:
                    summary_rows.append({"tracker": name, "scope": f"n_targets={n}",
                                         "innovation_flops_model": float(ANALYTIC[name](n_sensors, n)),
                                         "innovation_flops_counted": float(_counted_core(name, n_sensors, n)),
                                         "steering_flops_counted": float(counted_flops(name, n_sensors, n)["steering"])})
        per_scan_parts.append(pl.DataFrame(cols))
    per_scan = pl.concat(per_scan_parts, how="diagonal")
    wide = pl.DataFrame(summary_rows, infer_schema_length=None)
    summary = long_form(wide, ["tracker", "scope"]).drop_nulls("value").filter(pl.col("value").is_not_nan())
    sizes = {"runs": float(next(iter(tracks.values()))["angle_rad"].shape[0]) if tracks else np.nan,
             "scans": float(len(times)), "n_sensors": float(n_sensors) if n_sensors else np.nan,
             "n_targets": float(truth_angles.shape[-1]) if truth_angles is not None else np.nan}
    sizes = {k: v for k, v in sizes.items() if np.isfinite(v)}
    summary = pl.concat([summary, pl.DataFrame({"tracker": ["data"] * len(sizes), "scope": ["data"] * len(sizes),
                                                "metric": list(sizes), "value": list(sizes.values())})],
                        how="diagonal")
    return per_scan, summary.select("tracker", "metric", "scope", "value")


def _counted_core(strategy: str, n_sensors: int, n: int) -> int:
    """Counted FLOPs of the steps the paper's model covers (steering vectors excluded: both
    strategies build the same â, b̂ and the paper does not count them)."""
    counts = counted_flops(strategy, n_sensors, n)
    return int(sum(v for k, v in counts.items() if k != "steering"))
