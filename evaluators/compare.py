"""Paired comparison of two replays of the same data set: which metric differences are real.

Both replays ran on the same Monte Carlo runs, so their metrics are compared run against run: the
difference ``A − B`` of every metric is recomputed with each group of runs left out (the grouped
jackknife of :mod:`trackreplay.evaluators.confidence`), and the interval of the difference, not of each
metric, decides. Pairing removes the scenario's own run-to-run spread, which both share, so much
smaller differences are resolved than by comparing two intervals side by side. See
``docs/evaluation.md``.

Verdicts per metric: ``better`` / ``worse`` (for A, where the metric has a direction and the
95 % interval of the difference excludes 0), ``higher`` / ``lower`` (a metric without a
direction, e.g. a gain), ``no significant difference`` (the interval covers 0, or the two are
equal).
"""

from __future__ import annotations

import re

import numpy as np
import polars as pl

from trackreplay.evaluators.confidence import summary_intervals

KEY = ["tracker", "metric", "scope"]

# metric-name patterns where lower is better / higher is better (first match wins)
LOWER_IS_BETTER = re.compile(r"(rmse|rms_|ospa|gospa|npe|miss|false|break|switch|lost|swap|cep|bias|error|"
                             r"mostly_lost|partially_tracked|clamped|coasted|diverged|failed|"
                             r"^siap_ambiguity$|^siap_spuriousness$|^siap_position_accuracy|"
                             r"^siap_velocity_accuracy|^siap_track_number_change_rate$)")
HIGHER_IS_BETTER = re.compile(r"(mota|idf1|^idp$|^idr$|^hota$|^deta$|^assa$|^loca$|held|success|efficiency|"
                              r"mostly_tracked|inside_fraction|converged|^siap_completeness$|"
                              r"^siap_longest_track_segment$)")


def direction(metric: str) -> int:
    """−1 where lower is better, +1 where higher is better, 0 where the metric has no direction."""
    if HIGHER_IS_BETTER.search(metric):
        return 1
    if LOWER_IS_BETTER.search(metric):
        return -1
    return 0


def pair_trackers(names_a, names_b, pairs=None) -> list[tuple[str, str]]:
    """Which tracker of A is compared with which of B: ``pairs`` if given, else every name the
    two share, else the one tracker of each.

    Raises
    ------
    ValueError
        When nothing pairs.
    """
    if pairs:
        for a, b in pairs:  # a name neither output holds is the user's slip, said plainly
            for name, names, side in ((a, names_a, "A"), (b, names_b, "B")):
                if name not in names:
                    raise ValueError(f"--pair {a}:{b}: {side} has no tracker {name!r} (it has: {', '.join(names)})")
        return list(pairs)
    common = [n for n in names_a if n in names_b]
    if common:
        return [(n, n) for n in common]
    if len(names_a) == 1 and len(names_b) == 1:
        return [(names_a[0], names_b[0])]
    raise ValueError(f"the two outputs share no tracker (A: {', '.join(names_a)}; B: {', '.join(names_b)}); "
                     "name the pair with --pair A_NAME:B_NAME")


def verdict(metric: str, diff: float, low, high) -> str:
    if diff == 0 or low is None or high is None or not (low > 0 or high < 0):
        return "no significant difference"
    d = direction(metric)
    if d == 0:
        return "higher" if diff > 0 else "lower"
    return "better" if d * diff > 0 else "worse"


def paired_differences(score, tracks_a: dict, tracks_b: dict, reference_runs: dict, n_runs: int, pairs,
                       groups: int = 10) -> pl.DataFrame:
    """Every metric of A and B with the paired difference, its interval and a verdict.

    Parameters
    ----------
    score : callable
        ``score(tracks, reference_runs) -> (per_scan, summary)`` for one replay's trackers
        (summary in long form with ``tracker, metric, scope, value``).
    tracks_a, tracks_b : dict
        ``name -> outputs`` of each replay (arrays with a leading run axis).
    reference_runs : dict
        The data set's per-run arrays the score needs (truth, ...), shared by both.
    pairs : list of (str, str)
        Trackers of A and B to compare (see :func:`pair_trackers`).

    Returns
    -------
    polars.DataFrame
        ``tracker_a, tracker_b, metric, scope, value_a, value_b, difference, se, ci_low,
        ci_high, verdict``.
    """

    def both(runs):
        a = {f"{na}": runs["a"][na] for na, _ in pairs}
        b = {f"{nb}": runs["b"][nb] for _, nb in pairs}
        _, sa = score(a, runs["reference"])
        _, sb = score(b, runs["reference"])
        name_of_b = {nb: na for na, nb in pairs}
        sb = sb.filter(pl.col("tracker").is_in(list(name_of_b))).with_columns(
            pl.col("tracker").replace_strict(name_of_b).alias("tracker"))
        sa = sa.filter(pl.col("tracker").is_in([na for na, _ in pairs]))
        joined = sa.select(*KEY, pl.col("value").alias("value_a")).join(
            sb.select(*KEY, pl.col("value").alias("value_b")), on=KEY, how="inner")
        joined = joined.filter(pl.col("value_a").is_not_null() & pl.col("value_b").is_not_null())
        return joined, joined.with_columns((pl.col("value_a") - pl.col("value_b")).alias("value")).select(*KEY, "value")

    runs = {"a": {na: tracks_a[na] for na, _ in pairs}, "b": {nb: tracks_b[nb] for _, nb in pairs},
            "reference": reference_runs}
    joined, _ = both(runs)
    _, diffs = summary_intervals(lambda r: (None, both(r)[1]), runs, n_runs, groups)
    out = joined.join(diffs.rename({"value": "difference"}), on=KEY, how="left")
    name_b = dict(pairs)
    out = out.with_columns(pl.col("tracker").alias("tracker_a"),
                           pl.col("tracker").replace_strict(name_b).alias("tracker_b")).drop("tracker")
    verdicts = [verdict(r["metric"], r["difference"], r["ci_low"], r["ci_high"]) for r in out.iter_rows(named=True)]
    return out.with_columns(pl.Series("verdict", verdicts, pl.String)).select(
        "tracker_a", "tracker_b", "metric", "scope", "value_a", "value_b", "difference", "se", "ci_low", "ci_high",
        "verdict")


def write_comparison_figure(table: pl.DataFrame, path, title: str = "") -> None:
    """Differences A − B relative to |B| with their 95 % intervals, one row per metric."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = table.filter(pl.col("ci_low").is_not_null() & (pl.col("value_b").abs() > 0))
    labels = [f"{r['metric']} [{r['scope']}] {r['tracker_a']}" for r in t.iter_rows(named=True)]
    scale = np.abs(t["value_b"].to_numpy())
    d, lo, hi = (t[c].to_numpy() / scale * 100 for c in ("difference", "ci_low", "ci_high"))
    colours = {"better": "tab:green", "worse": "tab:red"}
    fig, ax = plt.subplots(figsize=(9, max(2.5, 0.22 * len(labels) + 1)))
    y = np.arange(len(labels))
    for i, v in enumerate(t["verdict"].to_list()):
        ax.errorbar(d[i], y[i], xerr=[[d[i] - lo[i]], [hi[i] - d[i]]], fmt="o", ms=3,
                    color=colours.get(v, "tab:gray"), capsize=2)
    ax.axvline(0, color="k", lw=0.8)
    ax.set_yticks(y, labels, fontsize=6)
    ax.invert_yaxis()
    ax.set_xlabel("A − B, % of B (95 % paired interval; green better, red worse for A)")
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
