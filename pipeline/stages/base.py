"""The stage interface: what a measurement family's stage declares and provides.

A stage declares its family (which fixes its input channels and output prefix), decodes the
family's channels into the family's measurement object, and says what its scores need and how
to score (``docs/architecture.md``): decode → call → arrays → scores. Everything done with those
hooks is the same for every family and lives in plain modules: the design values in
:mod:`trackreplay.design_values`, calling the trackers and writing and reading their outputs in
:mod:`trackreplay.stage_running`, the intervals, standard measures and track summary in
:mod:`trackreplay.stage_scoring`, the drawing in :mod:`trackreplay.evaluators.stage_figures`, the
printed text in :mod:`trackreplay.face.stage_text` and the Rerun views in
:mod:`trackreplay.face.rerun_views`.
"""

from __future__ import annotations

from trackreplay import vocabulary as vocab


class Stage:
    """Base class of stage processors: one per measurement family.

    A stage decodes its family's channels into the family's measurement object
    (:mod:`trackreplay.trackers.interface`), which every selected tracker is called with
    (:func:`trackreplay.stage_running.run_units`), and scores the outputs with its evaluator
    (:func:`trackreplay.stage_scoring.measure`). It holds no numerics of its own.

    Class attributes
    ----------------
    name : str
        Stage name.
    family : str
        The measurement family (a key of :data:`trackreplay.vocabulary.FAMILIES`); it fixes the
        input channels, the truth channel and the output channel prefix.
    design_keys : tuple of str
        Scenario parameters the stage itself uses (decoding, evaluation); each tracker's
        ``params`` add to them. Their defaults are the family's bundled scenario's.
    params : tuple of Param
        Those of :attr:`design_keys` with bounds, each checked by its
        :meth:`~trackreplay.trackers.interface.Param.check` (:func:`trackreplay.design_values.check`).
    evaluation_defaults : dict
        Design values of the standard measures (``docs/evaluation.md``): OSPA/GOSPA cut-off c
        and order p, and the largest track-to-truth distance of a match, in the family's own
        space → default.
    views_read_all_runs : bool
        Whether the face (Rerun views, figures) reads every Monte Carlo run of the outputs, not
        only the run it shows (``keep_runs`` of :func:`trackreplay.replay.replay`).
    report_metrics : tuple of str
        Per-scan metrics of the default ``report.png`` (one panel each, against time).
    report_lines : dict
        Horizontal reference lines per metric in the figures (e.g. NPE = 1).
    per_scan_axis : (str, bool)
        The per-scan column the scans stand for in the consistency figure, and whether on a log
        scale (a noise study's scans are noise levels).
    replay_report_lines : tuple of str or None
        Line beginnings of :meth:`report` that the generic metric tables do not show (with
        their indented continuation lines); None: all of it
        (:func:`trackreplay.face.stage_text.replay_report`).
    listing : (int, str) or None
        The state component a data set without truth lists per scan and its unit ("deg":
        radians shown in degrees; :func:`trackreplay.face.stage_text.track_listing`); None: no
        listing.
    when_unsaid : dict
        ``{sensor value: (what the stage reads instead, why)}`` for a sensor value a recording
        need not say (``replay info`` prints it as the value used).
    declared_scopes : tuple of str
        Scopes the family's report always shows, named even when no scan falls in one.
    declared_scopes_need : str or None
        A metric without which the declared scopes do not apply (truth-only scopes).
    """

    name = ""
    family = ""
    design_keys: tuple = ()
    params: tuple = ()
    evaluation_defaults: dict = {}
    views_read_all_runs = False
    report_metrics: tuple = ()
    report_lines: dict = {}
    per_scan_axis: tuple = ("scan", False)
    replay_report_lines: tuple | None = None
    listing: tuple | None = None
    when_unsaid: dict = {}
    declared_scopes: tuple = ()
    declared_scopes_need: str | None = None

    # --- identity: what the family's declaration in trackreplay.vocabulary fixes

    @property
    def scenario(self) -> str:
        """Bundled scenario whose parameters give the design defaults."""
        return vocab.FAMILIES[self.family].scenario

    @property
    def input_topics(self) -> tuple:
        return vocab.FAMILIES[self.family].inputs

    @property
    def output_prefix(self) -> str:
        return vocab.FAMILIES[self.family].output_prefix

    def entries(self, specs=()) -> list:
        """Trackers of this stage's family (built-in, entry points and ``specs``)."""
        from trackreplay.registry import trackers_of_family

        return trackers_of_family(self.family, specs)

    @property
    def trackers(self) -> tuple:
        """Names of the built-in trackers of this family."""
        return tuple(e.name for e in self.entries() if e.builtin)

    def check_design(self, design: dict) -> None:
        """:func:`trackreplay.design_values.check` (kept for :mod:`trackreplay.sweep`'s call)."""
        from trackreplay.design_values import check

        check(self, design)

    # --- to implement: decode

    def decode(self, dataset, design: dict):  # pragma: no cover - interface
        """The family's measurement object (:mod:`trackreplay.trackers.interface`), checked."""
        raise NotImplementedError

    def extras(self, measurements, design: dict) -> dict:
        """Outputs of the stage's own estimators that are not trackers (written beside them)."""
        return {}

    def holds_many_targets(self, dataset) -> bool:
        """Whether ``dataset`` is a scene of many targets (its truth is a set with identities),
        for which the family's multi-target trackers run by default."""
        return False

    def evaluation_defaults_from_data(self, dataset, design: dict) -> dict:
        """Evaluation design values that follow from the data set (its noise and geometry), in
        place of the fixed :attr:`evaluation_defaults`; a value the file records or the command
        line sets wins. None here: a family whose stage knows better says so."""
        return {}

    # --- to implement: scores

    def reference(self, dataset, design: dict) -> dict:  # pragma: no cover - interface
        """What the scores need from the data set: ``{"runs": {name: array with a leading run
        axis}, "fixed": {...}}`` (truth, measured values; per-scan bounds under ``fixed``).
        Keeping per-run values apart lets :func:`trackreplay.stage_scoring.measure` re-score
        subsets of the runs."""
        raise NotImplementedError

    def score(self, reference: dict, result: dict, design: dict):  # pragma: no cover - interface
        """``(per_scan, summary)`` polars tables from :meth:`reference` and the trackers'
        outputs; summary in long form ``tracker, metric, scope, value``."""
        raise NotImplementedError

    def score_groups(self, reference: dict, result: dict, design: dict, groups: int, left_out: bool):
        """:meth:`score` together with the summaries of ``groups`` round-robin groups of runs
        (each group's runs alone, or with ``left_out`` all runs but the group's), from one pass
        over the outputs: ``(per_scan, summary, group_summaries)``, or None (the default) when
        the family's scores are not functions of sums over runs and every group is re-scored
        (``score_groups`` of :func:`trackreplay.evaluators.confidence.summary_intervals`)."""
        return None

    def standard_space(self, design: dict, reference: dict | None = None):
        """The :class:`trackreplay.evaluators.standard.EvaluationSpace` of the family (its shape
        may depend on the data set's :meth:`reference`), or None: no standard measures."""
        return None

    def standard_truth(self, reference: dict):
        """Truth ``(R, K, [T,] n)`` in :meth:`standard_space`'s components, or None."""
        return None

    def standard_truth_ids(self, reference: dict):
        """Target identities ``(R, K, T)`` of :meth:`standard_truth`'s slots (−1 empty), or None:
        slot t is target t for the whole run."""
        return None

    # --- optional: the family's own figures and text

    def figures(self, per_scan, out_dir, title: str = "", result: dict | None = None, dataset=None) -> list:
        """PNG figures written by ``replay`` and ``replay eval --export``: by default
        ``report.png``, the :attr:`report_metrics` per scan against time
        (:func:`trackreplay.evaluators.stage_figures.metrics_report`). A family overrides it to
        add its own (bearing–time records, geometry, the paper's figures) from the replay's
        ``result`` and what it decodes of ``dataset``."""
        from trackreplay.evaluators.stage_figures import metrics_report

        return metrics_report(per_scan, out_dir, self.report_metrics, title, self.report_lines)

    def report(self, summary, per_scan) -> str:
        """Optional text in a paper's own layout (e.g. its table), for reports written to files."""
        return ""


class BearingStage(Stage):
    """A stage whose standard measures compare bearings: its reference holds the true bearing of
    each slot, ``(R, K, T)`` in radians (the cross-correlation and array families)."""

    def standard_space(self, design: dict, reference: dict | None = None):
        from trackreplay.evaluators.standard import bearing_space

        return bearing_space(design)

    def standard_truth(self, reference: dict):
        truth = reference["runs"]["truth"]
        return None if truth is None else truth[..., None]
