"""Running a sweep: every point of the grid on the chosen executor, finished points written as
they arrive, the results collected into one tidy table (:class:`SweepReport`); and the bundled
regression sweeps (``data/sweeps/*.toml``)."""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import polars as pl

from trackreplay.errors import InputError
from trackreplay.sweep.evaluation import EVALUATION_METADATA, evaluation_defaults_of
from trackreplay.sweep.executors import EXECUTORS, _iter_dask, _iter_process, _iter_serial, default_workers
from trackreplay.sweep.folder import (_folder_lock, _metrics_file, _named_output, _point_files, _record_file,
                                      _remove_temporaries, discard_point_files)
from trackreplay.sweep.grid import build_grid, scenario_families
from trackreplay.sweep.interruption import _stop_on_signals
from trackreplay.sweep.point import RECORD_SCHEMA, _point_frame
from trackreplay.sweep.resume import _resume_notes, _reuse

if TYPE_CHECKING:
    from trackreplay.sweep.grid import PointTask


@dataclass
class SweepReport:
    table: pl.DataFrame
    done: int
    skipped: int
    failed: dict[str, str]
    wall_s: float
    point_work_s: list[float]
    out_dir: Path | None
    # point label → [(where, message), ...] of trackers that failed there (others' metrics kept)
    tracker_failures: dict[str, list] = field(default_factory=dict)
    # one line per reason why a resumed sweep computed points again (what changed)
    notes: list[str] = field(default_factory=list)
    # point label → stage name → {evaluation design value: value} the point was scored with
    evaluation: dict = field(default_factory=dict)

    def tracker_failure_lines(self) -> list[str]:
        """One line per failing tracker: its first failure, the point, and on how many points."""
        by_where: dict[str, list] = {}
        for label, errors in self.tracker_failures.items():
            for where, message in errors:
                by_where.setdefault(where, []).append((label, message))
        lines = []
        for items in by_where.values():
            label, message = items[0]
            more = f"; failed at {len(items)} points" if len(items) > 1 else ""
            lines.append(f"{message} (point {label}{more})")
        return lines

    @property
    def median_point_s(self) -> float:
        """Median compute time of the points computed now; NaN when every point was resumed."""
        return float(np.median(self.point_work_s)) if self.point_work_s else float("nan")


def run_sweep(tasks: list[PointTask], swept: list[str], out_dir: Path | None, executor: str = "process",
              workers: int | None = None, scheduler: str | None = None, resume: bool = False,
              progress=None, outcome=None) -> SweepReport:
    """Run the grid and assemble one tidy table (point × tracker × metric).

    ``progress(n)`` is called as points finish, and ``outcome(kind)`` with ``"done"``,
    ``"resumed"`` or ``"failed"`` for each. Finished points are written immediately (when
    ``out_dir`` is given) so an interrupted sweep resumes with ``resume=True``; a point is
    reused only when its record (:meth:`PointTask.record`) is the task's.

    Raises
    ------
    KeyboardInterrupt, SweepTerminated
        On SIGINT, or SIGTERM/SIGHUP, after the workers are stopped; finished points are kept.
    InputError
        Another sweep holds the output folder.
    """
    if executor not in EXECUTORS:
        raise InputError(f"unknown executor {executor!r} (choose from {', '.join(EXECUTORS)})")
    workers = workers or default_workers()
    out_dir = Path(out_dir) if out_dir is not None else None
    with _stop_on_signals(), _folder_lock(out_dir):
        if out_dir is not None:
            _remove_temporaries(out_dir)  # left by a sweep that was killed
        try:
            return _run_sweep(tasks, swept, out_dir, executor, workers, scheduler, resume, progress, outcome)
        finally:
            if out_dir is not None:  # the unfinished points' half-written files, if any survived
                _remove_temporaries(out_dir)


def _run_sweep(tasks, swept, out_dir, executor, workers, scheduler, resume, progress, outcome=None) -> SweepReport:
    t0 = time.perf_counter()
    frames: dict[int, pl.DataFrame] = {}
    todo = []
    skipped = 0
    again: dict[str, str] = {}
    evaluation: dict[str, dict] = {}
    for t in tasks:
        if resume and out_dir is not None:
            frame, why, used = _reuse(t, out_dir, swept)
            if frame is not None:
                frames[t.index] = frame
                evaluation[t.label] = used
                skipped += 1
                if progress:
                    progress(1)
                if outcome:
                    outcome("resumed")
                continue
            if why:
                again[t.label] = why
        todo.append(t)
    by_index = {t.index: t for t in tasks}
    failed, work, tracker_failures = {}, [], {}
    # what each point's folder held before this sweep: a point that fails or is stopped leaves
    # nothing of its own there, and nothing else is touched (discard_point_files)
    before = {t.index: _point_files(Path(t.point_dir)) for t in todo if t.point_dir is not None}
    points_dir = out_dir / "points" if out_dir is not None else None
    points_existed = points_dir is not None and points_dir.is_dir()
    kept: set[int] = set()  # points whose files stay: their result arrived and is written
    if todo:
        if executor == "serial" or (executor == "process" and workers == 1):
            it = _iter_serial(todo)
        elif executor == "process":
            it = _iter_process(todo, workers)
        else:
            it = _iter_dask(todo, workers, scheduler)
        try:
            for res in it:
                work.append(res.work_s)
                if res.tracker_errors:
                    tracker_failures[res.label] = res.tracker_errors
                disk = getattr(res, "disk_error", None)  # a worker of an older installed copy may not send it
                if disk is not None:  # every point would fail the same way: stop, in one line
                    _, problem, where = disk
                    failed[res.label] = res.error
                    raise InputError(f"{problem}; the sweep stopped (finished points kept: {len(kept)}; the "
                                     "unfinished ones leave nothing)", where or by_index[res.index].point_dir)
                if res.error is not None:
                    failed[res.label] = res.error
                elif res.records or not res.tracker_errors:
                    task = by_index[res.index]
                    frame = _point_frame(task, res.records, swept)
                    frames[res.index] = frame
                    used = evaluation[res.label] = getattr(res, "evaluation", None) or {}
                    # a point where a tracker failed is not recorded as done: resume computes it
                    # again. The record goes last: metrics without their record are not reused.
                    if out_dir is not None and not res.tracker_errors:
                        with _named_output(_metrics_file(out_dir, res.label)) as fh:
                            frame.write_parquet(fh, metadata={EVALUATION_METADATA: json.dumps(used)})
                        with _named_output(_record_file(out_dir, res.label), "w") as fh:
                            json.dump({**task.record(), "evaluation": used}, fh, indent=1)
                if res.error is None:  # its files are complete (and its record written)
                    kept.add(res.index)
                if progress:
                    progress(1)
                if outcome:
                    outcome("failed" if res.error is not None else "done")
        finally:
            it.close()  # stops the workers when interrupted here rather than in the executor
            for t in todo:  # failed, stopped or never started: what they wrote goes
                if t.point_dir is not None and t.index not in kept:
                    discard_point_files(t.point_dir, before.get(t.index))
            if points_dir is not None and not points_existed:
                try:
                    points_dir.rmdir()  # only when no point is left in it
                except OSError:
                    pass
    table = (pl.concat([frames[i] for i in sorted(frames)], how="vertical_relaxed") if frames
             else pl.DataFrame(schema={"point_index": pl.Int64, "point": pl.Utf8, **RECORD_SCHEMA}))
    order = {t.label: t.index for t in tasks}
    return SweepReport(table, len(todo) - len(failed), skipped, failed, time.perf_counter() - t0, work, out_dir,
                       tracker_failures, _resume_notes(again),
                       {label: evaluation[label] for label in sorted(evaluation, key=order.get)})


def sweep_spec_report(spec_path: str | Path, executor: str = "serial", tracker_specs=(),
                      evaluation: dict | None = None) -> SweepReport:
    """Run a bundled regression sweep (``data/sweeps/*.toml``), metrics only, no files kept;
    ``tracker_specs`` adds plugged trackers beside the spec's trackers, and ``evaluation``
    (name → value) sets the evaluation design values at every point; the names the stages of
    the scenario do not declare are left out (:attr:`SweepReport.evaluation` says what each
    point used)."""
    import tomllib

    spec_path = Path(spec_path)
    try:
        doc = tomllib.loads(spec_path.read_text())
        specs = {k: [str(v) for v in vals] for k, vals in doc["params"].items()}
        scenario, runs, seed = doc["scenario"], int(doc["runs"]), int(doc["seed"])
    except (tomllib.TOMLDecodeError, KeyError, TypeError, ValueError) as exc:
        raise InputError(f"not a valid sweep spec ({type(exc).__name__}: {exc})", spec_path) from None
    fixed, defaults = {}, {}
    if evaluation:
        defaults = evaluation_defaults_of(scenario_families(scenario))
        fixed = {k: v for k, v in evaluation.items() if k in defaults}
    tasks = build_grid(scenario, specs, runs, seed, doc.get("trackers"), None, keep_data=False, fixed=fixed,
                       tracker_specs=tracker_specs, design_defaults=defaults)
    report = run_sweep(tasks, list(specs), None, executor=executor)
    if report.failed:
        raise InputError(f"sweep points failed: {report.failed}", spec_path)
    return report


def sweep_spec_scenario(spec_path: str | Path) -> str:
    """The scenario a sweep spec sweeps (for choosing the plugged trackers that apply)."""
    import tomllib

    try:
        return tomllib.loads(Path(spec_path).read_text())["scenario"]
    except (OSError, tomllib.TOMLDecodeError, KeyError) as exc:
        raise InputError(f"not a valid sweep spec ({type(exc).__name__}: {exc})", spec_path) from None
