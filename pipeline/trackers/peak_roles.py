"""Strength roles of the tracks in a peak scenario: strong and weak tracks, after the fitted
parameters of Park, Ryu & Lee (1994) (see ``docs/papers/bearing-peaks.md``).

One home for reading the ``pair`` parameter, shared by the peak recorders (which simulate each
target with its role's model), the bearing-peaks trackers (which give each track its role's
amplitude prior) and the stage (which names the evaluator's per-track scopes), so neither the
trackers nor the stage depend on a recorder.
"""

from __future__ import annotations

from pipeline.errors import InputError

PAIRS = {"strong-weak": ("strong", "weak"), "strong-strong": ("strong", "strong"),
         "weak-weak": ("weak", "weak")}


def track_roles(p: dict) -> tuple[str, ...]:
    """Roles of the targets in order (``pair = "strong-weak"``: target 0 strong, 1 weak)."""
    if p["pair"] not in PAIRS:
        raise InputError(f"pair must be one of {', '.join(PAIRS)} (got {p['pair']!r})")
    return PAIRS[p["pair"]]


def roles_for(p: dict, n_tracks: int) -> tuple[str, ...]:
    """:func:`track_roles`, checked against the number of targets the data hold.

    Raises
    ------
    InputError
        ``pair`` is unknown or describes another number of targets than ``n_tracks``.
    """
    roles = track_roles(p)
    if len(roles) != n_tracks:
        raise InputError(f"the data hold {n_tracks} target(s) but pair={p['pair']!r} describes {len(roles)}")
    return roles
