"""What every stage processor shares: naming, output channels and reading them back.

A stage consumes the channels it understands and returns its trackers' outputs as arrays with a
leading run axis; this base class writes them as batched frames on ``<output_prefix><tracker>``
and rebuilds them from a replay output file, so ``replay eval data.mcap out.mcap`` works for
every stage without stage-specific I/O. Subclasses implement :meth:`run`, :meth:`evaluate`,
:meth:`log_rerun` and :meth:`blueprint`, and set the class attributes.
"""

from __future__ import annotations

import numpy as np

from pipeline.errors import InputError


def _recorded_value(key: str, raw, default):
    """A design value from a file's scenario record, parsed like ``--set`` and type-checked.

    JSON metadata may hold a string (``"5"``), ``null`` or ``true`` where a number belongs;
    :func:`recorders.scenarios.coerce` parses strings, this also refuses the non-strings that
    would fail later, far from the file.
    """
    from recorders.scenarios import coerce

    if isinstance(default, str) and isinstance(raw, str):
        return raw  # as recorded (an empty string may be meaningful, e.g. "use the preset")
    value = coerce(key, raw, default)
    numeric = isinstance(default, (int, float)) and not isinstance(default, bool)
    if value is None or (numeric and (isinstance(value, bool) or not isinstance(value, (int, float)))):
        raise InputError(f"parameter {key!r}: cannot read {raw!r} as {type(default).__name__}")
    return value


class Stage:
    """Base class of stage processors.

    Class attributes
    ----------------
    name : str
        Stage name (also the scenario family it serves).
    input_topics : tuple of str
        Channels that must all be present for the stage to apply.
    trackers : tuple of str
        Tracker (strategy) names the stage can run.
    output_prefix : str
        Output channels are ``output_prefix + tracker``.
    scenario : str
        Bundled scenario whose parameters give the design defaults.
    design_keys : tuple of str
        Scenario parameters the trackers use (overridable with ``replay FILE --set``).
    """

    name = ""
    input_topics: tuple = ()
    trackers: tuple = ()
    output_prefix = ""
    scenario = ""
    design_keys: tuple = ()

    def applies(self, topics) -> bool:
        return all(t in topics for t in self.input_topics)

    def output_topic(self, tracker: str) -> str:
        return self.output_prefix + tracker

    def design(self, dataset, overrides: dict | None = None) -> dict:
        """Design values: those of the replay in progress if there is one, else the file's
        scenario record, else the bundled scenario's defaults, then ``overrides``."""
        from recorders.scenarios import coerce, load_scenario

        if not overrides and ("design", self.name) in dataset.cache:
            return dataset.cache[("design", self.name)]

        defaults = load_scenario(self.scenario).params
        recorded = dataset.scenario.get("params", {})
        out = {}
        for k in self.design_keys:
            try:
                out[k] = _recorded_value(k, recorded[k], defaults[k]) if k in recorded else defaults[k]
            except InputError as exc:  # the file's metadata, not the command line, is at fault
                raise InputError(f"scenario record: {exc.problem}", dataset.path) from None
        for k, v in (overrides or {}).items():
            if k not in self.design_keys:
                raise InputError(f"unknown tracker parameter {k!r} (known: {', '.join(self.design_keys)})")
            out[k] = coerce(k, v, defaults[k])
        return out

    # --- outputs: {"times": (scans,), "tracks": {tracker: {array: (runs, scans, ...)}}}

    def write(self, writer, result: dict) -> None:
        for name, out in result["tracks"].items():
            writer.write_grid(self.output_topic(name), result["times"], out)

    def outputs_from_dataset(self, out_dataset) -> dict:
        """Rebuild :meth:`run`'s result from a replay output file."""
        tracks, times = {}, None
        for topic, ch in out_dataset.channels.items():
            if topic.startswith(self.output_prefix):
                name = topic[len(self.output_prefix):]
                tracks[name] = {k: ch.grid(k) for k in ch.arrays}
                if "flags" in tracks[name]:
                    tracks[name]["flags"] = np.nan_to_num(tracks[name]["flags"]).astype(np.uint8)
                times = ch.times()
        if not tracks:
            raise InputError(f"no {self.output_prefix}* channels: not a {self.name} replay output", out_dataset.path)
        return {"times": times, "tracks": tracks}

    def report(self, summary, per_scan) -> str:
        """Optional extra text after the generic metrics table (e.g. a paper's table layout)."""
        return ""

    def figures(self, per_scan, out_dir, title: str = "") -> list:
        """Optional paper-style PNG figures written by ``replay`` and ``replay eval --export``."""
        return []

    # --- to implement

    def run(self, dataset, trackers, design: dict) -> dict:  # pragma: no cover - interface
        raise NotImplementedError

    def evaluate(self, dataset, result: dict, design: dict):  # pragma: no cover - interface
        """Return ``(per_scan, summary)`` polars tables; summary in long form
        ``tracker, metric, scope, value``."""
        raise NotImplementedError

    def log_rerun(self, rec, dataset, result: dict, per_scan, run: int = 0) -> None:  # pragma: no cover
        raise NotImplementedError

    def blueprint(self, trackers, dataset=None, run: int = 0):  # pragma: no cover - interface
        raise NotImplementedError
