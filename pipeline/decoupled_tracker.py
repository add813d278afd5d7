"""Track-while-scan tracker on converted radar plots, with four gain strategies over one core.

Spec: ``shared/spec/radar-alpha-beta.md`` (Kim & Lee 2006, after Kalata 1984 and Fitzgerald's
decoupled filter). State ``[x, y, ẋ, ẏ]``; plots ``(r, θ)`` are converted to ``(x, y)``.

The core (:func:`track_plots`) predicts with the white-acceleration model, picks the plot
nearest to the prediction (no clutter in the paper's scenario; misses coast), and asks a
**gain strategy** for the gain of the scan:

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
filtered from the third plot on.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.alpha_beta_gains import (
    approximate_gains,
    clamp_to_stability,
    kalata_gains,
    steady_state_covariance,
    tracking_index,
    with_startup,
)
from pipeline.converted_measurements import converted_covariance, polar_to_cartesian, rotation
from pipeline.kalman import apply_gain, kalman_gain, kf_predict, white_acceleration_model

FLAG_CLAMPED = 1
FLAG_COASTED = 2
FLAG_NO_TRACK = 4
FLAG_INITIALISING = 8

H_POSITION = np.hstack([np.eye(2), np.zeros((2, 2))])


@dataclass(frozen=True)
class TrackerDesign:
    """Filter design values (SI units, radians).

    Attributes
    ----------
    scan_period_s : float
        Nominal scan period T used in the gains.
    sigma_v : float
        Design acceleration noise σ_v (m/s²).
    sigma_range_m, sigma_bearing_rad : float
        Plot noise the filters assume.
    nominal_cross_range_m : float
        Cross-range error std at which the fixed gains are designed (λ̄ = σ_v T² / this).
    startup : bool
        α-β strategies use the expanding-memory start-up gains while they exceed the
        steady-state ones (textbook track start; without it a two-point start followed by
        small steady-state gains is worse than the raw plots for several scans).
    """

    scan_period_s: float
    sigma_v: float
    sigma_range_m: float
    sigma_bearing_rad: float
    nominal_cross_range_m: float
    startup: bool = True

    @property
    def lam_along(self) -> float:
        return float(tracking_index(self.sigma_v, self.scan_period_s, self.sigma_range_m))

    @property
    def lam_nominal(self) -> float:
        return float(tracking_index(self.sigma_v, self.scan_period_s, self.nominal_cross_range_m))


def _blockdiag2(D):
    z = np.zeros_like(D)
    return np.concatenate([np.concatenate([D, z], -1), np.concatenate([z, D], -1)], -2)


def _to_xyv(along, cross):
    """Assemble per-axis 2×2 (pos, vel) blocks into a 4×4 in (along, cross, v_along, v_cross)."""
    P = np.zeros(along.shape[:-2] + (4, 4))
    P[..., 0::2, 0::2] = along
    P[..., 1::2, 1::2] = cross
    return P


class AlphaBetaGains:
    """Decoupled α-β gain strategy; ``cross_gains(λ_k, λ̄)`` decides how the cross-range gains follow λ."""

    def __init__(self, name: str, cross_gains):
        self.name = name
        self._cross_gains = cross_gains

    def gain(self, x_pred, P_pred, z_range, z_bearing, n_plots, design: TrackerDesign):
        T = design.scan_period_s
        n = z_range.shape[0]
        lam_c = tracking_index(design.sigma_v, T, z_range * design.sigma_bearing_rad)
        alpha_r, beta_r = kalata_gains(np.full(n, design.lam_along))
        alpha_c, beta_c, clamped = self._cross_gains(lam_c, design.lam_nominal)
        if design.startup:
            alpha_r, beta_r = with_startup(alpha_r, beta_r, n_plots)
            alpha_c, beta_c = with_startup(alpha_c, beta_c, n_plots)
        Kbar = np.zeros((n, 4, 2))
        Kbar[:, 0, 0] = alpha_r
        Kbar[:, 1, 1] = alpha_c
        Kbar[:, 2, 0] = beta_r / T
        Kbar[:, 3, 1] = beta_c / T
        D = rotation(z_bearing)
        D2 = _blockdiag2(D)
        K = D2 @ Kbar @ np.swapaxes(D, -1, -2)
        P_local = _to_xyv(
            steady_state_covariance(alpha_r, beta_r, T, design.sigma_range_m),
            steady_state_covariance(alpha_c, beta_c, T, z_range * design.sigma_bearing_rad),
        )
        P_post = D2 @ P_local @ np.swapaxes(D2, -1, -2)
        return K, P_post, {
            "alpha": np.stack([alpha_r, alpha_c], -1),
            "beta": np.stack([beta_r, beta_c], -1),
            "lambda_cross": lam_c,
            "clamped": clamped,
        }


def _fixed(lam_c, lam_bar):
    a, b = kalata_gains(np.full_like(lam_c, lam_bar))
    return a, b, np.zeros(lam_c.shape, bool)


def _approximate(lam_c, lam_bar):
    return clamp_to_stability(*approximate_gains(lam_c, lam_bar))


def _exact(lam_c, lam_bar):
    a, b = kalata_gains(lam_c)
    return a, b, np.zeros(lam_c.shape, bool)


class KalmanGains:
    """Kalman gain with the converted-measurement covariance (reference strategy)."""

    name = "kalman"

    def gain(self, x_pred, P_pred, z_range, z_bearing, n_plots, design: TrackerDesign):
        T = design.scan_period_s
        R = converted_covariance(z_range, z_bearing, design.sigma_range_m, design.sigma_bearing_rad)
        K, _ = kalman_gain(P_pred, H_POSITION, R)
        _, P_post = apply_gain(x_pred, P_pred, K, np.zeros(x_pred.shape[:-1] + (2,)), H_POSITION, R)
        D = rotation(z_bearing)
        Kbar = np.swapaxes(_blockdiag2(D), -1, -2) @ K @ D
        return K, P_post, {
            "alpha": np.stack([Kbar[:, 0, 0], Kbar[:, 1, 1]], -1),
            "beta": np.stack([Kbar[:, 2, 0] * T, Kbar[:, 3, 1] * T], -1),
            "lambda_cross": tracking_index(design.sigma_v, T, z_range * design.sigma_bearing_rad),
            "clamped": np.zeros(z_range.shape, bool),
        }


STRATEGIES = {
    "fixed": AlphaBetaGains("fixed", _fixed),
    "approximate": AlphaBetaGains("approximate", _approximate),
    "exact": AlphaBetaGains("exact", _exact),
    "kalman": KalmanGains(),
}


def _nearest_plot(xy_all, valid, x_pred, started):
    """Index of the plot nearest to the prediction (first valid plot for tracks not started)."""
    d2 = np.sum((xy_all - x_pred[:, None, :2]) ** 2, axis=-1)
    d2 = np.where(valid, d2, np.inf)
    first = np.argmax(valid, axis=1)
    return np.where(started, np.argmin(d2, axis=1), first)


def track_plots(plot_range, plot_bearing, counts, times, design: TrackerDesign, strategy) -> dict:
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

    Returns
    -------
    dict of ndarray
        ``state (runs, scans, 4)``, ``covariance (runs, scans, 4, 4)``, ``alpha``/``beta``
        ``(runs, scans, 2)`` as (along-range, cross-range), ``lambda_cross``, ``innovation
        (runs, scans, 2)`` and ``flags (runs, scans)`` (bit mask, ``FLAG_*``).
    """
    n_runs, n_scans = counts.shape
    width = plot_range.shape[2] if plot_range.ndim == 3 else 0
    out = {
        "state": np.full((n_runs, n_scans, 4), np.nan),
        "covariance": np.full((n_runs, n_scans, 4, 4), np.nan),
        "alpha": np.full((n_runs, n_scans, 2), np.nan),
        "beta": np.full((n_runs, n_scans, 2), np.nan),
        "lambda_cross": np.full((n_runs, n_scans), np.nan),
        "innovation": np.full((n_runs, n_scans, 2), np.nan),
        "flags": np.zeros((n_runs, n_scans), np.uint8),
    }
    x = np.zeros((n_runs, 4))
    P = np.tile(np.eye(4), (n_runs, 1, 1))
    started = np.zeros(n_runs, bool)
    n_plots = np.zeros(n_runs, np.int64)  # plots a track has used, the start-up gains' n
    have_prev = np.zeros(n_runs, bool)
    prev_xy = np.zeros((n_runs, 2))
    prev_R = np.zeros((n_runs, 2, 2))
    prev_t = np.zeros(n_runs)
    rows = np.arange(n_runs)
    for k in range(n_scans):
        dt = times[k] - times[k - 1] if k else design.scan_period_s
        F, Q = white_acceleration_model(dt, design.sigma_v)
        x_pred, P_pred = kf_predict(x, P, F, Q)
        has = counts[:, k] > 0
        if width:
            valid = np.arange(width)[None, :] < counts[:, k, None]
            xy_all = polar_to_cartesian(plot_range[:, k], plot_bearing[:, k])
            j = _nearest_plot(xy_all, valid, x_pred, started)
            z_r = plot_range[rows, k, j]
            z_b = plot_bearing[rows, k, j]
            z_xy = xy_all[rows, j]
        else:
            z_r = z_b = np.full(n_runs, np.nan)
            z_xy = np.full((n_runs, 2), np.nan)

        upd = started & has
        coast = started & ~has
        init = ~started & has & have_prev
        first = ~started & has & ~have_prev

        x_new, P_new = x_pred.copy(), P_pred.copy()
        if upd.any():
            n_plots[upd] += 1
            K, P_post, diag = strategy.gain(x_pred[upd], P_pred[upd], z_r[upd], z_b[upd], n_plots[upd], design)
            innov = z_xy[upd] - x_pred[upd, :2]
            x_new[upd], _ = apply_gain(x_pred[upd], P_pred[upd], K, innov, H_POSITION, None)
            P_new[upd] = P_post
            out["alpha"][upd, k] = diag["alpha"]
            out["beta"][upd, k] = diag["beta"]
            out["lambda_cross"][upd, k] = diag["lambda_cross"]
            out["innovation"][upd, k] = innov
            out["flags"][upd, k] |= np.where(diag["clamped"], FLAG_CLAMPED, 0).astype(np.uint8)
        R_now = converted_covariance(z_r, z_b, design.sigma_range_m, design.sigma_bearing_rad)
        if init.any():
            gap = (times[k] - prev_t[init])[:, None]
            x_new[init, :2] = z_xy[init]
            x_new[init, 2:] = (z_xy[init] - prev_xy[init]) / gap
            P0 = np.zeros((int(init.sum()), 4, 4))
            P0[:, :2, :2] = R_now[init]
            P0[:, :2, 2:] = R_now[init] / gap[..., None]
            P0[:, 2:, :2] = R_now[init] / gap[..., None]
            P0[:, 2:, 2:] = (R_now[init] + prev_R[init]) / gap[..., None] ** 2
            P_new[init] = P0
        out["flags"][coast, k] |= FLAG_COASTED
        out["flags"][init, k] |= FLAG_INITIALISING
        idle = ~(started | init)
        out["flags"][idle, k] |= FLAG_NO_TRACK

        prev_xy[first], prev_R[first], prev_t[first] = z_xy[first], R_now[first], times[k]
        have_prev |= first
        started |= init
        n_plots[init] = 2
        x = np.where(started[:, None], x_new, x)
        P = np.where(started[:, None, None], P_new, P)
        out["state"][started, k] = x[started]
        out["covariance"][started, k] = P[started]
    return out
