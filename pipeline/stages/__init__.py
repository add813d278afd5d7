"""Stage processors: each consumes the channels it understands and emits channels in the same
data contract. ``replay`` discovers which stages apply from the channels a file holds.
See :class:`pipeline.stages.base.Stage` for the interface.
"""

from __future__ import annotations

import importlib

STAGE_CLASSES = (
    "pipeline.stages.radar_tws:RadarTwsStage",
    "pipeline.stages.bearing_peaks:BearingPeaksStage",
    "pipeline.stages.array_bearing:ArrayBearingStage",
    "pipeline.stages.emitter_localisation:EmitterLocalisationStage",
    "pipeline.stages.colored_noise_imm:ColoredNoiseImmStage",
    # one line per stage: "pipeline.stages.module:ClassName",
)


def _load(spec: str):
    module, cls = spec.split(":")
    return getattr(importlib.import_module(module), cls)()


STAGES = [_load(s) for s in STAGE_CLASSES]


def applicable_stages(topics) -> list:
    """Stages whose input channels are all present."""
    return [s for s in STAGES if s.applies(topics)]


def stage_for_outputs(topics):
    """The stage that wrote a replay output file (from its output channels)."""
    for s in STAGES:
        if any(t.startswith(s.output_prefix) for t in topics):
            return s
    return None
