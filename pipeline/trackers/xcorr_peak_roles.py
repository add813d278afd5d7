"""Strength roles of the tracks in a peak scenario: strong and weak tracks, after the fitted
parameters of Park, Ryu & Lee (1994) (see ``docs/papers/xcorr.md``).

One home for reading the ``roles`` and ``pair`` parameters, shared by the peak recorders (which
simulate each target with its role's model), the xcorr trackers (which give each track
its role's amplitude prior) and the stage (which names the evaluator's per-track scopes), so
neither the trackers nor the stage depend on a recorder.

The roles are a **pattern**, not a count: ``roles = "strong-weak-weak"`` gives target t the role
``pattern[t mod 3]``, whatever the number of targets. ``roles = "pair"`` (the scenarios'
default; an empty value too) takes the pattern of ``pair`` (``strong-weak``, ``strong-strong``,
``weak-weak``), so the paper's two-target scenarios read exactly as before, and
``pair = "strong-weak"`` over four targets means strong, weak, strong, weak.
"""

from __future__ import annotations

from trackreplay.errors import InputError

ROLE_NAMES = ("strong", "weak")
FROM_PAIR = "pair"  # the value of roles that defers to pair
PAIRS = {"strong-weak": ("strong", "weak"), "strong-strong": ("strong", "strong"),
         "weak-weak": ("weak", "weak")}


def role_pattern(p: dict) -> tuple[str, ...]:
    """The pattern of roles cycled over the targets: ``roles``, or ``pair``'s where ``roles`` is
    ``"pair"`` or empty.

    Raises
    ------
    InputError
        ``roles`` holds a name other than strong or weak (names are joined by ``-``), or ``roles``
        defers to ``pair`` and ``pair`` is unknown.
    """
    text = str(p.get("roles") or "").strip()
    if text and text != FROM_PAIR:
        pattern = tuple(part.strip().lower() for part in text.split("-"))
        if not all(part in ROLE_NAMES for part in pattern):
            raise InputError(f"roles must be {' or '.join(ROLE_NAMES)} joined by '-' (e.g. strong-weak-weak, "
                             f"cycled over the targets) or 'pair' (pair's roles); got {text!r}")
        return pattern
    if p.get("pair") not in PAIRS:
        raise InputError(f"pair must be one of {', '.join(PAIRS)} (got {p.get('pair')!r})")
    return PAIRS[p["pair"]]


def track_roles(p: dict, n_targets: int | None = None) -> tuple[str, ...]:
    """Roles of ``n_targets`` targets in order, the pattern cycled (target t takes
    ``pattern[t mod len(pattern)]``); without ``n_targets`` the pattern itself
    (``pair = "strong-weak"``: target 0 strong, 1 weak)."""
    pattern = role_pattern(p)
    if n_targets is None:
        return pattern
    return tuple(pattern[t % len(pattern)] for t in range(int(n_targets)))


def roles_for(p: dict, n_tracks: int) -> tuple[str, ...]:
    """:func:`track_roles` for the ``n_tracks`` targets the data hold (any number ≥ 0).

    Raises
    ------
    InputError
        An unknown role name in ``roles``, or an unknown ``pair`` when ``roles`` defers to it.
    """
    return track_roles(p, n_tracks)
