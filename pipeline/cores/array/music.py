"""MUSIC start-up: sample covariance, source count (MDL / AIC), spectrum and peak picking.

Start-up of Ryu, Lee & Lee (2001), section III.2 step 1 (the number of targets and their angles
from MUSIC at k = −1 and k = 0; ``docs/papers/array.md``), after Schmidt 1986 (the
paper's ref. [2]) and the information-theoretic source count of Wax & Kailath 1985.

Everything is batched over leading axes (scans × runs in one call):

* :func:`sample_covariance` ``R = X Xᴴ / Ns`` and :func:`eigen_decomposition` (ascending
  eigenvalues, as ``numpy.linalg.eigh`` returns them);
* :func:`information_criterion` and :func:`source_count`: ``MDL(k) = −Ns (M−k) log(g_k / a_k) + ½ k (2M − k) log Ns`` and
  ``AIC(k) = −2 Ns (M−k) log(g_k / a_k) + 2 k (2M − k)`` with g_k, a_k the geometric and
  arithmetic means of the M − k smallest eigenvalues; the estimate is the minimising k;
* :func:`music_spectrum` ``P(θ) = 1 / ‖E_nᴴ a(θ)‖²`` on an angle grid, evaluated as the
  trigonometric polynomial the quadratic form is for a uniform linear array, from whichever of
  the signal and noise bases is smaller: two real matrix products for all grid points (2M − 1
  coefficients from C = E Eᴴ, then a cos/sin table kept per (M, d/λ, grid));
* :func:`pick_peaks`: the N largest local maxima per spectrum, refined by a parabola through
  the three grid points around each (sub-grid accuracy; fitted to the smooth null spectrum
  1/P), returned in ascending angle order.

Speed (``benchmarks/bench_array.py``): a single block per call costs little more than its
eigen-decomposition (about 22 of some 50 µs at M = 15), so the one-block path avoids per-call
array overhead: ``np.dot`` for the 2-D products, SciPy's LAPACK wrapper for the EVD, and the
few peaks ranked and refined with Python floats (the same bits as the batched array form).
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from trackreplay.batched_linalg import over_stack


def sample_covariance(snapshots: np.ndarray) -> np.ndarray:
    """``R = X Xᴴ / Ns`` for snapshots ``(..., M, Ns)``; returns ``(..., M, M)``."""
    X = np.asarray(snapshots)
    R = np.dot(X, np.conj(X.T)) if X.ndim == 2 else np.matmul(X, np.conj(np.swapaxes(X, -1, -2)))
    if not np.issubdtype(R.dtype, np.inexact):
        return R / X.shape[-1]
    R /= X.shape[-1]
    return R


_ZHEEVD = []  # scipy's LAPACK zheevd, imported on first use


def eigen_decomposition(cov: np.ndarray):
    """Hermitian EVD, eigenvalues ascending: ``(values (..., M), vectors (..., M, M))``.

    ``numpy.linalg.eigh`` (LAPACK zheevd on the lower triangle). One complex matrix, a block
    per call, goes to the same LAPACK routine through SciPy's thinner wrapper (about 4 µs less
    of the 25 µs at M = 15; the same routine, triangle and results); a failure falls back to
    numpy, which raises as it always did. A stack of many matrices (every run of a scan) is
    shared among the available cores when the replay layer allows it
    (:func:`trackreplay.batched_linalg.over_stack`, the same bits): the EVDs are most of an array
    replay's filtering.
    """
    if isinstance(cov, np.ndarray) and cov.ndim == 2 and cov.dtype == np.complex128 and cov.shape[0] == cov.shape[1]:
        if not _ZHEEVD:
            from scipy.linalg.lapack import zheevd

            _ZHEEVD.append(zheevd)
        values, vectors, info = _ZHEEVD[0](cov, compute_v=1, lower=1)
        if info == 0:
            return values, vectors
    return over_stack(np.linalg.eigh, cov)


def information_criterion(eigenvalues: np.ndarray, n_snapshots: float, criterion: str = "mdl",
                          max_sources: int | None = None) -> np.ndarray:
    """MDL or AIC score of every source count k = 0 … kmax (Wax & Kailath 1985), batched.

    ``MDL(k) = −Ns (M−k) log(g_k / a_k) + ½ k (2M − k) log Ns`` and
    ``AIC(k) = −2 Ns (M−k) log(g_k / a_k) + 2 k (2M − k)``, with g_k and a_k the geometric and
    arithmetic means of the M − k smallest eigenvalues. :func:`source_count` takes the minimising
    k; the wideband count (:mod:`trackreplay.cores.array.wideband_count`) sums the scores of the
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
    from trackreplay.cores.array.linear_array import electrical_spacing

    lags = np.arange(1, n_sensors, dtype=float)
    phase = electrical_spacing(spacing_wavelengths) * lags[:, None] * np.sin(np.asarray(grid, float))[None, :]
    return np.concatenate([np.cos(phase), np.sin(phase)])


def _is_scalar(value) -> bool:
    """An int or a 0-d array (cheaper than ``np.ndim(value) == 0`` on the per-block path)."""
    return isinstance(value, (int, np.integer)) or getattr(value, "ndim", None) == 0


#: tables kept at the most (≈ 0.4 MB each at M = 15, G = 1801), the least recently used dropped first
_TABLES_KEPT = 32


def _cached_polynomial_table(grid: np.ndarray, n_sensors: int, spacing_wavelengths: float) -> np.ndarray:
    """``[1; cos(κ l sin θ); sin(κ l sin θ)]``, ``(2M − 1, G)``: :func:`lag_exponentials` under a
    row of ones (the constant term), kept per (M, d/λ, grid). The grid is part of the key byte by
    byte, so a changed grid never reuses a stale table (functools' cache, safe from any thread)."""
    g = np.ascontiguousarray(grid, dtype=float)
    return _polynomial_table(int(n_sensors), float(spacing_wavelengths), g.shape, g.tobytes())


@lru_cache(maxsize=_TABLES_KEPT)
def _polynomial_table(n_sensors: int, spacing_wavelengths: float, shape: tuple, grid_bytes: bytes) -> np.ndarray:
    g = np.frombuffer(grid_bytes, dtype=float).reshape(shape)
    table = np.concatenate([np.ones((1, g.shape[-1])), lag_exponentials(g, n_sensors, spacing_wavelengths)])
    table.flags.writeable = False
    return table


_LAG_SUMS: dict = {}  # (M, signal side) → real (2M², 2M − 1) map from C's real view to the coefficients


def _lag_sum_map(n_sensors: int, signal_side: bool) -> np.ndarray:
    """The trigonometric coefficients of ``‖E_nᴴ a(θ)‖²`` from ``C = E Eᴴ`` as one real product.

    With ``C.view(float)`` flattened to ``[Re C₀₀, Im C₀₀, Re C₀₁, …]`` (2M² values), the product
    with this map gives ``[tr C, 2 Re c₁ … 2 Re c_{M−1}, −2 Im c₁ … −2 Im c_{M−1}]``, where
    ``c_l = Σ_i C[i, i + l]`` (the l-th superdiagonal's sum, what ``np.trace(C, offset=l)`` is):
    the coefficients, on ``[1; cos; sin]``, of ``aᴴ(θ) C a(θ)`` for Hermitian C. For the signal
    side (C = E_s E_sᴴ, ‖E_nᴴa‖² = M − aᴴCa) the map is negated; the caller adds M to the first.
    """
    key = (int(n_sensors), bool(signal_side))
    W = _LAG_SUMS.get(key)
    if W is None:
        M = key[0]
        W = np.zeros((M, M, 2, 2 * M - 1))
        i = np.arange(M)
        W[i, i, 0, 0] = 1.0
        for lag in range(1, M):
            r = np.arange(M - lag)
            W[r, r + lag, 0, lag] = 2.0
            W[r, r + lag, 1, M - 1 + lag] = -2.0
        W = W.reshape(2 * M * M, 2 * M - 1)
        W = np.asfortranarray(-W if signal_side else W)  # column-major: one block's vector × map is faster
        W.flags.writeable = False
        _LAG_SUMS[key] = W
    return W


_BLAS_CALL_SIZE = 1 << 18  # multiply-adds per product call: OpenBLAS runs smaller GEMMs on one thread


def _rows_product(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a (R, K) @ b (K, N)`` in blocks of rows, each at most about 2¹⁸ multiply-adds.

    OpenBLAS splits larger products over threads; when another process holds a core (a shared
    machine, or the process pool of a sweep) the split call waits for a time slice and a batch
    of blocks took 2–3 times longer than one thread needs (``benchmarks/bench_array.py``). Every
    row is the same dot product either way: the result is the one-call product to rounding.
    """
    rows = a.shape[0]
    step = max(1, _BLAS_CALL_SIZE // max(1, a.shape[1] * b.shape[1]))
    if rows <= step:
        return a @ b
    out = np.empty((rows, b.shape[1]), dtype=np.result_type(a, b))
    for start in range(0, rows, step):
        np.matmul(a[start:start + step], b, out=out[start:start + step])
    return out


def _null_spectrum(basis: np.ndarray, signal_side: bool, table: np.ndarray, with_ones: bool) -> np.ndarray:
    """``‖E_nᴴ a(θ)‖²``, ``(..., G)``, from ``basis (..., M, r)`` (E_s or E_n): two real products.

    ``table`` is ``[1; cos; sin]`` when ``with_ones`` (the cached form), else the bare
    :func:`lag_exponentials` a caller passed (the constant term is then added separately).
    """
    M = basis.shape[-2]
    if basis.ndim == 2:  # one block: np.dot costs less than matmul here, and no batch to split
        C = np.dot(basis, np.conj(basis.T))
        if C.dtype != np.complex128:
            C = C.astype(complex)
        coef = C.view(float).reshape(2 * M * M) @ _lag_sum_map(M, signal_side)  # (2M − 1,)
        if signal_side:  # ‖E_nᴴa‖² = M − ‖E_sᴴa‖²
            coef[0] += M
        if with_ones:
            return coef @ table
        out = coef[1:] @ table
        out += coef[0]
        return out
    lead = basis.shape[:-2]
    C = np.matmul(basis, np.conj(np.swapaxes(basis, -1, -2)))
    if C.dtype != np.complex128 or not C.flags.c_contiguous:
        C = np.ascontiguousarray(C, dtype=complex)
    coef = _rows_product(C.view(float).reshape(-1, 2 * M * M), _lag_sum_map(M, signal_side))  # (B, 2M − 1)
    if signal_side:
        coef[:, 0] += M
    if with_ones:
        out = _rows_product(coef, table)
    else:
        out = _rows_product(coef[:, 1:], table)
        out += coef[:, :1]
    return out.reshape(lead + (table.shape[-1],))


def music_spectrum(eigenvectors: np.ndarray, n_sources, grid: np.ndarray, spacing_wavelengths: float,
                   lag_table: np.ndarray | None = None) -> np.ndarray:
    """MUSIC pseudo-spectrum ``1 / ‖E_nᴴ a(θ)‖²`` on ``grid`` (batched).

    For a uniform linear array ``aᴴ(θ) C a(θ) = Σ_l c_l exp(j κ l sin θ)`` with c_l the sum of
    the l-th diagonal of C: the quadratic form is a trigonometric polynomial of 2M − 1 terms.
    With ``C = E Eᴴ`` for the smaller of the signal and noise bases (‖E_nᴴa‖² = M − ‖E_sᴴa‖²)
    the whole spectrum is two real matrix products: C's real view times a fixed 0/±1/±2 map
    gives the 2M − 1 coefficients, and those times the table ``[1; cos; sin]`` give every grid
    point (the table is kept per (M, d/λ, grid) when ``lag_table`` is not passed). The same
    number to rounding; tests/test_array_music.py checks it against the definition.

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
    if lag_table is None:
        table, with_ones = _cached_polynomial_table(grid, M, spacing_wavelengths), True
    else:
        table, with_ones = np.asarray(lag_table, float), False
    lead = V.shape[:-2]
    if _is_scalar(n_sources):  # one signal dimension for the whole batch, leading axes kept
        k = int(n_sources)
        signal_side = k <= M // 2
        out = _null_spectrum(V[..., M - k:] if signal_side else V[..., : M - k], signal_side, table, with_ones)
    else:
        Vf = V.reshape((-1, M, M))
        nf = np.broadcast_to(np.asarray(n_sources, dtype=np.int64), lead).reshape(-1)
        out = np.empty((Vf.shape[0], table.shape[-1]))
        for k in np.unique(nf).tolist():  # one product per distinct signal dimension (usually one)
            sel = nf == k
            signal_side = k <= M // 2
            basis = Vf[sel][..., M - k:] if signal_side else Vf[sel][..., : M - k]
            out[sel] = _null_spectrum(basis, signal_side, table, with_ones)
        out = out.reshape(lead + (table.shape[-1],))
    np.maximum(out, 1e-15 * M, out=out)
    np.divide(1.0, out, out=out)
    return out


_AROUND = np.array([-1, 0, 1])


def _peaks_of_one(s: np.ndarray, grid: np.ndarray, width: int, refine: bool) -> list:
    """The ``width`` best peaks of one spectrum ``s (G,)`` as Python floats, ascending.

    A few peaks: Python floats cost less than a dozen array operations on a handful of values.
    The arithmetic is the array form's in :func:`pick_peaks` (the same IEEE operations in the
    same order, so the same bits; tests/test_array_music.py checks it).
    """
    centre = s[1:-1]
    idx = np.flatnonzero((centre > s[:-2]) & (centre >= s[2:]))
    # best first, the first of equal values first (a stable ranking, as the batched form's)
    best = sorted(zip((-s[idx + 1]).tolist(), idx.tolist()))[:width]
    best = [i + 1 for v, i in best if v > -math.inf]  # an infinite value takes its rank, not a place
    if not best:
        return []
    idx = np.array(best)
    angles = grid[idx].tolist()
    if refine:
        g0, g1 = grid[:2].tolist()
        step = g1 - g0
        for j, (pl, pm, pr) in enumerate(s[idx[:, None] + _AROUND].tolist()):
            if pl and pm and pr:
                left, mid, right = 1.0 / pl, 1.0 / pm, 1.0 / pr
            else:  # an array gives ±inf for 1/0 where a float raises
                left, mid, right = (1.0 / v if v else math.copysign(math.inf, v) for v in (pl, pm, pr))
            curv = left - 2 * mid + right
            shift = 0.5 * (left - right) / curv if curv > 0 else 0.0
            if shift - shift != 0.0:  # ±inf or NaN: no shift
                shift = 0.0
            elif shift > 0.5:
                shift = 0.5
            elif shift < -0.5:
                shift = -0.5
            angles[j] += shift * step
    if all(map(math.isfinite, angles)):
        angles.sort()
    else:
        angles = np.sort(angles).tolist()  # NaN last, as the array form sorts
    return angles


def pick_peaks(spectrum: np.ndarray, grid: np.ndarray, n_peaks, refine: bool = True) -> np.ndarray:
    """The ``n_peaks`` largest local maxima per spectrum, ascending in angle.

    A local maximum is a grid point above its left neighbour and not below its right one (the
    two ends are never peaks); only these few points are ranked, per spectrum, by value.

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
    B = flat.shape[0]
    if _is_scalar(n_peaks):
        n = None
        width = max(int(n_peaks), 0) if B else 0
    else:
        n = np.broadcast_to(np.asarray(n_peaks, dtype=np.int64), lead).reshape(-1)
        width = int(n.max()) if n.size else 0
    if width == 0:
        return np.full(lead + (0,), np.nan)
    grid = np.asarray(grid)
    if B == 1:  # one spectrum (a block per call)
        angles = _peaks_of_one(flat[0], grid, width if n is None else max(int(n[0]), 0), refine)
        return np.array(angles + [np.nan] * (width - len(angles))).reshape(lead + (width,))
    centre = flat[:, 1:-1]
    interior = (centre > flat[:, :-2]) & (centre >= flat[:, 2:])
    rows, idx = np.nonzero(interior)
    idx += 1
    value = flat[rows, idx]
    order = np.lexsort((-value, rows))  # by spectrum, then best first
    first = np.searchsorted(rows[order], rows[order])  # where each spectrum's run starts
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size) - first
    keep = (rank < (width if n is None else n[rows])) & np.isfinite(value)
    rows, idx, rank = rows[keep], idx[keep], rank[keep]
    angle = grid[idx]
    if refine:
        # the parabola goes through the null spectrum 1/P = ‖E_nᴴa‖², which is smooth and
        # locally quadratic at a source; P itself is a sharp 1/x² peak a parabola fits badly
        with np.errstate(invalid="ignore", divide="ignore"):
            left, mid, right = (1.0 / flat[rows, idx + d] for d in (-1, 0, 1))
            curv = left - 2 * mid + right
            shift = np.where(curv > 0, 0.5 * (left - right) / curv, 0.0)
        shift = np.where(np.isfinite(shift), shift, 0.0)
        angle = angle + np.clip(shift, -0.5, 0.5) * (grid[1] - grid[0])
    out = np.full((B, width), np.nan)
    out[rows, rank] = angle
    out.sort(axis=1)  # NaN last
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
    elif _is_scalar(n_sources):  # one count for every block: no per-block arrays on the way
        k = int(n_sources)
        counts = np.full(X.shape[:-2], k, dtype=np.int64)
        spec = music_spectrum(vectors, max(k, 1), grid, spacing_wavelengths, lag_table)
        return pick_peaks(spec, grid, k), counts, spec, values
    else:
        counts = np.broadcast_to(np.asarray(n_sources, dtype=np.int64), X.shape[:-2]).copy()
    spec = music_spectrum(vectors, np.maximum(counts, 1), grid, spacing_wavelengths, lag_table)
    angles = pick_peaks(spec, grid, counts)
    return angles, counts, spec, values
