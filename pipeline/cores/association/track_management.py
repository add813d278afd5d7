"""Track management: when a track is confirmed and when it ends, one mechanism for every tracker
that keeps tracks alive over scans (``docs/trackers.md``, "Track life").

A track's life in the output vocabulary (:data:`trackreplay.vocabulary.FLAGS`):

* **started** from measurements (a two-point start, MUSIC) or, for the papers' experiments, from
  the truth;
* **tentative** (flag ``INITIALISING``) until it is confirmed by the *M-of-N* rule
  (:class:`ConfirmationRule`): ``hits`` of its first ``window`` scans, the start's own
  measurements included, had a measurement. A track that cannot reach ``hits`` within the
  window is deleted. A track started from the truth is confirmed at its start;
* **coasted** (``COASTED``) on a scan without a measurement;
* **deleted** (``DELETED``, with ``NO_TRACK`` and no state: the flag marks the one scan where it
  ended; later scans of the slot are ``NO_TRACK`` until a new track starts in it) by
  :class:`EndingRule`: its position left the sensor's field by more than a margin, it coasted
  ``max_coasted_scans`` scans in a row, or its position variance grew beyond a bound. A track
  outside the field can only follow clutter or drift on its prediction, and a bearing outside
  the field is never a measurement the sensor can make.

:class:`TrackLife` carries these rules through a tracker's scan loop; arrays are batched over
any leading axes (runs, track slots) and nothing here knows the filter.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class EndingRule:
    """When a track ends (see :func:`ended`).

    Attributes
    ----------
    field : (low, high) or None
        The sensor's field of the position component (radians for a bearing); None: no edge.
    margin : float
        How far beyond an edge a track may be before it ends (e.g. half a gate: a target at the
        edge still has its measurements inside).
    max_coasted_scans : int
        Consecutive coasted scans that end a track; 0 never ends one for coasting.
    max_position_variance : float
        A track whose position variance exceeds this ends (its gate would cover the whole field);
        ``inf``: never.
    """

    field: tuple | None = None
    margin: float = 0.0
    max_coasted_scans: int = 0
    max_position_variance: float = np.inf


@dataclass(frozen=True)
class ConfirmationRule:
    """M-of-N confirmation: ``hits`` measurements within the first ``window`` scans of a track.

    ``hits = 0`` confirms every track at its start (tracks started from the truth).
    """

    hits: int = 0
    window: int = 0

    def __post_init__(self):
        if self.hits < 0 or (self.hits > 0 and self.window < self.hits):
            raise ValueError(f"M-of-N confirmation needs 0 ≤ M ≤ N (got M = {self.hits}, N = {self.window})")


def coasting_run(previous, coasted):
    """Consecutive coasted scans up to this one: ``previous + 1`` where coasted, else 0."""
    return np.where(coasted, np.asarray(previous) + 1, 0)


def ended(position, coasting, rule: EndingRule, position_variance=None):
    """Tracks that end at this scan (bool, the shape of ``position``).

    Parameters
    ----------
    position : ndarray
        The tracks' position component after this scan's update (e.g. bearing, radians).
    coasting : ndarray of int
        :func:`coasting_run` of each track.
    rule : EndingRule
    position_variance : ndarray, optional
        The position's variance, checked against ``rule.max_position_variance``.
    """
    position = np.asarray(position, float)
    out = np.zeros(position.shape, bool)
    if rule.field is not None:
        low, high = rule.field
        out |= (position < low - rule.margin) | (position > high + rule.margin)
    if rule.max_coasted_scans > 0:
        out |= np.asarray(coasting) >= rule.max_coasted_scans
    if position_variance is not None and np.isfinite(rule.max_position_variance):
        out |= np.asarray(position_variance) > rule.max_position_variance
    return out


class TrackLife:
    """The life of a batch of track slots through a scan loop (see the module docstring).

    Parameters
    ----------
    shape : tuple
        The slots' shape, e.g. ``(runs,)`` or ``(runs, tracks)``.
    confirmation : ConfirmationRule
    ending : EndingRule

    Attributes
    ----------
    alive : ndarray of bool
        Slots holding a track (started, not ended).
    tentative : ndarray of bool
        Alive tracks not yet confirmed.
    """

    def __init__(self, shape, confirmation: ConfirmationRule = ConfirmationRule(), ending: EndingRule = EndingRule()):
        self.confirmation, self.ending = confirmation, ending
        self.alive = np.zeros(shape, bool)
        self.tentative = np.zeros(shape, bool)
        self.hits = np.zeros(shape, np.int64)
        self.age = np.zeros(shape, np.int64)
        self.coasting = np.zeros(shape, np.int64)

    def start(self, where, hits=1, scans=1, confirmed=False) -> None:
        """Tracks start in the slots ``where``.

        ``hits`` measurements over ``scans`` scans made the start (2 and 2 for a two-point
        start); ``confirmed`` tracks (started from the truth) skip the M-of-N test.
        """
        where = np.asarray(where, bool)
        self.alive |= where
        rule = self.confirmation
        hits = np.broadcast_to(hits, where.shape)
        tentative = ~np.asarray(confirmed, bool) & (rule.hits > 0) & (hits < rule.hits)
        self.tentative = np.where(where, tentative, self.tentative)
        self.hits = np.where(where, hits, self.hits)
        self.age = np.where(where, scans, self.age)
        self.coasting = np.where(where, 0, self.coasting)

    def resize(self, slots: int) -> None:
        """Grow the last axis (the track slots) to ``slots``; the new slots hold no track. A
        multi-target tracker calls it when more tracks are alive than it has slots for."""
        extra = slots - self.alive.shape[-1]
        if extra <= 0:
            return

        def grown(a):
            return np.concatenate([a, np.zeros(a.shape[:-1] + (extra,), a.dtype)], axis=-1)

        self.alive, self.tentative = grown(self.alive), grown(self.tentative)
        self.hits, self.age, self.coasting = grown(self.hits), grown(self.age), grown(self.coasting)

    @property
    def settled(self) -> bool:
        """Whether :meth:`step` can change nothing but the coasting count.

        True when no track is tentative and the ending rule tests nothing (no field, no coasting
        limit, no variance bound); it stays true until tracks :meth:`start`. A scan loop that
        starts no tracks may then skip :meth:`step`: every slot stays as it is.
        """
        rule = self.ending
        return (rule.field is None and rule.max_coasted_scans <= 0 and not np.isfinite(rule.max_position_variance)
                and not self.tentative.any())

    def step(self, hit, position, position_variance=None):
        """One scan of the alive tracks after their update.

        Parameters
        ----------
        hit : ndarray of bool
            A measurement was used (not coasted).
        position : ndarray
            Position component after the update (checked against the field).
        position_variance : ndarray, optional

        Returns
        -------
        tentative, ending : ndarray of bool
            Alive tracks still tentative after this scan, and tracks that end at this scan (a
            tentative track that can no longer reach M hits in its window ends too). Ended
            slots are no longer alive.
        """
        hit = np.asarray(hit, bool)
        alive = self.alive
        self.coasting = coasting_run(self.coasting, ~hit)
        if self.settled:  # nothing to confirm and no rule to test: no track ends
            nothing = np.zeros(alive.shape, bool)
            return nothing, nothing.copy()
        ending = alive & ended(position, self.coasting, self.ending, position_variance)
        if self.tentative.any():
            rule = self.confirmation
            self.hits = self.hits + (alive & hit)
            self.age = self.age + alive
            confirmed = self.tentative & (self.hits >= rule.hits)
            # the hits still possible in the window cannot make up the deficit: give up now
            hopeless = self.tentative & ~confirmed & (self.hits + np.maximum(rule.window - self.age, 0) < rule.hits)
            self.tentative = self.tentative & ~confirmed
            ending |= hopeless
        self.alive = alive & ~ending
        self.tentative &= self.alive
        return self.tentative & self.alive, ending


def confirmation_scans(hit, rule: ConfirmationRule, start_hits: int = 1):
    """M-of-N for tracks whose hits are known in advance (a batch tracker), vectorised.

    Parameters
    ----------
    hit : ndarray of bool (..., K)
        Whether scan k had a measurement; scan 0 is the start (``start_hits`` measurements).
    rule : ConfirmationRule
    start_hits : int
        Measurements the start used (counted at scan 0).

    Returns
    -------
    tentative : ndarray of bool (..., K)
        Scans at which the track is still tentative (:class:`TrackLife` gives the same).
    failed : ndarray of int (...)
        The scan at which a track that cannot be confirmed is deleted, −1 where it is confirmed.
    """
    hit = np.asarray(hit, bool)
    K = hit.shape[-1]
    tentative = np.zeros(hit.shape, bool)
    failed = np.full(hit.shape[:-1], -1, np.int64)
    if rule.hits <= 0 or K == 0:
        return tentative, failed
    counted = np.cumsum(hit, axis=-1) - hit[..., :1] + start_hits   # hits up to and including scan k
    age = np.arange(1, K + 1)
    confirmed = counted >= rule.hits
    hopeless = ~confirmed & (counted + np.maximum(rule.window - age, 0) < rule.hits)
    first_confirmed = np.where(confirmed.any(axis=-1), np.argmax(confirmed, axis=-1), K)
    first_hopeless = np.where(hopeless.any(axis=-1), np.argmax(hopeless, axis=-1), K)
    tentative = np.arange(K) < np.minimum(first_confirmed, first_hopeless)[..., None]
    failed = np.where(first_hopeless < first_confirmed, first_hopeless, -1)
    return tentative, failed
