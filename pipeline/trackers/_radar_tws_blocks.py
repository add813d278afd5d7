"""The fast path of the radar scan loop (:func:`trackreplay.trackers.radar_tws.track_plots`):
stretches of steady scans taken as one block, the same outputs to the bit as the loop's scan by
scan (``track_plots(scan_blocks=False)``, the plain form; tests/test_long_recording.py holds the
two equal, clamps, floors, deletions and cut blocks included). For more runs than
``BLOCK_MAX_RUNS`` the Kalman strategy's steady stretches go scan by scan instead
(:func:`_steady_kalman_scans`), held to the loop alike. The sizes (``MIN_BLOCK_SCANS``,
``BLOCK_RUN_SCANS``, ``BLOCK_MAX_RUNS``, ``SCANS_RUN_SCANS``) are the loop's, in
:mod:`trackreplay.trackers.radar_tws`.
"""

from __future__ import annotations

import numpy as np

from trackreplay import vocabulary as vocab
from trackreplay.cores.filters.converted_measurements import (
    RELATIVE_VARIANCE_FLOOR,
    floored_polar_variances,
    rotated_diagonal,
)
# the Kalman recursions of a block, in the filters' fast forms (tested against the plain ones there)
from trackreplay.cores.filters._kalman_fast import (
    _cv_position_filter_covariances,
    _cv_position_scan_rows,
    _cv_predict_components_scans,
    _cv_states_with_gains,
)
from trackreplay.cores.filters.kalman import MATRIX_FROM_COMPONENTS, PIVOT_FLOOR, cv_relative_pivots
from trackreplay.trackers.radar_tws_design import MAX_TRACKING_INDEX, TrackerDesign
from trackreplay.trackers.radar_tws_strategies import KalmanGains


def _steady_stretches(counts):
    """For each scan k, how many scans from k on have a plot in every run (0 where scan k lacks one)."""
    every = (counts > 0).all(axis=0)
    idx = np.arange(len(every))
    gaps = np.append(np.flatnonzero(~every), len(every))
    return gaps[np.searchsorted(gaps, idx)] - idx


def _block_plot_variances(z_r, dt, design: TrackerDesign):
    """:func:`~trackreplay.trackers.radar_tws._plot_variances` of a block of scans ``(L, runs)`` with intervals ``dt`` ``(L,)``,
    scan by scan as the loop decides it (a scan with nothing to floor keeps σ_r² and σ_r).

    Returns ``(var_along, var_cross, floored, sigma_along, sigma_cross)``; ``floored`` is None when
    no scan of the block was floored.
    """
    least = (design.sigma_v * dt * dt / MAX_TRACKING_INDEX) ** 2
    var_r = design.sigma_range_m**2
    var_cross = (z_r * design.sigma_bearing_rad) ** 2
    lo, hi = np.maximum(RELATIVE_VARIANCE_FLOOR * var_r, least), var_r / RELATIVE_VARIANCE_FLOOR
    common = (var_r >= least) & ~((var_cross < lo[:, None]) | (var_cross > hi)).any(axis=1)
    if common.all():
        return var_r, var_cross, None, design.sigma_range_m, z_r * design.sigma_bearing_rad
    var_along_f, var_cross_f, floored = floored_polar_variances(z_r, design.sigma_range_m, design.sigma_bearing_rad)
    low_along, low_cross = var_along_f < least[:, None], var_cross_f < least[:, None]
    var_along_f = np.where(low_along, least[:, None], var_along_f)
    var_cross_f = np.where(low_cross, least[:, None], var_cross_f)
    keep = common[:, None]
    var_along = np.where(keep, var_r, var_along_f)
    var_cross = np.where(keep, var_cross, var_cross_f)
    floored = ~keep & (floored | low_along | low_cross)
    sigma_along = np.where(keep, design.sigma_range_m, np.sqrt(var_along))
    sigma_cross = np.where(keep, z_r * design.sigma_bearing_rad, np.sqrt(var_cross))
    return var_along, var_cross, floored, sigma_along, sigma_cross


def _steady_block(first, stop, x, c, n_plots, plot_range, plot_bearing, times, design: TrackerDesign, strategy, out):
    """Scans ``first`` to ``stop − 1`` of :func:`~trackreplay.trackers.radar_tws.track_plots` in one pass, where every run has a
    started, confirmed track, one plot in every scan, and no gate: then nothing the loop decides
    depends on the states (every scan updates every run, no track starts or ends), the α-β gains
    and covariances are functions of the plots alone, and the Kalman covariances of the plots and
    the covariance the block starts from. Those are computed for the whole block at once; only
    the recursions that must run scan after scan (the states, the Kalman covariance) do, on as
    little as they need (:func:`~trackreplay.cores.filters._kalman_fast._cv_states_with_gains`,
    :func:`~trackreplay.cores.filters._kalman_fast._cv_position_filter_covariances`). The outputs
    are written into ``out`` (the loop's arrays); returns ``(x, c, n_plots)`` after the block.
    """
    L = stop - first
    n_runs = x.shape[1]
    dt = times[first:stop] - times[first - 1:stop - 1]
    z_r = np.ascontiguousarray(plot_range[:, first:stop, 0].T)
    z_b = np.ascontiguousarray(plot_bearing[:, first:stop, 0].T)
    cos_b, sin_b = np.cos(z_b), np.sin(z_b)
    zx, zy = z_r * cos_b, z_r * sin_b
    var_along, var_cross, floored, sigma_along, sigma_cross = _block_plot_variances(z_r, dt, design)
    r_cov = rotated_diagonal(cos_b, sin_b, var_along, var_cross)
    T = np.broadcast_to(dt[:, None], (L, n_runs))
    plots = n_plots[None, :] + np.arange(1, L + 1)[:, None]
    if isinstance(strategy, KalmanGains):
        gain, c_post = _cv_position_filter_covariances(c, r_cov, dt, design.sigma_v)
        diag = strategy.diagnostics(gain, cos_b, sin_b, (sigma_along, sigma_cross), design, T)
    else:
        gain, c_post, diag = strategy.gain_and_covariance(None, cos_b, sin_b, r_cov, (sigma_along, sigma_cross),
                                                          plots, design, T)
    states = _cv_states_with_gains(x, gain, zx, zy, dt)
    # the predictions each scan started from, all at once (the same operations as the loop's)
    x_prev = np.concatenate([x[:, None], states[:, :-1]], axis=1)
    c_prev = np.concatenate([c[:, None], c_post[:, :-1]], axis=1)
    xp, cp = _cv_predict_components_scans(x_prev, c_prev, dt, design.sigma_v)
    scans = slice(first, stop)
    out["state"][scans] = states.transpose(1, 0, 2)
    out["cov"][scans] = c_post[MATRIX_FROM_COMPONENTS].transpose(1, 0, 2)
    out["used"][scans, 0], out["used"][scans, 1] = zx, zy
    out["innov"][scans, 0], out["innov"][scans, 1] = zx - xp[0], zy - xp[1]
    s_k = out["s_cov"][scans]
    s_k[..., 0] = cp[0] + r_cov[0]
    s_k[..., 1] = s_k[..., 2] = cp[1] + r_cov[1]
    s_k[..., 3] = cp[2] + r_cov[2]
    out["gains"][scans] = gain.transpose(1, 2, 0)
    _write_gain_diagnostics(out, scans, diag, floored)
    return states[:, -1].copy(), c_post[:, -1].copy(), n_plots + L


def _write_gain_diagnostics(out, scans, diag, floored) -> None:
    """A stretch's α, β and λ into the outputs, and its flags: plots whose variance was floored,
    gains clamped or floored by the strategy."""
    out["alpha"][scans] = diag["alpha"].transpose(1, 0, 2)
    out["beta"][scans] = diag["beta"].transpose(1, 0, 2)
    out["lam"][scans] = diag["lambda_cross"]
    flags = out["flags"][scans]
    if floored is not None:
        flags |= np.where(floored, vocab.FLOORED, 0).astype(np.uint16)
    if diag["clamped"].any():
        flags |= np.where(diag["clamped"], vocab.CLAMPED, 0).astype(np.uint16)
    if diag["floored"].any():
        flags |= np.where(diag["floored"], vocab.FLOORED, 0).astype(np.uint16)


def _steady_kalman_scans(first, stop, x, c, n_plots, plot_range, plot_bearing, times, design: TrackerDesign, strategy,
                         out):
    """:func:`_steady_block` for many runs and the Kalman strategy: the same scans, preconditions and
    outputs (to the bit), with the recursion scan by scan.

    At a few hundred runs a scan of the loop costs its NumPy calls, not its arithmetic, and a block's
    ``(scans, runs)`` temporaries outgrow the cache. Here what is a function of the plots alone (the
    converted plots, their covariances, the floors) is taken for the stretch at once, as in the
    block; the filter runs scan after scan
    (:func:`~trackreplay.cores.filters._kalman_fast._cv_position_scan_rows`), writing the state and
    the innovation where the outputs keep them; the gains' α, β and λ (functions of the gain and the
    plot) and the outputs laid out otherwise are written once at the end.
    """
    L = stop - first
    n_runs = x.shape[1]
    scans = slice(first, stop)
    dt = times[first:stop] - times[first - 1:stop - 1]
    z_r = np.ascontiguousarray(plot_range[:, scans, 0].T)
    z_b = np.ascontiguousarray(plot_bearing[:, scans, 0].T)
    cos_b, sin_b = np.cos(z_b), np.sin(z_b)
    used = out["used"][scans]
    np.multiply(z_r, cos_b, out=used[:, 0])
    np.multiply(z_r, sin_b, out=used[:, 1])
    var_along, var_cross, floored, sigma_along, sigma_cross = _block_plot_variances(z_r, dt, design)
    r_cov = np.empty((L, 3, n_runs))
    r_cov[:, 0], r_cov[:, 1], r_cov[:, 2] = rotated_diagonal(cos_b, sin_b, var_along, var_cross)
    s = np.empty((L, 3, n_runs))
    gain = np.empty((8, L, n_runs))  # rows first: the diagnostics below read them contiguous
    post = np.empty((10, L, n_runs))  # rows first, as the gains: the pivots below read them contiguous
    state, innov = out["state"], out["innov"]
    for j, d in enumerate(dt.tolist()):
        k = first + j
        _cv_position_scan_rows(x, c, d, design.sigma_v, used[j], r_cov[j], state[k], innov[k], s[j], gain[:, j],
                               post[:, j])
        x, c = state[k], post[:, j]
    # track_plots' last check of the reported covariances (cv_floor_components), made here while
    # they are in the cache: a stretch whose every covariance passes is not read again there
    if (cv_relative_pivots(post) >= PIVOT_FLOOR).all():
        out["safe"][scans] = True
    # mode="clip" (the indices are in range): with the default, take writes into a buffer and
    # copies it to out (numpy.take), a second pass over the largest output
    np.take(post, MATRIX_FROM_COMPONENTS, axis=0, out=out["cov"][scans].transpose(1, 0, 2), mode="clip")
    s_k = out["s_cov"][scans]
    s_k[..., 0] = s[:, 0]
    s_k[..., 1] = s_k[..., 2] = s[:, 1]
    s_k[..., 3] = s[:, 2]
    out["gains"][scans] = gain.transpose(1, 2, 0)
    # the intervals as a column: the same products as with a (scans, runs) array of them, without
    # its reads (a broadcast view costs more than a column)
    diag = strategy.diagnostics(gain, cos_b, sin_b, (sigma_along, sigma_cross), design, dt[:, None])
    _write_gain_diagnostics(out, scans, diag, floored)
    return x.copy(), c.copy(), n_plots + L
