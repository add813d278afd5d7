"""One line per tracker before the tables: the measures that matter with their intervals, and a
plain consistency verdict.

The verdict reads the consistency measures already in the summary (``docs/evaluation.md``,
"Filter consistency"): the time-averaged NEES against the interval a consistent filter's average
falls in (from the runs, which are independent), or, without truth, the time-averaged NIS against
its χ² interval. Above the interval the filter's errors are larger than its covariance says
(**optimistic**); below, smaller (**pessimistic**); inside, **consistent**; without a covariance or
an innovation covariance, **untestable**. Far above it (more than :data:`IMPLAUSIBLE_FACTOR` times
the interval's top) the track is **implausible**: its squared errors are an order of magnitude
beyond what its covariance allows, which a mistuned filter on its own target does not produce
but a track following clutter or another object does (a recording replayed without a gate, say);
the verdict then says so in words.
"""

from __future__ import annotations

import math

import polars as pl

#: measures the verdict line shows first, when a tracker has them (set errors, then assignment)
HEADLINE = ("gospa_mean_m", "gospa_mean_deg", "mota", "idf1", "hota")
#: (average, low bound, high bound) pairs the verdict tests, in order of preference
CONSISTENCY_TESTS = (("nees_time_average", "nees_time_average_low", "nees_time_average_high", "NEES"),
                     ("nis_time_average", "nis_time_average_low", "nis_time_average_high", "NIS"))


#: an average above this many times its interval's top is implausible, not merely optimistic
IMPLAUSIBLE_FACTOR = 10.0


def consistency_verdict(value, low, high) -> str:
    """``consistent`` when ``low ≤ value ≤ high``, ``optimistic`` above, ``implausible`` above
    :data:`IMPLAUSIBLE_FACTOR` times ``high``, ``pessimistic`` below, ``untestable`` when any of
    the three is missing."""
    if any(v is None or (isinstance(v, float) and math.isnan(v)) for v in (value, low, high)):
        return "untestable"
    if value > IMPLAUSIBLE_FACTOR * high:
        return "implausible"
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
        ``tracker, verdict, tested_by, note, measures`` with ``measures`` a list of
        ``(metric, value, ci_low, ci_high)`` records and ``note`` the plain words of an
        implausible verdict (empty otherwise).
    """
    overall = summary.filter(pl.col("scope") == "overall") if "scope" in summary.columns else summary
    rows = []
    for tracker in overall["tracker"].unique(maintain_order=True).to_list():
        if tracker is None:
            continue
        mine = overall.filter(pl.col("tracker") == tracker)
        cell = {r["metric"]: r for r in mine.iter_rows(named=True)}
        verdict, tested_by, note = "untestable", "", ""
        for average, low, high, label in CONSISTENCY_TESTS:
            if average in cell:
                value, bottom, top = (cell[average]["value"], cell.get(low, {}).get("value"),
                                      cell.get(high, {}).get("value"))
                v = consistency_verdict(value, bottom, top)
                if v != "untestable":
                    verdict, tested_by = v, label
                    if v == "implausible":
                        note = (f"average {label} {value:.3g} where a consistent filter's falls in "
                                f"[{bottom:.3g}, {top:.3g}]: its errors are about {math.sqrt(value / top):.0f}× "
                                "what its covariance allows, so the track likely follows clutter or another "
                                "object (no gate, or many targets for a single-target tracker)")
                    break
        shown = [m for m in (*family_metrics, *HEADLINE) if m in cell and cell[m]["value"] is not None]
        measures = [{"metric": m, "value": cell[m]["value"], "ci_low": cell[m].get("ci_low"),
                     "ci_high": cell[m].get("ci_high")} for m in dict.fromkeys(shown)]
        if measures or tested_by:  # an estimator's side outputs (no track) have neither
            rows.append({"tracker": tracker, "verdict": verdict, "tested_by": tested_by, "note": note,
                         "measures": measures})
    return pl.DataFrame(rows, schema={"tracker": pl.String, "verdict": pl.String, "tested_by": pl.String,
                                      "note": pl.String,
                                      "measures": pl.List(pl.Struct({"metric": pl.String, "value": pl.Float64,
                                                                     "ci_low": pl.Float64, "ci_high": pl.Float64}))})
