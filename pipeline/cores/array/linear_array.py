"""Uniform linear array: steering vectors and their angle derivative.

Ryu, Lee & Lee (2001), signal model eqs. (1)–(5) and the Taylor term of eq. (10); see
``docs/papers/array.md``. Sensor 1 (the left end) is the reference; angles are measured
from broadside, in radians. The electrical spacing enters only through
``κ = ω d / c = 2π d/λ`` (``spacing_wavelengths = d/λ``; d = λ/2 gives κ = π).

    a(θ) = [1, γ, γ², …, γ^(M−1)]ᵀ,   γ = exp(j κ sin θ)
    b(θ) = ∂a/∂θ = j κ cos θ · [0, 1, …, M−1]ᵀ ⊙ a(θ)
"""

from __future__ import annotations

import numpy as np


def electrical_spacing(spacing_wavelengths: float) -> float:
    """``κ = ω d / c = 2π d/λ`` (rad per unit of sin θ per sensor)."""
    return 2.0 * np.pi * float(spacing_wavelengths)


def steering_vectors(theta: np.ndarray, n_sensors: int, spacing_wavelengths: float) -> np.ndarray:
    """Steering vectors ``a(θ)`` for every angle, stacked on the last axis.

    Parameters
    ----------
    theta : ndarray, shape (..., N)
        Angles from broadside (rad).
    n_sensors : int
        M.
    spacing_wavelengths : float
        d/λ.

    Returns
    -------
    ndarray, complex, shape (..., M, N)
        Column n is ``a(θ_n)``.
    """
    theta = np.asarray(theta, dtype=float)
    m = np.arange(n_sensors, dtype=float)
    phase = electrical_spacing(spacing_wavelengths) * np.sin(theta)[..., None, :] * m[:, None]
    # exp(jφ) as cos φ + j sin φ written in place: the value of the complex exponential of a
    # purely imaginary argument, without the complex argument array and the complex exp
    out = np.empty(phase.shape, dtype=complex)
    np.cos(phase, out=out.real)
    np.sin(phase, out=out.imag)
    return out


def steering_derivatives(theta: np.ndarray, a: np.ndarray, spacing_wavelengths: float) -> np.ndarray:
    """``b(θ) = ∂a/∂θ`` given ``a = steering_vectors(θ)`` (paper eq. (10)).

    Parameters
    ----------
    theta : ndarray, shape (..., N)
    a : ndarray, complex, shape (..., M, N)
    spacing_wavelengths : float

    Returns
    -------
    ndarray, complex, shape (..., M, N)
    """
    m = np.arange(a.shape[-2], dtype=float)
    scale = electrical_spacing(spacing_wavelengths) * np.cos(np.asarray(theta, float))[..., None, :] * m[:, None]
    return 1j * scale * a


def beamwidth_rad(n_sensors: int, spacing_wavelengths: float = 0.5) -> float:
    """Broadside null-to-null half width ``λ/(M d)`` (≈ 2/M rad for d = λ/2)."""
    return 1.0 / (n_sensors * float(spacing_wavelengths))
