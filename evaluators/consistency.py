"""Filter consistency: NEES, NIS, their Monte Carlo χ² bounds, and the whiteness of innovations.

Bar-Shalom, Li & Kirubarajan (2001), *Estimation with Applications to Tracking and Navigation*,
§5.4: a filter is consistent when its errors have the covariance it reports. Over N independent
Monte Carlo runs the average normalised estimation error squared (ANEES) at a scan is χ²
with N·n degrees of freedom divided by N, so a two-sided 95 % interval is
``[χ²_{Nn}(0.025), χ²_{Nn}(0.975)] / N``; the same holds for the innovation (NIS, m
components). See ``docs/evaluation.md``.

The time average over runs *and* scans is another matter for the NEES: a filter's estimation
errors are correlated from scan to scan (the estimate at k carries most of the error at k − 1),
so its N·K values are not independent and ``χ²(N·K·n)/(N·K)`` is far too narrow (a correctly
modelled Kalman filter fell inside it in 28 of 100 model-matched data sets). Its interval is
therefore built from the runs, the independent units: the (skewness-corrected) t interval of
the pooled mean over runs (:func:`run_mean_interval`), and the filter is consistent when n lies
inside it. The
innovations of a correct filter are white, so the NIS keeps the χ² bounds of all N·K values.

Every function takes arrays with a leading ``(runs, scans)`` and treats NaN (no estimate, no
innovation) as missing: the number of runs behind each scan's average is counted, and its
bounds use that count.
"""

from __future__ import annotations

import numpy as np

from trackreplay.evaluators.tracking_metrics import nanmean
from trackreplay.batched_linalg import _whitened_entries, all_finite, sum_squares, whiten

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


def _whitened(error, covariance, squared: bool, both: bool = False):
    """:func:`whitened`, or with ``squared`` its ``‖w‖²`` (...), summed block by block so that
    the whitened errors are never held whole; with ``both``, ``(w, ‖w‖²)``."""
    e = np.asarray(error, float)
    P = np.asarray(covariance, float)
    lead = np.broadcast_shapes(e.shape[:-1], P.shape[:-2])
    n = e.shape[-1]
    if not lead:
        w = whiten(e.reshape(1, n), P.reshape(1, n, n))[0]
        return (w, sum_squares(w)) if both else np.sum(w * w) if squared else w
    e, P = np.broadcast_to(e, lead + (n,)), np.broadcast_to(P, lead + (n, n))
    w_out = None if squared and not both else np.empty(lead + (n,))
    total_out = np.empty(lead) if squared or both else None
    # the leading axes in the order the covariances lie in memory (a tracker's buffer often
    # holds the runs fastest): a block of the first of them then reads a few whole stretches
    # of the buffer; every matrix is whitened alone, so the order changes no value
    order = sorted(range(len(lead)), key=lambda i: -abs(P.strides[i]) if lead[i] > 1 else 0)
    e, P = (a.transpose(*order, *range(len(lead), a.ndim)) for a in (e, P))
    w_o = None if w_out is None else w_out.transpose(*order, len(lead))
    t_o = None if total_out is None else total_out.transpose(*order)
    # in blocks along that axis: the factor's entries and temporaries stay a few MB at any
    # number of runs; each block is whitened entry by entry where the matrices lie
    # (trackreplay.batched_linalg._whitened_entries: whiten's values, without its copies)
    per_row = int(np.prod(P.shape[1:len(lead)], dtype=np.int64))
    rows = max(1, WHITEN_BLOCK // max(per_row, 1))
    for start in range(0, P.shape[0], rows):
        part = slice(start, start + rows)
        total = _whitened_entries(e[part], P[part], None if w_o is None else w_o[part])
        if t_o is not None:
            t_o[part] = total
    if both:
        return w_out, total_out
    return total_out if squared else w_out


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
    # w and its squared norm from one pass (sum_squares(w), to the bit)
    return _whitened(nu, S, squared=False, both=True)


def normalised_squared(error, covariance):
    """``eᵀ P⁻¹ e`` over the last axes: ``‖w‖²`` of :func:`whitened` (NaN where it is)."""
    e = np.asarray(error, float)
    P = np.asarray(covariance, float)
    if e.ndim >= 2 and P.ndim >= 3:
        lead = np.broadcast_shapes(e.shape[:-1], P.shape[:-2])
        axis = _stack_axis(P, lead)
        if axis is not None:
            return _normalised_squared_stack_last(e, P, lead, axis)
    return _whitened(e, P, squared=True)


def _stack_axis(P, lead):
    """The leading axis along which ``P``'s matrices lie next to each other in memory (a
    tracker's buffer holding the runs fastest), or None: along it the covariances already have
    the layout of :mod:`trackreplay.batched_linalg` (every entry a contiguous vector of matrices)."""
    if P.ndim - 2 != len(lead) or P.shape[:-2] != lead:
        return None
    for i, size in enumerate(lead):
        if size > 1 and P.strides[i] == P.itemsize:
            return i
    return None


def _normalised_squared_stack_last(e, P, lead, axis: int):
    """:func:`normalised_squared` where ``P``'s matrices lie next to each other along the leading
    ``axis``: the factors are taken on views of the buffer (no copy of the covariances into
    the stack-last layout, which :func:`trackreplay.batched_linalg.whiten` makes), a block of
    the other leading axes at a time. Every matrix meets the same operations in the same order
    as in :func:`whiten`, so the values are the same to the bit (tests/test_evaluation_speed_paths.py)."""
    n = e.shape[-1]
    e = np.broadcast_to(e, lead + (n,))
    out = np.empty(lead)
    # the stack axis last: P (..., n, n, N), e (..., n, N), the output (..., N)
    Pv = np.moveaxis(P, axis, -1)
    ev = np.moveaxis(e, axis, -1)
    ov = np.moveaxis(out, axis, -1)
    others = ov.shape[:-1]
    if not others:
        Pv, ev, ov, others = Pv[None], ev[None], ov[None], (1,)
    per_row = int(np.prod(others[1:], dtype=np.int64)) * ov.shape[-1]
    rows = max(1, WHITEN_BLOCK // max(per_row, 1))
    for start in range(0, others[0], rows):
        part = slice(start, start + rows)
        # the matrix axes last again, as views: each entry a contiguous vector of the stack
        ov[part] = _whitened_entries(np.moveaxis(ev[part], -1, -2), np.moveaxis(Pv[part], -1, -3))
    return out


def run_mean_interval(nx, prob: float = 0.95):
    """The mean of every finite value of ``nx`` (runs, scans), with an interval whose units are
    the runs: values within a run may be correlated in any way, runs must be independent.

    The mean is the ratio ``Σ_r s_r / Σ_r c_r`` of per-run sums and counts. Each of the R runs
    with a value gives a pseudo-value ``y_r = mean + (s_r − mean·c_r)/c̄`` (its own average when
    every run has the same count ``c̄``), whose spread is the linearised (cluster-robust) one of
    the ratio: ``se = sd(y)/√R``. A t interval ``mean ± t_{R−1}·se`` would assume the run
    averages symmetric, but a run's time-averaged NEES is right-skewed (a χ² of few effective
    degrees of freedom when its errors are strongly correlated over scans), and with a few tens
    of runs that costs the t interval 2–3 points of coverage. The interval is therefore Hall's
    skewness-corrected t (Hall 1992, *J. R. Statist. Soc. B* 54, 221–228, a monotone form of
    Johnson 1978): with ``γ`` the sample skewness of the ``y_r`` and
    ``U(c) = (3/γ)·(∛(1 + γ(c/√R − γ/(6R))) − 1)``, the mean of the population lies in
    ``[mean − sd·U(t), mean − sd·U(−t)]``, ``t = t_{R−1}`` (the plain t interval at γ = 0).
    NaN with fewer than two runs.

    Returns
    -------
    mean, se, low, high, runs : float, float, float, float, int
    """
    nx = np.asarray(nx, float)
    return _run_mean_interval(nx, np.isfinite(nx), prob)


def _run_mean_interval(nx, finite, prob: float):
    """:func:`run_mean_interval` of float ``nx`` given where it is finite."""
    from trackreplay.evaluators.confidence import t_quantile

    counts = np.sum(finite, axis=1).astype(float)
    sums = np.sum(nx, axis=1, where=finite)
    used = counts > 0
    R = int(np.count_nonzero(used))
    if R == 0:
        return np.nan, np.nan, np.nan, np.nan, 0
    total = counts.sum()
    mean = float(sums.sum() / total)
    if R < 2:
        return mean, np.nan, np.nan, np.nan, R
    y = mean + (sums[used] - mean * counts[used]) / (total / R)
    dev = y - mean
    sd = float(np.sqrt(np.sum(dev * dev) / (R - 1)))
    se = sd / np.sqrt(R)
    if not sd > 0:
        return mean, se, mean, mean, R
    gamma = float(np.mean(dev**3)) / sd**3
    t = float(t_quantile(R - 1, prob))

    def u(c):
        if abs(gamma) < 1e-8:
            return c / np.sqrt(R)
        return 3 / gamma * (np.cbrt(1 + gamma * (c / np.sqrt(R) - gamma / (6 * R))) - 1)

    return mean, se, mean - sd * u(t), mean - sd * u(-t), R


def effective_scans(nx, max_block: int = 1 << 20) -> float:
    """The number of independent scans a sequence of per-scan averages of ``nx`` (runs, scans)
    is worth, for counting its scans inside a band as binomial trials.

    The per-scan average over independent runs has the autocorrelation ``ρ_j`` of a single
    run's values (averaging independent runs keeps it), estimated here pooled over runs from
    the values standardised per scan. For a nearly Gaussian average (the ANEES of more than a
    few runs) the indicator of a band has autocorrelation at most ``ρ_j²`` (its Hermite
    expansion has no linear term for a band around the centre, and ``|ρ|ⁿ ≤ ρ²`` for n ≥ 2), so
    ``K / (1 + 2 Σ_j (1 − j/K) ρ_j²)`` (the sum over lags while ``ρ_j`` stays positive) is
    the effective number of the K scans (at most K). Computed by FFT, a block of runs at a time.
    """
    nx = np.asarray(nx, float)
    present = np.isfinite(nx)
    return _effective_scans(nx, present, present.sum(axis=0), max_block)


def _effective_scans(nx, present, count, max_block: int = 1 << 20) -> float:
    """:func:`effective_scans` of float ``nx`` given where it is finite and the count of
    those values per scan."""
    have = count > 1
    K = int(np.count_nonzero(count > 0))
    if K < 2 or not have.any():
        return float(K)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.sum(nx, axis=0, where=present) / count
        dev = np.subtract(nx, mean, where=present, out=np.zeros_like(nx))
        sd = np.sqrt(np.sum(dev * dev, axis=0) / (count - 1))
    usable = present & have & (sd > 0)
    whole = bool(usable.all())
    n_runs, n_scans = nx.shape
    size = 1 << int(np.ceil(np.log2(2 * n_scans)))
    products = np.zeros(n_scans)
    # pairs of values at each lag: every run's K − j when none is missing
    pairs = n_runs * np.arange(n_scans, 0, -1.0) if whole else np.zeros(n_scans)
    step = max(1, max_block // size)
    scale = np.where(sd > 0, sd, 1.0)
    # each block's sums over its runs are added run after run, a few runs' transforms at a time
    # (FFT_ROWS): the same sums as of the block's transforms at once (each run's transform is
    # its own), with a few MB of transforms held instead of 30 MB at 10,000 runs
    rows = max(1, FFT_ROWS // size)
    # every run missing the same scans (the start-up scans of every track): each run's sums of
    # pairs are the same transform's, taken once and added run after run as below
    same_pairs = None
    if not whole and _same_rows(usable):
        same_pairs = _autocorrelation_sums(usable[:1].astype(float), size, n_scans)[0]
    for start in range(0, n_runs, step):
        block_products = block_pairs = None
        stop = min(start + step, n_runs)
        for first in range(start, stop, rows):
            part = slice(first, min(first + rows, stop))
            u = usable[part]
            z = dev[part] / scale if whole else np.where(u, dev[part] / scale, 0.0)
            block_products = _add_runs(block_products, _autocorrelation_sums(z, size, n_scans))
            if not whole and same_pairs is None:
                block_pairs = _add_runs(block_pairs, _autocorrelation_sums(u.astype(float), size, n_scans))
        products += block_products
        if same_pairs is not None:
            # a sum over the block's runs of one row: numpy adds the rows of a broadcast one
            # after another as it adds the rows of the block's transforms
            pairs += np.add.reduce(np.broadcast_to(same_pairs, (stop - start, n_scans)), axis=0)
        elif not whole:
            pairs += block_pairs
    with np.errstate(invalid="ignore", divide="ignore"):
        rho = products[1:] / products[0] * pairs[0] / pairs[1:]   # pooled correlation at lags 1..K−1
    rho = np.where(np.round(pairs[1:]) > 0, rho, 0.0)
    stop = np.flatnonzero(~(rho > 0))
    rho = rho[:stop[0]] if stop.size else rho
    lags = np.arange(1, rho.size + 1)
    inflation = 1 + 2 * np.sum((1 - lags / K).clip(0) * rho * rho)
    return float(K / max(inflation, 1.0))


#: values of the runs' transforms (runs × FFT length) :func:`effective_scans` holds at once
FFT_ROWS = 1 << 17


def _autocorrelation_sums(z, size: int, n_scans: int):
    """Each run's (row's) autocorrelation sums ``Σ_k z_k z_{k+j}``, lags 0..n_scans−1, by FFT
    of length ``size`` (≥ 2·n_scans: no wrap-around)."""
    fz = np.fft.rfft(z, size, axis=1)
    power = fz.real * fz.real          # as fz.real**2 + fz.imag**2 computes, with one temporary less
    power += fz.imag * fz.imag
    return np.fft.irfft(power, size, axis=1)[:, :n_scans]


def _same_rows(mask) -> bool:
    """Whether every row (run) of ``mask`` is the first one."""
    return bool((mask == mask[0]).all())


def _add_runs(total, rows):
    """``total`` (None: nothing yet) plus the sum of ``rows`` over runs, added one run after
    another as numpy adds an array over its first axis: ``rows.sum(axis=0)`` when ``total`` is
    None, and otherwise the sum of the rows of ``[total, *rows]``, so that adding a block's runs
    a few at a time gives the sums of the whole block to the bit."""
    if total is None:
        return rows.sum(axis=0)
    # ``total`` added to the first row in place (``rows`` are the caller's temporaries): the same
    # additions in the same order as over the rows of [total, *rows], without copying the rows
    rows[0] += total
    return rows.sum(axis=0)


def consistency_summary(nx, dim: int, prob: float = 0.95, white: bool = False) -> dict:
    """ANEES-style statistics of a normalised squared error ``nx`` (runs, scans).

    Parameters
    ----------
    nx : ndarray (runs, scans)
        NEES or NIS per run and scan, NaN where missing.
    dim : int
        Its degrees of freedom (n of the state compared, m of the innovation).
    white : bool
        Whether the values of a consistent filter are independent over scans (True for the NIS
        of a correct filter, whose innovations are white; False for the NEES, whose errors are
        correlated from scan to scan). It decides the time-average bounds, see below.

    Returns
    -------
    dict
        ``per_scan`` (scans,) average over runs; ``low``/``high`` (scans,) its χ² bounds for the
        number of runs present at each scan (one scan over independent runs: valid either way);
        ``inside_fraction`` of scans within them, over ``scans`` scans with a value, with its
        Wilson interval ``inside_low``/``inside_high`` (with ``white`` the scans are the
        binomial trials; without, their number is :func:`effective_scans`, ``inside_trials``);
        ``time_average`` over every run and scan with its bounds ``time_low``/``time_high``:
        with ``white``, the χ² bounds of the average of all the values; without, the interval
        the time average lies in under consistency (expected value ``dim``), built from the
        spread of the per-run averages (:func:`run_mean_interval`): it lies inside exactly
        when ``dim`` lies inside ``time_ci_low``/``time_ci_high``, the time average's own
        interval over runs (``time_se`` its standard error). Lower ends below 0 read 0.
    """
    from trackreplay.evaluators.confidence import wilson_interval

    nx = np.asarray(nx, float)
    # where the values are finite, found once for the counts, the run averages and the
    # effective number of scans
    finite = np.isfinite(nx)
    count = np.sum(finite, axis=0)
    per_scan = nanmean(nx, axis=0)
    low, high = average_bounds(dim, count, prob)
    have = count > 0
    inside = (per_scan >= low) & (per_scan <= high)
    total = int(count.sum())
    scans = int(np.count_nonzero(have))
    hits = int(np.count_nonzero(inside[have]))
    # the scans as binomial trials: independent for white values, else worth effective_scans
    trials = float(scans) if white else min(float(scans), _effective_scans(nx, finite, count))
    in_low, in_high = ((float(v) for v in wilson_interval(hits / scans * trials, trials, prob)) if scans
                       else (np.nan, np.nan))
    mean, se, ci_low, ci_high, _ = _run_mean_interval(nx, finite, prob)
    if white:
        t_low, t_high = (float(v) for v in average_bounds(dim, total, prob))
    else:
        # where the time average lies when dim is the mean: inside exactly when dim is inside
        # the time average's own interval [ci_low, ci_high]
        t_low, t_high = dim + (mean - ci_high), dim + (mean - ci_low)
    # a mean of squares is never negative: a bound below 0 (very skewed run averages) reads as 0,
    # which changes no verdict
    t_low, ci_low = (max(v, 0.0) if np.isfinite(v) else v for v in (t_low, ci_low))
    return {"per_scan": per_scan, "low": low, "high": high,
            "inside_fraction": hits / scans if scans else np.nan, "inside_low": in_low, "inside_high": in_high,
            "scans": scans, "inside_trials": trials, "time_average": mean if total else np.nan,
            "time_low": float(t_low), "time_high": float(t_high), "time_se": se,
            "time_ci_low": ci_low, "time_ci_high": ci_high, "count": count}


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
    # missing innovations as zeros with a presence mask: each lag's sums are then plain products
    # over whole arrays (no copies of the present pairs)
    present = all_finite(w)
    w0 = np.where(present[..., None], w, 0.0)
    return _whiteness(w0, present, sum_squares(w0), max_lag)


def _whiteness_of_whitened(w, nis, max_lag: int = 5) -> dict:
    """:func:`innovation_whiteness` of the innovations :func:`whitened_innovations` gives, ``(w,
    nis)`` (runs, scans, m) and (runs, scans): whitening leaves a row all finite or all NaN
    and ``nis`` is ``sum_squares(w)``, so a row is present where its NIS is not NaN and its
    ``‖w‖²`` with the missing rows zeroed is the NIS there (the same bits, tested), neither found
    again."""
    present = ~np.isnan(nis)
    w0 = np.where(present[..., None], w, 0.0)
    return _whiteness(w0, present, np.where(present, nis, 0.0), max_lag)


def _whiteness(w0, present, power, max_lag: int) -> dict:
    """The lags' correlations of :func:`innovation_whiteness` from the whitened innovations
    ``w0`` (runs, scans, m), 0 where missing, their presence and ``power`` = ``‖w0‖²``."""
    K = w0.shape[1]
    lags = np.arange(1, max_lag + 1)
    rho, bound = np.full(max_lag, np.nan), np.full(max_lag, np.nan)
    # every lag's products written into the one buffer (the start of it, C-ordered as the
    # product numpy would make): its pages are touched once, not once a lag
    products = np.empty(w0[:, 1:].size)
    for i, j in enumerate(lags):
        if j >= K:
            break
        both = present[:, :-j] & present[:, j:]
        count = int(np.count_nonzero(both))
        if not count:
            continue
        lagged = products[:w0[:, j:].size].reshape(w0[:, j:].shape)
        num = np.sum(np.multiply(w0[:, :-j], w0[:, j:], out=lagged))   # a missing partner contributes 0
        den = np.sqrt(np.sum(power[:, :-j], where=both) * np.sum(power[:, j:], where=both))
        rho[i] = num / den if den > 0 else np.nan
        bound[i] = NORMAL_95 / np.sqrt(count * w0.shape[-1])
    return {"lags": lags, "rho": rho, "bound": bound, "outside": int(np.sum(np.abs(rho) > bound))}
