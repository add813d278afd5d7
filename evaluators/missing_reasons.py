"""Why a metric has no value: the ``note`` column of the metrics table.

A metric is NaN (or null) when the data give it nothing to average: no track was ever started,
no estimate fell in the class it is taken over, a bound does not exist at the design values, a
covariance is not positive definite… A bare NaN says none of this, so every such row of the
summary gets a one-line reason in the ``note`` column (null where the metric has a value),
written to ``metrics.csv`` / ``metrics.parquet``, printed with ``replay eval --json`` and under
the printed tables (``docs/evaluation.md``, "Metrics without a value").

The reason is read from what the tracker returned (its ``state``, ``flags``, covariances and
innovations, in the vocabulary of ``docs/contract.md``) and from the other rows of the same
summary (e.g. the emitter family's ``runs_truth`` count, or the base metric of a ``_low`` /
``_high`` bound), never from how a tracker works, so one function serves every family. The
checks run from the most basic cause to the most specific, and the first that holds is given.
"""

from __future__ import annotations

import numpy as np
import polars as pl

from trackreplay.batched_linalg import cholesky_lower, positive_definite
from trackreplay.vocabulary import DELETED, INITIALISING, NO_TRACK, NOT_POSITIVE_DEFINITE, flag_names

NOTE = "note"
#: the reason of a metric that compares with a truth the data set does not have
NO_TRUTH = "the data set has no truth to compare the estimates with"

#: metrics taken over the emitter family's estimates in its ``truth`` class (trackreplay.evaluators.tdoa_fdoa)
TRUTH_CLASS_METRICS = ("rmse_position_m", "crlb_position_m", "position_efficiency", "inside_50pct_position",
                       "rmse_velocity_mps", "crlb_velocity_mps", "velocity_efficiency", "inside_50pct_velocity",
                       "mean_cost_per_dof", "mean_iterations", "converged_fraction")
#: the emitter family's class counts, in the order of trackreplay.evaluators.tdoa_fdoa.CLASSES
CLASS_COUNTS = ("runs_truth", "runs_elsewhere", "runs_diverged", "runs_not_converged", "runs_underdetermined",
                "runs_unclassified")
#: metrics that read a state's covariance (NEES and the error ellipses)
COVARIANCE_METRICS = ("nees", "anees", "inside_50pct", "idp")
#: metrics that read the innovations and their covariance
INNOVATION_METRICS = ("nis", "anis", "mean_nis", "whiteness")
#: metrics that pair tracks with true targets
MATCHED_METRICS = ("motp", "idp", "rmse_matched", "nees", "anees", "scans_to_confirmation")
#: bounds that need an information matrix at the truth
BOUND_METRICS = ("pcrb_", "crlb_")


def _missing(value) -> bool:
    return value is None or value != value


def _count(mask) -> int:
    return int(np.count_nonzero(mask))


class _TrackerFacts:
    """What one tracker's outputs say, computed once and only when a reason needs it."""

    def __init__(self, out: dict, innovation=None):
        self.out = out
        self.innovation = innovation
        state = np.asarray(out["state"])
        flags = out.get("flags")
        # flags are shaped like the state without its last axis (checked when the tracker ran)
        self.flags = (np.zeros(state.shape[:-1], np.int64) if flags is None
                      else np.asarray(flags).astype(np.int64).reshape(state.shape[:-1]))
        # an estimate: some component finite where the slot holds a track
        self.estimate = np.isfinite(state).any(axis=-1) & ((self.flags & NO_TRACK) == 0)

    def common_flags(self) -> str:
        """Names of the flags every cell carries ('' when none does)."""
        common = np.bitwise_and.reduce(self.flags.reshape(-1)) if self.flags.size else 0
        return ", ".join(flag_names(int(common)))

    def confirmed(self) -> int:
        return _count(self.estimate & ((self.flags & (INITIALISING | DELETED)) == 0))

    def tentative(self) -> int:
        return _count(self.estimate & ((self.flags & INITIALISING) > 0))

    def not_positive_definite(self, compared=None) -> int:
        """Estimates whose covariance is not positive definite: over the ``compared`` components
        (those a NEES reads; a component known exactly, with zero variance, elsewhere in the
        state does not matter to it), else as the flag ``NOT_POSITIVE_DEFINITE`` says."""
        cov = self.out.get("covariance")
        if compared is None or cov is None:
            return _count(self.estimate & ((self.flags & NOT_POSITIVE_DEFINITE) > 0))
        which = np.asarray(compared)
        block = np.asarray(cov)[self.estimate][:, which[:, None], which[None, :]]
        with np.errstate(invalid="ignore", divide="ignore"):
            factor = cholesky_lower(np.ascontiguousarray(np.moveaxis(block, 0, -1)))
        return _count(~positive_definite(factor))

    def finite_nis(self):
        """Cells with a finite NIS, or None when the tracker reports no innovation covariance."""
        if self.innovation is None:
            return None
        return _count(np.isfinite(self.innovation[1]))


def _side_output_reason(out: dict) -> str | None:
    """An estimator's side outputs (no ``state``): its float arrays all NaN is the reason."""
    arrays = {k: np.asarray(v) for k, v in out.items() if k != "flags"}
    empty = [k for k, a in arrays.items() if a.dtype.kind == "f" and a.size and not np.isfinite(a).any()]
    if empty and len(empty) == sum(a.dtype.kind == "f" for a in arrays.values()):
        return f"the estimator's outputs ({', '.join(empty)}) are NaN in every run and scan"
    return None


def _class_counts(rows: dict, tracker: str, scope: str) -> dict | None:
    counts = {m: rows.get((tracker, m, scope)) for m in CLASS_COUNTS}
    if _missing(counts["runs_truth"]):
        return None
    return counts


def _reason(tracker: str, metric: str, scope: str, facts: _TrackerFacts | None, rows: dict, out,
            compared=None, truthless=False) -> str:
    """The first cause that holds, from the most basic to the most specific."""
    if scope.startswith("no "):  # the standard measures' own convention: the scope says it
        return f"{scope}: the tracker reports none"
    if facts is None:
        side = _side_output_reason(out) if out is not None else None
        return side or "no run or scan gives this metric a value"
    if not facts.estimate.any():
        common = facts.common_flags()
        if common == "NO_TRACK":
            return "no track in any run or scan (every scan NO_TRACK)"
        return "no estimate in any run or scan" + (f" (every cell flagged {common})" if common else "")
    if truthless and not metric.startswith(INNOVATION_METRICS):
        return NO_TRUTH
    if metric in TRUTH_CLASS_METRICS:
        counts = _class_counts(rows, tracker, scope)
        if counts is not None and counts["runs_truth"] == 0:
            others = ", ".join(f"{int(v)} {k[5:].replace('_', ' ')}" for k, v in counts.items()
                               if k != "runs_truth" and not _missing(v) and v > 0)
            return "no estimate in the 'truth' class, over which it is taken" + (f" ({others})" if others else "")
    if metric.endswith(("_low", "_high", "_inside")):
        base = metric.rsplit("_", 1)[0]
        if (tracker, base, scope) in rows:
            if _missing(rows[(tracker, base, scope)]):
                return f"derived from {base}, which has no value: {_reason(tracker, base, scope, facts, rows, out, compared, truthless)}"
            if _missing(rows.get((tracker, base, scope, "ci"))):
                return (f"the bounds of {base} come from its interval over Monte Carlo runs, which has no value "
                        "(it needs finite values in at least two runs)")
    if metric.startswith(MATCHED_METRICS + ("track_lifetime",)) and facts.confirmed() == 0:
        tentative = facts.tentative()
        return ("no scan with a confirmed track" +
                (f": tracks were tentative in {tentative} (run, scan, slot) cells, none confirmed (M-of-N)" if tentative else ""))
    if metric.startswith(INNOVATION_METRICS):
        finite = facts.finite_nis()
        if finite is None:
            return "the tracker reports no innovation covariance"
        if finite == 0 and not np.isfinite(np.asarray(facts.out["innovation"])).any():
            return "no innovation in any run or scan: no measurement was used (every scan coasted)"
        if finite == 0:
            return ("no finite NIS: the innovation covariance is not positive definite (or its inverse overflows) "
                    "wherever there is an innovation")
        if metric.startswith("whiteness"):
            w = np.asarray(facts.innovation[0])
            finite_w = np.abs(w[np.isfinite(w)])
            if not finite_w.size:
                return "no whitened innovation in any run or scan"
            largest = float(finite_w.max())
            # a correlation over lags multiplies pairs of whitened innovations: beyond √(float max)
            # their products overflow
            if largest == 0:
                return "every whitened innovation is 0: a correlation has no spread to divide by"
            if largest > np.sqrt(np.finfo(float).max):
                return f"the whitened innovations overflow when multiplied (largest |w| = {largest:.3g})"
            return "no two scans at any lag both have a whitened innovation"
    if metric.startswith(COVARIANCE_METRICS):
        flagged = facts.not_positive_definite(compared)
        if flagged:
            return f"covariance not positive definite in {flagged} of {_count(facts.estimate)} estimates"
    if metric.endswith("_efficiency"):
        bound = next((k[1] for k in rows if len(k) == 3 and k[0] == tracker and k[2] == scope
                      and k[1].startswith(BOUND_METRICS) and k[1].split("_")[1] == metric.split("_")[0]), None)
        if bound is not None and _missing(rows[(tracker, bound, scope)]):
            return f"its bound {bound} has no value"
    if metric.endswith("_held") and not (rows.get((tracker, "held_rate", scope)) or 0) > 0:
        # taken over the tracks held (on their own target at the last scan, never swapped:
        # trackreplay.evaluators.xcorr)
        return "no track held its target to the last scan, over which it is taken"
    if metric.startswith(BOUND_METRICS):
        return ("the bound is not finite at any scan scored here: its information matrix is singular or overflows "
                "at these design values")
    if metric.startswith(MATCHED_METRICS) and _missing(rows.get((tracker, "motp", scope, "any unit"), 0.0)):
        # MOTP is the mean distance over matched pairs: without a value, there was no pair
        return "no track was matched to a true target (none inside the assignment gate at any scan)"
    return "no run or scan gives this metric a value on these data"


def explain_missing(summary: pl.DataFrame, tracks: dict, innovations: dict | None = None,
                    compared=None, truthless: bool = False) -> pl.DataFrame:
    """``summary`` with a ``note`` column: the reason of every metric without a value.

    Parameters
    ----------
    summary : polars.DataFrame
        Long form ``tracker, metric, scope, value[, ci_low, …]`` of one stage.
    tracks : dict
        ``name -> outputs`` in the vocabulary (``docs/contract.md``), the stage's own estimators'
        side outputs included.
    innovations : dict, optional
        ``name ->`` :func:`trackreplay.evaluators.consistency.whitened_innovations` (``(w, nis)`` or None), when
        already computed.
    compared : sequence of int, optional
        The state components the standard measures compare with the truth (and a NEES reads);
        without it a covariance counts as not positive definite where its flags say so.
    truthless : bool
        The data set has no truth: a metric that compares with it has none to compare.

    Returns
    -------
    polars.DataFrame
        The same rows and columns plus ``note`` (str): null where the metric has a value.
    """
    if not {"tracker", "metric", "scope", "value"} <= set(summary.columns) or not summary.height:
        return summary.with_columns(pl.lit(None, pl.String).alias(NOTE))
    value = pl.col("value")
    missing = value.is_null() | value.is_nan()
    if not summary.select(missing.any()).item():
        return summary.with_columns(pl.lit(None, pl.String).alias(NOTE))
    ci = summary["ci_low"] if "ci_low" in summary.columns else pl.Series([None] * summary.height, dtype=pl.Float64)
    rows = {}
    for t, m, s, v, c in zip(summary["tracker"], summary["metric"], summary["scope"], summary["value"], ci):
        rows[(t, m, s)] = v
        rows[(t, m, s, "ci")] = c
        if m.startswith("motp_"):  # in the space's unit (m, deg, …)
            rows[(t, "motp", s, "any unit")] = v
    facts: dict = {}
    notes = []
    for t, m, s, v in zip(summary["tracker"], summary["metric"], summary["scope"], summary["value"]):
        if not _missing(v):
            notes.append(None)
            continue
        out = tracks.get(t)
        if t not in facts:
            facts[t] = (_TrackerFacts(out, (innovations or {}).get(t) if innovations is not None else _innovation(out))
                        if out is not None and "state" in out else None)
        notes.append(_reason(t, m, s or "", facts[t], rows, out, compared, truthless))
    return summary.with_columns(pl.Series(NOTE, notes, dtype=pl.String))


def _innovation(out):
    from trackreplay.evaluators.consistency import whitened_innovations

    return whitened_innovations(out)


def notes_by_tracker(summary: pl.DataFrame) -> list[tuple[str, list[str], str]]:
    """``(tracker, metrics, note)`` for every distinct reason of a tracker, metrics in table order
    (what the printed summary lists under its tables)."""
    if NOTE not in summary.columns:
        return []
    groups: dict = {}
    for t, m, n in zip(summary["tracker"], summary["metric"], summary[NOTE]):
        if n is not None:
            groups.setdefault((t, n), dict())[m] = None
    return [(t, list(ms), n) for (t, n), ms in groups.items()]

