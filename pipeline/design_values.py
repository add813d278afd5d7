"""A stage's design values for a data set: the replay's, else the file's record, else the defaults.

Design values are the numbers a replay is run with: the parameters of the stage itself
(:attr:`trackreplay.stages.base.Stage.design_keys`), of its trackers (their ``params``) and of the
evaluation (:attr:`trackreplay.stages.base.Stage.evaluation_defaults`: matching gate, OSPA/GOSPA
cut-off and order, …; ``docs/evaluation.md``, "Evaluation design values"). :func:`resolve` takes
them, in order of precedence, from ``--set``, the data set's scenario record, and the defaults
(the family's bundled scenario, then each tracker's own), and checks them once, each by its
:class:`~trackreplay.trackers.interface.Param` (:func:`check`). A tracker's own parameters are
checked again by their ``Param`` when it is constructed, so that a value one tracker refuses
stops that tracker alone (``docs/trackers.md``).

A recording (:func:`trackreplay.sensor_values.is_recording`) says what it knows about its
sensor; a sensor value it does not say is never the bundled scenario's: it is estimated from the
data where the family documents how, else None, *unknown* (``docs/importers.md``, "Sensor values:
what a recording says and what it does not").
"""

from __future__ import annotations

import math

from trackreplay.errors import InputError
from trackreplay.trackers.interface import Param

#: open bounds of the evaluation's design values other than (0, ∞): the OSPA/GOSPA order p ≥ 1
#: (Schuhmacher, Vo & Vo 2008, eq. 3; ``docs/evaluation.md``); every cut-off, gate and scale > 0
EVALUATION_BOUNDS = {"ospa_order": (0.999999, 100.0)}


def _recorded_value(key: str, raw, default):
    """A design value from a file's scenario record, parsed like ``--set`` and type-checked.

    JSON metadata may hold a string (``"5"``), ``null`` or ``true`` where a number belongs;
    :func:`trackreplay.recorders.scenarios.coerce` parses strings, this also refuses the non-strings that
    would fail later, far from the file.
    """
    from trackreplay.recorders.scenarios import coerce

    if isinstance(default, str) and isinstance(raw, str):
        return raw  # as recorded (an empty string may be meaningful, e.g. "use the preset")
    value = coerce(key, raw, default)
    numeric = isinstance(default, (int, float)) and not isinstance(default, bool)
    if value is None or (numeric and (isinstance(value, bool) or not isinstance(value, (int, float)))):
        raise InputError(f"parameter {key!r}: cannot read {raw!r} as {type(default).__name__}")
    return value


def _entries(stage, entries):
    return stage.entries() if entries is None else entries


def parameter_defaults(stage, entries=None) -> dict:
    """Design keys of ``stage`` and of ``entries`` (default: every tracker of its family) →
    default value: the bundled scenario's first, then the evaluation's, then each tracker's own."""
    from trackreplay.recorders.scenarios import load_scenario

    scenario = load_scenario(stage.scenario).params
    out = {k: scenario[k] for k in stage.design_keys}
    out.update({k: scenario.get(k, v) for k, v in stage.evaluation_defaults.items()})
    for e in _entries(stage, entries):
        for p in e.cls.params:
            if p.name not in out:
                out[p.name] = scenario[p.name] if p.name in scenario and p.default is None else p.default
                if out[p.name] is None:
                    raise InputError(f"tracker {e.name!r}: parameter {p.name!r} has no default and the "
                                     f"{stage.scenario} scenario does not define it")
    return out


def scenario_sourced_keys(stage, entries=None) -> set:
    """The design keys whose default is the bundled scenario's value (the stage's own keys, and
    the trackers' parameters without a default of their own), as opposed to a tracker's own
    documented default."""
    from trackreplay.recorders.scenarios import load_scenario

    scenario = load_scenario(stage.scenario).params
    keys = {k for k in stage.design_keys if k in scenario}
    for e in _entries(stage, entries):
        keys.update(p.name for p in e.cls.params if p.default is None and p.name in scenario)
    return keys


def stage_params(stage) -> dict:
    """Name → :class:`~trackreplay.trackers.interface.Param` of the design values ``stage``
    itself checks: its declared :attr:`~trackreplay.stages.base.Stage.params` and the
    evaluation's (cut-offs, gates and scales in (0, ∞), the order in :data:`EVALUATION_BOUNDS`)."""
    params = {p.name: p for p in stage.params}
    for key, default in stage.evaluation_defaults.items():
        low, high = EVALUATION_BOUNDS.get(key, (0.0, math.inf))
        params.setdefault(key, Param(key, default, low=low, high=high))
    return params


def check(stage, design: dict) -> None:
    """Refuse a design value that is not finite, or one of ``stage``'s own outside its bounds
    (:func:`stage_params`), with one line naming it (:class:`InputError`). Each value is checked
    by its :meth:`Param.check <trackreplay.trackers.interface.Param.check>`; an unknown value
    (None: a sensor value a recording does not say) is not refused here, the tracker that needs
    it stops (:func:`unknown_values`)."""
    params = stage_params(stage)
    for key, value in design.items():
        if value is None:
            continue
        try:
            params.get(key, Param(key, None)).check(value)
        except ValueError as exc:
            raise InputError(f"design value {exc}") from None


def design_notes(dataset, stage_name: str) -> list:
    """What :func:`resolve` chose for the user on ``dataset`` (e.g. a scan period estimated from
    the scan times), one sentence each."""
    return list(dataset.cache.get(("design_notes", stage_name), ()))


def unknown_values(entry, design: dict) -> list:
    """The parameters of ``entry``'s tracker whose value is unknown for this data set (None in
    ``design``: a sensor value the recording does not say)."""
    return [p.name for p in entry.cls.params if p.name in design and design[p.name] is None]


def resolve(stage, dataset, overrides: dict | None = None, entries=None) -> dict:
    """Design values of ``stage`` on ``dataset``: those of the replay in progress if there is
    one, else the file's scenario record, else the defaults (:func:`parameter_defaults`), then
    ``overrides`` (``--set``); then the evaluation values that follow from the data
    (:meth:`~trackreplay.stages.base.Stage.evaluation_defaults_from_data`), and :func:`check`.

    A recording (:func:`trackreplay.sensor_values.is_recording`) says what it knows about its
    sensor; a sensor value it does not say (its family's ``sensor_keys``) is
    never the bundled scenario's: it is estimated from the data where the family documents how
    (the family's ``estimable_keys``; the estimate is noted in :func:`design_notes`),
    else None, *unknown*, and a tracker that needs it stops with one line naming the ``--set``
    it needs (:func:`trackreplay.stage_running.run_units`)."""
    from trackreplay import sensor_values as sv
    from trackreplay import vocabulary as vocab
    from trackreplay.recorders.scenarios import coerce

    if not overrides and entries is None and ("design", stage.name) in dataset.cache:
        return dataset.cache[("design", stage.name)]

    defaults = parameter_defaults(stage, entries)
    recorded = dataset.scenario.get("params", {})
    unknowable = set()
    if sv.is_recording(dataset.scenario):
        unknowable = set(vocab.FAMILIES[stage.family].sensor_keys) & scenario_sourced_keys(stage, entries)
    out, notes = {}, []
    for k, default in defaults.items():
        try:
            out[k] = _recorded_value(k, recorded[k], default) if k in recorded else default
        except InputError as exc:  # the file's metadata, not the command line, is at fault
            raise InputError(f"scenario record: {exc.problem}", dataset.path) from None
        if k in unknowable and k not in recorded:
            how = sv.ESTIMATES.get(k) if k in vocab.FAMILIES[stage.family].estimable_keys else None
            # what an estimate reads: the scan times of the family's first input channel
            out[k] = None if how is None else sv.estimate(k, dataset.channel(stage.input_topics[0]).times())
            if out[k] is not None and k not in (overrides or {}):
                notes.append(f"{k} = {out[k]:g} estimated from {how} (the recording does not say it; "
                             f"--set {k}=VALUE gives it)")
    for k, v in (overrides or {}).items():
        if k not in defaults:
            raise InputError(f"unknown tracker parameter {k!r} (known: {', '.join(defaults)})")
        out[k] = coerce(k, v, defaults[k])
    # from the values in force, --set ones included (a recording's noise may come only from there)
    derived = stage.evaluation_defaults_from_data(dataset, out)
    out.update({k: v for k, v in derived.items() if k not in recorded and k not in (overrides or {})})
    try:
        check(stage, out)
    except InputError as exc:  # a value of the file's record or of --set: named with the file
        if exc.path is not None:
            raise
        raise InputError(exc.problem, dataset.path) from None
    dataset.cache[("design_notes", stage.name)] = notes
    return out
