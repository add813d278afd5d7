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
from pipeline.batched_linalg import all_finite, sum_squares, whiten

NORMAL_95 = 1.959963984540054  # the two-sided 95 % quantile of the standard normal


def chi2_interval(dof, prob: float = 0.95):
    """Two-sided ``prob`` interval of a χ² variable with ``dof`` degrees of freedom (array-like)."""
    # chdtri(k, q) is the χ²_k quantile of upper tail q: the function scipy.stats.chi2.ppf
    # evaluates, without the 0.5 s import of scipy.stats that every replay would pay
    from scipy.special import chdtri

    dof = np.where(np.asarray(dof, float) > 0, dof, np.nan)
    return chdtri(dof, (1 + prob) / 2), chdtri(dof, (1 - prob) / 2)


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
    return _whitened(error, covariance, squared=False)


def _whitened(error, covariance, squared: bool):
    """:func:`whitened`, or with ``squared`` its ``‖w‖²`` (...), summed block by block so that
    the whitened errors are never held whole."""
    e = np.asarray(error, float)
    P = np.asarray(covariance, float)
    lead = np.broadcast_shapes(e.shape[:-1], P.shape[:-2])
    n = e.shape[-1]
    if not lead:
        w = whiten(e.reshape(1, n), P.reshape(1, n, n))[0]
        return np.sum(w * w) if squared else w
    e, P = np.broadcast_to(e, lead + (n,)), np.broadcast_to(P, lead + (n, n))
    out = np.empty(lead if squared else lead + (n,))
    # the leading axes in the order the covariances lie in memory (a tracker's buffer often
    # holds the runs fastest): a block of the first of them then flattens without a copy,
    # where cutting blocks of runs from such a buffer copies every block twice; every matrix
    # is whitened alone, so the order changes no value
    order = sorted(range(len(lead)), key=lambda i: -abs(P.strides[i]) if lead[i] > 1 else 0)
    e, P, o = (a.transpose(*order, *range(len(lead), a.ndim)) for a in (e, P, out))
    finish = sum_squares if squared else (lambda w: w)
    # in blocks along that axis: the factors and temporaries stay a few MB at any number of
    # runs, and an output that is a strided view is copied a block at a time, never whole
    per_row = int(np.prod(o.shape[1:len(lead)], dtype=np.int64))
    rows = max(1, WHITEN_BLOCK // max(per_row, 1))
    for start in range(0, o.shape[0], rows):
        part = slice(start, start + rows)
        block = o[part]
        block[...] = finish(whiten(e[part].reshape(-1, n), P[part].reshape(-1, n, n))).reshape(block.shape)
    return out


WHITEN_BLOCK = 32768


def whitened_innovations(out: dict):
    """``(w, nis)`` of a tracker's outputs: the whitened innovation ``L⁻¹ν`` (R, K, T, m) and the
    NIS ``νᵀS⁻¹ν`` (R, K, T), a single-track family given one slot; None without ``innovation``
    and ``innovation_covariance``. Computed once per replay and shared by the standard measures
    and the track summary (``docs/evaluation.md``)."""
    if "innovation" not in out or "innovation_covariance" not in out:
        return None
    nu = np.asarray(out["innovation"], float)
    S = np.asarray(out["innovation_covariance"], float)
    if nu.ndim == 3:  # no track axis
        nu, S = nu[:, :, None], S[:, :, None]
    w = whitened(nu, S)
    return w, sum_squares(w)


def normalised_squared(error, covariance):
    """``eᵀ P⁻¹ e`` over the last axes: ``‖w‖²`` of :func:`whitened` (NaN where it is)."""
    return _whitened(error, covariance, squared=True)


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
    # missing innovations as zeros with a presence mask: each lag's sums are then plain products
    # over whole arrays (no copies of the present pairs)
    present = all_finite(w)
    w0 = np.where(present[..., None], w, 0.0)
    power = sum_squares(w0)                                       # ‖w_k‖², 0 where missing
    for i, j in enumerate(lags):
        if j >= K:
            break
        both = present[:, :-j] & present[:, j:]
        count = int(np.count_nonzero(both))
        if not count:
            continue
        num = np.sum(w0[:, :-j] * w0[:, j:])                     # a missing partner contributes 0
        den = np.sqrt(np.sum(power[:, :-j], where=both) * np.sum(power[:, j:], where=both))
        rho[i] = num / den if den > 0 else np.nan
        bound[i] = NORMAL_95 / np.sqrt(count * nu.shape[-1])
    return {"lags": lags, "rho": rho, "bound": bound, "outside": int(np.sum(np.abs(rho) > bound))}
