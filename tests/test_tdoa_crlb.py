"""CRLB, projection vs slice, error ellipses, exact and approximate CEP, CEP planes."""

import numpy as np
import pytest
from hypothesis import assume, given, settings, strategies as st
from scipy.special import ndtri

from trackreplay.cores.localisation.cep_plane import cep_plane, grid_axis
from trackreplay.cores.localisation.crlb import (cep_approx, cep_exact, cep_exact_direct, cep_paper, crlb, disc_probability,
                           eigen_2x2, error_ellipse, fisher_information, projection_covariance,
                           slice_covariance, whitened_jacobian)
from trackreplay.cores.localisation.tdoa_fdoa_model import all_pairs, measurement_model
from trackreplay.recorders.scenarios import load_scenario
from trackreplay.recorders.tdoa_fdoa import resolve


def preset(**overrides):
    return resolve(load_scenario("tdoa-fdoa").with_overrides({k: str(v) for k, v in overrides.items()}).params)


@st.composite
def fisher_cases(draw):
    """H, σ and FIM for a random geometry of 3–5 sensors (all pairs), emitter ≥ 2 km away."""
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    m = draw(st.integers(3, 5))
    pos = rng.uniform(-8000, 8000, (m, 2))
    vel = rng.uniform(-300, 300, (m, 2))
    while True:
        p = rng.uniform(-40_000, 40_000, 2)
        if np.min(np.linalg.norm(pos - p, axis=1)) > 2000:
            break
    theta = np.concatenate([p, rng.uniform(-300, 300, 2)])
    pairs = all_pairs(m)
    _, H = measurement_model(theta, pos, vel, pairs, 1e9)
    sigma = np.concatenate([np.full(len(pairs), 10 ** rng.uniform(-9, -7)), np.full(len(pairs), 10 ** rng.uniform(0, 1.5))])
    return H, sigma


@settings(max_examples=100, deadline=None)
@given(fisher_cases())
def test_slice_is_below_projection_in_loewner_order_and_projection_is_the_schur_complement(case):
    H, sigma = case
    cov, singular = crlb(H, sigma)
    assume(not singular)
    fim = fisher_information(H, sigma)
    for comps, others in (([0, 1], [2, 3]), ([2, 3], [0, 1])):
        proj = projection_covariance(cov, comps)
        sl = slice_covariance(whitened_jacobian(H, sigma), comps)
        # projection − slice is positive semi-definite (eigenvalues ≥ −rounding)
        gap = np.linalg.eigvalsh(proj - sl)
        assert gap.min() >= -1e-9 * np.abs(np.linalg.eigvalsh(proj)).max()
        # eq. 19: (D I⁻¹ Dᵀ)⁻¹ = I_cc − I_co I_oo⁻¹ I_oc (independent route via the FIM)
        c, o = np.ix_(comps, comps), np.ix_(others, others)
        schur = fim[c] - fim[np.ix_(comps, others)] @ np.linalg.solve(fim[o], fim[np.ix_(others, comps)])
        # both routes lose ~cond(I)·ε of relative accuracy on near-singular random geometries
        rtol = max(1e-9, 1e-14 * np.linalg.cond(fim))
        np.testing.assert_allclose(np.linalg.inv(proj), schur, rtol=rtol, atol=1e-9 * np.abs(schur).max())
        # eq. 20: the slice (from the Jacobian's kept columns, by QR) is the inverse of the FIM block
        np.testing.assert_allclose(np.linalg.inv(sl), fim[c], rtol=rtol, atol=1e-9 * np.abs(fim[c]).max())


def test_crlb_equals_the_inverse_fisher_information_for_the_paper_geometries():
    for geometry in ("line", "triangle"):
        for emitter in (1, 2, 3):
            es = preset(geometry=geometry, emitter=emitter)
            _, H = measurement_model(es.emitter[0], es.sensor_pos[0], es.sensor_vel[0], es.pairs, es.carrier_hz)
            cov, singular = crlb(H, es.sigma[0])
            assert not singular
            ref = np.linalg.inv(fisher_information(H, es.sigma[0]))
            sd = np.sqrt(np.diag(ref))
            # compared in correlation units (entries that vanish by symmetry are ~1e-16 there)
            assert np.max(np.abs(cov - ref) / np.outer(sd, sd)) < 1e-7


def test_collinear_emitter_has_no_crlb():
    es = preset(geometry="line", emitter_position_m="12000,0")
    _, H = measurement_model(es.emitter[0], es.sensor_pos[0], es.sensor_vel[0], es.pairs, es.carrier_hz)
    cov, singular = crlb(H, es.sigma[0])
    assert singular and np.isnan(cov).all()


# --------------------------------------------------------------------------- CEP


def test_exact_cep_closed_forms():
    sigma = 3.0
    np.testing.assert_allclose(cep_exact(np.eye(2) * sigma**2), sigma * np.sqrt(2 * np.log(2)), rtol=1e-11)
    np.testing.assert_allclose(cep_exact(np.diag([sigma**2, 0.0])), sigma * ndtri(0.75), rtol=1e-11)
    for p in (0.3, 0.9, 0.99):  # circular: R = σ √(−2 ln(1 − P))
        np.testing.assert_allclose(cep_exact(np.eye(2) * sigma**2, p), sigma * np.sqrt(-2 * np.log1p(-p)), rtol=1e-11)
        np.testing.assert_allclose(cep_exact(np.diag([0.0, sigma**2]), p), sigma * ndtri(0.5 + p / 2), rtol=1e-11)


@settings(max_examples=60, deadline=None)
@given(st.floats(-12, 0), st.floats(0, np.pi), st.floats(-3, 6), st.sampled_from([0.5, 0.75, 0.95]))
def test_exact_cep_holds_its_probability_and_matches_the_direct_solver(log_kappa, angle, log_scale, p):
    lam1 = 10.0 ** log_scale
    lam2 = lam1 * 10.0 ** log_kappa
    c, s = np.cos(angle), np.sin(angle)
    rot = np.array([[c, -s], [s, c]])
    cov = rot @ np.diag([lam1, lam2]) @ rot.T
    r = cep_exact(cov, p)
    np.testing.assert_allclose(r, cep_exact_direct(cov, p), rtol=1e-10)
    np.testing.assert_allclose(disc_probability(r, cov), p, atol=1e-11)


def test_exact_cep_agrees_with_monte_carlo():
    rng = np.random.default_rng(5)
    n = 400_000
    for cov in (np.array([[4.0, 1.5], [1.5, 1.0]]), np.diag([100.0, 0.01]), np.eye(2)):
        e = rng.multivariate_normal([0, 0], cov, n)
        frac = np.mean(np.hypot(e[:, 0], e[:, 1]) <= cep_exact(cov))
        assert abs(frac - 0.5) < 4 * np.sqrt(0.25 / n)


@settings(max_examples=200, deadline=None)
@given(st.floats(0, 1), st.floats(-4, 6))
def test_approximations_agree_with_exact_cep_within_their_known_error(kappa, log_scale):
    cov = np.diag([10.0**log_scale, kappa * 10.0**log_scale])
    ratio = cep_approx(cov) / cep_exact(cov)
    # 0.75 √(λ1 + λ2): exact at neither end; −9.9 % for a circle, +11.2 % for a line
    low, high = 0.75 * np.sqrt(2) / np.sqrt(2 * np.log(2)), 0.75 / ndtri(0.75)
    assert low - 1e-12 <= ratio <= high + 1e-12
    # the paper's eq. 21 is √k (k = 2 ln 2 at P = 0.5) times the same approximation
    np.testing.assert_allclose(cep_paper(cov) / cep_approx(cov), np.sqrt(2 * np.log(2)), rtol=1e-14)


def test_error_ellipse_axes_angle_and_coverage():
    cov = np.array([[9.0, 4.0], [4.0, 5.0]])
    major, minor, angle = error_ellipse(cov, 0.5)
    lam, vec = np.linalg.eigh(cov)
    k = np.sqrt(2 * np.log(2))
    np.testing.assert_allclose([major, minor], k * np.sqrt(lam[::-1]), rtol=1e-12)
    assert abs(abs(np.cos(angle) * vec[0, 1] + np.sin(angle) * vec[1, 1]) - 1) < 1e-12
    e = np.random.default_rng(2).multivariate_normal([0, 0], cov, 200_000)
    d2 = np.einsum("bi,ij,bj->b", e, np.linalg.inv(cov), e)
    assert abs(np.mean(d2 <= k * k) - 0.5) < 0.005
    l1, l2, _ = eigen_2x2(cov)
    np.testing.assert_allclose([l1, l2], lam[::-1], rtol=1e-12)


# --------------------------------------------------------------------------- CEP planes


def paper_plane(geometry, method="exact"):
    es = preset(geometry=geometry)
    axis = grid_axis(50_000, 500)
    plane = cep_plane(es.sensor_pos[0], es.sensor_vel[0], es.pairs, es.emitter[0, 2:], es.carrier_hz, es.sigma[0],
                      axis, axis, method=method)
    return es, plane


def test_line_geometry_cep_plane_is_mirror_symmetric_and_blank_on_the_sensor_axis():
    _, plane = paper_plane("line")
    assert plane.position_m.shape == (201, 201)
    for z in (plane.position_m, plane.velocity_mps):
        ok = np.isfinite(z)
        np.testing.assert_allclose(z[ok], z[:, ::-1][ok], rtol=1e-9)  # x → −x
        np.testing.assert_allclose(z[ok], z[::-1][ok], rtol=1e-9)  # y → −y
    # y = 0 is collinear with the sensors: no CRLB there, and nowhere else
    assert plane.singular[100].all() and not plane.singular[np.arange(201) != 100].any()


@pytest.mark.parametrize("geometry", ["line", "triangle"])
def test_cep_plane_matches_a_pointwise_computation(geometry):
    es, plane = paper_plane(geometry)
    rng = np.random.default_rng(0)
    for iy, ix in rng.integers(0, 201, (25, 2)):
        if plane.singular[iy, ix]:
            continue
        theta = np.array([plane.x_m[ix], plane.y_m[iy], *es.emitter[0, 2:]])
        _, H = measurement_model(theta, es.sensor_pos[0], es.sensor_vel[0], es.pairs, es.carrier_hz)
        cov = np.linalg.inv(fisher_information(H, es.sigma[0]))
        np.testing.assert_allclose(plane.position_m[iy, ix], cep_exact_direct(cov[:2, :2]), rtol=1e-6)
        np.testing.assert_allclose(plane.velocity_mps[iy, ix], cep_exact_direct(cov[2:, 2:]), rtol=1e-6)


def test_paper_cep_plane_is_the_approximation_scaled():
    _, exact = paper_plane("triangle")
    _, paper = paper_plane("triangle", "paper")
    ok = np.isfinite(exact.position_m)
    ratio = paper.position_m[ok] / exact.position_m[ok]
    assert ratio.min() >= np.sqrt(2 * np.log(2)) * 0.9008 and ratio.max() <= np.sqrt(2 * np.log(2)) * 1.1120
