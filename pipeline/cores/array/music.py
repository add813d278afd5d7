"""MUSIC start-up: sample covariance, source count (MDL / AIC), spectrum and peak picking.

Start-up of Ryu, Lee & Lee (2001), section III.2 step 1 (the number of targets and their angles
from MUSIC at k = −1 and k = 0; ``docs/papers/array-bearing.md``), after Schmidt 1986 (the
paper's ref. [2]) and the information-theoretic source count of Wax & Kailath 1985.

Everything is batched over leading axes (scans × runs in one call):

* :func:`sample_covariance` ``R = X Xᴴ / Ns`` and :func:`eigen_decomposition` (ascending
  eigenvalues, as ``numpy.linalg.eigh`` returns them);
* :func:`information_criterion` and :func:`source_count`: ``MDL(k) = −Ns (M−k) log(g_k / a_k) + ½ k (2M − k) log Ns`` and
  ``AIC(k) = −2 Ns (M−k) log(g_k / a_k) + 2 k (2M − k)`` with g_k, a_k the geometric and
  arithmetic means of the M − k smallest eigenvalues; the estimate is the minimising k;
* :func:`music_spectrum` ``P(θ) = 1 / ‖E_nᴴ a(θ)‖²`` on an angle grid, evaluated as the
  trigonometric polynomial the quadratic form is for a uniform linear array (M − 1 products per
  grid point), from whichever of the signal and noise bases is smaller;
* :func:`pick_peaks`: the N largest local maxima per spectrum, refined by a parabola through
  the three grid points around each (sub-grid accuracy; fitted to the smooth null spectrum
  1/P), returned in ascending angle order.
"""

from __future__ import annotations

import numpy as np



def sample_covariance(snapshots: np.ndarray) -> np.ndarray:
    """``R = X Xᴴ / Ns`` for snapshots ``(..., M, Ns)``; returns ``(..., M, M)``."""
    X = np.asarray(snapshots)
    return np.einsum("...ms,...ns->...mn", X, np.conj(X)) / X.shape[-1]


def eigen_decomposition(cov: np.ndarray):
    """Hermitian EVD, eigenvalues ascending: ``(values (..., M), vectors (..., M, M))``."""
    return np.linalg.eigh(cov)


def information_criterion(eigenvalues: np.ndarray, n_snapshots: float, criterion: str = "mdl",
                          max_sources: int | None = None) -> np.ndarray:
    """MDL or AIC score of every source count k = 0 … kmax (Wax & Kailath 1985), batched.

    ``MDL(k) = −Ns (M−k) log(g_k / a_k) + ½ k (2M − k) log Ns`` and
    ``AIC(k) = −2 Ns (M−k) log(g_k / a_k) + 2 k (2M − k)``, with g_k and a_k the geometric and
    arithmetic means of the M − k smallest eigenvalues. :func:`source_count` takes the minimising
    k; the wideband count (:mod:`pipeline.cores.array.wideband_count`) sums the scores of the
    bins of a band first.

    Parameters
    ----------
    eigenvalues : ndarray, shape (..., M)
        Sample-covariance eigenvalues in ascending order.
    n_snapshots : float
        Ns, the snapshots behind the covariance (an effective, non-integer number is accepted).
    criterion : {"mdl", "aic"}
    max_sources : int, optional
        Largest count considered (default M − 1; never more than Ns − 1).

    Returns
    -------
    ndarray, shape (..., kmax + 1)
    """
    lam = np.maximum(np.asarray(eigenvalues, float), np.finfo(float).tiny)
    M = lam.shape[-1]
    kmax = M - 1 if max_sources is None else min(int(max_sources), M - 1)
    kmax = max(0, min(kmax, int(n_snapshots) - 1))
    k = np.arange(kmax + 1)
    p = M - k  # noise eigenvalues per hypothesis: the p smallest
    csum = np.cumsum(lam, axis=-1)
    clog = np.cumsum(np.log(lam), axis=-1)
    arith = csum[..., p - 1] / p
    log_geo = clog[..., p - 1] / p
    log_ratio = log_geo - np.log(arith)  # ≤ 0
    if criterion == "mdl":
        return -n_snapshots * p * log_ratio + 0.5 * k * (2 * M - k) * np.log(n_snapshots)
    if criterion == "aic":
        return -2.0 * n_snapshots * p * log_ratio + 2.0 * k * (2 * M - k)
    raise ValueError(f"unknown source-count criterion {criterion!r} (mdl or aic)")


def source_count(eigenvalues: np.ndarray, n_snapshots: int, criterion: str = "mdl",
                 max_sources: int | None = None) -> np.ndarray:
    """Number of sources by MDL or AIC (Wax & Kailath 1985), batched: the k minimising
    :func:`information_criterion`.

    Parameters
    ----------
    eigenvalues : ndarray, shape (..., M)
        Sample-covariance eigenvalues in ascending order.
    n_snapshots : int
        Ns, the snapshots behind the covariance.
    criterion : {"mdl", "aic"}
    max_sources : int, optional
        Largest count considered (default M − 1; never more than Ns − 1).

    Returns
    -------
    ndarray of int, shape (...)
    """
    return np.argmin(information_criterion(eigenvalues, n_snapshots, criterion, max_sources), axis=-1)


def angle_grid(step_rad: float, limit_rad: float = np.pi / 2) -> np.ndarray:
    """Uniform grid over ``[−limit, limit]`` with the given step (both ends included)."""
    n = int(round(2 * limit_rad / step_rad)) + 1
    return np.linspace(-limit_rad, limit_rad, n)


def lag_exponentials(grid: np.ndarray, n_sensors: int, spacing_wavelengths: float) -> np.ndarray:
    """``[cos(κ l sin θ); sin(κ l sin θ)]`` for lags l = 1 … M − 1 on the grid, ``(2(M − 1), G)``.

    The real and imaginary parts of exp(j κ l sin θ), stacked so that the real part of
    Σ_l c_l exp(j κ l sin θ) is one real matrix product with ``[Re c, −Im c]``.
    """
    from pipeline.cores.array.linear_array import electrical_spacing

    lags = np.arange(1, n_sensors, dtype=float)
    phase = electrical_spacing(spacing_wavelengths) * lags[:, None] * np.sin(np.asarray(grid, float))[None, :]
    return np.concatenate([np.cos(phase), np.sin(phase)])


def music_spectrum(eigenvectors: np.ndarray, n_sources, grid: np.ndarray, spacing_wavelengths: float,
                   lag_table: np.ndarray | None = None) -> np.ndarray:
    """MUSIC pseudo-spectrum ``1 / ‖E_nᴴ a(θ)‖²`` on ``grid`` (batched).

    For a uniform linear array ``aᴴ(θ) C a(θ) = Σ_l c_l exp(j κ l sin θ)`` with c_l the sum of
    the l-th diagonal of C: the quadratic form is a trigonometric polynomial of 2M − 1 terms.
    With ``C = E Eᴴ`` for the smaller of the signal and noise bases (‖E_nᴴa‖² = M − ‖E_sᴴa‖²)
    the whole spectrum costs M − 1 complex products per grid point instead of M·N (the same
    number to rounding; tests/test_array_music.py checks it against the definition).

    Parameters
    ----------
    eigenvectors : ndarray, complex, shape (..., M, M)
        Eigenvectors in ascending eigenvalue order.
    n_sources : int or ndarray of int, shape (...)
        Signal-subspace dimension per batch element.
    grid : ndarray, shape (G,)
        Angles (rad).
    spacing_wavelengths : float
    lag_table : ndarray, shape (2(M − 1), G), optional
        Precomputed :func:`lag_exponentials` (reuse across calls).

    Returns
    -------
    ndarray, shape (..., G)
    """
    V = np.asarray(eigenvectors)
    M = V.shape[-1]
    E = lag_exponentials(grid, M, spacing_wavelengths) if lag_table is None else lag_table
    n = np.broadcast_to(np.asarray(n_sources, dtype=np.int64), V.shape[:-2])
    lead = V.shape[:-2]
    Vf = V.reshape((-1, M, M))
    nf = n.reshape(-1)
    out = np.empty((Vf.shape[0], E.shape[-1]))
    for k in np.unique(nf):  # one product per distinct signal dimension (usually one)
        sel = nf == k
        signal_side = k <= M // 2
        basis = Vf[sel][..., M - k:] if signal_side else Vf[sel][..., : M - k]
        C = basis @ np.conj(np.swapaxes(basis, -1, -2))
        c = np.stack([np.trace(C, offset=l, axis1=-2, axis2=-1) for l in range(1, M)], axis=-1)  # (B, M − 1)
        quad = np.trace(C, axis1=-2, axis2=-1).real[:, None] + 2.0 * (np.concatenate([c.real, -c.imag], axis=-1) @ E)
        denom = M - quad if signal_side else quad
        out[sel] = 1.0 / np.maximum(denom, 1e-15 * M)
    return out.reshape(lead + (E.shape[-1],))


def pick_peaks(spectrum: np.ndarray, grid: np.ndarray, n_peaks, refine: bool = True) -> np.ndarray:
    """The ``n_peaks`` largest local maxima per spectrum, ascending in angle.

    Parameters
    ----------
    spectrum : ndarray, shape (..., G)
    grid : ndarray, shape (G,)
        Uniform angle grid (rad).
    n_peaks : int or ndarray of int, shape (...)
        Peaks wanted per spectrum (≤ its max over the batch sets the output width).
    refine : bool
        Parabolic interpolation of the null spectrum 1/P through the three grid points around
        each peak (exact for a locally quadratic null).

    Returns
    -------
    ndarray, shape (..., max n_peaks)
        Peak angles (rad); NaN where a spectrum has fewer peaks than asked (or asked fewer).
    """
    S = np.asarray(spectrum, float)
    lead = S.shape[:-1]
    flat = S.reshape(-1, S.shape[-1])
    n = np.broadcast_to(np.asarray(n_peaks, dtype=np.int64), lead).reshape(-1)
    width = int(n.max()) if n.size else 0
    out = np.full((flat.shape[0], width), np.nan)
    if width == 0:
        return out.reshape(lead + (0,))
    interior = (flat[:, 1:-1] > flat[:, :-2]) & (flat[:, 1:-1] >= flat[:, 2:])
    score = np.where(interior, flat[:, 1:-1], -np.inf)
    if width < score.shape[1]:
        top = np.argpartition(-score, width - 1, axis=1)[:, :width]  # the best `width`, unordered
    else:
        top = np.broadcast_to(np.arange(score.shape[1]), score.shape)
    value = np.take_along_axis(score, top, axis=1)
    best_first = np.argsort(-value, axis=1)  # order the few kept peaks, so the first n are the n best
    top, value = np.take_along_axis(top, best_first, axis=1), np.take_along_axis(value, best_first, axis=1)
    idx = top + 1
    angle = grid[idx]
    if refine:
        # the parabola goes through the null spectrum 1/P = ‖E_nᴴa‖², which is smooth and
        # locally quadratic at a source; P itself is a sharp 1/x² peak a parabola fits badly
        rows = np.arange(flat.shape[0])[:, None]
        with np.errstate(invalid="ignore", divide="ignore"):
            left, mid, right = (1.0 / flat[rows, idx + d] for d in (-1, 0, 1))
            curv = left - 2 * mid + right
            shift = np.where(curv > 0, 0.5 * (left - right) / curv, 0.0)
        shift = np.where(np.isfinite(shift), shift, 0.0)
        angle = angle + np.clip(shift, -0.5, 0.5) * (grid[1] - grid[0])
    keep = np.isfinite(value) & (np.arange(width)[None, :] < n[:, None])
    angle = np.where(keep, angle, np.nan)
    out = np.sort(angle, axis=1)  # NaN last
    return out.reshape(lead + (width,))


def music(snapshots: np.ndarray, spacing_wavelengths: float, grid: np.ndarray, n_sources=None,
          criterion: str = "mdl", max_sources: int | None = None, lag_table: np.ndarray | None = None):
    """Source count, spectrum and peak angles for snapshot blocks ``(..., M, Ns)``.

    Parameters
    ----------
    n_sources : int or ndarray, optional
        Known count(s); estimated with ``criterion`` when None.

    Returns
    -------
    angles : ndarray, shape (..., max count)
        Peak angles ascending (NaN padded).
    counts : ndarray of int, shape (...)
    spectrum : ndarray, shape (..., G)
    eigenvalues : ndarray, shape (..., M)
    """
    X = np.asarray(snapshots)
    values, vectors = eigen_decomposition(sample_covariance(X))
    if n_sources is None:
        counts = source_count(values, X.shape[-1], criterion, max_sources)
    else:
        counts = np.broadcast_to(np.asarray(n_sources, dtype=np.int64), X.shape[:-2]).copy()
    spec = music_spectrum(vectors, np.maximum(counts, 1), grid, spacing_wavelengths, lag_table)
    angles = pick_peaks(spec, grid, counts)
    return angles, counts, spec, values
