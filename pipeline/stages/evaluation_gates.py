"""Evaluation design values that follow from the data: the matching gate and the cut-off from the
measurement noise and geometry a data set records (issue 26, item 3).

One rule for every family (``docs/evaluation.md``, "Evaluation design values"): the matching gate
is the radius, in the space the standard measures compare, that holds all but 10⁻⁴ of a Gaussian
measurement error of the data set's largest spread s (the square root of the trace of the
measurement error's covariance in that space, at the worst point of the data set),

    gate = √(χ²_d quantile at 1 − 10⁻⁴) · s,    d = the space's dimension,

rounded up to two significant digits (a value a reader can quote), and GOSPA's cut-off c is twice
the gate (the ratio of the fixed defaults; HOTA's d₀ and GOSPA's γ follow c, the SIAP gate the
gate, in a family that does not list them). A filter's error is at most its measurements' after
the first update, so a gate this wide does not cut a track off a target it follows, and one this
narrow still calls a track that wanders many σ away a miss. The χ² gate is the validation region
of Bar-Shalom, Li & Kirubarajan, *Estimation with Applications to Tracking and Navigation* (2001),
applied here to the measurement error rather than the innovation; the radar stage's rule
(``RadarStage.evaluation_defaults_from_data``) is this one with d = 2.
"""

from __future__ import annotations

import math

#: the share of a Gaussian measurement error the gate may leave outside it
GATE_MISS_PROBABILITY = 1e-4


def gate_sigmas(dims: int, miss: float = GATE_MISS_PROBABILITY) -> float:
    """The radius, in σ, of the ball that holds all but ``miss`` of a standard Gaussian in
    ``dims`` dimensions: √ of the χ² quantile with ``dims`` degrees of freedom at 1 − miss.

    Closed forms: d = 1, √2 erfc⁻¹(miss) (3.89 σ at 10⁻⁴); d = 2, √(−2 ln miss) (4.29 σ)."""
    if dims == 2:
        return math.sqrt(-2.0 * math.log(miss))
    from scipy.stats import chi2

    return float(math.sqrt(chi2.isf(miss, dims)))


def round_up(value: float, digits: int = 2) -> float:
    """``value`` rounded up to ``digits`` significant digits (a gate a reader can quote)."""
    exponent = math.floor(math.log10(value)) - (digits - 1)
    # round() drops the binary residue of the product (7.1, not 7.1000000000000005)
    return float(round(math.ceil(value / 10.0 ** exponent - 1e-9) * 10.0 ** exponent, max(0, -exponent)))


def gates_from_spread(spread: float, dims: int, unit: str) -> dict:
    """``{assignment_gate_<unit>, ospa_cutoff_<unit>}`` of a measurement error of spread
    ``spread`` (in ``unit``) in a ``dims``-dimensional space, by the module's rule; ``{}`` when
    the spread is not a positive finite number (the file says nothing: the fixed defaults stay)."""
    if spread is None or not math.isfinite(spread) or spread <= 0:
        return {}
    gate = round_up(gate_sigmas(dims) * float(spread))
    return {f"assignment_gate_{unit}": gate, f"ospa_cutoff_{unit}": 2.0 * gate}
