"""Parameter sweeps: simulate → replay → evaluate every point of a grid, on one core, a
process pool or a Dask cluster.

* The grid is the cartesian product of ``--param NAME=v1,v2,...`` over a scenario's parameters;
  every point is validated by the scenario's recorder before any work starts.
* Each point's seed is derived from the base seed and the point's parameters
  (:func:`point_seed`), so a point gives the same numbers on any executor and in any order.
* :func:`run_point` is the whole job of one point: a pure function of its :class:`PointTask`
  that never raises (an error comes back as text), so one failed point never loses the others.
* The client (this process) writes each point's metrics to ``points/<label>/metrics.parquet``
  as it completes; ``resume`` skips points whose file exists.
* Dask is the engine beyond one machine (``Client(address)``); locally a ``LocalCluster``
  bound to 127.0.0.1 without dashboard. No home-made scheduler.
"""

from __future__ import annotations

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


@dataclass
class PointResult:
    index: int
    label: str
    records: list = field(default_factory=list)
    error: str | None = None
    work_s: float = 0.0


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
               out_dir: Path | None = None, keep_data: bool = True, fixed: dict | None = None) -> list[PointTask]:
    """The grid's tasks, every point validated before anything runs.

    Parameters
    ----------
    fixed : dict, optional
        Parameters set the same at every point (``--set``).
    """
    from recorders import recorder_module
    from recorders.scenarios import load_scenario

    base = load_scenario(scenario_name).with_overrides(fixed or {})
    validate = recorder_module(base.recorder).validate
    if runs < 1:
        raise InputError("--runs must be ≥ 1")
    names = list(specs)
    tasks = []
    for index, combo in enumerate(itertools.product(*(specs[n] for n in names))):
        sc = base.with_overrides(dict(zip(names, combo)))
        overrides = tuple((n, sc.params[n]) for n in names)
        try:
            validate(sc.params)
        except InputError as exc:
            raise InputError(f"grid point {point_label(overrides)}: {exc}") from None
        label = point_label(overrides)
        point_dir = str(Path(out_dir) / "points" / label) if (out_dir is not None and keep_data) else None
        # Fixed settings first, swept values after: applying them in order gives the point.
        tasks.append(PointTask(index, label, scenario_name, tuple((fixed or {}).items()) + overrides,
                               runs, point_seed(seed, overrides), tuple(trackers) if trackers else None, point_dir))
    return tasks


def run_point(task: PointTask) -> PointResult:
    """Simulate, replay and evaluate one grid point; errors come back in the result."""
    t0 = time.perf_counter()
    try:
        records = _run_point(task)
        return PointResult(task.index, task.label, records, None, time.perf_counter() - t0)
    except Exception as exc:  # isolate the point: the sweep reports it and goes on
        msg = str(exc) if isinstance(exc, InputError) else "".join(
            traceback.format_exception_only(type(exc), exc)).strip()
        return PointResult(task.index, task.label, [], msg, time.perf_counter() - t0)


def _run_point(task: PointTask) -> list[dict]:
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
                     rrd_path=work / "tracks.rrd" if keep else None)
    finally:
        if not keep:
            shutil.rmtree(work, ignore_errors=True)
    overall = res.summary.filter(pl.col("scope") == "overall")
    return [{"tracker": r["tracker"], "metric": r["metric"], "value": r["value"]} for r in overall.iter_rows(named=True)]


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


def _preload_worker() -> None:
    import pipeline.replay  # noqa: F401
    import recorders.simulated  # noqa: F401


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
        client.run(_preload_worker)
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

    @property
    def median_point_s(self) -> float:
        return float(np.median(self.point_work_s)) if self.point_work_s else float("nan")


def _metrics_file(out_dir: Path, label: str) -> Path:
    return out_dir / "points" / label / "metrics.parquet"


def _point_frame(task: PointTask, records: list[dict], swept: list[str]) -> pl.DataFrame:
    values = dict(task.overrides)  # the swept values come last, so they win
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
        f = _metrics_file(out_dir, t.label) if out_dir is not None else None
        if resume and f is not None and f.exists():
            frames[t.index] = pl.read_parquet(f)
            skipped += 1
            if progress:
                progress(1)
        else:
            todo.append(t)
    by_index = {t.index: t for t in tasks}
    failed, work = {}, []
    if todo:
        if executor == "serial" or (executor == "process" and workers == 1):
            it = _iter_serial(todo)
        elif executor == "process":
            it = _iter_process(todo, workers)
        else:
            it = _iter_dask(todo, workers, scheduler)
        for res in it:
            work.append(res.work_s)
            if res.error is not None:
                failed[res.label] = res.error
            else:
                frame = _point_frame(by_index[res.index], res.records, swept)
                frames[res.index] = frame
                if out_dir is not None:
                    with atomic_output(_metrics_file(out_dir, res.label)) as fh:
                        frame.write_parquet(fh)
            if progress:
                progress(1)
    table = (pl.concat([frames[i] for i in sorted(frames)], how="vertical_relaxed") if frames
             else pl.DataFrame(schema={"point_index": pl.Int64, "point": pl.Utf8, "tracker": pl.Utf8,
                                       "metric": pl.Utf8, "value": pl.Float64}))
    return SweepReport(table, len(todo) - len(failed), skipped, failed, time.perf_counter() - t0, work, out_dir)


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


def run_sweep_spec(spec_path: str | Path, executor: str = "serial") -> pl.DataFrame:
    """A bundled regression sweep (``data/sweeps/*.toml``): metrics only, no files kept."""
    import tomllib

    spec_path = Path(spec_path)
    try:
        doc = tomllib.loads(spec_path.read_text())
        specs = {k: [str(v) for v in vals] for k, vals in doc["params"].items()}
        scenario, runs, seed = doc["scenario"], int(doc["runs"]), int(doc["seed"])
    except (tomllib.TOMLDecodeError, KeyError, TypeError, ValueError) as exc:
        raise InputError(f"not a valid sweep spec ({type(exc).__name__}: {exc})", spec_path) from None
    tasks = build_grid(scenario, specs, runs, seed, doc.get("trackers"), None, keep_data=False)
    report = run_sweep(tasks, list(specs), None, executor=executor)
    if report.failed:
        raise InputError(f"sweep points failed: {report.failed}", spec_path)
    return report.table
