"""The peak recorders match their models: goodness-of-fit tests with fixed seeds.

Every statistical test below uses a fixed seed and significance level α = 0.01: with the
model implemented as stated each passes with probability 0.99 for a random seed, and the seed
fixes the outcome so the test is deterministic. A single seed can fail by chance (seed 11 gives
p = 0.003 for the weak amplitudes, a 1-in-100 event), so the amplitude and position models are
also checked for calibration: over many seeds their KS p-values must be uniform, which a wrong
generator fails whatever seed the single-seed tests use.
"""

import numpy as np
import pytest
from scipy import stats

from trackreplay.errors import InputError
from trackreplay.recorders import xcorr_peaks, xcorr_signals
from trackreplay.recorders.scenarios import load_scenario
from trackreplay.recorders.simulated import record

ALPHA = 0.01


def sim(name="xcorr-crossing", runs=200, seed=1, **ov):
    sc = load_scenario(name).with_overrides(ov)
    mod = xcorr_signals if sc.recorder == "xcorr-signals" else xcorr_peaks
    data = mod.simulate(sc.params, runs, seed)
    arr, counts = data.ragged["/xcorr/peaks"]
    return sc.params, data, arr, counts, data.fixed["/xcorr/truth"]


def valid_mask(arr, counts):
    return np.arange(arr["bearing_rad"].shape[2])[None, None, :] < counts[..., None]


def poisson_gof(counts, mean):
    """Chi-square goodness of fit of integer counts to Poisson(mean); bins 0 … 7+."""
    edges = np.arange(9)
    observed = np.array([np.sum(counts == k) for k in edges[:-1]] + [np.sum(counts >= edges[-1])])
    p = np.r_[stats.poisson.pmf(edges[:-1], mean), stats.poisson.sf(edges[-1] - 1, mean)]
    return stats.chisquare(observed, p * counts.size).pvalue


@pytest.fixture(scope="module")
def crossing():
    # wide field so that a background gate [55°, 65°] lies far from both targets
    return sim(runs=300, seed=1, crossing_angle_deg=30.0, field_min_deg=50.0)


def test_background_clutter_counts_are_poisson_with_the_configured_mean(crossing):
    p, data, arr, counts, truth = crossing
    b = np.rad2deg(arr["bearing_rad"])
    inside = valid_mask(arr, counts) & (b >= 55) & (b < 65)
    n = inside.sum(axis=2).ravel()
    assert poisson_gof(n, p["background_clutter_per_gate"]) > ALPHA
    assert abs(n.mean() - 2.0) < 3 * np.sqrt(2.0 / n.size)


def test_clutter_in_the_weak_targets_gate_is_poisson_3_uniform_and_exponential(crossing):
    p, data, arr, counts, truth = crossing
    weak = truth["bearing_rad"][..., 1]
    apart = np.abs(truth["bearing_rad"][..., 0] - weak) > np.deg2rad(p["gate_deg"])  # other gate disjoint
    off = arr["bearing_rad"] - weak[..., None]
    half = np.deg2rad(p["gate_deg"]) / 2
    clutter = valid_mask(arr, counts) & (arr["origin"] == -1) & (np.abs(off) <= half) & apart[..., None]
    n = clutter.sum(axis=2)[apart]
    assert poisson_gof(n, p["weak_clutter_per_gate"]) > ALPHA
    assert stats.kstest(off[clutter] / (2 * half) + 0.5, "uniform").pvalue > ALPHA
    amp = arr["amplitude"][clutter]
    assert stats.kstest(amp, "expon", args=(0, 1 / p["clutter_alpha"])).pvalue > ALPHA
    # mean and variance of an exponential: 1/α and 1/α² (3 standard errors)
    assert abs(amp.mean() * p["clutter_alpha"] - 1) < 3 / np.sqrt(amp.size)
    assert abs(amp.var() * p["clutter_alpha"] ** 2 - 1) < 3 * np.sqrt(8 / amp.size)


@pytest.mark.parametrize("target, role", [(0, "strong"), (1, "weak")])
def test_true_peaks_have_the_roles_gaussian_position_and_amplitude(crossing, target, role):
    p, data, arr, counts, truth = crossing
    mine = valid_mask(arr, counts) & (arr["origin"] == target)
    assert np.all(mine.sum(axis=2) == 1)  # P_D = 1: exactly one true peak per scan
    pos = (arr["bearing_rad"] - truth["bearing_rad"][..., target, None])[mine] / np.deg2rad(p[f"{role}_sigma_p_deg"])
    assert stats.kstest(pos, "norm").pvalue > ALPHA
    mu, sd = p[f"{role}_amplitude_mean"], p[f"{role}_amplitude_std"]
    amp = arr["amplitude"][mine]
    assert stats.kstest(amp, stats.truncnorm(-mu / sd, np.inf, mu, sd).cdf).pvalue > ALPHA
    assert abs(amp.mean() - mu) < 3 * sd / np.sqrt(amp.size)
    assert abs(amp.std() / sd - 1) < 3 / np.sqrt(2 * amp.size)
    assert np.all(arr["amplitude"][valid_mask(arr, counts)] >= 0)


def test_detection_probability_and_data_loss_stretches():
    p, data, arr, counts, truth = sim(runs=100, seed=3, crossing_angle_deg=10.0, detection_probability=0.8,
                                      data_loss_probability=0.02, data_loss_mean_scans=8.0)
    det = truth["detected"][:, 2:].astype(bool)
    lost_share = 0.02 / (0.02 + 1 / 8)  # stationary share of the loss state
    assert abs(det.mean() - 0.8 * (1 - lost_share)) < 0.02
    assert np.all(truth["detected"][:, :2])  # the track-start scans always carry the true peaks
    # stretches: recompute from independent uniforms is not possible, so check their lengths
    # with P_D = 1 (every miss is a loss): geometric with mean 8
    p, data, arr, counts, truth = sim(runs=200, seed=4, crossing_angle_deg=10.0, data_loss_probability=0.02,
                                      data_loss_mean_scans=8.0)
    miss = ~truth["detected"].astype(bool)
    d = np.diff(np.concatenate([np.zeros(miss.shape[:1] + (1,) + miss.shape[2:], bool), miss], axis=1).astype(int), axis=1)
    starts, ends = np.sum(d == 1), np.sum(d == -1)
    lengths = miss.sum() / max(starts, 1)
    assert starts > 300 and abs(lengths - 8.0) < 0.1 * 8.0 + (starts - ends) / starts * 8


@pytest.mark.parametrize("psi", [2.0, 10.0, 30.0])
def test_crossing_geometry(psi):
    p = load_scenario("xcorr-crossing").with_overrides({"crossing_angle_deg": psi}).params
    times, b, rate = xcorr_peaks.target_bearings(p)
    bd, rd = np.rad2deg(b), np.rad2deg(rate)
    assert np.allclose(rd[:, 0], np.tan(np.deg2rad(psi) / 2)) and np.allclose(rd[:, 1], -rd[:, 0])
    # angle between the two lines in the bearing–time plane (1° ≙ 1 s) is ψ
    angle = np.rad2deg(np.arctan(rd[0, 0]) - np.arctan(rd[0, 1]))
    assert angle == pytest.approx(psi)
    sep = np.abs(bd[:, 0] - bd[:, 1])
    assert sep[0] == pytest.approx(15.0, abs=2 * rd[0, 0]) and sep[-1] == pytest.approx(15.0, abs=2 * rd[0, 0])
    assert sep.min() < 2 * rd[0, 0]  # they cross within one scan of mid-run


@pytest.mark.parametrize("L", [0.5, 2.0, 8.0])
def test_maneuver_geometry_reaches_the_minimum_distance(L):
    p = load_scenario("xcorr-maneuver").with_overrides({"min_distance_deg": L}).params
    times, b, rate = xcorr_peaks.target_bearings(p)
    sep = np.rad2deg(b[:, 0] - b[:, 1])
    assert np.all(sep >= L - 1e-9) and sep.min() == pytest.approx(L, abs=p["approach_rate_deg_per_s"] ** 2)
    assert sep[0] == pytest.approx(15.0, abs=0.6) and np.all(np.abs(np.diff(np.rad2deg(rate[:, 0]))) <= 2 * 0.25 / 20 + 1e-9)


def test_same_seed_same_bytes_and_seed_matters(tmp_path):
    sc = load_scenario("xcorr-crossing").with_overrides({"crossing_angle_deg": 30.0})
    paths = [tmp_path / f"{i}.mcap" for i in range(3)]
    for path, seed in zip(paths, (5, 5, 6)):
        record(path, sc, runs=3, seed=seed)
    assert paths[0].read_bytes() == paths[1].read_bytes()
    assert paths[0].read_bytes() != paths[2].read_bytes()


@pytest.mark.parametrize("override, message", [
    ({"pair": "strong-medium"}, "pair must be one of"),
    ({"crossing_angle_deg": 0.0}, "crossing_angle_deg must be in (0, 180)"),
    ({"crossing_angle_deg": 0.05}, "scans"),
    ({"field_max_deg": 95.0}, "leave the field"),
    ({"clutter_alpha": -1.0}, "clutter_alpha must be > 0"),
    ({"detection_probability": 0.0}, "detection_probability must be in (0, 1]"),
])
def test_bad_parameters_are_rejected_before_any_work(override, message):
    p = load_scenario("xcorr-crossing").with_overrides(override).params
    with pytest.raises(InputError, match=message.replace("(", r"\(").replace(")", r"\)").replace("[", r"\[")):
        xcorr_peaks.validate(p)


# --------------------------------------------------------------------------- signal level


@pytest.fixture(scope="module")
def signals():
    return sim("xcorr-signals", runs=6, seed=2, crossing_angle_deg=30.0)


def test_signal_level_true_peaks_sit_at_the_physical_values(signals):
    """Correlation peak height = source variance (sensor noise variance 1) × scale; the
    strong source's bearing is estimated more precisely than the weak one's."""
    p, data, arr, counts, truth = signals
    # away from the other source and from the strong source's multipath ghost (whose
    # correlation sidelobes shift a nearby weak peak by more than the labelling tolerance)
    b = truth["bearing_rad"]
    ghost = b[..., 0] + np.deg2rad(p["multipath_offset_deg"])
    apart = (np.abs(b[..., 0] - b[..., 1]) > np.deg2rad(3)) & (np.abs(ghost - b[..., 1]) > np.deg2rad(3))
    sd = {}
    for t, role in enumerate(("strong", "weak")):
        mine = valid_mask(arr, counts) & (arr["origin"] == t) & apart[..., None]
        expected = p["amplitude_scale"] * 10 ** (p[f"{role}_snr_db"] / 10)
        assert arr["amplitude"][mine].mean() == pytest.approx(expected, rel=0.05)
        assert mine.sum(axis=2)[apart].mean() > 0.9  # found within one lag sample nearly every scan
        sd[role] = np.std((arr["bearing_rad"] - truth["bearing_rad"][..., t, None])[mine])
    assert sd["strong"] < sd["weak"] < np.deg2rad(1.0)


def test_signal_level_multipath_makes_ghost_peaks_at_the_echo_bearing(signals):
    p, data, arr, counts, truth = signals
    ghost = truth["bearing_rad"][..., 0] + np.deg2rad(p["multipath_offset_deg"])
    near = valid_mask(arr, counts) & (np.abs(arr["bearing_rad"] - ghost[..., None]) < np.deg2rad(0.5))
    far_from_weak = np.abs(ghost - truth["bearing_rad"][..., 1]) > np.deg2rad(3)
    amp = np.where(near, arr["amplitude"], -np.inf).max(axis=2)[far_from_weak]
    expected = p["multipath_gain"] ** 2 * p["amplitude_scale"] * 10 ** (p["strong_snr_db"] / 10)
    assert np.median(amp) == pytest.approx(expected, rel=0.15)


def test_gcc_phat_option_and_bounds(signals):
    p, data, arr, counts, truth = sim("xcorr-signals", runs=2, seed=3, crossing_angle_deg=30.0, gcc_phat=True)
    v = valid_mask(arr, counts)
    assert np.all(arr["amplitude"][v] >= 0) and np.all(arr["amplitude"][v] <= p["amplitude_scale"] * 1.0001)
    lo, hi = np.deg2rad([p["field_min_deg"], p["field_max_deg"]])
    assert np.all((arr["bearing_rad"][v] >= lo) & (arr["bearing_rad"][v] <= hi))
    assert (arr["origin"][v] == 0).sum() > 0.9 * counts.size  # the strong source is found


@pytest.mark.parametrize("role, target", [("strong", 0), ("weak", 1)])
def test_goodness_of_fit_p_values_are_uniform_over_seeds(role, target):
    """40 independent data sets: the KS p-values of the true-peak amplitudes and positions
    are themselves Uniform(0, 1) (KS at α = 0.01), and no more than 3 of 40 fall below 0.01
    (binomial tail P(≥ 4 | n = 40, p = 0.01) < 0.001)."""
    pvals_amp, pvals_pos = [], []
    for seed in range(100, 140):
        p, data, arr, counts, truth = sim(runs=40, seed=seed, crossing_angle_deg=30.0, field_min_deg=50.0)
        mine = valid_mask(arr, counts) & (arr["origin"] == target)
        mu, sd = p[f"{role}_amplitude_mean"], p[f"{role}_amplitude_std"]
        amp = arr["amplitude"][mine]
        pvals_amp.append(stats.kstest(amp, stats.truncnorm(-mu / sd, np.inf, mu, sd).cdf).pvalue)
        pos = (arr["bearing_rad"] - truth["bearing_rad"][..., target, None])[mine] / np.deg2rad(p[f"{role}_sigma_p_deg"])
        pvals_pos.append(stats.kstest(pos, "norm").pvalue)
    for pv in (pvals_amp, pvals_pos):
        assert stats.kstest(pv, "uniform").pvalue > ALPHA
        assert sum(v < ALPHA for v in pv) <= 3
