"""Polar radar plots as Cartesian measurements (spec: radar-alpha-beta.md, "Converted measurements").

Bearing convention used everywhere in this project: θ is measured counter-clockwise from the
+x axis (mathematical convention), so ``x = r cos θ``, ``y = r sin θ``.
"""

from __future__ import annotations

import numpy as np


def polar_to_cartesian(range_m, bearing_rad):
    """``(x, y) = (r cos θ, r sin θ)``; returns an array ``(..., 2)``."""
    r = np.asarray(range_m, dtype=float)
    th = np.asarray(bearing_rad, dtype=float)
    return np.stack([r * np.cos(th), r * np.sin(th)], axis=-1)


def rotation(bearing_rad):
    """``D(θ)``: columns are the along-range and cross-range unit vectors, ``(..., 2, 2)``."""
    c = np.cos(bearing_rad)
    s = np.sin(bearing_rad)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


def rotated_diagonal(cos_b, sin_b, along, cross):
    """Entries ``(m00, m01, m11)`` of ``D diag(along, cross) Dᵀ`` with ``D`` the rotation by θ.

    The element-wise form of rotating an (along-range, cross-range) diagonal matrix into x/y:
    used for converted covariances, decoupled gains and their steady-state covariances.
    """
    cc, ss, cs = cos_b * cos_b, sin_b * sin_b, cos_b * sin_b
    return along * cc + cross * ss, (along - cross) * cs, along * ss + cross * cc


#: Smallest ratio of the two principal variances of a converted covariance (σ ratio 10⁻³).
#: A Cartesian covariance holds its small eigenvalues only to about ε·(large one), and a Kalman
#: update in x/y turns a variance ratio κ between the plot's axes into relative errors of about
#: ε/κ² in the small directions of the posterior (ε = 2.2·10⁻¹⁶). Plots whose along-range and
#: cross-range errors differ by more than 10³ in σ (a very precise range far out, or a plot next
#: to the radar where r·σ_θ → 0) gave covariances that were not numerically positive definite;
#: at this floor the errors stay ~10⁻⁴ of the smallest variance. The paper's geometry
#: (σ_r = 100 m, σ_θ = 1°) reaches it only within 6 m of the radar.
RELATIVE_VARIANCE_FLOOR = 1e-6


def floored_polar_variances(range_m, sigma_range_m, sigma_bearing_rad, floor: float = RELATIVE_VARIANCE_FLOOR):
    """Along-range and cross-range variances ``(σ_r², r²σ_θ²)`` of a plot, the smaller raised to
    ``floor`` times the larger where it is below.

    Returns
    -------
    var_along, var_cross : ndarray
        ``σ_r²`` and ``(r σ_θ)²`` (broadcast to ``range_m``), floored.
    floored : ndarray of bool
        True where either was raised; callers flag those scans ``FLOORED``.
    """
    r = np.asarray(range_m, dtype=float)
    along = np.broadcast_to(np.asarray(sigma_range_m, dtype=float) ** 2, r.shape)
    cross = (r * sigma_bearing_rad) ** 2
    low_along = along < floor * cross
    low_cross = cross < floor * along
    along = np.where(low_along, floor * cross, along)
    cross = np.where(low_cross, floor * along, cross)
    return along, cross, low_along | low_cross


def converted_covariance(range_m, bearing_rad, sigma_range_m: float, sigma_bearing_rad: float):
    """``R = D diag(σ_r², r² σ_θ²) Dᵀ``, the linearised converted-measurement covariance.

    Valid while ``r σ_θ² / σ_r < 0.4`` and ``σ_θ < 0.4 rad`` (spec). Not floored (the trackers
    use :func:`floored_polar_variances`).
    """
    r = np.asarray(range_m, dtype=float)
    D = rotation(bearing_rad)
    diag = np.zeros(r.shape + (2, 2))
    diag[..., 0, 0] = sigma_range_m**2
    diag[..., 1, 1] = (r * sigma_bearing_rad) ** 2
    return D @ diag @ np.swapaxes(D, -1, -2)
