"""Checks every registered tracker passes, built in or plugged (in the style of scikit-learn's
``test_common.py``): the output vocabulary with its documented shapes and dtypes, covariances
symmetric positive definite where the state is finite, flags only from the one table, and a
write → read round trip of the outputs that is exact.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from trackreplay import stage_running, vocabulary as vocab
from trackreplay.contract import read_dataset
from trackreplay.registry import available_trackers
from trackreplay.replay import replay
from trackreplay.stages import STAGES

DATA = Path(__file__).resolve().parents[1] / "data"
# one bundled data set per measurement family
DEMO = {"radar": "radar_tws_demo.mcap", "xcorr": "xcorr_crossing_demo.mcap",
        "array": "array_crossing_demo.mcap", "tdoa-fdoa": "tdoa_fdoa_demo.mcap",
        "colored": "colored_imm_demo.mcap"}
ALL_FLAG_BITS = np.dtype(vocab.FLAG_DTYPE).type(sum(vocab.FLAGS.values()))
ENTRIES = sorted(available_trackers().values(), key=lambda e: (e.family, e.name))


def test_every_family_has_a_stage_and_a_demo():
    assert {s.family for s in STAGES} == set(vocab.FAMILIES) == set(DEMO)
    assert {e.family for e in ENTRIES} <= set(vocab.FAMILIES)


_RUNS: dict = {}


def _replayed(entry, tmp_path_factory):
    """Replay the family's demo with this tracker alone, outputs written (cached per tracker)."""
    if entry.name not in _RUNS:
        out = tmp_path_factory.mktemp(entry.name) / "tracks.mcap"
        res = replay(DATA / DEMO[entry.family], trackers=[entry.name], out_path=out)
        stage = next(s for s in STAGES if s.family == entry.family)
        _RUNS[entry.name] = (res, stage, out)
    return _RUNS[entry.name]


@pytest.mark.parametrize("entry", ENTRIES, ids=lambda e: e.name)
def test_output_vocabulary(entry, tmp_path_factory):
    res, stage, _ = _replayed(entry, tmp_path_factory)
    assert not res.failures
    out = res.results[stage.name]["tracks"][entry.name]
    for key in vocab.REQUIRED_OUTPUTS:
        assert key in out, f"{entry.name} lacks {key}"
    state, flags = out["state"], out["flags"]
    R, K = state.shape[:2]
    assert state.dtype == np.float64 and state.ndim in (3, 4)
    assert flags.dtype == np.dtype(vocab.FLAG_DTYPE) and flags.shape == state.shape[:-1]
    assert not np.any(flags & ~ALL_FLAG_BITS), "flag bits outside vocabulary.FLAGS"
    n = state.shape[-1]
    expected = {"covariance": state.shape + (n,), "track_id": state.shape[:-1]}
    for key, shape in expected.items():
        if key in out:
            assert out[key].shape == shape, key
    for key in ("innovation", "innovation_covariance", "gain"):
        if key in out:
            assert out[key].shape[: state.ndim - 1] == state.shape[:-1], key
    if "innovation_covariance" in out:
        m = out["innovation"].shape[-1]
        assert out["innovation_covariance"].shape[-2:] == (m, m)
    if "model_probabilities" in out:
        p = out["model_probabilities"]
        assert p.shape[:2] == (R, K)
        ok = np.isfinite(p).all(axis=-1)
        np.testing.assert_allclose(p[ok].sum(axis=-1), 1.0, rtol=0, atol=1e-9)


@pytest.mark.parametrize("entry", ENTRIES, ids=lambda e: e.name)
def test_covariance_symmetric_positive_definite(entry, tmp_path_factory):
    res, stage, _ = _replayed(entry, tmp_path_factory)
    out = res.results[stage.name]["tracks"][entry.name]
    assert "covariance" in out or not entry.builtin, "every built-in tracker reports its covariance"
    if "covariance" not in out:
        return
    live = np.isfinite(out["state"]).all(axis=-1)
    P = out["covariance"][live]
    assert np.isfinite(P).all()
    np.testing.assert_allclose(P, np.swapaxes(P, -1, -2), rtol=1e-9, atol=0)
    # Cholesky is the independent test of definiteness (validation used eigenvalues)
    np.linalg.cholesky(0.5 * (P + np.swapaxes(P, -1, -2)))


@pytest.mark.parametrize("entry", ENTRIES, ids=lambda e: e.name)
def test_write_read_round_trip_is_exact(entry, tmp_path_factory):
    res, stage, out_path = _replayed(entry, tmp_path_factory)
    written = res.results[stage.name]["tracks"][entry.name]
    back = stage_running.read_outputs(stage, read_dataset(out_path))["tracks"][entry.name]
    assert set(back) == set(written)
    for key, a in written.items():
        b = back[key]
        assert b.shape == a.shape, key
        np.testing.assert_array_equal(np.asarray(b, dtype=a.dtype) if a.dtype.kind in "iub" else b, a, err_msg=key)
