"""Which Rerun views draw which stage's results.

Each module named here exposes ``blueprint(stage, trackers, dataset=None, run=0)`` and
``log_rerun(stage, rec, dataset, result, per_scan, run=0)``, and may expose
``prepare(stage, dataset)``: what its views compute from the data set alone, done ahead (the
recording process calls it while the replay runs; :func:`prepare_views`). Stages hold no Rerun
code.
"""

from __future__ import annotations

import importlib
from pathlib import Path

from trackreplay.vocabulary import FAMILIES

# stage name -> the module of its views, ``face/rerun_<stem>.py`` (the family's declaration)
VIEW_MODULES = {f.name: f.view for f in FAMILIES.values()}


def views_for(stage):
    """The module (or fallback) that draws ``stage``'s results in Rerun."""
    name = VIEW_MODULES.get(stage.name)
    if name is None:
        raise KeyError(f"no Rerun views registered for stage {stage.name!r} (a family's views live in face/rerun_<stem>.py)")
    return importlib.import_module(name)


def prepare_views(stage, dataset) -> None:
    """Let ``stage``'s views compute ahead what depends on the data set alone (their
    ``prepare``, when they have one), so that drawing the results later waits only on them."""
    prepare = getattr(views_for(stage), "prepare", None)
    if prepare is not None:
        prepare(stage, dataset)


def write_recording(rrd_path, ds, stages, results, per_scan, rerun_run: int = 0) -> None:
    """A replay's Rerun recording: every stage's views, saved atomically to ``rrd_path``.

    ``results`` and ``per_scan`` are :func:`trackreplay.replay.replay`'s (the per-scan table with
    its ``stage`` column); one recording per file, whose default blueprint is the first stage's.
    """
    import polars as pl

    from trackreplay.face.timeline import recording

    first = stages[0]
    blueprint = views_for(first).blueprint(first, list(results[first.name]["tracks"]), ds, rerun_run)
    with recording(rrd_path, "trackreplay", Path(ds.path).stem, blueprint) as rec:
        for stage in stages:
            part = per_scan.filter(pl.col("stage") == stage.name)
            views_for(stage).log_rerun(stage, rec, ds, results[stage.name], part, rerun_run)


def log_comparison(comparison, rrd_path) -> None:
    """One recording with both replays on the same timeline: every tracker of A as ``A:name``
    and of B as ``B:name``, drawn by the stage's own views, which lay them side by side."""
    from trackreplay import design_values, stage_scoring
    from trackreplay.face.timeline import recording

    stage, ds = comparison.stage, comparison.dataset
    tracks = {}
    for na, nb in comparison.pairs:
        tracks[f"A:{na}"] = comparison.result_a["tracks"][na]
        tracks[f"B:{nb}"] = comparison.result_b["tracks"][nb]
    result = {"times": comparison.result_a["times"], "tracks": tracks}
    design = design_values.resolve(stage, ds)
    per_scan, _ = stage_scoring.measure(stage, ds, result, design)
    views = views_for(stage)
    with recording(rrd_path, "trackreplay-compare", "compare", views.blueprint(stage, list(tracks), ds, 0)) as rec:
        views.log_rerun(stage, rec, ds, result, per_scan, 0)
