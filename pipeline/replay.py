"""Replay orchestration: file in → stages → outputs MCAP, Rerun recording, metrics tables.

This is bookkeeping only: it finds the stages that apply, hands them the decoded channels,
writes what they return and collects their tables.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import polars as pl

from pipeline import __version__
from pipeline.contract import METADATA_PROVENANCE, Dataset, read_dataset, write_dataset
from pipeline.errors import InputError
from pipeline.stages import applicable_stages, stage_for_outputs


@dataclass
class ReplayResult:
    """What one replay produced."""

    dataset: Dataset
    per_scan: pl.DataFrame
    summary: pl.DataFrame
    results: dict = field(default_factory=dict)
    out_path: Path | None = None
    rrd_path: Path | None = None
    timings: dict = field(default_factory=dict)


def _select_trackers(stage, trackers):
    if not trackers:
        return list(stage.trackers)
    unknown = [t for t in trackers if t not in stage.trackers]
    if unknown:
        raise InputError(f"unknown tracker(s) {', '.join(unknown)} for {stage.name} (have: {', '.join(stage.trackers)})")
    return list(trackers)


def replay(path, trackers=None, out_path=None, rrd_path=None, recover=False, design_overrides=None,
           rerun_run: int = 0, dataset: Dataset | None = None, progress=None) -> ReplayResult:
    """Replay every applicable stage over a data set.

    Parameters
    ----------
    path : str or Path
        Input MCAP (never modified).
    trackers : list of str, optional
        Subset of trackers (default: all that apply).
    out_path, rrd_path : Path, optional
        Where to write the outputs MCAP and the Rerun recording (skipped when None).
    recover : bool
        Accept a truncated input, keeping its complete chunks.
    design_overrides : dict, optional
        Tracker design parameters to override (``name -> value``).
    rerun_run : int
        Which Monte Carlo run the per-run Rerun views show.
    dataset : Dataset, optional
        An already decoded data set (skips reading ``path``).
    progress : callable, optional
        Called with 1 after each of the four phases (filter, evaluate, write, rerun).
    """
    step = progress or (lambda n: None)
    t0 = time.perf_counter()
    ds = dataset if dataset is not None else read_dataset(path, recover=recover)
    timings = {"read_s": time.perf_counter() - t0}
    stages = applicable_stages(ds.channels)
    if not stages:
        have = ", ".join(sorted(ds.channels)) or "none"
        raise InputError(f"no stage applies to the channels in this file ({have})", ds.path)
    results, per_scan, summary, designs = {}, [], [], {}
    t1 = time.perf_counter()
    for stage in stages:
        design = stage.design(ds, design_overrides)
        # later calls of stage.design(ds) (Rerun logging, figures) see the values this run used
        ds.cache[("design", stage.name)] = design
        result = stage.run(ds, _select_trackers(stage, trackers), design)
        results[stage.name] = result
        designs[stage.name] = design
    timings["filter_s"] = time.perf_counter() - t1
    step(1)
    t2 = time.perf_counter()
    for stage in stages:
        p, s = stage.evaluate(ds, results[stage.name], designs[stage.name])
        per_scan.append(p.with_columns(pl.lit(stage.name).alias("stage")))
        summary.append(s.with_columns(pl.lit(stage.name).alias("stage")))
    timings["evaluate_s"] = time.perf_counter() - t2
    step(1)
    res = ReplayResult(ds, pl.concat(per_scan, how="diagonal"), pl.concat(summary, how="diagonal"), results,
                       timings=timings)
    if out_path is not None:
        t3 = time.perf_counter()
        meta = {METADATA_PROVENANCE: {"input": Path(ds.path).name, "package_version": __version__,
                                      "stages": ",".join(s.name for s in stages),
                                      "design": json.dumps(designs, sort_keys=True, default=str)}}
        if "replay.scenario" in ds.metadata:
            meta["replay.scenario"] = ds.metadata["replay.scenario"]
        with write_dataset(out_path, meta) as w:
            for stage in stages:
                stage.write(w, results[stage.name])
        res.out_path = Path(out_path)
        timings["write_s"] = time.perf_counter() - t3
    step(1)
    if rrd_path is not None:
        from pipeline.face.timeline import recording

        t4 = time.perf_counter()
        # One recording per file; with several stages the first stage's blueprint is the default.
        bp = stages[0].blueprint(list(results[stages[0].name]["tracks"]), ds, rerun_run)
        with recording(rrd_path, "trackreplay", Path(ds.path).stem, bp) as rec:
            for st in stages:
                part = res.per_scan.filter(pl.col("stage") == st.name)
                st.log_rerun(rec, ds, results[st.name], part, rerun_run)
        res.rrd_path = Path(rrd_path)
        timings["rerun_s"] = time.perf_counter() - t4
    step(1)
    timings["total_s"] = time.perf_counter() - t0
    return res


def evaluate_files(data_path, out_path=None, recover=False) -> ReplayResult:
    """Metrics of a data set: from a replay output file if given, else by replaying in memory."""
    if out_path is None:
        return replay(data_path, recover=recover)
    ds = read_dataset(data_path, recover=recover)
    out = read_dataset(out_path, recover=recover)
    stage = stage_for_outputs(out.channels)
    if stage is None:
        raise InputError("holds no tracker output channels (expected /tracks/...)", out_path)
    result = stage.outputs_from_dataset(out)
    # score with the design the replay used (including its --set overrides), not the file's
    used = json.loads(out.metadata.get(METADATA_PROVENANCE, {}).get("design", "{}")).get(stage.name)
    design = stage.design(ds, {k: v for k, v in (used or {}).items() if k in stage.design_keys})
    ds.cache[("design", stage.name)] = design
    p, s = stage.evaluate(ds, result, design)
    return ReplayResult(ds, p.with_columns(pl.lit(stage.name).alias("stage")),
                        s.with_columns(pl.lit(stage.name).alias("stage")), {stage.name: result})
