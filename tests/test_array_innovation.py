"""Angular innovation (proposed closed form vs Ryu's least squares) and the FLOP accounting."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from trackreplay.cores.array.angular_innovation import (
    INNOVATIONS,
    counted_flops,
    noise_projector,
    proposed_innovation,
    ryu_innovation,
)
from trackreplay.cores.array.flop_counts import (
    FlopTally,
    gaussian_elimination_flops,
    proposed_flops,
    ryu_flops,
)
from trackreplay.cores.array.linear_array import steering_derivatives, steering_vectors


def random_subspace(rng, shape, M, N):
    return rng.standard_normal(shape + (M, N)) + 1j * rng.standard_normal(shape + (M, N))


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), M=st.integers(3, 24), data=st.data())
def test_proposed_equals_ryu_on_random_subspaces(seed, M, data):
    """Eliminating Ryu's 2N coefficients leaves the proposed problem: same δθ to rounding."""
    N = data.draw(st.integers(1, M - 1))
    rng = np.random.default_rng(seed)
    W = random_subspace(rng, (8,), M, N)
    theta = rng.uniform(-1.3, 1.3, (8, N))
    spacing = data.draw(st.sampled_from([0.25, 0.4, 0.5]))
    a = proposed_innovation(W, theta, spacing)
    b = ryu_innovation(W, theta, spacing)
    assert np.max(np.abs(a - b)) <= 1e-9


def test_equal_on_subspaces_near_the_truth_with_large_innovations():
    """Subspaces that hold the targets (plus perturbation), predictions several degrees off."""
    rng = np.random.default_rng(7)
    M, N = 15, 5
    truth = np.deg2rad(np.array([-40.0, -12.0, 3.0, 20.0, 50.0]))
    W = steering_vectors(np.broadcast_to(truth, (200, N)), M, 0.5) + 0.2 * random_subspace(rng, (200,), M, N)
    theta = truth + np.deg2rad(rng.uniform(-4, 4, (200, N)))
    a, b = proposed_innovation(W, theta, 0.5), ryu_innovation(W, theta, 0.5)
    assert np.max(np.abs(a)) > np.deg2rad(2)  # innovations of several degrees, not just tiny ones
    assert np.max(np.abs(a - b)) <= 1e-9


def test_innovation_is_first_order_accurate():
    """On the true subspace the error after one update is quadratic in the prediction error.

    Asymptotically (ε → 0) halving ε divides the error by 4; for larger errors a cubic term
    adds to it (κ M ε is no longer small: at 2° the phase error across the array is ~1.6 rad),
    yet one update still removes > 95 % of a prediction error up to 0.5° and > 50 % at 2°.
    """
    M = 15
    truth = np.deg2rad(np.array([-35.0, -8.0, 14.0, 42.0]))
    W = steering_vectors(truth, M, 0.5)
    direction = np.array([1.0, -0.7, 0.4, -1.0])

    def errors(eps):
        out = []
        for e in eps:
            pred = truth + e * direction
            out.append([np.abs(pred + fn(W, pred, 0.5) - truth) for fn in INNOVATIONS.values()])
        return np.array(out)  # (eps, strategy, N)

    eps = 2e-5 * 2.0 ** -np.arange(5)  # rad
    err = errors(eps)
    assert np.allclose(err[:, 0], err[:, 1], rtol=1e-5, atol=1e-15)
    ratio = err[:-1, 0] / err[1:, 0]
    assert np.all((ratio > 3.8) & (ratio < 4.2)), ratio
    slope = np.polyfit(np.log(eps), np.log(err[:, 0]), 1)[0]
    assert np.all(np.abs(slope - 2.0) < 0.05), slope
    wide = np.deg2rad(np.array([2.0, 1.0, 0.5, 0.25, 0.125, 0.0625]))
    err_wide = errors(wide)[:, 0]
    pred_err = wide[:, None] * np.abs(direction)
    assert np.all(err_wide[2:] < 0.05 * pred_err[2:]) and np.all(err_wide < 0.5 * pred_err)


def test_noise_projector_is_the_orthogonal_projector():
    rng = np.random.default_rng(1)
    W = random_subspace(rng, (5,), 12, 4)
    P = noise_projector(W)
    assert np.allclose(P @ P, P, atol=1e-12)
    assert np.allclose(P, np.conj(np.swapaxes(P, -1, -2)), atol=1e-12)
    assert np.allclose(P @ W, 0, atol=1e-12)
    assert np.allclose(np.trace(P, axis1=-2, axis2=-1).real, 12 - 4)


def test_derivative_of_the_steering_vector():
    theta = np.array([-0.6, 0.1, 0.9])
    h = 1e-6
    a = steering_vectors(theta, 10, 0.5)
    numeric = (steering_vectors(theta + h, 10, 0.5) - steering_vectors(theta - h, 10, 0.5)) / (2 * h)
    assert np.allclose(steering_derivatives(theta, a, 0.5), numeric, atol=1e-8)


def test_bad_shapes_and_too_many_targets():
    rng = np.random.default_rng(0)
    W = random_subspace(rng, (), 6, 6)
    for fn in INNOVATIONS.values():
        with pytest.raises(ValueError, match="N ≤ M − 1"):
            fn(W, np.zeros(6), 0.5)
        with pytest.raises(ValueError, match="do not match"):
            fn(W[:, :3], np.zeros(4), 0.5)


# --------------------------------------------------------------------------- FLOPs


def test_flop_formulas_reproduce_the_spec_numbers():
    assert proposed_flops(15, 5) == 35_600 and ryu_flops(15, 5) == 89_210
    assert proposed_flops(15, 6) == 45_216 and ryu_flops(15, 6) == 152_724
    assert round(proposed_flops(15, 5) / ryu_flops(15, 5), 3) == 0.399
    assert round(proposed_flops(15, 6) / ryu_flops(15, 6), 3) == 0.296


def test_flop_formulas_grow_as_n_cubed_and_n_to_the_fourth():
    n = np.arange(1, 40)
    for M in (8, 15, 32):
        prop = np.array([proposed_flops(M, k) for k in n], dtype=float)
        ryu = np.array([ryu_flops(M, k) for k in n], dtype=float)
        # exact polynomial degree: the k-th finite difference is constant, the (k+1)-th zero
        d3, d4 = np.diff(prop, 3), np.diff(prop, 4)
        assert np.all(d4 == 0) and np.all(d3 == d3[0]) and d3[0] == 6 * 16  # 16 N³ → 3!·16
        e4, e5 = np.diff(ryu, 4), np.diff(ryu, 5)
        assert np.all(e5 == 0) and np.all(e4 == e4[0]) and e4[0] == 24 * 16  # 2·(2N)³·N → 4!·16
        # so the ratio falls without bound, like 1/N
        assert np.all(np.diff(prop / ryu) < 0)


def test_tally_counts_a_matmul_and_a_solve_by_hand():
    t = FlopTally()
    a = np.ones((4, 3), complex)
    b = np.ones((3, 2), complex)
    t.matmul(a, b, (4, 2))
    assert t.total == 4 * 2 * (3 * 6 + 2 * 2)
    t = FlopTally()
    t.matmul(np.ones((5, 7)), np.ones((7, 1)), (5, 1))
    assert t.total == 5 * (7 + 6)
    # 2 × 2 real system, one right-hand side: 1 division + 1 mult + 1 sub (factor),
    # 1 mult-sub forward, 1 mult-sub backward, 2 divisions
    assert gaussian_elimination_flops(2, 1, False) == 3 + 2 + 2 + 2
    t = FlopTally()
    t.batch((10,))
    t.matmul(np.ones((10, 4, 3)), np.ones((10, 3, 2)), (10, 4, 2))
    assert t.total == 4 * 2 * (3 + 2)  # per batch element


def test_the_counts_remembered_per_shape_are_the_counted_ones():
    """_counted_flops_memo (what a replay's flop table asks for, again and again) is counted_flops,
    a dict of its own each time."""
    from trackreplay.cores.array.angular_innovation import _counted_flops_memo

    for strategy in INNOVATIONS:
        for M, N, d in ((15, 5, 0.5), (15, 6, 0.5), (8, 3, 0.4), (40, 12, 0.5)):
            first = _counted_flops_memo(strategy, M, N, d)
            assert first == counted_flops(strategy, M, N, d)
            first["steering"] = -1  # the caller's own copy
            assert _counted_flops_memo(strategy, np.int64(M), N, d) == counted_flops(strategy, M, N, d)


def test_counted_flops_follow_the_kernels_and_the_model_shape():
    """Counted FLOPs depend on shapes only; proposed's per-target cost is 16M²+… like the model,
    and Ryu's counted cost grows like N⁴ while the proposed one grows like N³."""
    M = 15
    for N in (3, 5):
        c = counted_flops("proposed", M, N)
        # per-target step: P⊥·[b̂ â] (M × M × 2N complex) and two real 2M-dot products per target
        per_target = M * 2 * N * (M * 6 + (M - 1) * 2) + N * 2 * (2 * M + M + (M - 1)) + N
        assert c["per_target"] == per_target
        assert c == counted_flops("proposed", M, N)  # deterministic
    # counted FLOPs are exact polynomials in N too: degree 3 (proposed) and 4 (Ryu)
    n = range(1, 14)
    prop = np.array([sum(counted_flops("proposed", 40, k).values()) for k in n], float)
    ryu = np.array([sum(counted_flops("ryu", 40, k).values()) for k in n], float)
    d3, d4 = np.diff(prop, 3), np.diff(prop, 4)
    assert np.all(d4 == 0) and d3[0] > 0
    e4, e5 = np.diff(ryu, 4), np.diff(ryu, 5)
    assert np.all(e5 == 0) and e4[0] > 0
    assert np.all(np.diff(prop / ryu) < 0)  # the proposed form wins more the more targets


def test_model_says_the_closed_form_only_pays_off_from_three_targets_at_m15():
    """Forming the M × M projector costs O(M²N): for N ≤ 2 (M = 15) Ryu's model is cheaper."""
    ratio = [proposed_flops(15, n) / ryu_flops(15, n) for n in range(1, 11)]
    assert [r < 1 for r in ratio] == [False, False] + [True] * 8
    assert all(np.diff(ratio) < 0)
