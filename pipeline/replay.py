"""Replay orchestration: file in → stages → outputs MCAP, Rerun recording, metrics tables.

This is bookkeeping only: it finds the stages that apply, hands them the decoded channels,
writes what they return and collects their tables. The outputs file's provenance and its writer
are in :mod:`trackreplay.replay_outputs`.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import polars as pl

from trackreplay import design_values, stack_threads, stage_running, stage_scoring
from trackreplay.contract import METADATA_PROVENANCE, Dataset, read_dataset
from trackreplay.errors import InputError
from trackreplay.isolation import DEFAULT_TRACKER_TIME_LIMIT_S
from trackreplay.replay_outputs import OutputWriter, dataset_identity, output_provenance
from trackreplay.stages import applicable_stages, stage_for_outputs


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
    failures: list = field(default_factory=list)  # TrackerErrors of trackers left out
    targets: pl.DataFrame | None = None      # one row per true target and tracker (trackreplay.evaluators.life_tables)
    track_lives: pl.DataFrame | None = None  # one row per track


def select_trackers(stages, names=None, specs=(), dataset=None,
                    time_limit_s: float | None = DEFAULT_TRACKER_TIME_LIMIT_S) -> dict:
    """Stage name → the tracker entries to run: every built-in and plugged (``specs``) tracker
    of the stage's family, or the ones ``names`` selects.

    Without ``names``, a built-in tracker runs when it is made for the data set's kind of
    scene (``Tracker.targets``): the multi-target ones where :meth:`Stage.holds_many_targets`
    says ``dataset`` holds many targets, the single-target ones (the papers') elsewhere; a
    variant that does not run by default (``Tracker.runs_by_default``) runs when named.
    Plugged trackers always run; ``names`` picks any. A plugged file or module not yet imported
    is tried in a child process first, stopped at ``time_limit_s``
    (:func:`trackreplay.registry.load_spec`).

    Raises
    ------
    InputError
        A name no applicable stage has, or a plugged tracker of a family the file does not hold.
    """
    from trackreplay.registry import available_trackers, trackers_of_family

    families = {s.family for s in stages}
    if specs:  # every tracker, so that a plugged one's name clash with any other is refused
        table = available_trackers(specs, time_limit_s)
    else:  # only the families in the file: their numerics alone are imported
        table = {e.name: e for family in sorted(families)
                 for e in trackers_of_family(family, time_limit_s=time_limit_s)}
    plugged = {name for name, e in table.items() if e.source in specs}
    for name in plugged:
        if table[name].family not in families:
            raise InputError(f"tracker {name!r} consumes {table[name].family} measurements; this file holds "
                             f"{', '.join(sorted(families))}")
    chosen = {}
    for stage in stages:
        scene = "many" if dataset is not None and stage.holds_many_targets(dataset) else "one"
        # the --tracker ones always; by default the built-ins for this scene; installed
        # (entry-point) ones by name
        chosen[stage.name] = [e for e in table.values() if e.family == stage.family and
                              (e.name in plugged or (e.name in names if names else
                                                     e.builtin and getattr(e.cls, "targets", "one") == scene
                                                     and getattr(e.cls, "runs_by_default", True)))]
    if names:
        have = {e.name for pool in chosen.values() for e in pool}
        unknown = [n for n in names if n not in have]
        if unknown:
            known = sorted({x.name for s in stages for x in table.values() if x.family == s.family})
            raise InputError(f"unknown tracker(s) {', '.join(unknown)} for this file (have: {', '.join(known)})")
    return chosen


def replay(path, trackers=None, out_path=None, rrd_path=None, recover=False, design_overrides=None,
           rerun_run: int = 0, dataset: Dataset | None = None, progress=None, tracker_specs=(),
           keep_runs: int | None = None, recorder=None,
           tracker_time_limit_s: float | None = DEFAULT_TRACKER_TIME_LIMIT_S) -> ReplayResult:
    """Replay every applicable stage over a data set.

    Trackers go through in scoring units (:func:`trackreplay.stage_running.run_units`): once
    the outputs gathered reach 64 MiB they are written (a large unit on a thread of its own,
    while the same outputs are scored), scored and released before the next tracker runs, so
    that on many runs the memory a replay needs grows with one tracker's outputs, not with all
    of them (``docs/architecture.md``, ``docs/benchmarks.md``).

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
        ``progress(1)`` after the Rerun recording, and ``progress(1, seconds, note)`` for each of
        filter, evaluate and write (which run interleaved, tracker by tracker) with its time and
        a note saying when writing ran beside the scoring
        (:meth:`trackreplay.face.progress.Phases.step`).
    tracker_specs : sequence of str
        Plugged trackers (``file.py:Class`` or ``module:Class``) to run beside the built-ins.
    keep_runs : int, optional
        Keep only the first ``keep_runs`` runs of each tracker's outputs in the result once they
        are written and scored (what the per-run views and figures read); None keeps them all.
        A stage whose views read every run (:attr:`~trackreplay.stages.base.Stage.views_read_all_runs`)
        keeps them all regardless.
    recorder : callable, optional
        What writes the Rerun recording, called as ``recorder(rrd_path, dataset, stages,
        results, per_scan, rerun_run)`` once everything is scored, returning when the recording
        is written (or raising :class:`InputError`): by default
        :func:`trackreplay.face.rerun_views.write_recording`, in this process; the command line
        may pass a :class:`trackreplay.face.recording_process.RecordingProcess` instead.
    tracker_time_limit_s : float, optional
        Seconds a plugged tracker may take (its construction and ``track()``, and the first
        import of its file) before it is stopped and reported as failed; 0 or None: no limit.
        Plugged trackers run in a child process, so one that ends its process or hangs is
        that tracker's failure (:mod:`trackreplay.isolation`); built-in trackers run here, unlimited.

    Raises
    ------
    InputError
        Bad input; also, after every output is written, a plugged or built-in tracker that
        failed (its message names the tracker, the run and the scan).
    """
    step = progress or (lambda n, seconds=None, note=None: None)
    stack_threads.install()  # a replay shares large stacks of EVDs among the cores (the same bits)
    t0 = time.perf_counter()
    ds = dataset if dataset is not None else read_dataset(path, recover=recover)
    timings = {"read_s": time.perf_counter() - t0, "filter_s": 0.0, "evaluate_s": 0.0}
    stages = applicable_stages(ds.channels)
    if not stages:
        have = ", ".join(sorted(ds.channels)) or "none"
        raise InputError(f"no stage applies to the channels in this file ({have})", ds.path)
    chosen = select_trackers(stages, trackers, tracker_specs, ds, tracker_time_limit_s)
    designs = {}
    for stage in stages:
        design = design_values.resolve(stage, ds, design_overrides, chosen[stage.name])
        # later resolutions on ds (Rerun logging, figures) see the values this run used
        ds.cache[("design", stage.name)] = design
        designs[stage.name] = design
    results, per_scan, summary, failures, life_parts = {}, [], [], [], []
    with OutputWriter(out_path, lambda n_runs: output_provenance(ds, n_runs, stages, designs, tracker_specs)) as writer:
        for stage in stages:
            design = designs[stage.name]
            tables = []
            t1 = time.perf_counter()
            times, units = stage_running.run_units(stage, ds, chosen[stage.name], design, tracker_time_limit_s)
            result = results[stage.name] = {"times": times, "tracks": {}}
            extras = {}
            for own, unit, errors in units:
                failures += errors
                timings["filter_s"] += time.perf_counter() - t1
                if own:
                    # the outputs are written while they are scored; the stage's extras, scored
                    # with every unit, are written once, after the trackers
                    writer.write(stage, {"times": times, "tracks": {name: unit[name] for name in own}})
                    t2 = time.perf_counter()
                    scored, p, s, errors = measure_isolated(stage, ds, times, unit, own, design)
                    failures += errors
                    if scored:
                        tables.append((scored, p, s))
                        # (no name of its own: it would hold this unit's outputs through the next one)
                        lives = stage_scoring.life_tables(
                            stage, ds, {"times": times, "tracks": {n: unit[n] for n in scored}}, design)
                        if lives is not None:
                            life_parts.append(lives)
                    timings["evaluate_s"] += time.perf_counter() - t2
                    writer.wait()
                    keep = None if stage.views_read_all_runs else keep_runs
                    result["tracks"].update({name: _first_runs(unit[name], keep) for name in scored})
                    extras = {name: out for name, out in unit.items() if name not in own}
                # let go of this unit's outputs before the next one is filtered: the loop variable
                # would hold them alive until the generator yields again (a second tracker's worth
                # of memory at the peak, 170 MB at 10,000 radar runs)
                del unit
                t1 = time.perf_counter()
            if extras:
                writer.write(stage, {"times": times, "tracks": extras})
                writer.wait()
                keep = None if stage.views_read_all_runs else keep_runs
                result["tracks"].update({name: _first_runs(out, keep) for name, out in extras.items()})
            if not result["tracks"]:
                raise failures[0] if failures else InputError(f"no tracker ran on {stage.name}", ds.path)
            p, s = _joined_tables(tables)
            per_scan.append(p.with_columns(pl.lit(stage.name).alias("stage")))
            summary.append(s.with_columns(pl.lit(stage.name).alias("stage")))
    timings["write_s"] = writer.seconds
    timings["write_beside_s"] = writer.seconds_beside  # of write_s, on the thread while evaluate ran
    for phase in ("filter_s", "evaluate_s", "write_s"):  # they ran interleaved, tracker by tracker
        step(1, timings[phase], "beside evaluate" if phase == "write_s" and writer.seconds_beside else None)
    res = ReplayResult(ds, pl.concat(per_scan, how="diagonal"), pl.concat(summary, how="diagonal"), results,
                       timings=timings)
    if life_parts:
        res.targets = pl.concat([t for t, _ in life_parts])
        res.track_lives = pl.concat([t for _, t in life_parts])
    if out_path is not None:
        res.out_path = Path(out_path)
    if rrd_path is not None:
        if recorder is None:
            from trackreplay.face.rerun_views import write_recording as recorder

        t4 = time.perf_counter()
        recorder(rrd_path, ds, stages, results, res.per_scan, rerun_run)
        res.rrd_path = Path(rrd_path)
        timings["rerun_s"] = time.perf_counter() - t4
    step(1)
    timings["total_s"] = time.perf_counter() - t0
    res.failures = failures
    return res


def measure_isolated(stage, ds, times, unit: dict, own, design: dict):
    """:func:`trackreplay.stage_scoring.measure` of a unit of trackers, one tracker's failure kept to
    that tracker.

    A tracker whose outputs pass :func:`~trackreplay.trackers.interface.validate_outputs` may still
    hold something a measure cannot score (a plugged tracker's layout no evaluator foresaw).
    When the unit fails as a whole, each tracker is scored alone; the ones that still fail get
    one :class:`~trackreplay.trackers.interface.TrackerError` each and the others are kept.

    Returns
    -------
    scored : list of str
        Trackers of ``own`` whose scores are in the tables.
    per_scan, summary : polars.DataFrame or None
    errors : list of TrackerError
    """
    from trackreplay.trackers.interface import TrackerError

    try:
        p, s = stage_scoring.measure(stage, ds, {"times": times, "tracks": unit}, design)
        return list(own), p, s, []
    except TrackerError:
        pass
    except InputError:
        raise  # the data set or the design, not a tracker, is at fault: every tracker would fail
    except Exception:  # noqa: BLE001 - narrowed to the tracker at fault below
        pass
    extras = {name: out for name, out in unit.items() if name not in own}
    scored, parts, errors = [], [], []
    for name in own:
        try:
            parts.append(stage_scoring.measure(stage, ds, {"times": times, "tracks": {name: unit[name], **extras}},
                                               design))
            scored.append(name)
        except Exception as exc:  # noqa: BLE001 - this tracker's failure, reported as one line
            errors.append(TrackerError(f"tracker {name!r}: its outputs could not be scored: {type(exc).__name__}: "
                                       f"{exc}", name))
    if not scored:
        return [], None, None, errors
    if len(parts) == 1:
        return scored, parts[0][0], parts[0][1], errors
    p, s = _joined_tables([([n], p, s) for n, (p, s) in zip(scored, parts)])
    return scored, p, s, errors


def _first_runs(outputs: dict, keep: int | None) -> dict:
    """``outputs`` cut (copied) to their first ``keep`` runs, so the rest can be freed."""
    if keep is None:
        return outputs
    return {k: np.array(a[:keep]) if isinstance(a, np.ndarray) and a.ndim else a for k, a in outputs.items()}


def _joined_tables(tables):
    """One stage's ``(per_scan, summary)`` from the tables of its scoring units.

    Each unit's tables hold its own trackers' rows and the rows of the stage's extras (its own
    estimators, scored beside every unit, identically); the extras' rows are taken once, from
    the first unit. Summary rows are ordered metric by metric as the first unit lists them,
    trackers in the order they ran within a metric; per-scan rows tracker by tracker.
    """
    def mine(df, names, keep):
        if "tracker" not in df.columns:
            return df if keep else df.clear()
        inside = pl.col("tracker").is_in(names)
        return df.filter(inside if keep else ~inside)

    first_names, first_scan, first_summary = tables[0]
    if len(tables) == 1:  # every tracker in one unit: its tables are the stage's
        return first_scan, first_summary
    per_scan = pl.concat([mine(p, names, True) for names, p, _ in tables] + [mine(first_scan, first_names, False)],
                         how="diagonal_relaxed")
    columns = list(first_scan.columns) + [c for c in per_scan.columns if c not in first_scan.columns]
    summary = pl.concat([mine(s, names, True) for names, _, s in tables] + [mine(first_summary, first_names, False)],
                        how="diagonal_relaxed")
    if len(tables) > 1 and summary.height and {"tracker", "metric"} <= set(summary.columns):
        key = [c for c in ("kind", "metric", "scope") if c in summary.columns]
        order = (pl.concat([first_summary.select(key), summary.select(key)], how="diagonal_relaxed")
                 .unique(maintain_order=True).with_row_index("_key"))
        trackers = pl.DataFrame({"tracker": list(dict.fromkeys(summary["tracker"].to_list()))}).with_row_index("_who")
        summary = (summary.join(order, on=key, how="left", nulls_equal=True).join(trackers, on="tracker", how="left",
                                                                               nulls_equal=True)
                   .sort(["_key", "_who"], maintain_order=True).drop("_key", "_who"))
    return per_scan.select(columns), summary


def _outputs_of(ds, out_path, recover=False):
    """The stage and trackers' outputs of a replay output file made from ``ds``.

    Raises
    ------
    InputError
        The file holds no tracker outputs, or its provenance says it was made from another data
        set (a different content hash, or another run count).
    """
    out = read_dataset(out_path, recover=recover)
    stage = stage_for_outputs(out.channels)
    if stage is None:
        raise InputError("holds no tracker output channels (expected /tracks/...)", out_path)
    provenance = out.metadata.get(METADATA_PROVENANCE, {})
    try:  # the design each stage used, read again by _used_design: a JSON object of objects
        design = json.loads(provenance.get("design", "{}"))
    except (ValueError, RecursionError):  # (RecursionError: JSON nested deeper than the parser recurses)
        design = None
    if not isinstance(design, dict) or not all(isinstance(v, dict) for v in design.values()):
        raise InputError(f"{METADATA_PROVENANCE} metadata: 'design' is not a JSON object of design values", out_path)
    made_from = provenance.get("input_sha256", "")
    identity = dataset_identity(ds)
    if made_from and identity and made_from != identity:
        raise InputError(f"these outputs were made from another data set ({provenance.get('input', '?')}, "
                         f"sha256 {made_from[:12]}…), not {Path(ds.path).name} (sha256 {identity[:12]}…)", out_path)
    result = stage_running.read_outputs(stage, out)
    if not all(t in ds.channels for t in stage.input_topics):
        raise InputError(f"these are {stage.name} outputs but {Path(ds.path).name} holds no {stage.name} input "
                         "channels", out_path)
    return stage, result, provenance


def evaluate_files(data_path, out_path=None, recover=False, tracker_specs=(), evaluation_overrides=None) -> ReplayResult:
    """Metrics of a data set: from a replay output file if given, else by replaying in memory
    (with the plugged trackers ``tracker_specs`` beside the built-ins; their failures are in
    the result's ``failures``). ``evaluation_overrides`` change the evaluation's own design
    values (``Stage.evaluation_defaults``: matching gate, GOSPA cut-off and order, …); a
    tracker's design value is refused for an output file, whose trackers already ran."""
    if out_path is None:
        return replay(data_path, recover=recover, tracker_specs=tracker_specs, design_overrides=evaluation_overrides)
    if tracker_specs:
        raise InputError("--tracker applies when eval replays in memory; an output file's trackers already ran")
    ds = read_dataset(data_path, recover=recover)
    stage, result, provenance = _outputs_of(ds, out_path, recover)
    design = _used_design(stage, ds, provenance)
    if evaluation_overrides:
        from trackreplay.recorders.scenarios import coerce

        allowed = stage.evaluation_defaults
        for key, value in evaluation_overrides.items():
            if key not in allowed:
                raise InputError(f"--set {key}: with an output file only the evaluation's design values change "
                                 f"({', '.join(allowed)}); replay again to change a tracker's")
            design = {**design, key: coerce(key, value, allowed[key])}
        design_values.check(stage, design)
    p, s = stage_scoring.measure(stage, ds, result, design)
    return ReplayResult(ds, p.with_columns(pl.lit(stage.name).alias("stage")),
                        s.with_columns(pl.lit(stage.name).alias("stage")), {stage.name: result})


def replay_of_files(data_path, out_path, recover: bool = False) -> ReplayResult:
    """A finished replay rebuilt from its files, for drawing its figures: the data set, the
    trackers' outputs and the per-scan table written beside them (``per_scan.parquet``; the
    metrics are computed again only when it is missing). The summary is left empty."""
    ds = read_dataset(data_path, recover=recover)
    stage, result, provenance = _outputs_of(ds, out_path, recover)
    design = _used_design(stage, ds, provenance)  # the figures see the design the replay used
    table = Path(out_path).parent / "per_scan.parquet"
    if table.is_file():
        per_scan = pl.read_parquet(table)
    else:
        per_scan, _ = stage_scoring.measure(stage, ds, result, design)
        per_scan = per_scan.with_columns(pl.lit(stage.name).alias("stage"))
    return ReplayResult(ds, per_scan, pl.DataFrame(), {stage.name: result})


def _used_design(stage, ds, provenance) -> dict:
    """The design a replay used (its --set overrides included), from its outputs' provenance."""
    used = json.loads(provenance.get("design", "{}")).get(stage.name)
    design = design_values.resolve(stage, ds, {k: v for k, v in (used or {}).items()
                               if k in stage.design_keys or k in stage.evaluation_defaults})
    ds.cache[("design", stage.name)] = design
    return design


@dataclass
class Comparison:
    """What ``replay compare`` found: the paired table and what the views need."""

    table: pl.DataFrame
    stage: object
    dataset: Dataset
    result_a: dict
    result_b: dict
    pairs: list
    #: the evaluation design values both sides were scored with (name → value), and the names
    #: of those ``--set`` changed
    evaluation: dict = field(default_factory=dict)
    evaluation_set: tuple = ()


def evaluation_catalogue(stages=None) -> dict:
    """Stage name → its evaluation design values (name → default, :attr:`Stage.evaluation_defaults`):
    the values ``--set`` changes on ``replay compare``, ``check`` and ``sweep``."""
    if stages is None:
        from trackreplay.stages import STAGES as stages
    return {s.name: dict(s.evaluation_defaults) for s in stages}


def format_evaluation_values(values: dict) -> str:
    """``name=value, ...`` of some evaluation design values (numbers in their shortest form)."""
    return ", ".join(f"{k}={v:g}" if isinstance(v, float) else f"{k}={v}" for k, v in values.items())


def evaluation_overrides(stage, overrides: dict | None, command: str) -> dict:
    """``overrides`` (name → text or number) as ``stage``'s evaluation design values: parsed to
    the type of their defaults and checked against their ranges.

    Raises
    ------
    InputError
        One line: a name that is a tracker's design value (the trackers already ran: replay
        again) or no design value at all, listing the stage's evaluation values; or a value
        out of its range.
    """
    from trackreplay.recorders.scenarios import coerce

    allowed = stage.evaluation_defaults
    known = ", ".join(allowed)
    out = {}
    for key, value in (overrides or {}).items():
        if key not in allowed:
            try:
                tracker_value = key in design_values.parameter_defaults(stage)
            except InputError:
                tracker_value = False
            if tracker_value:
                raise InputError(f"--set {key}: {command} scores output files whose trackers already ran, so only "
                                 f"the evaluation's design values change (of {stage.name}: {known}); replay "
                                 "again to change a tracker's")
            raise InputError(f"--set {key}: not an evaluation design value of {stage.name} (known: {known})")
        out[key] = coerce(key, value, allowed[key])
    design_values.check(stage, out)
    return out


def compare_files(a_path, b_path, data_path=None, pairs=None, recover=False, evaluation=None) -> Comparison:
    """Paired comparison of two replay outputs of the same data set (see :mod:`trackreplay.evaluators.compare`).

    Parameters
    ----------
    a_path, b_path : path
        Replay outputs (``tracks.mcap``).
    data_path : path, optional
        The data set; by default the file named in A's provenance, looked up beside A, in the
        current folder and among the bundled data sets.
    pairs : list of (str, str), optional
        Trackers of A and B to compare (default: the names they share, or their only trackers).
    evaluation : dict, optional
        Evaluation design values (``--set``: matching gate, GOSPA cut-off and order, …) both
        sides are scored with, over those recorded in A's provenance; a tracker's design value
        is refused (:func:`evaluation_overrides`), since both replays already ran.
    """
    from trackreplay.evaluators.compare import pair_trackers, paired_differences

    if data_path is None:
        data_path = _find_input(a_path, recover)
    ds = read_dataset(data_path, recover=recover)
    stage_a, result_a, prov_a = _outputs_of(ds, a_path, recover)
    stage_b, result_b, _ = _outputs_of(ds, b_path, recover)
    if stage_a.name != stage_b.name:
        raise InputError(f"A holds {stage_a.name} outputs, B {stage_b.name} outputs: nothing to compare", b_path)
    design = _used_design(stage_a, ds, prov_a)
    changed = evaluation_overrides(stage_a, evaluation, "compare")
    if changed:
        design = {**design, **changed}
        design_values.check(stage_a, design)
        ds.cache[("design", stage_a.name)] = design  # the views see the values the scores used
    tracked = lambda r: [n for n, o in r["tracks"].items() if "state" in o]
    try:
        pairs = pair_trackers(tracked(result_a), tracked(result_b), pairs)
    except ValueError as exc:
        raise InputError(str(exc), b_path) from None
    runs_a = next(o["state"].shape[0] for o in result_a["tracks"].values() if "state" in o)
    runs_b = next(o["state"].shape[0] for o in result_b["tracks"].values() if "state" in o)
    if runs_a != runs_b:
        raise InputError(f"A holds {runs_a} runs, B {runs_b}: not replays of the same data set", b_path)
    reference = stage_a.reference(ds, design)
    fixed = reference.get("fixed", {})

    space = stage_a.standard_space(design, reference)

    def score(tracks, reference_runs):
        """The family's own measures and the standard ones (which every tracker has, a
        multi-target or plugged multi-slot one included) of one replay's trackers."""
        from trackreplay.evaluators.standard import evaluate_standard

        result = {"times": result_a["times"], "tracks": tracks}
        ref = {"runs": reference_runs, "fixed": fixed}
        per_scan, summary = stage_a.score(ref, result, design)
        truth = stage_a.standard_truth(ref) if space is not None else None
        if truth is None:
            return per_scan, summary
        truth_ids = stage_a.standard_truth_ids(ref)
        trackers = {n: o for n, o in tracks.items() if "state" in o and "flags" in o}
        _, standard = evaluate_standard(result_a["times"], trackers, truth, space, truth_ids=truth_ids)
        standard = standard.with_columns(scope=pl.lit("standard measures"))
        return per_scan, pl.concat([summary, standard.select(summary.columns)], how="diagonal_relaxed")

    table = paired_differences(score, result_a["tracks"], result_b["tracks"], reference["runs"], runs_a, pairs)
    used = {k: design[k] for k in stage_a.evaluation_defaults if k in design}
    return Comparison(table, stage_a, ds, result_a, result_b, pairs, used, tuple(changed))


def _installed_data() -> Path:
    from importlib.resources import files

    return Path(str(files("replay_data")))


def _find_input(out_path, recover=False) -> Path:
    out = read_dataset(out_path, recover=recover)
    name = out.metadata.get(METADATA_PROVENANCE, {}).get("input")
    if not name:
        raise InputError("records no input data set; give it with --data", out_path)
    for folder in (Path(out_path).resolve().parent, Path.cwd(), Path.cwd() / "data", _installed_data()):
        if (folder / name).is_file():
            return folder / name
    raise InputError(f"was made from {name}, which is not beside it, in the current folder or among the bundled "
                     "data sets; give it with --data", out_path)
