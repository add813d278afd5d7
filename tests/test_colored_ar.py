"""AR(1) parameter estimator (Wu & Chang 1996 in Kwon 1997) and the decorrelation process."""

from __future__ import annotations

import numpy as np
import pytest

from trackreplay import vocabulary as vocab
from trackreplay.cores.filters.ar1_estimation import (all_pole_filter, bias_corrected_alpha, estimate_ar1, scan_flags, transient_samples,
                                                   white_noise_variance)
from trackreplay.cores.filters.decorrelation import decorrelated_measurement_matrix, inverse_transition_rows, pseudo_measurements
from trackreplay.errors import InputError
from trackreplay.recorders.colored_noise import simulate
from trackreplay.recorders.scenarios import load_scenario

ALPHAS = (0.8, 0.4, 0.0, -0.4, -0.8)


@pytest.mark.parametrize("gain, poles", [(1.0, (1.0,)), (0.01, (1.0, -0.99)), (1.0, (1.0, -1.8, 0.81)),
                                         (0.3, (1.0, 0.5, -0.2, 0.1))])
def test_all_pole_filter_is_lfilter_to_the_bit(gain, poles):
    """The estimator's recursions equal scipy's direct form bit for bit, zeros and long runs
    included (the estimator's inputs start with exact zeros before the burn-in)."""
    from scipy.signal import lfilter

    rng = np.random.default_rng(3)
    x = rng.normal(size=(7, 1500, 2)) * rng.choice([0.0, 1e-3, 1.0, 1e6], size=(7, 1500, 2))
    x[:, :90] = 0.0
    np.testing.assert_array_equal(all_pole_filter(gain, poles, x), lfilter([gain], list(poles), x, axis=1))


@pytest.fixture(scope="module")
def ar_study():
    """The thesis's estimator experiment: non-manoeuvring target, 50 runs per α, ρ = 0.9, β = 0.99."""
    sc = load_scenario("colored-ar")
    data = simulate(sc.params, 50 * len(ALPHAS), seed=11)
    z = data.fixed[vocab.CHANNELS["colored_measurements"]]["position_m"]
    alpha_true = data.fixed[vocab.CHANNELS["colored_truth"]]["alpha"][:, 0, 0]
    est = estimate_ar1(z, beta=0.99, rho=0.9)
    return est, alpha_true, sc.params["measurement_variance_m2"]


@pytest.mark.parametrize("alpha", ALPHAS)
def test_bias_corrected_alpha_and_noise_variance_reach_the_truth(ar_study, alpha):
    est, alpha_true, R = ar_study
    runs = alpha_true == alpha
    late = slice(600, None)          # well past the start-up, as the thesis's Fig. 8 reads
    a_hat = np.nanmean(est.alpha[runs, late])
    var_hat = np.nanmean(est.noise_variance[runs, late])
    assert abs(a_hat - alpha) <= 0.05, (alpha, a_hat)
    assert abs(var_hat / ((1 - alpha**2) * R) - 1) <= 0.10, (alpha, var_hat)


def test_biased_alpha_is_biased_for_strongly_coloured_noise(ar_study):
    est, alpha_true, _ = ar_study
    runs = alpha_true == 0.8
    a_b = np.nanmean(est.alpha_biased[runs, 600:])
    assert abs(a_b - 0.8) > 0.05, a_b
    assert abs(np.nanmean(est.alpha[runs, 600:]) - 0.8) < abs(a_b - 0.8)


def test_cubic_has_root_one_and_the_kept_root_is_consistent():
    """ξ₃ + ξ₂ + ξ₁ + ξ₀ = 0 and the kept root of the quadratic solves the cubic (eq. 3.2.44)."""
    rho = 0.9
    for ab in np.linspace(-0.95, 0.75, 12):
        a, disc = bias_corrected_alpha(ab, rho)
        assert disc >= 0
        xi3 = (rho + 1) ** 3
        xi2 = (-2 * rho**2 - 10 * rho - 4) + (-6 * rho - 2) * ab
        xi1 = (-(rho**3) - 3 * rho**2 + 5 * rho + 7) + (8 * rho + 8) * ab
        xi0 = (2 * rho**2 + 2 * rho - 4) + (-2 * rho - 6) * ab
        assert abs(xi3 + xi2 + xi1 + xi0) < 1e-12
        assert abs(xi3 * a**3 + xi2 * a**2 + xi1 * a + xi0) < 1e-9


def test_bias_relation_matches_the_theoretical_autocorrelation_of_u():
    """Independent computation: the lag-0/1 autocorrelation of u = F(z)(1 − z⁻¹)²/(1 − αz⁻¹) η
    from its impulse response gives α^b; the bias correction must return α and eq. 3.2.43 σ_η²."""
    rho = 0.9
    n = np.arange(4000)
    for alpha in (0.8, 0.3, -0.5):
        eta = np.zeros(n.size)
        eta[0] = 1.0
        from scipy.signal import lfilter

        h = lfilter([1.0, -2.0, 1.0], np.polymul([1.0, -alpha], np.polymul([1.0, -rho], [1.0, -rho])), eta)
        r0, r1 = np.dot(h, h), np.dot(h[1:], h[:-1])
        a_hat, _ = bias_corrected_alpha(r1 / r0, rho)
        assert abs(a_hat - alpha) < 1e-9
        assert abs(white_noise_variance(a_hat, r0, r1, rho) - 1.0) < 1e-9


def test_negative_discriminant_is_clamped_and_flagged():
    rho = 0.9
    a, disc = bias_corrected_alpha(np.array([0.95]), rho)
    assert disc[0] < 0 and np.isfinite(a[0])
    # a noise whose α^b exceeds ≈ 0.81 at ρ = 0.9 (a random walk) trips the guard in the estimator
    rng = np.random.default_rng(0)
    z = np.cumsum(np.cumsum(rng.standard_normal((3, 800, 1)), axis=1), axis=1)
    est = estimate_ar1(z, 0.99, 0.9)
    assert est.flags.dtype == np.dtype(vocab.FLAG_DTYPE)
    assert not np.any(est.flags & ~np.uint16(vocab.CLAMPED | vocab.LIMITED | vocab.FLOORED))
    flagged = (est.flags & vocab.CLAMPED) > 0
    assert flagged.any()
    assert np.all(est.discriminant[flagged] < 0)
    assert np.all(np.isfinite(est.alpha[flagged]))
    assert np.all(np.abs(est.alpha[np.isfinite(est.alpha)]) <= 0.99)
    assert np.all((est.flags[np.abs(est.alpha) >= 0.99] & vocab.LIMITED) > 0)


def test_scan_flags_fold_the_axes_and_mark_the_cold_scans():
    """A filter's flags: any axis's estimator bits, and NOT_WARM exactly before ``warm``."""
    rng = np.random.default_rng(5)
    z = np.cumsum(np.cumsum(rng.standard_normal((2, 400, 2)), axis=1), axis=1)
    z[..., 1] = 10 * rng.standard_normal((2, 400))       # axis 1: white noise, rarely flagged
    est = estimate_ar1(z, 0.99, 0.9)
    f = scan_flags(est)
    assert f.dtype == np.dtype(vocab.FLAG_DTYPE) and f.shape == (2, 400)
    np.testing.assert_array_equal((f & vocab.NOT_WARM) > 0, np.broadcast_to(~est.warm, f.shape))
    for bit in (vocab.CLAMPED, vocab.LIMITED, vocab.FLOORED):
        np.testing.assert_array_equal((f & bit) > 0, np.any((est.flags & bit) > 0, axis=-1))


def test_start_up_burn_in_removes_the_zero_cancelling_transient():
    """Without the burn-in (the thesis's start), α^b sits near 0.9 for white noise early on."""
    rng = np.random.default_rng(2)
    z = 10 * rng.standard_normal((200, 400, 1))
    plain = estimate_ar1(z, 0.99, 0.9, normalised=False, burn_in=0)
    ours = estimate_ar1(z, 0.99, 0.9)
    assert transient_samples(0.9) == 87
    assert np.nanmedian(plain.alpha[:, 150]) > 0.3
    assert abs(np.nanmedian(ours.alpha[:, 150])) < 0.1
    assert not ours.warm[186] and ours.warm[187]


@pytest.mark.parametrize("beta,rho", [(1.0, 0.9), (0.0, 0.9), (0.99, 1.0), (0.99, -0.1)])
def test_bad_estimator_design_is_a_clear_error(beta, rho):
    with pytest.raises(InputError):
        estimate_ar1(np.zeros((1, 10, 1)), beta, rho)


def test_nan_measurements_are_a_clear_error():
    z = np.zeros((2, 10, 1))
    z[1, 4, 0] = np.nan
    with pytest.raises(InputError, match="NaN"):
        estimate_ar1(z)


def test_decorrelation_removes_the_colour_with_the_true_alpha():
    """y_k = z_k − α z_{k−1} has white noise of variance (1 − α²)R when the target is static."""
    rng = np.random.default_rng(4)
    alpha, R = 0.8187, 100.0
    from trackreplay.recorders.colored_noise import ar1_noise

    nu = ar1_noise(np.full((20, 3000, 1), alpha), R, rng.standard_normal((20, 3000, 1)), rng.standard_normal((20, 1)))
    y = pseudo_measurements(nu, np.full_like(nu, alpha))[:, 1:, 0]
    lag1 = np.mean(y[:, 1:] * y[:, :-1]) / np.mean(y * y)
    assert abs(lag1) < 0.02
    assert abs(np.var(y) / ((1 - alpha**2) * R) - 1) < 0.03
    raw = nu[..., 0]
    assert np.mean(raw[:, 1:] * raw[:, :-1]) / np.mean(raw * raw) > 0.75


def test_decorrelated_measurement_matrix_and_singular_phi():
    T = 0.05
    F = np.array([[1.0, T], [0.0, 1.0]])
    H = np.array([[1.0, 0.0]])
    HPi = inverse_transition_rows(H, F)
    np.testing.assert_allclose(HPi, [[1.0, -T]])
    Hh = decorrelated_measurement_matrix(H, HPi, np.array([[0.5]]))
    np.testing.assert_allclose(Hh, [[[0.5, 0.5 * T]]])
    with pytest.raises(InputError, match="singular"):
        inverse_transition_rows(H, np.array([[1.0, T], [0.0, 0.0]]))
