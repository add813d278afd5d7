"""When a track ends: one rule for every tracker that keeps tracks alive over scans.

A track ends (flag ``DELETED`` at that scan, ``NO_TRACK`` after it, its slot no longer
associated) when its position leaves the sensor's field by more than a margin, or when it has
coasted (no measurement in its gate) for ``max_coasted_scans`` scans in a row. A track outside
the field can only follow clutter or drift on its prediction, and a bearing outside the field is
never a measurement the sensor can make (``docs/trackers.md``).

Arrays are batched over any leading axes (runs, tracks); nothing here knows the filter.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class EndingRule:
    """The design of :func:`ended`.

    Attributes
    ----------
    field : (low, high) or None
        The sensor's field of the position component (radians for a bearing); None: no edge.
    margin : float
        How far beyond an edge a track may be before it ends (e.g. half a gate: a target at the
        edge still has its measurements inside).
    max_coasted_scans : int
        Consecutive coasted scans that end a track; 0 never ends one for coasting.
    """

    field: tuple | None = None
    margin: float = 0.0
    max_coasted_scans: int = 0


def coasting_run(previous, coasted):
    """Consecutive coasted scans up to this one: ``previous + 1`` where coasted, else 0."""
    return np.where(coasted, np.asarray(previous) + 1, 0)


def ended(position, coasting, rule: EndingRule):
    """Tracks that end at this scan (bool, the shape of ``position``).

    Parameters
    ----------
    position : ndarray
        The tracks' position component after this scan's update (e.g. bearing, radians).
    coasting : ndarray of int
        :func:`coasting_run` of each track.
    rule : EndingRule
    """
    position = np.asarray(position, float)
    out = np.zeros(position.shape, bool)
    if rule.field is not None:
        low, high = rule.field
        out |= (position < low - rule.margin) | (position > high + rule.margin)
    if rule.max_coasted_scans > 0:
        out |= np.asarray(coasting) >= rule.max_coasted_scans
    return out
