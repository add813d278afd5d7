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

See ``docs/evaluation.md``.
"""

from __future__ import annotations

import numpy as np

from evaluators.tracking_metrics import nanmean

JACKKNIFE_GROUPS = 20


def t_quantile(dof, prob: float = 0.95):
    """Two-sided ``prob`` quantile of Student's t (array-like ``dof``; NaN where dof < 1)."""
    from scipy.stats import t

    dof = np.asarray(dof, float)
    return t.ppf((1 + prob) / 2, np.where(dof >= 1, dof, np.nan))


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


def wilson_interval(successes, trials, prob: float = 0.95):
    """Wilson score interval of a proportion (well behaved at 0 and 1)."""
    from scipy.stats import norm

    k, n = np.asarray(successes, float), np.asarray(trials, float)
    z = norm.ppf((1 + prob) / 2)
    with np.errstate(invalid="ignore", divide="ignore"):
        p = k / n
        centre = (p + z * z / (2 * n)) / (1 + z * z / n)
        half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return centre - half, centre + half


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
    left_out = np.stack([np.asarray(statistic(np.setdiff1d(everything, p)), float) for p in parts])
    G = len(parts)
    with np.errstate(invalid="ignore"):
        centre = nanmean(left_out, axis=0)
        se = np.sqrt((G - 1) / G * np.nansum((left_out - centre) ** 2, axis=0))
    se = np.where(np.isfinite(value), se, np.nan)
    half = t_quantile(G - 1, prob) * se
    return value, se, value - half, value + half
