"""Filter consistency: NEES, NIS, their Monte Carlo χ² bounds, and the whiteness of innovations.

Bar-Shalom, Li & Kirubarajan (2001), *Estimation with Applications to Tracking and Navigation*,
§5.4: a filter is consistent when its errors have the covariance it reports. Over N independent
Monte Carlo runs the average normalised estimation error squared (ANEES) at a scan is χ²
with N·n degrees of freedom divided by N, so a two-sided 95 % interval is
``[χ²_{Nn}(0.025), χ²_{Nn}(0.975)] / N``; the same holds for the innovation (NIS, m
components). See ``docs/evaluation.md``.

Every function takes arrays with a leading ``(runs, scans)`` and treats NaN (no estimate, no
innovation) as missing: the number of runs behind each scan's average is counted, and its
bounds use that count.
"""

from __future__ import annotations

import numpy as np

from evaluators.tracking_metrics import nanmean

NORMAL_95 = 1.959963984540054  # the two-sided 95 % quantile of the standard normal


def chi2_interval(dof, prob: float = 0.95):
    """Two-sided ``prob`` interval of a χ² variable with ``dof`` degrees of freedom (array-like)."""
    from scipy.stats import chi2

    dof = np.asarray(dof, float)
    lo = chi2.ppf((1 - prob) / 2, np.where(dof > 0, dof, np.nan))
    hi = chi2.ppf((1 + prob) / 2, np.where(dof > 0, dof, np.nan))
    return lo, hi


def average_bounds(dim: int, count, prob: float = 0.95):
    """Bounds of the average of ``count`` independent χ²_dim variables (ANEES / ANIS bounds).

    Returns ``(low, high)`` with ``count``'s shape; NaN where ``count`` is 0.
    """
    count = np.asarray(count, float)
    lo, hi = chi2_interval(dim * count, prob)
    with np.errstate(invalid="ignore", divide="ignore"):
        return lo / count, hi / count


def whitened(error, covariance):
    """``w = L⁻¹ e`` with ``P = L Lᵀ`` (Cholesky, then a triangular solve; no inverse), so that
    ``eᵀ P⁻¹ e = ‖w‖²`` and white errors have unit covariance.

    Parameters
    ----------
    error : ndarray (..., n)
    covariance : ndarray (..., n, n)

    Returns
    -------
    ndarray (..., n)
        NaN where the error or the covariance is missing or the covariance is not positive
        definite (such a covariance has no NEES; validation flags it upstream).
    """
    e = np.asarray(error, float)
    P = np.asarray(covariance, float)
    out = np.full(e.shape, np.nan)
    ok = np.isfinite(e).all(axis=-1) & np.isfinite(P).all(axis=(-2, -1))
    if not ok.any():
        return out
    Pk, ek = P[ok], e[ok]
    try:
        out[ok] = np.linalg.solve(np.linalg.cholesky(Pk), ek[..., None])[..., 0]
    except np.linalg.LinAlgError:
        # one by one, leaving the indefinite ones NaN
        w = np.full(ek.shape, np.nan)
        for i in range(len(ek)):
            try:
                w[i] = np.linalg.solve(np.linalg.cholesky(Pk[i]), ek[i])
            except np.linalg.LinAlgError:
                continue
        out[ok] = w
    return out


def normalised_squared(error, covariance):
    """``eᵀ P⁻¹ e`` over the last axes: ``‖w‖²`` of :func:`whitened` (NaN where it is)."""
    w = whitened(error, covariance)
    return np.sum(w * w, axis=-1)


def consistency_summary(nx, dim: int, prob: float = 0.95) -> dict:
    """ANEES-style statistics of a normalised squared error ``nx`` (runs, scans).

    Returns
    -------
    dict
        ``per_scan`` (scans,) average over runs; ``low``/``high`` (scans,) its bounds for the
        number of runs present at each scan; ``inside_fraction`` of scans within them;
        ``time_average`` over every run and scan with its bounds ``time_low``/``time_high``.
    """
    nx = np.asarray(nx, float)
    count = np.sum(np.isfinite(nx), axis=0)
    per_scan = nanmean(nx, axis=0)
    low, high = average_bounds(dim, count, prob)
    have = count > 0
    inside = (per_scan >= low) & (per_scan <= high)
    total = int(count.sum())
    t_low, t_high = average_bounds(dim, total, prob)
    return {"per_scan": per_scan, "low": low, "high": high,
            "inside_fraction": float(inside[have].mean()) if have.any() else np.nan,
            "time_average": float(nanmean(nx)) if total else np.nan,
            "time_low": float(t_low), "time_high": float(t_high), "count": count}


def innovation_whiteness(innovation, covariance, max_lag: int = 5, whitened_innovation=None) -> dict:
    """Normalised autocorrelation of the whitened innovations at lags 1..``max_lag``.

    With ``w_k = L_k⁻¹ ν_k`` (``S_k = L_k L_kᵀ``), the sample autocorrelation at lag j, pooled
    over runs and scans, ``ρ_j = Σ w_kᵀ w_{k+j} / √(Σ ‖w_k‖² Σ ‖w_{k+j}‖²)``, is approximately
    normal with zero mean and variance 1/M for white innovations, M the number of products in
    the sum times the dimension (Bar-Shalom et al. 2001, §5.4.2). The bounds are ±1.96/√M.

    ``whitened_innovation`` (the :func:`whitened` innovations, when the caller has them already,
    e.g. from the NIS) skips the factorisations.

    Returns
    -------
    dict
        ``lags`` (max_lag,), ``rho`` (max_lag,), ``bound`` (max_lag,), ``outside`` count.
    """
    nu = np.asarray(innovation, float)
    w = whitened(nu, covariance) if whitened_innovation is None else np.asarray(whitened_innovation, float)
    K = nu.shape[1]
    lags = np.arange(1, max_lag + 1)
    rho, bound = np.full(max_lag, np.nan), np.full(max_lag, np.nan)
    for i, j in enumerate(lags):
        if j >= K:
            break
        a, b = w[:, :-j], w[:, j:]
        both = np.isfinite(a).all(axis=-1) & np.isfinite(b).all(axis=-1)
        if not both.any():
            continue
        num = np.sum(a[both] * b[both])
        den = np.sqrt(np.sum(a[both] ** 2) * np.sum(b[both] ** 2))
        rho[i] = num / den if den > 0 else np.nan
        bound[i] = NORMAL_95 / np.sqrt(both.sum() * nu.shape[-1])
    return {"lags": lags, "rho": rho, "bound": bound, "outside": int(np.sum(np.abs(rho) > bound))}
