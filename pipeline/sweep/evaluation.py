"""The evaluation design values of a sweep (the matching gate, the GOSPA cut-off and order, HOTA's
distance scale, the SIAP gate): which a scenario's stages declare, their checks, what each point
was scored with and the sweep's summary of them."""

from __future__ import annotations

import json


#: key of the Parquet metadata (sweep.parquet, a point's metrics.parquet) holding the evaluation
#: design values the metrics were scored with, as JSON
EVALUATION_METADATA = "replay.evaluation"


def evaluation_used(res) -> dict:
    """Stage name → the evaluation design values a replay's scores used (defaults, the data
    set's scenario record and ``--set``, as :meth:`Stage.design` resolved them)."""
    from trackreplay.stages import stage_named

    out = {}
    for name in res.results:
        design = res.dataset.cache.get(("design", name), {})
        out[name] = {k: design[k] for k in stage_named(name).evaluation_defaults if k in design}
    return json.loads(json.dumps(out, default=str))


def evaluation_defaults_of(families) -> dict:
    """Evaluation design value → default of the stages of ``families`` (measurement families):
    what ``--set`` may change in a sweep of a scenario that records them."""
    from trackreplay.stages import STAGES

    out = {}
    for stage in STAGES:
        if stage.family in families:
            out.update({k: v for k, v in stage.evaluation_defaults.items() if k not in out})
    return out


def check_evaluation_values(values: dict) -> None:
    """Refuse, before any work, an evaluation design value out of its range (name → raw values,
    checked by every stage that declares the name; other names are left alone).

    Raises
    ------
    InputError
        One line naming the value.
    """
    from trackreplay.stages import STAGES
    from trackreplay.recorders.scenarios import coerce

    for stage in STAGES:
        for name, raws in values.items():
            if name in stage.evaluation_defaults:
                for raw in raws:
                    stage.check_design({name: coerce(name, raw, stage.evaluation_defaults[name])})


def evaluation_summary(per_point: dict) -> dict:
    """Stage name → evaluation value → its value at every point, or ``{point label: value}``
    where the points differ (a swept value, or a default the data sets adapt)."""
    out: dict = {}
    for label, stages in per_point.items():
        for stage, values in (stages or {}).items():
            for name, value in values.items():
                out.setdefault(stage, {}).setdefault(name, {})[label] = value
    return {stage: {name: (next(iter(by.values())) if len(set(map(json.dumps, by.values()))) == 1 and
                           len(by) == len(per_point) else by)
                    for name, by in values.items()} for stage, values in out.items()}
