"""TDOA/FDOA measurement model: Jacobian against central differences, structure, pair rank."""

import itertools

import numpy as np
from hypothesis import given, settings, strategies as st

from trackreplay.cores.localisation.tdoa_fdoa_model import (SPEED_OF_LIGHT_MPS, all_pairs, independent_differences,
                                      independent_equations, measurement_model)


@st.composite
def geometries(draw):
    """Random sensors, a random pair list (often without a common reference) and an emitter
    at least 1 km from every sensor."""
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    m = draw(st.integers(2, 6))
    pos = rng.uniform(-10_000, 10_000, (m, 2))
    vel = rng.uniform(-300, 300, (m, 2))
    pairs = all_pairs(m)
    keep = rng.random(len(pairs)) < 0.7
    keep[rng.integers(len(pairs))] = True
    pairs = pairs[keep]
    pairs = np.where(rng.random((len(pairs), 1)) < 0.5, pairs, pairs[:, ::-1])  # either order
    while True:
        p = rng.uniform(-50_000, 50_000, 2)
        if np.min(np.linalg.norm(pos - p, axis=1)) > 1000:
            break
    theta = np.concatenate([p, rng.uniform(-300, 300, 2)])
    f0 = 10 ** rng.uniform(8, 10)
    return theta, pos, vel, pairs, f0


def central_differences(theta, pos, vel, pairs, f0):
    """∂g/∂θ by central differences with Richardson extrapolation (error O(h⁴))."""
    r_min = np.min(np.linalg.norm(pos - theta[:2], axis=1))
    steps = np.array([1e-3 * r_min, 1e-3 * r_min, 1.0, 1.0])
    cols = []
    for j in range(4):
        def d(h):
            e = np.zeros(4)
            e[j] = h
            return (measurement_model(theta + e, pos, vel, pairs, f0, jacobian=False)
                    - measurement_model(theta - e, pos, vel, pairs, f0, jacobian=False)) / (2 * h)
        cols.append((4 * d(steps[j] / 2) - d(steps[j])) / 3)
    return np.stack(cols, axis=-1)


@settings(max_examples=150, deadline=None)
@given(geometries())
def test_every_jacobian_entry_matches_central_differences(geom):
    theta, pos, vel, pairs, f0 = geom
    _, H = measurement_model(theta, pos, vel, pairs, f0)
    fd = central_differences(theta, pos, vel, pairs, f0)
    # entries are compared relative to themselves; entries that (nearly) cancel by geometry
    # are compared relative to the largest entry of their row and column block
    row_scale = np.maximum(np.abs(H[:, :2]).max(axis=1, keepdims=True), np.abs(H[:, 2:]).max(axis=1, keepdims=True))
    ref = np.maximum(np.abs(H), 1e-4 * row_scale)
    assert np.all(np.abs(H - fd) <= 1e-6 * ref), np.max(np.abs(H - fd) / ref)


def test_fdoa_velocity_block_is_carrier_times_tdoa_position_block_and_tdoa_ignores_velocity():
    rng = np.random.default_rng(3)
    pos, vel = rng.uniform(-5e3, 5e3, (4, 2)), rng.uniform(-300, 300, (4, 2))
    theta = np.array([2e3, 2e4, 150.0, -40.0])
    pairs = all_pairs(4)
    _, H = measurement_model(theta, pos, vel, pairs, 2.4e9)
    n = len(pairs)
    np.testing.assert_allclose(H[n:, 2:], 2.4e9 * H[:n, :2], rtol=1e-15)  # eq. 14
    assert np.all(H[:n, 2:] == 0.0)  # eq. 11


def test_paper_printed_tdoa_derivative_has_the_opposite_sign():
    # eq. (10) as printed: ∂τ/∂x = (1/c)[(x_i − x)/R_i − (x_j − x)/R_j]
    pos = np.array([[-3000.0, 0.0], [3000.0, 0.0]])
    theta = np.array([-5000.0, 15000.0, 200.0, 0.0])
    _, H = measurement_model(theta, pos, np.zeros((2, 2)), np.array([[0, 1]]), 1e9)
    R = np.linalg.norm(theta[:2] - pos, axis=1)
    printed = ((pos[0] - theta[:2]) / R[0] - (pos[1] - theta[:2]) / R[1]) / SPEED_OF_LIGHT_MPS
    np.testing.assert_allclose(H[0, :2], -printed, rtol=1e-12)


def test_three_sensor_measurements_satisfy_the_two_closure_relations():
    """τ_ac = τ_ab + τ_bc and f_ac = f_ab + f_bc: six measurements, four independent."""
    rng = np.random.default_rng(8)
    theta = np.array([[-5000.0, 15000.0, 200.0, 0.0]]) + rng.normal(0, 100, (20, 4))
    pos = np.array([[-3000.0, 0.0], [0.0, 5120.0], [3000.0, 0.0]])
    vel = np.full((3, 2), [300.0, 0.0])
    g, H = measurement_model(theta, pos, vel, np.array([[0, 1], [1, 2], [0, 2]]), 1e9)
    np.testing.assert_allclose(g[:, 2], g[:, 0] + g[:, 1], rtol=1e-9)
    np.testing.assert_allclose(g[:, 5], g[:, 3] + g[:, 4], rtol=1e-9)
    assert all(np.linalg.matrix_rank(h / np.abs(h).max(axis=1, keepdims=True)) == 4 for h in H)


@settings(max_examples=100, deadline=None)
@given(st.integers(2, 7), st.data())
def test_independent_differences_equal_the_rank_of_the_pair_incidence_matrix(m, data):
    candidates = list(itertools.combinations(range(m), 2))
    chosen = data.draw(st.lists(st.sampled_from(candidates), min_size=1, unique=True))
    incidence = np.zeros((len(chosen), m))
    for k, (i, j) in enumerate(chosen):
        incidence[k, i], incidence[k, j] = 1, -1
    assert independent_differences(np.array(chosen), m) == np.linalg.matrix_rank(incidence)


def test_pair_lists_without_a_common_reference():
    # a chain 0-1, 1-2, 2-3 (no sensor in every pair) gives three independent differences
    assert independent_differences(np.array([[0, 1], [1, 2], [2, 3]]), 4) == 3
    # two separate pairs give two, and joint TDOA/FDOA four equations
    assert independent_equations("joint", np.array([[0, 1], [2, 3]]), 4) == 4
    assert independent_equations("fdoa", np.array([[0, 1], [1, 2], [0, 2]]), 3) == 2


def test_model_broadcasts_over_leading_axes_identically():
    rng = np.random.default_rng(1)
    pos, vel = rng.uniform(-5e3, 5e3, (3, 2)), rng.uniform(-300, 300, (3, 2))
    theta = rng.uniform(-3e4, 3e4, (5, 7, 4))
    g, H = measurement_model(theta, pos, vel, all_pairs(3), 1e9)
    g1, H1 = measurement_model(theta[2, 3], pos, vel, all_pairs(3), 1e9)
    assert np.array_equal(g[2, 3], g1) and np.array_equal(H[2, 3], H1)
