"""Parameter sweeps: simulate → replay → evaluate every point of a grid, on one core, a
process pool or a Dask cluster.

* The grid is the cartesian product of ``--param NAME=v1,v2,...`` over a scenario's parameters;
  every point is validated by the scenario's recorder before any work starts.
* Each point's seed is derived from the base seed and the point's parameters
  (:func:`point_seed`), so a point gives the same numbers on any executor and in any order.
* :func:`run_point` is the whole job of one point: a pure function of its :class:`PointTask`
  that never raises (an error comes back as text), so one failed point never loses the others.
* The client (this process) writes each point's metrics to ``points/<label>/metrics.parquet``
  as it completes, then ``point.json``, the record of what the point computed (every scenario
  parameter, runs, base and point seed, tracker subset, plugged trackers' specs and file
  hashes, package version). ``resume`` reuses a point only when both read back and the record
  is the task's; any other point is computed again and :attr:`SweepReport.notes` says what
  changed. :func:`check_resume` refuses to resume into a folder that holds another sweep.
* Interruption: Ctrl-C (``KeyboardInterrupt``) and SIGTERM/SIGHUP (:class:`SweepTerminated`,
  exit status 128 + signal) stop the workers, keep every finished point and remove the
  temporaries of the unfinished ones. Pool workers ignore SIGINT (the client stops them) and
  exit when the client dies, even by SIGKILL (Dask's nannied workers do the same); temporaries
  a SIGKILL leaves behind are removed by the next sweep into the folder, which holds a lock on
  it while it runs.
* Evaluation design values (the matching gate, the GOSPA cut-off and order, HOTA's distance
  scale, the SIAP gate: :attr:`trackreplay.stages.base.Stage.evaluation_defaults`) go with
  ``--set`` or ``--param`` like the trackers' design values: to every point's replay, without
  changing its seed. A name that is also a parameter of the scenario is the scenario's (it goes
  into the data set, whose scenario record the evaluation reads as well, and into the seed).
  Every point's ``point.json`` (and its ``metrics.parquet``'s metadata) records the evaluation
  values it was scored with; ``sweep.json`` and ``sweep.parquet``'s metadata the sweep's.
* Plugged trackers (``--tracker``) travel to the workers as canonical specs (absolute file
  paths, :func:`trackreplay.registry.canonical_spec`) and are loaded again there, so serial, process
  pool and Dask runs load the same file. A tracker that fails on a point is reported with its
  message (tracker, run, scan) while the other trackers' metrics of that point are kept.
* A point that fails, or is stopped, leaves nothing of its own: the files it wrote in its folder
  (data set, outputs, recording) are removed, and only those (:func:`discard_point_files`). A
  worker process that dies under a point is that point's failure; the other points finish
  (:func:`_iter_process`; on Dask after its retries). A point whose files cannot be written (a
  full or read-only disk, a file size limit: :data:`trackreplay.paths.DISK_ERRNOS`) stops the
  whole sweep with one line naming the file, since every other point would fail the same way;
  finished points are kept for ``--resume``.
* Dask is the engine beyond one machine (``Client(address)``); locally a ``LocalCluster``
  whose scheduler, nannies and workers (and their HTTP routes, on a random port) listen on
  127.0.0.1 only, without dashboard. No home-made scheduler.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import os
import re
import shutil
import signal
import sys
import tempfile
import threading
import time
import traceback
import zlib
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import polars as pl

from trackreplay import __version__
from trackreplay.contract import atomic_output
from trackreplay.errors import InputError
from trackreplay.isolation import DEFAULT_TRACKER_TIME_LIMIT_S
# errors of writing a point's files that no other point would escape (a full or read-only disk, a
# file size limit): the sweep stops at the first, with one line naming the file
from trackreplay.paths import DISK_ERRNOS, disk_error

EXECUTORS = ("serial", "process", "dask")


class SweepTerminated(SystemExit):
    """A sweep stopped by SIGTERM or SIGHUP: finished points are kept, workers are stopped.
    Its code is the conventional exit status 128 + signal number."""


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


@dataclass
class PointResult:
    index: int
    label: str
    records: list = field(default_factory=list)
    error: str | None = None
    work_s: float = 0.0
    # (where, message) of every tracker that failed on this point; the others' records are kept
    tracker_errors: list = field(default_factory=list)
    # stage name → {evaluation design value: value} the point was scored with
    evaluation: dict = field(default_factory=dict)
    # (errno, problem, file) when the point failed because its files could not be written (a full
    # or read-only disk, a file size limit): every point would, so the sweep stops (DISK_ERRNOS)
    disk_error: tuple | None = None


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


def run_point(task: PointTask) -> PointResult:
    """Simulate, replay and evaluate one grid point; errors come back in the result."""
    from trackreplay.trackers.interface import TrackerError

    t0 = time.perf_counter()
    try:
        records, failures, evaluation = _run_point(task)
        return PointResult(task.index, task.label, records, None, time.perf_counter() - t0,
                           [(f.path or "", str(f)) for f in failures], evaluation)
    except TrackerError as exc:  # no tracker of the point ran (e.g. the plugged one alone failed)
        return PointResult(task.index, task.label, [], None, time.perf_counter() - t0, [(exc.path or "", str(exc))])
    except OSError as exc:
        msg = f"{exc.filename}: {exc.strerror or exc}" if exc.filename else str(exc)
        disk = (exc.errno, exc.strerror or str(exc), str(exc.filename or "")) if exc.errno in DISK_ERRNOS else None
        return PointResult(task.index, task.label, [], msg, time.perf_counter() - t0, disk_error=disk)
    except Exception as exc:  # isolate the point: the sweep reports it and goes on
        msg = str(exc) if isinstance(exc, InputError) else "".join(
            traceback.format_exception_only(type(exc), exc)).strip()
        return PointResult(task.index, task.label, [], msg, time.perf_counter() - t0)


def _run_point(task: PointTask) -> tuple[list[dict], list, dict]:
    from trackreplay.replay import replay
    from trackreplay.recorders.scenarios import load_scenario
    from trackreplay.recorders.simulated import record

    sc = load_scenario(task.scenario).with_overrides(dict(task.overrides))
    keep = task.point_dir is not None
    work = Path(task.point_dir) if keep else Path(tempfile.mkdtemp(prefix="sweep-point-"))
    before = _point_files(work) if keep else None
    writing = [work]  # the file being written, named in an error that names none

    def recording(*args):  # the Rerun recording is written last, after tracks.mcap
        from trackreplay.face.rerun_views import write_recording

        writing[0] = work / "tracks.rrd"
        return write_recording(*args)

    done = False
    try:
        work.mkdir(parents=True, exist_ok=True)
        data = writing[0] = work / "data.mcap"
        record(data, sc, task.runs, task.seed)
        writing[0] = work / "tracks.mcap"
        res = replay(data, list(task.trackers) if task.trackers else None,
                     out_path=work / "tracks.mcap" if keep else None,
                     rrd_path=work / "tracks.rrd" if keep else None,
                     design_overrides=dict(task.design) or None, tracker_specs=task.tracker_specs,
                     recorder=recording, tracker_time_limit_s=task.tracker_time_limit_s)
        done = True
    except (OSError, RuntimeError) as exc:  # a writer's failure that names no file (Rerun's: RuntimeError)
        named = disk_error(exc, writing[0])
        if named is not None:
            raise named from None
        raise
    finally:
        if not keep:
            shutil.rmtree(work, ignore_errors=True)
        elif not done:  # a point is complete or leaves nothing: what this point wrote goes
            discard_point_files(work, before)
    overall = res.summary.filter(pl.col("scope") == "overall")
    records = [{k: r.get(k) for k in RECORD_COLUMNS} for r in overall.iter_rows(named=True)]
    return records, res.failures, evaluation_used(res)


#: what a point writes into its folder (with --keep-data): removed again when the point fails
POINT_FILES = ("data.mcap", "tracks.mcap", "tracks.rrd")


def _point_files(folder: Path) -> dict:
    """What a point's folder holds of :data:`POINT_FILES` now: whether it exists, and each file's
    identity (inode, modification time, size), to tell later which files a run put there."""
    files = {}
    for name in POINT_FILES:
        try:
            st = (folder / name).stat()
        except OSError:
            continue
        files[name] = (st.st_ino, st.st_mtime_ns, st.st_size)
    return {"folder": folder.is_dir(), "files": files}


def discard_point_files(folder, before: dict | None) -> list[Path]:
    """Remove what a failed or stopped point wrote into ``folder``: each of :data:`POINT_FILES`
    that is not the file ``before`` (:func:`_point_files` taken before the point ran) saw, their
    half-written temporaries, and the folder when the point made it and it is left empty. Files
    the point did not write stay, whatever their names."""
    folder = Path(folder)
    before = before or {"folder": False, "files": {}}
    now = _point_files(folder)
    removed = []
    for name, identity in now["files"].items():
        if before["files"].get(name) != identity:
            try:
                (folder / name).unlink()
                removed.append(folder / name)
            except OSError:
                pass
    try:
        entries = list(folder.iterdir()) if now["folder"] else []
    except OSError:
        entries = []
    for f in entries:
        if _TEMPORARY.fullmatch(f.name) and f.name.startswith(tuple(n + "." for n in POINT_FILES)):
            try:
                f.unlink()
                removed.append(f)
            except OSError:
                pass
    if now["folder"] and not before["folder"]:
        try:
            folder.rmdir()  # only when empty
        except OSError:
            pass
    return removed


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


# every metric of a point with its Monte Carlo standard error and 95 % interval (docs/evaluation.md)
RECORD_COLUMNS = ("tracker", "metric", "value", "se", "ci_low", "ci_high")
RECORD_SCHEMA = {"tracker": pl.Utf8, "metric": pl.Utf8, "value": pl.Float64, "se": pl.Float64,
                 "ci_low": pl.Float64, "ci_high": pl.Float64}


# --------------------------------------------------------------------------- executors


def _iter_serial(tasks):
    for t in tasks:
        yield run_point(t)


PRELOAD = ["trackreplay.sweep", "trackreplay.replay", "trackreplay.recorders.simulated"]


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


class _WorkerStop(SystemExit):
    """Raised in a pool worker by SIGTERM: unwinds the point (its temporaries are removed)."""


def _worker_stop(signum, frame):
    signal.signal(signum, signal.SIG_IGN)  # once: let the unwinding finish
    raise _WorkerStop(128 + signum)


def _watch_client(pid: int, grace_s: float = 5.0) -> None:
    """End this worker when process ``pid`` (the sweep's client) ends, however it ends.

    A forkserver's children outlive the client otherwise: they wait on their task queue
    forever, and the forkserver waits for them. The worker first gets SIGTERM (it unwinds its
    point and removes its temporaries), then ``_exit`` after ``grace_s``.
    """
    try:
        fd = os.pidfd_open(pid)
    except ProcessLookupError:
        os._exit(128 + signal.SIGTERM)
    except (AttributeError, OSError):  # no pidfd (not Linux ≥ 5.3): poll
        fd = None

    def watch():
        if fd is not None:
            import select

            select.select([fd], [], [])
        else:
            while True:
                time.sleep(0.5)
                try:
                    os.kill(pid, 0)
                except ProcessLookupError:
                    break
                except PermissionError:
                    pass
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(grace_s)
        os._exit(128 + signal.SIGTERM)

    threading.Thread(target=watch, name="sweep-client-watch", daemon=True).start()


def _pool_worker_init(client_pid: int) -> None:
    # Ctrl-C reaches the whole process group: the client stops the pool, the workers do not
    # print tracebacks of their own.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, _worker_stop)
    sys.unraisablehook = _quiet_when_stopped
    _watch_client(client_pid)


def _quiet_when_stopped(unraisable) -> None:
    """A worker's stop can land in a finalizer (Rerun's recording stream flushes in its
    ``__del__``, after the recording was saved and disconnected): Python would print that as an
    "Exception ignored" traceback on the sweep's stderr. Those are dropped; anything else is
    reported as Python reports it."""
    stopped = isinstance(unraisable.exc_value, _WorkerStop)
    finalizer = getattr(unraisable.object, "__qualname__", "").endswith("RecordingStream.__del__")
    if not (stopped or finalizer):
        sys.__unraisablehook__(unraisable)


def _pool_run_point(task: PointTask) -> PointResult:
    try:
        return run_point(task)
    except _WorkerStop as stop:  # the point has unwound; leave now instead of taking the next one
        os._exit(stop.code)


def _stop_pool(pool, grace_s: float = 5.0) -> None:
    """Stop the workers now (SIGTERM, then SIGKILL), then cancel what has not started.

    The workers go first: shutting the pool down releases its queues, whose named semaphores
    a worker still starting (unpickling them in the forkserver's child) would then miss, with a
    traceback on the terminal; a worker stopped first never gets there.
    """
    procs = list((getattr(pool, "_processes", None) or {}).values())
    for p in procs:
        if p.is_alive():
            p.terminate()
    deadline = time.monotonic() + grace_s
    for p in procs:
        p.join(max(0.0, deadline - time.monotonic()))
    for p in procs:
        if p.is_alive():
            p.kill()
            p.join(2.0)
    pool.shutdown(wait=False, cancel_futures=True)


def _iter_process(tasks, workers):
    """Every task's :class:`PointResult`, from a pool of ``workers`` processes, as they finish.

    At most ``workers`` points are handed to the pool at a time, so that the points a pool
    holds are the ones its workers compute. A worker that dies (the interpreter crashes, the
    kernel's out-of-memory killer, code that calls ``os._exit`` outside a plugged tracker's own
    child process) breaks the whole pool: the points not handed out yet go on in a new pool;
    of the ones it held, a lone one is that point's failure (saying how its worker ended), and
    several are computed again one at a time, each in a pool of its own, so that only the point
    that kills its worker again fails and no other point is blamed or lost.
    """
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
    from concurrent.futures.process import BrokenProcessPool

    ctx = _forkserver_context()
    waiting, suspects = list(tasks), []
    while waiting or suspects:
        alone = bool(suspects)
        queue = iter([suspects.pop(0)] if alone else waiting)
        size = 1 if alone else workers
        if not alone:
            waiting = []
        pool = ProcessPoolExecutor(max_workers=size, mp_context=ctx, initializer=_pool_worker_init,
                                   initargs=(os.getpid(),))
        held, processes, lost = {}, {}, []
        finished = False
        try:
            while True:
                while len(held) < size and (task := next(queue, None)) is not None:
                    with _signals_held():  # a submit may start a worker
                        held[pool.submit(_pool_run_point, task)] = task
                        processes.update(getattr(pool, "_processes", None) or {})
                if not held:
                    break
                done, _ = wait(held, return_when=FIRST_COMPLETED)
                for f in done:
                    task = held.pop(f)
                    try:
                        res = f.result()
                    except BrokenProcessPool:
                        lost.append(task)
                        continue
                    yield res
                if lost:  # every point the pool held is lost with it
                    lost += list(held.values())
                    held.clear()
                    break
            finished = True
        finally:
            if not finished:  # interrupted, or the consumer stopped early
                _stop_pool(pool)
            else:
                pool.shutdown(wait=True)
        waiting += list(queue)  # not handed out: they go on in the next pool
        if len(lost) == 1:
            how = _how_workers_ended(list(processes.values()))
            yield PointResult(lost[0].index, lost[0].label, [], f"its worker process ended ({how}) while computing it")
        else:
            suspects += lost


def _how_workers_ended(processes) -> str:
    """How a broken pool's worker ended: the exit status or the signal of the first that died on
    its own (the pool terminates the others with SIGTERM)."""
    codes = []
    for p in processes:
        p.join(5.0)
        codes.append(p.exitcode)
    own = [c for c in codes if c is not None and c != -signal.SIGTERM] or [c for c in codes if c is not None]
    if not own:
        return "unknown how"
    code = own[0]
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit status {code}"


def _preload_worker(specs=()) -> None:
    import trackreplay.replay  # noqa: F401
    import trackreplay.recorders.simulated  # noqa: F401

    if specs:  # load the plugged trackers once per worker (a bad spec fails in the point, by name)
        from trackreplay.registry import available_trackers

        try:
            available_trackers(specs)
        except InputError:
            pass


def _ignore_sigint() -> None:
    """On a local Dask worker: Ctrl-C is the client's (it closes the cluster)."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)


def local_cluster(workers: int):
    """A ``LocalCluster`` that listens on 127.0.0.1 only, on random ports.

    ``dashboard_address=None`` alone still serves the scheduler's HTTP routes on the fixed
    port 8787; here they get a random loopback port and no dashboard. Nannies and workers
    bind the cluster's host.
    """
    import logging

    import dask
    from dask.distributed import LocalCluster

    # Local workers fork from the same preloaded server as the process pool instead of
    # spawning fresh interpreters that each import numpy, polars and distributed again.
    _forkserver_context(["distributed"])
    with dask.config.set({"distributed.worker.multiprocessing-method": "forkserver"}):
        return LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                            dashboard_address=None, worker_dashboard_address=None,
                            scheduler_kwargs={"dashboard": False, "dashboard_address": "127.0.0.1:0"},
                            # a point's failure reaches the user through its future, in one
                            # line; the workers' own logs only race the shutdown of an interrupt
                            # ("failed to communicate with scheduler") onto the terminal
                            silence_logs=logging.CRITICAL)


def _iter_dask(tasks, workers, scheduler):
    from dask.distributed import Client, as_completed

    cluster = None
    client = None
    futures = []
    finished = False
    try:
        if scheduler:
            try:
                client = Client(scheduler, timeout="10s")
            except (OSError, TimeoutError) as exc:
                raise InputError(f"cannot reach the Dask scheduler at {scheduler} ({type(exc).__name__}: "
                                 f"{str(exc).splitlines()[0] if str(exc) else 'no answer'})") from None
        else:
            cluster = local_cluster(workers)
            client = Client(cluster)
            client.run(_ignore_sigint)
        # import the numerics on every worker at once, before the first point, as the
        # forkserver preload does for the process pool
        client.run(_preload_worker, sorted({s for t in tasks for s in t.tracker_specs}))
        futures = client.map(run_point, tasks, pure=False)
        task_of = {f.key: t for f, t in zip(futures, tasks)}
        for f in as_completed(futures):
            try:
                res = f.result()
            except Exception as exc:  # noqa: BLE001 - its worker died (KilledWorker), more than once
                t = task_of[f.key]
                first = str(exc).split(". ")[0]  # Dask's KilledWorker goes on for lines
                res = PointResult(t.index, t.label, [], f"its worker process ended while computing it "
                                                        f"({type(exc).__name__}: {first})")
            yield res
        finished = True
    finally:
        _close_dask(client, cluster, futures, finished)


def _close_dask(client, cluster, futures, finished) -> None:
    import logging

    quiet = logging.getLogger("distributed")
    level = quiet.level
    if not finished:  # closing on an interrupt: the workers' complaints are expected
        quiet.setLevel(logging.CRITICAL)
    try:
        if client is not None:
            if futures and not finished:
                try:
                    client.cancel(futures, force=True)
                except Exception:
                    pass
            client.close(timeout=10)
        if cluster is not None:
            cluster.close(timeout=10)
    finally:
        quiet.setLevel(level)


def default_workers() -> int:
    from trackreplay.machine import usable_cores

    return usable_cores()


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


def _metrics_file(out_dir: Path, label: str) -> Path:
    return out_dir / "points" / label / "metrics.parquet"


def _record_file(out_dir: Path, label: str) -> Path:
    return out_dir / "points" / label / "point.json"


_TEMPORARY = re.compile(r".+\.[A-Za-z0-9_]{8}\.tmp$")  # atomic_output's mkstemp names


def _remove_temporaries(out_dir: Path) -> list[Path]:
    """Remove the half-written files (``<name>.<random>.tmp``) a killed sweep left in the
    folder: beside the table, in ``plots/`` and in every ``points/<label>/``."""
    dirs = [out_dir, out_dir / "plots"]
    points = out_dir / "points"
    if points.is_dir():
        dirs += [d for d in points.iterdir() if d.is_dir()]
    removed = []
    for d in dirs:
        try:
            entries = list(d.iterdir())
        except OSError:
            continue
        for f in entries:
            if _TEMPORARY.fullmatch(f.name) and f.is_file():
                try:
                    f.unlink()
                    removed.append(f)
                except OSError:
                    pass
    return removed


@contextmanager
def _folder_lock(out_dir: Path | None):
    """Hold an exclusive lock on the output folder (released by the kernel however the process
    ends), so that removing temporaries never races another sweep writing there."""
    if out_dir is None:
        yield
        return
    try:
        import fcntl
    except ImportError:  # not POSIX
        yield
        return
    out_dir.mkdir(parents=True, exist_ok=True)
    fd = os.open(out_dir, os.O_RDONLY)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise InputError("another sweep is writing to this folder; wait for it or choose another -o",
                             out_dir) from None
        yield
    finally:
        os.close(fd)


@contextmanager
def _stop_on_signals():
    """While a sweep runs: SIGINT raises ``KeyboardInterrupt`` and SIGTERM/SIGHUP raise
    :class:`SweepTerminated`, each once, so the executors' clean-up runs instead of the process
    dying with its workers left behind. A signal the process ignores (``nohup``) stays ignored."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    fired = []

    def handler(signum, frame):
        if _HELD["depth"]:  # in a step that must not be cut (starting a worker): after it
            _HELD["pending"].append(signum)
            return
        if fired:  # already stopping: let the clean-up finish
            return
        fired.append(signum)
        if signum == signal.SIGINT:
            raise KeyboardInterrupt
        name = signal.Signals(signum).name
        try:
            sys.stderr.write(f"sweep: stopped by {name}; finished points are kept\n")
            sys.stderr.flush()
        except (OSError, ValueError):
            pass
        raise SweepTerminated(128 + signum)

    sigs = [signal.SIGINT, signal.SIGTERM] + ([signal.SIGHUP] if hasattr(signal, "SIGHUP") else [])
    old = {s: signal.getsignal(s) for s in sigs}
    for s in sigs:
        if old[s] is not signal.SIG_IGN:
            signal.signal(s, handler)
    outer = _HELD["handler"]
    _HELD["handler"] = handler
    try:
        yield
    finally:
        _HELD["handler"] = outer
        for s, h in old.items():
            signal.signal(s, h if h is not None else signal.SIG_DFL)


# the stop signals held back while a worker starts (see _signals_held): its depth, the signals
# that came meanwhile, and the handler of the sweep running (None outside one)
_HELD = {"depth": 0, "pending": [], "handler": None}


@contextmanager
def _signals_held():
    """Hold back the sweep's stop signals (:func:`_stop_on_signals`) for a step that must not be
    cut, and act on them after it.

    Starting a pool worker is such a step: a signal that lands inside ``Process.start`` stops
    the sweep after the forkserver made the worker but before the pool recorded it, so it is
    never stopped; it goes on starting, finds its queues' semaphores gone with the sweep, and
    prints a traceback on the terminal.
    """
    _HELD["depth"] += 1
    try:
        yield
    finally:
        _HELD["depth"] -= 1
        if not _HELD["depth"] and _HELD["pending"]:
            signum = _HELD["pending"][0]
            _HELD["pending"].clear()
            if _HELD["handler"] is not None:
                _HELD["handler"](signum, None)


def _short(value, limit: int = 60) -> str:
    """A value for a one-line message: ``-`` for none, lists comma-separated, long text cut."""
    if value is None:
        text = "-"
    elif isinstance(value, list) and all(isinstance(v, (str, int, float)) for v in value):
        text = ",".join(map(str, value)) or "-"
    elif isinstance(value, str):
        text = value
    else:
        text = json.dumps(value, default=str)
    return text if len(text) <= limit else text[: limit - 1] + "…"


def record_changes(old: dict, new: dict) -> list[str]:
    """What differs between two point records, as short phrases ("runs 100 → 5")."""
    out = []
    for key in dict.fromkeys([*new, *old]):
        a, b = old.get(key), new.get(key)
        if a == b:
            continue
        if key == "seed" and old.get("base_seed") != new.get("base_seed"):
            continue  # follows from the base seed
        if key == "overrides" and old.get("params") != new.get("params"):
            continue  # the parameters say it better
        if key == "params" and isinstance(a, dict) and isinstance(b, dict):
            out += [f"{k} {_short(a.get(k))} → {_short(b.get(k))}"
                    for k in dict.fromkeys([*b, *a]) if a.get(k) != b.get(k)]
        elif key == "tracker_files" and isinstance(a, dict) and isinstance(b, dict) and set(a) == set(b):
            out += [f"tracker file {k.rpartition(':')[0]} edited" for k in b if a[k] != b[k]]
        else:
            label = {"version": "package version", "base_seed": "seed"}.get(key, key)
            out.append(f"{label} {_short(a)} → {_short(b)}")
    return out


def _reuse(task: PointTask, out_dir: Path, swept: list[str]) -> tuple[pl.DataFrame | None, str | None, dict]:
    """The point's table from a previous sweep, or ``None`` and why it is computed again
    (``None`` as the reason: it never finished); and the evaluation values it was scored with."""
    metrics = _metrics_file(out_dir, task.label)
    if not metrics.exists():
        return None, None, {}
    rec = _record_file(out_dir, task.label)
    if not rec.exists():
        return None, "no point.json records what it computed", {}
    try:
        old = json.loads(rec.read_text())
        if not isinstance(old, dict):
            raise ValueError("not a JSON object")
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        return None, f"point.json unreadable ({type(exc).__name__})", {}
    # what the point was scored with: a result, not part of what it computes (its record)
    evaluation = old.pop("evaluation", None)
    evaluation = evaluation if isinstance(evaluation, dict) else {}
    new = task.record()
    if old != new:
        return None, "; ".join(record_changes(old, new)) or "point.json differs", {}
    try:
        stored = pl.read_parquet(metrics)
        stored = stored.with_columns(*(pl.lit(None, pl.Float64).alias(c) for c in RECORD_COLUMNS
                                       if c not in stored.columns))
        records = stored.select(RECORD_COLUMNS).cast(RECORD_SCHEMA).to_dicts()
    except Exception as exc:  # any damage: compute the point again rather than trust it
        return None, f"metrics.parquet unreadable ({type(exc).__name__})", {}
    # the stored values under this grid's index, label and columns, as a fresh run builds them
    return _point_frame(task, records, swept), None, evaluation


def _resume_notes(reasons: dict[str, str]) -> list[str]:
    """One line per distinct reason why points of a resumed sweep were computed again."""
    by_reason: dict[str, list[str]] = {}
    for label, why in reasons.items():
        by_reason.setdefault(why, []).append(label)
    lines = []
    for why, labels in by_reason.items():
        which = f"point {labels[0]}" if len(labels) == 1 else f"{len(labels)} points"
        lines.append(f"resume: computing {which} again: {why}")
    return lines


def _spec_key(spec: dict) -> dict:
    """The parts of a sweep spec (``sweep.json``) that define its table."""
    keys = ("scenario", "params", "fixed", "runs", "seed", "trackers", "tracker_specs")
    return json.loads(json.dumps({k: spec.get(k) for k in keys}, default=str))


def check_resume(out_dir: Path, spec: dict) -> None:
    """Refuse to resume into a folder whose ``sweep.json`` describes another sweep.

    Raises
    ------
    InputError
        One line naming what changed (grid, fixed values, runs, seed, trackers).
    """
    path = Path(out_dir) / "sweep.json"
    if not path.exists():
        return  # a first sweep that was interrupted: every point's record decides
    try:
        old = json.loads(path.read_text())
        if not isinstance(old, dict):
            raise ValueError("not a JSON object")
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise InputError(f"--resume: cannot read sweep.json ({type(exc).__name__}); "
                         "drop --resume to compute the sweep again", out_dir) from None
    a, b = _spec_key(old), _spec_key(spec)
    changes = []
    for key in b:
        if a[key] == b[key]:
            continue
        if key in ("params", "fixed") and isinstance(a[key], dict) and isinstance(b[key], dict):
            for name in dict.fromkeys([*b[key], *a[key]]):
                va, vb = a[key].get(name), b[key].get(name)
                if va != vb:
                    changes.append(f"{'--param' if key == 'params' else '--set'} {name} {_short(va)} → {_short(vb)}")
        else:
            changes.append(f"{key} {_short(a[key])} → {_short(b[key])}")
    if changes:
        raise InputError(f"--resume: this folder holds another sweep ({'; '.join(changes)}); "
                         "drop --resume to compute it again, or choose another -o", out_dir)


def _point_frame(task: PointTask, records: list[dict], swept: list[str]) -> pl.DataFrame:
    values = {**dict(task.overrides), **dict(task.design)}  # the swept values come last, so they win
    df = pl.DataFrame(records, schema=RECORD_SCHEMA)
    return df.with_columns(
        pl.lit(task.label).alias("point"), pl.lit(task.index).alias("point_index"),
        pl.lit(task.seed, dtype=pl.UInt64).alias("seed"),
        *[pl.lit(values[n]).alias(n) for n in swept],
    ).select("point_index", "point", *swept, "seed", *RECORD_COLUMNS)


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


#: key of the Parquet metadata (sweep.parquet, a point's metrics.parquet) holding the evaluation
#: design values the metrics were scored with, as JSON
EVALUATION_METADATA = "replay.evaluation"


@contextmanager
def _named_output(path: Path, mode: str = "wb"):
    """:func:`~trackreplay.contract.atomic_output`, whose errors name the file: a write that fails
    (a full disk) raises an ``OSError`` without a file name, and the user's line must name it."""
    try:
        with atomic_output(path, mode) as fh:
            yield fh
    except OSError as exc:
        if exc.filename is None and exc.errno is not None:
            raise OSError(exc.errno, exc.strerror or str(exc), str(path)) from None
        raise


def write_sweep_outputs(report: SweepReport, swept: list[str], spec: dict) -> list[Path]:
    """Table as Parquet + CSV, the spec as JSON (with the evaluation design values the points were
    scored with: :func:`evaluation_summary`), and one PNG per metric vs the first swept parameter."""
    out = report.out_dir
    with _stop_on_signals(), _folder_lock(out):
        try:
            return _write_sweep_outputs(report, swept, {**spec, "version": __version__,
                                                        "evaluation": evaluation_summary(report.evaluation)})
        finally:
            # a signal can land between a temporary's creation and the code that removes it
            # (inside tempfile.mkstemp); whatever is left is swept up here
            _remove_temporaries(out)


def _write_sweep_outputs(report: SweepReport, swept: list[str], spec: dict) -> list[Path]:
    from trackreplay.evaluators.report_plots import plot_facets, plot_metrics_vs

    out = report.out_dir
    paths = []
    with _named_output(out / "sweep.parquet") as f:
        report.table.write_parquet(f, metadata={EVALUATION_METADATA: json.dumps(spec.get("evaluation", {}),
                                                                                default=str)})
    with _named_output(out / "sweep.csv") as f:
        report.table.write_csv(f)
    with _named_output(out / "sweep.json", "w") as f:
        json.dump(spec, f, indent=1, default=str)
    paths += [out / "sweep.parquet", out / "sweep.csv", out / "sweep.json"]
    if report.table.height == 0:
        return paths
    x = swept[0]
    others = swept[1:]
    wide = report.table.pivot(on="metric", index=["point", *swept, "tracker"], values="value", aggregate_function="first")
    plot_dir = out / "plots"
    for metric in report.table["metric"].unique(maintain_order=True):
        values = report.table.filter(pl.col("metric") == metric)["value"].drop_nulls().drop_nans()
        if values.n_unique() <= 1:
            continue  # the same at every point for every tracker (a bound, a count that stays 0): nothing to plot
        title = f"{spec.get('scenario', '')}: {metric} vs {x}"
        if others:  # one panel per combination of the other parameters' values, readable for any number
            paths.append(plot_facets(wide, x, metric, others, plot_dir / f"{metric}.png", title=title))
        else:
            paths.append(plot_metrics_vs(wide, x, [metric], plot_dir / f"{metric}.png", title=title))
    return paths


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
