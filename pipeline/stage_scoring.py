"""Scoring a stage's outputs: the family's own scores with their Monte Carlo intervals, the
standard measures and the track summary (``docs/evaluation.md``).

A stage (:class:`trackreplay.stages.base.Stage`) says what its scores need from the data set
(:meth:`~trackreplay.stages.base.Stage.reference`), scores outputs against it
(:meth:`~trackreplay.stages.base.Stage.score`) and names its truth space
(:meth:`~trackreplay.stages.base.Stage.standard_space`, ``standard_truth``); what is done with
those hooks is the same for every family and lives here: the grouped jackknife over runs
(:func:`trackreplay.evaluators.confidence.summary_intervals`), the standard measures
(:func:`trackreplay.evaluators.standard.evaluate_standard`), the track summary and the reasons of
the metrics without a value.
"""

from __future__ import annotations

import numpy as np

from trackreplay import vocabulary as vocab

#: metric and column names of bounds and of what is computed from them (docs/evaluation.md)
BOUND_PREFIXES, BOUND_SUFFIXES = ("crlb_", "pcrb_"), ("_efficiency",)


def model_recorded(dataset) -> bool:
    """Whether ``dataset`` records the model that generated it, so that a bound (the PCRB, the
    CRLB at the truth) and an efficiency can be computed: a simulation
    (:func:`trackreplay.sensor_values.is_simulation`), not a converted recording or a file without
    a scenario record, whose noise and motion no one knows."""
    from trackreplay.sensor_values import is_simulation

    return is_simulation(dataset.scenario)


def _is_bound(name: str) -> bool:
    return name.startswith(BOUND_PREFIXES) or name.endswith(BOUND_SUFFIXES)


def without_bounds(per_scan, summary):
    """``(per_scan, summary)`` without bounds and efficiencies: a recording has none."""
    import polars as pl

    if "metric" in summary.columns:
        metric = pl.col("metric")
        bound = pl.any_horizontal([metric.str.starts_with(p) for p in BOUND_PREFIXES] +
                                  [metric.str.ends_with(x) for x in BOUND_SUFFIXES])
        summary = summary.filter(~bound.fill_null(False))
    return per_scan.drop([c for c in per_scan.columns if _is_bound(c)]), summary


def has_truth(stage, dataset) -> bool:
    """Whether ``dataset`` holds the truth of ``stage``'s family (else only what needs no truth
    is scored: innovation consistency and the track summary)."""
    channel = vocab.FAMILIES[stage.family].truth
    return channel is None or channel in dataset.channels


def cached_reference(stage, dataset, design: dict) -> dict:
    """``stage``'s :meth:`~trackreplay.stages.base.Stage.reference`, computed once per data set
    and design (a replay scores its trackers one at a time, each against the same reference)."""
    return _cached(dataset, ("reference", stage.name), design, lambda: stage.reference(dataset, design))


def _cached(dataset, what: tuple, design: dict, compute):
    """``compute()``, kept in ``dataset.cache`` under ``what`` for as long as the design is the same."""
    import json

    key = json.dumps(design, sort_keys=True, default=str)
    cached = dataset.cache.get(what)
    if cached is None or cached[0] != key:
        cached = dataset.cache[what] = (key, compute())
    return cached[1]


def measure(stage, dataset, result: dict, design: dict):
    """Every metric with its Monte Carlo interval: the family's own scores (grouped jackknife
    over runs, :func:`trackreplay.evaluators.confidence.summary_intervals`) and the standard
    measures (:func:`trackreplay.evaluators.standard.evaluate_standard`) where the family has a
    truth space, and the track summary (:func:`trackreplay.evaluators.track_summary.track_summary`,
    kind ``standard``) for every family. Returns ``(per_scan, summary)``; summary columns
    ``tracker, metric, scope, value, se, ci_low, ci_high, kind``."""
    import polars as pl

    from trackreplay.evaluators.confidence import summary_intervals
    from trackreplay.evaluators.consistency import whitened_innovations
    from trackreplay.evaluators.missing_reasons import explain_missing
    from trackreplay.evaluators.standard import evaluate_standard, truth_one_identity_per_run
    from trackreplay.evaluators.track_summary import track_summary

    reference = cached_reference(stage, dataset, design)
    tracks = result["tracks"]
    n_runs = next(iter(o["state"] for o in tracks.values() if "state" in o)).shape[0]
    fixed = reference.get("fixed", {})

    def score(runs_data):
        sub = {**result, "tracks": runs_data["tracks"]}
        return stage.score({"runs": runs_data["reference"], "fixed": fixed}, sub, design)

    def score_groups(runs_data, groups, left_out):
        sub = {**result, "tracks": runs_data["tracks"]}
        return stage.score_groups({"runs": runs_data["reference"], "fixed": fixed}, sub, design, groups, left_out)

    per_scan, summary = summary_intervals(score, {"tracks": tracks, "reference": reference["runs"]}, n_runs,
                                          groups=10, score_groups=score_groups)
    tracks = {n: o for n, o in result["tracks"].items() if "state" in o and "flags" in o}
    # whitened once, read by the standard measures and the track summary
    innovations = {n: whitened_innovations(o) for n, o in tracks.items()}
    # the track summary reads the flags and innovations alone: every family has it, truth or not
    lives = track_summary(result["times"], tracks, innovations=innovations).with_columns(kind=pl.lit("standard"))
    if not model_recorded(dataset):
        per_scan, summary = without_bounds(per_scan, summary)
    space = stage.standard_space(design, reference)
    if space is None:
        family = summary if "kind" in summary.columns else summary.with_columns(kind=pl.lit("family"))
        # every metric without a value says why (trackreplay.evaluators.missing_reasons)
        return per_scan, explain_missing(pl.concat([family, lives], how="diagonal_relaxed"), result["tracks"],
                                         innovations)
    truth = stage.standard_truth(reference)
    truth_ids = stage.standard_truth_ids(reference) if truth is not None else None
    # whether the truth is one target a run: the same for every tracker, found once per data set
    truth_single = None if truth is None else _cached(
        dataset, ("standard_truth_single", stage.name), design,
        lambda: truth_one_identity_per_run(truth, space, truth_ids))
    std_scan, std_summary = evaluate_standard(result["times"], tracks, truth, space, innovations=innovations,
                                              truth_ids=truth_ids, truth_single=truth_single)
    if std_scan.height and per_scan.height and "scan" in per_scan.columns:
        extra = [c for c in std_scan.columns if c not in per_scan.columns or c in ("tracker", "scan")]
        per_scan = per_scan.join(std_scan.select(extra), on=["tracker", "scan"], how="left")
    elif std_scan.height and not per_scan.height:
        # no tracker the family's own measures apply to (multi-target trackers): the standard
        # per-scan measures are the table
        per_scan = std_scan
    return per_scan, explain_missing(pl.concat([summary.with_columns(kind=pl.lit("family")),
                                                std_summary.with_columns(kind=pl.lit("standard")), lives],
                                               how="diagonal_relaxed"), result["tracks"], innovations,
                                     list(space.truth_components), truthless=truth is None)


def life_tables(stage, dataset, result: dict, design: dict):
    """``(targets, tracks)`` tables of :mod:`trackreplay.evaluators.life_tables` for the trackers
    of ``result`` (first runs only), or None where the family has no truth space or the data set
    no truth."""
    from trackreplay.evaluators.consistency import whitened_innovations
    from trackreplay.evaluators.life_tables import LIFE_TABLE_RUNS, tables_for

    reference = cached_reference(stage, dataset, design)
    space = stage.standard_space(design, reference)
    truth = stage.standard_truth(reference) if space is not None else None
    if truth is None:
        return None
    # the first runs only, sliced before anything is computed on them
    first = slice(0, LIFE_TABLE_RUNS)
    tracks = {n: {k: (v[first] if isinstance(v, np.ndarray) and v.ndim else v) for k, v in o.items()}
              for n, o in result["tracks"].items() if "state" in o and "flags" in o}
    innovations = {n: whitened_innovations(o) for n, o in tracks.items()}
    ids = stage.standard_truth_ids(reference)
    return tables_for(result["times"], tracks, np.asarray(truth)[first], None if ids is None else ids[first],
                      space, innovations)
