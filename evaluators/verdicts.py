"""One line per tracker before the tables: the measures that matter with their intervals, and a
plain consistency verdict.

The verdict reads the consistency measures already in the summary (``docs/evaluation.md``,
"Filter consistency"): the time-averaged NEES against the interval a consistent filter's average
falls in (from the runs, which are independent), or, without truth, the time-averaged NIS against
its χ² interval. Above the interval the filter's errors are larger than its covariance says
(**optimistic**); below, smaller (**pessimistic**); inside, **consistent**; without a covariance or
an innovation covariance, **untestable**.
"""

from __future__ import annotations

import math

import polars as pl

#: measures the verdict line shows first, when a tracker has them (set errors, then assignment)
HEADLINE = ("gospa_mean_m", "gospa_mean_deg", "mota", "idf1", "hota")
#: (average, low bound, high bound) pairs the verdict tests, in order of preference
CONSISTENCY_TESTS = (("nees_time_average", "nees_time_average_low", "nees_time_average_high", "NEES"),
                     ("nis_time_average", "nis_time_average_low", "nis_time_average_high", "NIS"))


def consistency_verdict(value, low, high) -> str:
    """``consistent`` when ``low ≤ value ≤ high``, ``optimistic`` above, ``pessimistic`` below,
    ``untestable`` when any of the three is missing."""
    if any(v is None or (isinstance(v, float) and math.isnan(v)) for v in (value, low, high)):
        return "untestable"
    if value > high:
        return "optimistic"
    if value < low:
        return "pessimistic"
    return "consistent"


def tracker_verdicts(summary: pl.DataFrame, family_metrics=()) -> pl.DataFrame:
    """Per tracker: its headline measures and its consistency verdict.

    Parameters
    ----------
    summary : polars.DataFrame
        A replay's summary (``tracker, metric, scope, value, ci_low, ci_high``).
    family_metrics : sequence of str
        The family's own measures to show first (in scope ``overall``), e.g. the position RMSE.

    Returns
    -------
    polars.DataFrame
        ``tracker, verdict, tested_by, measures`` with ``measures`` a list of
        ``(metric, value, ci_low, ci_high)`` records.
    """
    overall = summary.filter(pl.col("scope") == "overall") if "scope" in summary.columns else summary
    rows = []
    for tracker in overall["tracker"].unique(maintain_order=True).to_list():
        if tracker is None:
            continue
        mine = overall.filter(pl.col("tracker") == tracker)
        cell = {r["metric"]: r for r in mine.iter_rows(named=True)}
        verdict, tested_by = "untestable", ""
        for average, low, high, label in CONSISTENCY_TESTS:
            if average in cell:
                v = consistency_verdict(cell[average]["value"], cell.get(low, {}).get("value"),
                                        cell.get(high, {}).get("value"))
                if v != "untestable":
                    verdict, tested_by = v, label
                    break
        shown = [m for m in (*family_metrics, *HEADLINE) if m in cell and cell[m]["value"] is not None]
        measures = [{"metric": m, "value": cell[m]["value"], "ci_low": cell[m].get("ci_low"),
                     "ci_high": cell[m].get("ci_high")} for m in dict.fromkeys(shown)]
        if measures or tested_by:  # an estimator's side outputs (no track) have neither
            rows.append({"tracker": tracker, "verdict": verdict, "tested_by": tested_by, "measures": measures})
    return pl.DataFrame(rows, schema={"tracker": pl.String, "verdict": pl.String, "tested_by": pl.String,
                                      "measures": pl.List(pl.Struct({"metric": pl.String, "value": pl.Float64,
                                                                     "ci_low": pl.Float64, "ci_high": pl.Float64}))})
