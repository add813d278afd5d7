"""AR(1) parameter estimation of coloured measurement noise (Wu & Chang 1996, as in Kwon 1997).

Kwon (1997), ch. III.2, the AR parameter estimator in five steps (thesis eqs. 3.2.3, 3.2.7,
3.2.15, 3.2.17–3.2.18, 3.2.43–3.2.51); see ``docs/papers/colored.md``. The measurement noise follows
``ν_k = α ν_{k−1} + η_k`` with ``var(ν) = R`` and ``var(η) = σ_η² = (1 − α²) R``.

1. ``ū_k = z_k − 2 z_{k−1} + z_{k−2}`` removes a constant-velocity state (eq. 3.2.3; the thesis
   prints the transfer function once as ``1 − z⁻¹ + z⁻²``, a misprint for ``(1 − z⁻¹)²``).
2. ``u_k = ū_k + 2ρ u_{k−1} − ρ² u_{k−2}`` cancels the two unit-circle zeros approximately
   (``F(z) = 1/(1 − ρ z⁻¹)²``, eq. 3.2.7).
3. Fading-memory autocorrelations with forgetting factor β (eqs. 3.2.17–3.2.18) and the biased
   coefficient ``α^b = r̂₁ / r̂₀`` (eq. 3.2.15).
4. Bias correction: ``α̂`` is the smaller root of ``ξ₃ α² + (ξ₃ + ξ₂) α + (ξ₃ + ξ₂ + ξ₁) = 0``
   (eqs. 3.2.46–3.2.51; the root α = 1 of the cubic is dropped).
5. ``σ_η²`` from eq. 3.2.43 at ``α = α̂``.

Every step is a linear recursion along the scan axis, so the whole estimator is three all-pole
filters over ``(runs, scans, axes)`` arrays (:func:`all_pole_filter`, one vectorised step per
scan over every run and axis).

Guards, each flagged per run, scan and axis with bits of :data:`trackreplay.vocabulary.FLAGS`:

* ``CLAMPED``: a negative discriminant in step 4 (it happens when ``α^b`` ≳ 0.81 for ρ = 0.9,
  e.g. for a strongly coloured noise or during a transient) is clamped to zero;
* ``LIMITED``: ``|α̂|`` is limited to :data:`ALPHA_LIMIT` (the clamped root can exceed 1, which
  is not a stationary AR(1) process);
* ``FLOORED``: a non-positive ``σ_η²`` is replaced by ``VARIANCE_FLOOR · r̂₀``.

:func:`scan_flags` folds them over the axes into one mask per run and scan and adds
``NOT_WARM`` where the estimator has not settled (what a decorrelating filter reports).

Start-up (our additions; ``burn_in=0, normalised=False`` is the thesis's plain recursion):

* The zero-cancelling filter starts from rest while the noise did not, which injects a smooth
  transient ``≈ ν₀ (k+1) ρ^k`` into u. Its energy, ``≈ Σ (k+1)² ρ^{2k} R ≈ 260 R`` at ρ = 0.9
  against ``≈ R`` per sample in steady state, dominates the fading-memory sums (memory
  ``1/(1 − β)`` = 100 samples) for several hundred samples and drives ``α^b``
  towards 0.9 whatever the true α (the thesis remarks on a poor transient, Fig. 9). The products
  are therefore accumulated only from ``burn_in`` samples on, by default the first N with
  ``(N+1) ρ^N ≤ 0.01`` (87 samples for ρ = 0.9; :func:`transient_samples`).
* The thesis starts ``r̂`` at zero, which biases ``r̂₀`` and ``r̂₁`` (hence ``σ_η²``) low by
  ``1 − β^n`` while leaving their ratio alone. With ``normalised=True`` (default) both are
  divided by their weight sum ``1 − β^n`` (n = number of products so far), the exact
  fading-memory average.
* Estimates are NaN until both sums hold a product, and ``warm`` marks the scans from which
  the sums hold at least one memory length ``1/(1 − β)`` of products: the filters that use the
  estimates fall back to the plain measurement before that.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trackreplay import vocabulary as vocab
from trackreplay.errors import InputError, require_finite

FLAG_DTYPE = np.dtype(vocab.FLAG_DTYPE)

ALPHA_LIMIT = 0.99
VARIANCE_FLOOR = 1e-6


@dataclass
class Ar1Estimates:
    """Estimator outputs, each ``(runs, scans, axes)`` (NaN before the first estimate).

    Attributes
    ----------
    alpha_biased : ndarray
        ``α^b = r̂₁ / r̂₀`` (eq. 3.2.15).
    alpha : ndarray
        Bias-corrected ``α̂`` (eq. 3.2.51, second root), limited to ``±ALPHA_LIMIT``.
    noise_variance : ndarray
        ``σ_η²`` (eq. 3.2.43), floored at ``VARIANCE_FLOOR · r̂₀``.
    discriminant : ndarray
        The discriminant of eq. 3.2.51 before clamping.
    flags : ndarray of uint32
        Bit-or of ``vocab.CLAMPED`` (negative discriminant clamped), ``vocab.LIMITED`` (``|α̂|``
        limited) and ``vocab.FLOORED`` (noise variance floored).
    warm : ndarray of bool (scans,)
        Scans whose sums hold at least ``1/(1 − β)`` products.
    """

    alpha_biased: np.ndarray
    alpha: np.ndarray
    noise_variance: np.ndarray
    discriminant: np.ndarray
    flags: np.ndarray
    warm: np.ndarray


def check_design(beta: float, rho: float) -> None:
    """Raise :class:`InputError` unless ``0 < β < 1`` and ``0 ≤ ρ < 1``."""
    if not (0.0 < beta < 1.0):
        raise InputError(f"forgetting factor beta must be in (0, 1), got {beta}")
    if not (0.0 <= rho < 1.0):
        raise InputError(f"zero-cancelling pole rho must be in [0, 1), got {rho} (rho = 1 blows up on manoeuvres)")


def bias_corrected_alpha(alpha_biased, rho: float):
    """Smaller root of eq. 3.2.50 given ``α^b`` (eqs. 3.2.46–3.2.51).

    Returns
    -------
    alpha : ndarray
        The root, with a negative discriminant clamped to zero (not yet limited to ±1).
    discriminant : ndarray
        ``(ξ₃ + ξ₂)² − 4 ξ₃ (ξ₃ + ξ₂ + ξ₁)`` before clamping.
    """
    ab = np.asarray(alpha_biased, dtype=float)
    xi3 = (rho + 1.0) ** 3
    xi2 = (-2 * rho**2 - 10 * rho - 4) + (-6 * rho - 2) * ab
    xi1 = (-(rho**3) - 3 * rho**2 + 5 * rho + 7) + (8 * rho + 8) * ab
    b = xi3 + xi2
    c = xi3 + xi2 + xi1
    disc = b * b - 4.0 * xi3 * c
    return (-b - np.sqrt(np.maximum(disc, 0.0))) / (2.0 * xi3), disc


def white_noise_variance(alpha, r0, r1, rho: float):
    """``σ_η²`` of eq. 3.2.43 from ``α`` and the autocorrelations of the filtered signal u."""
    a = np.asarray(alpha, dtype=float)
    num = ((-2 * rho**3 * a**2 + (1 - rho**4) * a + 2 * rho) * r0
           + ((rho**2 + rho**4) * a**2 + (2 * rho**3 - 2 * rho) * a - (rho**2 + 1)) * r1)
    return -num / ((1 + rho**2) * a + 2 * rho - 4)


def all_pole_filter(gain: float, poles_polynomial, x: np.ndarray) -> np.ndarray:
    """``y_k = gain · x_k − a₁ y_{k−1} − … − a_n y_{k−n}`` along axis 1 of ``x``, from rest.

    The same arithmetic, operation for operation, as ``scipy.signal.lfilter([gain], a, x,
    axis=1)`` with ``a = poles_polynomial = (1, a₁, …, a_n)`` (its transposed direct form II),
    so the results are equal to the last bit (``tests/test_colored_ar.py``). The estimator's
    filters are short recursions that one vectorised step per scan computes in a few
    milliseconds; importing ``scipy.signal`` for them cost 0.35–0.67 s of every coloured-noise
    replay and sweep worker.

    Parameters
    ----------
    gain : float
        Numerator ``b₀`` (the filters here have no zeros).
    poles_polynomial : sequence of float
        Denominator ``(1, a₁, …, a_n)``, leading coefficient 1.
    x : ndarray, shape (runs, scans, ...)

    Returns
    -------
    ndarray, the shape of ``x``
    """
    a = [float(v) for v in poles_polynomial]
    if a[0] != 1.0:
        raise ValueError("the denominator's leading coefficient must be 1")
    x = np.asarray(x, dtype=float)
    order = len(a) - 1
    scans_first = np.moveaxis(x, 1, 0)
    y = np.empty_like(scans_first)
    state = [np.zeros(scans_first.shape[1:]) for _ in range(order)]  # the form's delay line
    for k in range(scans_first.shape[0]):
        y_k = state[0] + gain * scans_first[k] if order else gain * scans_first[k]
        for i in range(order - 1):
            state[i] = state[i + 1] - y_k * a[i + 1]
        if order:
            state[order - 1] = -(y_k * a[order])
        y[k] = y_k
    return np.moveaxis(y, 0, 1)


def filtered_second_difference(z: np.ndarray, rho: float) -> np.ndarray:
    """Steps 1–2: ``u`` from measurements ``z`` ``(runs, scans, axes)`` (zero for scans 0–1)."""
    ubar = np.zeros_like(z, dtype=float)
    ubar[:, 2:] = z[:, 2:] - 2.0 * z[:, 1:-1] + z[:, :-2]
    return all_pole_filter(1.0, (1.0, -2.0 * rho, rho * rho), ubar)


def transient_samples(rho: float, level: float = 0.01) -> int:
    """Smallest N with ``(N + 1) ρ^N ≤ level``: how long the zero-cancelling filter rings."""
    n = 0
    while (n + 1) * rho**n > level:
        n += 1
    return n


def estimate_ar1(z, beta: float = 0.99, rho: float = 0.9, normalised: bool = True,
                 burn_in: int | None = None, path=None) -> Ar1Estimates:
    """Run the AR(1) estimator over every run and axis at once.

    Parameters
    ----------
    z : array_like, shape (runs, scans, axes)
        Position measurements per axis (any target; manoeuvres leak in through ρ < 1).
    beta : float
        Forgetting factor, 0 < β < 1 (thesis: 0.99).
    rho : float
        Pole of the zero-cancelling filter, 0 ≤ ρ < 1 (thesis: 0.9).
    normalised : bool
        Divide the fading-memory sums by their weight sum (see module docstring).
    burn_in : int, optional
        First scan whose products enter the sums (default :func:`transient_samples`; 0 or 2
        gives the thesis's start).
    path : str, optional
        File the measurements came from, for error messages.

    Returns
    -------
    Ar1Estimates
    """
    check_design(beta, rho)
    z = np.asarray(z, dtype=float)
    if z.ndim != 3:
        raise InputError(f"measurements must be (runs, scans, axes), got shape {z.shape}", path)
    require_finite("measurements", z, path)
    runs, scans, axes = z.shape
    first = max(2, transient_samples(rho) if burn_in is None else int(burn_in))
    u = filtered_second_difference(z, rho)
    prod0 = u * u
    prod1 = np.zeros_like(u)
    prod1[:, 1:] = u[:, 1:] * u[:, :-1]
    prod0[:, :first] = 0.0
    prod1[:, :first + 1] = 0.0
    r0 = all_pole_filter(1.0 - beta, (1.0, -beta), prod0)
    r1 = all_pole_filter(1.0 - beta, (1.0, -beta), prod1)
    k = np.arange(scans, dtype=float)
    valid = k >= first + 1
    if normalised:
        with np.errstate(divide="ignore", invalid="ignore"):
            r0 = r0 / (1.0 - beta ** np.maximum(k - first + 1.0, 0.0))[None, :, None]
            r1 = r1 / (1.0 - beta ** np.maximum(k - first, 0.0))[None, :, None]
    nan = np.full_like(u, np.nan)
    r0 = np.where(valid[None, :, None], r0, nan)
    r1 = np.where(valid[None, :, None], r1, nan)
    with np.errstate(divide="ignore", invalid="ignore"):
        alpha_b = r1 / r0
    alpha_raw, disc = bias_corrected_alpha(alpha_b, rho)
    flags = np.zeros(u.shape, dtype=FLAG_DTYPE)
    flags |= np.where(disc < 0, vocab.CLAMPED, 0).astype(FLAG_DTYPE)
    limited = np.abs(alpha_raw) > ALPHA_LIMIT
    flags |= np.where(limited, vocab.LIMITED, 0).astype(FLAG_DTYPE)
    alpha = np.clip(alpha_raw, -ALPHA_LIMIT, ALPHA_LIMIT)
    var = white_noise_variance(alpha, r0, r1, rho)
    floored = var <= 0
    flags |= np.where(floored, vocab.FLOORED, 0).astype(FLAG_DTYPE)
    var = np.where(floored, VARIANCE_FLOOR * r0, var)
    warm = k >= first + np.ceil(1.0 / (1.0 - beta))
    return Ar1Estimates(alpha_b, alpha, var, disc, flags, warm)


def scan_flags(est: Ar1Estimates) -> np.ndarray:
    """One flag mask per run and scan for a filter that uses the estimates.

    The estimator's bits of every axis (bit-or over the axes) and ``NOT_WARM`` on the scans
    before :attr:`Ar1Estimates.warm`, where the decorrelating filters fall back to the plain
    measurement.

    Parameters
    ----------
    est : Ar1Estimates

    Returns
    -------
    ndarray of uint16, shape (runs, scans)
    """
    per_scan = np.bitwise_or.reduce(est.flags, axis=-1).astype(FLAG_DTYPE)
    return per_scan | np.where(est.warm, 0, vocab.NOT_WARM).astype(FLAG_DTYPE)[None, :]
