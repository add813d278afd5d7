"""Parameter sweeps: simulate → replay → evaluate every point of a grid, on one core, a
process pool or a Dask cluster.

* The grid is the cartesian product of ``--param NAME=v1,v2,...`` over a scenario's parameters;
  every point is validated by the scenario's recorder before any work starts.
* Each point's seed is derived from the base seed and the point's parameters
  (:func:`point_seed`), so a point gives the same numbers on any executor and in any order.
* :func:`run_point` is the whole job of one point: a pure function of its :class:`PointTask`
  that never raises (an error comes back as text), so one failed point never loses the others.
* The client (this process) writes each point's metrics to ``points/<label>/metrics.parquet``
  as it completes, beside ``point.json``, the record of what the point computed (scenario
  values, runs, seed, tracker subset, plugged trackers' specs and file hashes); ``resume``
  skips a point only when both exist and the record is the task's.
* Plugged trackers (``--tracker``) travel to the workers as canonical specs (absolute file
  paths, :func:`pipeline.registry.canonical_spec`) and are loaded again there, so serial, process
  pool and Dask runs load the same file. A tracker that fails on a point is reported with its
  message (tracker, run, scan) while the other trackers' metrics of that point are kept.
* Dask is the engine beyond one machine (``Client(address)``); locally a ``LocalCluster``
  bound to 127.0.0.1 without dashboard. No home-made scheduler.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import os
import shutil
import tempfile
import time
import traceback
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import polars as pl

from pipeline.contract import atomic_output
from pipeline.errors import InputError

EXECUTORS = ("serial", "process", "dask")


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

    def record(self) -> dict:
        """What this point computes, as JSON (``points/<label>/point.json``): a resumed sweep
        reuses a point's metrics only when its record is the same."""
        doc = {"scenario": self.scenario, "overrides": [list(kv) for kv in self.overrides],
               "design": [list(kv) for kv in self.design], "runs": self.runs, "seed": self.seed,
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


@dataclass
class PointResult:
    index: int
    label: str
    records: list = field(default_factory=list)
    error: str | None = None
    work_s: float = 0.0
    # (where, message) of every tracker that failed on this point; the others' records are kept
    tracker_errors: list = field(default_factory=list)


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
               tracker_specs=(), design_defaults: dict | None = None) -> list[PointTask]:
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
    """
    from pipeline.registry import canonical_spec
    from recorders import recorder_module
    from recorders.scenarios import coerce, load_scenario

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
                               point_dir, specs_canon, tuple({**fixed_design, **design}.items())))
    return tasks


def scenario_families(scenario_name: str, fixed: dict | None = None) -> set[str]:
    """Measurement families (:data:`pipeline.vocabulary.FAMILIES`) a scenario's data set holds,
    from the channels of a one-run simulation (to refuse a plugged tracker of another family
    before a sweep starts)."""
    from pipeline import vocabulary as vocab
    from recorders import simulator_for
    from recorders.scenarios import load_scenario

    sc = load_scenario(scenario_name).with_overrides(fixed or {})
    data = simulator_for(sc.recorder)(sc.params, 1, 0)
    topics = set(data.fixed) | set(data.ragged)
    return {f.name for f in vocab.FAMILIES.values() if all(t in topics for t in f.inputs)}


def run_point(task: PointTask) -> PointResult:
    """Simulate, replay and evaluate one grid point; errors come back in the result."""
    from pipeline.trackers.interface import TrackerError

    t0 = time.perf_counter()
    try:
        records, failures = _run_point(task)
        return PointResult(task.index, task.label, records, None, time.perf_counter() - t0,
                           [(f.path or "", str(f)) for f in failures])
    except TrackerError as exc:  # no tracker of the point ran (e.g. the plugged one alone failed)
        return PointResult(task.index, task.label, [], None, time.perf_counter() - t0, [(exc.path or "", str(exc))])
    except Exception as exc:  # isolate the point: the sweep reports it and goes on
        msg = str(exc) if isinstance(exc, InputError) else "".join(
            traceback.format_exception_only(type(exc), exc)).strip()
        return PointResult(task.index, task.label, [], msg, time.perf_counter() - t0)


def _run_point(task: PointTask) -> tuple[list[dict], list]:
    from pipeline.replay import replay
    from recorders.scenarios import load_scenario
    from recorders.simulated import record

    sc = load_scenario(task.scenario).with_overrides(dict(task.overrides))
    keep = task.point_dir is not None
    work = Path(task.point_dir) if keep else Path(tempfile.mkdtemp(prefix="sweep-point-"))
    try:
        work.mkdir(parents=True, exist_ok=True)
        data = work / "data.mcap"
        record(data, sc, task.runs, task.seed)
        res = replay(data, list(task.trackers) if task.trackers else None,
                     out_path=work / "tracks.mcap" if keep else None,
                     rrd_path=work / "tracks.rrd" if keep else None,
                     design_overrides=dict(task.design) or None, tracker_specs=task.tracker_specs)
    finally:
        if not keep:
            shutil.rmtree(work, ignore_errors=True)
    overall = res.summary.filter(pl.col("scope") == "overall")
    records = [{"tracker": r["tracker"], "metric": r["metric"], "value": r["value"]}
               for r in overall.iter_rows(named=True)]
    return records, res.failures


# --------------------------------------------------------------------------- executors


def _iter_serial(tasks):
    for t in tasks:
        yield run_point(t)


PRELOAD = ["pipeline.sweep", "pipeline.replay", "recorders.simulated"]


def _forkserver_context(extra=()):
    """The forkserver context, with the numerics (and ``extra`` modules) preloaded.

    Workers fork from a clean server with the numerics already imported, so they start fast
    without inheriting this process's threads (polars, rerun, an event loop) the way plain
    fork would. The preload list only takes effect if the server is not running yet.
    """
    import multiprocessing as mp

    ctx = mp.get_context("forkserver")
    ctx.set_forkserver_preload([*PRELOAD, *extra])
    return ctx


def _iter_process(tasks, workers):
    from concurrent.futures import ProcessPoolExecutor, as_completed

    with ProcessPoolExecutor(max_workers=workers, mp_context=_forkserver_context()) as pool:
        futures = [pool.submit(run_point, t) for t in tasks]
        for f in as_completed(futures):
            yield f.result()


def _preload_worker(specs=()) -> None:
    import pipeline.replay  # noqa: F401
    import recorders.simulated  # noqa: F401

    if specs:  # load the plugged trackers once per worker (a bad spec fails in the point, by name)
        from pipeline.registry import available_trackers

        try:
            available_trackers(specs)
        except InputError:
            pass


def _iter_dask(tasks, workers, scheduler):
    from dask.distributed import Client, LocalCluster, as_completed

    if scheduler:
        client = Client(scheduler)
        cluster = None
    else:
        import dask

        # Local workers fork from the same preloaded server as the process pool instead of
        # spawning fresh interpreters that each import numpy, polars and distributed again.
        _forkserver_context(["distributed"])
        with dask.config.set({"distributed.worker.multiprocessing-method": "forkserver"}):
            cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                   host="127.0.0.1", dashboard_address=None)
        client = Client(cluster)
    try:
        # import the numerics on every worker at once, before the first point, as the
        # forkserver preload does for the process pool
        client.run(_preload_worker, sorted({s for t in tasks for s in t.tracker_specs}))
        futures = client.map(run_point, tasks, pure=False)
        for f in as_completed(futures):
            yield f.result()
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def default_workers() -> int:
    return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1))


# --------------------------------------------------------------------------- the sweep


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
        return float(np.median(self.point_work_s)) if self.point_work_s else float("nan")


def _metrics_file(out_dir: Path, label: str) -> Path:
    return out_dir / "points" / label / "metrics.parquet"


def _record_file(out_dir: Path, label: str) -> Path:
    return out_dir / "points" / label / "point.json"


def _resumable(task: PointTask, out_dir: Path) -> bool:
    """The point's metrics exist and were computed for this very task."""
    if not _metrics_file(out_dir, task.label).exists():
        return False
    rec = _record_file(out_dir, task.label)
    if not rec.exists():  # written before point records existed: no plugged trackers then
        return not task.tracker_specs and not task.design
    try:
        return json.loads(rec.read_text()) == task.record()
    except (OSError, json.JSONDecodeError):
        return False


def _point_frame(task: PointTask, records: list[dict], swept: list[str]) -> pl.DataFrame:
    values = {**dict(task.overrides), **dict(task.design)}  # the swept values come last, so they win
    df = pl.DataFrame(records, schema={"tracker": pl.Utf8, "metric": pl.Utf8, "value": pl.Float64})
    return df.with_columns(
        pl.lit(task.label).alias("point"), pl.lit(task.index).alias("point_index"),
        pl.lit(task.seed, dtype=pl.UInt64).alias("seed"),
        *[pl.lit(values[n]).alias(n) for n in swept],
    ).select("point_index", "point", *swept, "seed", "tracker", "metric", "value")


def run_sweep(tasks: list[PointTask], swept: list[str], out_dir: Path | None, executor: str = "process",
              workers: int | None = None, scheduler: str | None = None, resume: bool = False,
              progress=None) -> SweepReport:
    """Run the grid and assemble one tidy table (point × tracker × metric).

    ``progress(n)`` is called as points finish. Finished points are written immediately (when
    ``out_dir`` is given) so an interrupted sweep resumes with ``resume=True``.
    """
    if executor not in EXECUTORS:
        raise InputError(f"unknown executor {executor!r} (choose from {', '.join(EXECUTORS)})")
    workers = workers or default_workers()
    t0 = time.perf_counter()
    frames: dict[int, pl.DataFrame] = {}
    todo = []
    skipped = 0
    for t in tasks:
        if resume and out_dir is not None and _resumable(t, out_dir):
            frames[t.index] = pl.read_parquet(_metrics_file(out_dir, t.label))
            skipped += 1
            if progress:
                progress(1)
        else:
            todo.append(t)
    by_index = {t.index: t for t in tasks}
    failed, work, tracker_failures = {}, [], {}
    if todo:
        if executor == "serial" or (executor == "process" and workers == 1):
            it = _iter_serial(todo)
        elif executor == "process":
            it = _iter_process(todo, workers)
        else:
            it = _iter_dask(todo, workers, scheduler)
        for res in it:
            work.append(res.work_s)
            if res.tracker_errors:
                tracker_failures[res.label] = res.tracker_errors
            if res.error is not None:
                failed[res.label] = res.error
            elif res.records or not res.tracker_errors:
                task = by_index[res.index]
                frame = _point_frame(task, res.records, swept)
                frames[res.index] = frame
                # a point where a tracker failed is not recorded as done: resume computes it again
                if out_dir is not None and not res.tracker_errors:
                    with atomic_output(_record_file(out_dir, res.label), "w") as fh:
                        json.dump(task.record(), fh, indent=1)
                    with atomic_output(_metrics_file(out_dir, res.label)) as fh:
                        frame.write_parquet(fh)
            if progress:
                progress(1)
    table = (pl.concat([frames[i] for i in sorted(frames)], how="vertical_relaxed") if frames
             else pl.DataFrame(schema={"point_index": pl.Int64, "point": pl.Utf8, "tracker": pl.Utf8,
                                       "metric": pl.Utf8, "value": pl.Float64}))
    return SweepReport(table, len(todo) - len(failed), skipped, failed, time.perf_counter() - t0, work, out_dir,
                       tracker_failures)


def write_sweep_outputs(report: SweepReport, swept: list[str], spec: dict) -> list[Path]:
    """Table as Parquet + CSV, the spec as JSON, and one PNG per metric vs the first swept parameter."""
    from evaluators.report_plots import plot_metrics_vs

    out = report.out_dir
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    with atomic_output(out / "sweep.parquet") as f:
        report.table.write_parquet(f)
    with atomic_output(out / "sweep.csv") as f:
        report.table.write_csv(f)
    with atomic_output(out / "sweep.json", "w") as f:
        json.dump(spec, f, indent=1, default=str)
    paths += [out / "sweep.parquet", out / "sweep.csv", out / "sweep.json"]
    if report.table.height == 0:
        return paths
    x = swept[0]
    others = swept[1:]
    wide = report.table.pivot(on="metric", index=["point", *swept, "tracker"], values="value", aggregate_function="first")
    if others:
        wide = wide.with_columns(pl.concat_str([pl.col("tracker"), *[pl.format(f"{o}={{}}", pl.col(o)) for o in others]],
                                               separator=" ").alias("line"))
    else:
        wide = wide.with_columns(pl.col("tracker").alias("line"))
    plot_dir = out / "plots"
    for metric in report.table["metric"].unique(maintain_order=True):
        paths.append(plot_metrics_vs(wide, x, [metric], plot_dir / f"{metric}.png", group="line",
                                     title=f"{spec.get('scenario', '')}: {metric} vs {x}"))
    return paths


def sweep_spec_report(spec_path: str | Path, executor: str = "serial", tracker_specs=()) -> SweepReport:
    """Run a bundled regression sweep (``data/sweeps/*.toml``), metrics only, no files kept;
    ``tracker_specs`` adds plugged trackers beside the spec's trackers."""
    import tomllib

    spec_path = Path(spec_path)
    try:
        doc = tomllib.loads(spec_path.read_text())
        specs = {k: [str(v) for v in vals] for k, vals in doc["params"].items()}
        scenario, runs, seed = doc["scenario"], int(doc["runs"]), int(doc["seed"])
    except (tomllib.TOMLDecodeError, KeyError, TypeError, ValueError) as exc:
        raise InputError(f"not a valid sweep spec ({type(exc).__name__}: {exc})", spec_path) from None
    tasks = build_grid(scenario, specs, runs, seed, doc.get("trackers"), None, keep_data=False,
                       tracker_specs=tracker_specs)
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


def run_sweep_spec(spec_path: str | Path, executor: str = "serial", tracker_specs=()) -> pl.DataFrame:
    """A bundled regression sweep (``data/sweeps/*.toml``): metrics only, no files kept.

    Raises
    ------
    InputError
        A point failed, or a tracker failed on a point.
    """
    report = sweep_spec_report(spec_path, executor, tracker_specs)
    lines = report.tracker_failure_lines()
    if lines:
        raise InputError(lines[0])
    return report.table
