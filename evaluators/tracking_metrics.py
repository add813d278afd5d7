"""Monte Carlo error metrics over a leading run axis (pure functions, arrays in, arrays out).

Conventions: arrays are ``(runs, scans, ...)``; scans where a tracker has no filtered estimate
are NaN and are left out of every average (``nan``-aware reductions), so start-up scans never
dilute or inflate a figure.
"""

from __future__ import annotations

import warnings

import numpy as np
import polars as pl


def nanmean(a, axis=None):
    """``np.nanmean`` that returns NaN for all-NaN slices without a warning (scans with no
    estimate yet are expected, not an error)."""
    a = np.asarray(a)
    if a.dtype == np.float64 and a.size:
        # the NaNs found once, for the test and for the mean that leaves them out
        missing = np.isnan(a)
        if not missing.any():
            return np.mean(a, axis=axis, dtype=float)
        return _nanmean_float(a, missing, axis)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        if a.dtype.kind in "iub" or not np.isnan(a).any():
            # nothing to leave out: the plain mean, the same sum over the same count (bit for bit
            # np.nanmean's value, without its copy of the array)
            return np.mean(a, axis=axis, dtype=float)
        return np.nanmean(a, axis=axis)


def _nanmean_float(a, missing, axis):
    """``np.nanmean(a, axis)`` of a float64 ``a`` given its NaN mask ``missing`` (numpy would
    find it again): numpy's steps, the copy with the NaNs zeroed laid out as ``a`` and summed
    by the same reduction, and its counts, so the same bits (tests/test_evaluation_speed_paths.py)."""
    values = np.array(a, copy=True)
    np.copyto(values, 0.0, where=missing)
    count = np.sum(~missing, axis=axis, dtype=np.intp)
    total = np.sum(values, axis=axis)
    with np.errstate(invalid="ignore", divide="ignore"):
        if isinstance(total, np.ndarray):
            return np.divide(total, count, out=total, casting="unsafe")
        return total.dtype.type(total / count)


def root(mean_square):
    """``√mean_square``, NaN (no estimate) passing through without a warning."""
    with np.errstate(invalid="ignore"):
        return np.sqrt(mean_square)


def squared_error(estimate, truth):
    """``‖estimate − truth‖²`` over the last axis, ``(runs, scans)``."""
    e, t = np.broadcast_arrays(np.asarray(estimate, float), np.asarray(truth, float))
    # a component at a time, as trackreplay.batched_linalg.sum_squares sums: no full-size
    # difference or square is held, and numpy's slow reduction over a short axis is avoided;
    # the first square is the total (0 + d², as the sum starts, is d²: a square is never −0)
    # and each difference is squared where it was made. The result is C-ordered whatever the
    # inputs' layout: the sums over runs that read it (group_totals) add in its memory order
    total = np.zeros(e.shape[:-1]) if e.shape[-1] == 0 else np.empty(e.shape[:-1])
    if e.shape[-1] == 0:
        return total
    if total.ndim == 0:
        _add_squared_differences(e, t, total)
        return total
    # a block of runs at a time: a tracker's buffer holds the runs fastest and the result the
    # scans, so each operation reads and writes across both; a block's lines stay in cache
    # from one scan to the next (each value is computed alone: the block changes none)
    rows = max(1, SQUARED_ERROR_BLOCK // max(1, int(np.prod(total.shape[1:], dtype=np.int64))))
    for start in range(0, total.shape[0], rows):
        part = slice(start, start + rows)
        _add_squared_differences(e[part], t[part], total[part])
    return total


def _add_squared_differences(e, t, out):
    """``out`` = Σ_i (e_i − t_i)² over the last axis (at least one component), left to right."""
    np.subtract(e[..., 0], t[..., 0], out=out)
    np.multiply(out, out, out=out)
    if e.shape[-1] > 1:
        d = np.empty_like(out)
        for i in range(1, e.shape[-1]):
            np.subtract(e[..., i], t[..., i], out=d)
            out += np.multiply(d, d, out=d)


#: values of a block of runs of :func:`squared_error`
SQUARED_ERROR_BLOCK = 1 << 14


def rms(values, axis=None):
    """Root mean square over ``axis``, NaN entries (no estimate) left out."""
    v = np.asarray(values, float)
    return np.sqrt(nanmean(v * v, axis=axis))


def rmse_per_scan(estimate, truth):
    """RMS error per scan over runs: ``√(mean_runs ‖x̂ − x‖²)``, shape ``(scans,)``."""
    se = squared_error(estimate, truth)
    with np.errstate(invalid="ignore"):
        return np.sqrt(nanmean(se, axis=0)) if se.size else np.zeros(0)


def rmse_overall(estimate, truth):
    """RMS error over every run and every scan that has an estimate."""
    se = squared_error(estimate, truth)
    return float(np.sqrt(nanmean(se)))


def normalised_position_error(estimate_xy, truth_xy, measured_xy):
    """NPE per scan (Efe, Atherton & Bather 1998; ``docs/papers/radar.md``).

    ``NPE_k = √(Σ_runs ‖p̂_k − p_k‖²) / √(Σ_runs ‖z_k − p_k‖²)``; NPE ≥ 1 means the tracker is no
    better than the raw (converted) plots. Runs where either side is missing are left out of
    both sums, so the ratio compares like with like.
    """
    return npe_from_squared(squared_error(estimate_xy, truth_xy), squared_error(measured_xy, truth_xy))


def npe_from_squared(se, sm):
    """NPE per scan from the squared errors of the estimates ``se`` and of the plots ``sm``
    (both ``(runs, scans)``), as :func:`normalised_position_error`."""
    both = np.isfinite(se) & np.isfinite(sm)
    return npe_from_sums(np.where(both, se, 0.0).sum(axis=0), np.where(both, sm, 0.0).sum(axis=0), both.sum(axis=0))


def npe_from_sums(se_sum, sm_sum, count):
    """NPE per scan from the sums over runs of the squared errors of the estimates and of the
    plots, taken over the ``count`` runs where both exist (NaN where there are none): what
    :func:`npe_from_squared` computes, for sums gathered elsewhere (e.g. per group of runs)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(np.asarray(count) > 0, np.sqrt(se_sum) / np.sqrt(sm_sum), np.nan)


def long_form(wide: pl.DataFrame, id_cols: list[str]) -> pl.DataFrame:
    """Wide metric columns → records ``(*id_cols, metric, value)``."""
    value_cols = [c for c in wide.columns if c not in id_cols]
    return wide.unpivot(on=value_cols, index=id_cols, variable_name="metric", value_name="value").with_columns(
        pl.col("value").cast(pl.Float64))
