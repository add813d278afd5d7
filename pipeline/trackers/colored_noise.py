"""Trackers of this paper (being moved onto the tracker interface)."""

TRACKERS = ()
