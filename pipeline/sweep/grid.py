"""The grid of a sweep: ``--param`` parsing, one validated :class:`PointTask` per point, and each
point's seed and label (the role "grid" of :mod:`trackreplay.sweep`)."""

from __future__ import annotations

import hashlib
import itertools
import json
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from trackreplay import __version__
from trackreplay.errors import InputError
from trackreplay.isolation import DEFAULT_TRACKER_TIME_LIMIT_S


@dataclass(frozen=True)
class PointTask:
    """Everything one grid point needs (picklable, no open resources)."""

    index: int
    label: str
    scenario: str
    overrides: tuple  # ((name, value), ...) in grid order
    runs: int
    seed: int
    trackers: tuple | None
    point_dir: str | None  # keep data/recordings here; None = metrics only
    tracker_specs: tuple = ()  # canonical specs of plugged trackers, loaded again on the worker
    design: tuple = ()  # ((name, value), ...): tracker design values that are not scenario parameters
    base_seed: int | None = None  # the sweep's --seed (``seed`` is the point's, derived from it)
    params: tuple = ()  # ((name, value), ...): every parameter of the point's scenario, resolved
    recorder: str = ""
    # seconds a plugged tracker may take on this point (pipeline/isolation.py); how long the
    # work may take, not what it computes, so not part of the point's record
    tracker_time_limit_s: float | None = DEFAULT_TRACKER_TIME_LIMIT_S

    def record(self) -> dict:
        """What this point computes, as JSON (``points/<label>/point.json``): a resumed sweep
        reuses a point's metrics only when its record is the same."""
        doc = {"version": __version__, "scenario": self.scenario, "recorder": self.recorder,
               "params": dict(self.params), "overrides": [list(kv) for kv in self.overrides],
               "design": [list(kv) for kv in self.design], "runs": self.runs,
               "base_seed": self.base_seed, "seed": self.seed,
               "trackers": list(self.trackers) if self.trackers else None,
               "tracker_specs": list(self.tracker_specs), "tracker_files": _spec_hashes(self.tracker_specs)}
        return json.loads(json.dumps(doc, default=str))


def _spec_hashes(specs) -> dict:
    """SHA-256 of the file of every file spec (an edited tracker file makes a new point)."""
    out = {}
    for spec in specs:
        target, sep, _ = spec.rpartition(":")
        if sep and (target.endswith(".py") or "/" in target) and Path(target).is_file():
            out[spec] = hashlib.sha256(Path(target).read_bytes()).hexdigest()
    return out


def point_seed(base_seed: int, overrides) -> int:
    """A 63-bit seed from the base seed and the point's parameter values (order-free)."""
    canon = json.dumps(sorted((k, v) for k, v in overrides), default=str).encode()
    ss = np.random.SeedSequence([int(base_seed) & 0xFFFFFFFF, zlib.crc32(canon)])
    return int(ss.generate_state(1, np.uint64)[0] >> np.uint64(1))


def _format_value(v) -> str:
    return f"{v:g}" if isinstance(v, float) else str(v)


def point_label(overrides) -> str:
    return ",".join(f"{k}={_format_value(v)}" for k, v in overrides)


def parse_param_specs(items) -> dict[str, list[str]]:
    """``["a=1,2", "b=x"]`` → ``{"a": ["1", "2"], "b": ["x"]}`` with clear errors."""
    specs: dict[str, list[str]] = {}
    for item in items or ():
        if "=" not in item:
            raise InputError(f"--param expects NAME=v1,v2,..., got {item!r}")
        name, values = item.split("=", 1)
        name = name.strip()
        vals = [v.strip() for v in values.split(",") if v.strip() != ""]
        if not vals:
            raise InputError(f"--param {name}: empty value list")
        if name in specs:
            raise InputError(f"--param {name} given twice")
        specs[name] = vals
    if not specs:
        raise InputError("a sweep needs at least one --param NAME=v1,v2,...")
    return specs


def build_grid(scenario_name: str, specs: dict, runs: int, seed: int, trackers=None,
               out_dir: Path | None = None, keep_data: bool = True, fixed: dict | None = None,
               tracker_specs=(), design_defaults: dict | None = None,
               tracker_time_limit_s: float | None = DEFAULT_TRACKER_TIME_LIMIT_S) -> list[PointTask]:
    """The grid's tasks, every point validated before anything runs.

    Parameters
    ----------
    fixed : dict, optional
        Parameters set the same at every point (``--set``).
    tracker_specs : sequence of str, optional
        Plugged trackers; made canonical (absolute paths) so any worker loads the same file.
    design_defaults : dict, optional
        Tracker design parameters (name → default) that are not scenario parameters, e.g. a
        plugged tracker's own ``params``: a swept or fixed name found here goes to the replay's
        design overrides instead of the scenario, and does not change the point's seed (every
        design value of a scenario point sees the same data).
    tracker_time_limit_s : float, optional
        Seconds a plugged tracker may take on a point before it is stopped (0 or None: no limit).
    """
    from trackreplay.registry import canonical_spec
    from trackreplay.recorders import recorder_module
    from trackreplay.recorders.scenarios import coerce, load_scenario

    scenario = load_scenario(scenario_name)
    design_defaults = {k: v for k, v in (design_defaults or {}).items() if k not in scenario.defaults}
    fixed = dict(fixed or {})
    fixed_design = {k: coerce(k, fixed.pop(k), design_defaults[k]) for k in list(fixed) if k in design_defaults}
    base = scenario.with_overrides(fixed)
    validate = recorder_module(base.recorder).validate
    if runs < 1:
        raise InputError("--runs must be ≥ 1")
    specs_canon = tuple(dict.fromkeys(canonical_spec(s) for s in tracker_specs))
    names = list(specs)
    tasks = []
    for index, combo in enumerate(itertools.product(*(specs[n] for n in names))):
        point = dict(zip(names, combo))
        design = {k: coerce(k, v, design_defaults[k]) for k, v in point.items() if k in design_defaults}
        sc = base.with_overrides({k: v for k, v in point.items() if k not in design})
        values = tuple((n, design[n] if n in design else sc.params[n]) for n in names)
        scenario_values = tuple((n, v) for n, v in values if n not in design)
        try:
            validate(sc.params)
        except InputError as exc:
            raise InputError(f"grid point {point_label(values)}: {exc}") from None
        label = point_label(values)
        point_dir = str(Path(out_dir) / "points" / label) if (out_dir is not None and keep_data) else None
        # Fixed settings first, swept values after: applying them in order gives the point.
        tasks.append(PointTask(index, label, scenario_name, tuple(fixed.items()) + scenario_values,
                               runs, point_seed(seed, scenario_values), tuple(trackers) if trackers else None,
                               point_dir, specs_canon, tuple({**fixed_design, **design}.items()),
                               int(seed), tuple(sorted(sc.params.items())), sc.recorder, tracker_time_limit_s))
    return tasks


def scenario_families(scenario_name: str, fixed: dict | None = None) -> set[str]:
    """Measurement families (:data:`trackreplay.vocabulary.FAMILIES`) a scenario's data set holds,
    from the channels of a one-run simulation (to refuse a plugged tracker of another family
    before a sweep starts)."""
    from trackreplay import vocabulary as vocab
    from trackreplay.recorders import simulator_for
    from trackreplay.recorders.scenarios import load_scenario

    sc = load_scenario(scenario_name).with_overrides(fixed or {})
    data = simulator_for(sc.recorder)(sc.params, 1, 0)
    topics = set(data.fixed) | set(data.ragged)
    return {f.name for f in vocab.FAMILIES.values() if all(t in topics for t in f.inputs)}
