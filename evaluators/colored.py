"""Metrics of the coloured-noise trackers (Kwon 1997): RMSE of position, velocity and
acceleration, IMM model probabilities, and the AR(1) estimator against the true noise.

Scopes in the summary:

``overall``            every run and every scan after the initial one;
``manoeuvre``          scans where the true acceleration is non-zero (every scan of the circle);
``constant_velocity``  scans where it is zero;
``alpha=<value>``      (tracker ``ar_estimator``) *settled* scans whose true AR coefficient is
                       ``value``: the estimator is warm and the true α has not changed for
                       ``3/(1 − β)`` scans (95 % of the fading memory's weight).

Without truth (a file replayed with ``track_start=measurements``) only the ``overall`` scope is
reported: mean model probabilities and ``flagged_scans`` (scans whose flags are non-zero), and
the AR estimates per scan without a reference.

Figures (thesis Figs. 8–9, 13–15, 19–24) come from :func:`write_figures` through
:func:`trackreplay.evaluators.report_plots.plot_metrics_vs`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import polars as pl

from trackreplay.evaluators.tracking_metrics import long_form, nanmean, rms, root, squared_error

AR_TRACKER = "ar_estimator"
KINEMATICS = (("position", "rmse_position_m", 0), ("velocity", "rmse_velocity_mps", 1),
              ("acceleration", "rmse_acceleration_mps2", 2))
UNITS = {"position": "m", "velocity": "mps"}


def settled_scans(truth_alpha: np.ndarray, warm: np.ndarray, beta: float) -> np.ndarray:
    """``(runs, scans)`` mask of scans where the estimator is warm and the true α (axis 0) has
    been constant for the last ``ceil(3/(1 − β))`` scans."""
    a = truth_alpha[..., 0]
    runs, scans = a.shape
    hold = int(np.ceil(3.0 / (1.0 - beta)))
    change = np.zeros((runs, scans), dtype=np.int64)
    change[:, 1:] = (a[:, 1:] != a[:, :-1])
    last_change = np.maximum.accumulate(np.where(change > 0, np.arange(scans)[None, :], 0), axis=1)
    since = np.arange(scans)[None, :] - last_change
    return (since >= hold) & warm[None, :] & (np.arange(scans)[None, :] >= hold)


def _select(a: np.ndarray, mask: np.ndarray) -> np.ndarray:
    return np.where(mask[..., None], a, np.nan)


def _component(state: np.ndarray, c: int) -> np.ndarray:
    return state[..., c::3]


def evaluate(times, tracks: dict, truth_state, truth_alpha, measurement_variance: float, beta: float,
             model_names: list[str], pcrb_position_var=None, pcrb_velocity_var=None):
    """Per-scan and summary tables.

    Parameters
    ----------
    times : ndarray (scans,)
    tracks : dict
        ``tracker -> {"state" (runs, scans, 3·axes), "model_probabilities" (runs, scans, M), ...}``
        and ``"ar_estimator" -> {"alpha", "alpha_biased", "noise_variance", "warm", "flags"}``.
    truth_state : ndarray (runs, scans, 3·axes) or None
        ``[p, v, a]`` per axis (None: no RMSE, scope ``overall`` only).
    truth_alpha : ndarray (runs, scans, axes) or None
    measurement_variance : float
        R (the true ``σ_η² = (1 − α²) R``).
    beta : float
        The estimator's forgetting factor (defines the settled scans).
    model_names : list of str
        IMM model names (columns ``prob_<name>``).
    pcrb_position_var, pcrb_velocity_var : ndarray (scans,), optional
        Trace of the position (velocity) block of the posterior Cramér–Rao bound per scan
        (Tichavský, Muravchik & Nehorai 1998; ``docs/evaluation.md``): reported per scan as
        ``pcrb_position_m`` / ``pcrb_velocity_mps`` and, per scope, as the bound's RMS over the
        scope's scans and ``<kind>_efficiency`` = bound RMS / RMSE (≤ 1 up to Monte Carlo error,
        higher is better: the efficiency of every family, ``docs/evaluation.md``).

    Returns
    -------
    per_scan, summary : polars.DataFrame
        ``summary`` in long form ``tracker, metric, scope, value``.
    """
    scans = np.arange(len(times))
    after_start = scans >= 1
    scopes = [("overall", after_start)]
    if truth_state is not None:
        accel = np.abs(_component(truth_state, 2)).sum(axis=-1)            # (runs, scans)
        manoeuvre = np.all(accel > 0, axis=0) & after_start
        constant = np.all(accel == 0, axis=0) & after_start
        scopes += [("manoeuvre", manoeuvre), ("constant_velocity", constant)]
    per_scan_parts, rows = [], []
    for name, out in tracks.items():
        if name == AR_TRACKER:
            continue
        est = out["state"]
        cols = {"tracker": [name] * len(times), "scan": scans, "time_s": times}
        # squared errors once per component; every RMSE below is a masked mean of them
        squared = {} if truth_state is None else {
            metric: squared_error(_component(est, c), _component(truth_state, c)) for _, metric, c in KINEMATICS}
        for metric, se in squared.items():
            cols[metric] = root(nanmean(se, axis=0))
        bounds = {} if truth_state is None else {
            kind: var for kind, var in (("position", pcrb_position_var), ("velocity", pcrb_velocity_var))
            if var is not None}
        for kind, var in bounds.items():
            cols[f"pcrb_{kind}_{UNITS[kind]}"] = np.sqrt(var)
        mu = out.get("model_probabilities")
        is_imm = mu is not None and mu.shape[-1] == len(model_names) and len(model_names) > 1
        if is_imm:
            for j, m in enumerate(model_names):
                cols[f"prob_{m}"] = nanmean(mu[..., j], axis=0)
        for scope, sel in scopes:
            if not sel.any():
                continue
            row = {"tracker": name, "scope": scope, "scans": float(sel.sum())}
            for metric, se in squared.items():
                row[metric] = float(root(nanmean(se[:, sel])))
            for kind, var in bounds.items():
                bound = float(np.sqrt(np.mean(var[sel])))
                row[f"pcrb_{kind}_{UNITS[kind]}"] = bound
                row[f"{kind}_efficiency"] = bound / row[f"rmse_{kind}_{UNITS[kind]}"]
            if is_imm:
                for j, m in enumerate(model_names):
                    row[f"prob_{m}"] = float(nanmean(mu[:, sel, j]))
            if "flags" in out and scope == "overall":
                row["flagged_scans"] = float(np.sum(out["flags"][:, sel] > 0))
            rows.append(row)
        per_scan_parts.append(pl.DataFrame(cols))
    if AR_TRACKER in tracks:
        parts, ar_rows = _ar_tables(times, tracks[AR_TRACKER], truth_alpha, measurement_variance, beta)
        per_scan_parts += parts
        rows += ar_rows
    per_scan = pl.concat(per_scan_parts, how="diagonal")
    wide = pl.DataFrame(rows, infer_schema_length=None)
    summary = long_form(wide, ["tracker", "scope"]).drop_nulls("value").select("tracker", "metric", "scope", "value")
    return per_scan, summary


def _ar_tables(times, ar: dict, truth_alpha, R: float, beta: float):
    alpha, alpha_b, var = ar["alpha"], ar["alpha_biased"], ar["noise_variance"]
    scans = np.arange(len(times))
    flagged = (np.mean(ar["flags"] > 0, axis=(0, 2)) if ar["flags"].ndim == 3
               else np.mean(ar["flags"] > 0, axis=0))
    if truth_alpha is None:  # the estimates alone, no reference and no settled scans
        return [pl.DataFrame({
            "tracker": [AR_TRACKER] * len(times), "scan": scans, "time_s": times,
            "alpha_hat": nanmean(alpha.mean(-1), axis=0), "alpha_biased": nanmean(alpha_b.mean(-1), axis=0),
            "noise_variance_hat": nanmean(var.mean(-1), axis=0), "ar_flagged_fraction": flagged})], []
    warm = np.asarray(ar["warm"]).reshape(-1, alpha.shape[1])[0] > 0
    true_var = (1.0 - truth_alpha**2) * R
    # runs with the same true-α history form one curve (one for colored-imm, five for colored-ar)
    # grouped by each run's history as one opaque value (np.unique over rows costs 4 ms per
    # scoring), then ordered by the histories' values, as np.unique over rows would order them
    history = np.ascontiguousarray(truth_alpha[:, :, 0])
    # (the row's bytes from its shape: a C-contiguous array of one run may carry any stride there)
    _, first, inverse = np.unique(history.view(np.dtype((np.void, history.shape[1] * history.itemsize))).ravel(),
                                  return_index=True, return_inverse=True)
    order = np.lexsort(history[first].T[::-1])
    groups = [np.flatnonzero(inverse.ravel() == g) for g in order]
    parts = []
    for members in groups:
        a0 = truth_alpha[members[0], 0, 0]
        label = AR_TRACKER if len(groups) == 1 else f"{AR_TRACKER} (α={a0:g})"
        sl = (members, slice(None))
        parts.append(pl.DataFrame({
            "tracker": [label] * len(times), "scan": scans, "time_s": times,
            "alpha_true": nanmean(truth_alpha[sl].mean(-1), axis=0),
            "alpha_hat": nanmean(alpha[sl].mean(-1), axis=0),
            "alpha_biased": nanmean(alpha_b[sl].mean(-1), axis=0),
            "noise_variance_true": nanmean(true_var[sl].mean(-1), axis=0),
            "noise_variance_hat": nanmean(var[sl].mean(-1), axis=0),
            "ar_flagged_fraction": np.mean(ar["flags"][sl] > 0, axis=(0, 2)) if ar["flags"].ndim == 3
            else np.mean(ar["flags"][sl] > 0, axis=0),
        }))
    settled = settled_scans(truth_alpha, warm, beta)
    rows = []
    err = alpha - truth_alpha
    ratio = var / true_var
    flags = ar["flags"] if ar["flags"].ndim == 3 else ar["flags"][..., None]
    if settled.any():
        sel = settled[..., None] & np.ones_like(err, dtype=bool)
        rows.append({"tracker": AR_TRACKER, "scope": "overall", "samples": float(sel.sum()),
                     "alpha_rmse": float(rms(err[sel])),
                     "alpha_biased_rmse": float(rms((alpha_b - truth_alpha)[sel])),
                     "noise_variance_ratio": float(nanmean(ratio[sel])),
                     "flagged_fraction": float(np.mean(flags[sel] > 0))})
        for value in np.unique(truth_alpha[..., 0][settled]):
            s = sel & (truth_alpha == value)
            if not s.any():
                continue
            rows.append({"tracker": AR_TRACKER, "scope": f"alpha={value:g}", "samples": float(s.sum()),
                         "alpha_true": float(value),
                         "alpha_mean": float(nanmean(alpha[s])), "alpha_biased_mean": float(nanmean(alpha_b[s])),
                         "alpha_rmse": float(rms(err[s])),
                         "noise_variance_true": float((1 - value**2) * R),
                         "noise_variance_mean": float(nanmean(var[s])),
                         "noise_variance_ratio": float(nanmean(ratio[s])),
                         "flagged_fraction": float(np.mean(flags[s] > 0))})
    return parts, rows


# --------------------------------------------------------------------------- text and figures


def _pivot(summary: pl.DataFrame, scope: str, trackers, metrics) -> list[list]:
    part = summary.filter(pl.col("scope") == scope)
    table = []
    for t in trackers:
        vals = []
        for m in metrics:
            v = part.filter((pl.col("tracker") == t) & (pl.col("metric") == m))["value"]
            vals.append(float(v[0]) if len(v) else float("nan"))
        if not all(np.isnan(vals)):
            table.append([t, *vals])
    return table


def report_text(summary: pl.DataFrame, trackers, model_names) -> str:
    """The thesis's comparisons as plain tables (RMSE, model probabilities, AR estimates)."""
    lines = []
    metrics = [m for _, m, _ in KINEMATICS]
    for scope in ("overall", "manoeuvre", "constant_velocity"):
        tab = _pivot(summary, scope, trackers, metrics)
        if tab:
            lines.append(f"RMSE [{scope}]        position (m)  velocity (m/s)  acceleration (m/s²)")
            lines += [f"  {t:10s} {p:14.4f} {v:15.4f} {a:20.4f}" for t, p, v, a in tab]
    both = _pivot(summary, "overall", ["pimm", "mimm_k"], metrics)
    if len(both) == 2:
        rel = max(abs(a - b) / abs(b) for a, b in zip(both[0][1:], both[1][1:]))
        lines.append(f"PIMM vs MIMM_K (SRIF vs KF in the same IMM): largest relative RMSE difference {rel:.2e}")
    probs = [f"prob_{m}" for m in model_names]
    for scope in ("manoeuvre", "constant_velocity"):
        tab = _pivot(summary, scope, trackers, probs)
        if tab:
            lines.append(f"mean model probability [{scope}]  " + "  ".join(f"{m:>14s}" for m in model_names))
            lines += ["  " + f"{row[0]:10s}" + " " * 22 + "  ".join(f"{v:14.3f}" for v in row[1:]) for row in tab]
    ar = summary.filter((pl.col("tracker") == AR_TRACKER) & pl.col("scope").str.starts_with("alpha="))
    if not ar.height and lines:
        lines.append("AR(1) estimator: no settled scans (warm, and the true α constant for 3/(1 − β) scans)")
    if ar.height:
        lines.append("AR(1) estimator on settled scans   α̂ mean  α^b mean  α̂ RMSE  σ̂_η²/((1−α²)R)  flagged")
        for (scope,), part in ar.group_by(["scope"], maintain_order=True):
            g = {r["metric"]: r["value"] for r in part.iter_rows(named=True)}
            lines.append(f"  α = {g['alpha_true']:<8g}{'':20s}{g['alpha_mean']:7.4f}  {g['alpha_biased_mean']:8.4f}  "
                         f"{g['alpha_rmse']:7.4f}  {g['noise_variance_ratio']:15.4f}  {g['flagged_fraction']:7.3f}")
    return "\n".join(lines)


def write_figures(per_scan: pl.DataFrame, out_dir: str | Path, title: str = "") -> list[Path]:
    """PNG figures: RMSE per scan (Figs. 13–15, 19–21), model probabilities (Fig. 22) and AR
    estimates against the truth (Figs. 8–9, 23–24: one panel per true-α curve)."""
    from trackreplay.evaluators.report_plots import plot_metrics_vs

    out_dir = Path(out_dir)
    written = []
    trackers = per_scan.filter(~pl.col("tracker").str.starts_with(AR_TRACKER))
    metrics = [m for _, m, _ in KINEMATICS if m in trackers.columns]
    if trackers.height and metrics:
        written.append(plot_metrics_vs(trackers.select("tracker", "scan", *metrics), "scan", metrics,
                                       out_dir / "rmse.png", title=f"{title} RMSE per scan (over runs)"))
    probs = [c for c in per_scan.columns if c.startswith("prob_")]
    imms = trackers.filter(pl.col(probs[0]).is_not_null()) if probs else trackers.clear()
    if imms.height:
        written.append(plot_metrics_vs(imms.select("tracker", "scan", *probs), "scan", probs,
                                       out_dir / "model_probabilities.png",
                                       title=f"{title} mean model probabilities", hlines={p: [0.5] for p in probs}))
    ar = per_scan.filter(pl.col("tracker").str.starts_with(AR_TRACKER))
    if ar.height and "alpha_hat" in ar.columns:
        # one panel per true-α curve (runs sharing their true-α history), one line per series
        for fname, what, cols in (("ar_alpha.png", "AR coefficient",
                                   (("α̂ (bias-corrected)", "alpha_hat"), ("α^b (biased)", "alpha_biased"), ("truth", "alpha_true"))),
                                  ("ar_noise_variance.png", "white-noise variance σ_η² (m²)",
                                   (("σ̂_η²", "noise_variance_hat"), ("truth (1 − α²) R", "noise_variance_true")))):
            panels, frames = [], []
            cols = [(series, col) for series, col in cols if col in ar.columns]  # no truth: estimates only
            for (label,), part in ar.group_by(["tracker"], maintain_order=True):
                panel = label.replace(AR_TRACKER, "").strip(" ()") or "estimate"
                panels.append(panel)
                for series, col in cols:
                    frames.append(part.select(pl.col("scan"), pl.lit(series).alias("series"), pl.lit(panel).alias("panel"),
                                              pl.col(col).alias("value")))
            table = pl.concat(frames).pivot(on="panel", index=["scan", "series"], values="value")
            written.append(plot_metrics_vs(table, "scan", panels, out_dir / fname, group="series",
                                           title=f"{title} {what}: mean over runs vs truth"))
    return written
