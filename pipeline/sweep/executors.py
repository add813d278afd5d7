"""The executors of a sweep: serial, a process pool (forkserver, workers that end with their
client) and Dask (a local cluster on 127.0.0.1, or a scheduler's address); each yields the
points' :class:`~trackreplay.sweep.point.PointResult` as they finish."""

from __future__ import annotations

import os
import signal
import sys
import threading
import time
from typing import TYPE_CHECKING

from trackreplay.errors import InputError
from trackreplay.sweep.interruption import _signals_held
from trackreplay.sweep.point import PointResult, run_point

if TYPE_CHECKING:
    from trackreplay.sweep.grid import PointTask


EXECUTORS = ("serial", "process", "dask")


def default_workers() -> int:
    from trackreplay.machine import usable_cores

    return usable_cores()


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
    try:
        sys.unraisablehook = _quiet_when_stopped
        _watch_client(client_pid)
    except _WorkerStop as stop:
        # stopped while starting (the pool is being stopped): concurrent.futures would log an
        # "Exception in initializer" traceback on the sweep's stderr; leave quietly instead
        os._exit(stop.code)


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
    import itertools
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
        finished = broken = False
        try:
            while True:
                while len(held) < size and not broken and (task := next(queue, None)) is not None:
                    try:
                        with _signals_held():  # a submit may start a worker
                            held[pool.submit(_pool_run_point, task)] = task
                            processes.update(getattr(pool, "_processes", None) or {})
                    except BrokenProcessPool:
                        # a worker died since the last wait (its point's future tells which):
                        # this task was not handed out, so it goes on in the next pool
                        queue, broken = itertools.chain([task], queue), True
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
    # a worker the pool stopped ends by SIGTERM, or through its own SIGTERM handler (128 + 15)
    stopped = (-signal.SIGTERM, 128 + signal.SIGTERM)
    own = [c for c in codes if c is not None and c not in stopped] or [c for c in codes if c is not None]
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
