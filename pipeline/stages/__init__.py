"""Stage processors: each consumes the channels it understands and emits channels in the same
data contract. ``replay`` discovers which stages apply from the channels a file holds.

A stage exposes::

    name, input_topics, trackers
    applies(topics) -> bool
    design(dataset, overrides) -> dict          # parameters the trackers use
    run(dataset, trackers, design) -> {tracker: {array name: (runs, scans, ...)}}
    output_topic(tracker) -> str
    evaluate(dataset, outputs, design) -> (per_scan, summary)    # polars
    log_rerun(rec, dataset, outputs, per_scan, run)
    blueprint(trackers)
"""

from __future__ import annotations

from pipeline.stages.radar_tws import RadarTwsStage

STAGES = [RadarTwsStage()]


def applicable_stages(topics) -> list:
    """Stages whose input channels are all present."""
    return [s for s in STAGES if s.applies(topics)]


def stage_for_outputs(topics):
    """The stage that wrote a replay output file (from its output channels)."""
    for s in STAGES:
        if any(t.startswith(s.output_prefix) for t in topics):
            return s
    return None
