"""The update strategies of the radar track-while-scan trackers (Kim & Lee 2006;
``docs/papers/radar.md``): what :func:`trackreplay.trackers.radar_tws.track_plots` hands the
prediction and the plot to, and what returns the posterior, the innovation and the per-axis α, β
of the gain (see :mod:`trackreplay.trackers.radar_tws` for the loop and the paper's equations).

``fixed``        Kalata gains at the nominal cross-range index λ̄ (the paper's "conventional").
``approximate``  α_k = ᾱ + m_α Δλ, β_k = β̄ + m_β Δλ with λ_k from the plot's range (the paper's
                 "proposed"), clamped to the stability region and flagged when clamped.
``exact``        Kalata gains recomputed at λ_k every scan (reference).
``kalman``       Kalman gain with the converted covariance R = D diag(σ_r², r²σ_θ²) Dᵀ (reference).

A polar EKF or a UKF is one more strategy here; the loop does not change.
"""

from __future__ import annotations

import numpy as np

from trackreplay.cores.filters.alpha_beta_gains import (
    approximate_gains,
    clamp_to_stability,
    floor_velocity_factor,
    kalata_steady_state,
    steady_state_variances,
    tracking_index,
    velocity_factor,
    with_startup,
)
from trackreplay.cores.filters.converted_measurements import rotated_diagonal
from trackreplay.cores.filters._kalman_fast import cv_position_update_components_fast
from trackreplay.cores.filters.kalman import cv_apply_gain_components
from trackreplay.trackers.radar_tws_design import TrackerDesign


# Strategies work on runs-last arrays: covariance components (10, n) as in trackreplay.cores.filters.kalman,
# gains (8, n) = K_pos (00, 01, 10, 11) then K_vel (00, 01, 10, 11).


class AlphaBetaGains:
    """Decoupled α-β gain strategy; ``cross_gains(λ_k, λ̄)`` decides how the cross-range gains follow λ."""

    def __init__(self, name: str, cross_gains):
        self.name = name
        self._cross_gains = cross_gains

    def update(self, x_pred, c_pred, z_range, cos_b, sin_b, r_cov, sigmas, n_plots, design: TrackerDesign, dt: float):
        """Posterior with the gain ``K = D₂ K̄₂ Dᵀ`` and the steady-state covariance those gains imply.

        λ_k and β/T use this scan's interval ``dt`` (recorded scan times jitter); the fixed
        filter's nominal λ̄ stays at the design period. ``sigmas`` are the plot's (floored)
        along-range and cross-range error stds. The velocity variance of gains off Kalata's
        curve is floored (``diag["floored"]``) so that the covariance is positive definite.
        """
        gain, c_post, diag = self.gain_and_covariance(c_pred, cos_b, sin_b, r_cov, sigmas, n_plots, design, dt)
        x_post, innovation = _linear_update(x_pred, gain, z_range, cos_b, sin_b)
        return x_post, c_post, innovation, gain, diag

    def gain_and_covariance(self, c_pred, cos_b, sin_b, r_cov, sigmas, n_plots, design: TrackerDesign, dt):
        """The gain ``(8, ...)``, the posterior covariance ``(10, ...)`` and the diagnostics of
        :meth:`update`: functions of the plot alone (not of the predicted state or covariance),
        so a stretch of scans can be taken in one call
        (:func:`trackreplay.trackers._radar_tws_blocks._steady_block`). Elementwise:
        ``dt`` may be an array shaped like the plots."""
        T = dt
        sigma_along, sigma_cross = sigmas
        lam_c = tracking_index(design.sigma_v, T, sigma_cross)
        alpha_r, beta_r, nu_r = kalata_steady_state(tracking_index(design.sigma_v, T, sigma_along))
        if np.ndim(alpha_r) == 0:  # one range error for all runs (nothing floored)
            alpha_r, beta_r, nu_r = (np.full(cos_b.shape, v) for v in (alpha_r, beta_r, nu_r))
        alpha_c, beta_c, nu_c, clamped, floored = self._cross_gains(lam_c, design.lam_nominal)
        if design.startup:
            alpha_r, beta_r, nu_r = with_startup(alpha_r, beta_r, n_plots, nu_r)
            alpha_c, beta_c, nu_c = with_startup(alpha_c, beta_c, n_plots, nu_c)
        kp = rotated_diagonal(cos_b, sin_b, alpha_r, alpha_c)
        kv = rotated_diagonal(cos_b, sin_b, beta_r / T, beta_c / T)
        gain = np.stack([kp[0], kp[1], kp[1], kp[2], kv[0], kv[1], kv[1], kv[2]])
        along = steady_state_variances(alpha_r, beta_r, T, sigma_along, nu_r)
        cross = steady_state_variances(alpha_c, beta_c, T, sigma_cross, nu_c)
        A = rotated_diagonal(cos_b, sin_b, along[0], cross[0])
        B = rotated_diagonal(cos_b, sin_b, along[1], cross[1])
        C = rotated_diagonal(cos_b, sin_b, along[2], cross[2])
        c_post = np.stack([A[0], A[1], A[2], B[0], B[1], B[1], B[2], C[0], C[1], C[2]])
        return gain, c_post, {"alpha": np.stack([alpha_r, alpha_c]), "beta": np.stack([beta_r, beta_c]),
                              "lambda_cross": lam_c, "clamped": clamped, "floored": floored}


# Cross-range gain rules: (λ_k, λ̄) → α, β, their velocity factor ν (alpha_beta_gains), clamped,
# floored. Kalata and start-up gains imply a covariance with ρ² < 1/2, so only the approximate
# rule, whose gains leave Kalata's curve, needs the velocity floor.


def _fixed(lam_c, lam_bar):
    no = np.zeros(lam_c.shape, bool)
    return tuple(np.full_like(lam_c, v) for v in kalata_steady_state(lam_bar)) + (no, no)


def _approximate(lam_c, lam_bar):
    a, b, clamped = clamp_to_stability(*approximate_gains(lam_c, lam_bar))
    nu, floored = floor_velocity_factor(a, b, velocity_factor(a, b))
    return a, b, nu, clamped, floored


def _exact(lam_c, lam_bar):
    no = np.zeros(lam_c.shape, bool)
    return kalata_steady_state(lam_c) + (no, no)


class KalmanGains:
    """Kalman gain with the converted-measurement covariance (reference strategy)."""

    name = "kalman"

    def update(self, x_pred, c_pred, z_range, cos_b, sin_b, r_cov, sigmas, n_plots, design: TrackerDesign, dt: float):
        gain, c_post = cv_position_update_components_fast(c_pred, *r_cov)
        x_post, innovation = _linear_update(x_pred, gain, z_range, cos_b, sin_b)
        return x_post, c_post, innovation, gain, self.diagnostics(gain, cos_b, sin_b, sigmas, design, dt)

    @staticmethod
    def diagnostics(gain, cos_b, sin_b, sigmas, design: TrackerDesign, dt):
        """The gain seen in the (along-range, cross-range) frame as α and β, for comparison with
        the α-β strategies, and λ_k (elementwise: ``dt`` may be an array)."""
        T = dt
        cc, ss, cs = cos_b * cos_b, sin_b * sin_b, cos_b * sin_b
        k00, k01, k10, k11, g00, g01, g10, g11 = gain
        alpha, beta = np.empty((2,) + k00.shape), np.empty((2,) + k00.shape)
        kx, gx = cs * (k01 + k10), cs * (g01 + g10)
        alpha[0] = cc * k00 + kx + ss * k11
        alpha[1] = ss * k00 - kx + cc * k11
        beta[0] = T * (cc * g00 + gx + ss * g11)
        beta[1] = T * (ss * g00 - gx + cc * g11)
        lam_c = tracking_index(design.sigma_v, T, sigmas[1])
        no = np.zeros(cos_b.shape, bool)
        return {"alpha": alpha, "beta": beta, "lambda_cross": lam_c, "clamped": no, "floored": no}


def _linear_update(x_pred, gain, z_range, cos_b, sin_b):
    """``x + K ν`` with the converted plot's innovation ``ν = (r cos θ, r sin θ) − H x``."""
    nu = np.empty((2,) + z_range.shape)
    nu[0] = z_range * cos_b - x_pred[0]
    nu[1] = z_range * sin_b - x_pred[1]
    return cv_apply_gain_components(x_pred, gain, nu), nu


STRATEGIES = {
    "fixed": AlphaBetaGains("fixed", _fixed),
    "approximate": AlphaBetaGains("approximate", _approximate),
    "exact": AlphaBetaGains("exact", _exact),
    "kalman": KalmanGains(),
}
