"""Running a stage: decode once, call every tracker, write the outputs and read them back.

A stage (:class:`trackreplay.stages.base.Stage`) declares its family and decodes its channels
into the family's measurement object; what is done with it is the same for every family and
lives here: each selected tracker is constructed with its design values
(:func:`trackreplay.design_values.resolve`) and called through the one tracker interface
(:func:`trackreplay.trackers.interface.call_tracker`; a plugged tracker in a child process,
:mod:`trackreplay.isolation`), its outputs collected in scoring units, written one message per
scan holding every run on ``<output_prefix><tracker>``, and rebuilt from a replay output file, so
``replay eval data.mcap out.mcap`` works for every stage without stage-specific I/O
(``docs/architecture.md``).
"""

from __future__ import annotations

import numpy as np

from trackreplay import vocabulary as vocab
from trackreplay.design_values import unknown_values
from trackreplay.errors import InputError
from trackreplay.isolation import DEFAULT_TRACKER_TIME_LIMIT_S, run_plugged_tracker
from trackreplay.trackers.interface import TrackerError, call_tracker

#: a replay scores and releases trackers' outputs once they hold this many bytes (see
#: :func:`run_units`): the memory it needs is bounded by about one tracker's outputs
SCORING_UNIT_BYTES = 64 << 20

#: outputs that are whole numbers, stored as floats (NaN where a run has none) and read back as
#: their own type: the track flags of every family, a Gauss-Newton estimator's steps taken
INTEGER_OUTPUTS = {"flags": vocab.FLAG_DTYPE, "iterations": np.int32}


def outputs_nbytes(tracks: dict) -> int:
    """Bytes of the arrays of ``{tracker: outputs}``."""
    return sum(np.asarray(a).nbytes for out in tracks.values() for a in out.values())


def build(entry, design: dict):
    """Construct ``entry``'s tracker with its design values (each checked by its ``Param``)."""
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


def run(stage, dataset, entries, design: dict) -> dict:
    """Decode once, call every tracker, collect outputs and tracker failures.

    Returns ``{"times", "tracks": {name: outputs}, "errors": [TrackerError, ...]}``: a tracker
    that fails is reported and left out, the others' outputs are kept.
    """
    times, units = run_units(stage, dataset, entries, design)
    tracks, errors = {}, []
    extras = {}
    for own, unit, failed in units:
        errors += failed
        tracks.update({name: unit[name] for name in own})
        extras = {name: out for name, out in unit.items() if name not in own} or extras
    tracks.update(extras)
    return {"times": times, "tracks": tracks, "errors": errors}


def run_units(stage, dataset, entries, design: dict, time_limit_s: float | None = DEFAULT_TRACKER_TIME_LIMIT_S):
    """Decode once; then the trackers' outputs in scoring units, computed as they are read.

    Returns
    -------
    times : ndarray
        Scan times.
    units : iterator of (list of str, dict, list)
        Per unit: the names of its trackers, their outputs together with the stage's extras
        (:meth:`~trackreplay.stages.base.Stage.extras`, computed once, after the first tracker
        that ran; every unit's scores need them), and the :class:`TrackerError` of trackers that
        failed. A unit closes once its outputs reach :data:`SCORING_UNIT_BYTES` (on many runs:
        one tracker per unit; on a few, all in one, which spares the scoring's fixed cost per
        call). Every family's scores of a tracker read its own outputs and the extras alone, so
        the units' tables are those of scoring all at once (``tests/test_replay_streaming.py``).
    """
    measurements = stage.decode(dataset, design)
    times = np.asarray(measurements.times_s, dtype=float)

    def call(entry):
        from trackreplay.sensor_values import unknown_message

        unknown = unknown_values(entry, design)
        if unknown:  # never a guess: this tracker stops, the others run
            raise TrackerError(unknown_message(entry.name, unknown), dataset.path)
        # a plugged tracker that fails to construct is reported like one that fails to run
        if entry.builtin:
            try:
                tracker = build(entry, design)
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
            build(entry, design), measurements, entry.source), time_limit_s)

    def units():
        extras, tracks, errors = None, {}, []
        for entry in entries:
            try:
                tracks[entry.name] = call(entry)
            except TrackerError as exc:
                errors.append(exc)
            if tracks and outputs_nbytes(tracks) >= SCORING_UNIT_BYTES:
                extras = stage.extras(measurements, design) if extras is None else extras
                yield list(tracks), {**tracks, **extras}, errors
                tracks, errors = {}, []
        if tracks and extras is None:
            extras = stage.extras(measurements, design)
        if tracks or errors:
            yield list(tracks), ({**tracks, **extras} if tracks else {}), errors

    return times, units()


# --- outputs: {"times": (scans,), "tracks": {tracker: {array: (runs, scans, ...)}}}


def write_outputs(stage, writer, result: dict) -> None:
    """Write ``result``'s outputs, one channel ``<output_prefix><tracker>`` per tracker."""
    for name, out in result["tracks"].items():
        writer.write_grid(stage.output_prefix + name, result["times"], out)


def read_outputs(stage, out_dataset) -> dict:
    """Rebuild :func:`run`'s result from a replay output file (of this version or an earlier one)."""
    tracks, times = {}, None
    prefixes = vocab.FAMILIES[stage.family].output_prefixes  # files of earlier versions too
    for topic, ch in out_dataset.channels.items():
        prefix = next((p for p in prefixes if topic.startswith(p)), None)
        if prefix is not None:
            name = topic[len(prefix):]
            tracks[name] = {k: ch.grid(k) for k in ch.arrays}
            for key, dtype in INTEGER_OUTPUTS.items():
                if key in tracks[name]:
                    tracks[name][key] = np.nan_to_num(tracks[name][key]).astype(dtype)
            times = ch.times()
    if not tracks:
        raise InputError(f"no {stage.output_prefix}* channels: not a {stage.name} replay output", out_dataset.path)
    return {"times": times, "tracks": tracks}
