"""Truth as a set of targets per scan, laid out in slots every evaluator reads the same way.

A data set's truth channel holds, per run and scan, the targets present then: their states and,
for a multi-target family, their identities (``target_id``). Evaluators take truth as padded
arrays ``(R, K, T, n)`` with ``truth_ids`` ``(R, K, T)`` (−1 where a slot is empty), the layout of
the trackers' own track slots. :func:`identity_slots` gives each identity one slot for its whole
life (interval colouring, smallest free slot first), so a slot's time series is one target's
while it lives; a slot is reused only after its target's last scan and one empty scan.
"""

from __future__ import annotations

import numpy as np

from trackreplay.errors import InputError


def identity_slots(state, ids, counts, topic: str, path=None):
    """Truth rows ``state`` (R, K, W, n) with identities ``ids`` (R, K, W) (NaN or −1 beyond
    ``counts``) moved into identity-stable slots.

    Returns
    -------
    state_slots : ndarray (R, K, T, n)
        NaN where a slot holds no target.
    id_slots : ndarray of int64 (R, K, T)
        −1 where empty.

    Raises
    ------
    InputError
        An identity appears twice in one scan, or an identity is not a whole number ≥ 0.
    """
    R, K, W = ids.shape
    present = np.arange(W) < np.asarray(counts)[..., None]
    raw = np.where(present, ids, 0.0)
    if not np.all(np.isfinite(raw)) or np.any(raw < 0) or np.any(raw != np.round(raw)):
        raise InputError(f"{topic}: target_id must hold whole numbers ≥ 0", path)
    ids = np.where(present, raw, -1).astype(np.int64)
    ordered = np.sort(np.where(present, ids, -1), axis=2)
    twice = (ordered[..., 1:] == ordered[..., :-1]) & (ordered[..., 1:] >= 0)
    if twice.any():
        r, k, _ = (int(v[0]) for v in np.nonzero(twice))
        i = int(ordered[r, k][1:][twice[r, k]][0])
        raise InputError(f"{topic}: target {i} appears twice at run {r} scan {k}", path)
    slot = np.full((R, K, W), -1, np.int64)
    n_slots = 0
    for r in range(R):
        k_of, w_of = np.nonzero(present[r])
        who = ids[r, k_of, w_of]
        if who.size == 0:
            continue
        uniq, inverse = np.unique(who, return_inverse=True)
        first = np.full(uniq.size, K, np.int64)
        last = np.full(uniq.size, -1, np.int64)
        np.minimum.at(first, inverse, k_of)
        np.maximum.at(last, inverse, k_of)
        # greedy interval colouring in order of birth: optimal (as many slots as targets at once)
        free_from: list[int] = []  # per slot, the first scan it is free again
        slot_of = np.empty(uniq.size, np.int64)
        for i in np.argsort(first, kind="stable"):
            for s, free_scan in enumerate(free_from):
                if free_scan <= first[i]:
                    break
            else:
                s = len(free_from)
                free_from.append(0)
            slot_of[i] = s
            # one empty scan before the next identity: a slot's series breaks between targets
            # (a drawn line, a per-slot metric never joins two of them)
            free_from[s] = last[i] + 2
        slot[r, k_of, w_of] = slot_of[inverse]
        n_slots = max(n_slots, len(free_from))
    state_slots = np.full((R, K, n_slots) + state.shape[3:], np.nan)
    id_slots = np.full((R, K, n_slots), -1, np.int64)
    r, k, w = np.nonzero(slot >= 0)
    state_slots[r, k, slot[r, k, w]] = state[r, k, w]
    id_slots[r, k, slot[r, k, w]] = ids[r, k, w]
    return state_slots, id_slots


def single_target(state):
    """One target's truth ``(R, K, n)`` as a set: ``(R, K, 1, n)`` with identity 0 wherever its
    state is finite."""
    state = np.asarray(state, float)[:, :, None]
    return state, np.where(np.isfinite(state).all(axis=-1), 0, -1).astype(np.int64)
