"""Strength roles of the tracks in a peak scenario (spec xcorr-peaks-jpda.md, Table of fitted
parameters: strong and weak tracks).

One home for reading the ``pair`` parameter, shared by the peak recorders (which simulate each
target with its role's model) and the bearing-peaks stage (which gives each track its role's
amplitude prior), so the stage does not depend on a recorder.
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
