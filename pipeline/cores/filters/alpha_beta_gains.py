"""Kalata's optimal α-β gains and the approximate per-scan gain update (Kim & Lee 2006).

Kim & Lee (2006) after Kalata (1984); see ``docs/papers/radar-tws.md``. All functions are pure and broadcast over arrays.

* :func:`tracking_index` — Kalata's λ = σ_v T² / σ_w.
* :func:`kalata_gains` — α(λ), β(λ), the steady-state Kalman gains of the white-acceleration
  model (paper eq. for α, β; Kalata 1984).
* :func:`kalata_gain_slopes` — m_α = ∂α/∂λ, m_β = ∂β/∂λ at the nominal index (paper's
  linearisation).
* :func:`approximate_gains` — α_k = ᾱ + m_α Δλ, β_k = β̄ + m_β Δλ (the paper's proposed
  update, nominal-point form, the one it simulates).
* :func:`clamp_to_stability` — keep (α, β) inside 0 < α < 1, 0 < β < 4 − 2α and flag it.
* :func:`startup_gains` — expanding-memory (least-squares) gains for the first plots of a
  track, the textbook α-β track start; the filter uses them while they exceed the steady state.
* :func:`steady_state_covariance` — the updated error covariance the gains imply, used for
  gates and for the covariance an α-β track reports.
"""

from __future__ import annotations

import numpy as np


def tracking_index(sigma_v: float, T: float, sigma_w):
    """Kalata's tracking index ``λ = σ_v T² / σ_w``."""
    return sigma_v * T * T / np.asarray(sigma_w, dtype=float)


def kalata_gains(lam):
    """Optimal steady-state gains for tracking index ``λ``.

    Returns
    -------
    alpha, beta : ndarray
        ``α = −(λ² + 8λ − (λ + 4)√(λ² + 8λ)) / 8``, ``β = (λ² + 4λ − λ√(λ² + 8λ)) / 4``.
    """
    lam = np.asarray(lam, dtype=float)
    root = np.sqrt(lam * lam + 8.0 * lam)
    alpha = -(lam * lam + 8.0 * lam - (lam + 4.0) * root) / 8.0
    beta = (lam * lam + 4.0 * lam - lam * root) / 4.0
    return alpha, beta


def kalata_gain_slopes(lam_bar):
    """Derivatives of the Kalata gains at the nominal index ``λ̄``.

    Returns
    -------
    m_alpha, m_beta : ndarray
        ``m_α = −¼ (λ̄ + 4 − (λ̄² + 8λ̄ + 8)/√(λ̄² + 8λ̄))``,
        ``m_β = ½ (λ̄ + 2 − (λ̄² + 6λ̄)/√(λ̄² + 8λ̄))``.
    """
    lam = np.asarray(lam_bar, dtype=float)
    root = np.sqrt(lam * lam + 8.0 * lam)
    m_alpha = -0.25 * (lam + 4.0 - (lam * lam + 8.0 * lam + 8.0) / root)
    m_beta = 0.5 * (lam + 2.0 - (lam * lam + 6.0 * lam) / root)
    return m_alpha, m_beta


def approximate_gains(lam, lam_bar):
    """The paper's first-order gain update around the nominal index.

    Costs two multiply-adds per scan on top of the fixed-gain filter because ᾱ, β̄, m_α, m_β
    depend on ``λ̄`` only and are computed once.
    """
    alpha_bar, beta_bar = kalata_gains(lam_bar)
    m_alpha, m_beta = kalata_gain_slopes(lam_bar)
    d_lam = np.asarray(lam, dtype=float) - lam_bar
    return alpha_bar + m_alpha * d_lam, beta_bar + m_beta * d_lam


def clamp_to_stability(alpha, beta, margin: float = 1e-3):
    """Project gains into the α-β stability region and say where that was needed.

    The linearised update can leave ``0 < α < 1, 0 < β < 4 − 2α`` when λ_k is far from the
    nominal (a target close to the radar); such a filter would diverge, so the gains are
    pulled back inside by ``margin`` and the scan is flagged.

    Returns
    -------
    alpha, beta : ndarray
        Clamped gains.
    clamped : ndarray of bool
        True where either gain was changed.
    """
    alpha = np.asarray(alpha, dtype=float)
    beta = np.asarray(beta, dtype=float)
    a = np.clip(alpha, margin, 1.0 - margin)
    b = np.clip(beta, margin, 4.0 - 2.0 * a - margin)
    return a, b, (a != alpha) | (b != beta)


def startup_gains(n_plots):
    """Least-squares α-β gains after ``n`` plots of a new track.

    ``α_n = 2(2n − 1) / (n(n + 1))``, ``β_n = 6 / (n(n + 1))``: the gains that make the α-β
    filter the straight-line least-squares fit of the ``n`` plots so far. ``n = 2`` gives
    α = β = 1, exactly the two-point start; they fall towards zero as the track ages, and a
    filter switches to its steady-state gains once ``α_n`` drops below them.
    """
    n = np.asarray(n_plots, dtype=float)
    return 2.0 * (2.0 * n - 1.0) / (n * (n + 1.0)), 6.0 / (n * (n + 1.0))


def with_startup(alpha, beta, n_plots):
    """Use the start-up gains while they exceed the steady-state α (per element)."""
    a_ls, b_ls = startup_gains(n_plots)
    early = a_ls > alpha
    return np.where(early, a_ls, alpha), np.where(early, b_ls, beta)


def steady_state_covariance(alpha, beta, T: float, sigma_w):
    """Updated error covariance of a steady-state α-β filter, per axis.

    For gains that are Kalman-optimal for their λ (Kalata's relations)::

        p11 = α σ_w²,  p12 = β σ_w² / T,  p22 = β (α − β/2) σ_w² / ((1 − α) T²)

    Returns
    -------
    P : ndarray, shape (..., 2, 2)
        Position/velocity covariance of one axis.
    """
    p11, p12, p22 = steady_state_variances(alpha, beta, T, sigma_w)
    return np.stack([np.stack([p11, p12], -1), np.stack([p12, p22], -1)], -2)


def steady_state_variances(alpha, beta, T: float, sigma_w):
    """The three distinct entries ``(p11, p12, p22)`` of :func:`steady_state_covariance`."""
    alpha = np.asarray(alpha, dtype=float)
    beta = np.asarray(beta, dtype=float)
    var = np.asarray(sigma_w, dtype=float) ** 2
    return alpha * var, beta * var / T, beta * (alpha - 0.5 * beta) * var / ((1.0 - alpha) * T * T)
