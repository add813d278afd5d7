"""What every stage processor shares: naming, output channels and reading them back.

A stage consumes the channels it understands and returns its trackers' outputs as arrays with a
leading run axis; this base class writes them, one message per scan holding every run, on ``<output_prefix><tracker>``
and rebuilds them from a replay output file, so ``replay eval data.mcap out.mcap`` works for
every stage without stage-specific I/O. Subclasses implement :meth:`decode`, :meth:`reference`
and :meth:`score` (and optionally :meth:`extras`, :meth:`standard_space`, :meth:`report`) and set
the class attributes; their Rerun views live in the face (:mod:`trackreplay.face.rerun_views`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from trackreplay import vocabulary as vocab
from trackreplay.errors import InputError
from trackreplay.isolation import DEFAULT_TRACKER_TIME_LIMIT_S, run_plugged_tracker
from trackreplay.trackers.interface import TrackerError, call_tracker


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


def design_notes(dataset, stage_name: str) -> list:
    """What :meth:`Stage.design` chose for the user on ``dataset`` (e.g. a scan period
    estimated from the scan times), one sentence each."""
    return list(dataset.cache.get(("design_notes", stage_name), ()))


def model_recorded(dataset) -> bool:
    """Whether ``dataset`` records the model that generated it, so that a bound (the PCRB, the
    CRLB at the truth) and an efficiency can be computed: a simulation
    (:func:`trackreplay.sensor_values.is_simulation`), not a converted recording or a file without
    a scenario record, whose noise and motion no one knows."""
    from trackreplay.sensor_values import is_simulation

    return is_simulation(dataset.scenario)


#: metric and column names of bounds and of what is computed from them (docs/evaluation.md)
BOUND_PREFIXES, BOUND_SUFFIXES = ("crlb_", "pcrb_"), ("_efficiency",)


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


#: a replay scores and releases trackers' outputs once they hold this many bytes (see
#: :meth:`Stage.run_units`): the memory it needs is bounded by about one tracker's outputs
SCORING_UNIT_BYTES = 64 << 20


def outputs_nbytes(tracks: dict) -> int:
    """Bytes of the arrays of ``{tracker: outputs}``."""
    return sum(np.asarray(a).nbytes for out in tracks.values() for a in out.values())


class Stage:
    """Base class of stage processors: one per measurement family.

    A stage decodes its family's channels into the family's measurement object
    (:mod:`trackreplay.trackers.interface`), calls every selected tracker through the one tracker
    interface, and scores the outputs with its evaluator. It holds no numerics of its own.

    Class attributes
    ----------------
    name : str
        Stage name.
    family : str
        The measurement family (a key of :data:`trackreplay.vocabulary.FAMILIES`); it fixes the
        input channels and the output channel prefix.
    scenario : str
        Bundled scenario whose parameters give the design defaults (the family's, declared in
        :data:`trackreplay.vocabulary.FAMILIES`).
    design_keys : tuple of str
        Scenario parameters the stage itself uses (decoding, evaluation); each tracker's
        ``params`` add to them.
    """

    name = ""
    family = ""
    # design values of the standard measures (docs/evaluation.md): OSPA/GOSPA cut-off c and order
    # p, and the largest track-to-truth distance of a match, in the family's own space
    evaluation_defaults: dict = {}
    design_keys: tuple = ()

    @property
    def scenario(self) -> str:
        return vocab.FAMILIES[self.family].scenario

    @property
    def input_topics(self) -> tuple:
        return vocab.FAMILIES[self.family].inputs

    @property
    def output_prefix(self) -> str:
        return vocab.FAMILIES[self.family].output_prefix

    def applies(self, topics) -> bool:
        return all(t in topics for t in self.input_topics)

    def output_topic(self, tracker: str) -> str:
        return self.output_prefix + tracker

    def entries(self, specs=()) -> list:
        """Trackers of this stage's family (built-in, entry points and ``specs``)."""
        from trackreplay.registry import trackers_of_family

        return trackers_of_family(self.family, specs)

    @property
    def trackers(self) -> tuple:
        """Names of the built-in trackers of this family."""
        return tuple(e.name for e in self.entries() if e.builtin)

    def parameter_defaults(self, entries=None) -> dict:
        """Design keys of the stage and of ``entries`` → default value (bundled scenario first)."""
        from trackreplay.recorders.scenarios import load_scenario

        scenario = load_scenario(self.scenario).params
        out = {k: scenario[k] for k in self.design_keys}
        out.update({k: scenario.get(k, v) for k, v in self.evaluation_defaults.items()})
        for e in (self.entries() if entries is None else entries):
            for p in e.cls.params:
                if p.name not in out:
                    out[p.name] = scenario[p.name] if p.name in scenario and p.default is None else p.default
                    if out[p.name] is None:
                        raise InputError(f"tracker {e.name!r}: parameter {p.name!r} has no default and the "
                                         f"{self.scenario} scenario does not define it")
        return out

    def scenario_sourced_keys(self, entries=None) -> set:
        """The design keys whose default is the bundled scenario's value (the stage's own keys,
        and the trackers' parameters without a default of their own), as opposed to a
        tracker's own documented default."""
        from trackreplay.recorders.scenarios import load_scenario

        scenario = load_scenario(self.scenario).params
        keys = {k for k in self.design_keys if k in scenario}
        for e in (self.entries() if entries is None else entries):
            keys.update(p.name for p in e.cls.params if p.default is None and p.name in scenario)
        return keys

    def design(self, dataset, overrides: dict | None = None, entries=None) -> dict:
        """Design values: those of the replay in progress if there is one, else the file's
        scenario record, else the defaults (bundled scenario, then the trackers' own), then
        ``overrides``.

        A recording (:func:`trackreplay.sensor_values.is_recording`) says what it knows about its
        sensor; a sensor value it does not say (:data:`trackreplay.sensor_values.SENSOR_KEYS`) is
        never the bundled scenario's: it is estimated from the data where the family documents
        how (:data:`trackreplay.sensor_values.ESTIMABLE`; the estimate is noted in
        :func:`design_notes`), else None, *unknown*, and a tracker that needs it stops with one
        line naming the ``--set`` it needs (:meth:`run_units`)."""
        from trackreplay import sensor_values as sv
        from trackreplay.recorders.scenarios import coerce

        if not overrides and entries is None and ("design", self.name) in dataset.cache:
            return dataset.cache[("design", self.name)]

        defaults = self.parameter_defaults(entries)
        recorded = dataset.scenario.get("params", {})
        unknowable = set()
        if sv.is_recording(dataset.scenario):
            unknowable = set(sv.SENSOR_KEYS.get(self.family, ())) & self.scenario_sourced_keys(entries)
        out, notes = {}, []
        for k, default in defaults.items():
            try:
                out[k] = _recorded_value(k, recorded[k], default) if k in recorded else default
            except InputError as exc:  # the file's metadata, not the command line, is at fault
                raise InputError(f"scenario record: {exc.problem}", dataset.path) from None
            if k in unknowable and k not in recorded:
                how = sv.ESTIMABLE.get(self.family, {}).get(k)
                out[k] = None if how is None else sv.estimate(k, self.scan_times(dataset))
                if out[k] is not None and k not in (overrides or {}):
                    notes.append(f"{k} = {out[k]:g} estimated from {how} (the recording does not say it; "
                                 f"--set {k}=VALUE gives it)")
        for k, v in (overrides or {}).items():
            if k not in defaults:
                raise InputError(f"unknown tracker parameter {k!r} (known: {', '.join(defaults)})")
            out[k] = coerce(k, v, defaults[k])
        # from the values in force, --set ones included (a recording's noise may come only from there)
        derived = self.evaluation_defaults_from_data(dataset, out)
        out.update({k: v for k, v in derived.items() if k not in recorded and k not in (overrides or {})})
        try:
            self.check_design(out)
        except InputError as exc:  # a value of the file's record or of --set: named with the file
            if exc.path is not None:
                raise
            raise InputError(exc.problem, dataset.path) from None
        dataset.cache[("design_notes", self.name)] = notes
        return out

    def scan_times(self, dataset):
        """The scan times of the family's first input channel (what an estimate reads)."""
        return dataset.channel(self.input_topics[0]).times()

    def unknown_values(self, entry, design: dict) -> list:
        """The parameters of ``entry``'s tracker whose value is unknown for this data set (None
        in ``design``: a sensor value the recording does not say)."""
        return [p.name for p in entry.cls.params if p.name in design and design[p.name] is None]

    def evaluation_defaults_from_data(self, dataset, design: dict) -> dict:
        """Evaluation design values that follow from the data set (its noise and geometry), in
        place of the fixed :attr:`evaluation_defaults`; a value the file records or the command
        line sets wins. None here: a family whose stage knows better says so."""
        return {}

    # ranges (low, high), both exclusive, of the design values the stage itself uses; the
    # trackers check their own parameters
    design_ranges: dict = {}
    EVALUATION_RANGES = {"ospa_order": (0.999999, 100.0)}

    def check_design(self, design: dict) -> None:
        """Refuse a design value the stage uses that is not finite or outside its declared range
        (:attr:`design_ranges`; the standard measures' cut-off and gate must be > 0 and their
        order ≥ 1), with one line naming it."""
        import math

        ranges = dict(self.design_ranges)
        for key in self.evaluation_defaults:
            ranges.setdefault(key, self.EVALUATION_RANGES.get(key, (0.0, math.inf)))
        for key, value in design.items():
            if isinstance(value, float) and not math.isfinite(value):
                raise InputError(f"design value {key} = {value} must be finite")
            if key in ranges and isinstance(value, (int, float)) and not isinstance(value, bool):
                low, high = ranges[key]
                if not low < value < high:
                    raise InputError(f"design value {key} = {value:g} must be in ({low:g}, {high:g})")

    def build(self, entry, design: dict):
        """Construct ``entry``'s tracker with its design values."""
        values = {p.name: design[p.name] for p in entry.cls.params}
        if entry.builtin:
            return entry.cls(**values)  # a built-in's Param refuses a bad design value (ValueError)
        try:
            return entry.cls(**values)
        except InputError:
            raise
        except (Exception, SystemExit) as exc:  # a tracker's sys.exit() is its failure, not the tool's exit
            raise TrackerError(f"tracker {entry.name!r}: constructing it raised {type(exc).__name__}: {exc}",
                               entry.source) from None

    #: whether the face (Rerun views, figures) reads every Monte Carlo run of the outputs, not
    #: only the run it shows (see ``keep_runs`` of :func:`trackreplay.replay.replay`)
    views_read_all_runs = False

    def run(self, dataset, entries, design: dict) -> dict:
        """Decode once, call every tracker, collect outputs and tracker failures.

        Returns ``{"times", "tracks": {name: outputs}, "errors": [TrackerError, ...]}``: a
        tracker that fails is reported and left out, the others' outputs are kept.
        """
        times, units = self.run_units(dataset, entries, design)
        tracks, errors = {}, []
        extras = {}
        for own, unit, failed in units:
            errors += failed
            tracks.update({name: unit[name] for name in own})
            extras = {name: out for name, out in unit.items() if name not in own} or extras
        tracks.update(extras)
        return {"times": times, "tracks": tracks, "errors": errors}

    def run_units(self, dataset, entries, design: dict, time_limit_s: float | None = DEFAULT_TRACKER_TIME_LIMIT_S):
        """Decode once; then the trackers' outputs in scoring units, computed as they are read.

        Returns
        -------
        times : ndarray
            Scan times.
        units : iterator of (list of str, dict, list)
            Per unit: the names of its trackers, their outputs together with the stage's extras
            (:meth:`extras`, computed once, after the first tracker that ran; every unit's scores
            need them), and the :class:`TrackerError` of trackers that failed. A unit closes
            once its outputs reach :data:`SCORING_UNIT_BYTES` (on many runs: one tracker per
            unit; on a few, all in one, which spares the scoring's fixed cost per call). Every
            family's scores of a tracker read its own outputs and the extras alone, so the
            units' tables are those of scoring all at once (``tests/test_replay_streaming.py``).
        """
        measurements = self.decode(dataset, design)
        times = np.asarray(measurements.times_s, dtype=float)

        def call(entry):
            from trackreplay.sensor_values import unknown_message

            unknown = self.unknown_values(entry, design)
            if unknown:  # never a guess: this tracker stops, the others run
                raise TrackerError(unknown_message(entry.name, unknown), dataset.path)
            # a plugged tracker that fails to construct is reported like one that fails to run
            if entry.builtin:
                try:
                    tracker = self.build(entry, design)
                except (ValueError, InputError) as exc:  # a design value it refuses (e.g. a data set's own)
                    if isinstance(exc, InputError) and exc.path is not None:
                        raise
                    problem = exc.problem if isinstance(exc, InputError) else str(exc)
                    raise TrackerError(f"tracker {entry.name!r}: {problem}; change it with --set NAME=VALUE",
                                       dataset.path) from None
                return call_tracker(tracker, measurements, None)
            # a plugged one runs in a child process, stopped at time_limit_s (0 or None: never), so
            # that it cannot end or hang the replay (pipeline/isolation.py)
            return run_plugged_tracker(entry.name, entry.source, lambda: call_tracker(
                self.build(entry, design), measurements, entry.source), time_limit_s)

        def units():
            extras, tracks, errors = None, {}, []
            for entry in entries:
                try:
                    tracks[entry.name] = call(entry)
                except TrackerError as exc:
                    errors.append(exc)
                if tracks and outputs_nbytes(tracks) >= SCORING_UNIT_BYTES:
                    extras = self.extras(measurements, design) if extras is None else extras
                    yield list(tracks), {**tracks, **extras}, errors
                    tracks, errors = {}, []
            if tracks and extras is None:
                extras = self.extras(measurements, design)
            if tracks or errors:
                yield list(tracks), ({**tracks, **extras} if tracks else {}), errors

        return times, units()

    def extras(self, measurements, design: dict) -> dict:
        """Outputs of the stage's own estimators that are not trackers (written beside them)."""
        return {}

    # --- outputs: {"times": (scans,), "tracks": {tracker: {array: (runs, scans, ...)}}}

    def write(self, writer, result: dict) -> None:
        for name, out in result["tracks"].items():
            writer.write_grid(self.output_topic(name), result["times"], out)

    def outputs_from_dataset(self, out_dataset) -> dict:
        """Rebuild :meth:`run`'s result from a replay output file."""
        tracks, times = {}, None
        prefixes = vocab.FAMILIES[self.family].output_prefixes  # files of earlier versions too
        for topic, ch in out_dataset.channels.items():
            prefix = next((p for p in prefixes if topic.startswith(p)), None)
            if prefix is not None:
                name = topic[len(prefix):]
                tracks[name] = {k: ch.grid(k) for k in ch.arrays}
                if "flags" in tracks[name]:
                    tracks[name]["flags"] = np.nan_to_num(tracks[name]["flags"]).astype(vocab.FLAG_DTYPE)
                times = ch.times()
        if not tracks:
            raise InputError(f"no {self.output_prefix}* channels: not a {self.name} replay output", out_dataset.path)
        return {"times": times, "tracks": tracks}

    def report(self, summary, per_scan) -> str:
        """Optional text in a paper's own layout (e.g. its table), for reports written to files."""
        return ""

    #: line beginnings of :meth:`report` that the generic metric tables do not show (with their
    #: indented continuation lines); None: all of it
    replay_report_lines: tuple | None = None

    def replay_report(self, summary, per_scan) -> str:
        """What ``replay`` prints after the generic metric tables: the lines of :meth:`report`
        that say something those tables do not (:attr:`replay_report_lines`), so that every
        result is printed once."""
        text = self.report(summary, per_scan) or ""
        if self.replay_report_lines is None:
            return text
        kept, keeping = [], False
        for line in text.split("\n"):
            if line.startswith(self.replay_report_lines):
                keeping = True
            elif not line.startswith(" "):
                keeping = False
            if keeping:
                kept.append(line)
        return "\n".join(kept)

    #: per-scan metrics of the default ``report.png`` (one panel each, against time)
    report_metrics: tuple = ()
    #: the per-scan column the scans stand for in the consistency figure, and whether on a log
    #: scale (a noise study's scans are noise levels)
    per_scan_axis: tuple = ("scan", False)
    #: horizontal reference lines per metric in that figure (e.g. NPE = 1)
    report_lines: dict = {}

    def figures(self, per_scan, out_dir, title: str = "", result: dict | None = None, dataset=None) -> list:
        """PNG figures written by ``replay`` and ``replay eval --export``: by default
        ``report.png``, the :attr:`report_metrics` per scan against time, every tracker
        distinguishable. A family overrides it to add its own (bearing–time records, geometry,
        the paper's figures) from the replay's ``result`` and ``dataset``."""
        path = self.per_scan_figure(per_scan, Path(out_dir) / "report.png", self.report_metrics, title)
        return [] if path is None else [path]

    def per_scan_figure(self, per_scan, path, metrics, title: str = ""):
        """``metrics`` per scan against time, one panel each (those the table has), or None."""
        import polars as pl

        from trackreplay.evaluators.report_plots import plot_metrics_vs

        metrics = [m for m in metrics if m in per_scan.columns and per_scan[m].drop_nulls().len()]
        if not metrics:
            return None
        part = per_scan.filter(pl.col(metrics[0]).is_not_null())
        return plot_metrics_vs(part, "time_s", metrics, path, title=title, hlines=self.report_lines)

    #: channel of the truth that, when absent, makes :meth:`track_listing` print the tracks
    truth_channel: str | None = None
    #: the state component listed by :meth:`track_listing` and its unit ("deg": radians shown in degrees)
    listing = (0, "deg")
    LISTING_SCANS = 40  # more scans than this: the first and last halves, the rest in the outputs

    def track_listing(self, dataset, result: dict, run: int = 0) -> str:
        """For data without truth (a recording), where no error can be computed: run ``run``'s
        track positions per scan, one column per tracker and slot, so that a user sees what the
        trackers made of the data. Empty when the data have truth or the family lists nothing."""
        if self.truth_channel is None or self.truth_channel in dataset.channels:
            return ""
        component, unit = self.listing
        columns = {}
        for name, out in result["tracks"].items():
            if "state" not in out or "flags" not in out:
                continue
            state = np.asarray(out["state"], float)[run, ..., component]
            state = state.reshape(state.shape[0], -1)
            gone = (np.asarray(out["flags"])[run].reshape(state.shape) & (vocab.NO_TRACK | vocab.DELETED)) > 0
            state = np.where(gone, np.nan, np.rad2deg(state) if unit == "deg" else state)
            for slot in range(state.shape[1]):
                columns[name if state.shape[1] == 1 else f"{name}[{slot}]"] = state[:, slot]
        if not columns:
            return ""
        times = np.asarray(result["times"], float)
        scans = list(range(len(times)))
        if len(scans) > self.LISTING_SCANS:
            half = self.LISTING_SCANS // 2
            scans = scans[:half] + [None] + scans[-half:]
        head = f"{'scan':>5} {'time s':>9}" + "".join(f" {c:>12}" for c in columns)
        lines = [f"run {run} without truth: track positions ({unit}) per scan; every scan of every run is "
                 "in tracks.mcap", head]
        for k in scans:
            if k is None:
                lines.append(f"{'…':>5}")
                continue
            cells = "".join(f" {'—' if not np.isfinite(v[k]) else f'{v[k]:.2f}':>12}" for v in columns.values())
            lines.append(f"{k:>5} {times[k]:>9.2f}{cells}")
        return "\n".join(lines)

    def bearing_time_record(self, result: dict, out_dir, title: str = "", truth_rad=None, peaks=None,
                            field_deg=None, run: int = 0) -> Path:
        """``report.png`` of a bearing family: run ``run``'s tracks of every tracker (state
        component 0, radians) on a bearing–time record, with the truth ``(runs, scans, T)`` and
        the measured bearings ``(time_s, bearing_rad)`` where given."""
        from trackreplay.evaluators.report_plots import plot_bearing_time

        tracks = {name: np.rad2deg(np.asarray(out["state"], float)[run, ..., 0])
                  for name, out in result["tracks"].items() if "state" in out and "flags" in out}
        flags = {name: np.asarray(result["tracks"][name]["flags"])[run] for name in tracks}
        for name, bearings in tracks.items():
            bearings[(flags[name] & (vocab.NO_TRACK | vocab.DELETED)) > 0] = np.nan
        truth = None if truth_rad is None else np.rad2deg(np.asarray(truth_rad, float)[run])
        measured = None if peaks is None else (peaks[0], np.rad2deg(peaks[1]))
        label = f"{title}: run {run}" if title else f"run {run}"
        return plot_bearing_time(result["times"], tracks, Path(out_dir) / "report.png", truth_deg=truth,
                                 peaks=measured, field_deg=field_deg, title=f"{label}, bearing–time record")

    # --- to implement

    def decode(self, dataset, design: dict):  # pragma: no cover - interface
        """The family's measurement object (:mod:`trackreplay.trackers.interface`), checked."""
        raise NotImplementedError

    def evaluate(self, dataset, result: dict, design: dict):
        """``(per_scan, summary)`` polars tables; summary in long form ``tracker, metric, scope,
        value``. A stage implements :meth:`reference` and :meth:`score` (or overrides this)."""
        return self.score(self.reference(dataset, design), result, design)

    def reference(self, dataset, design: dict) -> dict:
        """What the scores need from the data set: ``{"runs": {name: array with a leading run
        axis}, "fixed": {...}}`` (truth, measured values; per-scan bounds under ``fixed``).
        Keeping per-run values apart lets :meth:`measure` re-score subsets of the runs."""
        raise NotImplementedError

    def score(self, reference: dict, result: dict, design: dict):
        """``(per_scan, summary)`` from :meth:`reference` and the trackers' outputs."""
        raise NotImplementedError

    def score_groups(self, reference: dict, result: dict, design: dict, groups: int, left_out: bool):
        """:meth:`score` together with the summaries of ``groups`` round-robin groups of runs
        (each group's runs alone, or with ``left_out`` all runs but the group's), from one pass
        over the outputs: ``(per_scan, summary, group_summaries)``, or None (the default) when
        the family's scores are not functions of sums over runs and every group is re-scored
        (``score_groups`` of :func:`trackreplay.evaluators.confidence.summary_intervals`)."""
        return None

    def cached_reference(self, dataset, design: dict) -> dict:
        """:meth:`reference`, computed once per data set and design (a replay scores its
        trackers one at a time, each against the same reference)."""
        import json

        key = json.dumps(design, sort_keys=True, default=str)
        cached = dataset.cache.get(("reference", self.name))
        if cached is None or cached[0] != key:
            cached = dataset.cache[("reference", self.name)] = (key, self.reference(dataset, design))
        return cached[1]

    def standard_space(self, design: dict, reference: dict | None = None):
        """The :class:`trackreplay.evaluators.standard.EvaluationSpace` of the family (its shape may depend
        on the data set's :meth:`reference`), or None: no standard measures."""
        return None

    def standard_truth(self, reference: dict):
        """Truth ``(R, K, [T,] n)`` in :meth:`standard_space`'s components, or None."""
        return None

    def standard_truth_ids(self, reference: dict):
        """Target identities ``(R, K, T)`` of :meth:`standard_truth`'s slots (−1 empty), or None:
        slot t is target t for the whole run."""
        return None

    def measure(self, dataset, result: dict, design: dict):
        """Every metric with its Monte Carlo interval: the family's own scores (grouped
        jackknife over runs, :func:`trackreplay.evaluators.confidence.summary_intervals`) and the standard
        measures (:func:`trackreplay.evaluators.standard.evaluate_standard`) where the family has a truth
        space, and the track summary (:func:`trackreplay.evaluators.track_summary.track_summary`, kind
        ``standard``) for every family. Returns ``(per_scan, summary)``; summary columns
        ``tracker, metric, scope, value, se, ci_low, ci_high, kind``."""
        import polars as pl

        from trackreplay.evaluators.confidence import summary_intervals
        from trackreplay.evaluators.consistency import whitened_innovations
        from trackreplay.evaluators.missing_reasons import explain_missing
        from trackreplay.evaluators.standard import evaluate_standard
        from trackreplay.evaluators.track_summary import track_summary

        try:
            reference = self.cached_reference(dataset, design)
        except NotImplementedError:
            per_scan, summary = self.evaluate(dataset, result, design)
            summary = summary.with_columns(*(pl.lit(None, pl.Float64).alias(c) for c in ("se", "ci_low", "ci_high")))
            reference = None
        else:
            tracks = result["tracks"]
            n_runs = next(iter(o["state"] for o in tracks.values() if "state" in o)).shape[0]
            fixed = reference.get("fixed", {})

            def score(runs_data):
                sub = {**result, "tracks": runs_data["tracks"]}
                return self.score({"runs": runs_data["reference"], "fixed": fixed}, sub, design)

            def score_groups(runs_data, groups, left_out):
                sub = {**result, "tracks": runs_data["tracks"]}
                return self.score_groups({"runs": runs_data["reference"], "fixed": fixed}, sub, design, groups,
                                         left_out)

            per_scan, summary = summary_intervals(score, {"tracks": tracks, "reference": reference["runs"]}, n_runs,
                                                  groups=10, score_groups=score_groups)
        tracks = {n: o for n, o in result["tracks"].items() if "state" in o and "flags" in o}
        # whitened once, read by the standard measures and the track summary
        innovations = {n: whitened_innovations(o) for n, o in tracks.items()}
        # the track summary reads the flags and innovations alone: every family has it, truth or not
        lives = track_summary(result["times"], tracks, innovations=innovations).with_columns(kind=pl.lit("standard"))
        if not model_recorded(dataset):
            per_scan, summary = without_bounds(per_scan, summary)
        space = self.standard_space(design, reference)
        if space is None:
            family = summary if "kind" in summary.columns else summary.with_columns(kind=pl.lit("family"))
            # every metric without a value says why (trackreplay.evaluators.missing_reasons)
            return per_scan, explain_missing(pl.concat([family, lives], how="diagonal_relaxed"), result["tracks"],
                                             innovations)
        truth = self.standard_truth(reference) if reference is not None else None
        truth_ids = self.standard_truth_ids(reference) if truth is not None else None
        std_scan, std_summary = evaluate_standard(result["times"], tracks, truth, space, innovations=innovations,
                                                  truth_ids=truth_ids)
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

    def life_tables(self, dataset, result: dict, design: dict):
        """``(targets, tracks)`` tables of :mod:`trackreplay.evaluators.life_tables` for the trackers of
        ``result`` (first runs only), or None where the family has no truth space or the data
        set no truth."""
        from trackreplay.evaluators.consistency import whitened_innovations
        from trackreplay.evaluators.life_tables import LIFE_TABLE_RUNS, tables_for

        try:
            reference = self.cached_reference(dataset, design)
        except NotImplementedError:
            return None
        space = self.standard_space(design, reference)
        truth = self.standard_truth(reference) if space is not None else None
        if truth is None:
            return None
        # the first runs only, sliced before anything is computed on them
        first = slice(0, LIFE_TABLE_RUNS)
        tracks = {n: {k: (v[first] if isinstance(v, np.ndarray) and v.ndim else v) for k, v in o.items()}
                  for n, o in result["tracks"].items() if "state" in o and "flags" in o}
        innovations = {n: whitened_innovations(o) for n, o in tracks.items()}
        ids = self.standard_truth_ids(reference)
        return tables_for(result["times"], tracks, np.asarray(truth)[first], None if ids is None else ids[first],
                          space, innovations)

    def holds_many_targets(self, dataset) -> bool:
        """Whether ``dataset`` is a scene of many targets (its truth is a set with identities),
        for which the family's multi-target trackers run by default."""
        return False

    def has_truth(self, dataset) -> bool:
        """Whether ``dataset`` holds the truth of this stage's family (else only what needs no
        truth is scored: innovation consistency and the track summary)."""
        family = vocab.FAMILIES.get(self.family)
        channel = family.truth if family is not None else self.truth_channel
        return channel is None or channel in dataset.channels
