"""The rule that turns a data set's measurement noise into the evaluation's matching gate and
cut-off (pipeline/stages/evaluation_gates.py, docs/evaluation.md "Evaluation design values")."""

from __future__ import annotations

import math

import numpy as np
import pytest

from trackreplay.stages.evaluation_gates import GATE_MISS_PROBABILITY, gate_sigmas, gates_from_spread, round_up
from trackreplay.stages.radar import GATE_SIGMAS


def _outside_ball(radius_sigmas: float, dims: int, n: int = 400_000) -> float:
    """Monte Carlo share of a standard Gaussian in ``dims`` dimensions outside the ball."""
    x = np.random.default_rng(7).standard_normal((n, dims))
    return float(np.mean(np.sum(x * x, axis=1) > radius_sigmas ** 2))


@pytest.mark.parametrize("dims", [1, 2, 3])
def test_the_gate_holds_all_but_its_miss_probability(dims):
    r = gate_sigmas(dims)
    assert math.isclose(_outside_ball(r, dims), GATE_MISS_PROBABILITY, abs_tol=4e-5)  # ±2.5 σ of 400 000 draws


def test_the_closed_forms_and_the_radar_stages_constant():
    assert math.isclose(gate_sigmas(1), math.sqrt(2.0) * 2.7510639057120607, rel_tol=1e-12)  # √2 erfc⁻¹(10⁻⁴)
    assert gate_sigmas(2) == GATE_SIGMAS == math.sqrt(-2.0 * math.log(1e-4))


@pytest.mark.parametrize("value, rounded", [(7.003, 7.1), (60.7, 61.0), (929.1, 930.0), (930.0, 930.0),
                                            (0.012345, 0.013), (12345.0, 13000.0)])
def test_a_gate_is_rounded_up_to_two_significant_digits(value, rounded):
    assert round_up(value) == rounded


def test_the_cutoff_is_twice_the_gate_and_a_file_that_says_nothing_keeps_the_fixed_values():
    assert gates_from_spread(1.8, 1, "deg") == {"assignment_gate_deg": 7.1, "ospa_cutoff_deg": 14.2}
    assert gates_from_spread(math.sqrt(200.0), 2, "m") == {"assignment_gate_m": 61.0, "ospa_cutoff_m": 122.0}
    for nothing in (None, 0.0, -1.0, math.nan, math.inf):
        assert gates_from_spread(nothing, 2, "m") == {}
