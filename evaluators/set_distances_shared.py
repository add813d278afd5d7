"""The small pieces :mod:`trackreplay.evaluators.set_distances` (the plain forms) and
:mod:`trackreplay.evaluators.set_distances_fast` (the fast forms) share: the size up to which an
assignment tries every permutation, the distance of a single pair, the squared distance summed a
component at a time (so that both forms of a close-pair search give the same distances, bit for
bit), the dense close-pair search (the plain form, which the windowed one falls back to) and the
numbering of distinct keys. Both modules import this one, and the plain module imports the fast
one, so the imports run one way. See ``docs/evaluation.md``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from trackreplay.batched_linalg import all_finite

BRUTE_FORCE_MAX = 6  # 6! = 720 permutations per scan, evaluated together


def single_pair_distance(rows, columns, angular: bool = False):
    """Distance (R, K) between the one element of ``rows`` and the one of ``columns`` (sets
    ``(R, K, 1, d)``) of every (run, scan), NaN where either is absent: :func:`~trackreplay.evaluators.set_distances.pairwise_distance`'s
    sum of squares of ``rows − columns``, a component at a time in the same order (bit for bit
    its value and :func:`~trackreplay.evaluators.set_distances.close_pairs`'s with the same rows; with angles the wrapped difference
    depends on the order by rounding)."""
    X, Y = np.asarray(rows, float), np.asarray(columns, float)
    total = np.zeros(X.shape[:2])
    for i in range(min(X.shape[-1], Y.shape[-1])):
        diff = X[:, :, 0, i] - Y[:, :, 0, i]
        if angular:
            diff = (diff + np.pi) % (2 * np.pi) - np.pi
        total += diff * diff
    return np.sqrt(total, out=total)


class SinglePair(NamedTuple):
    """What every single-target form reads of sets of one track and one target slot
    ``(R, K, 1, d)`` (:func:`single_pair_view`): arrays (R, K), C-ordered as the forms' own were
    (the layout decides the order in which numpy adds along the scans, so the sums keep their
    bits).

    Attributes
    ----------
    track_finite, truth_finite : ndarray of bool
        Every component of the track (target) finite.
    track_listed, truth_listed : ndarray of bool or None
        Its identity ≥ 0; None where no identities are given (every slot its own).
    track_present, truth_present : ndarray of bool
        Finite and listed: a reported track, a present target.
    distance : ndarray
        :func:`single_pair_distance` of target − track (NaN where either is absent).
    """

    track_finite: np.ndarray
    truth_finite: np.ndarray
    track_listed: np.ndarray | None
    truth_listed: np.ndarray | None
    track_present: np.ndarray
    truth_present: np.ndarray
    distance: np.ndarray


def single_pair_view(tracks, truths, track_ids=None, truth_ids=None, angular: bool = False) -> SinglePair:
    """The presences and the one distance per (run, scan) of sets of one track and one target
    slot ``(R, K, 1, d)``, found once for every single-target form (GOSPA, the matching, CLEAR
    and identity measures, HOTA, SIAP) instead of once in each.

    The distance is :func:`single_pair_distance`'s (target − track), with the same operations
    in the same order. Each of the target's components is read once, into a C-ordered buffer
    that its finiteness and its difference then read: the recorded truth holds the runs
    fastest, and read scan-major straight into the C-ordered sums every element would be a
    page apart (it is staged through a buffer laid out as the truth is).
    """
    X, Y = np.asarray(tracks, float), np.asarray(truths, float)
    R, K = X.shape[:2]
    track_finite = all_finite(X[:, :, 0])
    truth_finite = np.ones((R, K), bool)
    total, diff, column, finite = np.zeros((R, K)), np.empty((R, K)), np.empty((R, K)), np.empty((R, K), bool)
    staged = np.empty((K, R)).T if abs(Y.strides[0]) < abs(Y.strides[1]) else None
    for i in range(Y.shape[-1]):
        if staged is None:
            np.copyto(column, Y[:, :, 0, i])
        else:
            np.copyto(staged, Y[:, :, 0, i])     # along the runs, as the truth lies
            np.copyto(column, staged)
        truth_finite &= np.isfinite(column, out=finite)
        if i < X.shape[-1]:
            _add_square(total, np.subtract(column, X[:, :, 0, i], out=diff), angular)
    distance = np.sqrt(total, out=total)
    # written C-ordered whatever the identities' layout (a tracker's buffers hold the runs fastest)
    listed = lambda ids: None if ids is None else np.greater_equal(np.asarray(ids)[:, :, 0], 0,  # noqa: E731
                                                                   out=np.empty((R, K), bool))
    track_listed, truth_listed = listed(track_ids), listed(truth_ids)
    return SinglePair(track_finite, truth_finite, track_listed, truth_listed,
                      track_finite if track_listed is None else track_finite & track_listed,
                      truth_finite if truth_listed is None else truth_finite & truth_listed,
                      distance)


def _add_square(total, difference, angular: bool) -> None:
    """``total += difference²`` in place, the difference wrapped into [−π, π) first for an angle
    (``difference`` is overwritten): one component of a squared distance, summed the same way by
    both forms of :func:`~trackreplay.evaluators.set_distances.close_pairs` so that their distances agree bit for bit."""
    if angular:
        difference += np.pi
        np.mod(difference, 2 * np.pi, out=difference)
        difference -= np.pi
    np.multiply(difference, difference, out=difference)
    total += difference


#: pairs per block of :func:`_close_pairs_dense`: its squared distances stay in the cache
PAIR_BLOCK = 1 << 16


def _close_pairs_dense(X, Y, radius: float, angular: bool = False):
    """:func:`~trackreplay.evaluators.set_distances.close_pairs` by trying every pair of every problem: the plain form.

    The squared distances are summed a component at a time in buffers of :data:`PAIR_BLOCK`
    pairs that stay in the cache, and only the close pairs get a square root.
    """
    X, Y = np.asarray(X, float), np.asarray(Y, float)
    P, m, n = X.shape[0], X.shape[1], Y.shape[1]
    step = max(1, PAIR_BLOCK // max(m * n, 1))
    # a little above radius²: the exact test is on the distance itself below
    wide = radius * radius * (1 + 8 * np.finfo(float).eps)
    Xc = [np.ascontiguousarray(X[..., c]) for c in range(X.shape[-1])]
    Yc = [np.ascontiguousarray(Y[..., c]) for c in range(Y.shape[-1])]
    total, part = np.empty((step, m, n)), np.empty((step, m, n))
    found, squares = [], []
    for a in range(0, P, step):
        b = min(step, P - a)
        t, u = total[:b], part[:b]
        t.fill(0.0)
        for xc, yc in zip(Xc, Yc):
            _add_square(t, np.subtract(xc[a:a + b, :, None], yc[a:a + b, None, :], out=u), angular)
        flat = np.flatnonzero(t.reshape(-1) < wide)   # NaN (an absent row) is never closer
        found.append(flat + a * m * n)
        squares.append(t.reshape(-1)[flat])
    flat = np.concatenate(found) if found else np.zeros(0, np.intp)
    d = np.sqrt(np.concatenate(squares)) if squares else np.zeros(0)
    keep = d < radius
    flat, d = flat[keep], d[keep]
    p, ij = np.divmod(flat, m * n)
    i, j = np.divmod(ij, n)
    return p, i, j, d


def _compact(keys, n: int):
    """The distinct ``keys`` (< n) numbered 0… in increasing order, and how many there are."""
    keys = np.asarray(keys)
    if keys.size and keys.size < n // 4:
        # far fewer keys than values (a few of the (problem, row) keys of an assignment): when they
        # come sorted, as edges listed by problem and row do, they are numbered by counting the
        # changes, without a pass over all n values
        new = np.empty(keys.size, bool)
        new[0] = True
        np.not_equal(keys[1:], keys[:-1], out=new[1:])
        if not (keys[1:] < keys[:-1]).any():
            number = np.cumsum(new)
            number -= 1
            return number, int(number[-1]) + 1
    mark = np.zeros(n, bool)
    mark[keys] = True
    number = np.cumsum(mark) - 1
    return number[keys], int(mark.sum())
