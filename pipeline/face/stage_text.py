"""The text a replay prints for a stage beside the generic metric tables.

A stage provides its paper's own layout (:meth:`trackreplay.stages.base.Stage.report`) and says
which of its lines the generic tables do not show (``replay_report_lines``) and which state
component a data set without truth lists (``listing``); what is printed of them is decided here,
in the face (``docs/architecture.md``).
"""

from __future__ import annotations

import numpy as np

from trackreplay import vocabulary as vocab

#: a data set without truth of more scans than this lists the first and last halves of them
#: (every scan is in the outputs)
LISTING_SCANS = 40


def replay_report(stage, summary, per_scan) -> str:
    """What ``replay`` prints after the generic metric tables: the lines of ``stage``'s
    :meth:`~trackreplay.stages.base.Stage.report` that say something those tables do not
    (``replay_report_lines``, with their indented continuation lines; None: all of it), so that
    every result is printed once."""
    text = stage.report(summary, per_scan) or ""
    if stage.replay_report_lines is None:
        return text
    kept, keeping = [], False
    for line in text.split("\n"):
        if line.startswith(stage.replay_report_lines):
            keeping = True
        elif not line.startswith(" "):
            keeping = False
        if keeping:
            kept.append(line)
    return "\n".join(kept)


def track_listing(stage, dataset, result: dict, run: int = 0) -> str:
    """For data without truth (a recording), where no error can be computed: run ``run``'s track
    positions per scan (``stage.listing``'s state component), one column per tracker and slot,
    so that a user sees what the trackers made of the data. Empty when the data have truth or
    the family lists nothing."""
    truth_channel = vocab.FAMILIES[stage.family].truth
    if stage.listing is None or truth_channel in dataset.channels:
        return ""
    component, unit = stage.listing
    columns = {}
    for name, out in result["tracks"].items():
        if "state" not in out or "flags" not in out:
            continue
        state = np.asarray(out["state"], float)[run, ..., component]
        state = state.reshape(state.shape[0], -1)
        gone = (np.asarray(out["flags"])[run].reshape(state.shape) & (vocab.NO_TRACK | vocab.DELETED)) > 0
        state = np.where(gone, np.nan, np.rad2deg(state) if unit == "deg" else state)
        for slot in range(state.shape[1]):
            columns[name if state.shape[1] == 1 else f"{name}[{slot}]"] = state[:, slot]
    if not columns:
        return ""
    times = np.asarray(result["times"], float)
    scans = list(range(len(times)))
    if len(scans) > LISTING_SCANS:
        half = LISTING_SCANS // 2
        scans = scans[:half] + [None] + scans[-half:]
    head = f"{'scan':>5} {'time s':>9}" + "".join(f" {c:>12}" for c in columns)
    lines = [f"run {run} without truth: track positions ({unit}) per scan; every scan of every run is "
             "in tracks.mcap", head]
    for k in scans:
        if k is None:
            lines.append(f"{'…':>5}")
            continue
        cells = "".join(f" {'—' if not np.isfinite(v[k]) else f'{v[k]:.2f}':>12}" for v in columns.values())
        lines.append(f"{k:>5} {times[k]:>9.2f}{cells}")
    return "\n".join(lines)
