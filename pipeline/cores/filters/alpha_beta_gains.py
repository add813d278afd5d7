"""Kalata's optimal α-β gains and the approximate per-scan gain update (Kim & Lee 2006).

Kim & Lee (2006) after Kalata (1984); see ``docs/papers/radar.md``. All functions are pure and broadcast over arrays.

* :func:`tracking_index` — Kalata's λ = σ_v T² / σ_w.
* :func:`kalata_gains` — α(λ), β(λ), the steady-state Kalman gains of the white-acceleration
  model (paper eq. for α, β; Kalata 1984), evaluated in a form free of cancellation
  (:func:`kalata_steady_state` adds the velocity factor ν of their covariance).
* :func:`kalata_gain_slopes` — m_α = ∂α/∂λ, m_β = ∂β/∂λ at the nominal index (paper's
  linearisation).
* :func:`approximate_gains` — α_k = ᾱ + m_α Δλ, β_k = β̄ + m_β Δλ (the paper's proposed
  update, nominal-point form, the one it simulates).
* :func:`clamp_to_stability` — keep (α, β) inside 0 < α < 1, 0 < β < 4 − 2α and flag it.
* :func:`startup_gains` — expanding-memory (least-squares) gains for the first plots of a
  track, the textbook α-β track start; the filter uses them while they exceed the steady state.
* :func:`steady_state_covariance` — the updated error covariance the gains imply, used for
  gates and for the covariance an α-β track reports; :func:`kalata_velocity_factor`,
  :func:`velocity_factor` and :func:`floor_velocity_factor` give its velocity variance in a form
  that stays positive definite (see "Numerical range" below).

Numerical range
---------------
With ``r = √(λ² + 8λ)`` and ``s = λ + 4 + r`` the paper's expressions rearrange (using
``(λ + 4)² − r² = 16``) into ratios of positive terms::

    α = 2r/s,   β = 4λ/s,   1 − α = 16/s²,   α − β/2 = 16λ/(s(λ + r)),
    m_α = 32/(s² r),   m_β = 32λ/(s r (λ + r)),   p22 T²/σ_w² = 4λ²/(λ + r)

which is how they are evaluated here: the textbook forms subtract nearly equal numbers when λ is
large (a small σ_w or a long scan period) and gave α ≥ 1, hence a NaN or negative velocity
variance, from λ ≈ 10⁷ on. The rearranged forms keep full relative precision for every λ > 0.

Kalata-optimal gains and the least-squares start-up gains imply a covariance whose
position-velocity correlation ρ² = p12²/(p11 p22) is below 1/2 (the supremum, reached as λ → 0).
Gains off that curve (the approximate update far from λ̄, after the stability clamp) can imply a
negative or too small velocity variance; :func:`floor_velocity_factor` raises it to the value
with ρ² = 1/2 and says where it did (the trackers flag those scans ``FLOORED``).
"""

from __future__ import annotations

import numpy as np


def tracking_index(sigma_v: float, T: float, sigma_w):
    """Kalata's tracking index ``λ = σ_v T² / σ_w``."""
    return sigma_v * T * T / np.asarray(sigma_w, dtype=float)


def _root_and_sum(lam):
    """``r = √(λ² + 8λ)`` (as ``√λ √(λ + 8)``, which cannot overflow) and ``s = λ + 4 + r``."""
    lam = np.asarray(lam, dtype=float)
    root = np.sqrt(lam) * np.sqrt(lam + 8.0)
    return lam, root, lam + 4.0 + root


def kalata_gains(lam):
    """Optimal steady-state gains for tracking index ``λ``.

    Returns
    -------
    alpha, beta : ndarray
        ``α = −(λ² + 8λ − (λ + 4)√(λ² + 8λ)) / 8``, ``β = (λ² + 4λ − λ√(λ² + 8λ)) / 4``,
        evaluated as ``α = 2r/s``, ``β = 4λ/s`` (module docstring): the same numbers, to
        rounding, without the cancellation of the textbook form at large λ.
    """
    lam, root, s = _root_and_sum(lam)
    return 2.0 * root / s, 4.0 * lam / s


def kalata_steady_state(lam):
    """:func:`kalata_gains` and :func:`kalata_velocity_factor` in one pass: ``(α, β, ν)``."""
    lam, root, s = _root_and_sum(lam)
    return 2.0 * root / s, 4.0 * lam / s, 4.0 * lam * lam / (lam + root)


def kalata_velocity_factor(lam):
    """``ν = p22 T² / σ_w²`` of the Kalata-optimal filter at ``λ``: ``4λ² / (λ + √(λ² + 8λ))``.

    Equal to ``β(α − β/2)/(1 − α)`` at the Kalata gains (:func:`velocity_factor`), without the
    division by ``1 − α``, which rounds to zero for λ ≳ 10⁸.
    """
    lam, root, _ = _root_and_sum(lam)
    return 4.0 * lam * lam / (lam + root)


def velocity_factor(alpha, beta):
    """``ν = β(α − β/2)/(1 − α)`` for any gains with ``α < 1``: the velocity variance of
    :func:`steady_state_covariance` in units of ``σ_w²/T²`` (negative for gains with β > 2α)."""
    alpha = np.asarray(alpha, dtype=float)
    beta = np.asarray(beta, dtype=float)
    return beta * (alpha - 0.5 * beta) / (1.0 - alpha)


def floor_velocity_factor(alpha, beta, nu):
    """Raise ``ν`` to ``2β²/α`` where it is below, so that the covariance the gains imply has
    position-velocity correlation ρ² ≤ 1/2 and is positive definite.

    Kalata-optimal and least-squares start-up gains never reach the floor (their ρ² < 1/2);
    gains off that curve can (module docstring).

    Returns
    -------
    nu : ndarray
        Floored velocity factor.
    floored : ndarray of bool
        True where ``ν`` was raised (or was not a number).
    """
    alpha = np.asarray(alpha, dtype=float)
    beta = np.asarray(beta, dtype=float)
    nu = np.asarray(nu, dtype=float)
    floor = 2.0 * beta * beta / alpha
    floored = ~(nu >= floor)
    return np.where(floored, floor, nu), floored


def kalata_gain_slopes(lam_bar):
    """Derivatives of the Kalata gains at the nominal index ``λ̄``.

    Returns
    -------
    m_alpha, m_beta : ndarray
        ``m_α = −¼ (λ̄ + 4 − (λ̄² + 8λ̄ + 8)/√(λ̄² + 8λ̄))``,
        ``m_β = ½ (λ̄ + 2 − (λ̄² + 6λ̄)/√(λ̄² + 8λ̄))``, evaluated as ``m_α = 32/(s² r)``,
        ``m_β = 32λ̄/(s r (λ̄ + r))`` (module docstring).
    """
    lam, root, s = _root_and_sum(lam_bar)
    return 32.0 / (s * s * root), 32.0 * lam / (s * root * (lam + root))


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


def with_startup(alpha, beta, n_plots, nu=None):
    """Use the start-up gains while they exceed the steady-state α (per element).

    With ``nu`` (the steady-state gains' :func:`velocity_factor`) the velocity factor follows
    the gains and is returned third: the start-up gains' own,
    ``ν_n = 6(4n − 5)/(n(n + 1)(n − 1)(n − 2))``, which needs ``n ≥ 3`` (``α_2 = 1``).
    """
    a_ls, b_ls = startup_gains(n_plots)
    early = a_ls > alpha
    if not early.any():  # past start-up (most scans): the steady-state gains as they are
        return (alpha, beta) if nu is None else (alpha, beta, nu)
    out = np.where(early, a_ls, alpha), np.where(early, b_ls, beta)
    if nu is None:
        return out
    n = np.asarray(n_plots, dtype=float)
    nu_ls = 6.0 * (4.0 * n - 5.0) / (n * (n + 1.0) * (n - 1.0) * (n - 2.0))
    return out + (np.where(early, nu_ls, nu),)


def steady_state_covariance(alpha, beta, T: float, sigma_w, nu=None):
    """Updated error covariance of a steady-state α-β filter, per axis.

    For gains that are Kalman-optimal for their λ (Kalata's relations)::

        p11 = α σ_w²,  p12 = β σ_w² / T,  p22 = β (α − β/2) σ_w² / ((1 − α) T²) = ν σ_w² / T²

    ``nu`` gives ``ν`` directly (:func:`kalata_velocity_factor`, or a floored value); without it
    ``ν`` is :func:`velocity_factor` of the gains.

    Returns
    -------
    P : ndarray, shape (..., 2, 2)
        Position/velocity covariance of one axis.
    """
    p11, p12, p22 = steady_state_variances(alpha, beta, T, sigma_w, nu)
    return np.stack([np.stack([p11, p12], -1), np.stack([p12, p22], -1)], -2)


def steady_state_variances(alpha, beta, T: float, sigma_w, nu=None):
    """The three distinct entries ``(p11, p12, p22)`` of :func:`steady_state_covariance`."""
    alpha = np.asarray(alpha, dtype=float)
    beta = np.asarray(beta, dtype=float)
    var = np.asarray(sigma_w, dtype=float) ** 2
    if nu is None:
        return alpha * var, beta * var / T, beta * (alpha - 0.5 * beta) * var / ((1.0 - alpha) * T * T)
    return alpha * var, beta * var / T, np.asarray(nu, dtype=float) * var / (T * T)
