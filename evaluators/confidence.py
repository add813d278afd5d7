"""Monte Carlo uncertainty of metrics: standard errors and 95 % intervals over independent runs.

Every metric of a replay is a function of independent Monte Carlo runs, so its sampling error
can be estimated from the runs themselves. Two tools:

* closed forms for the common shapes: the mean of per-run values (Student t interval), and a
  root mean square (the t interval of the mean square, mapped through the square root);
* the **grouped jackknife** for any other metric (Efron & Tibshirani 1993, ch. 11): the runs are
  dealt into G groups, the metric is recomputed with each group left out, and
  ``SE = √((G − 1)/G · Σ_g (θ₍g₎ − θ̄)²)``, with a t interval on G − 1 degrees of freedom. It
  is exact for sums and means and first-order right for smooth functions of them (RMSE, NEES
  averages, rates), and needs only G re-evaluations of the metric, not one per bootstrap draw.
  A metric that is a function of sums over runs needs none: its G estimates come from the
  groups' totals (:func:`group_totals`, :func:`ratio_jackknife`, ``score_groups`` of
  :func:`summary_intervals`), one pass over the runs.

See ``docs/evaluation.md``.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from trackreplay.evaluators.tracking_metrics import nanmean

JACKKNIFE_GROUPS = 20
ROUNDING_SPREAD = 1e-12  # a standard error this small relative to its value is rounding, reported as 0


def t_quantile(dof, prob: float = 0.95):
    """Two-sided ``prob`` quantile of Student's t (array-like ``dof``; NaN where dof < 1)."""
    # stdtrit is the quantile scipy.stats.t.ppf evaluates, without importing scipy.stats (0.5 s)
    from scipy.special import stdtrit

    dof = np.asarray(dof, float)
    dof = np.where(dof >= 1, dof, np.nan)
    if dof.size <= 16:
        return stdtrit(dof, (1 + prob) / 2)
    # the degrees of freedom of a per-scan table repeat (runs - 1 in almost every scan), and
    # stdtrit's inversion costs ~0.1 ms a value: evaluate each distinct one once (same values)
    distinct, where = np.unique(dof, return_inverse=True)
    return stdtrit(distinct, (1 + prob) / 2)[where.reshape(dof.shape)]


def mean_interval(values, axis: int = 0, prob: float = 0.95):
    """Mean over ``axis`` of independent values (NaN left out), its standard error and interval.

    Returns
    -------
    mean, se, low, high : ndarray
    """
    v = np.asarray(values, float)
    n = np.sum(np.isfinite(v), axis=axis)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.nansum(v, axis=axis) / n
        dev = np.where(np.isfinite(v), v - np.expand_dims(mean, axis), 0.0)
        var = np.sum(dev * dev, axis=axis) / (n - 1)
        se = np.sqrt(var / n)
    half = t_quantile(n - 1, prob) * se
    return mean, se, mean - half, mean + half


def rms_interval(squared, axis: int = 0, prob: float = 0.95):
    """RMS from per-run mean squares, with the interval of the mean square mapped by √.

    ``squared`` holds one mean square per run (or per run and scan); the RMS is √(mean). The
    square root is monotone, so the mapped interval keeps the coverage of the mean's; the
    standard error is the delta-method ``se(mean) / (2 RMS)``.
    """
    mean, se, lo, hi = mean_interval(squared, axis, prob)
    rms = np.sqrt(mean)
    with np.errstate(invalid="ignore", divide="ignore"):
        return rms, se / (2 * rms), np.sqrt(np.maximum(lo, 0.0)), np.sqrt(hi)


def wilson_interval(successes, trials, prob: float = 0.95, quantile=None):
    """Wilson score interval of a proportion: inside [0, 1], and well behaved at 0 and 1 where
    the Wald interval ``p ± z√(p(1−p)/n)`` leaves [0, 1] or shrinks to a point.

    ``quantile`` replaces the normal quantile z (e.g. by Student's t where the trials are an
    effective number estimated with few degrees of freedom, :func:`proportion_intervals`).
    """
    from scipy.special import ndtri  # the normal quantile, without importing scipy.stats

    k, n = np.asarray(successes, float), np.asarray(trials, float)
    z = ndtri((1 + prob) / 2) if quantile is None else np.asarray(quantile, float)
    with np.errstate(invalid="ignore", divide="ignore"):
        p = k / n
        centre = (p + z * z / (2 * n)) / (1 + z * z / n)
        half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return centre - half, centre + half


#: rates that are one outcome per Monte Carlo run (per track for the ``track=`` scopes): the
#: interval is Wilson's with the runs as the trials (:func:`proportion_intervals`)
RUN_PROPORTIONS = frozenset({"success_rate", "swap_rate", "loss_rate", "coalescence_rate",
                             "held_rate", "swapped_rate", "lost_rate"})
#: rates pooled over several outcomes per run (scans, epochs, cells): Wilson's interval with the
#: effective number of trials that the spread over groups of runs implies
POOLED_PROPORTIONS = frozenset({"converged_fraction", "flagged_fraction", "inside_50pct_position",
                                "inside_50pct_velocity"})


def proportion_intervals(metrics, value, se, n_runs: int, dof, prob: float = 0.95):
    """Intervals inside [0, 1] for the rates among ``metrics``; ``(low, high)`` arrays, NaN for
    every other metric (which keeps its t interval).

    Runs are the independent units, so how the interval is built depends on what a rate counts:

    * **one outcome per run** (:data:`RUN_PROPORTIONS`, e.g. the success rate): the number of
      successes is binomial over the ``n_runs`` runs, and the interval is Wilson's on them.
      A value that is not a whole number of runs (some runs missing) is taken as pooled;
    * **several outcomes per run** (:data:`POOLED_PROPORTIONS`, e.g. a fraction over scans):
      outcomes within a run may be correlated, so the binomial count of outcomes overstates
      the information. The standard error ``se`` over groups of runs already holds that
      correlation; it implies an effective number of trials ``n_eff = p(1 − p)/se²`` (the
      outcomes divided by the design effect), and the interval is Clopper–Pearson's on
      ``n_eff`` trials shrunk by ``(z/t_dof)²`` for the groups' few degrees of freedom (Korn &
      Graubard 1998, *Survey Methodology* 24, 193–201; :func:`clopper_pearson_interval`).
      Where ``se`` is 0 (every group at 0 or every group at 1), ``n_eff`` is the number of
      runs: a run's outcomes count as one.

    Both stay inside [0, 1] and contain the value.
    """
    names = np.asarray(list(metrics), dtype=object)
    p, se = np.asarray(value, float), np.asarray(se, float)
    low, high = np.full(p.shape, np.nan), np.full(p.shape, np.nan)
    if not n_runs:
        return low, high
    run = np.isin(names, list(RUN_PROPORTIONS)) & np.isfinite(p)
    whole = np.abs(p * n_runs - np.round(p * n_runs)) <= 1e-6
    pooled = (np.isin(names, list(POOLED_PROPORTIONS)) | (run & ~whole)) & np.isfinite(p)
    run &= whole
    if run.any():
        low[run], high[run] = wilson_interval(np.round(p[run] * n_runs), n_runs, prob)
    if pooled.any():
        q = np.clip(p[pooled], 0.0, 1.0)
        s = se[pooled]
        with np.errstate(invalid="ignore", divide="ignore"):
            n_eff = np.where(np.isfinite(s) & (s > 0), q * (1 - q) / (s * s), np.nan)
        n_eff = np.where(np.isfinite(n_eff) & (n_eff > 0), n_eff, float(n_runs))
        low[pooled], high[pooled] = clopper_pearson_interval(q * n_eff, n_eff, prob, dof)
    low, high = np.clip(low, 0.0, 1.0), np.clip(high, 0.0, 1.0)
    inside = np.isfinite(low)
    # rounding alone can put the value a hair outside at 0 or 1
    low[inside], high[inside] = np.minimum(low[inside], p[inside]), np.maximum(high[inside], p[inside])
    return low, high


def clopper_pearson_interval(successes, trials, prob: float = 0.95, dof=None):
    """Clopper–Pearson interval of a proportion from (possibly fractional, effective)
    ``successes`` out of ``trials``; with ``dof`` the Korn–Graubard form, whose trials are
    first multiplied by ``(z/t_dof)²`` (an effective count estimated on ``dof`` degrees of
    freedom). Inside [0, 1]; 0 and 1 are reached at no and at every success."""
    from scipy.special import betaincinv, ndtri

    k, n = np.asarray(successes, float), np.asarray(trials, float)
    if dof is not None:
        shrink = (ndtri((1 + prob) / 2) / t_quantile(dof, prob)) ** 2
        k, n = k * shrink, n * shrink
    alpha = 1 - prob
    with np.errstate(invalid="ignore", divide="ignore"):
        low = np.where(k > 0, betaincinv(np.maximum(k, 1e-300), n - k + 1, alpha / 2), 0.0)
        high = np.where(k < n, betaincinv(k + 1, np.maximum(n - k, 1e-300), 1 - alpha / 2), 1.0)
    return low, high


def run_groups(n_runs: int, groups: int = JACKKNIFE_GROUPS) -> list[np.ndarray]:
    """Runs dealt into at most ``groups`` groups (run r goes to group r mod G): deterministic."""
    g = min(groups, n_runs)
    return [np.arange(i, n_runs, g) for i in range(g)] if g >= 2 else []


def jackknife(statistic, n_runs: int, groups: int = JACKKNIFE_GROUPS, prob: float = 0.95):
    """Grouped-jackknife standard error and interval of ``statistic(runs) -> ndarray``.

    Parameters
    ----------
    statistic : callable
        Maps an array of run indices to the metric values (any shape, NaN allowed); called once
        with all runs and once per group left out.
    n_runs : int
    groups : int

    Returns
    -------
    value, se, low, high : ndarray
        ``value`` from all runs; NaN intervals with fewer than two runs.
    """
    everything = np.arange(n_runs)
    value = np.asarray(statistic(everything), float)
    parts = run_groups(n_runs, groups)
    if not parts:
        nan = np.full(value.shape, np.nan)
        return value, nan, nan, nan

    def without(part):
        # a mask over runs rather than a set difference (which sorts): the same indices, in order
        kept = np.ones(n_runs, bool)
        kept[part] = False
        return everything[kept]

    left_out = np.stack([np.asarray(statistic(without(p)), float) for p in parts])
    return _jackknife_interval(value, left_out, prob)


def _jackknife_interval(value, left_out, prob: float):
    """``value, se, low, high`` of the grouped jackknife from the G leave-one-group-out
    estimates ``left_out`` (G, ...)."""
    G = left_out.shape[0]
    with np.errstate(invalid="ignore"):
        se = np.sqrt((G - 1) / G * _sum_of_squared_deviations(left_out))
        se = np.where(se <= ROUNDING_SPREAD * np.abs(value), 0.0, se)
    se = np.where(np.isfinite(value), se, np.nan)
    half = t_quantile(G - 1, prob) * se
    return value, se, value - half, value + half


def group_totals(values, groups: int, left_out: bool = False) -> np.ndarray:
    """Sums of per-run ``values`` (R, ...) over the runs of each round-robin group of
    :func:`run_groups` (run r in group r mod G), or with ``left_out`` over the runs outside
    each group: (G, ...).

    One pass over the values whatever G, where cutting the runs of every group (or of every
    complement) would copy them G times: a metric that is a function of sums over runs gets its
    G group estimates from these totals.
    """
    v = np.asarray(values)
    whole, rest = divmod(v.shape[0], groups)
    totals = np.add.reduce(v[:whole * groups].reshape((whole, groups) + v.shape[1:]), axis=0, dtype=float)
    totals[:rest] += v[whole * groups:]
    return totals.sum(axis=0) - totals if left_out else totals


def ratio_jackknife(sums, counts, groups: int = JACKKNIFE_GROUPS, prob: float = 0.95):
    """Grouped-jackknife interval of ``Σ sums / Σ counts`` over runs (a mean over every run's
    values, e.g. a time-averaged NEES), from per-run ``sums`` and ``counts`` (R,).

    The same estimates as :func:`jackknife` with that statistic, from the groups' totals
    (:func:`group_totals`) instead of G re-summations of nearly all runs. NaN where no value
    is counted.

    Returns
    -------
    value, se, low, high : float
    """
    sums, counts = np.asarray(sums, float), np.asarray(counts, float)
    with np.errstate(invalid="ignore", divide="ignore"):
        value = np.asarray(sums.sum() / counts.sum())   # 0/0: NaN
        G = len(run_groups(len(sums), groups))
        if not G:
            nan = np.asarray(np.nan)
            return value, nan, nan, nan
        left_out = group_totals(sums, G, left_out=True) / group_totals(counts, G, left_out=True)
    return _jackknife_interval(value, left_out, prob)


def _sum_of_squared_deviations(estimates):
    """``Σ_g (θ_g − θ̄)²`` over axis 0, NaN left out. Deviations are taken from the first group
    first, so a metric that no run changes (a bound, a design value) has exactly zero spread
    rather than the rounding error of its mean."""
    shifted = estimates - estimates[:1]
    centre = nanmean(shifted, axis=0)
    return np.nansum((shifted - centre) ** 2, axis=0)


class _RunSubset(Mapping):
    """A read-only view of a dict of per-run arrays cut to some runs; an array is cut (copied)
    only when read, so a scorer pays for the outputs it uses, not for every covariance."""

    def __init__(self, arrays: dict, runs, n_runs: int):
        self._arrays, self._runs, self._n_runs, self._cache = arrays, _as_slice(runs), n_runs, {}

    def __getitem__(self, key):
        if key not in self._cache:
            value = self._arrays[key]
            if isinstance(value, Mapping):
                value = _RunSubset(value, self._runs, self._n_runs)
            elif isinstance(value, np.ndarray) and value.ndim >= 1 and value.shape[0] == self._n_runs:
                value = value[self._runs]
            self._cache[key] = value
        return self._cache[key]

    def __iter__(self):
        return iter(self._arrays)

    def __len__(self):
        return len(self._arrays)


def _as_slice(runs):
    """Evenly spaced runs (a round-robin group) as a slice, which cuts an array without a copy."""
    if isinstance(runs, slice):
        return runs
    runs = np.asarray(runs)
    if runs.ndim == 1 and runs.size >= 2 and runs[0] >= 0:
        step = int(runs[1] - runs[0])
        if step > 0 and np.array_equal(runs, np.arange(runs[0], runs[0] + step * runs.size, step)):
            return slice(int(runs[0]), int(runs[-1]) + 1, step)
    return runs


def subset_runs(arrays: dict, runs: np.ndarray, n_runs: int) -> Mapping:
    """``arrays`` with every array that has a leading run axis of ``n_runs`` cut to ``runs``.

    Nested mappings are followed; anything else (scalars, None) passes through unchanged. The
    result is a read-only mapping that cuts each array when it is first read.
    """
    return _RunSubset(arrays, np.asarray(runs), n_runs)


RANDOM_GROUPS_MIN_RUNS = 200  # from here on each of the G groups holds ≥ 20 runs


def summary_intervals(score, runs_data: dict, n_runs: int, groups: int = 10, prob: float = 0.95,
                      score_groups=None):
    """A long-form metric table with a Monte Carlo standard error and interval on every row.

    Below :data:`RANDOM_GROUPS_MIN_RUNS` runs the **grouped jackknife**: the runs are dealt
    round-robin into G groups and the table is re-scored with each group left out (G scorings
    of nearly all runs). From there on the **random groups** method (Wolter 2007, *Introduction to
    Variance Estimation*, ch. 2): each group of at least 20 runs is scored alone,
    ``SE = sd(θ_g)/√G`` — G scorings of a tenth of the runs, about one scoring's cost, where the
    jackknife would cost nine. Both give a t interval on G − 1 degrees of freedom around the
    all-runs value.

    Parameters
    ----------
    score : callable
        ``score(runs_data) -> (per_scan, summary)``; ``summary`` in long form with the key
        columns ``tracker, metric, scope`` and ``value``.
    runs_data : dict
        Everything ``score`` reads that varies by Monte Carlo run (arrays with a leading run
        axis of ``n_runs``; see :func:`subset_runs`), e.g. the trackers' outputs and the truth.
    n_runs : int
    groups : int
        G (runs are dealt round-robin, so every group spans the whole data set).
    score_groups : callable, optional
        ``score_groups(runs_data, G, left_out) -> (per_scan, summary, group_summaries)`` or
        None: ``score``'s tables on all runs together with the G summaries it would give on
        each group's runs alone (``left_out`` False) or on all runs but the group's (True), each
        a table or its rows as records ``(tracker, metric, scope, value)``, for
        a scorer whose metrics are functions of sums over runs (:func:`group_totals`), so that
        the groups cost one pass over the data instead of G scorings. When it is not given or
        returns None, every group is scored by ``score``.

    Returns
    -------
    per_scan, summary : polars.DataFrame
        ``score`` on all runs; ``summary`` gains ``se``, ``ci_low`` and ``ci_high`` (null for a
        metric that is not finite or with fewer than two runs).
    """
    import polars as pl

    key = ["tracker", "metric", "scope"]
    parts = run_groups(n_runs, groups)
    alone = n_runs >= RANDOM_GROUPS_MIN_RUNS
    grouped = score_groups(runs_data, len(parts), not alone) if parts and score_groups is not None else None
    if grouped is not None:
        per_scan, summary, group_summaries = grouped
    else:
        per_scan, summary = score(runs_data)
        everything = np.arange(n_runs)
        group_summaries = (score(subset_runs(runs_data, part if alone else np.setdiff1d(everything, part), n_runs))[1]
                           for part in parts)
    if not parts or summary.height == 0:
        return per_scan, summary.with_columns(*(pl.lit(None, pl.Float64).alias(c) for c in ("se", "ci_low", "ci_high")))
    index = {k: i for i, k in enumerate(summary.select(key).iter_rows())}
    estimates = np.full((len(parts), summary.height), np.nan)
    for g, s in enumerate(group_summaries):
        # a table, or its rows as records (tracker, metric, scope, value)
        for *k, v in (s.select(*key, "value").iter_rows() if isinstance(s, pl.DataFrame) else s):
            i = index.get(tuple(k))
            if i is not None and v is not None:
                estimates[g, i] = v
    G = len(parts)
    value = summary["value"].to_numpy().astype(float)
    with np.errstate(invalid="ignore"):
        spread = _sum_of_squared_deviations(estimates)
        se = np.sqrt(spread / (G * (G - 1))) if alone else np.sqrt((G - 1) / G * spread)
        # a metric no run changes (a bound averaged over different runs) spreads by rounding alone
        se = np.where(se <= ROUNDING_SPREAD * np.abs(value), 0.0, se)
    ok = np.isfinite(value) & np.all(np.isfinite(estimates), axis=0)
    half = t_quantile(G - 1, prob) * se
    low, high = value - half, value + half
    # rates: an interval inside [0, 1] that counts runs, not outcomes, as the independent units
    rate_low, rate_high = proportion_intervals(summary["metric"].to_list(), value, se, n_runs, G - 1, prob)
    rate = np.isfinite(rate_low)
    low, high = np.where(rate, rate_low, low), np.where(rate, rate_high, high)
    column = lambda a: pl.Series(np.where(ok, a, np.nan)).fill_nan(None)
    return per_scan, summary.with_columns(se=column(se), ci_low=column(low), ci_high=column(high))
