"""Blocks of runs on the cores at once (``trackreplay.batched_linalg.over_blocks`` with the runner of
``trackreplay.stack_threads``): the same bits as one after the other (issue 27)."""

from __future__ import annotations

import threading

import numpy as np
import pytest

import trackreplay.batched_linalg as batched_linalg
import trackreplay.stack_threads as stack_threads
from trackreplay.recorders.array_snapshots import simulate
from trackreplay.recorders.scenarios import load_scenario
from trackreplay.trackers import array as ab


def test_blocks_on_threads_are_the_pieces_in_order_and_a_stack_inside_one_is_not_split(monkeypatch):
    monkeypatch.setattr(stack_threads, "_cores", lambda: 2)
    monkeypatch.setattr(stack_threads, "THREAD_MIN_WORK", 1)  # a stack alone would be split
    calls, threads = [], set()

    def piece(i):
        threads.add(threading.get_ident())
        calls.append(i)
        stack = np.eye(3)[None].repeat(40, axis=0) * (i + 1)
        return stack_threads.split_over_threads(lambda a: (calls.append(("stack", len(a))), a.sum())[1], stack)

    out = stack_threads.blocks_over_threads(piece, list(range(6)))
    assert out == [3.0 * 40 * (i + 1) for i in range(6)]  # in the order of the pieces
    assert sorted(c for c in calls if isinstance(c, int)) == list(range(6))
    assert [c for c in calls if isinstance(c, tuple)] == [("stack", 40)] * 6  # each stack whole, in its piece
    assert threading.get_ident() not in threads and len(threads) <= 2
    # a stack outside the pieces is split as before
    pieces = []
    stack_threads.split_over_threads(lambda a: pieces.append(len(a)) or a, np.eye(3)[None].repeat(40, axis=0))
    assert sorted(pieces) == [20, 20]


def test_an_error_in_a_block_reaches_the_caller(monkeypatch):
    monkeypatch.setattr(stack_threads, "_cores", lambda: 2)

    def piece(i):
        if i == 2:
            raise np.linalg.LinAlgError("no convergence")
        return i

    with pytest.raises(np.linalg.LinAlgError, match="no convergence"):
        stack_threads.blocks_over_threads(piece, list(range(4)))
    monkeypatch.setattr(batched_linalg, "block_runner", None)
    assert batched_linalg.over_blocks(lambda i: i * i, range(4)) == [0, 1, 4, 9]  # the plain form


@pytest.mark.parametrize("subspace", ["past", "batch"])
def test_the_array_trackers_give_the_same_bits_with_their_blocks_on_threads(monkeypatch, subspace):
    params = load_scenario("array-crossing").params
    data = simulate(dict(params, snr_db=[0.0, 10.0], n_scans=8), 5, 4)
    X = np.array(data.fixed["/array/snapshots"]["snapshots"])
    X.flags.writeable = False
    design = ab.SubspaceTrackerDesign(subspace=subspace, grid_step_rad=np.deg2rad(0.5))
    # several blocks of every kind, so that there is something to share among the threads
    monkeypatch.setattr(ab, "PAST_BLOCK_RUNS", 3)
    monkeypatch.setattr(ab, "FRONT_END_BLOCK_RUNS", 2)
    monkeypatch.setattr(ab, "INNOVATION_BLOCK_RUNS", 3)
    monkeypatch.setattr(stack_threads, "_cores", lambda: 2)
    outputs = {}
    for runner in (None, stack_threads.blocks_over_threads):
        monkeypatch.setattr(batched_linalg, "block_runner", runner)
        monkeypatch.setattr(ab, "_MEMO", [None])
        outputs[runner] = {s: ab.track_bearings(X, design, s) for s in ("proposed", "ryu")}
    one, shared = outputs.values()
    for strategy in one:
        assert one[strategy].keys() == shared[strategy].keys()
        for key, value in one[strategy].items():
            other = shared[strategy][key]
            assert value.dtype == other.dtype and value.shape == other.shape, key
            assert np.ascontiguousarray(value).tobytes() == np.ascontiguousarray(other).tobytes(), (strategy, key)
