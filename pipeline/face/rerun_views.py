"""Which Rerun views draw which stage's results.

Each module named here exposes ``blueprint(stage, trackers, dataset=None, run=0)`` and
``log_rerun(stage, rec, dataset, result, per_scan, run=0)``. Stages hold no Rerun code.
"""

from __future__ import annotations

import importlib

VIEW_MODULES = {
    "radar-tws": "pipeline.face.rerun_radar_tws",
    "xcorr-peaks": "pipeline.face.rerun_bearing_peaks",
    "colored-noise-imm": "pipeline.face.rerun_colored_noise",
}


class _StageMethods:
    """Fallback for a stage whose views still live on the stage itself."""

    @staticmethod
    def blueprint(stage, trackers, dataset=None, run: int = 0):
        return stage.blueprint(trackers, dataset, run)

    @staticmethod
    def log_rerun(stage, rec, dataset, result, per_scan, run: int = 0):
        return stage.log_rerun(rec, dataset, result, per_scan, run)


def views_for(stage):
    """The module (or fallback) that draws ``stage``'s results in Rerun."""
    name = VIEW_MODULES.get(stage.name)
    return importlib.import_module(name) if name else _StageMethods
