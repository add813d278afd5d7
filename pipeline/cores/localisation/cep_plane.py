"""CEP planes: position and velocity CEP at every emitter position of a grid.

Kim et al. (2013), Section IV, eqs. 18–22 and Figs. 5–6 (see ``docs/papers/tdoa-fdoa.md``):
for each grid position the 4-state CRLB is computed at θ = [x, y, ẋ, ẏ] with the emitter's
(fixed) velocity, projected onto the position and the velocity subspace (eq. 19), and reduced
to a CEP. The paper's grid is ±50 km at 500 m (201 × 201 points) with contours at
50/100/200 m (position) and 5/10/15 m/s (velocity).

All grid points are evaluated in one vectorised pass (Jacobians, QR-based CRLBs and CEPs).
Points where the bound does not exist — the emitter on a sensor, or collinear with a line of
sensors (the y = 0 axis of the paper's line geometry, where y and ẏ are unobservable) — are
NaN and reported in ``singular``, never given a number.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trackreplay.cores.localisation.crlb import cep_approx, cep_exact, cep_paper, crlb, projection_covariance
from trackreplay.cores.localisation.tdoa_fdoa_model import measurement_model, measurement_rows, unknowns

POSITION_CONTOURS_M = (50.0, 100.0, 200.0)
VELOCITY_CONTOURS_MPS = (5.0, 10.0, 15.0)
CEP_METHODS = ("exact", "paper", "approx")


@dataclass
class CepPlane:
    """Position and velocity CEP over a grid (rows = y, columns = x).

    Attributes
    ----------
    x_m, y_m : ndarray (nx,), (ny,)
    position_m : ndarray (ny, nx)
    velocity_mps : ndarray (ny, nx)
        NaN when velocity is not estimated (stationary emitter, TDOA only).
    singular : ndarray of bool (ny, nx)
        Points where the Fisher information is singular or undefined.
    method : str
    probability : float
    """

    x_m: np.ndarray
    y_m: np.ndarray
    position_m: np.ndarray
    velocity_mps: np.ndarray
    singular: np.ndarray
    method: str
    probability: float


def grid_axis(extent_m: float, step_m: float) -> np.ndarray:
    """Symmetric axis −extent … +extent at ``step_m`` (201 points for the paper's ±50 km, 500 m)."""
    n = int(np.floor(extent_m / step_m + 1e-9))
    return np.arange(-n, n + 1) * step_m


def _cep(cov2, method, probability):
    if method == "exact":
        return cep_exact(cov2, probability)
    if method == "paper":
        return cep_paper(cov2, probability)
    if method == "approx":
        if probability != 0.5:
            raise ValueError("the 0.75·√(λ₁+λ₂) approximation is for the 50 % CEP only")
        return cep_approx(cov2)
    raise ValueError(f"unknown CEP method {method!r} (have: {', '.join(CEP_METHODS)})")


def cep_plane(sensor_pos, sensor_vel, pairs, emitter_velocity, carrier_hz, sigma, x_m, y_m,
              kind: str = "joint", stationary: bool = False, method: str = "exact",
              probability: float = 0.5) -> CepPlane:
    """Position and velocity CEP at every (x, y) of a grid.

    Parameters
    ----------
    sensor_pos, sensor_vel : ndarray (M, 2)
    pairs : ndarray (N, 2)
    emitter_velocity : ndarray (2,)
        The emitter's velocity at every grid point (the paper: (200, 0) m/s).
    carrier_hz : float
    sigma : ndarray (2N,)
        σ of each measurement in g's layout (σ_TDOA for the N TDOAs, then σ_FDOA).
    x_m, y_m : ndarray
        Grid axes.
    kind : {"joint", "tdoa", "fdoa"}
        Measurements used.
    stationary : bool
        Velocity known (position-only CRLB).
    method : {"exact", "paper", "approx"}
        CEP formula (see :mod:`trackreplay.cores.localisation.crlb`).
    probability : float
        P_e.
    """
    x_m, y_m = np.asarray(x_m, float), np.asarray(y_m, float)
    gx, gy = np.meshgrid(x_m, y_m)
    theta = np.empty(gx.shape + (4,))
    theta[..., 0], theta[..., 1] = gx, gy
    theta[..., 2:] = np.asarray(emitter_velocity, float)
    rows = measurement_rows(kind, len(pairs))
    free = unknowns(kind, stationary)
    with np.errstate(all="ignore"):
        _, H = measurement_model(theta, np.asarray(sensor_pos, float), np.asarray(sensor_vel, float), pairs, carrier_hz)
        cov, singular = crlb(H[..., rows, :][..., free], np.asarray(sigma, float)[rows])
    pos = _cep(projection_covariance(cov, [0, 1]), method, probability)
    if len(free) == 4:
        vel = _cep(projection_covariance(cov, [2, 3]), method, probability)
    else:
        vel = np.full(pos.shape, np.nan)
    pos = np.where(singular, np.nan, pos)
    vel = np.where(singular, np.nan, vel)
    return CepPlane(x_m, y_m, pos, vel, singular, method, probability)


def cep_plane_areas(plane: CepPlane, step_m: float) -> dict:
    """The smallest CEP and the area below each of the paper's contour levels (Figs. 5–6).

    Parameters
    ----------
    plane : CepPlane
        A square grid (as :func:`grid_axis` gives).
    step_m : float
        Grid spacing (m).

    Returns
    -------
    dict
        ``{"position_m" | "velocity_mps": {"min": float, "area_km2": {level: km²}}}`` for the
        planes that hold a finite CEP; the area counts grid cells (fraction of the grid below the
        level times the grid's area).
    """
    area = (plane.x_m.size * step_m / 1e3) ** 2
    out = {}
    for key, levels in (("position_m", POSITION_CONTOURS_M), ("velocity_mps", VELOCITY_CONTOURS_MPS)):
        z = getattr(plane, key)
        if not np.isfinite(z).any():
            continue
        with np.errstate(invalid="ignore"):
            out[key] = {"min": float(np.nanmin(z)), "area_km2": {lv: float(np.mean(z < lv) * area) for lv in levels}}
    return out
