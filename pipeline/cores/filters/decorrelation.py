"""Decorrelation of AR(1) measurement noise by measurement differencing (Kwon 1997, ch. III.1).

Kwon (1997), ch. III.1, the decorrelation process (thesis eqs. 3.1.1–3.1.6); see
``docs/papers/colored.md``.
With an estimate ``ᾱ`` of the noise's AR coefficient (one per measured axis, ``Ā = diag(ᾱ)``)
the pseudo-measurement

    y_k = z_k − Ā z_{k−1} = Ĥ x_k + ν̂_k,     Ĥ = H − Ā H Φ⁻¹                      (3.1.1, 3.1.3)

has the noise ``ν̂_k = Ā H Φ⁻¹ Ψ w_{k−1} + (A − Ā) ν_{k−1} + η_k`` (3.1.4): white when
``Ā ≈ A`` but correlated with the previous process noise, a small term the thesis (and this
code) neglects. The filter then uses ``(y_k, Ĥ, R̂ = diag(σ_η²))``. ``Ĥ`` depends on each motion
model's Φ, so every model of an IMM has its own; ``Ā`` may differ per run (estimated per run).
"""

from __future__ import annotations

import numpy as np

from trackreplay.errors import InputError


def transition_inverse_check(Phi, name: str = "Phi",
                             needed_by: str = "the decorrelation process (eq. 3.1.3)") -> np.ndarray:
    """Validate a state transition whose inverse is used (decorrelation, SRIF time update).

    Parameters
    ----------
    Phi : array_like (n, n)
    name : str
        What Φ is (for the message).
    needed_by : str
        What needs Φ⁻¹ (for the message).

    Returns
    -------
    ndarray (n, n)
        Φ as float64.

    Raises
    ------
    InputError
        If Φ is not square, holds NaN/Inf, or is singular to working precision
        (condition number above 1/ε).
    """
    Phi = np.asarray(Phi, dtype=float)
    if Phi.ndim != 2 or Phi.shape[0] != Phi.shape[1]:
        raise InputError(f"{name} must be square, got shape {Phi.shape}")
    if not np.all(np.isfinite(Phi)):
        raise InputError(f"{name} holds NaN/Inf")
    cond = np.linalg.cond(Phi)
    if not np.isfinite(cond) or cond > 1.0 / np.finfo(float).eps:
        raise InputError(f"{name} is singular (condition number {cond:.3g}); {needed_by} needs Φ⁻¹")
    return Phi


def inverse_transition_rows(H: np.ndarray, Phi: np.ndarray, name: str = "Phi") -> np.ndarray:
    """``H Φ⁻¹`` through a solve (``Φᵀ Xᵀ = Hᵀ``); a singular Φ is an :class:`InputError`.

    Parameters
    ----------
    H : ndarray (m, n)
    Phi : ndarray (n, n)
    name : str
        What Φ is (for the message).
    """
    Phi = transition_inverse_check(Phi, name)
    return np.linalg.solve(Phi.T, np.asarray(H, dtype=float).T).T


def decorrelated_measurement_matrix(H: np.ndarray, H_Phi_inv: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """``Ĥ = H − Ā H Φ⁻¹`` (eq. 3.1.3) for every run.

    Parameters
    ----------
    H, H_Phi_inv : ndarray (m, n)
    alpha : ndarray (..., m)
        ``ᾱ`` per measured axis.

    Returns
    -------
    ndarray (..., m, n)
    """
    return H - np.asarray(alpha)[..., :, None] * H_Phi_inv


def pseudo_measurement(z: np.ndarray, z_prev: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """``y_k = z_k − Ā z_{k−1}`` (eq. 3.1.1); all arrays ``(..., m)``."""
    return z - alpha * z_prev


def pseudo_measurements(z: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """``y_k`` for a whole record ``z`` ``(runs, scans, m)``; scan 0 has no predecessor (NaN)."""
    y = np.full_like(z, np.nan, dtype=float)
    y[:, 1:] = pseudo_measurement(z[:, 1:], z[:, :-1], alpha[:, 1:])
    return y
