"""Gauss-Newton for weighted nonlinear least squares, every Monte Carlo run in one pass.

Kim et al. (2013), eqs. 6, 8 and 15–17 (see ``docs/papers/tdoa-fdoa.md``)::

    J(θ) = (u − g(θ))ᵀ Ψ⁻¹ (u − g(θ))                         (6)
    δ = (Hᵀ Ψ⁻¹ H)⁻¹ Hᵀ Ψ⁻¹ (u − g(θ̂_n)),  θ̂_{n+1} = θ̂_n + δ     (16, 17)

δ is computed as the whitened, column-scaled least-squares solution
min ‖Ψ^{-1/2}(H δ − (u − g))‖ by Householder QR (:mod:`trackreplay.cores.localisation.batched_least_squares`),
never by inverting HᵀΨ⁻¹H. The stopping rule is unit-free: a run has converged when its last
step was shorter than ``step_tolerance`` standard deviations, i.e. √(δᵀ I(θ̂) δ) < tol with
I = HᵀΨ⁻¹H (the same quantity as ‖Q₁ᵀ r‖ from the QR).

Runs are never averaged blindly: each ends with flags (the bits ``CONVERGED``,
``NOT_CONVERGED``, ``DIVERGED``, ``RANK_DEFICIENT`` and ``INVALID_START`` of the one flag table,
:data:`trackreplay.vocabulary.FLAGS`, as uint16) and keeps its last finite iterate. The loop runs
over iterations only; each iteration handles every still-active run in one vectorised call of
the model.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from trackreplay.cores.localisation.batched_least_squares import (RANK_RTOL, ZERO_COLUMN_RTOL, _covariance_rows, _factor,
                                                               _step)
# the status bits are those of the one flag table (uint16), re-exported for the callers of this core
from trackreplay.vocabulary import CONVERGED, DIVERGED, FLAG_DTYPE, INVALID_START, NOT_CONVERGED, RANK_DEFICIENT

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
        Bits of :data:`trackreplay.vocabulary.FLAGS`.
    """

    theta: np.ndarray
    iterates: np.ndarray
    iterations: np.ndarray
    step_sigma: np.ndarray
    cost: np.ndarray
    covariance: np.ndarray
    flags: np.ndarray


# the reductions of the loop, called as ufunc methods: the ndarray methods (.all(), .min())
# add a Python wrapper each, which a single run pays at every iteration
_all = np.logical_and.reduce


def _take(batch: dict, idx) -> dict:
    return {k: v[idx] for k, v in batch.items()}


def _whitened_system(model, theta, measured_t, sigma_t, free, rows):
    """[A | r] = [Ψ^{-1/2} H | Ψ^{-1/2} (u − g)] at ``theta``, stack axis last, and which runs
    are finite (None: all; the others are zeroed).

    Built straight into one (m, q + 1, b) array, the form
    :func:`trackreplay.cores.localisation.batched_least_squares.solve_augmented` factors, so that
    no separate right-hand side is copied or transformed. ``measured_t`` is (m, b), ``sigma_t``
    (m, b) or (m, 1); ``free`` is None when every component is free.
    """
    g, H = model(theta, **rows)
    b, m = g.shape
    q = H.shape[-1] if free is None else len(free)
    M = np.empty((m, q + 1, b))
    np.divide((H if free is None else H[:, :, free]).transpose(1, 2, 0), sigma_t[:, None, :], out=M[:, :q])
    r = M[:, q]
    np.subtract(measured_t, g.T, out=r)
    r /= sigma_t
    if _all(np.isfinite(M), axis=None):  # the usual case, tested once over the whole stack
        return M, None
    finite = np.isfinite(M).all(axis=(0, 1))
    M[:, :, ~finite] = 0.0
    return M, finite


def _prepare(theta, measured, sigma, free):
    """Shared argument handling: ``free`` as an index array or None (every component),
    measurements as (m, B) and σ as (m, B) or (m, 1) (views where possible)."""
    p = theta.shape[1]
    if free is not None:
        free = np.asarray(free, dtype=np.int64)
        if free.tolist() == list(range(p)):
            free = None
    measured = np.asarray(measured, float)
    sigma = np.asarray(sigma, float)
    if sigma.ndim == 1:  # one σ per measurement for every run: broadcast along the runs
        sigma_t = sigma[:, None]
    else:
        sigma = np.broadcast_to(sigma, measured.shape)
        sigma_t = sigma.T
    return free, measured, sigma, measured.T, sigma_t


def gauss_newton(model: Callable, theta0: np.ndarray, measured: np.ndarray, sigma: np.ndarray,
                 free=None, iterations: int = 10, step_tolerance: float = 1e-6, batch: dict | None = None,
                 diverged: Callable | None = None) -> GaussNewtonResult:
    """Run Gauss-Newton for every row of ``theta0`` at once.

    Each iteration costs a few dozen array calls whatever the number of runs, so that one run
    (recorded data usually is one) is not dominated by fixed per-call costs: the active runs'
    inputs are gathered again only when some run stops, the whitened system is built in place
    as one augmented array with the run axis last and solved by one stacked LAPACK QR and a
    back-substitution over the stack
    (:func:`trackreplay.cores.localisation.batched_least_squares.solve_augmented`), and the flags
    are touched only in iterations where some run stops. A run's answer does not depend on
    the other runs of the batch, to the last bit.

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
    theta = np.array(theta0, dtype=float)
    B, p = theta.shape
    free, measured, sigma, measured_t, sigma_t = _prepare(theta, measured, sigma, free)
    batch = batch or {}
    flags = np.zeros(B, FLAG_DTYPE)
    start_ok = _all(np.isfinite(theta if free is None else theta[:, free]), axis=1)
    active = start_ok.copy()
    steps = np.zeros(B, np.int64)
    step_sigma = np.empty(B)
    step_sigma.fill(np.nan)
    iterates = np.empty((B, iterations + 1, p))
    iterates[:, 0] = theta
    every = bool(_all(start_ok))
    if not every:
        flags[~start_ok] |= INVALID_START
    # the active runs' rows: a plain slice (views, no copies) while every run is active, and
    # gathered by index only after some run has stopped
    idx = slice(None) if every else np.flatnonzero(active)
    regather = not every
    rows, meas_a, sig_a = batch, measured_t, sigma_t
    pending, last_norm = 0, None  # steps taken by every active run, not yet written
    finished = False  # every run stopped in the same iteration
    with np.errstate(all="ignore"):
        for n in range(iterations):
            if regather:
                if idx.size == 0:
                    iterates[:, n + 1:] = theta[:, None, :]
                    break
                rows, meas_a = _take(batch, idx), measured[idx].T
                sig_a = sigma_t if sigma.ndim == 1 else sigma[idx].T
                regather = False
            th = theta[idx]
            M, finite = _whitened_system(model, th, meas_a, sig_a, free, rows)
            Rt, scale, bad, bad_any, _ = _factor(M, ZERO_COLUMN_RTOL, RANK_RTOL)
            x, norm = _step(Rt, scale, bad, bad_any)
            if free is None:
                new = th + x.T
            else:
                new = th.copy()
                new[:, free] += x.T
            div = None
            if diverged is not None:
                div = np.asarray(diverged(np.where(np.isfinite(new), new, 0.0), **rows), bool)
            if (finite is None and not bad_any and (div is None or not np.logical_or.reduce(div))
                    and _all(np.isfinite(new), axis=None)):
                # the usual iteration, tested with scalars: every active run takes its step
                theta[idx] = new
                pending += 1
                last_norm = norm
                done = norm < step_tolerance
                if np.logical_or.reduce(done):  # some have converged: write their record
                    steps[idx] += pending
                    step_sigma[idx] = norm
                    pending = 0
                    if _all(done):  # all of them (always so for one run): stop here
                        flags[idx] |= CONVERGED
                        active[idx] = False
                        iterates[:, n + 1:] = theta[:, None, :]
                        finished = True
                        break
                    at = np.arange(B)[idx][done]
                    flags[at] |= CONVERGED
                    active[at] = False
                    idx = np.flatnonzero(active)
                    regather = True
            else:
                if pending:
                    steps[idx] += pending
                    step_sigma[idx] = last_norm
                    pending = 0
                bad_step = ~_all(np.isfinite(new), axis=1)
                if finite is not None:
                    bad_step |= ~finite
                div = bad_step if div is None else bad_step | div
                ok = ~(div | bad)
                done = ok & (norm < step_tolerance)
                at = np.arange(B)[idx]
                theta[at[ok]] = new[ok]
                steps[at[ok]] += 1
                step_sigma[at[ok]] = norm[ok]
                flags[at[div]] |= DIVERGED
                flags[at[bad & ~div]] |= RANK_DEFICIENT
                flags[at[done]] |= CONVERGED
                active[at[~ok | done]] = False
                idx = np.flatnonzero(active)
                regather = True
            iterates[:, n + 1] = theta
        if pending:
            steps[idx] += pending
            step_sigma[idx] = last_norm
        cost, cov, final_rank_bad = _final_statistics(model, theta, measured_t, sigma_t, free, batch)
    if not finished:
        if isinstance(idx, slice):  # no run ever stopped
            flags |= NOT_CONVERGED
        else:
            flags[active] |= NOT_CONVERGED
    if np.logical_or.reduce(final_rank_bad):
        flags[final_rank_bad & ((flags & DIVERGED) == 0) & start_ok] |= RANK_DEFICIENT
    return GaussNewtonResult(theta, iterates, steps, step_sigma, cost, cov, flags)


def final_statistics(model, theta, measured, sigma, free, batch):
    """Cost J(θ̂) and covariance (HᵀΨ⁻¹H)⁻¹ at θ̂ over the free components.

    Returns ``cost (B,)``, ``covariance (B, p, p)`` and a rank-deficiency mask ``(B,)``.
    """
    free, _, _, measured_t, sigma_t = _prepare(theta, measured, sigma, free)
    with np.errstate(all="ignore"):
        return _final_statistics(model, theta, measured_t, sigma_t, free, batch)


def _final_statistics(model, theta, measured_t, sigma_t, free, batch):
    """:func:`final_statistics` on prepared arguments (under ``np.errstate(all="ignore")``)."""
    B, p = theta.shape
    finite_theta = np.isfinite(theta)
    every = bool(_all(finite_theta, axis=None))
    ok = None if every else _all(finite_theta, axis=1)
    th = theta if every else np.where(ok[:, None], theta, 0.0)
    M, finite = _whitened_system(model, th, measured_t, sigma_t, free, batch)
    Rt, scale, bad, bad_any, cost = _factor(M, ZERO_COLUMN_RTOL, RANK_RTOL)
    if not (every and finite is None):
        ok = finite if every else (ok if finite is None else ok & finite)
        bad = bad | ~ok
        bad_any = True
        cost[~ok] = np.nan
    cov_free = _covariance_rows(Rt, scale, bad, bad_any)
    if free is None:
        return cost, cov_free, bad
    cov = np.full((B, p, p), np.nan)
    cov[:, free[:, None], free[None, :]] = cov_free
    return cost, cov, bad
