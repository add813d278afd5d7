"""Metrics of the array bearing trackers (Ryu, Lee & Lee 2001; ``docs/papers/array.md``):
angle MSE per SNR, track swaps and losses, the innovation's FLOPs, and the paper's Table 1 text.

Outputs are read through the data contract's vocabulary only: the angle of track slot n is
``state[..., n, 0]``, the angular innovation ``innovation[..., n, 0]``, the gain ``gain[..., n, :, 0]``;
the family's extras (``n_tracks``, ``subspace_error_rad``, ``innovation_flops_*``) are used where a
tracker reports them. Definitions (angles in degrees at this boundary only):

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
* **FLOPs** (the paper's section IV): ``innovation_flops_model`` (the paper's analytic count) and
  ``innovation_flops_counted`` (what the kernel executes, steering vectors excluded) of one scan's
  innovation, as the tracker reports them for the most common N of the data set (scope
  ``overall``); for the paper's two table columns N = 5, 6 the stage passes them in
  (``flop_table``), with ``steering_flops_counted``.

Scopes in the summary: ``overall`` (every run), ``snr_db=<v>`` per SNR of the file,
``n_targets=5`` / ``n_targets=6`` (FLOPs of the innovation for the paper's two table columns)
and ``data`` (sizes of the data set).
"""

from __future__ import annotations

import numpy as np
import polars as pl

from trackreplay.evaluators.tracking_metrics import long_form, nanmean, rms
from trackreplay import vocabulary as vocab

FLOP_TABLE_N = (5, 6)
STARTUP_SCANS = 2  # scans 0 and 1 are the paper's k = −1 and k = 0 (MUSIC start-up); tracking from scan 2
LABELS = {"ryu": "Ryu 1999", "proposed": "proposed"}


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
    n_true = truth.shape[-1]
    # track and target axes first, (runs, scans) last: every operation runs along rows of
    # runs × scans values (with the 5-wide axes last, numpy's loops spent their time on loop
    # overhead); the same comparisons, so the same booleans
    T = np.ascontiguousarray(np.moveaxis(np.asarray(truth, float), -1, 0))  # (N, runs, scans)
    E = np.ascontiguousarray(np.moveaxis(np.asarray(est, float), -1, 0))  # (Nt, runs, scans)
    sep = np.abs(T[:, None] - T[None, :])  # (N, N, runs, scans)
    sep[np.arange(n_true), np.arange(n_true)] = np.inf
    valid = np.min(sep, axis=1) >= 2 * gate_rad  # (N, runs, scans)
    valid[:, :, :STARTUP_SCANS] = False
    dist = np.abs(E[:, None] - T[None, :])  # (Nt, N, runs, scans); NaN (no track) is never ≤ gate
    on = (dist <= gate_rad) & valid[None]
    own = np.asarray(assoc).T[:, None, :, None] == np.arange(n_true)[None, :, None, None]  # (Nt, N, runs, 1)
    own_on = np.any(on & own, axis=0)  # target j's own track is on it, (N, runs, scans)
    lost = valid & ~np.any(on, axis=0)
    swapped = np.any(on & ~own & ~own_on[None], axis=1)  # (Nt, runs, scans)
    return np.moveaxis(swapped, 0, -1), np.moveaxis(lost, 0, -1)


def _angles(out: dict) -> np.ndarray:
    """Track angles ``(runs, scans, slots)`` from the state ``[θ, θ̇]``."""
    return np.asarray(out["state"], float)[..., 0]


def _n_tracks(out: dict) -> np.ndarray:
    """Tracks of each run ``(runs,)``: the tracker's ``n_tracks``, else the slots holding a track at
    the end of the start-up."""
    if "n_tracks" in out:
        return np.asarray(out["n_tracks"][:, 0], dtype=np.int64)
    flags = np.asarray(out["flags"], np.uint16)[:, STARTUP_SCANS - 1]
    return np.sum((flags & vocab.NO_TRACK) == 0, axis=-1).astype(np.int64)


def _reported_flops(out: dict, key: str, runs: np.ndarray) -> float:
    """The per-scan FLOPs ``key`` a tracker reports for ``runs`` (NaN if it reports none)."""
    if key not in out or not runs.any():
        return np.nan
    values = np.asarray(out[key], float)[runs][:, STARTUP_SCANS:]
    values = values[np.isfinite(values)]
    return float(values[0]) if values.size else np.nan


def evaluate(times, tracks: dict, truth_angles=None, snr_db=None, gate_rad: float = np.deg2rad(3.0),
             n_sensors: int | None = None, flop_table: dict | None = None):
    """Per-scan and summary tables.

    Parameters
    ----------
    times : ndarray (scans,)
    tracks : dict
        ``tracker -> outputs`` with a leading run axis: ``state`` (runs, scans, slots, 2) and
        ``flags``, and where the tracker reports them ``innovation``, ``gain``,
        ``subspace_error_rad``, ``n_tracks``, ``innovation_flops_model``,
        ``innovation_flops_counted``.
    truth_angles : ndarray (runs, scans, N), optional
        Without truth only what needs none is reported.
    snr_db : ndarray (runs,), optional
        Nominal SNR of each run (per-SNR scopes).
    gate_rad : float
        Following gate.
    n_sensors : int, optional
        M, for the data record and the FLOP records.
    flop_table : dict, optional
        ``tracker -> {N: {"model", "counted", "steering"}}``: the innovation's FLOPs per scan for
        the paper's table columns (``n_targets=N`` scopes).

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
        est = _angles(out)
        n_tracks = _n_tracks(out)
        cols = {"tracker": [name] * len(times), "scan": scans, "time_s": times}
        common = {"n_tracks_mean": float(np.mean(n_tracks))}
        if "innovation" in out:
            innov_deg = np.rad2deg(np.asarray(out["innovation"], float)[..., 0])
            cols["rms_innovation_deg"] = rms(innov_deg, axis=(0, 2))
            common["rms_innovation_deg"] = float(rms(innov_deg[:, STARTUP_SCANS:]))
        if "gain" in out:
            gain = np.asarray(out["gain"], float)
            cols["gain_angle"] = nanmean(gain[..., 0, 0], axis=(0, 2))
            cols["gain_rate_per_s"] = nanmean(gain[..., 1, 0], axis=(0, 2))
        if "subspace_error_rad" in out:
            sub_err = np.rad2deg(np.asarray(out["subspace_error_rad"], float))
            cols["subspace_error_deg"] = nanmean(sub_err, axis=0)
            common["subspace_error_deg"] = float(nanmean(sub_err[:, STARTUP_SCANS:]))
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
                for key in ("innovation_flops_model", "innovation_flops_counted"):
                    overall[key] = _reported_flops(out, key, n_tracks == n_mode)
            for n, cost in sorted((flop_table or {}).get(name, {}).items()):
                if n < n_sensors:
                    summary_rows.append({"tracker": name, "scope": f"n_targets={n}",
                                         "innovation_flops_model": float(cost["model"]),
                                         "innovation_flops_counted": float(cost["counted"]),
                                         "steering_flops_counted": float(cost["steering"])})
        per_scan_parts.append(pl.DataFrame(cols))
    per_scan = pl.concat(per_scan_parts, how="diagonal")
    wide = pl.DataFrame(summary_rows, infer_schema_length=None)
    summary = long_form(wide, ["tracker", "scope"]).drop_nulls("value").filter(pl.col("value").is_not_nan())
    sizes = {"runs": float(_angles(next(iter(tracks.values()))).shape[0]) if tracks else np.nan,
             "scans": float(len(times)), "n_sensors": float(n_sensors) if n_sensors else np.nan,
             "n_targets": float(truth_angles.shape[-1]) if truth_angles is not None else np.nan}
    sizes = {k: v for k, v in sizes.items() if np.isfinite(v)}
    summary = pl.concat([summary, pl.DataFrame({"tracker": ["data"] * len(sizes), "scope": ["data"] * len(sizes),
                                                "metric": list(sizes), "value": list(sizes.values())})],
                        how="diagonal")
    return per_scan, summary.select("tracker", "metric", "scope", "value")


# --------------------------------------------------------------------------- Table 1


def _value(summary, tracker, metric, scope):
    hit = summary.filter((pl.col("tracker") == tracker) & (pl.col("metric") == metric) & (pl.col("scope") == scope))
    return float(hit["value"][0]) if hit.height else float("nan")


def table1(summary: pl.DataFrame, per_scan: pl.DataFrame | None = None, flop_steps: dict | None = None) -> str:
    """Text table in the layout of the paper's Table 1 (MSE per SNR, innovation FLOPs for N = 5, 6),
    plus swaps and losses per SNR.

    ``flop_steps`` : ``(tracker, N) -> {step: counted FLOPs}`` adds the counted FLOPs per step.
    Times are not measured here (a replay is no benchmark): ``benchmarks/bench_array.py`` times
    the innovation kernels.
    """
    s = summary
    present = [t for t in s["tracker"].unique(maintain_order=True).to_list() if t != "data"]
    trackers = [t for t in ("ryu", "proposed") if t in present] + [t for t in present if t not in ("ryu", "proposed")]
    if not trackers:
        return ""
    label = lambda t: LABELS.get(t, t)
    n_sensors = _value(s, "data", "n_sensors", "data")
    M = int(n_sensors) if np.isfinite(n_sensors) else None
    snr_scopes = sorted({sc for sc in s["scope"].to_list() if sc.startswith("snr_db=")}, key=lambda x: float(x[7:]))
    runs = _value(s, trackers[0], "runs", snr_scopes[0]) if snr_scopes else _value(s, "data", "runs", "data")
    n_true = _value(s, "data", "n_targets", "data")
    lines = [f"Table 1 (layout of Ryu, Lee & Lee 2001): M = {M}, "
             + (f"N = {n_true:g} targets, {runs:g} runs per SNR" if np.isfinite(n_true) else "no truth")]
    head = f"{'algorithm':<20}" + "".join(f"{'MSE ' + sc[7:] + ' dB':>12}" for sc in snr_scopes)
    head += "".join(f"{'FLOPs N=' + str(n) + ' model/counted':>28}" for n in FLOP_TABLE_N)
    lines += [head, "-" * len(head)]
    for t in trackers:
        row = f"{label(t):<20}" + "".join(f"{_value(s, t, 'angle_mse_deg2', sc):>12.4f}" for sc in snr_scopes)
        for n in FLOP_TABLE_N:
            model = _value(s, t, "innovation_flops_model", f"n_targets={n}")
            counted = _value(s, t, "innovation_flops_counted", f"n_targets={n}")
            row += f"{model:>16,.0f} / {counted:>9,.0f}" if np.isfinite(model) else f"{'–':>28}"
        lines.append(row)
    # The paper's own Table 1 is quoted in docs/papers/array.md for comparison; the code
    # reports only what it computes, so no printed number of the paper can turn into an expected output.
    ratios = []
    for n in FLOP_TABLE_N:
        scope = f"n_targets={n}"
        model = _value(s, "proposed", "innovation_flops_model", scope) / _value(s, "ryu", "innovation_flops_model", scope)
        counted = (_value(s, "proposed", "innovation_flops_counted", scope)
                   / _value(s, "ryu", "innovation_flops_counted", scope))
        if np.isfinite(model):
            ratios.append(f"N={n}: model {model:.3f}, counted {counted:.3f};")
    if ratios:
        lines.append("proposed / Ryu FLOP ratio  " + " ".join(ratios))
    for n in FLOP_TABLE_N:
        parts = [f"{label(t)}: " + " + ".join(f"{k} {v:,}" for k, v in flop_steps[(t, n)].items())
                 for t in trackers if (t, n) in (flop_steps or {})]
        if parts:
            lines.append(f"counted FLOPs per step, N={n}: " + "; ".join(parts))
    lines.append("counted FLOPs exclude the steering vectors both need; innovation times: "
                 "benchmarks/bench_array.py.")
    if snr_scopes:
        lines.append("")
        lines.append(f"{'per SNR':<20}{'MSE clean':>11}{'swaps/run':>11}{'no-swap runs':>14}"
                     f"{'losses/run':>12}{'no-loss runs':>14}{'N correct':>11}")
        for t in trackers:
            for sc in snr_scopes:
                lines.append(f"{label(t) + ' ' + sc[7:] + ' dB':<20}"
                             f"{_value(s, t, 'angle_mse_deg2_clean', sc):>11.4f}"
                             f"{_value(s, t, 'track_swaps_per_run', sc):>11.3f}"
                             f"{_value(s, t, 'runs_without_swap', sc):>14.1%}"
                             f"{_value(s, t, 'target_losses_per_run', sc):>12.3f}"
                             f"{_value(s, t, 'runs_without_loss', sc):>14.1%}"
                             f"{_value(s, t, 'source_count_correct', sc):>11.1%}")
        lines.append("MSE clean: runs with no swap and no loss only (the table's MSE keeps every run).")
    return "\n".join(lines)
