"""Metrics of the TWS radar trackers: RMSE of position and velocity, NPE, gain behaviour.

Scopes in the summary:

``overall``                    every run and every filtered scan;
``cross_range_above_nominal``  scans whose true cross-range error std r·σ_θ exceeds the design
                               value the fixed gains assume (where adaptive gains should help);
``cross_range_below_nominal``  the other filtered scans.

Scans before a track is filtered (the two start-up plots) are left out everywhere.
"""

from __future__ import annotations

import numpy as np
import polars as pl

from evaluators.tracking_metrics import (long_form, nanmean, npe_from_squared, rmse_overall, rmse_per_scan, root,
                                        squared_error)
from pipeline.vocabulary import CLAMPED as FLAG_CLAMPED, COASTED as FLAG_COASTED, INITIALISING as FLAG_INITIALISING, NO_TRACK as FLAG_NO_TRACK

SCOPES = ("overall", "cross_range_above_nominal", "cross_range_below_nominal")


def filtered_mask(flags: np.ndarray) -> np.ndarray:
    """Scans that carry a filtered estimate (track started and updated or coasted)."""
    return (flags & (FLAG_NO_TRACK | FLAG_INITIALISING)) == 0


def evaluate(times, tracks: dict, measured_xy, truth_state=None, cross_range_std=None,
             nominal_cross_range_m: float | None = None, pcrb_position_var=None):
    """Per-scan and summary tables.

    Parameters
    ----------
    times : ndarray (scans,)
    tracks : dict
        ``tracker -> outputs`` in the output vocabulary (``state``, ``flags``; the paper's ``alpha``,
        ``beta``, ``lambda_cross`` and the converted-plot ``innovation`` with ``measurement`` where a
        tracker has them; ``docs/contract.md``).
    measured_xy : ndarray (runs, scans, 2)
        Converted plot per scan (NaN when missed), for NPE; a tracker's own ``measurement``
        (the plot it used, which differs when a scan holds several) takes precedence.
    truth_state : ndarray (runs, scans, 4), optional
        Without truth only innovation statistics are reported.
    cross_range_std : ndarray (runs, scans), optional
        True r·σ_θ per scan, for the above/below-nominal scopes.
    pcrb_position_var : ndarray (scans,), optional
        Trace of the position block of the posterior Cramér–Rao bound per scan (Tichavský,
        Muravchik & Nehorai 1998): reported as ``pcrb_position_m`` and, over the filtered
        scans, as ``position_efficiency`` = bound RMS / RMSE (≤ 1 for an unbiased tracker).

    Returns
    -------
    per_scan : polars.DataFrame
        One row per tracker × scan.
    summary : polars.DataFrame
        Long form: ``tracker, metric, scope, value``.
    """
    scans = np.arange(len(times))
    per_scan_parts, rows = [], []
    if cross_range_std is not None and nominal_cross_range_m is not None:
        above_scan = np.nanmean(cross_range_std, axis=0) > nominal_cross_range_m
    else:
        above_scan = np.zeros(len(times), bool)
    for name, out in tracks.items():
        ok = filtered_mask(out["flags"])
        est = np.where(ok[..., None], out["state"], np.nan)
        cols = {"tracker": [name] * len(times), "scan": scans, "time_s": times}
        # the paper's gain diagnostics, where a tracker has them (the α-β strategies and the Kalman reference)
        for key, column in (("alpha", "alpha"), ("beta", "beta")):
            if key in out:
                cols[f"{column}_along"] = _nanmean0(out[key][..., 0])
                cols[f"{column}_cross"] = _nanmean0(out[key][..., 1])
        if "lambda_cross" in out:
            cols["lambda_cross"] = _nanmean0(out["lambda_cross"])
        cols["clamped_fraction"] = np.mean((out["flags"] & FLAG_CLAMPED) > 0, axis=0)
        row = {"tracker": name, "scope": "overall",
               "clamped_scans": float(np.sum((out["flags"] & FLAG_CLAMPED) > 0)),
               "coasted_scans": float(np.sum((out["flags"] & FLAG_COASTED) > 0))}
        if "innovation" in out and "measurement" in out:
            # innovation of the converted plot (x, y) in metres: trackers that report the plot they used
            innov = np.where(ok[..., None], out["innovation"], np.nan)
            cols["rms_innovation_m"] = _rms0(innov)
            row["rms_innovation_m"] = rmse_overall(innov, 0.0) if ok.any() else np.nan
        rows.append(row)
        if truth_state is not None:
            # squared errors once per tracker; every RMSE below is a masked mean of these
            se_pos = squared_error(est[..., :2], truth_state[..., :2])
            se_vel = squared_error(est[..., 2:], truth_state[..., 2:])
            measured = out.get("measurement", measured_xy)
            npe = npe_from_squared(se_pos, squared_error(measured, truth_state[..., :2]))
            cols["rmse_position_m"] = root(nanmean(se_pos, axis=0))
            cols["rmse_velocity_mps"] = root(nanmean(se_vel, axis=0))
            cols["npe"] = npe
            row.update(rmse_position_m=float(root(nanmean(se_pos))), rmse_velocity_mps=float(root(nanmean(se_vel))),
                       npe_max=float(np.nanmax(npe)), npe_mean=float(nanmean(npe)),
                       scans_npe_ge_1=float(np.sum(npe >= 1.0)))
            if pcrb_position_var is not None:
                cols["pcrb_position_m"] = np.sqrt(pcrb_position_var)
                filtered = ok.any(axis=0) & np.isfinite(pcrb_position_var)
                bound = float(np.sqrt(np.mean(pcrb_position_var[filtered]))) if filtered.any() else np.nan
                row.update(pcrb_position_m=bound, position_efficiency=bound / row["rmse_position_m"])
            for scope, sel in (("cross_range_above_nominal", above_scan), ("cross_range_below_nominal", ~above_scan)):
                if not (sel & ok.any(axis=0)).any():
                    continue
                rows.append({"tracker": name, "scope": scope,
                             "rmse_position_m": float(root(nanmean(se_pos[:, sel]))),
                             "rmse_velocity_mps": float(root(nanmean(se_vel[:, sel]))),
                             "npe_mean": float(nanmean(npe[sel])), "scans": float(sel.sum())})
        per_scan_parts.append(pl.DataFrame(cols))
    per_scan = pl.concat(per_scan_parts, how="diagonal")
    # one table for every tracker and scope: the metrics a row lacks are null and dropped, and
    # the metric order is that of first appearance, as the per-tracker tables had it
    summary = long_form(pl.DataFrame(rows, infer_schema_length=None), ["tracker", "scope"]).drop_nulls("value")
    return per_scan, summary.select("tracker", "metric", "scope", "value")


def _nanmean0(a):
    return nanmean(a, axis=0)


def _rms0(v):
    return rmse_per_scan(v, 0.0)
