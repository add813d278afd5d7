"""Metrics of TDOA/FDOA emitter localisation: classification of runs, RMSE, efficiency, ellipses.

Every (run, epoch) estimate is put in exactly one class before anything is averaged:

``truth``           finite, not diverged, and statistically consistent with the truth: its error's
                    Mahalanobis distance under the CRLB at the truth, d² = eᵀ I(θ) e, is below the
                    χ²_q quantile at 1 − 10⁻⁶;
``elsewhere``       converged (last step < tolerance), d² beyond that gate, and a residual that
                    fits the data (J ≤ χ²_{m−q} quantile at 1 − 10⁻³): another exact solution of
                    the equations (three sensors give only four independent equations, and the
                    triangle geometry with emitter 3 has a second solution near (3.5, 10.2) km);
``diverged``        the estimator flagged the run diverged, rank deficient or without a start;
``not_converged``   the rest: iteration budget spent far from the truth, or stopped at a point
                    whose residual does not fit the data;
``underdetermined`` fewer independent equations than unknowns: not estimated;
``unclassified``    no truth, or the CRLB at the truth does not exist (e.g. emitter collinear
                    with the sensors), so closeness to the truth cannot be judged.

RMSE, ``<block>_efficiency`` (√trace(CRLB block) / RMSE: the statistical efficiency, ≤ 1 up to
Monte Carlo error and higher is better, as in every family; see ``docs/evaluation.md``) and the
fraction inside the 50 % error ellipse are computed over the ``truth`` class only; the counts of
every class are reported next to them.
d² is ‖A e‖² with A the whitened Jacobian at the truth, so no information matrix is inverted.

Kim et al. (2013) report RMSE against the CRLB (eqs. 18–22, Figs. 5–7) over all runs; see
``docs/papers/tdoa-fdoa.md``, "Every run is classified before anything is averaged". The bound
at the truth is not computed here: the stage writes it beside the estimators' outputs as the
entry :data:`CRLB_ENTRY` (``/tracks/tdoa-fdoa/crlb``), per estimator kind k
(``joint``, ``tdoa``, ``fdoa``): ``whitened_jacobian_<k>`` (R, E, m, q) = Ψ^{-1/2} H at the truth
over the kind's m measurement rows and q unknowns (the first q state components),
``crlb_covariance_<k>`` (R, E, q, q) and ``crlb_singular_<k>`` (R, E). A tracker whose name is
not a kind (a plugged one) is scored against the ``joint`` bound. This module reads outputs
and truth only (no numerical cores).
"""

from __future__ import annotations

import numpy as np
import polars as pl

from trackreplay.evaluators.tracking_metrics import long_form, rmse_overall
from trackreplay.errors import InputError
from trackreplay.vocabulary import CONVERGED, DIVERGED, INVALID_START, RANK_DEFICIENT, UNDERDETERMINED

CLASSES = ("truth", "elsewhere", "diverged", "not_converged", "underdetermined", "unclassified")
TRUTH, ELSEWHERE, DIVERGED_CLASS, NOT_CONVERGED_CLASS, UNDERDETERMINED_CLASS, UNCLASSIFIED = range(6)
TRUTH_GATE_TAIL = 1e-6
RESIDUAL_GATE_TAIL = 1e-3
REPORTED_ITERATIONS = (1, 2, 3, 5, 10)  # the paper compares 5 and 10
CRLB_ENTRY = "crlb"  # the stage's extra output: the CRLB at the truth per estimator kind
DEFAULT_KIND = "joint"  # the bound a tracker that is not one of the kinds is scored against


def ellipse_scale(probability: float) -> float:
    """√k with k = −2 ln(1 − P) (eq. 22): the Mahalanobis radius holding probability P in 2-D."""
    if not 0 < probability < 1:
        raise ValueError("probability must be in (0, 1)")
    return float(np.sqrt(-2.0 * np.log1p(-probability)))


def bound_of(crlb: dict, name: str):
    """The bound at the truth that tracker ``name`` is scored against (its kind's, else joint's).

    Returns ``A`` (..., m, q), ``cov`` (..., q, q) and ``singular`` (...) bool.
    """
    kind = name if f"whitened_jacobian_{name}" in crlb else DEFAULT_KIND
    key = f"whitened_jacobian_{kind}"
    if key not in crlb:
        raise InputError(f"the {CRLB_ENTRY!r} output lacks {key!r} (have: {', '.join(sorted(crlb))})")
    singular = np.asarray(crlb[f"crlb_singular_{kind}"])
    if singular.dtype.kind == "f":  # read back from a file: NaN where a frame was missing
        singular = np.nan_to_num(singular, nan=1.0)
    return crlb[key], crlb[f"crlb_covariance_{kind}"], singular.astype(bool)


def classify(flags, error, A_truth, singular, cost, dof, has_truth=True):
    """Class of every estimate (see the module docstring).

    Parameters
    ----------
    flags : ndarray of uint16 (...)
        Bits of :data:`trackreplay.vocabulary.FLAGS`.
    error : ndarray (..., q)
        Estimate − truth over the free components.
    A_truth : ndarray (..., m, q)
        Whitened Jacobian at the truth.
    singular : ndarray of bool (...)
        CRLB at the truth does not exist.
    cost : ndarray (...)
        J(θ̂).
    dof : int
        m − q.
    """
    q = error.shape[-1]
    with np.errstate(all="ignore"):
        d2 = np.sum(np.einsum("...mq,...q->...m", A_truth, error) ** 2, axis=-1)
    # chdtri(k, tail) is scipy.stats.chi2.isf(tail, k), without the 0.5 s import of scipy.stats
    from scipy.special import chdtri

    gate = chdtri(q, TRUTH_GATE_TAIL)
    resid_gate = chdtri(max(dof, 1), RESIDUAL_GATE_TAIL)
    out = np.full(flags.shape, NOT_CONVERGED_CLASS, np.int8)
    failed = (flags & (DIVERGED | RANK_DEFICIENT | INVALID_START)) > 0
    finite = np.all(np.isfinite(error), axis=-1)
    judgeable = has_truth & ~singular & np.isfinite(d2)
    converged = (flags & CONVERGED) > 0
    out[judgeable & finite & ~failed & (d2 <= gate)] = TRUTH
    out[judgeable & finite & ~failed & (d2 > gate) & converged & (cost <= resid_gate)] = ELSEWHERE
    out[~judgeable & ~failed & finite] = UNCLASSIFIED
    out[failed | ~finite] = DIVERGED_CLASS
    out[(flags & UNDERDETERMINED) > 0] = UNDERDETERMINED_CLASS
    return out


def inside_ellipse(error2, cov2, probability=0.5):
    """Whether each 2-D error lies inside the ``probability`` ellipse of its covariance."""
    with np.errstate(all="ignore"):
        sol = np.linalg.solve(np.where(np.isfinite(cov2), cov2, np.eye(2)), error2[..., None])[..., 0]
    d2 = np.sum(error2 * sol, axis=-1)
    return d2 <= ellipse_scale(probability) ** 2


def _block_metrics(err, cov, sel, comps, prefix, unit):
    """RMSE, √trace(CRLB block), efficiency (bound / RMSE) and inside-50 % fraction over the
    selected cells."""
    if not sel.any() or not np.all(np.isfinite(err[sel][..., comps])):
        return {f"rmse_{prefix}_{unit}": np.nan, f"crlb_{prefix}_{unit}": np.nan,
                f"{prefix}_efficiency": np.nan, f"inside_50pct_{prefix}": np.nan}
    e = err[sel][..., comps]
    c = cov[sel][..., comps[:, None], comps[None, :]]
    mse = np.mean(np.sum(e * e, axis=-1))
    bound = np.mean(np.trace(c, axis1=-2, axis2=-1))
    with np.errstate(divide="ignore", invalid="ignore"):  # an error of exactly 0: inf (0 / 0: NaN)
        efficiency = float(np.sqrt(bound / mse))
    return {f"rmse_{prefix}_{unit}": float(np.sqrt(mse)), f"crlb_{prefix}_{unit}": float(np.sqrt(bound)),
            f"{prefix}_efficiency": efficiency,
            f"inside_50pct_{prefix}": float(np.mean(inside_ellipse(e, c)))}


def scope_metrics(classes, err_free, cov, cost, iterations, dof, free, sel):
    """All metrics of one tracker over the cells ``sel`` (bool, runs × epochs)."""
    row = {f"runs_{name}": float(np.sum(classes[sel] == k)) for k, name in enumerate(CLASSES)}
    row["runs"] = float(sel.sum())
    ok = sel & (classes == TRUTH)
    pos = np.array([0, 1])
    row.update(_block_metrics(err_free, cov, ok, pos, "position", "m"))
    if len(free) == 4:
        row.update(_block_metrics(err_free, cov, ok, np.array([2, 3]), "velocity", "mps"))
    if ok.any():
        row["mean_cost_per_dof"] = float(np.mean(cost[ok]) / dof) if dof > 0 else np.nan
        row["mean_iterations"] = float(np.mean(iterations[ok]))
    return row


def evaluate(times, tracks: dict, truth_state, sigma_range_m, sigma_rate_mps):
    """Per-epoch and summary tables.

    Parameters
    ----------
    times : ndarray (E,)
    tracks : dict
        ``tracker -> {"state", "flags", "iterates", "cost", "iterations", ...}`` (runs, epochs, ...),
        and the stage's :data:`CRLB_ENTRY` (see the module docstring).
    truth_state : ndarray (R, E, 4) or None
    sigma_range_m, sigma_rate_mps : ndarray (E,)
        The measurement noise per epoch in range units, c σ_TDOA and c σ_FDOA / f₀ averaged over
        runs and pairs (the axis of the paper's Fig. 7).
    """
    if CRLB_ENTRY not in tracks:
        raise InputError(f"the outputs lack the {CRLB_ENTRY!r} entry (the CRLB at the truth, written by the replay "
                         "beside the estimators); replay the data set again")
    crlb = tracks[CRLB_ENTRY]
    sigma_r = np.asarray(sigma_range_m, float)
    sigma_v = np.asarray(sigma_rate_mps, float)
    R, E = np.asarray(crlb[f"crlb_singular_{DEFAULT_KIND}"]).shape[:2]
    noise_varies = E > 1 and not np.allclose(sigma_r, sigma_r[0], rtol=1e-12)
    per_scan_parts, summary_rows = [], []
    for name, out in tracks.items():
        if name == CRLB_ENTRY:
            continue
        A, cov_free, singular = bound_of(crlb, name)
        n_rows, q = A.shape[-2:]
        free = np.arange(q)  # every estimator's unknowns are the first q components
        dof = n_rows - q
        flags = out["flags"]
        if truth_state is not None:
            err = out["state"][..., free] - truth_state[..., free]
        else:
            A = np.zeros((R, E, n_rows, q))
            cov_free = np.full((R, E, q, q), np.nan)
            singular = np.ones((R, E), bool)
            err = np.full((R, E, q), np.nan)
        classes = classify(flags, err, A, singular, out["cost"], dof, truth_state is not None)
        iterations = out["iterations"]
        every = np.ones((R, E), bool)
        base = {"tracker": name}
        summary_rows.append({**base, "scope": "overall",
                             **scope_metrics(classes, err, cov_free, out["cost"], iterations, dof, free, every),
                             "crlb_singular_cells": float(np.sum(singular)) if truth_state is not None else np.nan})
        cols = []
        for k in range(E):
            sel = np.zeros((R, E), bool)
            sel[:, k] = True
            m = scope_metrics(classes, err, cov_free, out["cost"], iterations, dof, free, sel)
            cols.append({"tracker": name, "scan": k, "time_s": float(times[k]), "sigma_range_m": float(sigma_r[k]),
                         "sigma_rate_mps": float(sigma_v[k]), **m})
            if noise_varies:
                summary_rows.append({**base, "scope": f"sigma_range_m={sigma_r[k]:.4g}", **m})
        per_scan_parts.append(pl.DataFrame(cols, infer_schema_length=None))
        # the paper's 5 vs 10 iterations: RMSE at every iteration over the runs that end at the truth
        ok = classes == TRUTH
        iterates = out["iterates"]
        last = iterates.shape[2] - 1
        for it in sorted({i for i in REPORTED_ITERATIONS if i <= last} | {last}):
            row = {**base, "scope": f"iteration={it:0{len(str(last))}d}"}
            if ok.any() and truth_state is not None:
                e = iterates[:, :, it][ok] - truth_state[ok]
                row["rmse_position_m"] = rmse_overall(e[:, :2], 0.0)
                if len(free) == 4:
                    row["rmse_velocity_mps"] = rmse_overall(e[:, 2:], 0.0)
                row["converged_fraction"] = float(np.mean(out["iterations"][ok] <= it))
            summary_rows.append(row)
    per_scan = pl.concat(per_scan_parts, how="diagonal")
    wide = pl.DataFrame(summary_rows, infer_schema_length=None)
    summary = long_form(wide, ["tracker", "scope"]).drop_nulls("value").select("tracker", "metric", "scope", "value")
    return per_scan, summary


def classes_of(tracks_out: dict, crlb: dict, name: str, truth_state) -> np.ndarray:
    """Classes (runs, epochs) of one tracker's estimates (for the Rerun views); ``crlb`` is the
    stage's :data:`CRLB_ENTRY` output over the same cells."""
    A, _, singular = bound_of(crlb, name)
    n_rows, q = A.shape[-2:]
    err = tracks_out["state"][..., :q] - truth_state[..., :q]
    return classify(tracks_out["flags"], err, A, singular, tracks_out["cost"], n_rows - q)


def report(summary: pl.DataFrame, per_scan: pl.DataFrame) -> str:
    """The paper's layouts: run classes and efficiency (√tr CRLB / RMSE) per estimator; RMSE per
    iteration; Fig. 7."""
    def get(tracker, metric, scope="overall"):
        v = summary.filter((pl.col("tracker") == tracker) & (pl.col("metric") == metric) & (pl.col("scope") == scope))["value"]
        return float(v[0]) if len(v) else float("nan")

    trackers = list(dict.fromkeys(summary["tracker"].to_list()))
    lines = ["TDOA/FDOA Gauss-Newton (Kim et al. 2013): runs by class; RMSE and efficiency (eff = √trCRLB / RMSE, "
             "≤ 1 up to Monte Carlo error) over 'truth' runs only",
             f"{'estimator':<10}{'truth':>7}{'elsewhere':>10}{'diverged':>9}{'not conv':>9}{'undeterm':>9}"
             f"{'RMSE pos m':>12}{'√trCRLB':>9}{'eff':>7}{'in 50%':>8}{'RMSE vel':>10}{'√trCRLB':>9}{'eff':>7}{'in 50%':>8}"]
    for t in trackers:
        lines.append(
            f"{t:<10}{get(t, 'runs_truth'):>7.0f}{get(t, 'runs_elsewhere'):>10.0f}{get(t, 'runs_diverged'):>9.0f}"
            f"{get(t, 'runs_not_converged'):>9.0f}{get(t, 'runs_underdetermined'):>9.0f}"
            f"{get(t, 'rmse_position_m'):>12.3f}{get(t, 'crlb_position_m'):>9.3f}{get(t, 'position_efficiency'):>7.3f}"
            f"{get(t, 'inside_50pct_position'):>8.3f}{get(t, 'rmse_velocity_mps'):>10.3f}{get(t, 'crlb_velocity_mps'):>9.3f}"
            f"{get(t, 'velocity_efficiency'):>7.3f}{get(t, 'inside_50pct_velocity'):>8.3f}")
    its = {int(s.split("=")[1]): s for s in summary["scope"].to_list() if s.startswith("iteration=")}
    if its:
        shown = sorted(its)
        lines.append("\nposition RMSE (m) after n iterations, same 'truth' runs:")
        lines.append(f"{'estimator':<10}" + "".join(f"{'n=' + str(i):>11}" for i in shown))
        for t in trackers:
            lines.append(f"{t:<10}" + "".join(f"{get(t, 'rmse_position_m', its[i]):>11.3f}" for i in shown))
    noise_scopes = [s for s in dict.fromkeys(summary["scope"].to_list()) if s.startswith("sigma_range_m=")]
    if noise_scopes:
        lines.append("\nFig. 7: position RMSE (m) vs noise, 0.1 σ_r = σ_v ('truth' runs; CRLB in brackets; "
                     "runs not at the truth in the last column)")
        lines.append(f"{'σ_r (m)':>10}" + "".join(f"{t:>24}" for t in trackers) + f"{'not truth':>14}")
        for s in noise_scopes:
            cells = []
            others = []
            for t in trackers:
                cells.append(f"{get(t, 'rmse_position_m', s):>11.3f} [{get(t, 'crlb_position_m', s):>9.3f}]")
                others.append(f"{get(t, 'runs', s) - get(t, 'runs_truth', s):.0f}")
            lines.append(f"{float(s.split('=')[1]):>10.4g}" + "".join(f"{c:>24}" for c in cells) + f"{'/'.join(others):>14}")
    return "\n".join(lines)
