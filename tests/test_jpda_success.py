"""Fig. 8 orderings (Park, Ryu & Lee 1994): JPDA_A vs JPDA success rates over the swept geometry.

Monte Carlo error: both filters run on the same 100 runs, so a difference is judged with the
paired standard error of the per-run success indicators (``paired_difference``); "within Monte
Carlo error" means within 2 paired standard errors (≈ 95 %). Seeds are fixed.

What the paper reports and what we assert:

* strong/weak pair: JPDA_A's success is at least JPDA's at every crossing angle and every
  minimum distance (paper: far better; here too: see docs/papers/xcorr.md);
* similar strengths: the paper says JPDA_A is "slightly better or equal". We assert it is
  never worse beyond MC error for both similar pairs, that weak/weak is within MC error at
  every angle (jointly over the five angles: each within 2.58 paired standard errors, the
  Bonferroni bound that keeps the family's error rate at 5 %), and that the amplitude gain for
  similar strengths is smaller than for strong/weak. For strong/strong the gain exceeds MC
  error at some angles (the amplitude term also rejects clutter, whose amplitudes are far
  below a strong track's): reported, not hidden.
* the shape of Fig. 8 with the default design (q read as (0.1°)², docs/papers/xcorr.md):
  JPDA_A's strong/weak success does not fall from the largest crossing angle to the smallest
  beyond MC error, while JPDA's does. The paper's percentages themselves are not asserted.
"""

import numpy as np
import pytest

from trackreplay.evaluators.xcorr import paired_difference, track_outcomes
from recorded_peaks import track_recorded
from trackreplay.recorders import xcorr_peaks
from trackreplay.recorders.scenarios import load_scenario

RUNS = 100
ANGLES = (2.0, 5.0, 10.0, 20.0, 30.0)
JOINT_Z = 2.576  # two-sided 1 % normal quantile: 5 % over the five angles jointly (Bonferroni)
DISTANCES = (0.5, 1.0, 2.0, 4.0, 8.0)


def success(scenario, key, value, pair, seed=11):
    p = load_scenario(scenario).with_overrides({key: value, "pair": pair}).params
    res = track_recorded(xcorr_peaks.simulate(p, RUNS, seed), p, seed=seed, scenario=scenario)
    out = {}
    for name, tr in res["tracks"].items():
        held, swapped, lost = track_outcomes(tr["state"][..., 0], res["truth"], res["gate_rad"])
        out[name] = held.all(axis=1)
    return paired_difference(out["jpda_a"], out["jpda"]), out


@pytest.fixture(scope="module")
def crossing():
    return {pair: {a: success("xcorr-crossing", "crossing_angle_deg", a, pair) for a in ANGLES}
            for pair in ("strong-weak", "strong-strong", "weak-weak")}


def test_strong_weak_crossing_jpda_a_at_least_jpda_at_every_angle(crossing):
    for angle, ((diff, se), out) in crossing["strong-weak"].items():
        assert diff >= -2 * se, (angle, diff, se)
    # and the gain is real overall, not just "not worse"
    diffs = np.array([d for (d, _), _ in crossing["strong-weak"].values()])
    ses = np.array([s for (_, s), _ in crossing["strong-weak"].values()])
    assert diffs.mean() > 2 * np.sqrt(np.sum(ses**2)) / len(ses)


def test_strong_weak_maneuver_jpda_a_at_least_jpda_at_every_distance():
    for L in DISTANCES:
        (diff, se), _ = success("xcorr-maneuver", "min_distance_deg", L, "strong-weak")
        assert diff >= -2 * se, (L, diff, se)


def test_similar_strengths_jpda_a_equal_or_better_and_gain_smaller_than_strong_weak(crossing):
    for pair in ("strong-strong", "weak-weak"):
        for angle, ((diff, se), _) in crossing[pair].items():
            assert diff >= -2 * se, (pair, angle, diff, se)
    for angle, ((diff, se), _) in crossing["weak-weak"].items():
        assert abs(diff) <= JOINT_Z * se, (angle, diff, se)
    gain = {pair: np.mean([d for (d, _), _ in crossing[pair].values()]) for pair in crossing}
    assert gain["strong-weak"] > gain["strong-strong"] and gain["strong-weak"] > gain["weak-weak"]


def test_jpda_a_holds_its_success_at_small_crossing_angles_where_jpda_falls(crossing):
    """Fig. 8's shape: from the largest crossing angle to the smallest, JPDA_A's strong/weak
    success stays within Monte Carlo error while JPDA's drops beyond it (binomial standard
    errors of the two independent points)."""
    small, large = min(ANGLES), max(ANGLES)

    def drop(tracker):
        a, b = crossing["strong-weak"][large][1][tracker].mean(), crossing["strong-weak"][small][1][tracker].mean()
        se = np.sqrt(a * (1 - a) / RUNS + b * (1 - b) / RUNS)
        return a - b, max(se, 1.0 / RUNS)

    d, se = drop("jpda_a")
    assert d <= 2 * se, ("jpda_a", d, se)
    d, se = drop("jpda")
    assert d > 2 * se, ("jpda", d, se)
