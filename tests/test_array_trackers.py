"""The array trackers on the tracker interface: registration, the output vocabulary and
flags, the shared start-up/subspace memo, FLOP outputs, design checks, and an evaluator that reads
only the vocabulary."""

import numpy as np
import pytest

from trackreplay.evaluators.array import evaluate
from trackreplay import vocabulary as vocab
from trackreplay.errors import InputError
from trackreplay.registry import trackers_of_family
from trackreplay.trackers import array as ab
from trackreplay.trackers.interface import ArraySnapshots, call_tracker
from trackreplay.recorders.array_snapshots import simulate
from trackreplay.recorders.scenarios import load_scenario

PARAMS = load_scenario("array-crossing").params


def design(**over):
    return {**{p.name: PARAMS.get(p.name, p.default) for p in ab.PARAMS}, **over}


@pytest.fixture(scope="module")
def small():
    """Two runs per SNR at 0 and 10 dB, 12 scans, the default five targets (read-only, as the stage decodes)."""
    data = simulate(dict(PARAMS, snr_db=[0.0, 10.0], n_scans=12), 2, 4)
    X = np.array(data.fixed["/array/snapshots"]["snapshots"])
    X.flags.writeable = False
    truth = data.fixed["/array/truth"]["angle_rad"]
    return ArraySnapshots(snapshots=X, times_s=np.asarray(data.times, float), spacing_wavelengths=0.5,
                          truth_angle_rad=truth)


def test_both_strategies_are_registered_trackers_of_the_family():
    assert [cls.name for cls in ab.TRACKERS] == ["proposed", "ryu"]
    entries = {e.name: e for e in trackers_of_family("array")}
    assert {"proposed", "ryu"} <= set(entries)
    for name in ("proposed", "ryu"):
        assert entries[name].builtin and entries[name].cls.form == "batch"


def test_outputs_follow_the_vocabulary(small):
    out = call_tracker(ab.Proposed(**design()), small)
    R, K = small.n_runs, small.n_scans
    T = out["state"].shape[2]
    assert out["state"].shape == (R, K, T, 2) and T == 5
    assert out["covariance"].shape == (R, K, T, 2, 2)
    assert out["innovation"].shape == (R, K, T, 1) and out["innovation_covariance"].shape == (R, K, T, 1, 1)
    assert out["gain"].shape == (R, K, T, 2, 1)
    assert out["flags"].dtype == np.dtype(vocab.FLAG_DTYPE)
    assert np.all(out["flags"][:, :2] & vocab.INITIALISING)
    assert np.all(out["flags"][:, 0] & vocab.NOT_ESTIMATED) and not np.any(out["flags"][:, 1:] & vocab.NOT_ESTIMATED)
    assert np.all(np.isnan(out["state"][:, 0, :, 1])) and np.all(np.isfinite(out["state"][:, 1:]))
    assert np.all(np.isnan(out["innovation"][:, :2])) and np.all(np.isfinite(out["innovation"][:, 2:]))
    # S = P⁻₀₀ + σ_z² and the gain is P⁻ Hᵀ S⁻¹
    sz2 = np.deg2rad(1.0) ** 2 * PARAMS["innovation_variance_deg2"]
    assert np.all(out["innovation_covariance"][:, 2:] > sz2)
    assert "innovation_time_s" not in out  # no wall-clock timing in a tracker
    for key in ("predicted_rad", "n_tracks", "source_count", "subspace_error_rad"):
        assert out[key].shape[:2] == (R, K)


def test_padded_slots_are_no_track():
    X = np.zeros((2, 4, 6, 10), complex)
    rng = np.random.default_rng(0)
    X[:] = rng.standard_normal(X.shape) + 1j * rng.standard_normal(X.shape)
    from trackreplay.cores.array.linear_array import steering_vectors

    X[0] += steering_vectors(np.deg2rad([-20.0, 25.0]), 6, 0.5) @ (10 * rng.standard_normal((2, 10)))
    X[1] += steering_vectors(np.deg2rad([10.0]), 6, 0.5) @ (10 * rng.standard_normal((1, 10)))
    m = ArraySnapshots(snapshots=X, times_s=np.arange(4.0), spacing_wavelengths=0.5)
    out = call_tracker(ab.Ryu(**design()), m)
    assert out["n_tracks"][:, 0].tolist() == [2, 1]
    assert np.all(out["flags"][1, :, 1] == vocab.NO_TRACK) and np.all(np.isnan(out["state"][1, :, 1]))
    assert not np.any(out["flags"][0] & vocab.NO_TRACK)


def test_the_shared_front_end_changes_nothing(small):
    writable = ArraySnapshots(snapshots=np.array(small.snapshots), times_s=small.times_s, spacing_wavelengths=0.5)
    for cls in ab.TRACKERS:
        a = call_tracker(cls(**design()), small)  # memo (read-only input)
        b = call_tracker(cls(**design()), writable)  # recomputed
        assert a.keys() == b.keys()
        for key in a:
            np.testing.assert_array_equal(a[key], b[key], err_msg=key)
    # another design or other snapshots are not served from the memo
    batch = call_tracker(ab.Proposed(**design(subspace_tracker="batch")), small)
    assert not np.array_equal(batch["state"], call_tracker(ab.Proposed(**design()), small)["state"], equal_nan=True)


def test_the_trackers_report_the_flops_of_their_innovation(small):
    for cls, model in ((ab.Proposed, 35_600), (ab.Ryu, 89_210)):  # the paper's model at M = 15, N = 5
        out = call_tracker(cls(**design()), small)
        assert np.all(out["innovation_flops_model"][:, 2:] == model)
        assert np.all(np.isnan(out["innovation_flops_model"][:, :2]))
        assert cls.innovation_flops(15, 5)["model"] == model
        assert np.all(out["innovation_flops_counted"][:, 2:] == cls.innovation_flops(15, 5)["counted"])


@pytest.mark.parametrize("key, value, message", [
    ("source_count_criterion", "bic", "mdl or aic"),
    ("subspace_tracker", "svd", "subspace_tracker"),
    ("past_forgetting", 1.5, "(0, 1]"),
    ("innovation_variance_deg2", 0.0, "innovation_variance_deg2"),
    ("n_sources", -1, "≥ 0"),
])
def test_bad_design_values_are_refused(key, value, message):
    with pytest.raises(InputError, match=message.replace("(", r"\(").replace(")", r"\)").replace("]", r"\]")):
        ab.Proposed(**design(**{key: value}))


def test_the_evaluator_needs_only_state_and_flags(small):
    """A plugged tracker that reports nothing but the required outputs is scored all the same."""
    truth = small.truth_angle_rad
    state = np.stack([truth, np.zeros_like(truth)], axis=-1)
    flags = np.zeros(truth.shape, np.uint16)
    per_scan, summary = evaluate(np.arange(small.n_scans, dtype=float), {"oracle": {"state": state, "flags": flags}},
                                 truth, np.repeat([0.0, 10.0], 2), np.deg2rad(3.0), 15)
    mse = summary.filter((summary["tracker"] == "oracle") & (summary["metric"] == "angle_mse_deg2"))
    assert mse.height == 3 and np.all(mse["value"].to_numpy() == 0.0)
    assert not summary["metric"].str.starts_with("innovation_flops").any()
    assert "mse_deg2" in per_scan.columns
