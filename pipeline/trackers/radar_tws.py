"""Kim & Lee (2006): track-while-scan α-β filtering with gains that follow the tracking index.

The paper (after Kalata 1984 and Fitzgerald's decoupled filter) filters converted radar plots
with α-β gains designed at a nominal cross-range error, and proposes gains linearised in the
tracking index λ_k so they follow the plot's range. See ``docs/papers/radar.md``.
State ``[x, y, ẋ, ẏ]``; plots ``(r, θ)`` are converted to ``(x, y)``.

The loop (:func:`track_plots`) predicts with the white-acceleration model, picks the plot
nearest to the prediction (no clutter in the paper's scenario; misses coast), and hands the
prediction and the plot to an **update strategy**, which returns the posterior state and
covariance, the innovation and its diagnostics (the strategies live in
:mod:`trackreplay.trackers.radar_tws_strategies`). A polar EKF or a UKF is one more strategy (or a
plugged tracker, see ``docs/trackers.md``); the loop does not change. The strategies:

``fixed``        Kalata gains at the nominal cross-range index λ̄ (the paper's "conventional").
``approximate``  α_k = ᾱ + m_α Δλ, β_k = β̄ + m_β Δλ with λ_k from the plot's range (the paper's
                 "proposed"), clamped to the stability region and flagged when clamped.
``exact``        Kalata gains recomputed at λ_k every scan (reference).
``kalman``       Kalman gain with the converted covariance R = D diag(σ_r², r²σ_θ²) Dᵀ (reference).

The α-β strategies use the decoupled gain ``K_k = D₂ K̄₂ Dᵀ`` with
``K̄₂ = [[α_r, 0], [0, α_c], [β_r/T, 0], [0, β_c/T]]`` and ``D`` the rotation by the plot's bearing.
Every strategy reports its per-axis (along-range, cross-range) α and β — for the Kalman filter
the gain rotated into that frame — so the gains can be compared on one plot.

Tracks start from two plots (position of the second, velocity from their difference) and are
filtered from the third plot on. Track management is the shared mechanism of
:mod:`trackreplay.cores.association.track_management`: a track is tentative (``INITIALISING``) until
``confirm_hits`` of its first ``confirm_window`` scans had a plot (the two start plots
included), and is deleted (``NO_TRACK | DELETED``) after ``max_coasted_scans`` coasted scans in a
row or when it fails confirmation; its run then starts a new track from its next two plots. With
``gate_probability`` > 0 a started track uses the nearest plot only inside its χ² gate (for
recordings with clutter; the paper's scenario has none, and no gate is the default).

Covariances stay symmetric positive definite at every design value the trackers accept
(:func:`check_design` refuses the rest with a one-line :class:`~trackreplay.errors.InputError`).
The Kalata gains and their covariance are evaluated in a form free of cancellation
(:mod:`trackreplay.cores.filters.alpha_beta_gains`) and the Kalman update forms ``I − K_pos`` as
``R S⁻¹`` (:func:`~trackreplay.cores.filters.kalman.cv_position_update_components`). Repairs,
each flagged ``FLOORED`` on its scan, cover what a Cartesian covariance cannot hold:

* a plot's along-range or cross-range variance is raised to
  :data:`~trackreplay.cores.filters.converted_measurements.RELATIVE_VARIANCE_FLOOR` times the other
  (a very precise range far out, or a plot next to the radar where r·σ_θ → 0), and to the value
  that makes its tracking index σ_v T²/σ at most :data:`MAX_TRACKING_INDEX`;
* an α-β velocity variance implied by gains off Kalata's curve (the approximate gains after the
  stability clamp) is raised to keep the position-velocity correlation ρ² ≤ 1/2;
* last, any reported covariance whose relative LDLᵀ pivot is below
  :data:`~trackreplay.cores.filters.kalman.PIVOT_FLOOR` has the eigenvalues of its correlation
  matrix raised (:func:`~trackreplay.cores.filters.kalman.cv_floor_components`); the innovation
  covariance's correlation likewise. Only extreme cases reach them (a track started from a plot
  micrometres from the radar, fixed gains designed for a nominal error far from the plot's).

None of them acts on the paper's scenario or the bundled data sets.
"""

from __future__ import annotations

import numpy as np

from trackreplay.cores.filters.converted_measurements import (
    RELATIVE_VARIANCE_FLOOR,
    floored_polar_variances,
    rotated_diagonal,
)
from trackreplay.cores.filters.kalman import (
    cv_floor_components,
    cv_predict_components,
    MATRIX_FROM_COMPONENTS,
)

from trackreplay.cores.association.track_management import ConfirmationRule, EndingRule, TrackLife

from trackreplay import vocabulary as vocab
from trackreplay.errors import InputError
from trackreplay.trackers.interface import Param, Tracker
# the design values, the update strategies, and the scan loop's fast path (steady stretches as
# blocks, tested equal to the loop scan by scan); each imports the design module, none this one
from trackreplay.trackers.radar_tws_design import DESIGN_RANGE, MAX_TRACKING_INDEX, TrackerDesign  # noqa: F401
from trackreplay.trackers.radar_tws_strategies import STRATEGIES, AlphaBetaGains, KalmanGains  # noqa: F401
from trackreplay.trackers._radar_tws_blocks import _steady_block, _steady_kalman_scans, _steady_stretches



def _plot_variances(z_range, dt: float, design: TrackerDesign):
    """Along-range and cross-range variances of each run's plot, floored (module docstring).

    Returns ``(var_along, var_cross, floored)``, arrays over runs (NaN where there is no plot),
    or ``(σ_r², var_cross, None)`` when nothing was floored.
    """
    # tracking index σ_v dt²/σ ≤ MAX_TRACKING_INDEX  ⇔  σ² ≥ (σ_v dt² / MAX_TRACKING_INDEX)²
    least = (design.sigma_v * dt * dt / MAX_TRACKING_INDEX) ** 2
    var_r = design.sigma_range_m**2
    var_cross = (z_range * design.sigma_bearing_rad) ** 2
    # the common case, decided by two comparisons: nothing to floor
    lo, hi = max(RELATIVE_VARIANCE_FLOOR * var_r, least), var_r / RELATIVE_VARIANCE_FLOOR
    if var_r >= least and not ((var_cross < lo) | (var_cross > hi)).any():
        return var_r, var_cross, None
    var_along, var_cross, floored = floored_polar_variances(z_range, design.sigma_range_m, design.sigma_bearing_rad)
    low_along, low_cross = var_along < least, var_cross < least
    var_along = np.where(low_along, least, var_along)
    var_cross = np.where(low_cross, least, var_cross)
    return var_along, var_cross, floored | low_along | low_cross


def _floor_innovation_covariance(s_cov):
    """Innovation covariances ``(scans, runs, 4)`` (s00, s01, s10, s11) with their correlation
    limited to ρ² ≤ 1 − 10⁻⁹ where it is above (the α-β filters' predicted covariance next to
    the radar); returns them and the mask of those changed (None when none were)."""
    s00, s01, s11 = s_cov[..., 0], s_cov[..., 1], s_cov[..., 3]
    limit = (1.0 - 1e-9) * s00 * s11
    high = s01 * s01 > limit  # False where there was no update (NaN)
    if not high.any():
        return s_cov, None
    s_cov = s_cov.copy()
    s_cov[..., 1] = s_cov[..., 2] = np.where(high, np.sign(s01) * np.sqrt(limit), s01)
    return s_cov, high


def _select_plots(plot_range, plot_bearing, counts_k, x_pred, started):
    """Range and bearing of the plot each run uses this scan (nearest to the prediction;
    the first plot for tracks not started yet; NaN where the scan has none)."""
    width = plot_range.shape[1]
    if width == 1:
        return plot_range[:, 0], plot_bearing[:, 0]
    if width == 0:
        nan = np.full(plot_range.shape[0], np.nan)
        return nan, nan
    valid = np.arange(width)[None, :] < counts_k[:, None]
    px = plot_range * np.cos(plot_bearing) - x_pred[0][:, None]
    py = plot_range * np.sin(plot_bearing) - x_pred[1][:, None]
    d2 = np.where(valid, px * px + py * py, np.inf)
    j = np.where(started, np.argmin(d2, axis=1), np.argmax(valid, axis=1))
    rows = np.arange(plot_range.shape[0])
    return plot_range[rows, j], plot_bearing[rows, j]


#: Shortest stretch of steady scans :func:`track_plots` takes as one block (below it the scan
#: loop's own step costs no more).
MIN_BLOCK_SCANS = 4
#: Run-scans per block: bounds the block's temporaries (a few dozen arrays of this size) at any
#: number of runs.
BLOCK_RUN_SCANS = 1 << 18
#: Blocks are for few runs: beyond this many the scan loop's own calls are already over arrays long
#: enough to pay for themselves, and at 500 runs a block measured a third slower than the loop
#: (its temporaries no longer fit in the cache; docs/benchmarks.md). Beyond it the Kalman strategy
#: takes a steady stretch scan by scan instead (``_steady_kalman_scans``), at most
#: :data:`SCANS_RUN_SCANS` run-scans at a time.
BLOCK_MAX_RUNS = 256
#: Run-scans per stretch of ``_steady_kalman_scans``: bounds its per-stretch arrays (a few dozen
#: of this many values).
SCANS_RUN_SCANS = 1 << 12


def track_plots(plot_range, plot_bearing, counts, times, design: TrackerDesign, strategy,
                scan_blocks: bool = True) -> dict:
    """Run one tracker over all Monte Carlo runs at once.

    Parameters
    ----------
    plot_range, plot_bearing : ndarray, shape (runs, scans, width)
        Plots per scan, NaN-padded (``counts`` says how many are real).
    counts : ndarray of int, shape (runs, scans)
    times : ndarray, shape (scans,)
        Scan times (s).
    design : TrackerDesign
    strategy : AlphaBetaGains or KalmanGains
        One of :data:`STRATEGIES`.
    scan_blocks : bool
        Take stretches of steady scans (every run has a confirmed track and one plot a scan, no
        gate) as blocks (:func:`~trackreplay.trackers._radar_tws_blocks._steady_block`) when the runs are few (at most
        :data:`BLOCK_MAX_RUNS`): the same outputs, to the bit, with a few NumPy calls per block
        instead of a few hundred per scan (``docs/benchmarks.md``); with more runs, the Kalman
        strategy's steady stretches go scan by scan, what depends on the plots alone taken for the
        stretch at once (:func:`~trackreplay.trackers._radar_tws_blocks._steady_kalman_scans`), the
        same outputs to the bit. False: the loop scan by scan throughout (the
        reference form the tests hold both to).

    Returns
    -------
    dict of ndarray
        ``state (runs, scans, 4)``, ``covariance (runs, scans, 4, 4)``, ``alpha``/``beta``
        ``(runs, scans, 2)`` as (along-range, cross-range), ``lambda_cross``, ``innovation
        (runs, scans, 2)`` and its covariance ``(runs, scans, 2, 2)``, ``gain (runs, scans, 4, 2)``,
        ``measurement (runs, scans, 2)`` (the converted plot used, NaN when the scan had none) and
        ``flags (runs, scans)`` (bits of :data:`trackreplay.vocabulary.FLAGS`; ``FLOORED`` where the
        plot's variances, the α-β velocity variance or the reported covariance were floored, see
        the module docstring).
    """
    n_runs, n_scans = counts.shape
    if plot_range.ndim != 3:
        plot_range = plot_range.reshape(n_runs, n_scans, -1)
        plot_bearing = plot_bearing.reshape(n_runs, n_scans, -1)
    nan = np.nan
    # outputs are filled scan by scan, runs last (contiguous), and transposed once at the end.
    # They are allocated unfilled: the loop sets its scan's entries to NaN before it writes those
    # it has, the blocks write every entry of theirs (filling them all first was one more pass over
    # some 10 MB at 500 runs x 64 scans, which the blocks then overwrote)
    state = np.empty((n_scans, 4, n_runs))
    # the covariance's 16 entries row by row, written once per scan from the ten components
    # the filter carries: the (runs, scans, 4, 4) output is a view of it, with no second pass
    cov = np.empty((n_scans, 16, n_runs))
    alpha = np.empty((n_scans, 2, n_runs))
    beta = np.empty((n_scans, 2, n_runs))
    lam = np.empty((n_scans, n_runs))
    innov = np.empty((n_scans, 2, n_runs))
    used = np.empty((n_scans, 2, n_runs))  # the plot each run used (for NPE against it)
    # innovation covariance (s00, s01, s10, s11) and gain rows runs-first, so that the (runs,
    # scans, 2, 2) and (runs, scans, 4, 2) outputs are views, not copies
    s_cov = np.empty((n_scans, n_runs, 4))
    gains = np.empty((n_scans, n_runs, 8))
    flags = np.zeros((n_scans, n_runs), np.uint16)

    x = np.zeros((4, n_runs))
    c = np.zeros((10, n_runs))
    started = np.zeros(n_runs, bool)
    have_prev = np.zeros(n_runs, bool)
    prev = np.zeros((5, n_runs))  # x, y, r00, r01, r11 of the first plot of a track
    prev_t = np.zeros(n_runs)
    n_plots = np.zeros(n_runs, np.int64)  # plots a track has used, the start-up gains' n
    life = TrackLife((n_runs,), design.confirmation, design.ending)
    gated = np.isfinite(design.gate_chi2)
    # stretches of scans where nothing decided depends on the states go as blocks (_steady_block):
    # no gate, one plot a scan at most (so none is chosen by distance), an ending rule that only
    # counts coasted scans
    steady = (scan_blocks and not gated and plot_range.shape[2] == 1
              and design.ending.field is None and not np.isfinite(design.ending.max_position_variance))
    if n_runs <= BLOCK_MAX_RUNS:
        blocks, take_block = steady, _steady_block
        longest = max(MIN_BLOCK_SCANS, BLOCK_RUN_SCANS // max(n_runs, 1))
    else:  # many runs: the Kalman strategy's steady stretches scan by scan (the α-β ones keep the loop)
        blocks, take_block = steady and isinstance(strategy, KalmanGains), _steady_kalman_scans
        longest = max(MIN_BLOCK_SCANS, SCANS_RUN_SCANS // n_runs)
    stretch = _steady_stretches(counts) if blocks else None
    # scans whose reported covariances a stretch already found safely positive definite (the check
    # below, made while they were in the cache)
    safe = np.zeros(n_scans, bool)
    out = dict(state=state, cov=cov, alpha=alpha, beta=beta, lam=lam, innov=innov, used=used, s_cov=s_cov,
               gains=gains, flags=flags, safe=safe)
    resume = 0
    for k in range(n_scans):
        if k < resume:
            continue
        if blocks and k > 0 and stretch[k] >= MIN_BLOCK_SCANS and started.all() and not life.tentative.any():
            resume = k + min(int(stretch[k]), longest)
            x, c, n_plots = take_block(k, resume, x, c, n_plots, plot_range, plot_bearing, times, design, strategy,
                                       out)
            life.coasting = np.zeros(n_runs, np.int64)  # every scan of the block had a plot
            continue
        for a in (state, cov, alpha, beta, lam, innov, used, s_cov, gains):
            a[k] = nan
        dt = float(times[k] - times[k - 1]) if k else design.scan_period_s
        xp, cp = cv_predict_components(x, c, dt, design.sigma_v)
        has = counts[:, k] > 0
        z_r, z_b = _select_plots(plot_range[:, k], plot_bearing[:, k], counts[:, k], xp, started)
        cos_b, sin_b = np.cos(z_b), np.sin(z_b)
        zx, zy = z_r * cos_b, z_r * sin_b
        used[k, 0], used[k, 1] = zx, zy
        var_along, var_cross, floored = _plot_variances(z_r, dt, design)
        r_cov = rotated_diagonal(cos_b, sin_b, var_along, var_cross)
        if floored is not None:
            flags[k] |= np.where(floored & has, vocab.FLOORED, 0).astype(np.uint16)

        if gated:  # a started track takes the nearest plot only inside its χ² gate
            s00, s01, s11 = cp[0] + r_cov[0], cp[1] + r_cov[1], cp[2] + r_cov[2]
            ex, ey = zx - xp[0], zy - xp[1]
            d2 = (s11 * ex * ex - 2 * s01 * ex * ey + s00 * ey * ey) / (s00 * s11 - s01 * s01)
            has = has & (~started | (d2 <= design.gate_chi2))
        upd = started & has
        if upd.all():
            sel = slice(None)  # the common case: every run updates, no masking or copies
        else:
            sel = np.flatnonzero(upd)
        x_new, c_new = xp, cp
        if upd.any():
            n_plots[sel] += 1
            if floored is None:
                sigmas = (design.sigma_range_m, z_r[sel] * design.sigma_bearing_rad)
            else:
                sigmas = (np.sqrt(var_along[sel]), np.sqrt(var_cross[sel]))
            xu, c_post, nu, gain, diag = strategy.update(xp[:, sel], cp[:, sel], z_r[sel], cos_b[sel], sin_b[sel],
                                                         tuple(r[sel] for r in r_cov), sigmas, n_plots[sel], design,
                                                         dt)
            if isinstance(sel, slice):
                x_new, c_new = xu, c_post
            else:
                x_new, c_new = xp.copy(), cp.copy()
                x_new[:, sel], c_new[:, sel] = xu, c_post
            alpha[k][:, sel] = diag["alpha"]
            beta[k][:, sel] = diag["beta"]
            lam[k][sel] = diag["lambda_cross"]
            innov[k][:, sel] = nu
            # S = H P⁻ Hᵀ + R: the covariance the innovation has if the prediction is right
            s_k = s_cov[k]
            s_k[sel, 0] = cp[0, sel] + r_cov[0][sel]
            s_k[sel, 1] = s_k[sel, 2] = cp[1, sel] + r_cov[1][sel]
            s_k[sel, 3] = cp[2, sel] + r_cov[2][sel]
            gains[k][sel] = gain.T
            if diag["clamped"].any():
                flags[k][sel] |= np.where(diag["clamped"], vocab.CLAMPED, 0).astype(np.uint16)
            if diag["floored"].any():
                flags[k][sel] |= np.where(diag["floored"], vocab.FLOORED, 0).astype(np.uint16)
        tentative, ending = life.step(upd, x_new[0], c_new[0] + c_new[2])
        if tentative.any():
            flags[k][tentative] |= vocab.INITIALISING
        if ending.any():  # the track ends here (no state); its run starts afresh from its next plots
            flags[k][ending] |= vocab.NO_TRACK | vocab.DELETED
            started = started & ~ending
            have_prev = have_prev & ~ending
            upd = upd & ~ending
            for a in (innov[k], used[k], alpha[k], beta[k]):
                a[:, ending] = nan
            lam[k][ending] = nan
            s_cov[k][ending] = nan
            gains[k][ending] = nan
        if not upd.all():
            init = ~started & has & have_prev & ~ending
            first = ~started & has & ~have_prev
            if init.any():
                i = np.flatnonzero(init)
                gap = times[k] - prev_t[i]
                r00, r01, r11 = (r[i] for r in r_cov)
                x_new[:, i] = np.stack([zx[i], zy[i], (zx[i] - prev[0, i]) / gap, (zy[i] - prev[1, i]) / gap])
                # two-point start: P = [[R₁, R₁/Δt], [R₁/Δt, (R₀ + R₁)/Δt²]]
                c_new[:, i] = np.stack([r00, r01, r11, r00 / gap, r01 / gap, r01 / gap, r11 / gap,
                                        (r00 + prev[2, i]) / gap**2, (r01 + prev[3, i]) / gap**2,
                                        (r11 + prev[4, i]) / gap**2])
                flags[k][i] |= vocab.INITIALISING
                n_plots[i] = 2
                life.start(init, hits=2, scans=2)  # the two start plots count towards M-of-N
            f = np.flatnonzero(first & ~ending)
            prev[:, f] = np.stack([zx[f], zy[f], r_cov[0][f], r_cov[1][f], r_cov[2][f]])
            prev_t[f] = times[k]
            have_prev |= first & ~ending
            flags[k][started & ~has] |= vocab.COASTED
            started = started | init
            flags[k][~started] |= vocab.NO_TRACK
            # runs without a track keep their (unused) state; tracks that coast keep the prediction
            x = np.where(started, x_new, x)
            c = np.where(started, c_new, c)
            state[k][:, started] = x[:, started]
            cov[k][:, started] = c[MATRIX_FROM_COMPONENTS][:, started]
        else:
            x, c = x_new, c_new
            state[k] = x
            np.take(c, MATRIX_FROM_COMPONENTS, axis=0, out=cov[k], mode="clip")  # unbuffered (numpy.take)
    # last line of defence, over all scans at once: a reported covariance that is not safely
    # positive definite is repaired and flagged (the forms above keep the filters far from it
    # except at extreme designs; the filters' recursion does not see the repair). Scans found
    # safe already (``safe``) would neither be repaired nor flagged: they are left out
    todo = np.flatnonzero(~safe)
    if todo.size == n_scans:
        live = ~np.isnan(state).any(axis=1)
        checked, repaired = cv_floor_components(cov.transpose(1, 0, 2), live)
        if repaired.any():
            cov = checked.transpose(1, 0, 2)
            flags |= np.where(repaired, vocab.FLOORED, 0).astype(np.uint16)
    elif todo.size:
        live = ~np.isnan(state[todo]).any(axis=1)
        checked, repaired = cv_floor_components(cov[todo].transpose(1, 0, 2), live)
        if repaired.any():
            cov[todo] = checked.transpose(1, 0, 2)
            flags[todo] |= np.where(repaired, vocab.FLOORED, 0).astype(np.uint16)
    s_cov, repaired = _floor_innovation_covariance(s_cov)
    if repaired is not None:
        flags |= np.where(repaired, vocab.FLOORED, 0).astype(np.uint16)
    s = s_cov.transpose(1, 0, 2)
    g = gains.transpose(1, 0, 2)
    return {
        "state": state.transpose(2, 0, 1),
        "covariance": cov.transpose(2, 0, 1).reshape(n_runs, n_scans, 4, 4),  # a view (the last axis splits)
        "innovation_covariance": s.reshape(s.shape[:2] + (2, 2)),
        "gain": g.reshape(g.shape[:2] + (4, 2)),  # rows x, y, ẋ, ẏ; columns the converted x, y
        "alpha": alpha.transpose(2, 0, 1),
        "beta": beta.transpose(2, 0, 1),
        "lambda_cross": lam.T,
        "innovation": innov.transpose(2, 0, 1),
        "measurement": used.transpose(2, 0, 1),
        "flags": flags.T.copy(),
    }


# --------------------------------------------------------------------------- the trackers

PARAMS = (
    # the positive design values within the range the filters represent (DESIGN_RANGE)
    Param("scan_period_s", None, "s", "nominal scan period T of the gains", *DESIGN_RANGE, closed=True),
    Param("design_sigma_v_mps2", None, "m/s²", "design acceleration noise σ_v", *DESIGN_RANGE, closed=True),
    Param("sigma_range_m", None, "m", "plot range noise the filter assumes", *DESIGN_RANGE, closed=True),
    Param("sigma_bearing_deg", None, "deg", "plot bearing noise the filter assumes", *DESIGN_RANGE, closed=True),
    Param("nominal_cross_range_m", None, "m", "cross-range error std at which the fixed gains are designed",
          *DESIGN_RANGE, closed=True),
    Param("startup_gains", None, "", "least-squares start-up gains while they exceed the steady-state ones"),
    Param("gate_probability", 0.0, "", "χ² gate of a started track: the nearest plot is used only inside the gate "
          "that holds the true plot with this probability (0: no gate, the paper's clutter-free scenario; e.g. "
          "0.999 for recordings with clutter)", low=-1e-12, high=1.0),
    Param("confirm_hits", 3, "scans", "M of M-of-N confirmation: a track is tentative until M of its first N "
          "scans (its two start plots included) had a plot; 0: no confirmation", low=-1),
    Param("confirm_window", 4, "scans", "N of M-of-N confirmation (a tentative track that cannot reach M is deleted)",
          low=-1),
    Param("max_coasted_scans", 5, "scans", "a track that coasts this many scans in a row is deleted, and its run "
          "starts a new track from its next two plots (0: never)", low=-1),
)


def check_design(design: dict) -> None:
    """Refuse design values whose relations the filters cannot represent (:class:`InputError`,
    one line); each value's own range is its :class:`Param`'s (checked first, when the tracker is
    built).

    M of M-of-N must not exceed N, and the tracking indices σ_v T²/σ_r and λ̄ = σ_v T²/σ_nominal
    must not exceed :data:`MAX_TRACKING_INDEX` (every plot's range error would be floored
    otherwise; fixed gains at a larger λ̄ are α = 1, β = 2 to 10⁻¹⁰, and the covariance they imply
    is not representable beside the range axis).
    """
    lo, hi = DESIGN_RANGE
    hits, window = int(design.get("confirm_hits", 0)), int(design.get("confirm_window", 0))
    if hits > 0 and window < hits:
        raise InputError(f"confirm_hits (M = {hits}) must be ≤ confirm_window (N = {window})")
    sigma_v, T = float(design["design_sigma_v_mps2"]), float(design["scan_period_s"])
    least = sigma_v * T * T / MAX_TRACKING_INDEX
    for key, sigma in (("sigma_range_m", "σ_r"), ("nominal_cross_range_m", "σ_nominal")):
        if float(design[key]) < least:
            raise InputError(f"{key} must be in [{max(least, lo):.3g}, {hi:g}] m with design_sigma_v_mps2={sigma_v:g} "
                             f"and scan_period_s={T:g} (tracking index σ_v T²/{sigma} ≤ {MAX_TRACKING_INDEX:g}; "
                             f"got {design[key]!r})")


def chi2_2dof_gate(probability: float) -> float:
    """The χ² gate of 2 degrees of freedom holding a true plot with ``probability`` (closed
    form: ``−2 ln(1 − p)``); ``inf`` for 0 (no gate) or 1."""
    if probability <= 0.0 or probability >= 1.0:
        return np.inf
    return float(-2.0 * np.log1p(-probability))


class _RadarStrategyTracker(Tracker):
    """One of the four strategies of :data:`STRATEGIES` run by :func:`track_plots`."""

    family = "radar"
    params = PARAMS

    def __init__(self, **design):
        super().__init__(**design)
        check_design(self.design)
        self.tracker_design = TrackerDesign(
            scan_period_s=float(self.scan_period_s), sigma_v=float(self.design_sigma_v_mps2),
            sigma_range_m=float(self.sigma_range_m), sigma_bearing_rad=float(np.deg2rad(self.sigma_bearing_deg)),
            nominal_cross_range_m=float(self.nominal_cross_range_m), startup=bool(self.startup_gains),
            gate_chi2=chi2_2dof_gate(float(self.gate_probability)),
            confirmation=ConfirmationRule(int(self.confirm_hits), int(self.confirm_window)),
            ending=EndingRule(max_coasted_scans=int(self.max_coasted_scans)))

    def track(self, plots):
        return track_plots(plots.range_m, plots.bearing_rad, plots.counts, plots.times_s, self.tracker_design,
                           STRATEGIES[self.name])


class FixedGains(_RadarStrategyTracker):
    """Kalata gains at the nominal tracking index λ̄ (the paper's conventional filter)."""

    name = "fixed"


class ApproximateGains(_RadarStrategyTracker):
    """Gains linearised in λ_k around λ̄ (Kim & Lee 2006, the proposed filter)."""

    name = "approximate"


class ExactGains(_RadarStrategyTracker):
    """Kalata gains recomputed at λ_k every scan (reference)."""

    name = "exact"


class KalmanReference(_RadarStrategyTracker):
    """Kalman filter on converted plots with the converted covariance (reference)."""

    name = "kalman"


TRACKERS = (FixedGains, ApproximateGains, ExactGains, KalmanReference)


# --------------------------------------------------------------------------- the bound


#: Run-scans per block of :func:`radar_pcrb`'s average of the plots' information.
PCRB_BLOCK = 65536


def radar_pcrb(truth_state, times, truth_sigma_v: float, sigma_range_m: float, sigma_bearing_rad: float,
               detected=None) -> np.ndarray:
    """Posterior Cramér–Rao bound per scan for the radar scenario (``docs/evaluation.md``).

    The recursion of :func:`trackreplay.cores.filters.pcrb.pcrb_recursion` (in its constant-velocity
    form, ``_cv_position_pcrb_recursion``) with the truth's own
    motion model (white acceleration ``truth_sigma_v``, the real scan intervals) and the
    range–bearing information averaged over the runs that have a plot at each scan. It starts at
    scan 1 from the covariance of the two-point start evaluated at the true positions (averaged
    over runs), the information two plots carry; scan 0 has no bound (NaN).

    Parameters
    ----------
    truth_state : ndarray (runs, scans, 4)
    times : ndarray (scans,)
    truth_sigma_v : float
        The truth's acceleration noise σ_v (m/s²); 0 for constant-velocity truth.
    sigma_range_m, sigma_bearing_rad : float
        The plots' noise.
    detected : ndarray of bool (runs, scans), optional
        Scans with a plot (default: all).

    Returns
    -------
    ndarray (scans, 4, 4)
    """
    from trackreplay.cores.filters.converted_measurements import converted_covariance
    from trackreplay.cores.filters.pcrb import _cv_position_pcrb_recursion, polar_position_information

    truth = np.asarray(truth_state, float)
    R, K = truth.shape[:2]
    out = np.full((K, 4, 4), np.nan)
    if K < 2:
        return out
    detected = np.ones((R, K), bool) if detected is None else np.asarray(detected, bool)
    # the average over runs of the information, of its one non-zero (position) block alone, a
    # few scans at a time: its temporaries stay a few MB at any number of runs (the mean over
    # runs adds them in the same order whatever the block)
    info = np.zeros((K, 4, 4))
    step = max(1, PCRB_BLOCK // R)
    for first in range(0, K, step):
        scans = slice(first, first + step)
        block = polar_position_information(truth[:, scans, :2], sigma_range_m, sigma_bearing_rad)
        info[scans, :2, :2] = np.where(detected[:, scans, None, None], block, 0.0).mean(axis=0)
    dt = np.diff(np.asarray(times, float), prepend=np.nan)  # dt[k]: the interval into scan k
    # two-point start at the truth: P = [[R₁, R₁/Δt], [R₁/Δt, (R₀ + R₁)/Δt²]] (as the trackers' start)
    rng0, brg0 = np.hypot(truth[:, 0, 0], truth[:, 0, 1]), np.arctan2(truth[:, 0, 1], truth[:, 0, 0])
    rng1, brg1 = np.hypot(truth[:, 1, 0], truth[:, 1, 1]), np.arctan2(truth[:, 1, 1], truth[:, 1, 0])
    R0 = converted_covariance(rng0, brg0, sigma_range_m, sigma_bearing_rad).mean(axis=0)
    R1 = converted_covariance(rng1, brg1, sigma_range_m, sigma_bearing_rad).mean(axis=0)
    gap = float(times[1] - times[0])
    P1 = np.block([[R1, R1 / gap], [R1 / gap, (R0 + R1) / gap**2]])
    # the recursion in its constant-velocity, position-information form: the same bound to
    # rounding, without 4 × 4 products and a solve per scan (a long recording has 10⁵ scans)
    out[1:] = _cv_position_pcrb_recursion(P1, dt[1:], truth_sigma_v, info[1:, :2, :2])
    return out
