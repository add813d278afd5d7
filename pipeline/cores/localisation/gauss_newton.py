"""Gauss-Newton for weighted nonlinear least squares, every Monte Carlo run in one pass.

Kim et al. (2013), eqs. 6, 8 and 15–17 (see ``docs/papers/tdoa-fdoa.md``)::

    J(θ) = (u − g(θ))ᵀ Ψ⁻¹ (u − g(θ))                         (6)
    δ = (Hᵀ Ψ⁻¹ H)⁻¹ Hᵀ Ψ⁻¹ (u − g(θ̂_n)),  θ̂_{n+1} = θ̂_n + δ     (16, 17)

δ is computed as the whitened, column-scaled least-squares solution
min ‖Ψ^{-1/2}(H δ − (u − g))‖ by Householder QR (:mod:`pipeline.cores.localisation.batched_least_squares`),
never by inverting HᵀΨ⁻¹H. The stopping rule is unit-free: a run has converged when its last
step was shorter than ``step_tolerance`` standard deviations, i.e. √(δᵀ I(θ̂) δ) < tol with
I = HᵀΨ⁻¹H (the same quantity as ‖Q₁ᵀ r‖ from the QR).

Runs are never averaged blindly: each ends with flags (the bits ``CONVERGED``,
``NOT_CONVERGED``, ``DIVERGED``, ``RANK_DEFICIENT`` and ``INVALID_START`` of the one flag table,
:data:`pipeline.vocabulary.FLAGS`, as uint16) and keeps its last finite iterate. The loop runs
over iterations only; each iteration handles every still-active run in one vectorised call of
the model.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from pipeline.cores.localisation.batched_least_squares import covariance_from_factor, scaled_least_squares
# the status bits are those of the one flag table (uint16), re-exported for the callers of this core
from pipeline.vocabulary import CONVERGED, DIVERGED, FLAG_DTYPE, INVALID_START, NOT_CONVERGED, RANK_DEFICIENT

__all__ = ["CONVERGED", "NOT_CONVERGED", "DIVERGED", "RANK_DEFICIENT", "INVALID_START", "GaussNewtonResult",
           "gauss_newton", "final_statistics"]


@dataclass
class GaussNewtonResult:
    """Outcome of :func:`gauss_newton` for B runs with p state components.

    Attributes
    ----------
    theta : ndarray (B, p)
        Final (last finite) estimate.
    iterates : ndarray (B, iterations + 1, p)
        θ̂₀ … θ̂_n; a run that stopped early repeats its final value.
    iterations : ndarray of int (B,)
        Steps applied.
    step_sigma : ndarray (B,)
        Length of the last step in standard deviations.
    cost : ndarray (B,)
        J(θ̂) (eq. 6) at the final estimate.
    covariance : ndarray (B, p, p)
        (HᵀΨ⁻¹H)⁻¹ at the final estimate over the free components (NaN elsewhere, and where
        singular).
    flags : ndarray of uint16 (B,)
        Bits of :data:`pipeline.vocabulary.FLAGS`.
    """

    theta: np.ndarray
    iterates: np.ndarray
    iterations: np.ndarray
    step_sigma: np.ndarray
    cost: np.ndarray
    covariance: np.ndarray
    flags: np.ndarray


def _take(batch: dict, idx) -> dict:
    return {k: v[idx] for k, v in batch.items()}


def gauss_newton(model: Callable, theta0: np.ndarray, measured: np.ndarray, sigma: np.ndarray,
                 free=None, iterations: int = 10, step_tolerance: float = 1e-6, batch: dict | None = None,
                 diverged: Callable | None = None) -> GaussNewtonResult:
    """Run Gauss-Newton for every row of ``theta0`` at once.

    Parameters
    ----------
    model : callable
        ``model(theta, **batch_rows) -> (g, H)`` with ``theta`` (b, p), ``g`` (b, m),
        ``H`` (b, m, p), evaluated on any subset of runs (``batch_rows`` are the same rows of
        ``batch``).
    theta0 : ndarray (B, p)
        Initial guesses.
    measured : ndarray (B, m)
        Measurements u.
    sigma : ndarray (B, m) or (m,)
        Standard deviation of each measurement (Ψ diagonal).
    free : sequence of int, optional
        Components to estimate (others stay at their ``theta0`` value). Default: all.
    iterations : int
        Maximum number of steps.
    step_tolerance : float
        Convergence when √(δᵀ I δ) < ``step_tolerance`` (0 runs every iteration).
    batch : dict of ndarray, optional
        Per-run model inputs with leading axis B (e.g. sensor positions).
    diverged : callable, optional
        ``diverged(theta, **batch_rows) -> bool (b,)``: extra divergence test (e.g. the
        estimate left the region of interest).

    Returns
    -------
    GaussNewtonResult
    """
    theta = np.array(theta0, dtype=float, copy=True)
    B, p = theta.shape
    measured = np.asarray(measured, float)
    sigma = np.broadcast_to(np.asarray(sigma, float), measured.shape)
    free = np.arange(p) if free is None else np.asarray(free, dtype=np.int64)
    batch = batch or {}
    flags = np.zeros(B, FLAG_DTYPE)
    start_ok = np.all(np.isfinite(theta[:, free]), axis=1)
    flags[~start_ok] |= INVALID_START
    active = start_ok.copy()
    steps = np.zeros(B, np.int64)
    step_sigma = np.full(B, np.nan)
    iterates = np.empty((B, iterations + 1, p))
    iterates[:, 0] = theta
    for n in range(iterations):
        idx = np.flatnonzero(active)
        if idx.size:
            rows = _take(batch, idx)
            th = theta[idx]
            with np.errstate(all="ignore"):
                g, H = model(th, **rows)
                A = H[:, :, free] / sigma[idx][:, :, None]
                resid = (measured[idx] - g) / sigma[idx]
            bad_model = ~(np.all(np.isfinite(A), axis=(1, 2)) & np.all(np.isfinite(resid), axis=1))
            A = np.where(bad_model[:, None, None], 0.0, A)
            resid = np.where(bad_model[:, None], 0.0, resid)
            sol = scaled_least_squares(A, resid)
            new = th.copy()
            new[:, free] += sol.x
            with np.errstate(all="ignore"):
                div = bad_model | ~np.all(np.isfinite(new), axis=1)
                if diverged is not None:
                    div |= np.asarray(diverged(np.where(np.isfinite(new), new, 0.0), **rows), bool)
            rank_bad = sol.rank_deficient & ~div
            ok = ~div & ~rank_bad
            theta[idx[ok]] = new[ok]
            steps[idx[ok]] += 1
            step_sigma[idx[ok]] = sol.projected_norm[ok]
            done = ok & (sol.projected_norm < step_tolerance)
            flags[idx[div]] |= DIVERGED
            flags[idx[rank_bad]] |= RANK_DEFICIENT
            flags[idx[done]] |= CONVERGED
            active[idx[~ok | done]] = False
        iterates[:, n + 1] = theta
    flags[active] |= NOT_CONVERGED
    cost, cov, final_rank_bad = final_statistics(model, theta, measured, sigma, free, batch)
    flags[final_rank_bad & ((flags & DIVERGED) == 0) & start_ok] |= RANK_DEFICIENT
    return GaussNewtonResult(theta, iterates, steps, step_sigma, cost, cov, flags)


def final_statistics(model, theta, measured, sigma, free, batch):
    """Cost J(θ̂) and covariance (HᵀΨ⁻¹H)⁻¹ at θ̂ over the free components.

    Returns ``cost (B,)``, ``covariance (B, p, p)`` and a rank-deficiency mask ``(B,)``.
    """
    B, p = theta.shape
    ok = np.all(np.isfinite(theta), axis=1)
    th = np.where(ok[:, None], theta, 0.0)
    with np.errstate(all="ignore"):
        g, H = model(th, **batch)
        A = H[:, :, free] / sigma[:, :, None]
        resid = (measured - g) / sigma
    ok &= np.all(np.isfinite(A), axis=(1, 2)) & np.all(np.isfinite(resid), axis=1)
    A = np.where(ok[:, None, None], A, 0.0)
    sol = scaled_least_squares(A, np.where(ok[:, None], resid, 0.0))
    cov_free = covariance_from_factor(sol.R, sol.scale, sol.rank_deficient | ~ok)
    cov = np.full((B, p, p), np.nan)
    cov[:, free[:, None], free[None, :]] = cov_free
    cost = np.where(ok, np.sum(resid * resid, axis=1), np.nan)
    return cost, cov, sol.rank_deficient | ~ok
