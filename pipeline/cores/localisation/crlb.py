"""Cramér-Rao bound, its position/velocity subspaces, error ellipses and CEP.

Kim et al. (2013), eqs. 18–22 (see ``docs/papers/tdoa-fdoa.md``)::

    I(θ) = Hᵀ Ψ⁻¹ H,  CRLB = I⁻¹                        (18)
    projection:  I_p = (D I⁻¹ Dᵀ)⁻¹   (marginal)          (19)
    slice:       I_s = D I Dᵀ         (conditional)       (20)
    CEP ≈ ¾ √k √(λ₁ + λ₂),  k = −2 ln(1 − P_e)            (21, 22)

Functions return the subspace *covariances* (I_p⁻¹ = the 2×2 block of the CRLB, I_s⁻¹), since
ellipses and CEPs are drawn from covariances. The CRLB itself comes from the QR factor of the
whitened, column-scaled Jacobian (:func:`trackreplay.cores.localisation.batched_least_squares.information_covariance`),
not from inverting I; so does the slice, from the Jacobian's columns of the kept components.

CEP, three ways (all for a zero-mean 2-D Gaussian with covariance eigenvalues λ₁ ≥ λ₂):

* :func:`cep_paper` — eq. (21) as printed, ¾√k√(λ₁+λ₂). At P_e = 0.5 this is 0.883√(λ₁+λ₂),
  which is not the usual CEP approximation; it is kept because it is what the paper plots.
* :func:`cep_approx` — the familiar 50 % approximation 0.75√(λ₁+λ₂): between −9.9 % (circular
  case) and +11.2 % (degenerate case) of the exact value.
* :func:`cep_exact` — the radius R with P(‖e‖ ≤ R) = P_e, from a 1-D integral:
  P(λ₁Z₁² + λ₂Z₂² ≤ R²) = ∫ φ(z)·erf(√((R² − λ₁z²)/(2λ₂))) dz over |z| ≤ R/√λ₁, evaluated by
  Gauss-Legendre quadrature on a split interval that resolves the boundary layer of very
  elongated ellipses, and solved for R by safeguarded Newton iterations.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy.special import erf, ndtri

from trackreplay.cores.localisation.batched_least_squares import information_covariance


def whitened_jacobian(H: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """Ψ^{-1/2} H for a diagonal Ψ: each row divided by its σ."""
    return np.asarray(H, float) / np.asarray(sigma, float)[..., None]


def fisher_information(H: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """I = Hᵀ Ψ⁻¹ H (eq. 18) for a stack of Jacobians (..., m, q) and σ (..., m)."""
    A = whitened_jacobian(H, sigma)
    return np.einsum("...ki,...kj->...ij", A, A)


def crlb(H: np.ndarray, sigma: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """CRLB = I⁻¹ via QR of the whitened, column-scaled Jacobian.

    Returns
    -------
    cov : ndarray (..., q, q)
        NaN where I is singular.
    singular : ndarray of bool (...)
    """
    return information_covariance(whitened_jacobian(H, sigma))


def projection_covariance(cov: np.ndarray, components) -> np.ndarray:
    """(D I⁻¹ Dᵀ): the marginal covariance of ``components`` (eq. 19's I_p⁻¹)."""
    c = np.asarray(components)
    return cov[..., c[:, None], c[None, :]]


def slice_covariance(whitened: np.ndarray, components) -> np.ndarray:
    """(D I Dᵀ)⁻¹: covariance of ``components`` when the others are known (eq. 20's I_s⁻¹).

    Knowing the other components removes their columns from the whitened Jacobian
    ``A = Ψ^{-1/2} H``, and ``D I Dᵀ = A_cᵀ A_c`` for the kept columns ``A_c``, so the slice is
    the QR-based covariance of ``A_c`` (:func:`trackreplay.cores.localisation.batched_least_squares.information_covariance`):
    the information matrix is neither formed nor inverted.

    Parameters
    ----------
    whitened : ndarray (..., m, q)
        Whitened Jacobian (:func:`whitened_jacobian`).
    components : sequence of int
        Columns of the slice.

    Returns
    -------
    ndarray (..., k, k)
        NaN where ``A_c`` is rank deficient.
    """
    c = np.asarray(components)
    return information_covariance(np.asarray(whitened, float)[..., c])[0]


def eigen_2x2(cov2: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eigenvalues λ₁ ≥ λ₂ and the major axis angle (rad, from +x) of 2×2 covariances."""
    a, b, d = cov2[..., 0, 0], cov2[..., 0, 1], cov2[..., 1, 1]
    half_tr = 0.5 * (a + d)
    disc = np.sqrt(0.25 * (a - d) ** 2 + b * b)
    lam1 = half_tr + disc
    lam2 = np.maximum(half_tr - disc, 0.0)
    angle = 0.5 * np.arctan2(2 * b, a - d)
    return lam1, lam2, angle


def ellipse_scale(probability: float) -> float:
    """√k with k = −2 ln(1 − P) (eq. 22): the Mahalanobis radius holding probability P in 2-D."""
    if not 0 < probability < 1:
        raise ValueError("probability must be in (0, 1)")
    return float(np.sqrt(-2.0 * np.log1p(-probability)))


def error_ellipse(cov2: np.ndarray, probability: float = 0.5):
    """Semi-axes and orientation of the ellipse holding ``probability`` of a 2-D Gaussian.

    Returns
    -------
    semi_major, semi_minor : ndarray
        In the covariance's units (√k √λ).
    angle_rad : ndarray
        Major axis angle from +x, counter-clockwise.
    """
    lam1, lam2, angle = eigen_2x2(cov2)
    s = ellipse_scale(probability)
    return s * np.sqrt(lam1), s * np.sqrt(lam2), angle


def ellipse_points(center, cov2, probability: float = 0.5, n: int = 121) -> np.ndarray:
    """Closed polyline (n, 2) of the ``probability`` ellipse of one 2×2 covariance."""
    major, minor, angle = error_ellipse(np.asarray(cov2, float), probability)
    t = np.linspace(0, 2 * np.pi, n)
    c, s = np.cos(angle), np.sin(angle)
    x, y = major * np.cos(t), minor * np.sin(t)
    return np.asarray(center, float) + np.stack([c * x - s * y, s * x + c * y], axis=-1)


def cep_paper(cov2: np.ndarray, probability: float = 0.5) -> np.ndarray:
    """Eq. (21) as printed: ¾ √k √(λ₁ + λ₂), k = −2 ln(1 − P_e)."""
    return 0.75 * ellipse_scale(probability) * np.sqrt(np.trace(cov2, axis1=-2, axis2=-1))


def cep_approx(cov2: np.ndarray) -> np.ndarray:
    """The familiar 50 % approximation 0.75 √(λ₁ + λ₂)."""
    return 0.75 * np.sqrt(np.trace(cov2, axis1=-2, axis2=-1))


# --------------------------------------------------------------------------- exact CEP

_NODES = 24


@lru_cache(maxsize=None)
def _gauss_legendre(n: int):
    x, w = np.polynomial.legendre.leggauss(n)
    return 0.5 * (x + 1.0), 0.5 * w  # on [0, 1]


def _disc_probability_normalised(rho, kappa, derivative=False):
    """P(Z₁² + κ Z₂² ≤ ρ²) for standard normals (κ = λ₂/λ₁ ∈ [0, 1]), and d/dρ.

    With z = ρ sin t: P = 2 ∫₀^{π/2} φ(ρ sin t) erf(ρ cos t / √(2κ)) ρ cos t dt. The erf factor
    switches from 0 to 1 within cos t ≲ √(2κ)/ρ of t = π/2; the interval is split there so
    both parts are smooth for Gauss-Legendre at any κ.
    """
    rho = np.asarray(rho, float)[..., None]
    kappa = np.asarray(kappa, float)[..., None]
    x, w = _gauss_legendre(_NODES)
    sk = np.sqrt(2.0 * np.maximum(kappa, 1e-300))
    # width of the layer in t (8 layer widths: erfc(8) ≈ 1e-29), at most the whole interval
    width = np.minimum(np.arcsin(np.minimum(8.0 * sk / np.maximum(rho, 1e-300), 1.0)), np.pi / 2)
    split = np.pi / 2 - width
    t = np.concatenate([split * x, split + width * x], axis=-1)
    wt = np.concatenate([split * w, width * w], axis=-1)
    st, ct = np.sin(t), np.cos(t)
    phi = np.exp(-0.5 * (rho * st) ** 2) / np.sqrt(2 * np.pi)
    p = 2.0 * np.sum(wt * phi * erf(rho * ct / sk) * rho * ct, axis=-1)
    if not derivative:
        return p
    # d/dρ of 2 ∫₀^ρ φ(z) erf(√(ρ² − z²)/√(2κ)) dz (the boundary term vanishes: erf(0) = 0)
    dens = 2.0 * np.sum(wt * phi * (2 / np.sqrt(np.pi)) * np.exp(-((rho * ct / sk) ** 2)) * rho / sk, axis=-1)
    return p, dens


def disc_probability(radius, cov2) -> np.ndarray:
    """P(‖e‖ ≤ radius) for e ~ N(0, cov2), exact up to quadrature error (~1e-12)."""
    lam1, lam2, _ = eigen_2x2(np.asarray(cov2, float))
    rho = np.asarray(radius, float) / np.sqrt(lam1)
    return _disc_probability_normalised(rho, lam2 / lam1)


def cep_exact_direct(cov2: np.ndarray, probability: float = 0.5, rtol: float = 1e-13) -> np.ndarray:
    """Radius of the circle (centred on the mean) holding ``probability`` of N(0, cov2).

    Solved point by point: the normalised radius ρ = R/√λ₁ lies between the degenerate
    (κ = 0: Φ⁻¹((1 + P)/2)) and circular (κ = 1: √k) values, which bracket a safeguarded
    Newton iteration on the quadrature of :func:`disc_probability`. NaN where the covariance
    is not finite. :func:`cep_exact` gives the same values (to ~1e-12 relative) faster.
    """
    cov2 = np.asarray(cov2, float)
    lam1, lam2, _ = eigen_2x2(cov2)
    ok = np.isfinite(lam1) & np.isfinite(lam2) & (lam1 > 0)
    kappa = np.where(ok, np.clip(lam2 / np.where(ok, lam1, 1.0), 0.0, 1.0), 0.5)
    rho = _normalised_cep(kappa, probability, rtol)
    return _denormalise(rho, lam1, ok)


def _normalised_cep(kappa, probability, rtol):
    lo = np.full(kappa.shape, float(ndtri(0.5 * (1 + probability))))
    hi = np.full(kappa.shape, ellipse_scale(probability))
    rho = lo + (hi - lo) * np.sqrt(kappa)  # exact at both ends of the bracket
    for _ in range(60):
        p, dens = _disc_probability_normalised(rho, kappa, derivative=True)
        f = p - probability
        lo = np.where(f < 0, rho, lo)
        hi = np.where(f > 0, rho, hi)
        with np.errstate(divide="ignore", invalid="ignore"):
            newton = rho - f / dens
        inside = np.isfinite(newton) & (newton > lo) & (newton < hi)
        new = np.where(inside, newton, 0.5 * (lo + hi))
        if np.all(np.abs(new - rho) <= rtol * rho):
            return new
        rho = new
    return rho


def _denormalise(rho, lam1, ok):
    out = rho * np.sqrt(np.where(ok, lam1, np.nan))
    return np.where(ok, out, np.where(np.isfinite(lam1) & (lam1 == 0), 0.0, np.nan))


_TABLE_DEGREE = 128


@lru_cache(maxsize=16)
def _cep_table(probability: float):
    """Chebyshev interpolant of ρ(s), s = √(λ₂/λ₁) ∈ [0, 1], built from the direct solver.

    ρ is smooth in s (not analytic at κ = 0, hence s rather than κ); degree 128 reproduces the
    direct solution to ~1e-12 (tested), at the cost of one polynomial evaluation per point.
    """
    from numpy.polynomial import Chebyshev

    return Chebyshev.interpolate(lambda s: _normalised_cep(s * s, probability, 1e-14),
                                 _TABLE_DEGREE, domain=[0.0, 1.0])


def cep_exact(cov2: np.ndarray, probability: float = 0.5) -> np.ndarray:
    """Exact CEP of N(0, cov2): the radius R with P(‖e‖ ≤ R) = ``probability``.

    Vectorised over leading axes (a 201 × 201 CEP plane in milliseconds) through an
    interpolant of the direct solution :func:`cep_exact_direct` in the eccentricity
    √(λ₂/λ₁); NaN where the covariance is not finite, 0 where it is zero.
    """
    cov2 = np.asarray(cov2, float)
    lam1, lam2, _ = eigen_2x2(cov2)
    ok = np.isfinite(lam1) & np.isfinite(lam2) & (lam1 > 0)
    s = np.sqrt(np.where(ok, np.clip(lam2 / np.where(ok, lam1, 1.0), 0.0, 1.0), 0.25))
    return _denormalise(_cep_table(float(probability))(s), lam1, ok)
