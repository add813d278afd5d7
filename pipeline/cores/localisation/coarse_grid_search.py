"""Coarse grid search for a Gauss-Newton start when no prior fix is available.

The paper starts Gauss-Newton from "prior information or an AOA fix" (Section I); a user
without either needs a start from the measurements alone. FDOA is linear in the emitter
velocity for a fixed position (Kim et al. 2013, eq. 4: f_k = (f₀/c)[u_iᵀ(v − ṡ_i) − u_jᵀ(v − ṡ_j)]), so
for every position of a coarse grid the best velocity is a 2-unknown weighted least-squares
problem, and the grid point with the smallest remaining cost J (eq. 6) is the start.
Every run and grid point is handled in vectorised chunks (no loop per run).

With three sensors the cost can have two exact minima (a second solution of the four
independent equations), so a grid start can pick the wrong one: the evaluator classifies
such runs as converged elsewhere rather than averaging them in.
"""

from __future__ import annotations

import numpy as np

from trackreplay.cores.localisation.batched_least_squares import scaled_least_squares
from trackreplay.cores.localisation.cep_plane import grid_axis
from trackreplay.cores.localisation.tdoa_fdoa_model import measurement_model

CHUNK_ELEMENTS = 200_000  # runs × grid points per vectorised block


def grid_offsets(extent_m: float, step_m: float) -> np.ndarray:
    """Offsets (G, 2) of a square grid ±``extent_m`` at ``step_m`` spacing (both axes
    :func:`trackreplay.cores.localisation.cep_plane.grid_axis`)."""
    axis = grid_axis(extent_m, step_m)
    gx, gy = np.meshgrid(axis, axis)
    return np.stack([gx.ravel(), gy.ravel()], axis=-1)


def coarse_grid_start(measured, sigma, sensor_pos, sensor_vel, pairs, carrier_hz, rows,
                      velocity_free: bool, extent_m: float, step_m: float) -> np.ndarray:
    """Best grid position (and its least-squares velocity) for every run.

    Parameters
    ----------
    measured, sigma : ndarray (B, 2N)
        Measurements and their standard deviations (full TDOA+FDOA layout).
    sensor_pos, sensor_vel : ndarray (B, M, 2)
    pairs : ndarray (N, 2)
    carrier_hz : ndarray (B,)
    rows : ndarray of int
        Measurement rows the estimator uses.
    velocity_free : bool
        Fit the velocity per grid point (else it is 0: stationary emitter, or TDOA only).
    extent_m, step_m : float
        Grid half-width and spacing, centred on each run's sensor centroid.

    Returns
    -------
    ndarray (B, 4)
        Start states; NaN for a run whose every grid cost is undefined.
    """
    offsets = grid_offsets(extent_m, step_m)
    B, G = measured.shape[0], len(offsets)
    n = len(pairs)
    fdoa_rows = rows[rows >= n]
    out = np.full((B, 4), np.nan)
    chunk = max(1, CHUNK_ELEMENTS // G)
    for lo in range(0, B, chunk):
        sl = slice(lo, min(B, lo + chunk))
        b = sl.stop - sl.start
        centre = sensor_pos[sl].mean(axis=1)
        theta = np.zeros((b, G, 4))
        theta[..., :2] = centre[:, None, :] + offsets[None]
        with np.errstate(all="ignore"):
            g, H = measurement_model(theta, sensor_pos[sl, None], sensor_vel[sl, None], pairs,
                                     carrier_hz[sl, None])
            resid = (measured[sl, None, :] - g) / sigma[sl, None, :]
        cost = np.sum(resid[..., rows] ** 2, axis=-1)
        vel = np.zeros((b, G, 2))
        if velocity_free and fdoa_rows.size:
            A = (H[..., fdoa_rows, 2:] / sigma[sl, None, fdoa_rows, None]).reshape(b * G, len(fdoa_rows), 2)
            r = resid[..., fdoa_rows].reshape(b * G, len(fdoa_rows))
            finite = np.all(np.isfinite(A), axis=(1, 2)) & np.all(np.isfinite(r), axis=1)
            sol = scaled_least_squares(np.where(finite[:, None, None], A, 0.0), np.where(finite[:, None], r, 0.0))
            usable = finite & ~sol.rank_deficient
            vel = np.where(usable[:, None], sol.x, 0.0).reshape(b, G, 2)
            # the velocity fit removes the projected part of the FDOA residual from the cost
            cost = cost - np.where(usable, sol.projected_norm ** 2, 0.0).reshape(b, G)
        cost = np.where(np.isfinite(cost), cost, np.inf)
        best = np.argmin(cost, axis=1)
        found = np.isfinite(cost[np.arange(b), best])
        pick = theta[np.arange(b), best]
        pick[:, 2:] = vel[np.arange(b), best]
        out[sl] = np.where(found[:, None], pick, np.nan)
    return out
